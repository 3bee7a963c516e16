"""Problem files (spec/formats.md) read into the typed problems of ``vine_nlp.problem``.

One problem kind per file, decided by its tables: [target] design, [routing] forward,
[measured] fit, [[targets]] multishape (one sPAM routing, K shapes), [tip] tip. Every
bad input raises :class:`vine_nlp.errors.InputError` ``(file, key, reason)`` with the
dotted key of the offending value ("tube.diameter", "routing.theta"), or "line N" for
TOML syntax errors. Paths inside a file are relative to that file's directory.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vine_nlp import targets
from vine_nlp.errors import InputError
from vine_nlp.io import actuators as several
from vine_nlp.io import limits
from vine_nlp.io.calibration import calibration_of
from vine_nlp.io.data_files import check_spread, data_points
from vine_nlp.io.expr import ExpressionError, compile_expression
from vine_nlp.io.loads import load_of
from vine_nlp.io.obstacles import DESIGN_KEYS as OBSTACLE_DESIGN_KEYS
from vine_nlp.io.obstacles import parse_obstacle_design, parse_obstacles
from vine_nlp.io.validate import (
    SourceFile,
    check,
    check_scale,
    choice,
    integer,
    is_number,
    nonempty_text,
    parse_toml,
    point_list,
    read_text,
    real_array,
    real_number,
    required_value,
    rigid_pose,
    sub_table,
    unknown_key,
    validate_routing,
)
from vine_nlp.model.routing import MEASURED_LINES, Routing
from vine_nlp.problem import (
    ACTUATOR_KINDS,
    BASES,
    HESSIANS,
    METHODS,
    SOLVERS,
    TIP_OBJECTIVES,
    Actuator,
    DesignOptions,
    DesignProblem,
    FitProblem,
    ForwardProblem,
    MultiShapeProblem,
    TipProblem,
)

# Sec. VI-A: an sPAM contracts to lambda = 0.5 ... 0.7 depending on its construction.
SPAM_LAMBDA_MIN = 0.5


_TOP_KEYS = {
    "design": ("name", "units", "tube", "target", "actuator", "design", "calibration", "obstacles", "routing", "load"),
    "forward": ("name", "units", "tube", "routing", "load"),
    "fit": ("name", "units", "tube", "measured", "routing", "fit"),
    "multishape": ("name", "units", "tube", "targets", "actuator", "design"),
    "tip": ("name", "units", "tube", "tip", "actuator", "design", "obstacles"),
    "actuators": ("name", "units", "tube", "actuators", "states", "routing", "design"),
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

_DESIGN_KEYS = ("method", *_OPTION_INTS, "tol", "hessian", "solver", "budget", "smoothness")

# buildable designs (design problems only): [design] keys; a fixed base's pose is [routing] initial_pose
_BUILD_KEYS = ("correction_margin", "min_feature", "base")

_SMOOTHNESS_FIELDS = {"theta": "smooth_theta", "lambda": "smooth_lambda"}

_ANGLE_KEYS = ("theta", "theta_deg", "phi")

_ROUTING_KEYS = ("length", "segment_length", *_ANGLE_KEYS, "lambda", "initial_pose")

_MEASURED_KEYS = ("file", "line")

_FIT_KEYS = ("free",)

FREE_CHOICES = ("lambda",)

# basin hopping (hops) and the corner search (budget) are strategies of the design NLP only
_OTHER_DESIGN_KEYS = tuple(k for k in _DESIGN_KEYS if k not in ("hops", "budget"))

_MULTISHAPE_DESIGN_KEYS = (*_OTHER_DESIGN_KEYS, "shared_pose", "correction_margin", "min_feature")  # the levels' band, the pouches

_TIP_DESIGN_KEYS = (*_OTHER_DESIGN_KEYS, "correction_margin", "min_feature")  # buildable: its base is [tip] initial_pose

_TIP_KEYS = ("position", "direction", "length", "segments", "objective", "initial_pose")

MAX_TIP_SEGMENTS = 10_000

# Multi-shape and tip problems are multimodal: without [design] starts, a few starts (the
# geometric guesses and seeded perturbations) are the default.
DEFAULT_STARTS = {"multishape": 4, "tip": 4}


@dataclass
class ProblemFile:
    path: str
    source: str  # the file's text, stored in result archives
    kind: str  # "design" | "forward" | "fit" | "multishape" ([[targets]]) | "tip" ([tip])
    name: str
    units: str
    problem: DesignProblem | ForwardProblem | FitProblem | MultiShapeProblem | TipProblem


# ---------------------------------------------------------------- entry points


def load_problem(path) -> ProblemFile:
    """Read and validate a design, forward or fit problem file."""
    path = str(path)
    source = read_text(path, path, "file")
    return parse_problem(parse_toml(path, source), path, source)


def parse_problem(data: dict, path: str, source: str) -> ProblemFile:
    """Validate an already parsed problem (a TOML document as a dict); ``path`` names it in errors."""
    f = SourceFile(path)
    if not isinstance(data, dict):
        raise f.error("file", "must be a TOML table")
    kind = _kind(f, data)
    for key in data:
        if key not in _TOP_KEYS[kind]:
            if key in _ALL_TOP_KEYS:
                raise f.error(key, f"not used in a {kind} problem")
            raise f.error(key, unknown_key(key, _TOP_KEYS[kind]))
    name = nonempty_text(f, "name", data.get("name", Path(path).stem), limits.MAX_NAME_CHARS)
    units = nonempty_text(f, "units", data.get("units", "cm"), limits.MAX_UNITS_CHARS)
    tube = sub_table(f, data, "tube", ("diameter",), required=True)
    diameter = real_number(f, "tube.diameter", required_value(f, tube, "diameter", "tube."))
    check(f, "tube.diameter", diameter > 0, "must be > 0")
    check(f, "tube.diameter", diameter <= limits.MAX_COORDINATE, f"must be <= {limits.MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE)")

    if kind == "actuators":
        kind, problem = several.parse_actuators(f, data, name, units, diameter, sys.modules[__name__])
    elif kind == "design":
        problem = _design(f, data, name, units, diameter)
    elif kind == "forward":
        routing = _routing(f, sub_table(f, data, "routing", _ROUTING_KEYS, required=True), diameter)
        problem = ForwardProblem(name=name, diameter=diameter, routing=routing, units=units, load=load_of(f, data, units))
    elif kind == "multishape":
        problem = _multishape(f, data, name, units, diameter)
    elif kind == "tip":
        problem = _tip(f, data, name, units, diameter)
    else:
        problem = _fit(f, data, name, units, diameter)
    return ProblemFile(path=path, source=source, kind=kind, name=name, units=units, problem=problem)


# ---------------------------------------------------------------- problems


def _kind(f: SourceFile, data: dict) -> str:
    if "actuators" in data or "states" in data:  # several actuators on one tube (io.actuators)
        return "actuators"
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


def _design(f: SourceFile, data: dict, name: str, units: str, diameter: float) -> DesignProblem:
    return design_problem(f, data, name, units, diameter, *_target(f, data, diameter))


def design_problem(f: SourceFile, data: dict, name: str, units: str, diameter: float, points: np.ndarray, points_key: str) -> DesignProblem:
    """A design problem around its checked target ``points``: [actuator], [design], a fixed base's [routing] and
    the optional tables of ``data``, as a problem file has them (the Python API passes its arguments so)."""
    actuator = _actuator(f, sub_table(f, data, "actuator", _ACTUATOR_KEYS))
    design = sub_table(f, data, "design", (*_DESIGN_KEYS, *OBSTACLE_DESIGN_KEYS, *_BUILD_KEYS))
    options = _build_options(f, data, design, actuator, _options(f, {k: v for k, v in design.items() if k not in _BUILD_KEYS}))
    need = options.points_per_segment + 1
    check(f, points_key, points.shape[0] >= need, f"needs at least points_per_segment + 1 = {need} points, got {points.shape[0]}")
    problem = DesignProblem(name=name, diameter=diameter, target=points, actuator=actuator, options=options, units=units)
    return _design_tables(f, data, problem)


def _design_tables(f: SourceFile, data: dict, problem: DesignProblem) -> DesignProblem:
    """The optional tables of a design problem beyond [target], [actuator] and [design]: each read by its own
    module of ``vine_nlp.io`` (its key listed in ``_TOP_KEYS["design"]``) and applied with ``dataclasses.replace``."""
    cal = calibration_of(f, data)
    if cal is not None:
        problem = dataclasses.replace(problem, calibration=cal)
    return dataclasses.replace(problem, load=load_of(f, data, problem.units), **_obstacles_of(f, data))


def _obstacles_of(f: SourceFile, data: dict) -> dict:
    """[[obstacles]] and [design] obstacle_margin, growth (vine_nlp.io.obstacles) as problem fields."""
    design = data.get("design", {})
    margin, growth = parse_obstacle_design(design if isinstance(design, dict) else {}, f.path)
    obstacles = tuple(parse_obstacles(data["obstacles"], f.path, f.dir)) if "obstacles" in data else ()
    return {"obstacles": obstacles, "obstacle_margin": margin, "growth": growth}


def _build_options(f: SourceFile, data: dict, table: dict, actuator: Actuator, options: DesignOptions) -> DesignOptions:
    """[design] correction_margin, min_feature, base, and a fixed base's [routing] initial_pose. Without
    correction_margin, the default shrinks to leave room: min(default, (1 - lambda_min) / 2)."""
    margin = min(options.correction_margin, (1 - actuator.lambda_min) / 2)
    if "correction_margin" in table:
        margin = real_number(f, "design.correction_margin", table["correction_margin"])
        check(f, "design.correction_margin", margin >= 0, "must be >= 0")
        low, high = actuator.lambda_min + margin, 1 - margin
        check(f, "design.correction_margin", low <= high, f"leaves no room: actuator.lambda_min + margin = {low:g} > 1 - margin = {high:g}")
    changes = {"correction_margin": margin}
    if "min_feature" in table:
        changes["min_feature"] = real_number(f, "design.min_feature", table["min_feature"])
        check(f, "design.min_feature", changes["min_feature"] >= 0, "must be >= 0")
    base = changes["base"] = choice(f, "design.base", table.get("base", "free"), BASES)
    routing = sub_table(f, data, "routing", ("initial_pose",))
    if "initial_pose" in routing:
        check(f, "routing.initial_pose", base == "fixed", 'a design problem\'s base pose needs [design] base = "fixed"')
        changes["base_pose"] = tuple(map(tuple, rigid_pose(f, "routing.initial_pose", routing["initial_pose"]).tolist()))
    check(f, "design.base", base == "free" or "base_pose" in changes, '"fixed" needs a base pose: give [routing] initial_pose (4 x 4)')
    return dataclasses.replace(options, **changes)


def _target(f: SourceFile, data: dict, diameter: float) -> tuple[np.ndarray, str]:
    """The sampled target curve and the key to blame when there are too few points."""
    table = sub_table(f, data, "target", None, required=True)
    for key in table:
        if key not in _ALL_TARGET_KEYS:
            raise f.error(f"target.{key}", unknown_key(key, _ALL_TARGET_KEYS))
    curve = choice(f, "target.curve", required_value(f, table, "curve", "target."), tuple(_CURVE_KEYS))
    for key in table:
        if key != "curve" and key not in _CURVE_KEYS[curve]:
            raise f.error(f"target.{key}", f"not used by curve '{curve}'")

    if curve == "points":
        points = data_points(f, "target.file", required_value(f, table, "file", "target."), ordered=True)
        check_scale(f, "target.file", points, diameter)
        return points, "target.file"

    kwargs = {}
    if "samples" in table:
        kwargs["samples"] = integer(f, "target.samples", table["samples"], 3, limits.MAX_TARGET_POINTS)
    if curve == "trefoil":
        if "scale" in table:
            kwargs["scale"] = real_array(f, "target.scale", table["scale"], 3)
        if "t_range" in table:
            t_range = real_array(f, "target.t_range", table["t_range"], 2)
            check(f, "target.t_range", t_range[0] < t_range[1], "must be [start, end] with start < end")
            kwargs["t_range"] = t_range
    elif curve in ("bezier", "polyline"):
        kwargs["control_points"] = point_list(f, "target.control_points", required_value(f, table, "control_points", "target."))
    else:  # helix
        for key in ("radius", "pitch", "length"):
            kwargs[key] = real_number(f, f"target.{key}", required_value(f, table, key, "target."))
        check(f, "target.radius", kwargs["radius"] >= 0, "must be >= 0")
        check(f, "target.length", kwargs["length"] > 0, "must be > 0")
        check(f, "target.radius", kwargs["radius"] > 0 or kwargs["pitch"] != 0, "radius and pitch cannot both be 0")

    try:
        with np.errstate(all="ignore"):  # extreme inputs give non-finite points, reported below
            points = targets.check_points(getattr(targets, curve)(**kwargs))
    except ValueError as err:
        raise f.error(f"target.{_CURVE_MAIN_KEY[curve]}", str(err)) from None
    check_scale(f, f"target.{_CURVE_MAIN_KEY[curve]}", points, diameter)
    return points, "target.samples"


def _actuator(f: SourceFile, table: dict) -> Actuator:
    kind = choice(f, "actuator.kind", table.get("kind", Actuator.kind), ACTUATOR_KINDS)
    lambda_min = table.get("lambda_min", SPAM_LAMBDA_MIN if kind == "spam" else Actuator.lambda_min)
    lambda_min = real_number(f, "actuator.lambda_min", lambda_min)
    check(f, "actuator.lambda_min", 0 < lambda_min <= 1, "must be in (0, 1]")
    theta_max = Actuator.theta_max
    if "theta_max_deg" in table:
        theta_max_deg = real_number(f, "actuator.theta_max_deg", table["theta_max_deg"])
        check(f, "actuator.theta_max_deg", 0 < theta_max_deg < 90, "must be in (0, 90)")
        theta_max = math.radians(theta_max_deg)
    return Actuator(kind=kind, lambda_min=lambda_min, theta_max=theta_max)


def _options(f: SourceFile, table: dict) -> DesignOptions:
    changes = {}
    if "method" in table:
        changes["method"] = choice(f, "design.method", table["method"], METHODS)
    for key, least in _OPTION_INTS.items():
        if key in table:
            changes[key] = integer(f, f"design.{key}", table[key], least)
    if "tol" in table:
        changes["tol"] = real_number(f, "design.tol", table["tol"])
        check(f, "design.tol", changes["tol"] > 0, "must be > 0")
    if "hessian" in table:
        changes["hessian"] = choice(f, "design.hessian", table["hessian"], HESSIANS)
    if "solver" in table:
        changes["solver"] = choice(f, "design.solver", table["solver"], SOLVERS)
    if "budget" in table:
        changes["budget"] = real_number(f, "design.budget", table["budget"])
        check(f, "design.budget", changes["budget"] >= 0, "must be >= 0")
    smoothness = sub_table(f, table, "smoothness", tuple(_SMOOTHNESS_FIELDS), prefix="design.")
    for key, field_name in _SMOOTHNESS_FIELDS.items():
        if key in smoothness:
            weight = real_number(f, f"design.smoothness.{key}", smoothness[key])
            check(f, f"design.smoothness.{key}", weight >= 0, "must be >= 0")
            changes[field_name] = weight
    return dataclasses.replace(DesignOptions(), **changes)


def _fit(f: SourceFile, data: dict, name: str, units: str, diameter: float) -> FitProblem:
    measured = sub_table(f, data, "measured", _MEASURED_KEYS, required=True)
    points = data_points(f, "measured.file", required_value(f, measured, "file", "measured."), ordered=False)
    line = choice(f, "measured.line", required_value(f, measured, "line", "measured."), MEASURED_LINES)
    routing = _routing(f, sub_table(f, data, "routing", _ROUTING_KEYS, required=True), diameter)
    free = sub_table(f, data, "fit", _FIT_KEYS).get("free", [])
    check(f, "fit.free", isinstance(free, list), "must be a list: [] or [\"lambda\"]")
    for item in free:
        choice(f, "fit.free", item, FREE_CHOICES)
    check(f, "fit.free", len(set(free)) == len(free), "lists a parameter twice")
    check_spread(str(f.dir / measured["file"]), points, diameter, 3)
    check_scale(f, "measured.file", points, diameter, "the measurement")
    return FitProblem(name=name, diameter=diameter, measured=points, line=line, routing=routing, free=tuple(free), units=units)


# ---------------------------------------------------------------- multi-shape and tip problems


def _further_kind(f: SourceFile, data: dict) -> str:
    """[[targets]] (multishape) or [tip] (tip): each excludes the other kind-deciding tables."""
    kind, table = ("multishape", "targets") if "targets" in data else ("tip", "tip")
    for other in ("target", "targets", "tip", "measured", "routing"):
        if other != table and other in data:
            has = "[[targets]] (multishape)" if table == "targets" else "[tip] (tip)"
            raise f.error(other, f"not used in a {kind} problem: a problem with {has} has no [{other}]")
    return kind


class _TargetFile(SourceFile):
    """Reads target ``k`` of [[targets]] with ``_target``: its "target.<key>" errors become "targets.<k>.<key>"."""

    def __init__(self, f: SourceFile, k: int):
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


def _multishape(f: SourceFile, data: dict, name: str, units: str, diameter: float) -> MultiShapeProblem:
    """[[targets]]: K targets (same number of points), each optionally with a fixed lambda; an sPAM actuator."""
    items = data["targets"]
    check(f, "targets", isinstance(items, list) and len(items) > 0 and all(isinstance(t, dict) for t in items),
          "must be an array of tables ([[targets]]), at least one")
    check(f, "targets", len(items) <= limits.MAX_LEVELS, f"has {len(items)} targets; at most {limits.MAX_LEVELS}")
    table = sub_table(f, data, "actuator", _ACTUATOR_KEYS)
    if "kind" in table and table["kind"] != "spam":
        raise f.error("actuator.kind", "must be 'spam' in a multishape problem (one lambda per pressure level)")
    actuator = _actuator(f, {**table, "kind": "spam"})
    design = sub_table(f, data, "design", _MULTISHAPE_DESIGN_KEYS)
    shared_pose = design.get("shared_pose", True)
    check(f, "design.shared_pose", isinstance(shared_pose, bool), "must be true or false")
    options = _options(f, {k: v for k, v in design.items() if k not in ("shared_pose", *_BUILD_KEYS)})
    options = _build_options(f, data, design, actuator, options)
    check(f, "design.method", options.method == "nlp", "must be 'nlp' in a multishape problem (the one formulation)")
    options = _starts_default(design, options, "multishape")
    need = options.points_per_segment + 1
    points, levels = [], []
    for k, item in enumerate(items):
        tf = _TargetFile(f, k)
        pts, points_key = _target(tf, {"target": {key: v for key, v in item.items() if key != "lambda"}}, diameter)
        check(tf, points_key, pts.shape[0] >= need, f"needs at least points_per_segment + 1 = {need} points, got {pts.shape[0]}")
        if k > 0 and pts.shape[0] != points[0].shape[0]:
            raise tf.error(points_key, f"has {pts.shape[0]} points; every target needs as many as targets.0 ({points[0].shape[0]})")
        level = None
        if "lambda" in item:
            level = real_number(f, f"targets.{k}.lambda", item["lambda"])
            check(f, f"targets.{k}.lambda", actuator.lambda_min <= level <= 1,
                  f"must be in [actuator.lambda_min, 1] = [{actuator.lambda_min:g}, 1]")
        points.append(pts)
        levels.append(level)
    return MultiShapeProblem(name=name, diameter=diameter, targets=tuple(points), levels=tuple(levels), actuator=actuator,
                             options=options, shared_pose=shared_pose, units=units)


def _tip(f: SourceFile, data: dict, name: str, units: str, diameter: float) -> TipProblem:
    """[tip]: position, optional direction, tube length, segments, objective, optional fixed base pose."""
    table = sub_table(f, data, "tip", _TIP_KEYS, required=True)
    position = real_array(f, "tip.position", required_value(f, table, "position", "tip."), 3)
    direction = None
    if "direction" in table:
        direction = real_array(f, "tip.direction", table["direction"], 3)
        norm = float(np.linalg.norm(direction))
        check(f, "tip.direction", math.isfinite(norm) and norm > 0, "must be a nonzero vector")
        direction = direction / norm
    length = real_number(f, "tip.length", required_value(f, table, "length", "tip."))
    check(f, "tip.length", length > 0, "must be > 0")
    check_scale(f, "tip.length", [[0.0, 0.0, 0.0], [length, 0.0, 0.0]], diameter, "the tube")
    check_scale(f, "tip.position", [position], None)
    segments = integer(f, "tip.segments", table.get("segments", 10), 1, MAX_TIP_SEGMENTS)
    objective = choice(f, "tip.objective", table.get("objective", "contraction"), TIP_OBJECTIVES)
    pose = rigid_pose(f, "tip.initial_pose", table["initial_pose"]) if "initial_pose" in table else np.eye(4)
    actuator = _actuator(f, sub_table(f, data, "actuator", _ACTUATOR_KEYS))
    design = sub_table(f, data, "design", (*_TIP_DESIGN_KEYS, *OBSTACLE_DESIGN_KEYS))
    options = _build_options(f, data, design, actuator, _options(f, {k: v for k, v in design.items() if k not in _BUILD_KEYS}))
    options = _starts_default(design, options, "tip")
    return TipProblem(**_obstacles_of(f, data), name=name, diameter=diameter, position=position, length=length, segments=segments,
                      direction=direction, objective=objective, initial_pose=pose, actuator=actuator, options=options, units=units)


# ---------------------------------------------------------------- routing


def _routing(f: SourceFile, table: dict, diameter: float) -> Routing:
    """Segments of a given routing (paper Sec. IV-B): per-segment theta, lambda and length. ``segment_length`` is
    one number (equal segments up to ``length``, the last one shorter) or one length per segment (``length``,
    if given, their sum)."""
    step = required_value(f, table, "segment_length", "routing.")
    if isinstance(step, list):
        check(f, "routing.segment_length", 0 < len(step) <= limits.MAX_SEGMENTS, f"needs 1 to {limits.MAX_SEGMENTS} values (one per segment)")
        lengths = real_array(f, "routing.segment_length", step)
        j = int(np.argmin(lengths))
        check(f, "routing.segment_length", lengths[j] > 0, f"must be > 0 (segment {j + 1}: {lengths[j]:.6g})")
        total = float(lengths.sum())
        if "length" in table:
            given = real_number(f, "routing.length", table["length"])
            check(f, "routing.length", abs(given - total) <= 1e-9 * total, f"must be the sum of routing.segment_length ({total:.12g}), got {given:.12g}")
    else:
        total = real_number(f, "routing.length", required_value(f, table, "length", "routing."))
        check(f, "routing.length", total > 0, "must be > 0")
        step = real_number(f, "routing.segment_length", step)
        check(f, "routing.segment_length", step > 0, "must be > 0")
        check(f, "routing.segment_length", step <= total, "must be <= routing.length")
        check(f, "routing.segment_length", total / step <= limits.MAX_SEGMENTS, f"gives more than {limits.MAX_SEGMENTS} segments")
        # The 1e-9 keeps round-off in length/segment_length from adding a sliver of a last segment.
        ends = np.minimum(step * np.arange(math.ceil(total / step - 1e-9) + 1), total)
        ends[-1] = total
        lengths = np.diff(ends)
    check_scale(f, "routing.length", [[0.0, 0.0, 0.0], [total, 0.0, 0.0]], diameter, "the routing")
    ends = np.concatenate([[0.0], np.cumsum(lengths)])
    starts = ends[:-1]
    given = [key for key in _ANGLE_KEYS if key in table]
    if not given:
        raise f.error("routing.theta", "missing (give one of theta, theta_deg, phi)")
    if len(given) > 1:
        raise f.error(f"routing.{given[1]}", f"conflicts with routing.{given[0]} (give only one of theta, theta_deg, phi)")
    angle_key = f"routing.{given[0]}"
    if given[0] == "phi":
        # Inverse of eq. (phi(s_j)): phi_{j+1} - phi_j = (2/D) tan(theta_j) dl_j.
        phi = np.broadcast_to(_per_point(f, angle_key, table["phi"], ends, "one per segment end"), ends.shape)
        with np.errstate(all="ignore"):
            theta = np.arctan((diameter / 2) * np.diff(phi) / lengths)
    else:
        theta = _per_point(f, angle_key, table[given[0]], starts, "one per segment")
        theta = np.radians(theta) if given[0] == "theta_deg" else theta
    lam = _per_point(f, "routing.lambda", required_value(f, table, "lambda", "routing."), starts, "one per segment")
    keys = {"theta": angle_key, "lam": "routing.lambda", "length": "routing.segment_length", "initial_pose": "routing.initial_pose"}
    return validate_routing(f, theta, lam, lengths, table.get("initial_pose"), keys, segments=lengths.size, diameter=diameter)


def _per_point(f: SourceFile, key: str, value, s: np.ndarray, what: str) -> np.ndarray:
    """A number (a 0-d array), an array with one value per s, or an expression of s evaluated at s."""
    if isinstance(value, str):
        try:
            values = compile_expression(value)(s)
        except ExpressionError as err:
            raise f.error(key, str(err)) from None
        bad = ~np.isfinite(values)
        if bad.any():
            raise f.error(key, f"expression is not finite at s = {s[np.argmax(bad)]:g}")
        return np.broadcast_to(values, s.shape)
    if isinstance(value, list):
        values = real_array(f, key, value)
        check(f, key, values.size == s.size, f"needs {s.size} values ({what}), got {values.size}")
        return values
    if not is_number(value):
        raise f.error(key, "must be a number, an array or an expression of s")
    return np.array(real_number(f, key, value))


@dataclass(frozen=True)
class LoadedProblem:
    """The problem of an archive whose problem type is not rebuilt (multishape, tip, unknown kinds)."""

    name: str
    diameter: float
    units: str
    target: np.ndarray | None = None
