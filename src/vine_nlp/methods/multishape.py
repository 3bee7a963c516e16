"""Multi-shape sPAM design: ONE routing, K shapes at K pressures (paper, Conclusion).

An sPAM contracts its whole actuator line to one ratio lambda that the pressure sets. One routing theta_j,
dl_j is shared by K chains; chain k uses the level lambda_k (bounded [lambda_min, 1], free or fixed by the
problem) and should take the shape of target k. The K shapes grow from the SAME base, so by default one
base pose is shared (the routing then also explains how the shapes differ, what a user measuring one robot
at several pressures wants); ``shared_pose=False`` gives each level its own (targets in different frames).
One NLP over all K chains on the transcription, every chain's frames variables in stage order:

  J = (1/K) sum_k (1/N) sum_i |r_k(i) - r_dk(i)|^2 / D^2 + w_theta (1/L) int (D dtheta/ds)^2 ds,

the smoothness on the mean of the targets' chord lengths. Starts (``drive.multistart``): the geometric
guess of the most actuated level's target (the smallest fixed lambda when all are fixed, else the shortest
target), free lambda_k from the chord length of target k, frames on each level's own target; its mirrored
side; seeded perturbations (lambdas spread in chord order, theta perturbed)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vine_nlp.analysis.buildability import POUCH_LAMBDA_MIN
from vine_nlp.methods import drive, variables
from vine_nlp.methods.common import evaluate, geometric_guess, pair_points
from vine_nlp.methods.settings import MAX_ITER, TOL, Settings
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Smoothness, SoftTip, Spec, cell_data, get_solver, smoothing_steps
from vine_nlp.model.helix import center_rates
from vine_nlp.model.pairing import Pairing
from vine_nlp.model.shape import routing_metrics
from vine_nlp.problem import MultiShapeProblem, Result, Routing

RUN = "multishape"

# ---------------------------------------------------------------- result


@dataclass(eq=False)
class MultiShapeResult(Result):
    """A Result whose ``routing``/``shape`` are level 0's (so generic writers and readers work),
    plus the shared routing's K levels, K poses, K shapes and per-level metrics.

    ``metrics`` holds the overall figures: rmse over all points of all levels,
    max_error the largest of all, plus tv_theta, tv_lambda."""

    levels: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (K,) lambda_k
    fixed: tuple = ()  # K booleans: lambda_k was fixed by the problem
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))  # (K, 4, 4) T^0_w of each level
    shapes: list = field(default_factory=list)  # K Shapes, row i pairs with target row i
    level_metrics: list = field(default_factory=list)  # K dicts: rmse, max_error
    shared_pose: bool = True

    @property
    def count(self) -> int:
        return int(np.size(self.levels))


# ---------------------------------------------------------------- the NLP


def multishape_spec(M: int, n: int, K: int, shared_pose: bool, max_iter: int = MAX_ITER, tol: float = TOL) -> Spec:
    """K chains of one routing (theta_j, dl_j shared), one lambda per level, one base pose or one per level."""
    return Spec(Structure(M, n, K, "level", "shared" if shared_pose else "level"), (Smoothness(lam=False), SoftTip()),
                "exact", Settings(max_iter, tol))


# ---------------------------------------------------------------- guesses


@dataclass
class MultiGuess:
    theta: np.ndarray  # (M,)
    length: np.ndarray  # (M,)
    levels: np.ndarray  # (K,)
    poses: list  # (4, 4) per pose variable (1 or K)
    frames: list  # K arrays (M+1, 4, 4)


def _pairings(problem: MultiShapeProblem) -> list[Pairing]:
    n = problem.options.points_per_segment
    return [pair_points(t, n) for t in problem.targets]


def _lambda_for_length(theta, length, arc, lo) -> float:
    """The lambda at which the chain (theta, length) has center-line length ``arc`` (bisection; lambda_c grows with lambda)."""

    def total(lam):
        return float(np.sum(length * center_rates(theta, lam, 1.0)[2]))

    if total(1.0) <= arc:
        return 1.0
    if total(lo) >= arc:
        return lo
    a, b = lo, 1.0
    for _ in range(60):
        m = 0.5 * (a + b)
        a, b = (m, b) if total(m) < arc else (a, m)
    return 0.5 * (a + b)


def reference_level(problem: MultiShapeProblem, pairings) -> int:
    """The most actuated level: the smallest fixed lambda if all are fixed, else the shortest target."""
    if all(v is not None for v in problem.levels):
        return int(np.argmin(problem.levels))
    return int(np.argmin([p.chord[-1] for p in pairings]))


def initial_guess(problem: MultiShapeProblem, pairings, flip: float = 1.0) -> MultiGuess:
    """Geometric guess of the most actuated target; free lambdas from the chord lengths; frames on every target."""
    a, K = problem.actuator, problem.count
    r = reference_level(problem, pairings)
    g = geometric_guess(problem.level_problem(r), pairings[r], flip)
    theta = g.theta
    arc_r = np.maximum(pairings[r].segment_chord, 1e-12)
    # one lambda for the reference: fixed, or the mean of the per-segment guess
    lam_r = problem.levels[r] if problem.levels[r] is not None else float(np.clip(np.mean(g.lam), a.lambda_min, 1.0))
    length = arc_r / center_rates(theta, lam_r, problem.diameter)[2]
    levels = np.empty(K)
    for k in range(K):
        if problem.levels[k] is not None:
            levels[k] = problem.levels[k]
        elif k == r:
            levels[k] = lam_r
        else:
            levels[k] = _lambda_for_length(theta, length / problem.diameter, pairings[k].chord[-1] / problem.diameter, a.lambda_min)
    gs = [g if k == r else geometric_guess(problem.level_problem(k), pairings[k], flip) for k in range(K)]
    frames = [gk.frames.copy() for gk in gs]
    poses = [gk.initial_pose.copy() for gk in gs]
    if problem.shared_pose:
        poses = [g.initial_pose.copy()]
        for fr in frames:
            fr[0] = g.initial_pose
    return MultiGuess(theta, length, levels, poses, frames)


def _in_band(problem: MultiShapeProblem, levels) -> np.ndarray:
    lo, hi = level_band(problem)
    return np.array([np.clip(v, lo, hi) if f is None else v for v, f in zip(levels, problem.levels)])


def start_guesses(problem: MultiShapeProblem, pairings, starts: int) -> list[MultiGuess]:
    """Start 0: the initial guess; start 1: its mirrored side; further starts: seeded perturbations
    (theta perturbed, free lambdas spread between lambda_min and 1 in the order of the targets' chord lengths)."""
    guesses = [initial_guess(problem, pairings, +1.0)]
    if starts > 1:
        guesses.append(initial_guess(problem, pairings, -1.0))
    rng = np.random.default_rng(problem.options.seed)
    a = problem.actuator
    order = np.argsort([p.chord[-1] for p in pairings])  # most actuated first
    rank = np.empty(problem.count, int)
    rank[order] = np.arange(problem.count)
    for s in range(2, starts):
        base = guesses[s % 2]
        theta = variables.perturb(variables.THETA, base.theta, rng, a)
        spread = a.lambda_min + (1.0 - a.lambda_min) * (rank + rng.uniform(0.2, 0.8, problem.count)) / problem.count
        levels = np.array([v if v is not None else spread[k] for k, v in enumerate(problem.levels)])
        guesses.append(MultiGuess(theta, base.length.copy(), levels, [p.copy() for p in base.poses], [f.copy() for f in base.frames]))
    return [MultiGuess(g.theta, g.length, _in_band(problem, g.levels), g.poses, g.frames) for g in guesses]


# ---------------------------------------------------------------- solve


def level_band(problem: MultiShapeProblem) -> tuple[float, float]:
    """A designed level's bounds: an sPAM's buildable band [max(lambda_min, 2/pi) + margin, 1 - margin] (methods.buildable)."""
    m = problem.options.correction_margin
    lo = max(problem.actuator.lambda_min, POUCH_LAMBDA_MIN) + m
    return lo, max(lo, 1.0 - m)


def solve_from(problem: MultiShapeProblem, guess: MultiGuess, pairings=None) -> MultiShapeResult:
    """One IPOPT solve of the multi-shape NLP from ``guess``."""
    o, D, K = problem.options, problem.diameter, problem.count
    pairings = pairings or _pairings(problem)
    M, n = pairings[0].segments, pairings[0].n
    solver = get_solver(multishape_spec(M, n, K, problem.shared_pose, o.max_iter, o.tol))
    P = solver.structure.poses
    N = problem.targets[0].shape[0]
    cells = np.zeros((5 * n, M * K))
    for k, (tgt, pr) in enumerate(zip(problem.targets, pairings)):
        cell_data(pr, tgt / D, 1.0 / (N * K), K, k, cells)
    h, L = smoothing_steps(np.mean([pr.chord for pr in pairings], axis=0) / D, pairings[0].bounds)
    R0 = np.column_stack([G[:3, :3].ravel(order="F") for G in guess.poses[:P]])
    p = solver.pack_params({"cells": cells, "R0g": R0, "smooth": [o.smooth_theta, 0.0], "h": h, "L": L,
                            "tip": np.column_stack([t[-1] / D for t in problem.targets]), "wtip": np.full(K, 1.0 / (N * K))})
    fr = [frames12(f, D) for f in guess.frames]
    poses = np.array([np.r_[np.zeros(3), G[:3, 3] / D] for G in guess.poses[:P]])
    x0 = solver.pack_x(np.array(fr), poses=poses, lam_global=guess.levels, theta=guess.theta, lam=None, length=guess.length / D)
    seg_chord = np.max([pr.segment_chord for pr in pairings], axis=0) / D
    a = problem.actuator
    lo, hi = level_band(problem)  # a free level buildable, with room to correct; a fixed one as the problem fixes it
    levels = ([lo if v is None else v for v in problem.levels], [hi if v is None else v for v in problem.levels])
    lbx, ubx = solver.bounds(**variables.box(a, seg_chord) | {"lam": levels})  # lambda: one per level
    sol = solver.solve(x0, p, lbx, ubx)
    v, st = sol.unpack(), sol.stats
    T = [sol.routing(D, guess.poses[q][:3, :3], k).initial_pose for k, q in enumerate(solver.layout.pose_of_level)]
    stats = st | {"segments": M, "points_per_segment": n, "levels": K, "shared_pose": problem.shared_pose,
                  "fixed_levels": [lv is not None for lv in problem.levels], "smooth_theta": o.smooth_theta, "tol": o.tol,
                  "max_iter": o.max_iter}
    return assemble(problem, v["theta"], v["length"] * D, v["lam_global"], T, pairings, status=sol.status, objective=sol.objective,
                    solve_time_s=stats.pop("solve_time_s"), iterations=stats.pop("iterations"), stats=stats)


def assemble(problem: MultiShapeProblem, theta, length, levels, poses, pairings=None, **kw) -> MultiShapeResult:
    """Evaluate a shared routing at its K levels against the K targets: the MultiShapeResult."""
    pairings = pairings or _pairings(problem)
    K = problem.count
    levels = np.asarray(levels, float).reshape(K)
    poses = np.asarray(poses, float).reshape(K, 4, 4)
    per = [evaluate(problem.level_problem(k), Routing(theta=theta, lam=np.full(np.size(theta), levels[k]), length=length, initial_pose=poses[k]), pairings[k], RUN)
           for k in range(K)]
    d2 = np.concatenate([np.sum((r.shape.center - t) ** 2, axis=1) for r, t in zip(per, problem.targets)])
    level_metrics = [{"rmse": r.metrics["rmse"], "max_error": r.metrics["max_error"], "lambda": float(levels[k])} for k, r in enumerate(per)]
    metrics = {"rmse": float(np.sqrt(d2.mean())), "max_error": float(np.sqrt(d2.max()))} | routing_metrics(per[0].routing)
    return MultiShapeResult(method=RUN, routing=per[0].routing, shape=per[0].shape, metrics=metrics, diameter=problem.diameter,
                            levels=levels, fixed=tuple(v is not None for v in problem.levels), poses=poses, shapes=[r.shape for r in per],
                            level_metrics=level_metrics, shared_pose=problem.shared_pose, **kw)


def design_multishape(problem: MultiShapeProblem, starts: int | None = None, progress=None) -> MultiShapeResult:
    """One sPAM routing for K shapes at K contraction levels; multi-start (``options.starts``), lowest objective wins."""
    if problem.actuator.kind != "spam":
        raise ValueError("multi-shape design needs an sPAM actuator (one lambda per level)")
    pairings = _pairings(problem)
    n_starts = max(1, problem.options.starts if starts is None else starts)
    guesses = start_guesses(problem, pairings, n_starts)
    stats = drive.Stats()
    found = drive.multistart(lambda g: solve_from(problem, g, pairings), guesses, progress=progress)
    return stats.stamp(drive.record_starts(found, stats, always=True))


__all__ = ["MultiShapeResult", "design_multishape", "multishape_spec", "start_guesses", "solve_from", "assemble"]
