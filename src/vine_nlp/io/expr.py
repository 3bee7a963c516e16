"""Expressions of s in problem files (spec/formats.md, "Expressions").

A routing value such as ``theta = "pi/12 * sin(0.1 * s)"`` is parsed with :func:`ast.parse` and accepted only if every
node is on a short whitelist: numbers, ``+ - * / **``, unary ``-``/``+``, the names ``s``, ``pi``, ``e`` and
one-argument calls of ``sin cos tan exp log sqrt abs``. The accepted tree is turned into a chain of numpy calls; the
text is never handed to ``eval`` or ``exec``."""

from __future__ import annotations

import ast
import warnings
from typing import Callable

import numpy as np

MAX_LENGTH = 1000
MAX_DEPTH = 50

_FUNCTIONS = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "exp": np.exp, "log": np.log, "sqrt": np.sqrt, "abs": np.abs}
_CONSTANTS = {"pi": float(np.pi), "e": float(np.e)}
_VARIABLE = "s"
_ALLOWED_NAMES = "s, pi, e, " + ", ".join(_FUNCTIONS)

_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide, ast.Pow: np.power}
_UNARY = {ast.USub: np.negative, ast.UAdd: np.positive}

_OPERATOR_TEXT = {ast.Mod: "%", ast.FloorDiv: "//", ast.MatMult: "@", ast.LShift: "<<", ast.RShift: ">>", ast.BitOr: "|",
                  ast.BitXor: "^", ast.BitAnd: "&", ast.Not: "not", ast.Invert: "~"}
_SYNTAX_TEXT = {
    ast.Attribute: "attribute access", ast.Subscript: "indexing", ast.Compare: "comparison", ast.BoolOp: "'and'/'or'",
    ast.IfExp: "'if ... else'", ast.Lambda: "lambda", ast.List: "a list", ast.Tuple: "a tuple", ast.Set: "a set", ast.Dict: "a dict",
    ast.Starred: "'*' unpacking", ast.NamedExpr: "':='", ast.JoinedStr: "an f-string",
}


class ExpressionError(ValueError):
    """An expression that is not in the allowed language; the message is a short reason."""


class Expression:
    """A compiled expression; calling it evaluates it at s (any shape) and returns an array of that shape.

    Floating-point warnings are silenced: a log of a negative number is NaN, and the
    caller decides whether non-finite values are acceptable."""

    def __init__(self, text: str, fn: Callable):
        self.text = text
        self._fn = fn

    def __call__(self, s) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        with np.errstate(all="ignore"):
            value = self._fn(s)
        # Constant expressions do not depend on s but must still give one value per s.
        return np.array(np.broadcast_to(value, s.shape), dtype=float)

    def __repr__(self) -> str:
        return f"Expression({self.text!r})"


def compile_expression(text: str) -> Callable[[np.ndarray], np.ndarray]:
    """Parse ``text`` into a vectorized function of s, or raise :class:`ExpressionError`."""
    if not isinstance(text, str):
        raise ExpressionError("an expression must be a string")
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"expression is too long (more than {MAX_LENGTH} characters)")
    text = text.strip()
    if not text:
        raise ExpressionError("empty expression")
    # Bracket depth is checked on the text because parentheses leave no node in the tree.
    if _bracket_depth(text) > MAX_DEPTH:
        raise _too_deep()
    try:
        with warnings.catch_warnings():
            # Escape-sequence warnings of string literals are irrelevant: strings are rejected anyway.
            warnings.simplefilter("ignore")
            tree = ast.parse(text, mode="eval")
    except SyntaxError as err:
        raise ExpressionError(f"syntax error: {err.msg}") from None
    except (RecursionError, MemoryError):
        raise _too_deep() from None
    except ValueError:  # e.g. NUL characters
        raise ExpressionError("invalid characters in expression") from None
    return Expression(text, _build(tree.body, 1))


def _bracket_depth(text: str) -> int:
    depth = deepest = 0
    for ch in text:
        if ch in "([{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in ")]}":
            depth -= 1
    return deepest


def _too_deep() -> ExpressionError:
    return ExpressionError(f"expression is nested too deeply (more than {MAX_DEPTH} levels)")


def _build(node: ast.AST, depth: int) -> Callable:
    if depth > MAX_DEPTH:
        raise _too_deep()
    if isinstance(node, ast.BinOp):
        op = _BINARY.get(type(node.op))
        if op is None:
            raise _operator_error(node.op)
        left, right = _build(node.left, depth + 1), _build(node.right, depth + 1)
        return lambda s: op(left(s), right(s))
    if isinstance(node, ast.UnaryOp):
        op = _UNARY.get(type(node.op))
        if op is None:
            raise _operator_error(node.op)
        operand = _build(node.operand, depth + 1)
        return lambda s: op(operand(s))
    if isinstance(node, ast.Constant):
        return _constant(node.value)
    if isinstance(node, ast.Name):
        return _name(node.id)
    if isinstance(node, ast.Call):
        return _call(node, depth)
    what = _SYNTAX_TEXT.get(type(node), f"'{type(node).__name__}' syntax")
    raise ExpressionError(f"{what} is not allowed")


def _operator_error(op: ast.AST) -> ExpressionError:
    symbol = _OPERATOR_TEXT.get(type(op), type(op).__name__)
    hint = " (use ** for powers)" if isinstance(op, ast.BitXor) else ""
    return ExpressionError(f"operator '{symbol}' is not allowed{hint}")


def _constant(value) -> Callable:
    # type() rather than isinstance(): bool is a subclass of int.
    if type(value) not in (int, float):
        if isinstance(value, str):
            raise ExpressionError("strings are not allowed")
        raise ExpressionError(f"constant {value!r} is not allowed")
    try:
        number = float(value)
    except OverflowError:
        raise ExpressionError("number is too large") from None
    return lambda s: number


def _name(name: str) -> Callable:
    if name == _VARIABLE:
        return lambda s: s
    if name in _CONSTANTS:
        number = _CONSTANTS[name]
        return lambda s: number
    if name in _FUNCTIONS:
        raise ExpressionError(f"'{name}' is a function; write {name}(...)")
    raise ExpressionError(f"name '{name}' is not allowed (use {_ALLOWED_NAMES})")


def _call(node: ast.Call, depth: int) -> Callable:
    if not isinstance(node.func, ast.Name):
        raise ExpressionError(f"only {', '.join(_FUNCTIONS)} can be called")
    name = node.func.id
    fn = _FUNCTIONS.get(name)
    if fn is None:
        if name == _VARIABLE or name in _CONSTANTS:
            raise ExpressionError(f"'{name}' is not a function")
        raise ExpressionError(f"function '{name}' is not allowed (use {', '.join(_FUNCTIONS)})")
    if len(node.args) != 1 or node.keywords or isinstance(node.args[0], ast.Starred):
        raise ExpressionError(f"{name}() takes exactly one argument")
    arg = _build(node.args[0], depth + 1)
    return lambda s: fn(arg(s))
