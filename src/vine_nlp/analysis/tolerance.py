"""Manufacturing tolerance: how construction errors in theta, lambda and segment length move the shape.

Error model: every segment's (theta_j, lambda_j, dl_j) is built with independent, zero-mean Gaussian errors of standard
deviations (see :class:`Sigmas`), by the physical rule (spec "Physical builds", model.routing.built_lambda): no lambda
error where lambda_j = 1 (no actuator), elsewhere the built lambda min(1, lambda_j + error), at least lambda_min

* sigma_theta  [rad]  drawn angle of the actuator,
* sigma_lambda [-]    contraction ratio (absolute: lambda 0.70 +- 0.02),
* sigma_length        segment length, *relative* by default (0.02 = 2 % of each
                      segment's length, like a stopper or pinch cut 2 % off); with
                      ``relative_length=False`` an absolute length in problem units.

First order. With J the Jacobian of the paired center points (single shooting, CasADi, :func:`point_jacobian`) with
respect to q = (theta_j, lambda_j, dl_j)_j and Sigma = diag(sigma^2), the point errors are N(0, J_k Sigma J_k^T) and the
expected squared error of the linearization is exact:

    E[MSE] = MSE_0 + (1/N) sum_k tr(J_k Sigma J_k^T)    (the cross term has zero mean),

so the "first-order RMSE" is sqrt(E[MSE]) (Jensen: E[RMSE] <= sqrt(E[MSE])). The tip
covariance is J_tip Sigma J_tip^T, and the contribution of segment m to the tip
variance is sum over its three parameters of |J_tip[:, (m, p)]|^2 sigma_(m, p)^2.

First order ignores the clips (a derivative of 1; of 0 without an actuator). Monte Carlo builds by the rule itself: the
numpy chain evaluated for all samples at once (model functions broadcast over a (samples, segments) array), seeded RNG."""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.model.pairing import pair_points
from vine_nlp.model.routing import Sigmas, actuated, built_lambda  # Sigmas re-exported: its old home
from vine_nlp.model.segment import segment_function, segment_point, segment_transform


@lru_cache(maxsize=8)
def segment_jacobian_function(n: int) -> ca.Function:
    """model.segment.segment_function(n) and its Jacobian: (X, theta, lam, dl, u) ->
    (Xn (12), pts (3 x n), d[Xn; vec(pts)] / d[X; theta; lam; dl] ((12 + 3 n) x 15)), units of D."""
    F = segment_function(n)
    X, th, la, dl, u = ca.SX.sym("X", 12), ca.SX.sym("theta"), ca.SX.sym("lam"), ca.SX.sym("dl"), ca.SX.sym("u", n)
    Xn, pts = F(X, th, la, dl, u)
    jac = ca.jacobian(ca.vertcat(Xn, ca.vec(pts)), ca.vertcat(X, th, la, dl))
    return ca.Function("segment_jacobian", [X, th, la, dl, u], [Xn, pts, jac])


def point_jacobian(routing, D: float, seg, frac):
    """Center points at (seg, frac) and their Jacobian wrt (theta_j, lambda_j, dl_j), single shooting.

    Returns (points (P, 3), J (P, 3, 3M)); column 3 j + p is parameter p (0 theta, 1 lambda, 2 dl) of segment j, in
    problem units. The chain is the NLP's per-segment function (model.segment.segment_function, units of D) in a loop;
    its CasADi Jacobian (frame and points wrt frame and parameters) is chained forward, S_{j+1} = A_j S_j + B_j with S_j
    = dX_j/dq: O(M) evaluations of one small function, exact derivatives."""
    M = routing.segments
    seg, frac = np.asarray(seg, int), np.asarray(frac, float)
    counts = np.bincount(seg, minlength=M)
    n = int(max(1, counts.max()))
    G = segment_jacobian_function(n)
    T0 = np.asarray(routing.initial_pose, float)
    X = np.concatenate([T0[:3, :3].ravel(order="F"), T0[:3, 3] / D])
    S = np.zeros((12, 3 * M))  # dX_j / dq; the base frame is not a construction parameter
    points, J = np.empty((seg.size, 3)), np.empty((seg.size, 3, 3 * M))
    for j in range(M):
        idx = np.flatnonzero(seg == j)
        u = np.zeros(n)
        u[: idx.size] = frac[idx]
        Xn, pts, jac = G(X, routing.theta[j], routing.lam[j], routing.length[j] / D, u)
        jac = np.array(jac)
        if idx.size:
            rows = jac[12 : 12 + 3 * idx.size]  # vec(pts): point after point, x y z each
            Jp = rows[:, :12] @ S
            Jp[:, 3 * j : 3 * j + 3] += rows[:, 12:]
            J[idx] = Jp.reshape(idx.size, 3, 3 * M)
            points[idx] = np.array(pts)[:, : idx.size].T
        S = jac[:12, :12] @ S
        S[:, 3 * j : 3 * j + 3] += jac[:12, 12:]
        X = np.array(Xn).ravel()
    points *= D
    J *= D
    J[:, :, 2::3] /= D  # d/d(dl) in problem units (dl was scaled by D)
    return points, J


