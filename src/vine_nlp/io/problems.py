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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vine_nlp.io import actuators as several
from vine_nlp.io import limits, sections
from vine_nlp.io.calibration import calibration_of
from vine_nlp.io.data_files import check_spread, data_points
from vine_nlp.io.loads import load_of
from vine_nlp.io.obstacles import DESIGN_KEYS as OBSTACLE_DESIGN_KEYS
from vine_nlp.io.obstacles import parse_obstacle_design, parse_obstacles
from vine_nlp.io.validate import (
    SourceFile,
    check,
    check_scale,
    choice,
    integer,
    nonempty_text,
    parse_toml,
    read_text,
    real_array,
    real_number,
    required_value,
    rigid_pose,
    sub_table,
    unknown_key,
)
from vine_nlp.model.routing import MEASURED_LINES
from vine_nlp.problem import (
    TIP_OBJECTIVES,
    DesignOptions,
    DesignProblem,
    FitProblem,
    ForwardProblem,
    MultiShapeProblem,
    TipProblem,
)

_TOP_KEYS = {
    "design": ("name", "units", "tube", "target", "actuator", "design", "calibration", "obstacles", "routing", "load"),
    "forward": ("name", "units", "tube", "routing", "load"),
    "fit": ("name", "units", "tube", "measured", "routing", "fit"),
    "multishape": ("name", "units", "tube", "targets", "actuator", "design"),
    "tip": ("name", "units", "tube", "tip", "actuator", "design", "obstacles"),
    "actuators": ("name", "units", "tube", "actuators", "states", "routing", "design"),
}

_ALL_TOP_KEYS = tuple(dict.fromkeys(k for keys in _TOP_KEYS.values() for k in keys))

_ACTUATOR_KEYS = ("kind", "lambda_min", "theta_max_deg")

_ROUTING_KEYS = ("length", "segment_length", *sections._ANGLE_KEYS, "lambda", "initial_pose")

_MEASURED_KEYS = ("file", "line")

_FIT_KEYS = ("free",)

FREE_CHOICES = ("lambda",)

_MULTISHAPE_DESIGN_KEYS = (*sections._OTHER_DESIGN_KEYS, "shared_pose", "correction_margin", "min_feature")  # the levels' band, the pouches

_TIP_DESIGN_KEYS = (*sections._OTHER_DESIGN_KEYS, "correction_margin", "min_feature")  # buildable: its base is [tip] initial_pose

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
        kind, problem = several.parse_actuators(f, data, name, units, diameter)
    elif kind == "design":
        problem = _design(f, data, name, units, diameter)
    elif kind == "forward":
        routing = sections.read_routing(f, sub_table(f, data, "routing", _ROUTING_KEYS, required=True), diameter)
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
    return design_problem(f, data, name, units, diameter, *sections.read_target(f, data, diameter))


def design_problem(f: SourceFile, data: dict, name: str, units: str, diameter: float, points: np.ndarray, points_key: str) -> DesignProblem:
    """A design problem around its checked target ``points``: [actuator], [design], a fixed base's [routing] and
    the optional tables of ``data``, as a problem file has them (the Python API passes its arguments so)."""
    actuator = sections.read_actuator(f, sub_table(f, data, "actuator", _ACTUATOR_KEYS))
    design = sub_table(f, data, "design", (*sections._DESIGN_KEYS, *OBSTACLE_DESIGN_KEYS, *sections._BUILD_KEYS))
    options = sections.design_options(f, data, design, actuator)
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


def _fit(f: SourceFile, data: dict, name: str, units: str, diameter: float) -> FitProblem:
    measured = sub_table(f, data, "measured", _MEASURED_KEYS, required=True)
    points = data_points(f, "measured.file", required_value(f, measured, "file", "measured."), ordered=False)
    line = choice(f, "measured.line", required_value(f, measured, "line", "measured."), MEASURED_LINES)
    routing = sections.read_routing(f, sub_table(f, data, "routing", _ROUTING_KEYS, required=True), diameter)
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
    actuator = sections.read_actuator(f, {**table, "kind": "spam"})
    design = sub_table(f, data, "design", _MULTISHAPE_DESIGN_KEYS)
    shared_pose = design.get("shared_pose", True)
    check(f, "design.shared_pose", isinstance(shared_pose, bool), "must be true or false")
    options = sections.design_options(f, data, design, actuator, skip=("shared_pose",))
    check(f, "design.method", options.method == "nlp", "must be 'nlp' in a multishape problem (the one formulation)")
    options = _starts_default(design, options, "multishape")
    need = options.points_per_segment + 1
    points, levels = [], []
    for k, item in enumerate(items):
        tf = sections.Item(f, f"targets.{k}", "target")
        pts, points_key = sections.read_target(tf, {"target": {key: v for key, v in item.items() if key != "lambda"}}, diameter)
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
    actuator = sections.read_actuator(f, sub_table(f, data, "actuator", _ACTUATOR_KEYS))
    design = sub_table(f, data, "design", (*_TIP_DESIGN_KEYS, *OBSTACLE_DESIGN_KEYS))
    options = sections.design_options(f, data, design, actuator)
    options = _starts_default(design, options, "tip")
    return TipProblem(**_obstacles_of(f, data), name=name, diameter=diameter, position=position, length=length, segments=segments,
                      direction=direction, objective=objective, initial_pose=pose, actuator=actuator, options=options, units=units)


# ---------------------------------------------------------------- routing


@dataclass(frozen=True)
class LoadedProblem:
    """The problem of an archive whose problem type is not rebuilt (multishape, tip, unknown kinds)."""

    name: str
    diameter: float
    units: str
    target: np.ndarray | None = None
