"""Uncertainty of the as-built estimate: the Laplace approximation around the MAP estimate.

The inverse of the Gauss-Newton Hessian of the MAP objective (point-to-line residuals / sigma_m and the prior's
residuals) with respect to the per-segment values, the systematic parts and the pose, the frames eliminated.
numpy chain: a segment's change moves what follows it rigidly, so the Jacobian comes from one twist per
segment and variable (:func:`line_jacobian`), not one chain evaluation per variable.
"""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.methods.correct.pairing import LINE_SIDE, in_frame
from vine_nlp.methods.settings import SLIDE
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Routing
from vine_nlp.model.segment import segment_transform, so3_exp


def line_jacobian(r: Routing, D: float, seg, frac, side: float, step: float = 1e-6):
    """Points of the line at (seg, frac) and their derivatives (3, N, 3 M) with respect to (theta, lam, length)
    of every segment: a segment's change moves everything after it rigidly (a world-frame twist
    F_k dA_k A_k^-1 F_k^-1 applied to the point), and moves the points on it through their own local transform
    (central differences of the segment transform only, vectorized: a handful of model calls instead of one
    chain evaluation per variable)."""
    M = r.segments
    F = chain_frames(r.theta, r.lam, r.length, D, r.initial_pose)
    A = segment_transform(r.theta, r.lam, r.length, D)
    seg, frac = np.asarray(seg, int), np.asarray(frac, float)
    y = np.array([0.0, side * D, 0.0, 1.0])
    local = segment_transform(r.theta[seg], r.lam[seg], frac * r.length[seg], D)
    P = (F[seg] @ local) @ y  # (N, 4)
    Finv = np.linalg.inv(F[:-1])
    Ainv = np.linalg.inv(A)
    J = np.zeros((3, seg.size, 3 * M))
    before = np.arange(M)[:, None] < seg[None, :]  # (M, N): segment k lies before point i
    args = [r.theta, r.lam, r.length]
    largs = [r.theta[seg], r.lam[seg], r.length[seg]]
    for q in range(3):
        h = step * (r.length if q == 2 else np.ones(M))
        up, dn = list(args), list(args)
        up[q], dn[q] = args[q] + h, args[q] - h
        dA = (segment_transform(*up, D) - segment_transform(*dn, D)) / (2 * h)[:, None, None]
        Xi = F[:-1] @ dA @ Ainv @ Finv  # (M, 4, 4)
        moved = np.einsum("kij,nj->ikn", Xi[:, :3, :], P) * before[None]  # (3, M, N)
        hl = h[seg]
        lu, ld = list(largs), list(largs)
        lu[q], ld[q] = largs[q] + hl, largs[q] - hl
        lu[2], ld[2] = frac * lu[2], frac * ld[2]
        dloc = (segment_transform(*lu, D) - segment_transform(*ld, D)) / (2 * hl)[:, None, None]
        own = ((F[seg][:, :3, :] @ dloc) @ y).T  # (3, N)
        block = moved.transpose(0, 2, 1)  # (3, N, M)
        block[:, np.arange(seg.size), seg] += own
        J[:, :, q * M : (q + 1) * M] = block
    return P[:, :3], J