def batch_points(theta, lam, length, D: float, seg, frac, initial_pose=None, chunk: int = 256) -> np.ndarray:
    """Center points at (seg, frac) of many designs at once: (S, M) arrays -> (S, P, 3) (numpy chain)."""
    theta, lam, length = np.broadcast_arrays(*(np.atleast_2d(np.asarray(v, float)) for v in (theta, lam, length)))
    S, M = theta.shape
    seg, frac = np.asarray(seg, int), np.asarray(frac, float)
    T0 = np.eye(4) if initial_pose is None else np.asarray(initial_pose, float)
    out = np.empty((S, seg.size, 3))
    for a in range(0, S, chunk):
        b = min(S, a + chunk)
        th, la, ln = theta[a:b], lam[a:b], length[a:b]
        steps = segment_transform(th, la, ln, D)  # (s, M, 4, 4)
        F = np.empty((b - a, M + 1, 4, 4))
        F[:, 0] = T0
        for j in range(M):
            F[:, j + 1] = F[:, j] @ steps[:, j]
        local = np.stack(segment_point(th[:, seg], la[:, seg], ln[:, seg], D, frac), axis=-1)  # (s, P, 3)
        Fs = F[:, seg]
        out[a:b] = np.einsum("spij,spj->spi", Fs[..., :3, :3], local) + Fs[..., :3, 3]
    return out


def tolerance_report(problem, result, sigmas: Sigmas, samples: int = 2000, seed: int = 0) -> dict:
    """First-order and Monte Carlo sensitivity of a design to construction errors.

    The shape is measured at the paired points of ``problem`` (pair_points with its points_per_segment, the tip last),
    as the design methods do; the result's routing must have that pairing's segment count. Lengths in problem units.

    Returns dict with sigmas, units, segments, points; nominal: rmse, mse, tip (3,); first_order: mse_increase,
      rmse (= sqrt(MSE_0 + increase)), rmse_increase, tip_cov (3, 3), tip_std (= sqrt(trace)), point_std (N,);
      per_segment: l_start, l_end, l_mid (material coordinate), tip_var (M,), tip_var_by_param (M, 3), mse (M,),
      mse_by_param (M, 3) (columns theta, lambda, length; they add up to the totals above); monte_carlo: samples,
      seed, rmse (S,), mean_rmse, rms_rmse (= sqrt(mean MSE)), mse_increase, tip_cov (3, 3), tip_std, tip_mean_shift."""
    D, r = problem.diameter, result.routing
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    if pairing.segments != r.segments:
        raise ValueError(f"the design has {r.segments} segments, the problem's pairing {pairing.segments}")
    M = r.segments
    pts, J = point_jacobian(r, D, pairing.seg, pairing.frac)
    sig = sigmas.per_segment(r.length) * np.c_[np.ones(M), actuated(r.lam), np.ones(M)]  # (M, 3): no lambda error without an actuator
    dq = np.random.default_rng(seed).standard_normal((samples, M, 3)) * sig
    lam = built_lambda(r.lam, dq[..., 1], problem.actuator.lambda_min)
    P = batch_points(r.theta + dq[..., 0], lam, r.length + dq[..., 2], D, pairing.seg, pairing.frac, r.initial_pose)
    return tolerance_summary(pts, J * sig.reshape(-1), problem.target, P, r.length, sigmas, getattr(problem, "units", ""), seed)


