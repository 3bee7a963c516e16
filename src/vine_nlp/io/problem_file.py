"""Problem, sweep and fit files (spec/formats.md) read into the typed problems of ``vine_nlp.design.problem``.

Every bad input raises :class:`vine_nlp.errors.InputError` ``(file, key, reason)``
with the dotted key of the offending value ("tube.diameter", "routing.theta"), or
"line N" for TOML syntax errors and lines of CSV data files, or "values" for a data
file's content as a whole. Paths inside a file are relative to that file's directory.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vine_nlp import targets
from vine_nlp.design.problem import (  # further formulations: multi-shape sPAM and tip targets
    ACTUATOR_KINDS,
    HESSIANS,
    MEASURED_LINES,
    METHODS,
    TIP_OBJECTIVES,
    Actuator,
    DesignOptions,
    DesignProblem,
    FitProblem,
    ForwardProblem,
    MultiShapeProblem,
    Routing,
    TipProblem,
)
from vine_nlp.errors import InputError
from vine_nlp.io.expr import ExpressionError, compile_expression

# Guards against inputs that would exhaust memory long before they are useful.
MAX_SAMPLES = 100_000
MAX_SEGMENTS = 100_000
MAX_SWEEP_ITEMS = 100_000
MAX_INT = 2**31 - 1  # solver options such as max_iter are C ints

# Sec. VI-A: an sPAM contracts to lambda = 0.5 ... 0.7 depending on its construction.
SPAM_LAMBDA_MIN = 0.5
POSE_TOL = 1e-6

_TOP_KEYS = {
    "design": ("name", "units", "tube", "target", "actuator", "design"),
    "forward": ("name", "units", "tube", "routing"),
    "fit": ("name", "units", "tube", "measured", "routing", "fit"),
    "multishape": ("name", "units", "tube", "targets", "actuator", "design"),
    "tip": ("name", "units", "tube", "tip", "actuator", "design"),
}
_ALL_TOP_KEYS = tuple(dict.fromkeys(k for keys in _TOP_KEYS.values() for k in keys))
_CURVE_KEYS = {
    "trefoil": ("scale", "t_range", "samples"),
    "bezier": ("control_points", "samples"),
    "polyline": ("control_points", "samples"),
    "helix": ("radius", "pitch", "length", "samples"),
    "points": ("file",),
}
_ALL_TARGET_KEYS = ("curve",) + tuple(dict.fromkeys(k for keys in _CURVE_KEYS.values() for k in keys))
_CURVE_MAIN_KEY = {"trefoil": "scale", "bezier": "control_points", "polyline": "control_points", "helix": "radius"}
_ACTUATOR_KEYS = ("kind", "lambda_min", "theta_max_deg")
_OPTION_INTS = {"points_per_segment": 1, "lookahead": 1, "starts": 1, "hops": 0, "greedy_starts": 1, "seed": 0, "max_iter": 1}
_DESIGN_KEYS = ("method", *_OPTION_INTS, "tol", "hessian", "smoothness")
_SMOOTHNESS_FIELDS = {"theta": "smooth_theta", "lambda": "smooth_lambda"}
_ANGLE_KEYS = ("theta", "theta_deg", "phi")
_ROUTING_KEYS = ("length", "segment_length", *_ANGLE_KEYS, "lambda", "initial_pose")
_MEASURED_KEYS = ("file", "line")
_FIT_KEYS = ("free",)
_FREE_CHOICES = ("lambda",)
_SWEEP_KEYS = ("name", "base", "methods", "grid")
# basin hopping (hops) is a strategy of the design NLP only
_OTHER_DESIGN_KEYS = tuple(k for k in _DESIGN_KEYS if k != "hops")
_MULTISHAPE_DESIGN_KEYS = (*_OTHER_DESIGN_KEYS, "shared_pose")
_TIP_KEYS = ("position", "direction", "length", "segments", "objective", "initial_pose")
MAX_LEVELS = 1000  # [[targets]] of a multishape problem
MAX_TIP_SEGMENTS = 10_000
# Multi-shape and tip problems are multimodal: without [design] starts, a few starts (the
# geometric guesses and seeded perturbations) are the default.
DEFAULT_STARTS = {"multishape": 4, "tip": 4}
_SWEEP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")


@dataclass
class ProblemFile:
    path: str
    source: str  # the file's text, stored in result archives
    kind: str  # "design" | "forward" | "fit" | "multishape" ([[targets]]) | "tip" ([tip])
    name: str
    units: str
    problem: DesignProblem | ForwardProblem | FitProblem | MultiShapeProblem | TipProblem


@dataclass
class Sweep:
    path: str
    source: str
    name: str
    base_path: str
    base_data: dict
    methods: list[str]
    grid: dict[str, list]  # dotted key -> values, in file order
    base_source: str = ""
    _items: list | None = field(default=None, repr=False, compare=False)

    def items(self) -> list[tuple[str, dict, ProblemFile]]:
        """(item name, {dotted key: value}, problem) for the cartesian product of the grid, in grid order.

        Item names are ``<sweep name>-<index:04d>``; each item's problem is named after it.
        """
        if self._items is None:
            self._items = _expand(self)
        return list(self._items)


# ---------------------------------------------------------------- entry points


def load_problem(path) -> ProblemFile:
    """Read and validate a design, forward or fit problem file."""
    path = str(path)
    source = _read_text(path, path, "file")
    return parse_problem(_parse_toml(path, source), path, source)


def parse_problem(data: dict, path: str, source: str) -> ProblemFile:
    """Validate an already parsed problem (a TOML document as a dict); ``path`` names it in errors."""
    f = _File(path)
    if not isinstance(data, dict):
        raise f.error("file", "must be a TOML table")
    kind = _kind(f, data)
    for key in data:
        if key not in _TOP_KEYS[kind]:
            if key in _ALL_TOP_KEYS:
                raise f.error(key, f"not used in a {kind} problem")
            raise f.error(key, _unknown(key, _TOP_KEYS[kind]))
    name = _text(f, "name", data.get("name", Path(path).stem))
    units = _text(f, "units", data.get("units", "cm"))
    tube = _table(f, data, "tube", ("diameter",), required=True)
    diameter = _real(f, "tube.diameter", _required(f, tube, "diameter", "tube."))
    _check(f, "tube.diameter", diameter > 0, "must be > 0")

    if kind == "design":
        problem = _design(f, data, name, units, diameter)
    elif kind == "forward":
        routing = _routing(f, _table(f, data, "routing", _ROUTING_KEYS, required=True), diameter)
        problem = ForwardProblem(name=name, diameter=diameter, routing=routing, units=units)
    elif kind == "multishape":
        problem = _multishape(f, data, name, units, diameter)
    elif kind == "tip":
        problem = _tip(f, data, name, units, diameter)
    else:
        problem = _fit(f, data, name, units, diameter)
    return ProblemFile(path=path, source=source, kind=kind, name=name, units=units, problem=problem)


def load_sweep(path) -> Sweep:
    """Read a sweep file and validate its base problem and every item."""
    path = str(path)
    f = _File(path)
    source = _read_text(path, path, "file")
    data = _parse_toml(path, source)
    _check_keys(f, data, "", _SWEEP_KEYS)
    name = data.get("name", re.sub(r"[^A-Za-z0-9._+-]", "_", Path(path).stem).lstrip(".") or "sweep")
    name = _text(f, "name", name)
    _check(f, "name", _SWEEP_NAME.fullmatch(name) is not None, "must be a plain file name (letters, digits, . _ + -)")

    base = _text(f, "base", _required(f, data, "base", ""))
    base_path = str(f.dir / base)
    base_source = _read_text(base_path, path, "base")
    base_data = _parse_toml(base_path, base_source)
    if parse_problem(base_data, base_path, base_source).kind != "design":
        raise f.error("base", "must be a design problem file (one with [target])")

    methods = data.get("methods", ["nlp"])
    _check(f, "methods", isinstance(methods, list) and len(methods) > 0, "must be a non-empty list of methods")
    for m in methods:
        _choice(f, "methods", m, METHODS)
    _check(f, "methods", len(set(methods)) == len(methods), "lists a method twice")

    grid_table = data.get("grid", {})
    _check(f, "grid", isinstance(grid_table, dict), "must be a table")
    grid = _flatten(grid_table)
    size = 1
    for key, values in grid.items():
        if not (isinstance(values, list) and values):
            raise f.error(f"grid.{key}", "must be a non-empty list of values")
        size *= len(values)
    _check(f, "grid", size <= MAX_SWEEP_ITEMS, f"has {size} items; at most {MAX_SWEEP_ITEMS}")

    sweep = Sweep(path, source, name, base_path, base_data, list(methods), grid, base_source)
    sweep.items()  # bad items are bad input: fail now, before any work is done
    return sweep


def apply_override(data: dict, dotted_key: str, value, file: str = "<sweep>") -> dict:
    """A deep copy of ``data`` with the value at ``dotted_key`` replaced ("target.scale.0" = element 0).

    Missing tables are created (a sweep may set a key the base leaves at its default);
    an index needs an existing array and must be in range. Bad paths raise
    ``InputError(file, dotted_key, ...)``.
    """
    data = copy.deepcopy(data)
    _set(data, dotted_key, value, file)
    return data


# ---------------------------------------------------------------- problems


class _File:
    """The file being read: names it in errors and anchors relative paths."""

    def __init__(self, path: str):
        self.path = str(path)
        self.dir = Path(self.path).parent

    def error(self, key: str, reason: str) -> InputError:
        return InputError(self.path, key, reason)


def _kind(f: _File, data: dict) -> str:
    if "target" in data and "measured" in data:
        raise f.error("target", "a problem has [target] (design) or [measured] (fit), not both")
    if "targets" in data or "tip" in data:
        return _further_kind(f, data)
    if "target" in data:
        return "design"
    if "measured" in data:
        return "fit"
    if "routing" in data:
        return "forward"
    raise f.error("target", "missing: a problem needs [target] (design), [routing] (forward) or [measured] (fit)")


def _design(f: _File, data: dict, name: str, units: str, diameter: float) -> DesignProblem:
    points, points_key = _target(f, data)
    actuator = _actuator(f, _table(f, data, "actuator", _ACTUATOR_KEYS))
    options = _options(f, _table(f, data, "design", _DESIGN_KEYS))
    need = options.points_per_segment + 1
    _check(
        f,
        points_key,
        points.shape[0] >= need,
        f"needs at least points_per_segment + 1 = {need} points, got {points.shape[0]}",
    )
    return DesignProblem(name=name, diameter=diameter, target=points, actuator=actuator, options=options, units=units)


def _target(f: _File, data: dict) -> tuple[np.ndarray, str]:
    """The sampled target curve and the key to blame when there are too few points."""
    table = _table(f, data, "target", None, required=True)
    for key in table:
        if key not in _ALL_TARGET_KEYS:
            raise f.error(f"target.{key}", _unknown(key, _ALL_TARGET_KEYS))
    curve = _choice(f, "target.curve", _required(f, table, "curve", "target."), tuple(_CURVE_KEYS))
    for key in table:
        if key != "curve" and key not in _CURVE_KEYS[curve]:
            raise f.error(f"target.{key}", f"not used by curve '{curve}'")

    if curve == "points":
        points = _data_points(f, "target.file", _required(f, table, "file", "target."), ordered=True)
        return points, "target.file"

    kwargs = {}
    if "samples" in table:
        kwargs["samples"] = _integer(f, "target.samples", table["samples"], 3, MAX_SAMPLES)
    if curve == "trefoil":
        if "scale" in table:
            kwargs["scale"] = _reals(f, "target.scale", table["scale"], 3)
        if "t_range" in table:
            t_range = _reals(f, "target.t_range", table["t_range"], 2)
            _check(f, "target.t_range", t_range[0] < t_range[1], "must be [start, end] with start < end")
            kwargs["t_range"] = t_range
    elif curve in ("bezier", "polyline"):
        kwargs["control_points"] = _point_list(
            f, "target.control_points", _required(f, table, "control_points", "target.")
        )
    else:  # helix
        for key in ("radius", "pitch", "length"):
            kwargs[key] = _real(f, f"target.{key}", _required(f, table, key, "target."))
        _check(f, "target.radius", kwargs["radius"] >= 0, "must be >= 0")
        _check(f, "target.length", kwargs["length"] > 0, "must be > 0")
        _check(f, "target.radius", kwargs["radius"] > 0 or kwargs["pitch"] != 0, "radius and pitch cannot both be 0")

    try:
        with np.errstate(all="ignore"):  # extreme inputs give non-finite points, reported below
            points = targets.check_points(getattr(targets, curve)(**kwargs))
    except ValueError as err:
        raise f.error(f"target.{_CURVE_MAIN_KEY[curve]}", str(err)) from None
    return points, "target.samples"


def _actuator(f: _File, table: dict) -> Actuator:
    kind = _choice(f, "actuator.kind", table.get("kind", Actuator.kind), ACTUATOR_KINDS)
    lambda_min = table.get("lambda_min", SPAM_LAMBDA_MIN if kind == "spam" else Actuator.lambda_min)
    lambda_min = _real(f, "actuator.lambda_min", lambda_min)
    _check(f, "actuator.lambda_min", 0 < lambda_min <= 1, "must be in (0, 1]")
    theta_max = Actuator.theta_max
    if "theta_max_deg" in table:
        theta_max_deg = _real(f, "actuator.theta_max_deg", table["theta_max_deg"])
        _check(f, "actuator.theta_max_deg", 0 < theta_max_deg < 90, "must be in (0, 90)")
        theta_max = math.radians(theta_max_deg)
    return Actuator(kind=kind, lambda_min=lambda_min, theta_max=theta_max)


def _options(f: _File, table: dict) -> DesignOptions:
    changes = {}
    if "method" in table:
        changes["method"] = _choice(f, "design.method", table["method"], METHODS)
    for key, least in _OPTION_INTS.items():
        if key in table:
            changes[key] = _integer(f, f"design.{key}", table[key], least)
    if "tol" in table:
        changes["tol"] = _real(f, "design.tol", table["tol"])
        _check(f, "design.tol", changes["tol"] > 0, "must be > 0")
    if "hessian" in table:
        changes["hessian"] = _choice(f, "design.hessian", table["hessian"], HESSIANS)
    smoothness = _table(f, table, "smoothness", tuple(_SMOOTHNESS_FIELDS), prefix="design.")
    for key, field_name in _SMOOTHNESS_FIELDS.items():
        if key in smoothness:
            weight = _real(f, f"design.smoothness.{key}", smoothness[key])
            _check(f, f"design.smoothness.{key}", weight >= 0, "must be >= 0")
            changes[field_name] = weight
    return dataclasses.replace(DesignOptions(), **changes)


def _fit(f: _File, data: dict, name: str, units: str, diameter: float) -> FitProblem:
    measured = _table(f, data, "measured", _MEASURED_KEYS, required=True)
    points = _data_points(f, "measured.file", _required(f, measured, "file", "measured."), ordered=False)
    line = _choice(f, "measured.line", _required(f, measured, "line", "measured."), MEASURED_LINES)
    routing = _routing(f, _table(f, data, "routing", _ROUTING_KEYS, required=True), diameter)
    free = _table(f, data, "fit", _FIT_KEYS).get("free", [])
    _check(f, "fit.free", isinstance(free, list), "must be a list: [] or [\"lambda\"]")
    for item in free:
        _choice(f, "fit.free", item, _FREE_CHOICES)
    _check(f, "fit.free", len(set(free)) == len(free), "lists a parameter twice")
    return FitProblem(
        name=name, diameter=diameter, measured=points, line=line, routing=routing, free=tuple(free), units=units
    )


# ---------------------------------------------------------------- multi-shape and tip problems


def _further_kind(f: _File, data: dict) -> str:
    """[[targets]] (multishape) or [tip] (tip): each excludes the other kind-deciding tables."""
    kind, table = ("multishape", "targets") if "targets" in data else ("tip", "tip")
    for other in ("target", "targets", "tip", "measured", "routing"):
        if other != table and other in data:
            has = "[[targets]] (multishape)" if table == "targets" else "[tip] (tip)"
            raise f.error(other, f"not used in a {kind} problem: a problem with {has} has no [{other}]")
    return kind


class _TargetFile(_File):
    """Reads target ``k`` of [[targets]] with ``_target``: its "target.<key>" errors become "targets.<k>.<key>"."""

    def __init__(self, f: _File, k: int):
        super().__init__(f.path)
        self.k = k

    def error(self, key: str, reason: str) -> InputError:
        if key == "target" or key.startswith("target."):
            key = f"targets.{self.k}" + key[len("target") :]
        return super().error(key, reason)


def _starts_default(table: dict, options: DesignOptions, kind: str) -> DesignOptions:
    if "starts" in table:
        return options
    return dataclasses.replace(options, starts=DEFAULT_STARTS[kind])


def _multishape(f: _File, data: dict, name: str, units: str, diameter: float) -> MultiShapeProblem:
    """[[targets]]: K targets (same number of points), each optionally with a fixed lambda; an sPAM actuator."""
    items = data["targets"]
    _check(
        f,
        "targets",
        isinstance(items, list) and len(items) > 0 and all(isinstance(t, dict) for t in items),
        "must be an array of tables ([[targets]]), at least one",
    )
    _check(f, "targets", len(items) <= MAX_LEVELS, f"has {len(items)} targets; at most {MAX_LEVELS}")
    table = _table(f, data, "actuator", _ACTUATOR_KEYS)
    if "kind" in table and table["kind"] != "spam":
        raise f.error("actuator.kind", "must be 'spam' in a multishape problem (one lambda per pressure level)")
    actuator = _actuator(f, {**table, "kind": "spam"})
    design = _table(f, data, "design", _MULTISHAPE_DESIGN_KEYS)
    shared_pose = design.get("shared_pose", True)
    _check(f, "design.shared_pose", isinstance(shared_pose, bool), "must be true or false")
    options = _options(f, {k: v for k, v in design.items() if k != "shared_pose"})
    _check(f, "design.method", options.method == "nlp", "must be 'nlp' in a multishape problem (the one formulation)")
    options = _starts_default(design, options, "multishape")
    need = options.points_per_segment + 1
    points, levels = [], []
    for k, item in enumerate(items):
        tf = _TargetFile(f, k)
        pts, points_key = _target(tf, {"target": {key: v for key, v in item.items() if key != "lambda"}})
        _check(tf, points_key, pts.shape[0] >= need, f"needs at least points_per_segment + 1 = {need} points, got {pts.shape[0]}")
        if k > 0 and pts.shape[0] != points[0].shape[0]:
            raise tf.error(
                points_key, f"has {pts.shape[0]} points; every target needs as many as targets.0 ({points[0].shape[0]})"
            )
        level = None
        if "lambda" in item:
            level = _real(f, f"targets.{k}.lambda", item["lambda"])
            _check(
                f,
                f"targets.{k}.lambda",
                actuator.lambda_min <= level <= 1,
                f"must be in [actuator.lambda_min, 1] = [{actuator.lambda_min:g}, 1]",
            )
        points.append(pts)
        levels.append(level)
    return MultiShapeProblem(
        name=name,
        diameter=diameter,
        targets=tuple(points),
        levels=tuple(levels),
        actuator=actuator,
        options=options,
        shared_pose=shared_pose,
        units=units,
    )


def _tip(f: _File, data: dict, name: str, units: str, diameter: float) -> TipProblem:
    """[tip]: position, optional direction, tube length, segments, objective, optional fixed base pose."""
    table = _table(f, data, "tip", _TIP_KEYS, required=True)
    position = _reals(f, "tip.position", _required(f, table, "position", "tip."), 3)
    direction = None
    if "direction" in table:
        direction = _reals(f, "tip.direction", table["direction"], 3)
        norm = float(np.linalg.norm(direction))
        _check(f, "tip.direction", math.isfinite(norm) and norm > 0, "must be a nonzero vector")
        direction = direction / norm
    length = _real(f, "tip.length", _required(f, table, "length", "tip."))
    _check(f, "tip.length", length > 0, "must be > 0")
    segments = _integer(f, "tip.segments", table.get("segments", 10), 1, MAX_TIP_SEGMENTS)
    objective = _choice(f, "tip.objective", table.get("objective", "contraction"), TIP_OBJECTIVES)
    pose = _pose(f, "tip.initial_pose", table["initial_pose"]) if "initial_pose" in table else np.eye(4)
    actuator = _actuator(f, _table(f, data, "actuator", _ACTUATOR_KEYS))
    design = _table(f, data, "design", _OTHER_DESIGN_KEYS)
    options = _starts_default(design, _options(f, design), "tip")
    return TipProblem(
        name=name,
        diameter=diameter,
        position=position,
        length=length,
        segments=segments,
        direction=direction,
        objective=objective,
        initial_pose=pose,
        actuator=actuator,
        options=options,
        units=units,
    )

# ---------------------------------------------------------------- routing


def _routing(f: _File, table: dict, diameter: float) -> Routing:
    """Segments of a given routing (paper Sec. IV-B): per-segment theta, lambda and length."""
    total = _real(f, "routing.length", _required(f, table, "length", "routing."))
    _check(f, "routing.length", total > 0, "must be > 0")
    step = _real(f, "routing.segment_length", _required(f, table, "segment_length", "routing."))
    _check(f, "routing.segment_length", step > 0, "must be > 0")
    _check(f, "routing.segment_length", step <= total, "must be <= routing.length")
    ratio = total / step
    _check(f, "routing.segment_length", ratio <= MAX_SEGMENTS, f"gives more than {MAX_SEGMENTS} segments")
    # The 1e-9 keeps round-off in length/segment_length from adding a sliver of a last segment.
    m = math.ceil(ratio - 1e-9)
    ends = np.minimum(step * np.arange(m + 1), total)
    ends[-1] = total
    lengths = np.diff(ends)
    starts = ends[:-1]

    given = [key for key in _ANGLE_KEYS if key in table]
    if not given:
        raise f.error("routing.theta", "missing (give one of theta, theta_deg, phi)")
    if len(given) > 1:
        raise f.error(f"routing.{given[1]}", f"conflicts with routing.{given[0]} (give only one of theta, theta_deg, phi)")
    angle_key = f"routing.{given[0]}"
    value = table[given[0]]
    if given[0] == "phi":
        # Inverse of eq. (phi(s_j)): phi_{j+1} - phi_j = (2/D) tan(theta_j) dl_j.
        phi = _per_point(f, angle_key, value, ends, "one per segment end")
        with np.errstate(all="ignore"):
            theta = np.arctan((diameter / 2) * np.diff(phi) / lengths)
    else:
        theta = _per_point(f, angle_key, value, starts, "one per segment")
        if given[0] == "theta_deg":
            theta = np.radians(theta)
    _check_each(f, angle_key, value, np.abs(theta) < math.pi / 2, np.degrees(theta), "|theta| must be < 90 deg", " deg")

    lam_value = _required(f, table, "lambda", "routing.")
    lam = _per_point(f, "routing.lambda", lam_value, starts, "one per segment")
    _check_each(f, "routing.lambda", lam_value, (lam > 0) & (lam <= 1), lam, "must be in (0, 1]", "")

    pose = np.eye(4)
    if "initial_pose" in table:
        pose = _pose(f, "routing.initial_pose", table["initial_pose"])
    return Routing(theta=theta, lam=lam, length=lengths, initial_pose=pose)


def _per_point(f: _File, key: str, value, s: np.ndarray, what: str) -> np.ndarray:
    """A number, an array with one value per s, or an expression of s evaluated at s."""
    if isinstance(value, str):
        try:
            values = compile_expression(value)(s)
        except ExpressionError as err:
            raise f.error(key, str(err)) from None
        bad = ~np.isfinite(values)
        if bad.any():
            raise f.error(key, f"expression is not finite at s = {s[np.argmax(bad)]:g}")
        return values
    if isinstance(value, list):
        values = _reals(f, key, value)
        _check(f, key, values.size == s.size, f"needs {s.size} values ({what}), got {values.size}")
        return values
    if not _is_number(value):
        raise f.error(key, "must be a number, an array or an expression of s")
    return np.full(s.size, _real(f, key, value))


def _check_each(f: _File, key: str, given, ok: np.ndarray, shown: np.ndarray, rule: str, unit: str) -> None:
    if ok.all():
        return
    if _is_number(given):
        raise f.error(key, rule)
    j = int(np.argmin(ok))
    raise f.error(key, f"{rule} (segment {j + 1}: {shown[j]:.6g}{unit})")


def _pose(f: _File, key: str, value) -> np.ndarray:
    """T^0_w: a 4 x 4 rigid transform (rotation with det +1, last row 0 0 0 1)."""
    shape_ok = isinstance(value, list) and len(value) == 4
    shape_ok = shape_ok and all(isinstance(row, list) and len(row) == 4 and all(map(_is_number, row)) for row in value)
    _check(f, key, shape_ok, "must be a 4 x 4 array (4 rows of 4 numbers)")
    pose = np.array([[_real(f, key, x) for x in row] for row in value])
    rotation = pose[:3, :3]
    _check(f, key, np.allclose(pose[3], [0, 0, 0, 1], rtol=0, atol=POSE_TOL), "last row must be [0, 0, 0, 1]")
    _check(
        f,
        key,
        np.allclose(rotation.T @ rotation, np.eye(3), rtol=0, atol=POSE_TOL),
        "rotation part (first 3 rows and columns) is not orthonormal",
    )
    _check(f, key, abs(np.linalg.det(rotation) - 1) <= POSE_TOL, "rotation part has det -1 (a mirror, not a rotation)")
    return pose


# ---------------------------------------------------------------- data files


def read_points(path, ordered: bool = False) -> np.ndarray:
    """Points of a .csv or .npy data file given on the command line (e.g. ``fit --frames``).

    Bad files raise InputError naming the data file, exactly as when a problem file names them.
    """
    path = Path(path)
    f = _File(str(path))
    if not path.is_file():
        raise f.error("--frames", "no such file")
    return _data_points(_File(str(path.parent / path.name)), "--frames", path.name, ordered)


def _data_points(f: _File, key: str, value, ordered: bool) -> np.ndarray:
    """Points of a .csv or .npy file named by ``key``; ordered points must also pass targets.check_points."""
    name = _text(f, key, value)
    path = f.dir / name
    if path.suffix.lower() not in (".csv", ".npy"):
        raise f.error(key, f"unsupported file type '{path.suffix}' (use .csv or .npy)")
    if not path.is_file():
        raise f.error(key, f"no such file: {path}")
    data_file = _File(str(path))
    points = _read_npy(data_file) if path.suffix.lower() == ".npy" else _read_csv(data_file)
    if ordered:
        try:
            return targets.check_points(points)
        except ValueError as err:
            raise data_file.error("values", str(err)) from None
    # Measured points come in any order, so repeats are fine; the fit needs a few of them.
    _check(data_file, "values", points.shape[0] >= 3, f"needs at least 3 points, got {points.shape[0]}")
    return np.column_stack([points, np.zeros(points.shape[0])]) if points.shape[1] == 2 else points


def _read_csv(f: _File) -> np.ndarray:
    """Rows of x y z (or x y), separated by commas or whitespace; one header line and # comments allowed."""
    try:
        text = Path(f.path).read_text(encoding="utf-8-sig")  # -sig: spreadsheets write a BOM
    except UnicodeDecodeError:
        raise f.error("values", "not a UTF-8 text file") from None
    except OSError as err:
        raise f.error("values", f"cannot read the file ({err.strerror})") from None
    rows: list[list[float]] = []
    header_seen = False
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = re.split(r"\s*,\s*|\s+", line)
        values = [_float_or_none(x) for x in fields]
        if not rows and not header_seen and all(v is None for v in values):
            header_seen = True
            continue
        where = f"line {number}"
        for text_value, v in zip(fields, values):
            if v is None:
                raise f.error(where, f"'{text_value[:40]}' is not a number")
            if not math.isfinite(v):
                raise f.error(where, f"'{text_value[:40]}' is not finite")
        columns = len(rows[0]) if rows else None
        if columns is None and len(values) not in (2, 3):
            raise f.error(where, f"expected 3 values (x y z) or 2 (x y), got {len(values)}")
        if columns is not None and len(values) != columns:
            raise f.error(where, f"expected {columns} values like the first row, got {len(values)}")
        rows.append(values)
    if not rows:
        raise f.error("values", "no data rows")
    return np.array(rows, dtype=float)


