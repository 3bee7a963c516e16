"""Tip targets: reach a tip position (and optionally a tip direction) with the least actuation (paper, Conclusion).

The robot grows from a FIXED base pose T^0_w with a given tube length L cut into M segments (sum_j dl_j = L,
dl_j >= settings.MIN_LENGTH_FACTOR L/M). Among the routings that put the tip at ``position`` (and its tangent along
``direction``) it picks the one with the least actuation:

  "contraction" (default):  J = (1/L) sum_j (1 - lambda_j) dl_j
  "turns":                  J = (1/L) sum_j sqrt(tan^2 theta_j + eps) dl_j   (turning: (2/D) sum |tan theta_j| dl_j)

Each leaves the other actuator parameter free (a degenerate optimum, slow for IPOPT): a tie-break of weight
settings.TIE_BREAK adds the least of the other measure (tan^2 theta_j dl_j, resp. (1 - lambda_j)^2 dl_j), plus the
smoothness terms of ``methods.nlp`` on the uniform spacing L/M. Rows: continuity, tip position, tip tangent
(t . e1 = t . e2 = 0 with e1, e2 perpendicular to the direction, and t . direction >= 0: rank 2), sum dl = L;
exact bounds (``settings.Settings.exact_bounds``: no relaxation, no "acceptable" stop leaving the tip loosely met).

Starts (``drive.multistart``), tried in order until one is optimal: the geometric guess of a guide curve (a
cubic Bezier from the base along its tangent to the tip along the direction, stretched to about the actuated
tube length), its mirrored side, then seeded uniform helices. The landscape is rugged (many local optima of
bends at the shortest segments) and a start costs hundreds of iterations, so later starts are fallbacks.
IPOPT's monotone barrier (``settings.Settings.monotone``) takes fewer iterations and finds lower optima here than the
adaptive one; the other changes tried (barrier, scaling, inertia correction, MUMPS, guide curves, a
coarse-to-fine start) moved designs to other local optima, more often worse.

Reachability: the center line is never longer than the tube, so a tip farther than L from the base is out of
reach. That, or no converged start, gives status "infeasible" and the nearest approach (the tip distance as
the objective instead of rows), so tip_error tells how far out of reach the target is; a nearest approach
that does reach the tip (IPOPT's infeasibility is local) re-solves the design."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.methods import drive, settings
from vine_nlp.methods.blocks import BlockType
from vine_nlp.methods.buildable import Build, made_buildable
from vine_nlp.methods.common import _perpendicular, _unit, geometric_guess, pair_points
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Chain, Smoothness, Solution, Spec, get_solver
from vine_nlp.methods.variables import ROUTE, box
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.shape import forward_shape, routing_metrics
from vine_nlp.problem import DesignProblem, Result, Routing, TipProblem

RUN = "tip"


@dataclass(frozen=True)
class TipTerms:
    """The tip formulation's terms and rows on the chain (module docstring): actuation objective with its
    tie-break, total length row, tip position and direction rows (or, ``closest``, the tip miss as the
    objective). Parameters: tip_position (3), tip_frame (3 x 3: direction, e1, e2), tube_length."""

    direction: bool
    objective: str
    closest: bool = False

    def apply(self, c: Chain) -> None:
        P_tip, P_dir, P_L = c.param("tip_position", (3, 1)), c.param("tip_frame", (3, 3)), c.param("tube_length", (1, 1))
        tip, tangent = c.tip(0), c.frames(0)[0:3, -1]  # tangent: first column of the tip rotation
        scale = settings.CLOSEST_ACTUATION if self.closest else 1.0
        M, lay = c.s.M, c.lay
        idx = np.array([lay.routing_at(j) for j in range(M)]).T  # variables.ROUTE
        w = ca.repmat(scale / P_L, 1, M)
        main, tie = actuation_blocks(self.objective)
        c.add_block(main, idx, w, term="actuation")
        c.add_block(tie, idx, settings.TIE_BREAK * w, term="smooth")
        c.add_rows("length", ca.sum2(c.dl) - P_L, 0.0, 0.0)
        if self.closest:
            # the nearest the tube can get: tip distance (and direction) as the objective, actuation as a tie-break
            miss = ca.sumsqr(tip - P_tip)
            if self.direction:
                miss += ca.sumsqr(tangent - P_dir[:, 0])
            c.add_term("miss", miss)
            return
        c.add_rows("tip", tip - P_tip, 0.0, 0.0)
        if self.direction:
            c.add_rows("direction", ca.mtimes(P_dir[:, 1:].T, tangent), 0.0, 0.0)
            c.add_rows("direction_sign", ca.dot(P_dir[:, 0], tangent), 0.0, np.inf)


@lru_cache(maxsize=None)
def actuation_blocks(objective: str) -> tuple[BlockType, BlockType]:
    """Per-segment actuation and its tie-break as blocks: v = ``variables.ROUTE`` (theta, lam, dl), d = weight (1/L, scaled).

    "contraction": (1 - lam) dl, tie-break tan^2 theta dl (least twist among least-contraction routings);
    "turns": sqrt(tan^2 theta + eps) dl, tie-break (1 - lam)^2 dl (least contraction among least-turning ones)."""
    v, d = ca.SX.sym("v", ROUTE.size), ca.SX.sym("d")
    th, la, dl = ROUTE.split(v)
    if objective == "contraction":
        main, tie = (1 - la) * dl, ca.tan(th) ** 2 * dl
    else:
        main, tie = ca.sqrt(ca.tan(th) ** 2 + settings.TURNS_EPS) * dl, (1 - la) ** 2 * dl
    empty = ca.SX(0, 1)
    return (BlockType(f"actuation_{objective}", ca.Function("actuation", [v, d], [d * main, empty])),
            BlockType(f"actuation_tie_{objective}", ca.Function("actuation_tie", [v, d], [d * tie, empty])))


def tip_spec(M: int, shared: bool, direction: bool, objective: str, max_iter: int = settings.MAX_ITER, tol: float = settings.TOL, closest: bool = False,
             monotone: bool = False, hard: bool = False, extra: int = 0, terms: tuple = ()) -> Spec:
    """A fixed base, no points to fit (one empty slot per segment), the tip terms and rows, the smoothness, exact
    bounds; ``monotone``: IPOPT's monotone barrier (design_tip's own solves); ``terms`` (with ``extra`` stage
    variables, ``hard`` rows): a formulation built on it."""
    return Spec(Structure(M, 1, 1, "shared" if shared else "segment", "fixed", extra=extra),
                (Smoothness(), TipTerms(direction, objective, closest)) + tuple(terms), "exact",
                settings.Settings(max_iter, tol, exact_bounds=True, monotone=monotone, hard=hard))


def _perpendicular_pair(d):
    e1 = _perpendicular(d)
    return e1, np.cross(d, e1)


def guide_curve(problem: TipProblem, samples: int) -> np.ndarray:
    """A smooth curve from the base (along its tangent) to the tip (along the direction, or the chord):
    a cubic Bezier whose handles are stretched until it is about as long as the tube will be when actuated."""
    T0 = problem.initial_pose
    p0, t0 = T0[:3, 3], T0[:3, 0]
    p1 = problem.position
    chord = float(np.linalg.norm(p1 - p0))
    d = problem.direction if problem.direction is not None else (_unit(p1 - p0) if chord > 0 else t0)
    L = problem.length
    lam_c_min = 0.5 * (1 + problem.actuator.lambda_min)  # center compression of a planar bend at lambda_min
    want = min(max(0.5 * (chord + L), 1.02 * lam_c_min * L), L) if chord < L else chord
    u = np.linspace(0.0, 1.0, 4 * samples)

    def curve(a):
        P = np.array([p0, p0 + a * t0, p1 - a * d, p1])
        B = np.stack([(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u), u**3], axis=1)
        return B @ P

    def length(a):
        return float(np.linalg.norm(np.diff(curve(a), axis=0), axis=1).sum())

    lo, hi = 1e-3 * L, 1e-3 * L
    while length(hi) < want and hi < 100 * L:
        hi *= 2
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if length(mid) < want else (lo, mid)
    c = curve(hi)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], samples)
    return np.column_stack([np.interp(t, s, c[:, i]) for i in range(3)])


def start_guesses(problem: TipProblem, starts: int):
    """(theta, lam, dl, frames (M+1, 4, 4)) per start: the geometric guess of a guide curve
    (frames on the curve), its mirrored side, then uniform helices (frames on their chains)."""
    M, D, a, L = problem.segments, problem.diameter, problem.actuator, problem.length
    out = []
    curve = guide_curve(problem, M * settings.GUESS_POINTS + 1)
    dp = DesignProblem(problem.name, D, curve, a, replace(problem.options, points_per_segment=settings.GUESS_POINTS))
    pairing = pair_points(curve, settings.GUESS_POINTS)
    for flip in (1.0, -1.0):
        g = geometric_guess(dp, pairing, flip)
        lam = np.full(M, np.clip(np.mean(g.lam), a.lambda_min, 1.0)) if a.shared_lambda else g.lam
        dl = np.maximum(g.length * L / g.length.sum(), settings.MIN_LENGTH_FACTOR * L / M)
        dl *= L / dl.sum()
        frames = g.frames.copy()
        frames[0] = problem.initial_pose
        out.append((g.theta, lam, dl, frames))
    rng = np.random.default_rng(problem.options.seed)
    while len(out) < starts:
        th = float(np.clip(rng.normal(0.0, 0.3), -a.theta_max, a.theta_max))
        lam = np.full(M, rng.uniform(a.lambda_min, 1.0))
        theta = np.clip(np.full(M, th) + rng.normal(0.0, 0.1, M), -a.theta_max, a.theta_max)
        dl = np.full(M, L / M)
        out.append((theta, lam, dl, chain_frames(theta, lam, dl, D, problem.initial_pose)))
    return out[:starts]


def tip_data(problem: TipProblem, closest: bool = False) -> dict:
    """The tip NLP's data (units of D); ``closest``: the nearest approach's (the actuation scaled down)."""
    o, D, M, L = problem.options, problem.diameter, problem.segments, problem.length
    d = problem.direction if problem.direction is not None else np.array([1.0, 0.0, 0.0])
    e1, e2 = _perpendicular_pair(d)
    scale = settings.CLOSEST_ACTUATION if closest else 1.0
    return {"cells": np.zeros((5, M)), "smooth": [scale * o.smooth_theta, scale * o.smooth_lambda], "h": np.full(max(M - 1, 1), L / M / D),
            "L": L / D, "tip_position": problem.position / D, "tip_frame": np.column_stack([d, e1, e2]), "tube_length": L / D}


def tip_bounds(solver, problem: TipProblem, lam=None) -> tuple:
    """Box bounds of the tip NLP: the design's theta and lambda (``lam``: these lambda bounds, a buildable design's
    classes), lengths from settings.MIN_LENGTH_FACTOR L / M to L, the base fixed."""
    a, D, M, L = problem.actuator, problem.diameter, problem.segments, problem.length
    X0 = frames12(problem.initial_pose[None], D)[:, 0]
    b = box(a, np.zeros(M), only=("theta", "lam")) | ({} if lam is None else {"lam": lam})
    return solver.bounds(X0=X0, **b, length=(settings.MIN_LENGTH_FACTOR * L / M / D, L / D))


def tip_result(problem: TipProblem, sol: Solution, closest: bool = False) -> Result:
    """The Result of a solution of the tip NLP (or a formulation built on it)."""
    o, st = problem.options, sol.stats
    scale = settings.CLOSEST_ACTUATION if closest else 1.0
    stats = st | {"objective_actuation": st["objective_actuation"] / scale, "objective_miss": st.get("objective_miss", 0.0),
                  "objective_kind": problem.objective, "closest_approach": closest, "segments": problem.segments,
                  "tube_length": problem.length, "smooth_theta": o.smooth_theta, "smooth_lambda": o.smooth_lambda, "tol": o.tol,
                  "max_iter": o.max_iter}
    stats.pop("objective_fit", None)
    return evaluate_tip(problem, sol.routing(problem.diameter, problem.initial_pose), status=sol.status, objective=sol.objective,
                        solve_time_s=stats.pop("solve_time_s"), iterations=stats.pop("iterations"), stats=stats)


def solve_from(problem: TipProblem, theta, lam, dl, frames, closest: bool = False, monotone: bool = True, bounds=None) -> Result:
    """One IPOPT solve of the tip NLP from a guess; ``closest``: the nearest approach instead (no tip constraints);
    ``monotone``: IPOPT's monotone barrier, else the adaptive one; ``bounds``: lambda's (a buildable design's classes)."""
    o, D = problem.options, problem.diameter
    solver = get_solver(tip_spec(problem.segments, problem.actuator.shared_lambda, problem.direction is not None, problem.objective,
                                 o.max_iter, o.tol, closest, monotone))
    x0 = solver.pack_x(frames12(frames, D)[None], theta=theta, lam=lam, length=dl / D)
    return tip_result(problem, solver.solve(x0, solver.pack_params(tip_data(problem, closest)), *tip_bounds(solver, problem, bounds)), closest)


def actuation(routing: Routing, diameter: float) -> dict:
    """Both measures of actuation of a routing: contraction sum (1 - lambda) dl [length] and turning (2/D) sum |tan theta| dl [rad]."""
    return {"actuation_contraction": float(np.sum((1 - routing.lam) * routing.length)),
            "actuation_turning": float(2.0 / diameter * np.sum(np.abs(np.tan(routing.theta)) * routing.length))}


def evaluate_tip(problem: TipProblem, routing: Routing, **kw) -> Result:
    """The forward shape of ``routing`` and its tip metrics (tip_error = rmse = max_error, so generic readers work)."""
    D = problem.diameter
    shape = forward_shape(routing, D)
    end = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)[-1]
    err = float(np.linalg.norm(end[:3, 3] - problem.position))
    metrics = {"tip_error": err, "rmse": err, "max_error": err}
    if problem.direction is not None:
        t = end[:3, 0]
        metrics["direction_error"] = float(math.atan2(np.linalg.norm(np.cross(t, problem.direction)), np.dot(t, problem.direction)))
    metrics |= actuation(routing, D) | routing_metrics(routing)
    metrics["tube_length"] = float(routing.length.sum())
    return Result(method=RUN, routing=routing, shape=shape, metrics=metrics, diameter=D, **kw)