def tolerance_summary(pts, Js, target, P, length, sigmas: Sigmas, units: str = "", seed: int = 0, kinds=(0, 1, 2)) -> dict:
    """:func:`tolerance_report`'s figures from the nominal points (N, 3) paired with ``target``, their Jacobian
    with its columns scaled by their standard deviations ``Js`` (N, 3, M n: segment by segment, n parameters each,
    ``kinds`` saying which of theta 0, lambda 1, length 2 each is) and Monte Carlo points ``P`` (S, N, 3)."""
    target = np.asarray(target, float)
    N, M = target.shape[0], len(length)
    err0 = np.sum((pts - target) ** 2, axis=1)
    mse0 = float(err0.mean())
    by = np.sum(Js**2, axis=1).reshape(N, M, len(kinds)) @ np.eye(3)[list(kinds)]  # (N, M, 3): variance of point k from (m, p)
    mse_by = by.mean(axis=0)
    inc = float(mse_by.sum())
    tip_by = by[-1]
    tip_cov = Js[-1] @ Js[-1].T
    cum = np.concatenate([[0.0], np.cumsum(length)])
    mse = np.mean(np.sum((P - target) ** 2, axis=2), axis=1)
    tips = P[:, -1]
    mc_cov = np.cov(tips.T)
    return {
        "sigmas": sigmas.as_dict(), "units": units, "segments": M, "points": N,
        "nominal": {"rmse": math.sqrt(mse0), "mse": mse0, "tip": pts[-1]},
        "first_order": {
            "mse_increase": inc, "rmse": math.sqrt(mse0 + inc), "rmse_increase": math.sqrt(mse0 + inc) - math.sqrt(mse0),
            "tip_cov": tip_cov, "tip_std": float(math.sqrt(np.trace(tip_cov))), "point_std": np.sqrt(by.sum(axis=(1, 2))),
        },
        "per_segment": {
            "l_start": cum[:-1], "l_end": cum[1:], "l_mid": 0.5 * (cum[:-1] + cum[1:]),
            "tip_var": tip_by.sum(axis=1), "tip_var_by_param": tip_by,
            "mse": mse_by.sum(axis=1), "mse_by_param": mse_by,
        },
        "monte_carlo": {
            "samples": int(P.shape[0]), "seed": int(seed), "rmse": np.sqrt(mse), "mean_rmse": float(np.sqrt(mse).mean()),
            "rms_rmse": float(math.sqrt(mse.mean())), "mse_increase": float(mse.mean() - mse0), "tip_cov": mc_cov,
            "tip_std": float(math.sqrt(np.trace(mc_cov))), "tip_mean_shift": tips.mean(axis=0) - pts[-1],
        },
    }


def tolerance_metrics(report: dict) -> dict:
    """Flat floats of a tolerance report for archive attributes (problem length units)."""
    fo, mc, ps = report["first_order"], report["monte_carlo"], report["per_segment"]
    worst = int(np.argmax(ps["tip_var"]))
    return {"tolerance_rmse_first_order": fo["rmse"], "tolerance_rmse_increase_first_order": fo["rmse_increase"],
            "tolerance_tip_std_first_order": fo["tip_std"], "tolerance_rmse_mc_mean": mc["mean_rmse"],
            "tolerance_rmse_mc_rms": mc["rms_rmse"], "tolerance_tip_std_mc": mc["tip_std"],
            "tolerance_worst_segment": float(worst), "tolerance_worst_segment_l_mid": float(ps["l_mid"][worst]),
            "tolerance_worst_segment_tip_share": float(ps["tip_var"][worst] / max(ps["tip_var"].sum(), 1e-300))}
