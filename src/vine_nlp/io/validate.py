"""Validation of values read from input files: every bad value is one InputError ``(file, key, reason)``.

The checks the readers of problem, sweep and data files share (``vine_nlp.io.problems``, ``vine_nlp.io.sweep_file``,
``vine_nlp.io.data_files``): reading and parsing a TOML file, tables and their keys (with a "did you mean" hint for
unknown ones), numbers, arrays, choices, strings and rigid poses. Each takes the :class:`SourceFile` being read (it
names the file in errors) and the dotted key of the value ("tube.diameter")."""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from pathlib import Path

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io import limits
from vine_nlp.io.files import read_text  # noqa: F401  the bounded reader, for the readers importing it from here
from vine_nlp.model.routing import Routing

MAX_INT = 2**31 - 1  # solver options such as max_iter are C ints

POSE_TOL = 1e-6


class SourceFile:
    """The file being read: names it in errors (of type ``error_type``, an InputError) and anchors relative paths."""

    def __init__(self, path: str, error_type: type = InputError):
        self.path = str(path)
        self.dir = Path(self.path).parent
        self.error_type = error_type

    def error(self, key: str, reason: str) -> InputError:
        return self.error_type(self.path, key, reason)


MAX_DEPTH = 32  # tables and arrays inside each other, parts of a dotted key
_DEEP_KEY = re.compile(r"(?<![A-Za-z0-9_.'\"-])(?:(?:[A-Za-z0-9_-]++|\"[^\"\n]*+\"|'[^'\n]*+')[ \t]*+\.[ \t]*+){%d,}" % MAX_DEPTH)


def parse_toml(path: str, source: str) -> dict:
    """The TOML document ``source`` of the file ``path``, checked by :func:`check_document`."""
    deep = _DEEP_KEY.search(source)  # tomllib takes time and memory quadratic in a key's parts
    if deep:
        raise InputError(path, f"line {source.count(chr(10), 0, deep.start()) + 1}", f"a key of more than {MAX_DEPTH} dotted parts")
    try:
        return check_document(path, tomllib.loads(source))
    except ValueError as err:  # TOMLDecodeError, or an integer of more than 4300 digits
        if not isinstance(err, tomllib.TOMLDecodeError):
            digits = re.search(r"[0-9_]{4300}", source)
            line = f"line {source.count(chr(10), 0, digits.start()) + 1}" if digits else "file"
            raise InputError(path, line, "integer out of range (TOML integers are 64-bit)") from None
        message = str(err)
        match = re.search(r"\s*\(at line (\d+), column \d+\)$", message)
        if match:
            line = int(match.group(1))
            message = message[: match.start()]
        else:
            line = source.rstrip().count("\n") + 1  # the last line with text, not the empty one after it
            message = re.sub(r"\s*\(at end of document\)$", "", message)
        raise InputError(path, f"line {line}", f"invalid TOML: {message}") from None
    except RecursionError:
        raise InputError(path, "file", "TOML nested too deeply") from None


def check_document(path: str, doc: dict) -> dict:
    """Refuse, wherever they are in a parsed document, what no key can use: integers beyond 64 bits
    (TOML's own range), keys and strings with control characters (newlines, NUL, ANSI escapes),
    and nesting deeper than MAX_DEPTH (a 30 000-level dotted key). Iterative: no recursion."""
    todo = [(doc, "", 0)]
    while todo:
        node, where, depth = todo.pop()
        if depth > MAX_DEPTH:
            raise InputError(path, where, f"nested more than {MAX_DEPTH} levels deep")
        items = node.items() if isinstance(node, dict) else enumerate(node)
        for k, v in items:
            key = f"{where}.{k}" if where else str(k)
            if isinstance(k, str) and not (k.isprintable() and len(k) <= limits.MAX_NAME_CHARS):
                raise InputError(path, key, f"a key must be printable text of at most {limits.MAX_NAME_CHARS} characters")
            if isinstance(v, (dict, list)):
                todo.append((v, key, depth + 1))
            elif isinstance(v, str) and not v.isprintable():
                raise InputError(path, key, "must be printable text (no newlines or control characters)")
            elif isinstance(v, int) and not isinstance(v, bool) and not -(2**63) <= v < 2**63:
                raise InputError(path, key, "integer out of range (TOML integers are 64-bit)")
    return doc


def sub_table(f: SourceFile, parent: dict, name: str, allowed, required: bool = False, prefix: str = "") -> dict:
    key = prefix + name
    if name not in parent:
        if required:
            raise f.error(key, "missing table")
        return {}
    table = parent[name]
    check(f, key, isinstance(table, dict), "must be a table")
    if allowed is not None:
        check_keys(f, table, key + ".", allowed)
    return table


