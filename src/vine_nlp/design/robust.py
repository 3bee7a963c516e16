"""Robust inverse design: minimize the expected error under construction errors.

Objective (units of D, as in design.nlp):

    J_robust = J_nlp + E[dMSE],   E[dMSE] = sum_k w_k tr(J_k Sigma J_k^T),

J_k the Jacobian of paired point k (and the tip) with respect to every segment's
(theta, lambda, dl), Sigma = diag(sigma^2) of analysis.tolerance.Sigmas (sigma_dl
relative: sigma times the segment's length variable). E[dMSE] is the exact
expected increase of the mean squared error of the linearized chain (the cross
term has zero mean), smooth, and computed in O(M) without forming J:

An error dq_m in segment m moves the segment's end frame by a small rigid motion,
so every point k downstream moves by b + a x r_k with r_k = p_k - o_{m+1}
(o_{m+1} the end frame's origin), a_i = sigma_i R_m (dR_s/dq_i R_s^T)^vee and
b_i = sigma_i R_m dp_s/dq_i from the segment's own transform (R_s, p_s). Summed over
the downstream points with weights w_k:

    sum_k w_k E|dp_k|^2 = W |B|_F^2 - 2 c . sum_i a_i x b_i + sum_i (|a_i|^2 tr Q - a_i^T Q a_i),

with W = sum w_k, c = sum w_k r_k, Q = sum w_k r_k r_k^T: suffix sums over the
segments of sum w, sum w p, sum w p p^T. Points inside segment m add their direct
term sum_k w_k sum_i sigma_i^2 |d rho_k / d q_i|^2 (rho_k in the segment's start frame).
All of it is written on the multiple-shooting frames of nlp.py's NLP
(design.clearance.ExtendedNLP), started from design_nlp's result. The suffix sums
are auxiliary variables with a banded recursion (RobustTerm): written directly in
x they couple every segment to everything downstream, and building the dense
Hessian takes minutes (trefoil m = 4: 90 s MX, 360 s SX) instead of 2 s.
"""

from __future__ import annotations

import time
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.analysis.tolerance import Sigmas
from vine_nlp.design.clearance import ExtendedNLP
from vine_nlp.design.nlp import design_nlp
from vine_nlp.design.problem import DesignProblem
from vine_nlp.design.result import Result
from vine_nlp.model.helix import center_rates
from vine_nlp.model.segment import twist_parts


def _sym6(p):
    """Upper triangle of p p^T: (xx, xy, xz, yy, yz, zz)."""
    return ca.vertcat(p[0] * p[0], p[0] * p[1], p[0] * p[2], p[1] * p[1], p[1] * p[2], p[2] * p[2])


def _full3(v):
    return ca.vertcat(ca.horzcat(v[0], v[1], v[2]), ca.horzcat(v[1], v[3], v[4]), ca.horzcat(v[2], v[4], v[5]))


def _vee(S):
    return ca.vertcat(S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]) / 2


@lru_cache(maxsize=8)
def robust_segment_function(n: int) -> ca.Function:
    """One segment's pieces of E[dMSE] (SX, units of D).

    (X (12), theta, lam, dl, u (n), w (n), sig (3)) -> (A (3x3), B (3x3): sigma-scaled world
    twist of the end frame per parameter; direct: the segment's own points' term; W, P1 (3),
    P2 (6): sums of w, w p, w p p^T (xx, xy, xz, yy, yz, zz) over its points).
    """
    X = ca.SX.sym("X", 12)
    th, la, dl = ca.SX.sym("theta"), ca.SX.sym("lam"), ca.SX.sym("dl")
    u, w, sig = ca.SX.sym("u", n), ca.SX.sym("w", n), ca.SX.sym("sig", 3)
    q = ca.vertcat(th, la, dl)
    R, o = ca.reshape(X[:9], 3, 3), X[9:]
    kappa, tau, lc = center_rates(th, la, 1.0)
    Rs_, ps_ = twist_parts(kappa, tau, dl * lc)
    Rs = ca.vertcat(*[ca.horzcat(*row) for row in Rs_])
    ps = ca.vertcat(*ps_)
    dRs = ca.jacobian(ca.vec(Rs), q)
    dps = ca.jacobian(ps, q)
    A = ca.horzcat(*[sig[i] * ca.mtimes(R, _vee(ca.mtimes(ca.reshape(dRs[:, i], 3, 3), Rs.T))) for i in range(3)])
    B = ca.mtimes(R, dps) @ ca.diag(sig)
    direct, W, P1, P2 = 0, 0, ca.SX.zeros(3), ca.SX.zeros(6)
    for i in range(n):
        _, rho_ = twist_parts(kappa, tau, u[i] * dl * lc)
        rho = ca.vertcat(*rho_)
        Jr = ca.jacobian(rho, q) @ ca.diag(sig)
        p = o + ca.mtimes(R, rho)
        direct += w[i] * ca.sumsqr(Jr)
        W += w[i]
        P1 += w[i] * p
        P2 += w[i] * _sym6(p)
    return ca.Function("robust_segment", [X, th, la, dl, u, w, sig], [A, B, direct, W, P1, P2],
                       ["X", "theta", "lam", "dl", "u", "w", "sig"], ["A", "B", "direct", "W", "P1", "P2"])


