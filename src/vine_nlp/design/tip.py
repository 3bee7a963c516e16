"""Tip targets: reach a tip position (and optionally a tip direction) with the least actuation (paper, Conclusion).

The robot grows from a FIXED base pose T^0_w (given, default identity) with a
given tube length L cut into M segments (sum_j dl_j = L, dl_j >= 0.2 L/M: the
tube length is a design input, the segment lengths are free). Among all routings
that put the tip at ``position`` (and its tangent along ``direction`` when given)
it picks the one with the least actuation:

  "contraction" (default):  J = (1/L) sum_j (1 - lambda_j) dl_j
  "turns":                  J = (1/L) sum_j sqrt(tan^2 theta_j + eps) dl_j,  eps = 1e-6
                            (the actuator's turning around the tube is (2/D) sum |tan theta_j| dl_j)

Each objective leaves the other actuator parameter free (contraction does not
price twisting, turns does not price contracting), which makes the optimum
degenerate and IPOPT slow; a tie-break with weight 1e-2 picks the least of the
other measure: + 1e-2 (1/L) sum tan^2 theta_j dl_j for "contraction",
+ 1e-2 (1/L) sum (1 - lambda_j)^2 dl_j for "turns"; plus the smoothness terms of
``design.nlp`` (weights ``options.smooth_theta``, ``options.smooth_lambda``, on
the uniform spacing L/M). Bounds as in design: |theta| <= theta_max,
lambda_min <= lambda <= 1 (one lambda for an sPAM).

Multiple shooting as in ``design.nlp``: frames at the segment ends are variables
(stage order), lengths scaled by D. Constraints: continuity, tip position
(3 equalities), tip tangent (2 equalities t . e1 = t . e2 = 0 with e1, e2
perpendicular to the direction, and t . direction >= 0: rank 2, no redundant
equality), sum dl = L. IPOPT runs without bound relaxation and without
"acceptable" stops that would leave the tip loosely met.

Initial guesses: the geometric guess (``design.common.geometric_guess``) of a
guide curve (a cubic Bezier from the base along its tangent to the tip along the
direction, stretched to about the actuated tube length), its mirrored side, then
seeded uniform helices; the lowest objective among converged starts wins.

Reachability: the center line is never longer than the tube (lambda_c <= 1 for
lambda <= 1 and |theta| <= 60 deg), so a tip farther than L from the base is out
of reach. That, or no converged start, gives status "infeasible" (the CLI exits
1); the result is then the nearest approach (the same NLP with the tip distance
as the objective instead of a constraint), so tip_error tells how far out of
reach the target is. A nearest approach that does reach the tip (IPOPT's
infeasibility is local) is used to re-solve the design.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.design.common import (
    frames12,
    geometric_guess,
    ipopt_options,
    ipopt_status,
    pair_points,
    solver_stats,
)
from vine_nlp.design.nlp import segment_function
from vine_nlp.design.problem import DesignProblem, Routing, TipProblem
from vine_nlp.design.result import Result, forward_shape, routing_metrics
from vine_nlp.model.chain import chain_frames

RUN = "tip"
MIN_LENGTH_FACTOR = 0.2  # dl_j >= 0.2 L / M
TURNS_EPS = 1e-6
TIE_BREAK = 1e-2  # weight of the secondary measure (see module doc)
CLOSEST_ACTUATION = 1e-6  # weight of the actuation in the nearest-approach variant
CLOSE_ENOUGH = 1e-3  # nearest approach within this many D of the tip: re-solve the design from it
# hard constraints: no bound relaxation (the returned routing needs no projection that would move the tip)
# and no "acceptable" stop with a loosely met tip
TIP_IPOPT = {"ipopt.bound_relax_factor": 0.0, "ipopt.acceptable_constr_viol_tol": 1e-10}
GUESS_POINTS = 4  # points per segment of the guide curve of the geometric guess


class TipSolver:
    """The tip NLP of one structure (M segments, shared lambda, direction given, objective)."""

    def __init__(self, M: int, shared: bool, direction: bool, objective: str, max_iter: int = 3000, tol: float = 1e-8, closest: bool = False):
        t0 = time.perf_counter()
        self.M, self.shared, self.direction, self.objective, self.closest = M, shared, direction, objective, closest
        self.per = 2 if shared else 3  # theta, (lam), dl per stage
        self.width = self.per + 12
        self.off = 1 if shared else 0
        self.size = self.off + M * self.width
        x = ca.MX.sym("x", self.size)
        P_X0 = ca.MX.sym("X0", 12)
        P_tip = ca.MX.sym("tip", 3)
        P_dir = ca.MX.sym("dir", 3, 3)  # direction, e1, e2 (columns)
        P_L = ca.MX.sym("L")
        P_smooth = ca.MX.sym("smooth", 2)
        params = [P_X0, P_tip, P_dir, P_L, P_smooth]
        self._param_shapes = [(p.size1(), p.size2()) for p in params]
        stages = ca.reshape(x[self.off :], self.width, M)
        theta = stages[0, :]
        if shared:
            lam = ca.repmat(x[0], 1, M)
            dl = stages[1, :]
        else:
            lam, dl = stages[1, :], stages[2, :]
        Xnext = stages[self.per :, :]
        Xstart = ca.horzcat(P_X0, Xnext[:, : M - 1])
        F = segment_function(1).map(M, "serial")
        Xn, _ = F(Xstart, theta, lam, dl, ca.DM.ones(1, M))
        tip = Xnext[9:, M - 1]
        tangent = Xnext[0:3, M - 1]  # first column of the tip rotation
        g = [ca.vec(Xn - Xnext), ca.sum2(dl) - P_L]
        lbg = [np.zeros(12 * M), [0.0]]
        ubg = [np.zeros(12 * M), [0.0]]
        if closest:
            # the nearest the tube can get: tip distance (and direction) as the objective, actuation as a tie-break
            miss = ca.sumsqr(tip - P_tip)  # in D^2: a squared distance is flat near 0, keep it large
            if direction:
                miss += ca.sumsqr(tangent - P_dir[:, 0])
        else:
            g.append(tip - P_tip)
            lbg.append(np.zeros(3))
            ubg.append(np.zeros(3))
        if direction and not closest:
            g += [ca.mtimes(P_dir[:, 1:].T, tangent), ca.dot(P_dir[:, 0], tangent)]
            lbg += [np.zeros(2), [0.0]]
            ubg += [np.zeros(2), [np.inf]]
        if objective == "contraction":
            J = ca.sum2((1 - lam) * dl) / P_L
            tie = ca.sum2(ca.tan(theta) ** 2 * dl) / P_L  # least twist among least-contraction routings
        else:
            J = ca.sum2(ca.sqrt(ca.tan(theta) ** 2 + TURNS_EPS) * dl) / P_L
            tie = ca.sum2((1 - lam) ** 2 * dl) / P_L  # least contraction among least-turning routings
        smooth = TIE_BREAK * tie
        if M > 1:
            h = P_L / M
            smooth += P_smooth[0] * ca.sumsqr(ca.diff(theta.T)) / h / P_L
            if not shared:
                smooth += P_smooth[1] * ca.sumsqr(ca.diff(lam.T)) / h / P_L
        f = CLOSEST_ACTUATION * (J + smooth) + miss if closest else J + smooth
        p = ca.vertcat(*[ca.vec(q) for q in params])
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        opts = ipopt_options(max_iter, tol)
        opts.update(TIP_IPOPT)
        self.solver = ca.nlpsol("vine_nlp_tip", "ipopt", {"x": x, "p": p, "f": f, "g": ca.vertcat(*g)}, opts)
        self._terms = ca.Function("terms", [x, p], [J, smooth, miss if closest else ca.MX(0)])
        self.build_time_s = time.perf_counter() - t0

    def pack_params(self, values) -> np.ndarray:
        return np.concatenate([np.asarray(v, float).reshape(s, order="F").ravel(order="F") for v, s in zip(values, self._param_shapes)])

    def pack_x(self, theta, lam, dl, fr12) -> np.ndarray:
        x = np.zeros(self.size)
        cols = [theta, dl] if self.shared else [theta, lam, dl]
        if self.shared:
            x[0] = float(np.mean(lam))
        x[self.off :] = np.vstack([np.atleast_2d(c) for c in cols] + [fr12[:, 1:]]).ravel(order="F")
        return x

    def unpack_x(self, x):
        stages = x[self.off :].reshape(self.width, self.M, order="F")
        theta = stages[0].copy()
        if self.shared:
            return theta, np.full(self.M, x[0]), stages[1].copy()
        return theta, stages[1].copy(), stages[2].copy()

    def bounds(self, theta_max, lambda_min, dl_min, dl_max):
        lbx, ubx = np.full(self.size, -np.inf), np.full(self.size, np.inf)
        if self.shared:
            lbx[0], ubx[0] = lambda_min, 1.0
        W, o, M = self.width, self.off, self.M
        lbx[o : o + W * M : W], ubx[o : o + W * M : W] = -theta_max, theta_max
        if not self.shared:
            lbx[o + 1 : o + W * M : W], ubx[o + 1 : o + W * M : W] = lambda_min, 1.0
        k = o + self.per - 1
        lbx[k : k + W * M : W], ubx[k : k + W * M : W] = dl_min, dl_max
        return lbx, ubx


@lru_cache(maxsize=16)
def get_solver(M: int, shared: bool, direction: bool, objective: str, max_iter: int = 3000, tol: float = 1e-8, closest: bool = False) -> TipSolver:
    """Cached per structure (building costs more than one solve); ``closest`` is the variant without the tip constraints."""
    return TipSolver(M, shared, direction, objective, max_iter, tol, closest)


def _unit(v):
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def _perpendicular_pair(d):
    a = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = _unit(a - np.dot(a, d) * d)
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
    M, D, a = problem.segments, problem.diameter, problem.actuator
    L = problem.length
    out = []
    curve = guide_curve(problem, M * GUESS_POINTS + 1)
    dp = DesignProblem(problem.name, D, curve, a, replace(problem.options, points_per_segment=GUESS_POINTS))
    pairing = pair_points(curve, GUESS_POINTS)
    for flip in (1.0, -1.0):
        g = geometric_guess(dp, pairing, flip)
        lam = np.full(M, np.clip(np.mean(g.lam), a.lambda_min, 1.0)) if a.shared_lambda else g.lam
        dl = np.maximum(g.length * L / g.length.sum(), MIN_LENGTH_FACTOR * L / M)
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


def solve_from(problem: TipProblem, theta, lam, dl, frames, closest: bool = False) -> Result:
    """One IPOPT solve of the tip NLP from a guess; ``closest``: the nearest approach instead (no tip constraints)."""
    o, a, D, M, L = problem.options, problem.actuator, problem.diameter, problem.segments, problem.length
    has_dir = problem.direction is not None
    solver = get_solver(M, a.shared_lambda, has_dir, problem.objective, o.max_iter, o.tol, closest)
    T0 = problem.initial_pose
    X0 = frames12(T0[None])[:, 0].copy()
    X0[9:] /= D
    d = problem.direction if has_dir else np.array([1.0, 0.0, 0.0])
    e1, e2 = _perpendicular_pair(d)
    p = solver.pack_params([X0, problem.position / D, np.column_stack([d, e1, e2]), L / D, [o.smooth_theta, o.smooth_lambda]])
    fr = frames.copy()
    fr[:, :3, 3] /= D
    lbx, ubx = solver.bounds(a.theta_max, a.lambda_min, MIN_LENGTH_FACTOR * L / M / D, L / D)
    x0 = np.clip(solver.pack_x(theta, lam, dl / D, frames12(fr)), lbx, ubx)
    t0 = time.perf_counter()
    sol = solver.solver(x0=x0, p=p, lbx=lbx, ubx=ubx, lbg=solver.lbg, ubg=solver.ubg)
    solve_time = time.perf_counter() - t0
    st = solver.solver.stats()
    x = np.array(sol["x"]).ravel()
    theta, lam, dl = solver.unpack_x(x)
    J, smooth, miss = (float(v) for v in solver._terms(x, p))
    status = ipopt_status(st, x)
    stats = solver_stats(st, sol, solver.build_time_s) | {
        "objective_actuation": J,
        "objective_miss": miss,
        "objective_smooth": smooth,
        "objective_kind": problem.objective,
        "closest_approach": closest,
        "segments": M,
        "tube_length": L,
        "smooth_theta": o.smooth_theta,
        "smooth_lambda": o.smooth_lambda,
        "tol": o.tol,
        "max_iter": o.max_iter,
        "max_constraint_violation": _violation(np.array(sol["g"]).ravel(), solver.lbg, solver.ubg),
    }
    return evaluate_tip(problem, Routing(theta, lam, dl * D, T0), status=status, solve_time_s=solve_time,
                        iterations=int(st.get("iter_count", 0)), stats=stats)


def _violation(g, lb, ub) -> float:
    return float(np.max(np.maximum(lb - g, 0) + np.maximum(g - ub, 0))) if g.size else 0.0


def actuation(routing: Routing, diameter: float) -> dict:
    """Both measures of actuation of a routing: contraction sum (1 - lambda) dl [length] and turning (2/D) sum |tan theta| dl [rad]."""
    return {
        "actuation_contraction": float(np.sum((1 - routing.lam) * routing.length)),
        "actuation_turning": float(2.0 / diameter * np.sum(np.abs(np.tan(routing.theta)) * routing.length)),
    }


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


def design_tip(problem: TipProblem, starts: int | None = None, progress=None) -> Result:
    """Least-actuation routing for a tip target: multi-start (``options.starts``), lowest objective among converged starts.

    Unreachable tips get status "infeasible" and the nearest approach (the routing
    that brings the tip closest, solved without the tip constraints), so tip_error
    says how far out of reach the target is. A tip farther from the base than the
    tube is long is not attempted (only the nearest approach is solved); when no
    start converges, the nearest approach is solved too and, if it does reach the
    tip after all (IPOPT's infeasibility is local), the design is re-solved from it.
    """
    n = max(1, problem.options.starts if starts is None else starts)
    guesses = start_guesses(problem, n)
    t0 = time.perf_counter()
    reach = reachable_distance(problem)
    results = []
    if reach:
        for g in guesses:
            results.append(solve_from(problem, *g))
            if progress:
                progress(len(results), len(guesses))
    best = _best(results) if results else None
    reason = "" if reach else "the tip is farther from the base than the tube is long"
    if best is None or not best.converged:
        near = solve_from(problem, *guesses[0], closest=True)
        retry = None
        if reach and near.metrics["tip_error"] <= CLOSE_ENOUGH * problem.diameter:
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
    best.stats["starts"] = len(results)
    best.stats["start_objectives"] = [r.stats["objective"] for r in results]
    best.stats["start_status"] = [r.status for r in results]
    best.stats["best_start"] = next(k for k, r in enumerate(results) if r is best)
    if reason:
        best.stats["infeasible_reason"] = reason
    best.solve_time_s = time.perf_counter() - t0
    best.iterations = sum(r.iterations for r in results)
    best.metrics["reachable"] = float(best.converged)
    return best


def _best(results):
    def rank(r):
        return (0 if r.converged else 1, r.stats["objective"] if r.converged else r.metrics["tip_error"])

    best_rank = min(rank(r) for r in results)
    return next(r for r in results if rank(r)[0] == best_rank[0] and rank(r)[1] <= best_rank[1] * (1 + 1e-9) + 1e-15)


def write_tip_archive(path, problem_file, result: Result) -> None:
    """The standard archive with run ``/runs/tip`` plus /tip/position (and /tip/direction when given)."""
    from vine_nlp.io.archive import Archive, write_archive

    problem = problem_file.problem
    extra = {"tip/position": problem.position}
    if problem.direction is not None:
        extra["tip/direction"] = problem.direction
    archive = Archive(
        name=problem_file.name, kind="tip", source=problem_file.source, diameter=problem.diameter,
        units=problem_file.units, runs={RUN: result}, extra=extra,
    )
    write_archive(path, archive)


def report_lines(result: Result, problem: TipProblem, units: str) -> list[str]:
    """The CLI's lines: status and tip error, direction error, actuation."""
    m = result.metrics
    reach = "reachable" if result.converged else ("NOT reachable" if result.status == "infeasible" else "not solved")
    lines = [
        f"{RUN}: {result.status}, tip {reach}, tip error {m['tip_error']:.4g} {units}, "
        f"solve time {result.solve_time_s:.3f} s, {result.iterations} iterations"
    ]
    if result.stats.get("closest_approach"):
        lines[0] += " (nearest approach: " + result.stats.get("infeasible_reason", "") + ")"
    if "direction_error" in m:
        lines.append(f"  direction error {math.degrees(m['direction_error']):.4g} deg")
    lines.append(
        f"  objective ({problem.objective}) {result.stats['objective_actuation']:.6g}; "
        f"contraction sum (1-lambda) dl = {m['actuation_contraction']:.4g} {units}, "
        f"actuator turning = {m['actuation_turning']:.4g} rad, tube length {m['tube_length']:.4g} {units}"
    )
    return lines
