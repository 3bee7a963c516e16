"""The design problem of an archive (``analyze``, ``correct``), from the archive alone.

An archive is self-contained: its stored source is parsed again with every file it names replaced by what
the archive stores (the target by ``/target/points``, obstacles by ``/obstacles``; a calibration only
shifts how a design is built, which ``analyze`` and ``correct`` do not need), so no file is opened because
an archive names it, and a moved archive reads the same. The pairing of target points and segments is the
run's own; a run that cannot pair with the archived target is one error line.
"""

from __future__ import annotations

import dataclasses
import math

from vine_nlp.errors import InputError
from vine_nlp.io.problems import parse_problem
from vine_nlp.io.validate import parse_toml
from vine_nlp.problem import DesignOptions, DesignProblem


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