def check_keys(f: SourceFile, table: dict, prefix: str, allowed) -> None:
    for key in table:
        if key not in allowed:
            raise f.error(f"{prefix}{key}", unknown_key(key, allowed))


def unknown_key(key, allowed) -> str:
    close = difflib.get_close_matches(str(key), list(allowed), n=1)
    return f"unknown key; did you mean '{close[0]}'?" if close else "unknown key"


def required_value(f: SourceFile, table: dict, name: str, prefix: str):
    if name not in table:
        raise f.error(prefix + name, "missing (required)")
    return table[name]


def check(f: SourceFile, key: str, ok: bool, reason: str) -> None:
    if not ok:
        raise f.error(key, reason)


def is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def real_number(f: SourceFile, key: str, value) -> float:
    if not is_number(value):
        raise f.error(key, "must be a number")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise f.error(key, "must be finite")
    return number


def integer(f: SourceFile, key: str, value, least: int, most: int = MAX_INT) -> int:
    # 400.0 is accepted as 400: sweeps and hand-edited files mix the two.
    whole = value.is_integer() if isinstance(value, float) else is_number(value)
    if not whole or value < least:
        raise f.error(key, f"must be an integer >= {least}")
    if value > most:
        raise f.error(key, f"must be an integer <= {most}")
    return int(value)


def real_array(f: SourceFile, key: str, value, count: int | None = None) -> np.ndarray:
    shape = f"a list of {count} numbers" if count else "a list of numbers"
    check(f, key, isinstance(value, list) and (count is None or len(value) == count), f"must be {shape}")
    out = np.empty(len(value))
    for i, x in enumerate(value):
        check(f, key, is_number(x), f"must be {shape}")
        try:
            out[i] = float(x)
        except OverflowError:
            out[i] = math.inf
        check(f, key, math.isfinite(out[i]), f"must be finite (entry {i + 1})")
    return out


def point_list(f: SourceFile, key: str, value) -> np.ndarray:
    reason = "must be a list of at least 2 points [x, y, z] (or [x, y])"
    check(f, key, isinstance(value, list) and len(value) >= 2, reason)
    check(f, key, all(isinstance(p, list) and len(p) in (2, 3) for p in value), reason)
    check(f, key, len({len(p) for p in value}) == 1, "points must all have 3 coordinates (or all 2)")
    return np.array([real_array(f, key, p) for p in value])


def nonempty_text(f: SourceFile, key: str, value, most: int | None = None) -> str:
    """A non-empty string of printable characters (at most ``most`` of them)."""
    check(f, key, isinstance(value, str) and value.strip() != "", "must be a non-empty string")
    check(f, key, value.isprintable(), "must be printable text (no newlines or control characters)")
    check(f, key, most is None or len(value) <= most, f"longer than {most} characters")
    return value


def check_scale(f: SourceFile, key: str, points, diameter: float | None, what: str = "the target") -> None:
    """Coordinates within MAX_COORDINATE and a span (bounding-box diagonal) of MIN_DIAMETERS to
    MAX_DIAMETERS tube diameters (``diameter`` None: coordinates only); beyond them the solvers work at the edge of float64 (a 1e-15 tube
    around a 20 cm target kept Fatrop looping for good, a 1e-300 target gave NaN)."""
    points = np.asarray(points, float)
    big = float(np.abs(points).max())
    if big > limits.MAX_COORDINATE:
        raise f.error(key, f"coordinates up to {big:.4g}: at most {limits.MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE)")
    span = float(np.linalg.norm(np.ptp(points, axis=0)))
    if diameter is None:
        return
    if span > limits.MAX_DIAMETERS * diameter:
        raise f.error("tube.diameter", f"{diameter:.4g} is too thin for {what} spanning {span:.4g}: at most "
                      f"{limits.MAX_DIAMETERS:g} tube diameters (vine_nlp.io.limits.MAX_DIAMETERS)")
    if span < limits.MIN_DIAMETERS * diameter:
        raise f.error(key, f"{what} spans {span:.4g}, less than {limits.MIN_DIAMETERS:g} tube diameters "
                      "(vine_nlp.io.limits.MIN_DIAMETERS)")


