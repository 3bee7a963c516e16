"""The design problem of an archive (``analyze``, ``correct``), from the archive alone.

An archive is self-contained: its stored source is parsed again with every file it names replaced by what
the archive stores (the target by ``/target/points``, obstacles by ``/obstacles``; a calibration only
shifts how a design is built, which ``analyze`` and ``correct`` do not need), so no file is opened because
an archive names it, and a moved archive reads the same. The pairing of target points and segments is the
run's own; a run that cannot pair with the archived target is one error line."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io.problems import LoadedProblem, parse_problem
from vine_nlp.io.validate import parse_toml
from vine_nlp.methods.actuators import ActuatorsProblem, Line
from vine_nlp.model.routing import MEASURED_LINES
from vine_nlp.problem import DesignOptions, DesignProblem, FitProblem, ForwardProblem


def archived_problem(archive, path, run: str) -> DesignProblem:
    """The archive's design problem with ``run``'s pairing (module docstring); InputError naming the run
    when its segments cannot pair with the archived target."""
    N, M = archive.target.shape[0], archive.runs[run].routing.segments
    problem = None
    try:
        data = parse_toml(str(path), archive.source)
        if isinstance(data, dict) and "target" in data:
            data = {k: v for k, v in data.items() if k not in ("obstacles", "calibration")}
            data["target"] = {"curve": "polyline", "control_points": archive.target.tolist(), "samples": N}
            problem = parse_problem(data, str(path), archive.source).problem
    except InputError:
        pass
    if not isinstance(problem, DesignProblem):
        problem = DesignProblem(archive.name, archive.diameter, archive.target, units=archive.units)
    n = problem.options.points_per_segment
    if math.ceil((N - 1) / n) != M:
        n = max(1, math.ceil((N - 1) / M))
        if math.ceil((N - 1) / n) != M:
            raise InputError(str(path), f"/runs/{run}/design/theta",
                             f"{M} segments cannot pair with the {N} points of /target/points (ceil((N - 1) / n) segments for no n)")
    options = dataclasses.replace(problem.options, points_per_segment=n) if isinstance(problem.options, DesignOptions) else problem.options
    return dataclasses.replace(problem, target=archive.target, obstacles=tuple(archive.obstacles), options=options, calibration=None)


def problem_of_archive(archive, runs: dict, path):
    """A problem object for a read archive: what the archive holds of it (solver settings stay in ``source``); no file
    is opened because the archive names it (a design problem: :func:`archived_problem`)."""
    first = next(iter(runs.values()), None)
    if archive.kind == "design" and archive.target is not None and first is not None:
        return archived_problem(archive, path, next(iter(runs)))
    if archive.kind == "forward" and first is not None:
        return ForwardProblem(archive.name, archive.diameter, first.routing, units=archive.units)
    if archive.kind == "fit" and first is not None and "measured/points" in archive.extra:
        line = first.stats.get("line")
        return FitProblem(archive.name, archive.diameter, np.asarray(archive.extra["measured/points"]),
                          line if line in MEASURED_LINES else "outer", first.routing, units=archive.units)
    return LoadedProblem(name=archive.name, diameter=archive.diameter, units=archive.units, target=archive.target)


def archived_actuators(archive, path, run) -> ActuatorsProblem:
    """The problem of an archive of several actuators (``run``: an ActuatorsResult of it, its lines and states): the
    stored source parsed with every state's target the archived ``/targets/<state>/points`` (module docstring); the
    actuators' defaults where the source does not parse. InputError naming a state without an archived target."""
    states = {s: tuple(v) for s, v in run.stats["states"].items()}
    targets = {s: np.asarray(archive.extra[f"targets/{s}/points"], float) for s in states if f"targets/{s}/points" in archive.extra}
    if len(targets) < len(states):
        raise InputError(str(path), f"/targets/{next(s for s in states if s not in targets)}/points", "missing: correct needs every state's target")
    problem = None
    try:
        data = parse_toml(str(path), archive.source)
        for item in data.get("states", []):
            if isinstance(item, dict) and item.get("name") in targets:
                t = targets[item["name"]]
                item["target"] = {"curve": "polyline", "control_points": t.tolist(), "samples": len(t)}
        problem = parse_problem({k: v for k, v in data.items() if k != "calibration"}, str(path), archive.source).problem
    except (InputError, AttributeError, TypeError):
        pass
    if not isinstance(problem, ActuatorsProblem) or problem.names != run.lines.names:
        problem = ActuatorsProblem(archive.name, archive.diameter, tuple(Line(n) for n in run.lines.names), states)
    return dataclasses.replace(problem, states=states, targets=targets, units=archive.units)