@lru_cache(maxsize=1)
def _downstream_function() -> ca.Function:
    """E|dp|^2 summed over the downstream points of one segment, from (A, B, o, W, P1, P2)."""
    A, B = ca.SX.sym("A", 3, 3), ca.SX.sym("B", 3, 3)
    o, W, P1, P2v = ca.SX.sym("o", 3), ca.SX.sym("W"), ca.SX.sym("P1", 3), ca.SX.sym("P2", 6)
    P2 = _full3(P2v)
    c = P1 - W * o
    Q = P2 - ca.mtimes(P1, o.T) - ca.mtimes(o, P1.T) + W * ca.mtimes(o, o.T)
    trQ = ca.trace(Q)
    val = W * ca.sumsqr(B)
    for i in range(3):
        a, b = A[:, i], B[:, i]
        val += -2 * ca.dot(c, ca.cross(a, b)) + ca.sumsqr(a) * trQ - ca.mtimes([a.T, Q, a])
    return ca.Function("downstream", [A, B, o, W, P1, P2v], [val])


class RobustTerm:
    """E[dMSE] (units of D^2) of an ExtendedNLP's design under ``sigmas`` (module docstring).

    ``value``: the expression in x alone (dense: every segment couples to all points
    downstream), for evaluation. For the optimizer the downstream sums are auxiliary
    variables ``z`` (9 x M: sum w p, sum w p p^T after each segment, tip included) tied by
    the banded recursion ``g`` = 0, so the term, its constraints and the Lagrangian
    Hessian stay block-banded like the rest of the multiple-shooting NLP
    (``objective``: the term in x and z). ``z_of_x``: the sums' values at a given x.
    """

    def __init__(self, nlp: ExtendedNLP, sigmas: Sigmas):
        M, n, D = nlp.M, nlp.n, nlp.D
        _, w, u, _, wtip = nlp.params[:5]
        w = np.asarray(w, float).reshape(M, n).T  # slot-major per segment -> (n, M)
        u = np.asarray(u, float)
        wtip = float(wtip)
        sdl = sigmas.length * nlp.dl if sigmas.relative_length else ca.DM.ones(1, M) * (sigmas.length / D)
        sig = ca.vertcat(ca.DM.ones(1, M) * sigmas.theta, ca.DM.ones(1, M) * sigmas.lam, sdl)
        F = robust_segment_function(n).map(M, "serial")
        A, B, direct, _, P1, P2 = F(nlp.frames[:, :M], nlp.theta, nlp.lam, nlp.dl, u, w, sig)
        L = ca.vertcat(P1, P2)  # (9, M): each segment's own sums
        tip = nlp.frames[9:, M]
        T = wtip * ca.vertcat(tip, _sym6(tip))
        Wd = np.cumsum(w.sum(axis=0)[::-1])[::-1]  # constants: sum of weights from segment m on
        Wd = np.concatenate([Wd[1:], [0.0]]) + wtip  # ... after segment m, plus the tip
        G = _downstream_function().map(M, "serial")
        o_end = nlp.frames[9:, 1:]
        # dense: suffix sums as a product with a strictly triangular matrix
        U = ca.DM(np.triu(np.ones((M, M)), 1).T)  # U[j, m] = 1 for j > m
        S_dense = ca.mtimes(L, U) + ca.repmat(T, 1, M)
        self.value = ca.sum2(G(A, B, o_end, ca.DM(Wd).T, S_dense[:3, :], S_dense[3:, :])) + ca.sum2(direct)
        # banded: S_m = S_{m+1} + L_{m+1}, S_{M-1} = T
        self.z = ca.MX.sym("S", 9 * M)
        S = ca.reshape(self.z, 9, M)
        nxt = ca.horzcat(S[:, 1:] + L[:, 1:], T) if M > 1 else T
        self.g = ca.vec(S - nxt)
        self.objective = ca.sum2(G(A, B, o_end, ca.DM(Wd).T, S[:3, :], S[3:, :])) + ca.sum2(direct)
        self._S = ca.Function("S", [nlp.x], [ca.vec(S_dense)])
        self._value = ca.Function("value", [nlp.x], [self.value])
        self.D = D

    def z_of_x(self, x) -> np.ndarray:
        return np.array(self._S(x)).ravel()

    def mse_increase(self, x) -> float:
        """First-order expected MSE increase at x, problem units^2."""
        return float(self._value(x)) * self.D**2