def reachable_distance(problem: TipProblem) -> bool:
    """Necessary condition: the tip is no farther from the base than the tube is long."""
    return float(np.linalg.norm(problem.position - problem.initial_pose[:3, 3])) <= problem.length * (1 + 1e-12)


def design_tip(problem: TipProblem, starts: int | None = None, progress=None, thorough: bool = False) -> Result:
    """Least-actuation routing for a tip target: up to ``options.starts`` starts, tried in order until one is
    optimal (module docstring); the lowest objective among converged starts (:func:`rank`). ``thorough``: every
    start, with IPOPT's adaptive barrier (the obstacle design's start: a wider search for a design that clears).

    Unreachable tips get status "infeasible" and the nearest approach (the routing that brings the tip closest, solved
    without the tip constraints), so tip_error says how far out of reach the target is. A tip farther from the base than
    the tube is long is not attempted (only the nearest approach is solved); when no start converges, the nearest
    approach is solved too and, if it does reach the tip after all (IPOPT's infeasibility is local), the design is
    re-solved from it."""
    n = max(1, problem.options.starts if starts is None else starts)
    guesses = start_guesses(problem, n)
    stats = drive.Stats()
    reach = reachable_distance(problem)
    results, best = [], None
    if reach:
        # the mirrored guide curve can be the same curve: the same solve again
        unique = [g for i, g in enumerate(guesses) if not any(all(np.array_equal(a, b) for a, b in zip(g, h)) for h in guesses[:i])]
        found = drive.multistart(lambda g: solve_from(problem, *g, monotone=not thorough), unique, key=rank,
                                 accept=None if thorough else (lambda r: r.status == "optimal"),
                                 progress=progress and (lambda done, _: progress(done, len(guesses))))
        results, best = found.results, found.best
    reason = "" if reach else "the tip is farther from the base than the tube is long"
    if best is None or not best.converged:
        near = solve_from(problem, *guesses[0], closest=True)
        retry = None
        if reach and near.metrics["tip_error"] <= settings.CLOSE_ENOUGH * problem.diameter:
            r = near.routing
            retry = solve_from(problem, r.theta, r.lam, r.length, chain_frames(r.theta, r.lam, r.length, problem.diameter, r.initial_pose))
            results.append(retry)
        if retry is not None and retry.converged:
            best = retry
        else:
            tried = [r.status for r in results]
            results.append(near)
            best = near
            best.stats["closest_status"] = near.status
            best.status = "infeasible"
            reason = reason or f"no start reached the tip (statuses {', '.join(tried)}); nearest approach reported"
    drive.record_starts(drive.Starts(best, next(k for k, r in enumerate(results) if r is best), results), stats, always=True)
    best.stats["start_status"] = [r.status for r in results]
    if reason:
        best.stats["infeasible_reason"] = reason
    best.metrics["reachable"] = float(best.converged)
    built = buildable_tip(problem, best) if best.converged else best
    if built is not best:  # its solves counted, the starts' record kept
        stats.absorb(built)
        built.stats, built.metrics["reachable"] = best.stats | built.stats, 1.0
    return stats.stamp(built)


def buildable_tip(problem: TipProblem, result: Result, solve=None) -> Result:
    """A converged tip design made buildable (methods.buildable.made_buildable): one solve more with the classes'
    lambda bounds, from it (``solve(start, lam)``, default the tip NLP's own; a formulation built on it passes its own)."""
    D = problem.diameter

    def own(r: Routing, lam):
        return solve_from(problem, r.theta, r.lam, r.length, chain_frames(r.theta, r.lam, r.length, D, r.initial_pose), bounds=lam)

    def finish(res: Result, routing: Routing) -> Result:
        out = evaluate_tip(problem, routing, status=res.status, objective=res.objective, solve_time_s=res.solve_time_s,
                           iterations=res.iterations, stats=res.stats)
        out.metrics = res.metrics | out.metrics
        return out

    return made_buildable(result, Build.of(problem), solve or own, finish)


def rank(result: Result) -> tuple:
    """The drive's ranking of tip designs: converged by the objective, the others by their tip error."""
    return drive.rank(result, result.converged, result.metrics["tip_error"])
