"""Inverse design as ONE nonlinear program, solved with IPOPT.

Multiple shooting over the chain (paper eq. iterativeTransform): the frames
T^j_w at the segment ends are variables, and each segment adds the continuity
constraint T^{j+1}_w = T^j_w T^{j+1}_j(theta_j, lam_j, dl_j). Variables are
created in stage order (pose, then theta_j, lam_j, dl_j, T^{j+1}_w per segment),
so the constraint Jacobian and the Lagrangian Hessian are block-banded and the
cost of an IPOPT iteration grows linearly with the number of segments.

Everything is scaled by the tube diameter D inside the NLP (D = 1), so one
solver serves every tube and the tolerances mean the same thing for every problem.

Objective (all terms dimensionless):
  J = (1/N) sum_k w_k |r_c(k) - r_cd(k)|^2 / D^2
      + w_theta (1/L) int (D dtheta/ds)^2 ds + w_lambda (1/L) int (D dlambda/ds)^2 ds,
the derivative integrals taken on the target's arc length so the penalties mean the
same whatever the discretization (they replace the paper's low-pass filter).

The solver is built once per structure (M segments, n points per segment,
shared or per-segment lambda) and cached; target, weights and guesses are
parameters, so multi-start and sweeps reuse it. Its constraint Jacobian and
Lagrangian Hessian are assembled from one segment's SX derivatives
(``_separable_derivatives``). Targets with corners have many local minima:
``basin_hops`` searches them.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.design.common import (
    LENGTH_FACTOR,
    Guess,
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
from vine_nlp.design.problem import DesignProblem, Routing
from vine_nlp.design.result import Result
from vine_nlp.model.helix import center_rates
from vine_nlp.model.segment import so3_exp, twist_parts


@lru_cache(maxsize=8)
def segment_function(n: int) -> ca.Function:
    """One segment, SX: (frame X_j (12), theta, lam, dl, fractions u (n)) -> (X_{j+1}, points (3 x n))."""
    X = ca.SX.sym("X", 12)  # rotation column-major (9), then position (3)
    theta, lam, dl = ca.SX.sym("theta"), ca.SX.sym("lam"), ca.SX.sym("dl")
    u = ca.SX.sym("u", n)
    R = ca.reshape(X[:9], 3, 3)
    p = X[9:]
    kappa_c, tau_c, lambda_c = center_rates(theta, lam, 1.0)
    sigma = dl * lambda_c
    Rs, ps = twist_parts(kappa_c, tau_c, sigma)
    Rstep = ca.vertcat(*[ca.horzcat(*row) for row in Rs])
    Xn = ca.vertcat(ca.vec(ca.mtimes(R, Rstep)), p + ca.mtimes(R, ca.vertcat(*ps)))
    pts = []
    for i in range(n):
        # point positions only: the rotation entries of the partial motion are not needed
        _, q = twist_parts(kappa_c, tau_c, u[i] * sigma)
        pts.append(p + ca.mtimes(R, ca.vertcat(*q)))
    return ca.Function("segment", [X, theta, lam, dl, u], [Xn, ca.horzcat(*pts)], ["X", "theta", "lam", "dl", "u"], ["Xn", "pts"])


@dataclass
class _Layout:
    """Where each quantity lives in the decision vector (stage order)."""

    M: int
    shared: bool

    @property
    def pose(self):
        return slice(0, 6)  # rotation vector (relative to the guess's rotation), position

    def stage(self, j):
        start = 6 + (1 if self.shared else 0) + j * self.width
        return start

    @property
    def width(self):
        return (3 if not self.shared else 2) + 12

    @property
    def size(self):
        return 6 + (1 if self.shared else 0) + self.M * self.width


class NLPSolver:
    """The NLP of one structure, built once; ``solve`` runs IPOPT from a given guess."""

    def __init__(
        self, M: int, n: int, shared_lambda: bool, max_iter: int = 3000, tol: float = 1e-8, warm: bool = False, hessian: str = "exact"
    ):
        t0 = time.perf_counter()
        self.M, self.n, self.shared = M, n, shared_lambda
        lay = self.layout = _Layout(M, shared_lambda)
        x = ca.MX.sym("x", lay.size)
        # parameters
        P_tgt = ca.MX.sym("target", 3, n * M)  # paired target points (scaled), slot-major per segment
        P_w = ca.MX.sym("w", 1, n * M)  # pairing weights (0 for unused slots), already / N
        P_u = ca.MX.sym("u", n, M)  # fractions of each slot
        P_tip = ca.MX.sym("tip", 3)
        P_wtip = ca.MX.sym("wtip")
        P_R0 = ca.MX.sym("R0", 9)  # rotation of the guess: the pose is a rotation vector relative to it
        P_smooth = ca.MX.sym("smooth", 2)  # w_theta, w_lambda
        P_h = ca.MX.sym("h", max(M - 1, 1))  # arc length between segment middles (scaled)
        P_L = ca.MX.sym("L")  # total arc length (scaled)
        params = [P_tgt, P_w, P_u, P_tip, P_wtip, P_R0, P_smooth, P_h, P_L]
        self._param_shapes = [(p.size1(), p.size2()) for p in params]

        w_rot, p0 = x[0:3], x[3:6]
        R0 = ca.mtimes(ca.reshape(P_R0, 3, 3), so3_exp(w_rot))
        X0 = ca.vertcat(ca.vec(R0), p0)
        off = 6
        lam_shared = None
        if shared_lambda:
            lam_shared = x[off]
            off += 1
        W = lay.width
        stages = ca.reshape(x[off:], W, M)
        theta = stages[0, :]
        if shared_lambda:
            lam = ca.repmat(lam_shared, 1, M)
            dl = stages[1, :]
            Xnext = stages[2:, :]
        else:
            lam = stages[1, :]
            dl = stages[2, :]
            Xnext = stages[3:, :]
        Xstart = ca.horzcat(X0, Xnext[:, : M - 1])
        F = segment_function(n).map(M, "serial")
        Xn, pts = F(Xstart, theta, lam, dl, P_u)
        g = ca.vec(Xn - Xnext)
        err = pts - P_tgt
        fit = ca.sum2(P_w * ca.sum1(err * err)) + P_wtip * ca.sumsqr(Xnext[9:, M - 1] - P_tip)
        smooth = 0
        if M > 1:
            smooth = P_smooth[0] * ca.sum1(ca.diff(theta.T) ** 2 / P_h) / P_L
            if not shared_lambda:
                smooth += P_smooth[1] * ca.sum1(ca.diff(lam.T) ** 2 / P_h) / P_L
        f = fit + smooth
        p = ca.vertcat(*[ca.vec(q) for q in params])
        opts = ipopt_options(max_iter, tol, warm)
        # the quadratic terms (tip, smoothness) have the same Hessian in both variants
        opts["jac_g"], opts["hess_lag"] = _separable_derivatives(
            lay, n, x, p, g, smooth + P_wtip * ca.sumsqr(Xnext[9:, M - 1] - P_tip), [P_tgt, P_w, P_u],
            ca.reshape(P_R0, 3, 3), (Xstart, theta, lam, dl), hessian,
        )
        self.solver = ca.nlpsol("vine_nlp", "ipopt", {"x": x, "p": p, "f": f, "g": g}, opts)
        self._terms = ca.Function("terms", [x, p], [fit, smooth])
        self.build_time_s = time.perf_counter() - t0

    def pack_params(self, values) -> np.ndarray:
        return np.concatenate([np.asarray(v, float).reshape(s, order="F").ravel(order="F") for v, s in zip(values, self._param_shapes)])

    def pack_x(self, w_rot, p0, theta, lam, dl, frames12) -> np.ndarray:
        lay = self.layout
        x = np.zeros(lay.size)
        x[0:3], x[3:6] = w_rot, p0
        off = 6
        if self.shared:
            x[off] = float(np.mean(lam))
            off += 1
            cols = [theta, dl]
        else:
            cols = [theta, lam, dl]
        stages = np.vstack([np.atleast_2d(c) for c in cols] + [frames12[:, 1:]])
        x[off:] = stages.ravel(order="F")
        return x

    def unpack_x(self, x):
        lay = self.layout
        off = 6
        lam_shared = None
        if self.shared:
            lam_shared = x[off]
            off += 1
        stages = x[off:].reshape(lay.width, self.M, order="F")
        theta = stages[0]
        if self.shared:
            lam = np.full(self.M, lam_shared)
            dl = stages[1]
        else:
            lam, dl = stages[1], stages[2]
        return x[0:3], x[3:6], theta, lam, dl

    def bounds(self, lo, hi):
        """Box bounds in stage order from per-segment (theta, lam, dl) bounds (scaled)."""
        lay = self.layout
        lbx = np.full(lay.size, -np.inf)
        ubx = np.full(lay.size, np.inf)
        off = 6
        if self.shared:
            lbx[off], ubx[off] = lo[1][0], hi[1][0]
            off += 1
            rows = [0, 2]
        else:
            rows = [0, 1, 2]
        W = lay.width
        for k, r in enumerate(rows):
            lbx[off + k : off + W * self.M : W] = lo[r]
            ubx[off + k : off + W * self.M : W] = hi[r]
        return lbx, ubx


@lru_cache(maxsize=8)
def _segment_derivatives(n: int, first: bool) -> tuple[ca.Function, ca.Function, ca.Function]:
    """One segment's derivatives, SX, with respect to its local variables: the Jacobian of
    X_{j+1}, and the upper triangle of the Hessian of its share of the Lagrangian, exact
    and Gauss-Newton.

    The share is sigma * sum_i w_i |r_i - r_d,i|^2 + lam_g . X_{j+1}(X_j, theta, lam, dl):
    the rest of the Lagrangian is linear in x (the continuity rows' -X_{j+1}) or a
    quadratic of few variables (smoothness, tip). Local variables: the segment's start
    frame X_j (12), or for the first segment the pose (rotation vector relative to
    R0g, position), then theta, lam, dl.
    """
    seg = segment_function(n)
    theta, lam, dl = ca.SX.sym("theta"), ca.SX.sym("lam"), ca.SX.sym("dl")
    u, tgt, w = ca.SX.sym("u", n), ca.SX.sym("tgt", 3, n), ca.SX.sym("w", 1, n)
    lam_g, sigma = ca.SX.sym("lam_g", 12), ca.SX.sym("sigma")
    R0g = ca.SX.sym("R0g", 3, 3)
    if first:
        head = ca.SX.sym("pose", 6)
        X = ca.vertcat(ca.vec(ca.mtimes(R0g, so3_exp(head[:3]))), head[3:])
    else:
        X = head = ca.SX.sym("X", 12)
    Xn, pts = seg(X, theta, lam, dl, u)
    err = pts - tgt
    ell = sigma * ca.sum2(w * ca.sum1(err * err)) + ca.dot(lam_g, Xn)
    v = ca.vertcat(head, theta, lam, dl)
    H, _ = ca.hessian(ell, v)
    args = [head, theta, lam, dl, u, tgt, w, lam_g, sigma, R0g]
    # Gauss-Newton: sigma * 2 J^T J of the weighted residuals, the constraint curvature left out
    Jr = ca.jacobian(ca.vec(ca.repmat(ca.sqrt(w), 3, 1) * err), v)
    gn = sigma * ca.triu(2 * ca.mtimes(Jr.T, Jr))
    # separate functions: an MX call evaluates every output of its function
    jac = ca.Function("segment_jac", [head, theta, lam, dl, u, R0g], [ca.jacobian(Xn, v)])
    return jac, ca.Function("segment_hess", args, [ca.triu(H)]), ca.Function("segment_gn", args, [gn])


def _scatter(shape, blocks, symmetric: bool):
    """Sparse MX of ``shape`` from per-segment dense-pattern blocks.

    ``blocks``: (values, pattern, rows, cols) with ``values`` the horizontally
    concatenated block outputs of a mapped call, ``pattern`` one block's sparsity and
    ``rows``/``cols`` per block the global index of each local row/column. Entries
    that land on the same place (a shared lambda is a variable of every segment) are
    summed; ``symmetric`` stores each entry in the upper triangle.
    """
    R, C, V = [], [], []
    for values, pattern, rows, cols in blocks:
        r, c = (np.asarray(v) for v in pattern.get_triplet())
        for ri, ci in zip(rows, cols):
            a, b = ri[r], ci[c]
            if symmetric:
                a, b = np.minimum(a, b), np.maximum(a, b)
            R.append(a)
            C.append(b)
        V.append(values.nz[:])
    R, C, V = np.concatenate(R), np.concatenate(C), ca.vertcat(*V)
    key = C.astype(np.int64) * shape[0] + R  # column-major: the order of a CasADi sparsity's nonzeros
    uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    single = counts[inverse] == 1
    order = np.flatnonzero(single)[np.argsort(key[single], kind="stable")]
    out = ca.MX(ca.Sparsity.triplet(*shape, R[order].tolist(), C[order].tolist()), V[order.tolist()])
    for k in np.flatnonzero(counts > 1):
        at = np.flatnonzero(inverse == k)
        sp = ca.Sparsity.triplet(*shape, [int(R[at[0]])], [int(C[at[0]])])
        out = out + ca.MX(sp, ca.sum1(V[at.tolist()]))
    return out


def _separable_derivatives(lay: _Layout, n: int, x, p, g, quadratic, data, R0g, X, hessian: str = "exact"):
    """Jacobian of the constraints and Hessian of the Lagrangian (nlpsol's ``jac_g`` and
    ``hess_lag``; ``hessian`` "exact" or "gauss-newton"), assembled from one segment's SX
    derivatives mapped over the chain.

    CasADi's automatic MX derivatives colour the whole banded matrix and sweep the
    mapped segment function once per colour; here each segment's block is computed
    once (per-segment terms on their own variables, plus the continuity rows' constant
    -I and the Hessian of the quadratic terms ``quadratic``): measured, the exact
    Hessian about 4x and the Jacobian about 9x cheaper to evaluate, an IPOPT iteration
    about 2.5x cheaper (results/BENCHMARKS.md, "Derivatives"). The SX functions are
    built once per process (per points per segment, first or later segment), so the
    build does not grow with M.

    Gauss-Newton (f = |r|^2 with r the weighted residuals): H ~ 2 J^T J ignores the
    residuals' and the constraints' curvature; always positive semidefinite, cheap,
    linear convergence on large-residual targets.
    """
    M = lay.M
    P_tgt, P_w, P_u = data
    Xstart, theta, lam, dl = X
    sigma = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", g.size1())
    LG = ca.reshape(lam_g, 12, M)
    ith, ilam, idl = _stage_indices(lay)
    iframe = _frame_indices(lay)
    (j0, h0, g0), (jj, hj, gj) = _segment_derivatives(n, True), _segment_derivatives(n, False)
    if hessian == "gauss-newton":
        h0, hj = g0, gj
    cols = [np.r_[0:6, ith[0], ilam[0], idl[0]]] + [np.r_[iframe[:, j - 1], ith[j], ilam[j], idl[j]] for j in range(1, M)]
    rows = [np.arange(12 * j, 12 * j + 12) for j in range(M)]
    head = [x[0:6], theta[0], lam[0], dl[0], P_u[:, 0]]
    tail = [Xstart[:, 1:], theta[1:], lam[1:], dl[1:], P_u[:, 1:]]
    jac_blocks = [(j0(*head, R0g), j0.sparsity_out(0), rows[:1], cols[:1])]
    if M > 1:
        jac_blocks.append((jj.map(M - 1, "serial")(*tail, R0g), jj.sparsity_out(0), rows[1:], cols[1:]))
    # the continuity rows' -X_{j+1}: a constant -1 per row
    jac = _scatter((g.size1(), lay.size), jac_blocks, False) - ca.MX(
        ca.Sparsity.triplet(g.size1(), lay.size, list(range(12 * M)), iframe.T.ravel().tolist()), 1.0
    )
    jac_g = ca.Function("nlp_jac_g", [x, p], [g, jac], ["x", "p"], ["g", "jac_g_x"])
    hess_blocks = [(h0(*head, P_tgt[:, :n], P_w[:, :n], LG[:, 0], sigma, R0g), h0.sparsity_out(0), cols[:1], cols[:1])]
    if M > 1:
        vals = hj.map(M - 1, "serial")(*tail, P_tgt[:, n:], P_w[:, n:], LG[:, 1:], sigma, R0g)
        hess_blocks.append((vals, hj.sparsity_out(0), cols[1:], cols[1:]))
    hess = _scatter((lay.size, lay.size), hess_blocks, True) + ca.triu(ca.hessian(sigma * quadratic, x)[0])
    hess_lag = ca.Function("nlp_hess_l", [x, p, sigma, lam_g], [hess], ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
    return jac_g, hess_lag


def _stage_indices(lay: _Layout):
    """Indices in x of theta_j, lam_j, dl_j (arrays of length M)."""
    base = np.array([lay.stage(j) for j in range(lay.M)])
    if lay.shared:
        return base, np.full(lay.M, 6), base + 1
    return base, base + 1, base + 2


def _frame_indices(lay: _Layout):
    """Indices in x of the frame X_{j+1} (12 x M): the last 12 entries of stage j."""
    first = np.array([lay.stage(j) for j in range(lay.M)]) + lay.width - 12
    return first[None, :] + np.arange(12)[:, None]


@lru_cache(maxsize=16)
def get_solver(
    M: int, n: int, shared_lambda: bool, max_iter: int = 3000, tol: float = 1e-8, warm: bool = False, hessian: str = "exact"
) -> NLPSolver:
    """Cached solver per structure: building costs more than one solve."""
    return NLPSolver(M, n, shared_lambda, max_iter, tol, warm, hessian)


def nlp_parameters(problem: DesignProblem, pairing: Pairing, R0g: np.ndarray) -> list:
    """Values of NLPSolver's parameters for ``problem`` (scaled by D), in its order: targets per
    slot, weights 1/N, slot fractions, tip, guess rotation, smoothing weights, arc steps
    between segment middles, total arc length."""
    o = problem.options
    D = problem.diameter
    M, n = pairing.segments, pairing.n
    N = problem.target.shape[0]
    tgt = problem.target / D
    slots = np.zeros((3, n * M))
    w = np.zeros(n * M)
    u = np.zeros((n, M))
    k = np.arange(N - 1)  # the tip (last point) is paired with the last frame
    i = k - pairing.seg[k] * n
    slot = pairing.seg[k] * n + i
    slots[:, slot] = tgt[k].T
    w[slot] = 1.0 / N
    u[i, pairing.seg[k]] = pairing.frac[k]
    mids = 0.5 * (pairing.chord[pairing.bounds[:-1]] + pairing.chord[pairing.bounds[1:]]) / D
    h = np.diff(mids) if M > 1 else np.ones(1)
    Ltot = pairing.chord[-1] / D
    return [slots, w, u, tgt[-1], 1.0 / N, R0g.ravel(order="F"), [o.smooth_theta, o.smooth_lambda], h, Ltot]


# multi-start: objectives this close (relative) are the same optimum reached from different starts
TIE_RTOL = 1e-6
# "auto": Gauss-Newton first, capped at this many iterations, then the exact Hessian if it did not converge
AUTO_GN_MAX_ITER = 50


def solve_from(
    problem: DesignProblem, guess: Guess | None = None, pairing: Pairing | None = None, frames: str = "target", warm: bool = False
) -> Result:
    """One IPOPT solve of the inverse-design NLP for ``problem`` from ``guess`` (default: the geometric guess).

    frames="target" starts the shooting frames on the target (multiple shooting's
    advantage: the error does not accumulate along the chain in the first iterate);
    frames="chain" starts them on the chain of the guessed design. ``warm`` uses the
    solver variant that keeps a start close to the answer (IPOPT warm-start options).

    ``options.hessian``: "exact", "gauss-newton", or "auto" (default): Gauss-Newton is
    several times cheaper per iteration and converges on targets the model can follow
    closely; its answer is a true KKT point (IPOPT tests exact gradients). Where it
    does not converge within AUTO_GN_MAX_ITER iterations (large residuals: corners),
    the same start is solved again with the exact Hessian; where it stops at IPOPT's
    "acceptable" level, the exact Hessian polishes its answer (a warm start).
    """
    o = problem.options
    pairing = pairing or pair_points(problem.target, o.points_per_segment)
    guess = guess or geometric_guess(problem, pairing)
    if o.hessian != "auto":
        return _solve(problem, guess, pairing, frames, warm, o.hessian, o.max_iter)
    t0 = time.perf_counter()
    first = _solve(problem, guess, pairing, frames, warm, "gauss-newton", min(o.max_iter, AUTO_GN_MAX_ITER))
    if first.status == "optimal":
        first.stats["hessian"] = "gauss-newton"
        return first
    if first.status == "acceptable":
        second = _solve(problem, guess_from_routing(problem, pairing, first.routing), pairing, "chain", True, "exact", o.max_iter)
        second.stats["hessian"] = "exact, polishing gauss-newton's acceptable point"
    else:
        second = _solve(problem, guess, pairing, frames, warm, "exact", o.max_iter)
        second.stats["hessian"] = "exact (after gauss-newton did not converge)"
    second.iterations += first.iterations
    second.solve_time_s = time.perf_counter() - t0
    return second


def _solve(problem, guess, pairing, frames, warm, hessian, max_iter) -> Result:
    from vine_nlp.model import chain_frames

    o = problem.options
    D = problem.diameter
    M, n = pairing.segments, pairing.n
    shared = problem.actuator.shared_lambda
    t_build = time.perf_counter()
    solver = get_solver(M, n, shared, max_iter, o.tol, warm, hessian)
    build_time = time.perf_counter() - t_build

    R0g = guess.initial_pose[:3, :3]
    p = solver.pack_params(nlp_parameters(problem, pairing, R0g))

    if frames == "target":
        fr = guess.frames.copy()
        fr[0] = guess.initial_pose
    else:
        fr = chain_frames(guess.theta, guess.lam, guess.length, D, guess.initial_pose)
    fr = fr.copy()
    fr[:, :3, 3] /= D
    x0 = solver.pack_x(np.zeros(3), guess.initial_pose[:3, 3] / D, guess.theta, guess.lam, guess.length / D, frames12(fr))
    chord = pairing.segment_chord / D
    lo = (np.full(M, -problem.actuator.theta_max), np.full(M, problem.actuator.lambda_min), LENGTH_FACTOR[0] * chord)
    hi = (np.full(M, problem.actuator.theta_max), np.ones(M), LENGTH_FACTOR[1] * chord)
    lbx, ubx = solver.bounds(lo, hi)
    x0 = np.clip(x0, lbx, ubx)
    sol, x, st, solve_time = run_ipopt(solver.solver, x0, p, lbx, ubx)
    status = ipopt_status(st, x)
    w_rot, p0, theta, lam, dl = solver.unpack_x(x)
    T0 = np.eye(4)
    T0[:3, :3] = R0g @ so3_exp(w_rot)
    T0[:3, 3] = p0 * D
    routing = Routing(theta, lam, dl * D, T0)
    fit, smooth = (float(v) for v in solver._terms(x, p))
    return evaluate(
        problem,
        routing,
        pairing,
        "nlp",
        status=status,
        solve_time_s=solve_time,
        iterations=int(st.get("iter_count", 0)),
        stats=solver_stats(st, sol, solver.build_time_s if build_time > 1e-3 else 0.0)
        | {
            "objective_fit": fit,
            "objective_smooth": smooth,
            "segments": M,
            "points_per_segment": n,
            "smooth_theta": o.smooth_theta,
            "smooth_lambda": o.smooth_lambda,
            "tol": o.tol,
            "max_iter": max_iter,
            "hessian": hessian,
            "max_constraint_violation": float(np.abs(np.array(sol["g"])).max()) if M else 0.0,
        },
    )


def start_guesses(problem: DesignProblem, pairing: Pairing, starts: int) -> list[Guess]:
    """The starts of a multi-start, deterministic for a given ``options.seed``.

    Start 0 is the geometric guess; start 1 the same guess with the other choice of
    side at bending reversals (its mirror for planar targets); further starts perturb
    theta and lambda of start 0 or 1 randomly inside the bounds (the symmetry
    breaking and the spread that decide more than solver options do).
    """
    guesses = [geometric_guess(problem, pairing, +1.0)]
    if starts > 1:
        guesses.append(geometric_guess(problem, pairing, -1.0))
    rng = np.random.default_rng(problem.options.seed)
    a = problem.actuator
    for k in range(2, starts):
        base = guesses[k % 2]
        theta = np.clip(base.theta + rng.normal(0.0, 0.25, base.theta.shape), -a.theta_max, a.theta_max)
        lam = np.clip(base.lam + rng.normal(0.0, 0.1, base.lam.shape), a.lambda_min, 1.0)
        if a.shared_lambda:
            lam = np.full_like(lam, np.clip(rng.uniform(a.lambda_min, 1.0), a.lambda_min, 1.0))
        guesses.append(Guess(theta, lam, base.length, base.initial_pose, base.frames))
    return guesses


def _solve_start(args):
    problem, guess, frames, warm = args
    return solve_from(problem, guess, frames=frames, warm=warm)


def guess_from_routing(problem: DesignProblem, pairing: Pairing, routing: Routing) -> Guess:
    """A warm start from an earlier design: resampled onto this problem's segments if their count differs."""
    from vine_nlp.model import chain_frames

    M = pairing.segments
    if routing.segments == M:
        theta, lam, length = routing.theta, routing.lam, routing.length
    else:
        s_old = (np.arange(routing.segments) + 0.5) / routing.segments
        s_new = (np.arange(M) + 0.5) / M
        theta = np.interp(s_new, s_old, routing.theta)
        lam = np.interp(s_new, s_old, routing.lam)
        length = np.full(M, routing.length.sum() / M)
    a = problem.actuator
    theta = np.clip(theta, -a.theta_max, a.theta_max)
    lam = np.clip(lam, a.lambda_min, 1.0)
    if a.shared_lambda:
        lam = np.full(M, float(np.mean(lam)))
    frames = chain_frames(theta, lam, length, problem.diameter, routing.initial_pose)
    return Guess(theta, lam, length, routing.initial_pose.copy(), frames)


def design_nlp(
    problem: DesignProblem, starts: int | None = None, workers: int = 1, warm: Routing | None = None, progress=None, hops: int | None = None
) -> Result:
    """Inverse design as one NLP: multi-start (``options.starts``) keeping the lowest objective,
    then ``options.hops`` rounds of basin hopping (``basin_hops``).

    ``warm``: start from an earlier design instead (one start, frames on its chain).
    ``workers`` > 1 runs the starts in parallel processes (each builds its own solver).
    ``progress(done, total)`` is called after each start and each hop.
    """
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    n_hops = max(0, problem.options.hops if hops is None else hops)
    if warm is not None:
        jobs = [(problem, guess_from_routing(problem, pairing, warm), "chain", True)]
    else:
        n = max(1, problem.options.starts if starts is None else starts)
        jobs = [(problem, g, "target", False) for g in start_guesses(problem, pairing, n)]
    total = len(jobs) + n_hops
    t0 = time.perf_counter()
    results = []
    if workers > 1 and len(jobs) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
            for r in pool.map(_solve_start, jobs):  # map keeps start order: deterministic choice
                results.append(r)
                if progress:
                    progress(len(results), total)
    else:
        for job in jobs:
            results.append(_solve_start(job))
            if progress:
                progress(len(results), total)

    def rank(r):
        return (0 if r.converged else 1, r.stats["objective"])

    # the first start within the solver's tolerance of the best objective wins: ties do not depend on timing
    best_rank = min(rank(r) for r in results)
    k_best = next(k for k, r in enumerate(results) if rank(r)[0] == best_rank[0] and rank(r)[1] <= best_rank[1] * (1 + TIE_RTOL) + 1e-15)
    best = results[k_best]
    if len(results) > 1:
        best.stats["starts"] = len(results)
        best.stats["start_objectives"] = [r.stats["objective"] for r in results]
        best.stats["best_start"] = k_best
        best.solve_time_s = time.perf_counter() - t0
        best.iterations = sum(r.iterations for r in results)
    if warm is not None:
        best.stats["warm_start"] = True
    if n_hops:
        before = sum(r.iterations for r in results) if len(results) > 1 else best.iterations
        best = basin_hops(problem, best, n_hops, pairing, lambda k: progress and progress(len(results) + k, total))
        best.iterations = before + sum(best.stats["hop_iterations"])
        best.solve_time_s = time.perf_counter() - t0
    return best


# basin hopping: the number of neighbouring segments re-drawn around the chosen one (a corner
# spans about three segments at n = 10 points per segment)
HOP_WINDOW = 3


def basin_hops(problem: DesignProblem, result: Result, hops: int, pairing: Pairing | None = None, progress=None) -> Result:
    """Basin hopping for rugged targets (corners): ``hops`` rounds of re-drawing theta and lambda
    of HOP_WINDOW neighbouring segments and solving again, keeping a lower objective.

    The window's middle segment is drawn with probability proportional to its squared
    error, so the search goes where the design misses the target (on a polyline, the
    corners: each corner can be taken on several sides and swings, separate local
    minima of the one NLP that no single descent crosses). The new values are drawn
    uniformly inside the bounds; the rest of the design, its lengths and its frames
    are kept. Deterministic for a given ``options.seed``. Stats: ``hops``,
    ``hops_accepted``, ``hop_objectives``, ``hop_iterations``.
    """
    from vine_nlp.model import chain_frames

    o, a = problem.options, problem.actuator
    if o.hessian == "auto" and str(result.stats.get("hessian", "")).startswith("exact"):
        # Gauss-Newton did not converge on this target: do not try it again on every hop
        problem = dataclasses.replace(problem, options=dataclasses.replace(o, hessian="exact"))
    pairing = pairing or pair_points(problem.target, o.points_per_segment)
    M = pairing.segments
    rng = np.random.default_rng([o.seed, 1])  # a stream apart from start_guesses'
    best, objectives, iterations, accepted = result, [], [], 0
    for k in range(hops):
        err2 = np.sum((best.shape.center - problem.target) ** 2, axis=1)
        per_segment = np.bincount(pairing.seg, weights=err2, minlength=M) + 1e-300
        j = int(rng.choice(M, p=per_segment / per_segment.sum()))
        start = max(0, min(j - HOP_WINDOW // 2, M - HOP_WINDOW))
        w = slice(start, start + HOP_WINDOW)
        old = best.routing
        theta, lam = old.theta.copy(), old.lam.copy()
        theta[w] = rng.uniform(-a.theta_max, a.theta_max, theta[w].shape)
        if not a.shared_lambda:  # one shared lambda is not a property of a window
            lam[w] = rng.uniform(a.lambda_min, 1.0, lam[w].shape)
        # multiple shooting: frames inside the window follow the new values, the others stay where
        # the design put them, so the only continuity defect is at the window's end
        frames = chain_frames(old.theta, old.lam, old.length, problem.diameter, old.initial_pose)
        frames[start + 1 : start + HOP_WINDOW] = chain_frames(theta, lam, old.length, problem.diameter, old.initial_pose)[start + 1 : start + HOP_WINDOW]
        guess = Guess(theta, lam, old.length.copy(), old.initial_pose.copy(), frames)
        r = solve_from(problem, guess, pairing, frames="target")
        objectives.append(r.stats["objective"])
        iterations.append(r.iterations)
        if r.converged and r.stats["objective"] < best.stats["objective"] * (1 - TIE_RTOL):
            best, accepted = r, accepted + 1
        if progress:
            progress(k + 1)
    best.stats |= {"hops": hops, "hops_accepted": accepted, "hop_objectives": objectives, "hop_iterations": iterations}
    return best