def choice(f: SourceFile, key: str, value, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        listed = ", ".join(f"'{c}'" for c in choices)
        close = difflib.get_close_matches(value, list(choices), n=1) if isinstance(value, str) else []
        hint = f"; did you mean '{close[0]}'?" if close else ""
        raise f.error(key, f"must be one of {listed}{hint}")
    return value


def rigid_pose(f: SourceFile, key: str, value) -> np.ndarray:
    """T^0_w: a 4 x 4 rigid transform (rotation with det +1, last row 0 0 0 1); a list of rows or an array."""
    value = np.asarray(value, dtype=object).tolist() if isinstance(value, np.ndarray) else value
    shape_ok = isinstance(value, list) and len(value) == 4
    shape_ok = shape_ok and all(isinstance(row, list) and len(row) == 4 and all(map(is_number, row)) for row in value)
    check(f, key, shape_ok, "must be a 4 x 4 array (4 rows of 4 numbers)")
    pose = np.array([[real_number(f, key, x) for x in row] for row in value])
    rotation = pose[:3, :3]
    check(f, key, np.allclose(pose[3], [0, 0, 0, 1], rtol=0, atol=POSE_TOL), "last row must be [0, 0, 0, 1]")
    check(f, key, np.allclose(rotation.T @ rotation, np.eye(3), rtol=0, atol=POSE_TOL),
          "rotation part (first 3 rows and columns) is not orthonormal")
    check(f, key, abs(np.linalg.det(rotation) - 1) <= POSE_TOL, "rotation part has det -1 (a mirror, not a rotation)")
    return pose


ROUTING_KEYS = {"theta": "theta", "lam": "lam", "length": "length", "initial_pose": "initial_pose"}


def validate_routing(f: SourceFile, theta, lam, length, initial_pose=None, keys: dict = ROUTING_KEYS, segments: int | None = None,
                     diameter: float | None = None) -> Routing:
    """The one check of a routing, wherever it is read (problem files, the Python API, archives): ``theta``
    (rad), ``lam`` and ``length`` are numbers (the same on every segment) or float arrays of one value per
    segment; M is ``segments``, else the size of the first array among length, theta, lam. Every bad value
    is ``f.error(keys[name], reason)`` (``f``: any object with that method; an archive's reader:
    ``SourceFile(file, ArchiveError)`` with ``keys`` the datasets), naming the segment for arrays.
    With ``diameter`` (a routing to run), its forward shape must fit an archive (MAX_SHAPE_POINTS rows)."""
    values = {k: np.asarray(v, dtype=float) for k, v in (("theta", theta), ("lam", lam), ("length", length))}
    for k, v in values.items():
        check(f, keys[k], v.ndim <= 1, f"must be a number or a 1-D array (one value per segment), got shape {v.shape}")
    sizes = [values[k].size for k in ("length", "theta", "lam") if values[k].ndim == 1]
    m = segments if segments is not None else (sizes[0] if sizes else 1)
    first = next((k for k in ("length", "theta", "lam") if values[k].ndim == 1), "length")
    check(f, keys[first], m >= 1, "needs at least one value (one per segment)")
    check(f, keys[first], m <= limits.MAX_SEGMENTS, f"gives more than {limits.MAX_SEGMENTS} segments")
    for k, v in values.items():
        check(f, keys[k], v.ndim == 0 or v.size == m, f"needs {m} values (one per segment), got {v.size}")
        bad = ~np.isfinite(np.atleast_1d(v))
        check(f, keys[k], not bad.any(), "must be finite" if v.ndim == 0 else f"must be finite (segment {int(np.argmax(bad)) + 1})")
    th, la, dl = (np.broadcast_to(values[k], (m,)).copy() for k in ("theta", "lam", "length"))
    for (_, ok, rule, shown, unit), k, v in zip(limits.ROUTING_RULES, ("theta", "lam", "length"), (th, la, dl)):
        good = ok(v)
        if not good.all():
            j = int(np.argmin(good))
            raise f.error(keys[k], rule if values[k].ndim == 0 else f"{rule} (segment {j + 1}: {shown(v[j]):.6g}{unit})")
    check(f, keys["theta"], (why := limits.winding_rule(th, dl)) is None, why)
    if diameter is not None:  # the forward shape: pieces of at most D/4 (model.shape.forward_shape)
        rows = int(np.maximum(1, np.ceil(dl / (0.25 * diameter))).sum()) + 1
        check(f, keys["length"], rows <= limits.MAX_SHAPE_POINTS, f"a tube {float(dl.sum()) / diameter:.4g} diameters long has a "
              f"shape of {rows} points (pieces of D/4); at most {limits.MAX_SHAPE_POINTS}")
    pose = np.eye(4) if initial_pose is None else rigid_pose(f, keys["initial_pose"], initial_pose)
    return Routing(theta=th, lam=la, length=dl, initial_pose=pose)