def expected_increase(nlp: ExtendedNLP, sigmas: Sigmas):
    """E[dMSE] as one MX expression of nlp.x (units of D^2): for evaluation and checks."""
    return RobustTerm(nlp, sigmas).value


def design_robust(problem: DesignProblem, sigmas: Sigmas, samples: int = 0, seed: int = 0, weight: float = 1.0,
                  start: Result | None = None, expand: bool = False, **kw) -> Result:
    """Inverse design minimizing nominal error + ``weight`` * first-order expected increase under ``sigmas``.

    ``start``: the design to start from (default design_nlp(problem, **kw)). ``expand``: SX
    evaluation inside IPOPT (faster iterations but a much slower build: trefoil m = 4, 16 s vs 2 s). With ``samples`` > 0,
    the start and the robust design are both checked by Monte Carlo on the same seeded samples
    (analysis.tolerance.tolerance_report). stats: robust_* entries (lengths in problem units):
    expected_mse_increase / _start (first order), expected_rmse / _start (sqrt(MSE_0 + increase)),
    start_rmse, and with samples mc_mean_rmse / _start, mc_rms_rmse / _start.
    """
    t_all = time.perf_counter()
    start = start or design_nlp(problem, **kw)
    nlp = ExtendedNLP(problem, start.routing)
    term = RobustTerm(nlp, sigmas)
    g = term.g
    x, _, st = nlp.solve(weight * term.objective, g, np.zeros(g.numel()), np.zeros(g.numel()), x0=nlp.x0, z=term.z,
                         z0=term.z_of_x(nlp.x0), expand=expand)
    res = nlp.result(x, st, "nlp_robust")
    i0, i1 = term.mse_increase(nlp.x0), term.mse_increase(x)
    m0, m1 = start.metrics["rmse"] ** 2, res.metrics["rmse"] ** 2
    res.stats.update({
        "robust_weight": float(weight),
        **{f"robust_{k}": v for k, v in sigmas.as_dict().items()},
        "robust_expected_mse_increase": i1, "robust_expected_mse_increase_start": i0,
        "robust_expected_rmse": float(np.sqrt(m1 + i1)), "robust_expected_rmse_start": float(np.sqrt(m0 + i0)),
        "robust_start_rmse": float(start.metrics["rmse"]),
    })
    if samples:
        from vine_nlp.analysis.tolerance import tolerance_report

        a = tolerance_report(problem, start, sigmas, samples, seed)["monte_carlo"]
        b = tolerance_report(problem, res, sigmas, samples, seed)["monte_carlo"]
        res.stats.update({
            "robust_mc_samples": int(samples), "robust_mc_seed": int(seed),
            "robust_mc_mean_rmse": b["mean_rmse"], "robust_mc_mean_rmse_start": a["mean_rmse"],
            "robust_mc_rms_rmse": b["rms_rmse"], "robust_mc_rms_rmse_start": a["rms_rmse"],
        })
    res.solve_time_s = time.perf_counter() - t_all
    return res
