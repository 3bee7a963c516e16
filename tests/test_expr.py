"""The whitelist expression language of problem files (spec/formats.md, "Expressions")."""

from __future__ import annotations

import ast
import inspect
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vine_nlp.io import expr
from vine_nlp.io.expr import ExpressionError, compile_expression

S = np.linspace(0.5, 100.0, 37)

VALID = [
    ("pi/12 * sin(0.1 * s)", lambda s: np.pi / 12 * np.sin(0.1 * s)),
    ("s**2 - 3*s + 1", lambda s: s**2 - 3 * s + 1),
    ("-s + +2", lambda s: -s + 2),
    ("exp(-s) * cos(s)", lambda s: np.exp(-s) * np.cos(s)),
    ("sqrt(abs(s - 50)) + log(1 + s**2)", lambda s: np.sqrt(np.abs(s - 50)) + np.log(1 + s**2)),
    ("tan(s / 1000)", lambda s: np.tan(s / 1000)),
    ("e**(s/100)", lambda s: np.e ** (s / 100)),
    ("2**-1 * s", lambda s: 0.5 * s),
    ("1e-3 * s - 2.5E2", lambda s: 1e-3 * s - 250.0),
    ("-2**2", lambda s: np.full_like(s, -4.0)),  # Python precedence: -(2**2)
    ("5887*(s/1000)**4 - 2847*(s/1000)**3 + 320*(s/1000)**2 + 6*s/1000",  # the paper's phi(s)
     lambda s: 5887 * (s / 1000) ** 4 - 2847 * (s / 1000) ** 3 + 320 * (s / 1000) ** 2 + 6 * s / 1000),
    ("  s  ", lambda s: s),
    ("sin(" * 20 + "s" + ")" * 20, None),
]


@pytest.mark.parametrize("text, reference", VALID, ids=[v[0][:40] for v in VALID])
def test_valid_expressions_match_numpy(text, reference):
    value = compile_expression(text)(S)
    if reference is None:
        reference = lambda s: _nested_sin(s, 20)  # noqa: E731
    np.testing.assert_allclose(value, reference(S), rtol=1e-12, atol=1e-15)
    assert value.shape == S.shape and value.dtype == float


def _nested_sin(s, n):
    for _ in range(n):
        s = np.sin(s)
    return s


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_constants_are_broadcast_to_the_shape_of_s(shape):
    value = compile_expression("2 * pi")(np.zeros(shape))
    assert value.shape == shape
    assert np.all(value == 2 * np.pi)


def test_invalid_math_gives_nan_without_warnings():
    s = np.array([-1.0, 0.0, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log, inverse = compile_expression("log(s) + sqrt(s)")(s), compile_expression("1/s")(s)
    assert np.isnan(log[0]) and np.isinf(log[1]) and log[2] == 1.0
    assert np.isinf(inverse[1])


REJECTED = [
    "s.__class__",
    "__import__('os')",
    "__import__('os').system('true')",
    "x",
    "S",
    "sin(s, s)",
    "sin()",
    "sin(s=1)",
    "sin(*[s])",
    "'a'",
    "b'a'",
    "f'{s}'",
    "s if s else 1",
    "[1]",
    "(1, 2)",
    "{1: 2}",
    "{1}",
    "lambda: 1",
    "s < 1",
    "s and 1",
    "not s",
    "~1",
    "s % 2",
    "s // 2",
    "s ^ 2",
    "s @ s",
    "s[0]",
    "(s := 1)",
    "[s for s in (1, 2)]",
    "sin",
    "s(1)",
    "pi(2)",
    "max(s, 1)",
    "eval('1')",
    "True",
    "None",
    "1j",
    "...",
    "",
    "   ",
    "1 +",
    "s s",
    "1\x00",
    "1" * 2000,
    "(" * 100 + "s" + ")" * 100,
    "-" * 60 + "s",
    "s" + "**s" * 60,
    "9" * 400,
]


@pytest.mark.parametrize("text", REJECTED, ids=[repr(t[:30]) for t in REJECTED])
def test_rejected_expressions(text):
    with pytest.raises(ExpressionError):
        compile_expression(text)


@pytest.mark.parametrize(
    "text, reason",
    [
        ("x", "name 'x' is not allowed (use s, pi, e, sin, cos, tan, exp, log, sqrt, abs)"),
        ("s.__class__", "attribute access is not allowed"),
        ("sin(s, s)", "sin() takes exactly one argument"),
        ("s ^ 2", "operator '^' is not allowed (use ** for powers)"),
        ("'a'", "strings are not allowed"),
        ("1" * 1001, "expression is too long (more than 1000 characters)"),
        ("(" * 51 + "s" + ")" * 51, "expression is nested too deeply (more than 50 levels)"),
    ],
)
def test_rejection_reasons_are_short_and_specific(text, reason):
    with pytest.raises(ExpressionError) as info:
        compile_expression(text)
    assert str(info.value) == reason


def test_depth_limit_is_exactly_fifty_levels():
    compile_expression("-" * 49 + "s")  # 49 minus signs + s: 50 levels
    with pytest.raises(ExpressionError):
        compile_expression("-" * 50 + "s")
    compile_expression("(" * 50 + "s" + ")" * 50)


def test_non_string_is_rejected():
    with pytest.raises(ExpressionError):
        compile_expression(1.0)


def test_module_never_calls_eval_or_exec():
    tree = ast.parse(inspect.getsource(expr))
    names = {node.id for node in ast.walk(tree) if isinstance(node, ast.Name)}
    assert not names & {"eval", "exec", "compile", "__import__"}


_ALPHABET = "s pie+-*/().,0123456789sincoatexplgqrb_[]'x^%<=" + "\n\t"


@settings(max_examples=400, deadline=None)
@given(st.one_of(st.text(max_size=60), st.text(alphabet=_ALPHABET, max_size=60)))
def test_arbitrary_text_compiles_or_raises_expression_error(text):
    try:
        f = compile_expression(text)
    except ExpressionError:
        return
    value = f(S)
    assert value.shape == S.shape and value.dtype == float