def laplace(ab, g, shifts, ms, pts, pairs, D, sig_m, sigmas, sys_sig, prior, shared, free, centroid, Tcorr):
    """Standard deviations from the inverse Gauss-Newton Hessian of the MAP objective (module docstring).

    The measurement residuals' Jacobian is assembled from the chain's twists (:func:`line_jacobian`); the
    prior's (cheap, no model) and the free pose's (six variables) by central differences."""
    M = ab.segments
    nl = 1 if shared else M
    n_free = 6 if free else 0
    T0 = ab.initial_pose

    def unpack(q):
        th, la = q[:M], q[M : M + nl]
        la = np.full(M, la[0]) if shared else la
        ln, gg = q[M + nl : 2 * M + nl], q[2 * M + nl : 2 * M + nl + 3]
        return th, la, ln, gg, q[2 * M + nl + 3 :]

    def moved(p, m, pose):
        if m.frame != "free":
            return p
        return (in_frame(p, m, Tcorr) - centroid) @ so3_exp(pose[:3]).T + centroid + pose[3:]

    def prior_residuals(q):
        th, la, ln, gg, _ = unpack(q)
        L = prior[2] * D * math.exp(gg[2])
        sl = sigmas.length * L if sigmas.relative_length else np.full(M, sigmas.length)
        out = [(th - prior[0] - gg[0]) / sigmas.theta]
        if not shared:  # where the latest build has no actuator lambda is 1, known (prior[3] = 0)
            out.append(np.where(prior[3] > 0, (la - prior[1] - gg[1]) / sigmas.lam, (la - prior[1]) / (1e-6 * sigmas.lam)))
        out += [(ln - L) / sl, np.asarray(gg) / np.asarray(sys_sig)]
        return np.concatenate(out)

    q0 = np.concatenate([ab.theta, ab.lam[:1] if shared else ab.lam, ab.length, g, np.zeros(n_free)])
    nq = q0.size
    rows, dists = [], []
    for p, m, pr in zip(pts, ms, pairs):
        a, b, c = shifts[m.build]
        r = Routing(theta=ab.theta + a, lam=np.minimum(1.0, ab.lam + b), length=ab.length * c, initial_pose=T0)
        P, JP = line_jacobian(r, D, pr.seg, pr.frac, LINE_SIDE[m.line])
        JP[:, :, M : 2 * M] *= ab.lam + b < 1.0  # the physical rule: no lambda change beyond 1
        t = pr.tangent
        dists.append(np.linalg.norm(P - moved(p, m, np.zeros(6)), axis=1))
        # point-to-line: the tangent at the pair projected out (but SLIDE), as in the estimate
        JP = JP - (1.0 - SLIDE) * t.T[:, :, None] * np.einsum("in,ink->nk", t.T, JP)[None]
        Jm = np.zeros((3, P.shape[0], nq))
        Jm[:, :, :M] = JP[:, :, :M]
        if shared:
            Jm[:, :, M] = JP[:, :, M : 2 * M].sum(axis=2)
        else:
            Jm[:, :, M : 2 * M] = JP[:, :, M : 2 * M]
        Jm[:, :, M + nl : 2 * M + nl] = c * JP[:, :, 2 * M :]  # the build's lengths are the latest ones times c
        if m.frame == "free":
            for k in range(6):
                dq = np.zeros(6)
                dq[k] = 1e-6 * (D if k >= 3 else 1.0)
                de = -(moved(p, m, dq) - moved(p, m, -dq)) / (2 * dq[k])
                de = de - t * np.sum(t * de, axis=1, keepdims=True)
                Jm[:, :, nq - 6 + k] = de.T
        rows.append(Jm.transpose(1, 0, 2).reshape(-1, nq) / sig_m)
    steps = np.concatenate([np.full(M, 1e-6), np.full(nl, 1e-6), ab.length * 1e-6, np.full(3, 1e-6), np.full(n_free, 1e-6 * D)])
    Jp = np.empty((prior_residuals(q0).size, nq))
    for k in range(nq):
        dq = np.zeros_like(q0)
        dq[k] = steps[k]
        Jp[:, k] = (prior_residuals(q0 + dq) - prior_residuals(q0 - dq)) / (2 * steps[k])
    var = _inverse_diagonal(np.vstack(rows + [Jp]))
    sd = np.sqrt(np.maximum(var, 0.0))
    th_sd, la_sd, ln_sd, g_sd, _ = unpack(sd)
    if shared:
        la_sd = np.full(M, g_sd[1])
    sys_std = np.array([g_sd[0], g_sd[1], math.exp(g[2]) * g_sd[2]])
    return np.column_stack([th_sd, la_sd, ln_sd]), sys_std, dists


def _inverse_diagonal(J: np.ndarray) -> np.ndarray:
    """diag((J^T J)^-1), by BLAS/LAPACK kernels that stay single-threaded at this size (numpy's J.T @ J and inv()
    go through threaded OpenBLAS paths, tens to hundreds of times slower on a loaded 2-core machine)."""
    from scipy.linalg import blas, lapack  # SciPy loads only where measurements are paired

    H = blas.dsyrk(1.0, J, trans=1, lower=0)  # upper triangle of J^T J
    U, info = lapack.dpotrf(H, lower=0, clean=1)  # H = U^T U
    if info == 0:
        # the prior makes H positive definite (every variable but the pose has one, the pose is measured);
        # diag(H^-1) = row sums of squares of U^-1
        Ui, info = lapack.dtrtri(U, lower=0)
    if info == 0:
        return np.sum(Ui * Ui, axis=1)
    return np.diag(np.linalg.pinv(np.triu(H) + np.triu(H, 1).T, rcond=1e-12, hermitian=True))