def _read_npy(f: _File) -> np.ndarray:
    try:
        array = np.load(f.path, allow_pickle=False)  # never unpickle user files
    except (OSError, ValueError, EOFError, MemoryError):
        raise f.error("values", "not a readable .npy array file") from None
    if not isinstance(array, np.ndarray) or not (
        np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)
    ):
        raise f.error("values", "must hold an array of real numbers")
    if array.ndim != 2 or array.shape[1] not in (2, 3) or array.shape[0] == 0:
        raise f.error("values", f"must be an N x 3 (or N x 2) array, got shape {array.shape}")
    array = array.astype(float)
    finite = np.all(np.isfinite(array), axis=1)
    if not finite.all():
        raise f.error("values", f"row {int(np.argmin(finite)) + 1} is not finite")
    return array


def _float_or_none(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


# ---------------------------------------------------------------- sweeps


def _expand(sweep: Sweep) -> list[tuple[str, dict, ProblemFile]]:
    keys = list(sweep.grid)
    items = []
    for index, combo in enumerate(itertools.product(*(sweep.grid[k] for k in keys))):
        item = f"{sweep.name}-{index:04d}"
        overrides = dict(zip(keys, combo))
        data = copy.deepcopy(sweep.base_data)
        for key, value in overrides.items():
            _set(data, key, value, sweep.path)
        data["name"] = item
        described = ", ".join(f"{k} = {v!r}" for k, v in overrides.items()) or "the base problem"
        # The archive stores the source; the note makes the item reproducible from it.
        source = sweep.base_source.rstrip("\n") + f"\n\n# sweep '{sweep.name}' item {item}: {described}\n"
        try:
            problem = parse_problem(data, sweep.base_path, source)
        except InputError as err:
            if err.file != sweep.base_path:
                raise  # a data file's own error
            raise InputError(sweep.path, err.key, f"{err.reason} (item {item}: {described})") from None
        items.append((item, overrides, problem))
    return items


def _set(data: dict, dotted_key: str, value, file: str) -> None:
    def fail(reason):
        return InputError(file, dotted_key, reason)

    if not isinstance(dotted_key, str) or not all(dotted_key.split(".")):
        raise fail("not a dotted key like target.scale.0")
    parts = dotted_key.split(".")
    node = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[: depth + 1])
        if isinstance(node, dict):
            if last:
                node[part] = value
            elif part not in node:
                if parts[depth + 1].isdigit():
                    raise fail(f"'{where}' is not in the base problem; an index needs an existing array")
                node[part] = {}
            node = node[part]
        elif isinstance(node, list):
            if not part.isdigit():
                raise fail(f"'{'.'.join(parts[:depth])}' is an array; '{part}' is not an index")
            i = int(part)
            if i >= len(node):
                raise fail(f"index {i} is out of range ('{'.'.join(parts[:depth])}' has {len(node)} elements)")
            if last:
                node[i] = value
            node = node[i]
        else:
            raise fail(f"'{'.'.join(parts[:depth])}' is a value, not a table or array")


