"""Robust inverse design: minimize the expected error under construction errors.

Objective (units of D, as in methods.nlp):

    J_robust = J_nlp + E[dMSE],   E[dMSE] = sum_k w_k tr(J_k Sigma J_k^T),

J_k the Jacobian of paired point k (and the tip) with respect to every segment's (theta, lambda, dl), Sigma =
diag(sigma^2) of analysis.tolerance.Sigmas (sigma_dl relative: sigma times the segment's length variable; sigma_lambda 0
where the start design has no actuator, lambda 1: the physical rule, spec "Physical builds"). E[dMSE] is the exact
expected increase of the mean squared error of the linearized chain (the cross term has zero mean), smooth, and computed
in O(M) without forming J:

An error dq_m in segment m moves the segment's end frame by a small rigid motion, so every point k downstream moves by b
+ a x r_k with r_k = p_k - o_{m+1} (o_{m+1} the end frame's origin), a_i = sigma_i R_m (dR_s/dq_i R_s^T)^vee and b_i =
sigma_i R_m dp_s/dq_i from the segment's own transform (R_s, p_s). Summed over the downstream points with weights w_k:

    sum_k w_k E|dp_k|^2 = W |B|_F^2 - 2 c . sum_i a_i x b_i + sum_i (|a_i|^2 tr Q - a_i^T Q a_i),

with W = sum w_k, c = sum w_k r_k, Q = sum w_k r_k r_k^T: suffix sums over the segments of sum w, sum w p, sum w p p^T.
Points inside segment m add their direct term sum_k w_k sum_i sigma_i^2 |d rho_k / d q_i|^2 (rho_k in the segment's
start frame). This is the linear-Gaussian propagation of the construction errors along the chain, run backwards: instead
of carrying the 6 x 6 frame covariance forward (21 numbers per stage), the downstream sums (sum w p, sum w p p^T: 9
numbers) are carried back. They are extra stage variables S_j of the one transcription (methods.transcription), tied by
the banded recursion S_j = S_{j+1} + L_{j+1}(stage j+1), so the term and its rows are per-stage blocks with their own SX
derivatives and the cost per iteration stays linear in M. Written directly in x they would couple every segment to
everything downstream (a dense Hessian). Started from design_nlp's result."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.analysis.tolerance import tolerance_report
from vine_nlp.methods import drive
from vine_nlp.methods.blocks import BlockType
from vine_nlp.methods.buildable import inherited_bounds
from vine_nlp.methods.common import pair_points
from vine_nlp.methods.nlp import chain_guess, design_nlp, extended_solver, nlp_parameters, result_of, start_x
from vine_nlp.methods.transcription import Chain, segment_point_index
from vine_nlp.methods.variables import POINT, ROUTE, Slots
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import Sigmas, actuated
from vine_nlp.model.segment import _exp_coefficients, twist_parts
from vine_nlp.problem import DesignProblem, Result


def _sym6(p):
    """Upper triangle of p p^T: (xx, xy, xz, yy, yz, zz)."""
    return ca.vertcat(p[0] * p[0], p[0] * p[1], p[0] * p[2], p[1] * p[1], p[1] * p[2], p[2] * p[2])


@lru_cache(maxsize=8)
def robust_segment_function(n: int) -> ca.Function:
    """One segment's pieces of E[dMSE] (SX, units of D).

    (X (12), theta, lam, dl, u (n), w (n), sig (3)) -> (A (3x3), B (3x3): sigma-scaled world twist of the end frame per
    parameter; W, P1 (3), P2 (6): sums of w, w p, w p p^T (xx, xy, xz, yy, yz, zz) over its points)."""
    X = ca.SX.sym("X", 12)
    th, la, dl = ca.SX.sym("theta"), ca.SX.sym("lam"), ca.SX.sym("dl")
    u, w, sig = ca.SX.sym("u", n), ca.SX.sym("w", n), ca.SX.sym("sig", 3)
    q = ca.vertcat(th, la, dl)
    R, o = ca.reshape(X[:9], 3, 3), X[9:]
    kappa, tau, lc = center_rates(th, la, 1.0)
    ps = ca.vertcat(*twist_parts(kappa, tau, dl * lc)[1])
    # (dR_s/dq_i R_s^T)^vee = J_l(phi) dphi/dq_i: the left Jacobian of SO(3) at the segment's rotation vector
    # phi = sigma (tau, 0, kappa), J_l = I + B phi^ + C phi^2 with exp's coefficients (a quarter fewer
    # instructions in the block's Hessian than differentiating R_s)
    phi = dl * lc * ca.vertcat(tau, 0, kappa)
    _, Bc, Cc = _exp_coefficients(ca.sumsqr(phi))
    P = ca.skew(phi)
    Jl = ca.SX.eye(3) + Bc * P + Cc * ca.mtimes(P, P)
    A = ca.mtimes(R, ca.mtimes(Jl, ca.jacobian(phi, q))) @ ca.diag(sig)
    B = ca.mtimes(R, ca.jacobian(ps, q)) @ ca.diag(sig)
    W, P1, P2 = 0, ca.SX.zeros(3), ca.SX.zeros(6)
    for i in range(n):
        p = o + ca.mtimes(R, ca.vertcat(*twist_parts(kappa, tau, u[i] * dl * lc)[1]))
        W += w[i]
        P1 += w[i] * p
        P2 += w[i] * _sym6(p)
    return ca.Function("robust_segment", [X, th, la, dl, u, w, sig], [A, B, W, P1, P2],
                       ["X", "theta", "lam", "dl", "u", "w", "sig"], ["A", "B", "W", "P1", "P2"])


def direct_term(theta, lam, dl, u, w, sig):
    """The segment's own points' term sum_i w_i sum_q sig_q^2 |d rho_i / d q|^2 (rho_i in the segment's start frame,
    SX). The center line is parametrized by arc length s = u dl lambda_c, so |d rho / d dl| = u lambda_c: the dl part
    is closed-form, and only theta and lambda are differentiated through the helix (about half the Hessian's cost)."""
    kappa, tau, lc = center_rates(theta, lam, 1.0)
    q = ca.vertcat(theta, lam)
    val = sig[2] ** 2 * lc**2 * ca.dot(w, u**2)
    for i in range(u.numel()):
        J = ca.jacobian(ca.vertcat(*twist_parts(kappa, tau, u[i] * dl * lc)[1]), q)
        val += w[i] * (sig[0] ** 2 * ca.sumsqr(J[:, 0]) + sig[1] ** 2 * ca.sumsqr(J[:, 1]))
    return val


def _block(name: str, v, d, f, r=None) -> BlockType:
    """A block whose function has its common subexpressions merged: its SX derivatives are ~30 % smaller."""
    return BlockType(name, ca.Function(name, [v, d], [f, ca.SX(0, 1) if r is None else r], {"cse": True}))


@lru_cache(maxsize=1)
def _downstream_function() -> ca.Function:
    """E|dp|^2 summed over the downstream points of one segment, from (A, B, o, W, P1, P2)."""
    A, B = ca.SX.sym("A", 3, 3), ca.SX.sym("B", 3, 3)
    o, W, P1, P2v = ca.SX.sym("o", 3), ca.SX.sym("W"), ca.SX.sym("P1", 3), ca.SX.sym("P2", 6)
    P2 = ca.vertcat(ca.horzcat(P2v[0], P2v[1], P2v[2]), ca.horzcat(P2v[1], P2v[3], P2v[4]), ca.horzcat(P2v[2], P2v[4], P2v[5]))
    c = P1 - W * o
    Q = P2 - ca.mtimes(P1, o.T) - ca.mtimes(o, P1.T) + W * ca.mtimes(o, o.T)
    trQ = ca.trace(Q)
    val = W * ca.sumsqr(B)
    for i in range(3):
        a, b = A[:, i], B[:, i]
        val += -2 * ca.dot(c, ca.cross(a, b)) + ca.sumsqr(a) * trQ - ca.mtimes([a.T, Q, a])
    return ca.Function("downstream", [A, B, o, W, P1, P2v], [val])


@lru_cache(maxsize=8)
def robust_blocks(n: int) -> tuple[BlockType, BlockType, BlockType]:
    """The robust term's three per-stage blocks (sig = (s_theta, s_lam, s_len_rel, s_len_abs), sigma_dl =
    s_len_rel dl + s_len_abs; weight: the term's weight).

    downstream: v = (X_j (12), theta, lam, dl, o_{j+1} (3), S_j (9)); d = (W_j, sig (4), weight):
      weight times the downstream points' term of segment j's errors.
    direct: v = (theta, lam, dl); d = (u (n), w (n), sig (4), weight): weight times the segment's own points'
      term (it does not depend on the frame: a block of 3 variables keeps its Hessian cheap).
    recursion: v = (S_j (9), S_{j+1} (9), X_{j+1} (12), theta, lam, dl of stage j+1); d = (u (n), w (n)) of stage j+1:
      r = S_j - S_{j+1} - (sum w p, sum w p p^T)(stage j+1)."""
    seg, down = robust_segment_function(n), _downstream_function()
    one = robust_segment_function(1)
    down_v = POINT + (("tip", 3), ("S", 9))  # variables.POINT, X_{j+1}'s position, S_j
    v, d = ca.SX.sym("v", down_v.size), ca.SX.sym("d", 6)
    W, sg, weight = d[0], d[1:5], d[5]
    X, th, la, dl, tip, S = down_v.split(v)
    sig = ca.vertcat(sg[0], sg[1], sg[2] * dl + sg[3])
    A, B, _, _, _ = one(X, th, la, dl, 0.0, 0.0, sig)
    downstream = _block(f"robust_downstream{n}", v, d, weight * down(A, B, tip, W, S[:3], S[3:]))
    v1, d1 = ca.SX.sym("v", ROUTE.size), ca.SX.sym("d", 2 * n + 5)
    th, la, dl = ROUTE.split(v1)
    sg1 = d1[2 * n : 2 * n + 4]
    sig1 = ca.vertcat(sg1[0], sg1[1], sg1[2] * dl + sg1[3])
    own = _block(f"robust_direct{n}", v1, d1, d1[2 * n + 4] * direct_term(th, la, dl, d1[:n], d1[n : 2 * n], sig1))
    rec_v = Slots(("S", 9), ("S_next", 9)) + POINT.parts  # S_j, S_{j+1}, variables.POINT of stage j+1
    v2, d2 = ca.SX.sym("v", rec_v.size), ca.SX.sym("d", 2 * n)
    S, S_next, X, th, la, dl = rec_v.split(v2)
    _, _, _, P1, P2 = seg(X, th, la, dl, d2[:n], d2[n:], ca.SX.zeros(3))
    # rows only: f is a structural zero, so the block stays out of the objective's evaluation and gradient
    recursion = _block(f"robust_recursion{n}", v2, d2, ca.SX(1, 1), S - S_next - ca.vertcat(P1, P2))
    return downstream, own, recursion


@dataclass(frozen=True)
class RobustTerm:
    """weight * E[dMSE] (units of D^2) under the parameters ``robust`` = (sigmas (4), weight) as stage blocks
    on the chain's 9 extra stage variables S_j (module docstring). Needs Structure(extra=9)."""

    def apply(self, c: Chain) -> None:
        s, lay = c.s, c.lay
        M, n = s.M, s.n
        P = c.param("robust", (5, 1))
        Wd = c.param("robust_W", (1, M))  # sum of weights after each segment, tip included
        u, w = c.cells[:n, :], c.cells[4 * n :, :]
        down, own, rec = robust_blocks(n)
        act = c.param("robust_act", (1, M))  # 0 where there is no actuator: no lambda error
        sig = ca.vertcat(ca.repmat(P[0], 1, M), P[1] * act, ca.repmat(P[2:], 1, M))
        idx = np.array([np.r_[segment_point_index(c, j), lay.X[j + 1, 0, 9:], lay.extra[j]] for j in range(M)]).T
        c.add_block(down, idx, ca.vertcat(Wd, sig), term="robust")
        c.add_block(own, np.array([lay.routing_at(j) for j in range(M)]).T, ca.vertcat(u, w, sig), term="robust")
        if M > 1:
            idx = np.array([np.r_[lay.extra[j], lay.extra[j + 1], segment_point_index(c, j + 1)] for j in range(M - 1)]).T
            c.add_block(rec, idx, ca.vertcat(u[:, 1:], w[:, 1:]))
        tip = c.tip(0)
        wtip = c.param("robust_wtip", (1, 1))
        c.add_rows("robust_tail", c.extra[:, M - 1] - wtip * ca.vertcat(tip, _sym6(tip)), 0.0, 0.0)


def robust_parameters(params: dict, sigmas: Sigmas, weight: float, D: float, n: int, act) -> dict:
    """The robust term's data beside the plain NLP's ``params`` (scaled by D); ``act``: where there is an actuator."""
    w = np.asarray(params["cells"])[4 * n :, :]
    wtip = float(params["wtip"])
    Wd = np.cumsum(w.sum(axis=0)[::-1])[::-1]
    Wd = np.concatenate([Wd[1:], [0.0]]) + wtip
    rel, ab = (sigmas.length, 0.0) if sigmas.relative_length else (0.0, sigmas.length / D)
    return {"robust": [sigmas.theta, sigmas.lam, rel, ab, weight], "robust_W": Wd, "robust_wtip": wtip, "robust_act": np.asarray(act, float)}


@lru_cache(maxsize=8)
def _sums_function(solver) -> ca.Function:
    """(x, p) -> each stage's (sum w p, sum w p p^T), the tip's (p, p p^T): on this solver's own variables and parameters."""
    c, M, n = solver.chain, solver.structure.M, solver.structure.n
    F = robust_segment_function(n).map(M, "serial")
    _, _, _, P1, P2 = F(c.frames(0)[:, :M], c.theta, c.lam_of(0), c.dl, c.cells[:n, :], c.cells[4 * n :, :], ca.DM.zeros(3, M))
    P = ca.vertcat(*[ca.vec(q) for _, q in c.params])
    return ca.Function("sums", [c.x, P], [ca.vertcat(P1, P2), ca.vertcat(c.tip(0), _sym6(c.tip(0)))])


def downstream_sums(solver, x, p) -> np.ndarray:
    """S (9, M) where the recursion holds for x's chain: suffix sums of each stage's (sum w p, sum w p p^T)."""
    M = solver.structure.M
    Lv, T = (np.array(v) for v in _sums_function(solver)(x, p))
    wtip = float(p[solver.param_slice("robust_wtip")][0])
    S = np.zeros((9, M))
    S[:, M - 1] = wtip * T.ravel()
    for j in range(M - 2, -1, -1):
        S[:, j] = S[:, j + 1] + Lv[:, j + 1]
    return S


def robust_solver(problem: DesignProblem, pairing):
    """The plain NLP plus the robust term, cached per structure."""
    return extended_solver(problem, pairing, (RobustTerm(),), extra=9)


def expected_increase(problem: DesignProblem, routing, sigmas: Sigmas) -> float:
    """First-order expected MSE increase of ``routing`` under ``sigmas`` (problem units^2), evaluated
    through the transcription's robust term (checks: analysis.tolerance)."""
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    solver = robust_solver(problem, pairing)
    x, p = _robust_start(problem, pairing, solver, routing, sigmas, 1.0)
    return solver.terms(x, p)["robust"] * problem.diameter**2


def _robust_start(problem, pairing, solver, routing, sigmas, weight):
    D = problem.diameter
    params = nlp_parameters(problem, pairing, routing.initial_pose[:3, :3].copy())
    p = solver.pack_params(params | robust_parameters(params, sigmas, weight, D, pairing.n, actuated(routing.lam)))
    x = start_x(solver, chain_guess(problem, routing), D, "chain")
    x[solver.layout.extra.T] = downstream_sums(solver, x, p)
    return x, p


def design_robust(problem: DesignProblem, sigmas: Sigmas, samples: int = 0, seed: int = 0, weight: float = 1.0,
                  start: Result | None = None, **kw) -> Result:
    """Inverse design minimizing nominal error + ``weight`` * first-order expected increase under ``sigmas``.

    ``start``: the design to start from (default design_nlp(problem, **kw)). With ``samples`` > 0, the start and the
    robust design are both checked by Monte Carlo on the same seeded samples (analysis.tolerance.tolerance_report).
    stats: robust_* entries (lengths in problem units): expected_mse_increase / _start (first order), expected_rmse /
    _start (sqrt(MSE_0 + increase)), start_rmse, and with samples mc_mean_rmse / _start, mc_rms_rmse / _start."""
    stats = drive.Stats()
    start = start or design_nlp(problem, **kw)
    D = problem.diameter
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    solver = robust_solver(problem, pairing)
    x0, p = _robust_start(problem, pairing, solver, start.routing, sigmas, weight)
    i0 = solver.terms(x0, p)["robust"] / weight * D**2 if weight else 0.0
    lbx, ubx = solver.bounds(**inherited_bounds(problem, pairing, start))  # a buildable start's classes kept
    res = stats.absorb(result_of(problem, pairing, solver.solve(x0, p, lbx, ubx), start.routing.initial_pose[:3, :3].copy(), "nlp_robust"))
    # the increase of the design found, evaluated with weight 1 (the recursion holds at a converged x)
    i1 = expected_increase(problem, res.routing, sigmas)
    if not weight:
        i0 = expected_increase(problem, start.routing, sigmas)
    m0, m1 = start.metrics["rmse"] ** 2, res.metrics["rmse"] ** 2
    res.stats.update({"robust_weight": float(weight), **{f"robust_{k}": v for k, v in sigmas.as_dict().items()},
                      "robust_expected_mse_increase": i1, "robust_expected_mse_increase_start": i0,
                      "robust_expected_rmse": float(np.sqrt(m1 + i1)), "robust_expected_rmse_start": float(np.sqrt(m0 + i0)),
                      "robust_start_rmse": float(start.metrics["rmse"])})
    if samples:
        a = tolerance_report(problem, start, sigmas, samples, seed)["monte_carlo"]
        b = tolerance_report(problem, res, sigmas, samples, seed)["monte_carlo"]
        res.stats.update({"robust_mc_samples": int(samples), "robust_mc_seed": int(seed),
                          "robust_mc_mean_rmse": b["mean_rmse"], "robust_mc_mean_rmse_start": a["mean_rmse"],
                          "robust_mc_rms_rmse": b["rms_rmse"], "robust_mc_rms_rmse_start": a["rms_rmse"]})
    return stats.stamp(res)
