"""Rigid alignment of measured points to a model line: pose starts, ICP and a Gauss-Newton polish.

Transforms are 4x4 homogeneous matrices; ``T`` maps measured points into the model frame (``T @ measured ~ model``). The
model line is a :class:`Polyline` (distances are to the polyline). :func:`fit_pose` is the global search: principal-axis
alignments times the 24 rotations of the octahedral group, plus seeded random rotations (:func:`pose_starts`), each
refined by ICP (closest point, Kabsch SVD update) on a subsample, the best few polished by a damped Gauss-Newton on the
point-to-line distances."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vine_nlp.methods.settings import GLOBAL_POINTS, ICP_GLOBAL_ITER, POLISH_TOP

# ---------------------------------------------------------------- rigid transforms


def apply_transform(T, points) -> np.ndarray:
    """Points (K, 3) moved by the 4x4 transform T."""
    T = np.asarray(T, float)
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


def invert_transform(T) -> np.ndarray:
    T = np.asarray(T, float)
    return make_transform(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])


def make_transform(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _kabsch(X, Y):
    """R, t minimizing sum |R x + t - y|^2 (Kabsch/Umeyama without scale)."""
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    H = (X - mx).T @ (Y - my)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, my - R @ mx


def principal_axes(X):
    """Centroid and principal axes (columns, decreasing variance, right-handed) of a point set."""
    c = X.mean(axis=0)
    if X.shape[0] < 2:
        return c, np.eye(3)
    w, V = np.linalg.eigh(np.cov((X - c).T) + 1e-300 * np.eye(3))
    V = V[:, np.argsort(w)[::-1]]
    if np.linalg.det(V) < 0:
        V[:, 2] *= -1
    return c, V


def _octahedral() -> np.ndarray:
    """The 24 proper rotations mapping the coordinate axes onto themselves; the four
    diagonal ones (identity and the sign flips of two axes) first."""
    from scipy.spatial.transform import Rotation  # SciPy loads where it is used: the command line starts faster
    G = np.round(Rotation.create_group("O").as_matrix())
    diag = np.array([np.allclose(g, np.diag(np.diag(g))) for g in G])
    first = G[diag]
    first = first[np.argsort([-np.trace(g) for g in first], kind="stable")]
    return np.concatenate([first, G[~diag]])


def pose_starts(source, target, starts: int = 24, seed: int = 0) -> list[np.ndarray]:
    """Deterministic starting transforms mapping ``source`` onto ``target``.

    The principal axes of both point sets are aligned in all 24 ways of the octahedral group (every axis permutation
    with every sign flip that keeps a rotation; the 4 pure sign flips first), centroid onto centroid. Beyond 24, seeded
    uniformly random rotations follow."""
    cx, Vx = principal_axes(np.asarray(source, float))
    cy, Vy = principal_axes(np.asarray(target, float))
    Rs = [Vy @ g @ Vx.T for g in _octahedral()][: max(starts, 1)]
    if starts > 24:
        from scipy.spatial.transform import Rotation  # SciPy loads where it is used: the command line starts faster
        Rs += list(Rotation.random(starts - 24, random_state=seed).as_matrix())
    return [make_transform(R, cy - R @ cx) for R in Rs]


# ---------------------------------------------------------------- model lines and measured point sets


class Polyline:
    """A densely sampled line; closest points on it (a line of one point: that point)."""

    def __init__(self, points, s_tube=None):
        p = np.asarray(points, float).reshape(-1, 3)
        if p.shape[0] == 0:
            raise ValueError("a model line needs at least one point")
        keep = np.r_[True, np.linalg.norm(np.diff(p, axis=0), axis=1) > 0]
        self.p = p[keep]
        self.s_tube = None if s_tube is None else np.asarray(s_tube, float)[keep]
        self.path = self.p.shape[0] >= 2
        from scipy.spatial import cKDTree  # SciPy loads where it is used: the command line starts faster
        self.tree = cKDTree(self.p)
        if self.path:
            self.d = np.diff(self.p, axis=0)
            self.seglen = np.linalg.norm(self.d, axis=1)
            self.tangent = self.d / self.seglen[:, None]
            self.s = np.r_[0.0, np.cumsum(self.seglen)]
        else:
            self.s = np.zeros(self.p.shape[0])

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def project(self, x):
        """Closest points of (K, 3) ``x``: (closest, distance, s, tangent, free_end).

        ``s`` is the arc length of the closest point along the line, ``tangent`` the unit direction of its piece and
        ``free_end`` marks points whose closest point is an end of the line (or a line's one point): their residual is
        not perpendicular to the line."""
        x = np.asarray(x, float)
        K = x.shape[0]
        if not self.path:
            dist, idx = self.tree.query(x)
            return self.p[idx], dist, self.s[idx], np.zeros((K, 3)), np.ones(K, bool)
        nseg = self.d.shape[0]
        k = min(3, self.p.shape[0])
        _, idx = self.tree.query(x, k=k)
        idx = idx.reshape(K, k)
        cand = np.clip(np.concatenate([idx - 1, idx], axis=1), 0, nseg - 1)  # (K, 2k) segments
        a = self.p[cand]
        d = self.d[cand]
        u = np.clip(np.einsum("kcj,kcj->kc", x[:, None, :] - a, d) / (self.seglen[cand] ** 2), 0.0, 1.0)
        c = a + u[..., None] * d
        dist2 = np.sum((x[:, None, :] - c) ** 2, axis=2)
        j = np.argmin(dist2, axis=1)
        rows = np.arange(K)
        seg, uu = cand[rows, j], u[rows, j]
        closest = c[rows, j]
        s = self.s[seg] + uu * self.seglen[seg]
        end = ((seg == 0) & (uu <= 0.0)) | ((seg == nseg - 1) & (uu >= 1.0))
        return closest, np.sqrt(dist2[rows, j]), s, self.tangent[seg], end

    def tube_length_at(self, s):
        """Unactuated tube length at arc length ``s`` of this line (linear between samples)."""
        if self.s_tube is None:
            return np.full(np.shape(s), np.nan)
        return np.interp(s, self.s, self.s_tube)


@dataclass
class PointSet:
    """Measured points of one line against the model polyline of that line."""

    points: np.ndarray  # (K, 3), measurement frame
    line: Polyline


def project_all(sets, Xt):
    """Closest points of the stacked transformed points, set by set."""
    ends = np.cumsum([0] + [st.points.shape[0] for st in sets])
    parts = [st.line.project(Xt[a:b]) for st, a, b in zip(sets, ends[:-1], ends[1:])]
    return [np.concatenate(v) for v in zip(*parts)]


def stack_points(sets):
    return np.concatenate([st.points for st in sets])


def clean_points(points, what="measured"):
    X = np.asarray(points, float).reshape(-1, 3)
    X = X[np.all(np.isfinite(X), axis=1)]
    if X.shape[0] < 3:
        raise ValueError(f"{what}: a fit needs at least 3 finite points, got {X.shape[0]}")
    return X


def r_squared(measured, residuals, groups=None) -> float:
    """Coefficient of determination of measured coordinates, as the paper uses it.

    1 - SS_res / SS_tot with SS_res the sum of squared distances of the measured points to the model and SS_tot the sum
    of squared distances to the centroid of the measured points (of each group, e.g. each measured line, separately)."""
    X, res = np.asarray(measured, float), np.asarray(residuals, float)
    ss_res = float(np.sum(res**2))
    groups = np.zeros(X.shape[0], int) if groups is None else groups
    ss_tot = 0.0
    for gk in np.unique(groups):
        Xg = X[groups == gk]
        ss_tot += float(np.sum((Xg - Xg.mean(axis=0)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else (1.0 if ss_res == 0 else -math.inf)


# ---------------------------------------------------------------- ICP and polish


def icp_refine(sets, T, max_iter=100, tol=1e-10):
    """Point-to-closest-point ICP with Kabsch updates. Returns (T, mean squared distance, iterations)."""
    X = stack_points(sets)
    prev, it = math.inf, 0
    for it in range(1, max_iter + 1):
        c, d, *_ = project_all(sets, apply_transform(T, X))
        cost = float(np.mean(d**2))
        if (it > 1 and prev - cost <= tol * prev) or cost == 0.0:  # prev is inf on the first pass: inf <= inf
            return T, cost, it
        prev = cost
        T = make_transform(*_kabsch(X, c))
    c, d, *_ = project_all(sets, apply_transform(T, X))
    return T, float(np.mean(d**2)), it


def _skew(q):
    Q = np.zeros(q.shape[:-1] + (3, 3))
    Q[..., 0, 1], Q[..., 0, 2] = -q[..., 2], q[..., 1]
    Q[..., 1, 0], Q[..., 1, 2] = q[..., 2], -q[..., 0]
    Q[..., 2, 0], Q[..., 2, 1] = -q[..., 1], q[..., 0]
    return Q


def polish_pose(sets, T, max_iter=50, tol=1e-10):
    """Damped Gauss-Newton (Levenberg-Marquardt) on the point-to-line distances.

    Linearizes each distance about its closest point with the projector I - t t^T onto the line's normal plane (the line
    may slide along itself), so unlike point-to-point ICP it converges quickly along the near-symmetric sliding
    directions of a helix. Returns (T, mean squared distance, iterations)."""
    X = stack_points(sets)
    K = X.shape[0]
    scale = max(float(np.ptp(X, axis=0).max()), 1e-12)
    floor = (1e-13 * scale) ** 2

    def evaluate(T):
        Xt = apply_transform(T, X)
        c, d, _, tan, end = project_all(sets, Xt)
        return Xt, c, tan, end, float(np.sum(d**2))

    state = evaluate(T)
    mu, it = 1e-4, 0
    for it in range(1, max_iter + 1):  # noqa: B007  (the count is returned after the loop)
        Xt, c, tan, end, cost = state
        if cost <= floor * K:
            break
        P = np.eye(3) - tan[:, :, None] * tan[:, None, :]
        P[end] = np.eye(3)
        c0 = Xt.mean(axis=0)
        A = np.zeros((K, 3, 6))
        A[:, :, :3] = -_skew(Xt - c0)
        A[:, :, 3:] = np.eye(3)
        J = P @ A
        r = np.einsum("kij,kj->ki", P, Xt - c)
        H = np.einsum("kia,kib->ab", J, J)
        g = np.einsum("kia,ki->a", J, r)
        dH = np.diag(np.diag(H)) + 1e-12 * np.trace(H) * np.eye(6) + 1e-300 * np.eye(6)
        improved = False
        radius = float(np.sqrt(np.mean(np.sum((Xt - c0) ** 2, axis=1))))
        while mu < 1e10:
            step = np.linalg.solve(H + mu * dH, -g)
            if np.linalg.norm(step[:3]) * radius + np.linalg.norm(step[3:]) <= 1e-15 * scale:
                break  # nothing left to gain at this precision
            from scipy.spatial.transform import Rotation  # SciPy loads where it is used: the command line starts faster
            Rw = Rotation.from_rotvec(step[:3]).as_matrix()
            Tn = make_transform(Rw @ T[:3, :3], Rw @ (T[:3, 3] - c0) + c0 + step[3:])
            new = evaluate(Tn)
            if new[4] < cost:
                improved = True
                break
            mu *= 5.0
        if not improved:
            break
        mu = max(mu / 3.0, 1e-12)
        T, state = Tn, new
        if cost - new[4] <= tol * cost:
            break
    return T, state[4] / K, it


@dataclass
class PoseFit:
    T: np.ndarray
    mse: float
    iterations: int


def subsample(sets, n, seed=0):
    """The same sets with at most ``n`` points in all (deterministic), for the global stage."""
    total = sum(st.points.shape[0] for st in sets)
    if total <= n:
        return sets
    rng = np.random.default_rng(seed)
    out = []
    for st in sets:
        k = min(max(3, int(round(n * st.points.shape[0] / total))), st.points.shape[0])
        idx = np.sort(rng.choice(st.points.shape[0], k, replace=False))
        out.append(PointSet(st.points[idx], st.line))
    return out


def fit_pose(sets, starts_T, global_iter=ICP_GLOBAL_ITER, top=POLISH_TOP, polish_iter=50) -> PoseFit:
    """ICP from every start (on a subsample), then polish the best few on all points."""
    few = subsample(sets, GLOBAL_POINTS)
    runs, iters = [], 0
    for T0 in starts_T:
        T, mse, it = icp_refine(few, T0, max_iter=global_iter, tol=1e-9)
        iters += it
        runs.append((mse, T))
    runs.sort(key=lambda r: r[0])
    best = None
    for _, T in runs[:top]:
        T, mse, it = icp_refine(sets, T, max_iter=20, tol=1e-9) if few is not sets else (T, None, 0)
        iters += it
        T, mse, it = polish_pose(sets, T, max_iter=polish_iter)
        iters += it
        if best is None or mse < best.mse:
            best = PoseFit(T, mse, 0)
    best.iterations = iters
    return best
