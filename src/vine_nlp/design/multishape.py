"""Multi-shape sPAM design: ONE routing, K shapes at K pressures (paper, Conclusion).

An sPAM contracts its whole actuator line to one ratio lambda that the pressure
sets. One routing theta_j with segment lengths dl_j is shared by K chains; chain k
uses contraction level lambda_k (one scalar per level, bounded [lambda_min, 1],
free or fixed by the problem) and should take the shape of target k.

Base pose: the K shapes grow from the SAME physical base, so by default ONE base
pose (6 variables) is shared by all K chains: the routing must then also explain
how the shapes differ relative to each other, which is what a user measuring one
robot at several pressures wants. ``shared_pose=False`` gives each level its own
pose (targets measured or drawn in different frames).

One NLP over all K chains, multiple shooting per chain exactly as in
``design.nlp``: the frames at the segment ends of every chain are variables,
created in stage order (theta_j, dl_j, then the K frames T^{j+1}_w(k)), so the
KKT matrix stays block-banded; ``nlp.segment_function(n)`` is mapped over the
K M (segment, level) pairs. Lengths are scaled by D.

Objective (dimensionless):
  J = (1/K) sum_k (1/N) sum_i |r_k(i) - r_dk(i)|^2 / D^2 + w_theta (1/L) int (D dtheta/ds)^2 ds,
the smoothness term as in ``design.nlp`` (on the mean of the targets' chord lengths).

Initialization: the geometric guess (``design.common.geometric_guess``) of the
target of the most actuated level (the fixed smallest lambda when all levels are
fixed, else the target with the shortest chord length: the center line shortens
as lambda drops), free lambda_k from the chord length of target k (the chord
length of the shared routing at lambda_k equals it), frames on each level's own
target; then a multi-start over the mirrored side and seeded perturbations
(lambda spread between lambda_min and 1 in chord order, theta perturbed).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.design.common import (
    LENGTH_FACTOR,
    Pairing,
    evaluate,
    frames12,
    geometric_guess,
    ipopt_options,
    ipopt_status,
    pair_points,
    run_ipopt,
    solver_stats,
)
from vine_nlp.design.nlp import segment_function
from vine_nlp.design.problem import MultiShapeProblem, Routing
from vine_nlp.design.result import Result, Shape, routing_metrics
from vine_nlp.model.helix import center_rates
from vine_nlp.model.segment import so3_exp

RUN = "multishape"

# ---------------------------------------------------------------- result


@dataclass(eq=False)
class MultiShapeResult(Result):
    """A Result whose ``routing``/``shape`` are level 0's (so generic writers and readers work),
    plus the shared routing's K levels, K poses, K shapes and per-level metrics.

    ``metrics`` holds the overall figures: rmse over all points of all levels,
    max_error the largest of all, plus tv_theta, tv_lambda.
    """

    levels: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (K,) lambda_k
    fixed: tuple = ()  # K booleans: lambda_k was fixed by the problem
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))  # (K, 4, 4) T^0_w of each level
    shapes: list = field(default_factory=list)  # K Shapes, row i pairs with target row i
    level_metrics: list = field(default_factory=list)  # K dicts: rmse, max_error
    shared_pose: bool = True

    @property
    def count(self) -> int:
        return int(np.size(self.levels))

    def level_routing(self, k: int) -> Routing:
        r = self.routing
        return Routing(r.theta, np.full(r.segments, float(self.levels[k])), r.length, self.poses[k])

    def level_result(self, k: int) -> Result:
        """Level k as a plain single-shape Result."""
        return Result(
            method=self.method,
            routing=self.level_routing(k),
            shape=self.shapes[k],
            status=self.status,
            solve_time_s=self.solve_time_s,
            iterations=self.iterations,
            metrics=dict(self.level_metrics[k]),
            stats=dict(self.stats),
            diameter=self.diameter,
        )


# ---------------------------------------------------------------- the NLP


@dataclass(frozen=True)
class _Layout:
    M: int
    K: int
    shared_pose: bool

    @property
    def poses(self) -> int:
        return 1 if self.shared_pose else self.K

    @property
    def lam(self) -> slice:
        return slice(6 * self.poses, 6 * self.poses + self.K)

    @property
    def stages(self) -> int:
        return 6 * self.poses + self.K

    @property
    def width(self) -> int:
        return 2 + 12 * self.K  # theta_j, dl_j, K frames T^{j+1}_w

    @property
    def size(self) -> int:
        return self.stages + self.M * self.width


class MultiShapeSolver:
    """The multi-shape NLP of one structure (M segments, n points per segment, K levels, pose sharing)."""

    def __init__(self, M: int, n: int, K: int, shared_pose: bool, max_iter: int = 3000, tol: float = 1e-8):
        t0 = time.perf_counter()
        self.M, self.n, self.K, self.shared_pose = M, n, K, shared_pose
        lay = self.layout = _Layout(M, K, shared_pose)
        C = K * M  # (segment, level) pairs, column c = j K + k
        x = ca.MX.sym("x", lay.size)
        P_tgt = ca.MX.sym("target", 3, n * C)  # paired target points (scaled), slot c n + i
        P_w = ca.MX.sym("w", 1, n * C)  # weights (0 for unused slots), 1 / (N K)
        P_u = ca.MX.sym("u", n, C)  # fractions of each slot
        P_tip = ca.MX.sym("tip", 3, K)
        P_wtip = ca.MX.sym("wtip", 1, K)
        P_R0 = ca.MX.sym("R0", 9, lay.poses)  # rotations of the guess: poses are rotation vectors relative to them
        P_smooth = ca.MX.sym("smooth")
        P_h = ca.MX.sym("h", max(M - 1, 1))
        P_L = ca.MX.sym("L")
        params = [P_tgt, P_w, P_u, P_tip, P_wtip, P_R0, P_smooth, P_h, P_L]
        self._param_shapes = [(p.size1(), p.size2()) for p in params]

        X0 = []
        for q in range(lay.poses):
            R = ca.mtimes(ca.reshape(P_R0[:, q], 3, 3), so3_exp(x[6 * q : 6 * q + 3]))
            X0.append(ca.vertcat(ca.vec(R), x[6 * q + 3 : 6 * q + 6]))
        X0 = ca.repmat(X0[0], 1, K) if shared_pose else ca.horzcat(*X0)
        lam = x[lay.lam]
        stages = ca.reshape(x[lay.stages :], lay.width, M)
        theta, dl = stages[0, :], stages[1, :]
        Xnext = ca.reshape(stages[2:, :], 12, C)
        Xstart = ca.horzcat(X0, Xnext[:, : K * (M - 1)])
        TH = ca.reshape(ca.repmat(theta, K, 1), 1, C)
        DL = ca.reshape(ca.repmat(dl, K, 1), 1, C)
        LAM = ca.reshape(ca.repmat(lam, 1, M), 1, C)
        F = segment_function(n).map(C, "serial")
        Xn, pts = F(Xstart, TH, LAM, DL, P_u)
        g = ca.vec(Xn - Xnext)
        err = pts - P_tgt
        tips = Xnext[9:, K * (M - 1) :]
        fit = ca.sum2(P_w * ca.sum1(err * err)) + ca.sum2(P_wtip * ca.sum1((tips - P_tip) ** 2))
        smooth = P_smooth * ca.sum1(ca.diff(theta.T) ** 2 / P_h) / P_L if M > 1 else ca.MX(0)
        p = ca.vertcat(*[ca.vec(q) for q in params])
        self.solver = ca.nlpsol("vine_nlp_multishape", "ipopt", {"x": x, "p": p, "f": fit + smooth, "g": g}, ipopt_options(max_iter, tol))
        self._terms = ca.Function("terms", [x, p], [fit, smooth])
        self.build_time_s = time.perf_counter() - t0

    def pack_params(self, values) -> np.ndarray:
        return np.concatenate([np.asarray(v, float).reshape(s, order="F").ravel(order="F") for v, s in zip(values, self._param_shapes)])

    def pack_x(self, poses, lam, theta, dl, frames) -> np.ndarray:
        """poses: list of (w_rot, p0); frames: K arrays (12, M+1)."""
        lay = self.layout
        x = np.zeros(lay.size)
        for q, (w, p0) in enumerate(poses[: lay.poses]):
            x[6 * q : 6 * q + 3], x[6 * q + 3 : 6 * q + 6] = w, p0
        x[lay.lam] = lam
        stages = np.vstack([np.atleast_2d(theta), np.atleast_2d(dl)] + [f[:, 1:] for f in frames])
        x[lay.stages :] = stages.ravel(order="F")
        return x

    def unpack_x(self, x):
        lay = self.layout
        poses = [(x[6 * q : 6 * q + 3], x[6 * q + 3 : 6 * q + 6]) for q in range(lay.poses)]
        stages = x[lay.stages :].reshape(lay.width, self.M, order="F")
        return poses, x[lay.lam].copy(), stages[0].copy(), stages[1].copy()

    def bounds(self, lam_lo, lam_hi, theta_max, dl_lo, dl_hi):
        lay = self.layout
        lbx, ubx = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
        lbx[lay.lam], ubx[lay.lam] = lam_lo, lam_hi
        W, s = lay.width, lay.stages
        lbx[s : s + W * self.M : W], ubx[s : s + W * self.M : W] = -theta_max, theta_max
        lbx[s + 1 : s + W * self.M : W], ubx[s + 1 : s + W * self.M : W] = dl_lo, dl_hi
        return lbx, ubx


@lru_cache(maxsize=8)
def get_solver(M: int, n: int, K: int, shared_pose: bool, max_iter: int = 3000, tol: float = 1e-8) -> MultiShapeSolver:
    """Cached per structure: building costs more than one solve."""
    return MultiShapeSolver(M, n, K, shared_pose, max_iter, tol)


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
        if total(m) < arc:
            a = m
        else:
            b = m
    return 0.5 * (a + b)


def reference_level(problem: MultiShapeProblem, pairings) -> int:
    """The most actuated level: the smallest fixed lambda if all are fixed, else the shortest target."""
    if all(v is not None for v in problem.levels):
        return int(np.argmin(problem.levels))
    return int(np.argmin([p.chord[-1] for p in pairings]))


def initial_guess(problem: MultiShapeProblem, pairings, flip: float = 1.0) -> MultiGuess:
    """Geometric guess of the most actuated target; free lambdas from the chord lengths; frames on every target."""
    a = problem.actuator
    K = problem.count
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
    frames, poses = [], []
    for k in range(K):
        gk = g if k == r else geometric_guess(problem.level_problem(k), pairings[k], flip)
        fr = gk.frames.copy()
        frames.append(fr)
        poses.append(gk.initial_pose.copy())
    if problem.shared_pose:
        poses = [g.initial_pose.copy()]
        for fr in frames:
            fr[0] = g.initial_pose
    return MultiGuess(theta, length, levels, poses, frames)


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
        theta = np.clip(base.theta + rng.normal(0.0, 0.25, base.theta.shape), -a.theta_max, a.theta_max)
        spread = a.lambda_min + (1.0 - a.lambda_min) * (rank + rng.uniform(0.2, 0.8, problem.count)) / problem.count
        levels = np.array([v if v is not None else spread[k] for k, v in enumerate(problem.levels)])
        guesses.append(MultiGuess(theta, base.length.copy(), levels, [p.copy() for p in base.poses], [f.copy() for f in base.frames]))
    return guesses


# ---------------------------------------------------------------- solve


def _level_bounds(problem: MultiShapeProblem):
    lo = np.array([problem.actuator.lambda_min if v is None else v for v in problem.levels])
    hi = np.array([1.0 if v is None else v for v in problem.levels])
    return lo, hi


def solve_from(problem: MultiShapeProblem, guess: MultiGuess, pairings=None) -> MultiShapeResult:
    """One IPOPT solve of the multi-shape NLP from ``guess``."""
    o, D, K = problem.options, problem.diameter, problem.count
    pairings = pairings or _pairings(problem)
    M, n = pairings[0].segments, pairings[0].n
    solver = get_solver(M, n, K, problem.shared_pose, o.max_iter, o.tol)
    N = problem.targets[0].shape[0]
    C = K * M
    slots = np.zeros((3, n * C))
    w = np.zeros(n * C)
    u = np.zeros((n, C))
    tips = np.zeros((3, K))
    i = np.arange(N - 1)  # the tip pairs with the last frame
    for k, (tgt, pr) in enumerate(zip(problem.targets, pairings)):
        within = i - pr.bounds[pr.seg[i]]
        c = pr.seg[i] * K + k
        slots[:, c * n + within] = tgt[i].T / D
        w[c * n + within] = 1.0 / (N * K)
        u[within, c] = pr.frac[i]
        tips[:, k] = tgt[-1] / D
    chord = np.mean([pr.chord for pr in pairings], axis=0) / D
    b = pairings[0].bounds
    mids = 0.5 * (chord[b[:-1]] + chord[b[1:]])
    h = np.diff(mids) if M > 1 else np.ones(1)
    R0 = np.column_stack([P[:3, :3].ravel(order="F") for P in guess.poses[: solver.layout.poses]])
    p = solver.pack_params([slots, w, u, tips, np.full(K, 1.0 / (N * K)), R0, o.smooth_theta, h, chord[-1]])

    fr = []
    for f in guess.frames:
        f = f.copy()
        f[:, :3, 3] /= D
        fr.append(frames12(f))
    x0 = solver.pack_x([(np.zeros(3), P[:3, 3] / D) for P in guess.poses], guess.levels, guess.theta, guess.length / D, fr)
    seg_chord = np.max([pr.segment_chord for pr in pairings], axis=0) / D
    lam_lo, lam_hi = _level_bounds(problem)
    lbx, ubx = solver.bounds(lam_lo, lam_hi, problem.actuator.theta_max, LENGTH_FACTOR[0] * seg_chord, LENGTH_FACTOR[1] * seg_chord)
    x0 = np.clip(x0, lbx, ubx)
    sol, x, st, solve_time = run_ipopt(solver.solver, x0, p, lbx, ubx)
    poses, levels, theta, dl = solver.unpack_x(x)
    T = []
    for q, (wr, p0) in enumerate(poses):
        P = np.eye(4)
        P[:3, :3] = guess.poses[q][:3, :3] @ so3_exp(wr)
        P[:3, 3] = p0 * D
        T.append(P)
    T = np.array(T * K if problem.shared_pose else T)
    fit, smooth = (float(v) for v in solver._terms(x, p))
    status = ipopt_status(st, x)
    stats = solver_stats(st, sol, solver.build_time_s) | {
        "objective_fit": fit,
        "objective_smooth": smooth,
        "segments": M,
        "points_per_segment": n,
        "levels": K,
        "shared_pose": problem.shared_pose,
        "fixed_levels": [v is not None for v in problem.levels],
        "smooth_theta": o.smooth_theta,
        "tol": o.tol,
        "max_iter": o.max_iter,
        "max_constraint_violation": float(np.abs(np.array(sol["g"])).max()) if M else 0.0,
    }
    return assemble(problem, theta, dl * D, levels, T, pairings, status=status, solve_time_s=solve_time,
                    iterations=int(st.get("iter_count", 0)), stats=stats)


def assemble(problem: MultiShapeProblem, theta, length, levels, poses, pairings=None, **kw) -> MultiShapeResult:
    """Evaluate a shared routing at its K levels against the K targets: the MultiShapeResult."""
    pairings = pairings or _pairings(problem)
    K = problem.count
    levels = np.asarray(levels, float).reshape(K)
    poses = np.asarray(poses, float).reshape(K, 4, 4)
    per = [evaluate(problem.level_problem(k), Routing(theta, np.full(np.size(theta), levels[k]), length, poses[k]), pairings[k], RUN)
           for k in range(K)]
    d2 = np.concatenate([np.sum((r.shape.center - t) ** 2, axis=1) for r, t in zip(per, problem.targets)])
    level_metrics = [{"rmse": r.metrics["rmse"], "max_error": r.metrics["max_error"], "lambda": float(levels[k])} for k, r in enumerate(per)]
    metrics = {"rmse": float(np.sqrt(d2.mean())), "max_error": float(np.sqrt(d2.max()))} | routing_metrics(per[0].routing)
    return MultiShapeResult(
        method=RUN,
        routing=per[0].routing,
        shape=per[0].shape,
        metrics=metrics,
        diameter=problem.diameter,
        levels=levels,
        fixed=tuple(v is not None for v in problem.levels),
        poses=poses,
        shapes=[r.shape for r in per],
        level_metrics=level_metrics,
        shared_pose=problem.shared_pose,
        **kw,
    )


def design_multishape(problem: MultiShapeProblem, starts: int | None = None, progress=None) -> MultiShapeResult:
    """One sPAM routing for K shapes at K contraction levels; multi-start (``options.starts``), lowest objective wins."""
    if problem.actuator.kind != "spam":
        raise ValueError("multi-shape design needs an sPAM actuator (one lambda per level)")
    pairings = _pairings(problem)
    n_starts = max(1, problem.options.starts if starts is None else starts)
    guesses = start_guesses(problem, pairings, n_starts)
    t0 = time.perf_counter()
    results = []
    for g in guesses:
        results.append(solve_from(problem, g, pairings))
        if progress:
            progress(len(results), len(guesses))

    def rank(r):
        return (0 if r.converged else 1, r.stats["objective"])

    best_rank = min(rank(r) for r in results)
    k_best = next(k for k, r in enumerate(results) if rank(r)[0] == best_rank[0] and rank(r)[1] <= best_rank[1] * (1 + 1e-9) + 1e-15)
    best = results[k_best]
    best.stats["starts"] = len(results)
    best.stats["start_objectives"] = [r.stats["objective"] for r in results]
    best.stats["best_start"] = k_best
    best.solve_time_s = time.perf_counter() - t0
    best.iterations = sum(r.iterations for r in results)
    return best


# ---------------------------------------------------------------- archive


def write_multishape_archive(path, problem_file, result: MultiShapeResult) -> None:
    """Write a multi-shape design archive atomically (the contract's layout, extended).

    Standard part (old readers work): /problem (kind "multishape"), /tube,
    /target/points = target 0, /runs/multishape/{design,shape,metrics,solver} with
    design/lambda = level 0 repeated and shape = level 0's shape; metrics rmse and
    max_error are over all levels. Extension: /runs/multishape/design/levels (K,),
    /runs/multishape/levels/<k>/{shape/{center,inner,outer}, initial_pose} with attrs
    lambda, fixed and metrics attrs (rmse, max_error), /targets/<k>/points.
    ``problem_file`` is a ProblemFile (name, source, units, problem) of a MultiShapeProblem.
    """
    import h5py

    from vine_nlp.io.archive import Archive, write_archive, write_atomic

    problem = problem_file.problem
    archive = Archive(
        name=problem_file.name,
        kind="multishape",
        source=problem_file.source,
        diameter=problem.diameter,
        units=problem_file.units,
        target=problem.targets[0],
        runs={RUN: result},
        extra={f"targets/{k}/points": t for k, t in enumerate(problem.targets)},
    )

    def write(tmp):
        write_archive(tmp, archive)  # the standard layout (itself atomic onto tmp)
        with h5py.File(tmp, "a") as h5:
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

    write_atomic(path, write)


def read_multishape_archive(path):
    """(Archive, MultiShapeResult, targets): the archive as the generic reader sees it, the
    full multi-shape result (levels, poses, shapes, per-level metrics) and the K targets."""
    import h5py

    from vine_nlp.io.archive import load_archive

    a = load_archive(path)
    base = a.runs[RUN]
    with h5py.File(path, "r") as h5:
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
    r = MultiShapeResult(
        method=base.method, routing=base.routing, shape=base.shape, status=base.status, solve_time_s=base.solve_time_s,
        iterations=base.iterations, metrics=base.metrics, stats=base.stats, diameter=base.diameter,
        levels=levels, fixed=tuple(fixed), poses=np.array(poses), shapes=shapes, level_metrics=lm, shared_pose=shared,
    )
    return a, r, targets


def plot_multishape(archive_path, fig_path):
    """Figure of a multi-shape archive (see ``vine_nlp.front.multishape_plot``)."""
    from vine_nlp.front.multishape_plot import plot_multishape_file

    return plot_multishape_file(archive_path, fig_path)


def report_lines(result: MultiShapeResult, units: str) -> list[str]:
    """The CLI's lines: one overall, one per level."""
    m = result.metrics
    lines = [
        f"{RUN}: {result.status}, {result.count} levels, RMSE {m['rmse']:.4g} {units}, max error {m['max_error']:.4g} {units}, "
        f"solve time {result.solve_time_s:.3f} s, {result.iterations} iterations"
    ]
    for k in range(result.count):
        lm = result.level_metrics[k]
        tag = "fixed" if result.fixed and result.fixed[k] else "free"
        lines.append(f"  level {k}: lambda {result.levels[k]:.6g} ({tag}), RMSE {lm['rmse']:.4g} {units}, max error {lm['max_error']:.4g} {units}")
    return lines


__all__ = [
    "MultiShapeResult",
    "MultiShapeSolver",
    "design_multishape",
    "write_multishape_archive",
    "read_multishape_archive",
    "plot_multishape",
    "report_lines",
    "get_solver",
    "start_guesses",
    "solve_from",
    "assemble",
]
