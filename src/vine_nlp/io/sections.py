"""The readers of the sections several problem kinds share: [actuator], [target], [design] (its options and the
buildable keys) and [routing], with their key tables. Below ``io.problems`` and ``io.actuators``, which both read
their sections with these (an [[actuators]] item or a [[targets]] entry through :class:`Item`, which names the
item's key in errors).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vine_nlp import targets
from vine_nlp.errors import InputError
from vine_nlp.io import limits
from vine_nlp.io.data_files import data_points
from vine_nlp.io.expr import ExpressionError, compile_expression
from vine_nlp.io.validate import (
    SourceFile,
    check,
    check_scale,
    choice,
    integer,
    is_number,
    point_list,
    real_array,
    real_number,
    required_value,
    rigid_pose,
    sub_table,
    unknown_key,
    validate_routing,
)
from vine_nlp.model.routing import Routing
from vine_nlp.problem import ACTUATOR_KINDS, BASES, HESSIANS, METHODS, SOLVERS, Actuator, DesignOptions

# Sec. VI-A: an sPAM contracts to lambda = 0.5 ... 0.7 depending on its construction.
SPAM_LAMBDA_MIN = 0.5

_CURVE_KEYS = {
    "trefoil": ("scale", "t_range", "samples"),
    "bezier": ("control_points", "samples"),
    "polyline": ("control_points", "samples"),
    "helix": ("radius", "pitch", "length", "samples"),
    "points": ("file",),
}

_ALL_TARGET_KEYS = ("curve",) + tuple(dict.fromkeys(k for keys in _CURVE_KEYS.values() for k in keys))

_CURVE_MAIN_KEY = {"trefoil": "scale", "bezier": "control_points", "polyline": "control_points", "helix": "radius"}

_OPTION_INTS = {"points_per_segment": 1, "lookahead": 1, "starts": 1, "hops": 0, "greedy_starts": 1, "seed": 0, "max_iter": 1}

_DESIGN_KEYS = ("method", *_OPTION_INTS, "tol", "hessian", "solver", "budget", "smoothness")

# buildable designs (design problems only): [design] keys; a fixed base's pose is [routing] initial_pose
_BUILD_KEYS = ("correction_margin", "min_feature", "base")

_SMOOTHNESS_FIELDS = {"theta": "smooth_theta", "lambda": "smooth_lambda"}

_ANGLE_KEYS = ("theta", "theta_deg", "phi")

# basin hopping (hops) and the corner search (budget) are strategies of the design NLP only
_OTHER_DESIGN_KEYS = tuple(k for k in _DESIGN_KEYS if k not in ("hops", "budget"))


class Item(SourceFile):
    """Errors of a shared reader ("target.x", "routing.theta", "actuator.kind") renamed to the item's key: ``prefix``
    for ``borrowed`` (only the last parts in ``only``, if given), e.g. "targets.2.x" for [[targets]]' third."""

    def __init__(self, f: SourceFile, prefix: str, borrowed: str, only=None):
        super().__init__(f.path)
        self.prefix, self.borrowed, self.only = prefix, borrowed, only

    def error(self, key: str, reason: str) -> InputError:
        if (key == self.borrowed or key.startswith(self.borrowed + ".")) and (self.only is None or key.split(".")[-1] in self.only):
            key = self.prefix + key[len(self.borrowed):]
        return super().error(key, reason)


def read_actuator(f: SourceFile, table: dict) -> Actuator:
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


def read_target(f: SourceFile, data: dict, diameter: float) -> tuple[np.ndarray, str]:
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


def read_options(f: SourceFile, table: dict) -> DesignOptions:
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


def design_options(f: SourceFile, data: dict, design: dict, actuator: Actuator, skip=()) -> DesignOptions:
    """[design]'s options (``read_options``; without the keys ``skip`` and the buildable keys), then its buildable keys."""
    return build_options(f, data, design, actuator, read_options(f, {k: v for k, v in design.items() if k not in (*skip, *_BUILD_KEYS)}))


def build_options(f: SourceFile, data: dict, table: dict, actuator: Actuator, options: DesignOptions) -> DesignOptions:
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


def read_routing(f: SourceFile, table: dict, diameter: float) -> Routing:
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
        phi = np.broadcast_to(per_point(f, angle_key, table["phi"], ends, "one per segment end"), ends.shape)
        with np.errstate(all="ignore"):
            theta = np.arctan((diameter / 2) * np.diff(phi) / lengths)
    else:
        theta = per_point(f, angle_key, table[given[0]], starts, "one per segment")
        theta = np.radians(theta) if given[0] == "theta_deg" else theta
    lam = per_point(f, "routing.lambda", required_value(f, table, "lambda", "routing."), starts, "one per segment")
    keys = {"theta": angle_key, "lam": "routing.lambda", "length": "routing.segment_length", "initial_pose": "routing.initial_pose"}
    return validate_routing(f, theta, lam, lengths, table.get("initial_pose"), keys, segments=lengths.size, diameter=diameter)


def per_point(f: SourceFile, key: str, value, s: np.ndarray, what: str) -> np.ndarray:
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
