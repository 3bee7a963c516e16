"""The text of a problem made without a file (the Python API, a forward re-run of an archived routing):
TOML that the problem-file reader reads back, archived as ``/problem@source``."""

from __future__ import annotations

import json
import math

import numpy as np

from vine_nlp.io.calibration import KEYS as CALIBRATION_KEYS
from vine_nlp.model.routing import Routing
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, FitProblem, ForwardProblem, MultiShapeProblem, TipProblem

_SOURCE_ARRAY_MAX = 200  # per-segment arrays longer than this stay out of the source text (HDF5 attributes are small)


def toml_value(v) -> str:
    if isinstance(v, str):
        # a JSON string is a TOML basic string, once DEL is escaped (raw non-ASCII: TOML has no surrogate escapes)
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(x) for x in np.asarray(v).tolist()) + "]"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def toml_text(comment: str, top: dict, tables: dict) -> str:
    """TOML text: comment lines, top-level keys, then [tables] (a value None is left out)."""
    lines = [f"# {line}" if line else "#" for line in comment.splitlines()]
    lines += [f"{k} = {toml_value(v)}" for k, v in top.items() if v is not None]
    for name, table in tables.items():
        lines += ["", f"[{name}]"]
        for k, v in table.items():
            if isinstance(v, str) and v.startswith("#"):
                lines.append(v)
            elif v is not None:
                lines.append(f"{k} = {toml_value(v)}")
    return "\n".join(lines) + "\n"


def _actuator_table(a: Actuator) -> dict:
    return {"kind": a.kind, "lambda_min": float(a.lambda_min), "theta_max_deg": round(math.degrees(a.theta_max), 9)}


def _options_table(o: DesignOptions, kind: str = "design") -> dict:
    table = {"method": o.method, "points_per_segment": o.points_per_segment, "starts": o.starts}
    if kind == "design":
        table |= {"hops": o.hops, "budget": o.budget}
        if o.solver != DesignOptions.solver:
            table["solver"] = o.solver
        table |= {"correction_margin": o.correction_margin, "min_feature": o.min_feature, "base": o.base}
    table["seed"] = o.seed
    return table


def _routing_table(r: Routing) -> dict:
    """[routing] of a problem file where it can say the routing exactly (per-segment arrays of up to
    _SOURCE_ARRAY_MAX values), else a pointer to the archive."""
    table = {"length": float(r.length.sum())}
    for key, v, name in (("segment_length", r.length, "length"), ("theta", r.theta, "theta"), ("lambda", r.lam, "lambda")):
        if v.size and np.all(v == v[0]):
            table[key] = float(v[0])
        elif v.size <= _SOURCE_ARRAY_MAX:
            table[key] = v
        else:
            table[f"#{key}"] = f"# {key}: per segment, see /runs/<run>/design/{name}"
    if not np.array_equal(r.initial_pose, np.eye(4)):
        table["initial_pose"] = r.initial_pose
    return table


def problem_source(problem, call: str, notes=()) -> str:
    """The source text of a problem object (the API's, a re-run routing's): a problem file the reader takes
    back where it can say everything, with comment lines for what stays in the archive (``notes``: more)."""
    tables = {"tube": {"diameter": float(problem.diameter)}}
    notes = [f"written by vine_nlp: {call}", *notes]
    if isinstance(problem, DesignProblem):
        notes.append(f"the target: the archive's /target/points ({problem.target.shape[0]} points), not a [target] table")
    if isinstance(problem, (ForwardProblem, FitProblem)):
        tables["routing"] = _routing_table(problem.routing)
    if isinstance(problem, FitProblem):
        tables["measured"] = {"line": problem.line, "#file": "# points: the archive's /measured/points"}
        tables["fit"] = {"free": list(problem.free)}
    if isinstance(problem, TipProblem):
        tables["tip"] = {"position": problem.position, "direction": problem.direction, "length": float(problem.length),
                         "segments": int(problem.segments), "objective": problem.objective, "initial_pose": problem.initial_pose}
    if isinstance(problem, MultiShapeProblem):
        notes.append(f"[[targets]]: {problem.count} targets, the archive's /targets/<k>/points, lambda levels {list(problem.levels)}")
    if hasattr(problem, "actuator"):
        tables["actuator"] = _actuator_table(problem.actuator)
    if hasattr(problem, "options"):
        tables["design"] = _options_table(problem.options, "design" if isinstance(problem, DesignProblem) else "other")
    if isinstance(problem, DesignProblem):
        tables["design.smoothness"] = {"theta": problem.options.smooth_theta, "lambda": problem.options.smooth_lambda}
        if problem.options.base_pose is not None:
            tables["routing"] = {"initial_pose": problem.options.base_pose}
        if problem.calibration is not None:
            tables["calibration"] = {k: getattr(problem.calibration, k) for k in CALIBRATION_KEYS}
    if getattr(problem, "load", None) is not None:  # read back by analyze and correct
        tables["load"] = {k: list(v) if k == "gravity" else v for k, v in vars(problem.load).items()
                          if k != "safety" or any(problem.load.gravity)}
    return toml_text("\n".join(notes), {"name": problem.name, "units": problem.units}, tables)


def call_text(func: str, **shown) -> str:
    return f"vine_nlp.{func}(" + ", ".join(f"{k}={v!r}" for k, v in shown.items()) + ")"
