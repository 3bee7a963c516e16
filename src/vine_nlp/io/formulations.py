"""Archives of the formulations with layouts of their own (multi-shape, tip): the contract's standard
layout (every reader works) plus their extensions (README, "Extensions made here")."""

from __future__ import annotations

import numpy as np

from vine_nlp.io.archive import Archive, load_archive, write_archive
from vine_nlp.io.h5read import open_archive
from vine_nlp.methods.multishape import RUN as MULTISHAPE_RUN
from vine_nlp.methods.multishape import MultiShapeResult
from vine_nlp.methods.tip import RUN as TIP_RUN
from vine_nlp.model.shape import Shape
from vine_nlp.problem import Result

RUN = MULTISHAPE_RUN


def write_multishape_archive(path, problem_file, result: MultiShapeResult) -> None:
    """Write a multi-shape design archive atomically (the contract's layout, extended).

    Standard part (old readers work): /problem (kind "multishape"), /tube, /target/points = target 0,
    /runs/multishape/{design,shape,metrics,solver} with design/lambda = level 0 repeated and shape = level 0's shape;
    metrics rmse and max_error are over all levels. Extension: /runs/multishape/design/levels (K,),
    /runs/multishape/levels/<k>/{shape/{center,inner,outer}, initial_pose} with attrs lambda, fixed and metrics attrs
    (rmse, max_error), /targets/<k>/points. ``problem_file`` is a ProblemFile (name, source, units, problem) of a
    MultiShapeProblem."""
    problem = problem_file.problem
    archive = Archive(name=problem_file.name, kind="multishape", source=problem_file.source, diameter=problem.diameter,
                      units=problem_file.units, target=problem.targets[0], runs={RUN: result},
                      extra={f"targets/{k}/points": t for k, t in enumerate(problem.targets)})

    def extend(h5):  # the in-memory file after the standard layout: HDF5 never writes to the disk
        g = h5[f"runs/{RUN}"]
        g["design"].create_dataset("levels", data=np.asarray(result.levels, float))
        g.attrs["levels"] = result.count
        g.attrs["shared_pose"] = bool(result.shared_pose)
        for k in range(result.count):
            lv = g.create_group(f"levels/{k}")
            lv.attrs.update(**{"lambda": float(result.levels[k]), "fixed": bool(result.fixed[k]) if result.fixed else False})
            lv.create_dataset("initial_pose", data=result.poses[k])
            s = lv.create_group("shape")
            for line in ("center", "inner", "outer"):
                s.create_dataset(line, data=getattr(result.shapes[k], line), compression="gzip", compression_opts=4, shuffle=True)
            lv.create_group("metrics").attrs.update({key: float(v) for key, v in result.level_metrics[k].items()})

    write_archive(path, archive, extend=extend)


def read_multishape_archive(path):
    """(Archive, MultiShapeResult, targets): the archive as the generic reader sees it, the
    full multi-shape result (levels, poses, shapes, per-level metrics) and the K targets."""
    a = load_archive(path)
    base = a.runs[RUN]
    with open_archive(path) as h5:
        g = h5[f"runs/{RUN}"]
        levels = g["design/levels"][()]
        K = levels.size
        targets = [h5[f"targets/{k}/points"][()] for k in range(K)]
        shapes, poses, lm, fixed = [], [], [], []
        for k in range(K):
            lv = g[f"levels/{k}"]
            shapes.append(Shape(*(lv["shape"][line][()] for line in ("center", "inner", "outer"))))
            poses.append(lv["initial_pose"][()])
            lm.append({key: float(v) for key, v in lv["metrics"].attrs.items()})
            fixed.append(bool(lv.attrs.get("fixed", False)))
        shared = bool(g.attrs.get("shared_pose", True))
    r = MultiShapeResult(method=base.method, routing=base.routing, shape=base.shape, status=base.status, solve_time_s=base.solve_time_s,
                         iterations=base.iterations, metrics=base.metrics, stats=base.stats, diameter=base.diameter, levels=levels,
                         fixed=tuple(fixed), poses=np.array(poses), shapes=shapes, level_metrics=lm, shared_pose=shared)
    return a, r, targets


def write_tip_archive(path, problem_file, result: Result) -> None:
    """The standard archive with run ``/runs/tip`` plus /tip/position (and /tip/direction when given)."""
    problem = problem_file.problem
    extra = {"tip/position": problem.position}
    if problem.direction is not None:
        extra["tip/direction"] = problem.direction
    archive = Archive(name=problem_file.name, kind="tip", source=problem_file.source, diameter=problem.diameter,
                      units=problem_file.units, runs={TIP_RUN: result}, extra=extra, obstacles=list(problem.obstacles))
    write_archive(path, archive)