def _flatten(table: dict, prefix: str = "") -> dict:
    # [grid] target.scale.0 = [...] (bare dotted key) arrives as nested tables.
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


# ---------------------------------------------------------------- readers of single values


def _read_text(path: str, named_by: str, key: str) -> str:
    """The text of a TOML file; errors name the file and key that referred to it."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        reason = "no such file" if named_by == path else f"no such file: {path}"
    except IsADirectoryError:
        reason = "is a directory" if named_by == path else f"is a directory: {path}"
    except UnicodeDecodeError:
        raise InputError(path, "file", "not a UTF-8 text file") from None
    except OSError as err:
        reason = f"cannot read {path} ({err.strerror})"
    raise InputError(named_by, key, reason)


def _parse_toml(path: str, source: str) -> dict:
    try:
        return tomllib.loads(source)
    except tomllib.TOMLDecodeError as err:
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


def _table(f: _File, parent: dict, name: str, allowed, required: bool = False, prefix: str = "") -> dict:
    key = prefix + name
    if name not in parent:
        if required:
            raise f.error(key, "missing table")
        return {}
    table = parent[name]
    _check(f, key, isinstance(table, dict), "must be a table")
    if allowed is not None:
        _check_keys(f, table, key + ".", allowed)
    return table


def _check_keys(f: _File, table: dict, prefix: str, allowed) -> None:
    for key in table:
        if key not in allowed:
            raise f.error(f"{prefix}{key}", _unknown(key, allowed))


def _unknown(key, allowed) -> str:
    close = difflib.get_close_matches(str(key), list(allowed), n=1)
    return f"unknown key; did you mean '{close[0]}'?" if close else "unknown key"


def _required(f: _File, table: dict, name: str, prefix: str):
    if name not in table:
        raise f.error(prefix + name, "missing (required)")
    return table[name]


def _check(f: _File, key: str, ok: bool, reason: str) -> None:
    if not ok:
        raise f.error(key, reason)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _real(f: _File, key: str, value) -> float:
    if not _is_number(value):
        raise f.error(key, "must be a number")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise f.error(key, "must be finite")
    return number


def _integer(f: _File, key: str, value, least: int, most: int = MAX_INT) -> int:
    # 400.0 is accepted as 400: sweeps and hand-edited files mix the two.
    whole = value.is_integer() if isinstance(value, float) else _is_number(value)
    if not whole or value < least:
        raise f.error(key, f"must be an integer >= {least}")
    if value > most:
        raise f.error(key, f"must be an integer <= {most}")
    return int(value)


def _reals(f: _File, key: str, value, count: int | None = None) -> np.ndarray:
    shape = f"a list of {count} numbers" if count else "a list of numbers"
    _check(f, key, isinstance(value, list) and (count is None or len(value) == count), f"must be {shape}")
    out = np.empty(len(value))
    for i, x in enumerate(value):
        _check(f, key, _is_number(x), f"must be {shape}")
        try:
            out[i] = float(x)
        except OverflowError:
            out[i] = math.inf
        _check(f, key, math.isfinite(out[i]), f"must be finite (entry {i + 1})")
    return out


def _point_list(f: _File, key: str, value) -> np.ndarray:
    reason = "must be a list of at least 2 points [x, y, z] (or [x, y])"
    _check(f, key, isinstance(value, list) and len(value) >= 2, reason)
    _check(f, key, all(isinstance(p, list) and len(p) in (2, 3) for p in value), reason)
    _check(f, key, len({len(p) for p in value}) == 1, "points must all have 3 coordinates (or all 2)")
    return np.array([_reals(f, key, p) for p in value])


def _text(f: _File, key: str, value) -> str:
    _check(f, key, isinstance(value, str) and value.strip() != "", "must be a non-empty string")
    return value


def _choice(f: _File, key: str, value, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        listed = ", ".join(f"'{c}'" for c in choices)
        close = difflib.get_close_matches(value, list(choices), n=1) if isinstance(value, str) else []
        hint = f"; did you mean '{close[0]}'?" if close else ""
        raise f.error(key, f"must be one of {listed}{hint}")
    return value
