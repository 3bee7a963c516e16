"""Layer 3: model validation, fitting the model to measured shapes (paper Sec. V).

Everything here compares measured points with the geometric model of a *known*
routing; only the rigid pose (and, for an sPAM, the shared lambda) is estimated.

* :func:`fit_problem` / :func:`fit_lines` (``vine-nlp fit``): measured points in any
  order and any pose against the model's center, inner or outer line. Global search
  over the rigid pose (principal-axis alignments times the 24 rotations of the
  octahedral group, plus seeded random rotations), each start refined by ICP
  (closest point on the densely sampled model line, Kabsch SVD update) and the best
  few polished by a damped Gauss-Newton on the point-to-line distances. With
  ``free = ("lambda",)`` an outer 1-D search over the shared lambda (coarse grid,
  then bounded Brent) re-runs the pose fit (paper Sec. V-A2 and V-B2).
* :func:`best_fit_helix`, :func:`best_fit_helix_pair`, :func:`parameter_errors`: the
  free helix fits of Sec. V-A1 (paper Fig. 5(b) and Fig. 6). By default they minimize
  the orthogonal distance to the helix (as the model fit does, so R^2 values compare);
  the paper's eq. (error_func), the in-plane distance at the point's height, is
  available as ``residual="height"`` (it multiplies axial noise by R/b on flat helices).
* :func:`icp`: rigid alignment of a measured path to a modeled one (Figs. 7 and 8).
* :func:`fit_frames`: many frames of one actuator, lambda per frame (Fig. 9(d)).

The model line is sampled with spacing <= ``SPACING * D`` and treated as a polyline;
distances are to the polyline (the chord error of that spacing is about
``(D/10)^2 kappa / 8``, far below tracker noise).

Transforms are 4x4 homogeneous matrices. ``T`` returned by the fits maps measured
points into the model frame (``T @ measured ~ model``); the archived shape is the
model moved onto the measurement, i.e. the routing's initial pose becomes
``inv(T) @ initial_pose``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize_scalar
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from vine_nlp.design.problem import MEASURED_LINES, FitProblem, Routing
from vine_nlp.design.result import Result, Shape
from vine_nlp.model import helix_forward, helix_inverse, shape_lines
from vine_nlp.model.chain import segment_end_samples

SPACING = 0.1  # model lines are sampled at <= SPACING * D
LAMBDA_BOUNDS = (0.3, 1.0)
LAMBDA_GRID_STEP = 0.05
GLOBAL_POINTS = 300  # measured points used by the ICP of the global stage (all points are used for the polish)
ICP_GLOBAL_ITER = 60
POLISH_TOP = 3
GRID_POLISH_ITER = 12  # the lambda grid only ranks values; the refinement polishes fully
GRID_POINTS = 1000  # measured points used while ranking the lambda grid
LINE_CODE = {name: k for k, name in enumerate(MEASURED_LINES)}  # center 0, inner 1, outer 2

__all__ = [
    "fit_problem",
    "fit_lines",
    "fit_frames",
    "FrameFit",
    "icp",
    "best_fit_helix",
    "best_fit_helix_pair",
    "parameter_errors",
    "r_squared",
    "model_lines",
    "describe_fit",
    "pose_starts",
    "Polyline",
    "apply_transform",
    "invert_transform",
]


# ---------------------------------------------------------------- rigid transforms


def apply_transform(T, points) -> np.ndarray:
    """Points (K, 3) moved by the 4x4 transform T."""
    T = np.asarray(T, float)
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


def invert_transform(T) -> np.ndarray:
    T = np.asarray(T, float)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _make_T(R, t) -> np.ndarray:
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


def _principal(X):
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
    G = np.round(Rotation.create_group("O").as_matrix())
    diag = np.array([np.allclose(g, np.diag(np.diag(g))) for g in G])
    first = G[diag]
    first = first[np.argsort([-np.trace(g) for g in first], kind="stable")]
    return np.concatenate([first, G[~diag]])


def pose_starts(source, target, starts: int = 24, seed: int = 0) -> list[np.ndarray]:
    """Deterministic starting transforms mapping ``source`` onto ``target``.

    The principal axes of both point sets are aligned in all 24 ways of the
    octahedral group (every axis permutation with every sign flip that keeps a
    rotation; the 4 pure sign flips first), centroid onto centroid. Beyond 24,
    seeded uniformly random rotations follow.
    """
    cx, Vx = _principal(np.asarray(source, float))
    cy, Vy = _principal(np.asarray(target, float))
    Rs = [Vy @ g @ Vx.T for g in _octahedral()][: max(starts, 1)]
    if starts > 24:
        Rs += list(Rotation.random(starts - 24, random_state=seed).as_matrix())
    return [_make_T(R, cy - R @ cx) for R in Rs]


# ---------------------------------------------------------------- model lines as polylines


class Polyline:
    """A densely sampled line; closest points on it (``path=False``: on its vertices only)."""

    def __init__(self, points, s_tube=None, path: bool = True):
        p = np.asarray(points, float).reshape(-1, 3)
        if p.shape[0] == 0:
            raise ValueError("a model line needs at least one point")
        keep = np.r_[True, np.linalg.norm(np.diff(p, axis=0), axis=1) > 0]
        self.p = p[keep]
        self.s_tube = None if s_tube is None else np.asarray(s_tube, float)[keep]
        self.path = path and self.p.shape[0] >= 2
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

        ``s`` is the arc length of the closest point along the line, ``tangent`` the
        unit direction of its piece and ``free_end`` marks points whose closest point
        is an end of the line (or a vertex, for ``path=False``): their residual is
        not perpendicular to the line.
        """
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
class _Set:
    """Measured points of one line against the model polyline of that line."""

    points: np.ndarray  # (K, 3), measurement frame
    line: Polyline


def _project_all(sets, Xt):
    """Closest points of the stacked transformed points, set by set."""
    out = [[], [], [], [], []]
    k0 = 0
    for st in sets:
        k1 = k0 + st.points.shape[0]
        for lst, v in zip(out, st.line.project(Xt[k0:k1])):
            lst.append(v)
        k0 = k1
    return [np.concatenate(v) for v in out]


def _stack(sets):
    return np.concatenate([st.points for st in sets])


# ---------------------------------------------------------------- ICP and polish


def _icp(sets, T, max_iter=100, tol=1e-10):
    """Point-to-closest-point ICP with Kabsch updates. Returns (T, mean squared distance, iterations)."""
    X = _stack(sets)
    prev = math.inf
    it = 0
    for it in range(1, max_iter + 1):
        c, d, *_ = _project_all(sets, apply_transform(T, X))
        cost = float(np.mean(d**2))
        if prev - cost <= tol * prev or cost == 0.0:
            return T, cost, it
        prev = cost
        T = _make_T(*_kabsch(X, c))
    c, d, *_ = _project_all(sets, apply_transform(T, X))
    return T, float(np.mean(d**2)), it


def _skew(q):
    Q = np.zeros(q.shape[:-1] + (3, 3))
    Q[..., 0, 1], Q[..., 0, 2] = -q[..., 2], q[..., 1]
    Q[..., 1, 0], Q[..., 1, 2] = q[..., 2], -q[..., 0]
    Q[..., 2, 0], Q[..., 2, 1] = -q[..., 1], q[..., 0]
    return Q


def _polish(sets, T, max_iter=50, tol=1e-10):
    """Damped Gauss-Newton (Levenberg-Marquardt) on the point-to-line distances.

    Linearizes each distance about its closest point with the projector
    I - t t^T onto the line's normal plane (the line may slide along itself), so
    unlike point-to-point ICP it converges quickly along the near-symmetric
    sliding directions of a helix. Returns (T, mean squared distance, iterations).
    """
    X = _stack(sets)
    K = X.shape[0]
    scale = max(float(np.ptp(X, axis=0).max()), 1e-12)
    floor = (1e-13 * scale) ** 2

    def evaluate(T):
        Xt = apply_transform(T, X)
        c, d, _, tan, end = _project_all(sets, Xt)
        return Xt, c, tan, end, float(np.sum(d**2))

    state = evaluate(T)
    mu = 1e-4
    it = 0
    for it in range(1, max_iter + 1):
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
            Rw = Rotation.from_rotvec(step[:3]).as_matrix()
            Tn = _make_T(Rw @ T[:3, :3], Rw @ (T[:3, 3] - c0) + c0 + step[3:])
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
class _PoseFit:
    T: np.ndarray
    mse: float
    iterations: int


def _subsample(sets, n, seed=0):
    """The same sets with at most ``n`` points in all (deterministic), for the global stage."""
    total = sum(st.points.shape[0] for st in sets)
    if total <= n:
        return sets
    rng = np.random.default_rng(seed)
    out = []
    for st in sets:
        k = max(3, int(round(n * st.points.shape[0] / total)))
        k = min(k, st.points.shape[0])
        idx = np.sort(rng.choice(st.points.shape[0], k, replace=False))
        out.append(_Set(st.points[idx], st.line))
    return out


def _fit_pose(sets, starts_T, global_iter=ICP_GLOBAL_ITER, top=POLISH_TOP, polish_iter=50) -> _PoseFit:
    """ICP from every start (on a subsample), then polish the best few on all points."""
    few = _subsample(sets, GLOBAL_POINTS)
    runs = []
    iters = 0
    for T0 in starts_T:
        T, mse, it = _icp(few, T0, max_iter=global_iter, tol=1e-9)
        iters += it
        runs.append((mse, T))
    runs.sort(key=lambda r: r[0])
    best = None
    for _, T in runs[:top]:
        T, mse, it = _icp(sets, T, max_iter=20, tol=1e-9) if few is not sets else (T, None, 0)
        iters += it
        T, mse, it = _polish(sets, T, max_iter=polish_iter)
        iters += it
        if best is None or mse < best.mse:
            best = _PoseFit(T, mse, 0)
    best.iterations = iters
    return best


# ---------------------------------------------------------------- the model lines


def model_lines(routing: Routing, diameter: float, spacing: float = SPACING):
    """Center, inner and outer lines of ``routing`` sampled at <= spacing * D.

    Returns (dict line -> (P, 3), s_tube (P,), per_segment (M,)): s_tube is the
    unactuated tube length of every sample; every segment end is a sample.
    The lines' actuated lengths are at most 1/cos(theta) times the unactuated one,
    which the sample count allows for.
    """
    h = spacing * diameter * np.cos(np.clip(np.abs(routing.theta), 0, 1.5))
    per_segment = np.maximum(1, np.ceil(routing.length / h)).astype(int)
    seg, frac = segment_end_samples(routing.length, per_segment)
    c, i, o = shape_lines(routing.theta, routing.lam, routing.length, diameter, seg, frac, routing.initial_pose)
    starts = np.r_[0.0, np.cumsum(routing.length)]
    s_tube = starts[seg] + frac * routing.length[seg]
    return {"center": c, "inner": i, "outer": o}, s_tube, per_segment


def _with_lambda(routing: Routing, lam) -> Routing:
    if lam is None:
        return routing
    return Routing(routing.theta, np.full(routing.segments, float(lam)), routing.length, routing.initial_pose)


def r_squared(measured, residuals, groups=None) -> float:
    """Coefficient of determination of measured coordinates, as the paper uses it.

    1 - SS_res / SS_tot with SS_res the sum of squared distances of the measured
    points to the model and SS_tot the sum of squared distances to the centroid of
    the measured points (of each group, e.g. each measured line, separately).
    """
    X = np.asarray(measured, float)
    res = np.asarray(residuals, float)
    ss_res = float(np.sum(res**2))
    if groups is None:
        groups = np.zeros(X.shape[0], int)
    ss_tot = 0.0
    for gk in np.unique(groups):
        Xg = X[groups == gk]
        ss_tot += float(np.sum((Xg - Xg.mean(axis=0)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else (1.0 if ss_res == 0 else -math.inf)


# ---------------------------------------------------------------- the fit


def _clean(points, what="measured"):
    X = np.asarray(points, float).reshape(-1, 3)
    X = X[np.all(np.isfinite(X), axis=1)]
    if X.shape[0] < 3:
        raise ValueError(f"{what}: a fit needs at least 3 finite points, got {X.shape[0]}")
    return X


class _Fitter:
    """Pose (and lambda) fit of measured lines to the model of one routing."""

    def __init__(self, routing, diameter, measured: dict, starts=24, seed=0, spacing=SPACING):
        self.routing = routing
        self.D = float(diameter)
        self.measured = {line: _clean(pts, f"measured {line} line") for line, pts in measured.items()}
        for line in self.measured:
            if line not in MEASURED_LINES:
                raise ValueError(f"line must be one of {MEASURED_LINES}, not {line!r}")
        self.starts, self.seed, self.spacing = starts, seed, spacing
        self.evaluations = []  # (lambda, rmse)
        self.iterations = 0
        self._cache = {}

    def sets(self, lam):
        key = None if lam is None else round(float(lam), 12)
        if key not in self._cache:
            lines, s_tube, _ = model_lines(_with_lambda(self.routing, lam), self.D, self.spacing)
            self._cache = {key: [_Set(pts, Polyline(lines[line], s_tube)) for line, pts in self.measured.items()]}
        return self._cache[key]

    def global_starts(self, sets):
        X = _stack(sets)
        Y = np.concatenate([st.line.p for st in sets])
        return pose_starts(X, Y, self.starts, self.seed)

    def pose(self, lam, warm=(), full=True, polish_iter=50) -> _PoseFit:
        sets = self.sets(lam)
        starts = list(warm) + (self.global_starts(sets) if full else [])
        if full:
            # the grid stage (short polish) ranks on a subsample; same points for every lambda
            fit = _fit_pose(sets if polish_iter >= 50 else _subsample(sets, GRID_POINTS), starts, polish_iter=polish_iter)
        else:  # warm starts only: short ICP then polish, keep the best
            fit = None
            for T0 in starts:
                T, _, it1 = _icp(sets, T0, max_iter=10, tol=1e-9)
                T, mse, it2 = _polish(sets, T)
                self.iterations += it1 + it2
                if fit is None or mse < fit.mse:
                    fit = _PoseFit(T, mse, 0)
        self.iterations += fit.iterations
        if lam is not None:
            self.evaluations.append((float(lam), math.sqrt(fit.mse)))
        return fit

    def fit_lambda(self, lam0, bounds=LAMBDA_BOUNDS, warm=(), local=None):
        """Shared lambda minimizing the pose-fitted RMSE.

        ``local=None``: coarse grid over ``bounds`` (full pose search at every
        value, warm-started from the best pose so far), then bounded Brent between
        the neighbours of the best grid value. ``local=(lo, hi)``: Brent in that
        interval only, warm-started (for frame sequences).
        """
        best = {"lam": None, "fit": None}

        def keep(lam, fit):
            if best["fit"] is None or fit.mse < best["fit"].mse:
                best["lam"], best["fit"] = lam, fit

        if local is None:
            lo, hi = bounds
            n = max(2, int(round((hi - lo) / LAMBDA_GRID_STEP)) + 1)
            grid = np.unique(np.round(np.r_[np.linspace(lo, hi, n), np.clip(lam0, lo, hi)], 12))
            costs, poses = [], []
            for lam in grid:
                w = list(warm) + ([poses[int(np.argmin(costs))]] if poses else [])
                fit = self.pose(lam, warm=w, full=True, polish_iter=GRID_POLISH_ITER)
                costs.append(fit.mse)
                poses.append(fit.T)
            k = int(np.argmin(costs))
            a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
            self.grid = (grid, np.sqrt(costs))
            # grid costs are for ranking only (short polish, subsample): redo the best one fully
            keep(float(grid[k]), self.pose(float(grid[k]), warm=[poses[k]], full=False))
        else:
            a, b = local
            for T in warm:
                keep(float(np.clip(lam0, a, b)), self.pose(float(np.clip(lam0, a, b)), warm=[T], full=False))

        def objective(lam):
            fit = self.pose(lam, warm=[best["fit"].T], full=False)
            keep(float(lam), fit)
            return fit.mse

        if b > a:
            minimize_scalar(objective, bounds=(a, b), method="bounded", options={"xatol": 1e-5})
        return best["lam"], best["fit"]


def fit_lines(
    routing: Routing,
    diameter: float,
    measured: dict,
    free=(),
    starts: int = 24,
    seed: int = 0,
    spacing: float = SPACING,
    lambda_bounds=LAMBDA_BOUNDS,
    warm_start=None,
):
    """Fit the model of ``routing`` to measured lines sharing one rigid pose.

    ``measured``: {"center" | "inner" | "outer": (K, 3) points in any order}; several
    lines are fitted together, as the paper does for the inner and outer lines of
    its static helices. ``free``: () or ("lambda",) (one shared lambda).
    ``warm_start``: optional 4x4 measured -> model transform tried besides the global starts.

    Returns (Result, extras): see :func:`fit_problem`.
    """
    t0 = time.perf_counter()
    free = tuple(free)
    unknown = set(free) - {"lambda"}
    if unknown:
        raise ValueError(f"free parameters must be () or ('lambda',), not {free}")
    fitter = _Fitter(routing, diameter, measured, starts=starts, seed=seed, spacing=spacing)
    warm = [] if warm_start is None else [np.asarray(warm_start, float)]
    lam_fit = None
    if "lambda" in free:
        lam0 = float(np.mean(routing.lam))
        lam_fit, pose = fitter.fit_lambda(lam0, lambda_bounds, warm=warm)
    else:
        pose = fitter.pose(None, warm=warm, full=True)
    result, extras = _finish(fitter, lam_fit, pose.T, free, spacing)
    result.solve_time_s = time.perf_counter() - t0
    result.iterations = fitter.iterations
    result.stats.update(starts=starts, seed=seed)
    if "lambda" in free:
        grid, costs = fitter.grid
        result.stats.update(lambda_bounds=list(lambda_bounds), lambda_grid=grid.tolist(), lambda_grid_rmse=costs.tolist())
    return result, extras


def _finish(fitter: _Fitter, lam_fit, T, free, spacing):
    """Result and extras of a fitted pose (and lambda)."""
    routing = _with_lambda(fitter.routing, lam_fit)
    D = fitter.D
    lines, s_tube, _ = model_lines(routing, D, spacing)
    polylines = {name: Polyline(pts, s_tube) for name, pts in lines.items()}
    Tinv = invert_transform(T)
    fitted = Routing(routing.theta, routing.lam, routing.length, Tinv @ routing.initial_pose)
    shape = Shape(*(apply_transform(Tinv, lines[name]) for name in ("center", "inner", "outer")))

    pts, closest, err, s, s_tube_pts, code = [], [], [], [], [], []
    per_line = {}
    for line, X in fitter.measured.items():
        Xt = apply_transform(T, X)
        c, d, sl, _, _ = polylines[line].project(Xt)
        pts.append(X)
        closest.append(apply_transform(Tinv, c))
        err.append(d)
        s.append(sl)
        s_tube_pts.append(polylines[line].tube_length_at(sl))
        code.append(np.full(X.shape[0], LINE_CODE[line]))
        per_line[line] = Xt
    pts, closest, err, s, s_tube_pts, code = map(np.concatenate, (pts, closest, err, s, s_tube_pts, code))
    rmse = float(np.sqrt(np.mean(err**2)))
    metrics = {
        "rmse": rmse,
        "max_error": float(err.max()),
        "r2": r_squared(pts, err, code),
        "lambda": float(lam_fit) if lam_fit is not None else float(np.mean(routing.lam)),
    }
    stats = {
        "line": ",".join(fitter.measured),
        "free": list(free),
        "points": int(pts.shape[0]),
        "spacing": spacing * D,
        "transform": T.tolist(),
        "lambda_evaluations": len(fitter.evaluations),
        "model_line_length": {name: polylines[name].length for name in MEASURED_LINES},
    }
    # RMSE of all measured points against each model line, at the fitted pose (diagnostic:
    # the measured line should be the one with the smallest).
    X_all = np.concatenate(list(per_line.values()))
    for name in MEASURED_LINES:
        _, d, *_ = polylines[name].project(X_all)
        stats[f"rmse_{name}"] = float(np.sqrt(np.mean(d**2)))
    for line in fitter.measured:  # the measured lines' own RMSE (paper Fig. 5(a): inner and outer separately)
        stats[f"rmse_measured_{line}"] = float(np.sqrt(np.mean(err[code == LINE_CODE[line]] ** 2)))
    status = "optimal" if np.isfinite(rmse) else "failed"
    result = Result(method="fit", routing=fitted, shape=shape, status=status, metrics=metrics, stats=stats, diameter=D)
    extras = {
        "measured/points": pts,
        "measured/closest": closest,
        "measured/error": err,
        "measured/s": s,
        "measured/s_tube": s_tube_pts,
        "measured/line": code.astype(np.int8),
    }
    return result, extras


def fit_problem(problem: FitProblem, starts: int = 24, seed: int = 0):
    """Fit the model of a fit problem to its measured points (``vine-nlp fit``).

    Returns ``(result, extras)``:

    * ``result``: a :class:`Result` with method ``"fit"``; its routing is the known
      routing with the fitted lambda (``design/lambda``) and the initial pose that
      puts the model onto the measurement (``inv(T) @ routing.initial_pose``); its
      shape holds the three model lines in the measurement's frame, sampled at
      <= D/10; metrics ``rmse``, ``max_error`` (measured points to the closest point
      of the model line that was measured), ``r2`` (:func:`r_squared`) and
      ``lambda``; stats hold the transform T (measured -> model frame), the RMSE
      against each model line (``rmse_center``, ``rmse_inner``, ``rmse_outer``) and
      the lambda grid that was searched.
    * ``extras``: arrays to archive as datasets, keyed by their archive path:
      ``measured/points`` (K, 3) as given (non-finite rows dropped),
      ``measured/closest`` (K, 3) closest model points (measurement frame),
      ``measured/error`` (K,), ``measured/s`` (K,) arc length of the closest point
      along the fitted model line, ``measured/s_tube`` (K,) the same as unactuated
      tube length, ``measured/line`` (K,) 0 center, 1 inner, 2 outer.
    """
    return fit_lines(
        problem.routing, problem.diameter, {problem.line: problem.measured}, free=problem.free, starts=starts, seed=seed
    )


def describe_fit(result: Result, units: str = "cm") -> str:
    """One line for the command line: what was fitted and how well."""
    m, st = result.metrics, result.stats
    free = st.get("free", [])
    lam = f", lambda {m['lambda']:.4f}" + (" (fitted)" if "lambda" in free else " (given)")
    return (
        f"fit of the {st.get('line', '?')} line to {st.get('points', '?')} points: rmse {m['rmse']:.4g} {units}, "
        f"max {m['max_error']:.4g} {units}, R^2 {m['r2']:.4f}{lam}"
    )


# ---------------------------------------------------------------- ICP of general paths


def icp(
    source, target, initial=None, max_iter: int = 100, tol: float = 1e-10, *, path: bool = True, starts: int = 24, seed: int = 0
):
    """Rigid alignment of ``source`` points onto ``target`` (paper Figs. 7 and 8).

    ``target`` is a modeled path (ordered samples, distances to its polyline) or,
    with ``path=False``, a point cloud (distances to its points). ``initial``: a
    4x4 starting transform; None runs the global start set of :func:`pose_starts`
    (``starts`` of them). Point-to-closest-point ICP with Kabsch updates, then a
    point-to-line Gauss-Newton polish.

    Returns (T, rmse, max_error): T maps source onto target.
    """
    src = _clean(source, "source")
    sets = [_Set(src, Polyline(np.asarray(target, float), path=path))]
    if initial is None:
        T = _fit_pose(sets, pose_starts(src, sets[0].line.p, starts, seed)).T
    else:
        T, _, _ = _icp(sets, np.asarray(initial, float), max_iter=max_iter, tol=tol)
    T, _, _ = _polish(sets, T, max_iter=max_iter, tol=tol)
    _, d, *_ = sets[0].line.project(apply_transform(T, src))
    return T, float(np.sqrt(np.mean(d**2))), float(d.max())


# ---------------------------------------------------------------- frame sequences


class FrameFit(tuple):
    """``(lambda, rmse)`` of one frame; more as attributes: ``r2``, ``max_error``,
    ``transform`` (measured -> model), ``error`` and ``s`` (per point, for the
    error-against-length figure), ``points`` (finite measured points), ``ok``.
    A frame that could not be fitted (fewer than ``min_points`` finite points) is
    ``(nan, nan)`` with ``ok = False``."""

    def __new__(cls, lam, rmse, **info):
        obj = super().__new__(cls, (float(lam), float(rmse)))
        obj.__dict__.update(info)
        return obj

    @property
    def lam(self) -> float:
        return self[0]

    @property
    def rmse(self) -> float:
        return self[1]


def fit_frames(
    problem: FitProblem, measured_list, starts: int = 24, seed: int = 0, window: float = 0.1, min_points: int = 4
):
    """Fit every frame of a sequence of one actuator (paper Fig. 9(d)): a list of :class:`FrameFit`.

    Each frame is one point set of ``problem.line`` (rows with NaN, e.g. occluded
    markers, are dropped). The first good frame gets the full global fit; every
    later one starts from the previous frame's pose and lambda (Brent over
    lambda within +-``window``), and falls back to the full global fit when that
    is clearly worse (RMSE above 3x the previous frame's or 5 % of D). With lambda
    not free only the pose is fitted.
    """
    free = tuple(problem.free)
    D = problem.diameter
    out = []
    prev = None  # (lam, T, rmse)
    for k, frame in enumerate(measured_list):
        X = np.asarray(frame, float).reshape(-1, 3)
        X = X[np.all(np.isfinite(X), axis=1)]
        if X.shape[0] < min_points:
            out.append(
                FrameFit(math.nan, math.nan, ok=False, r2=math.nan, max_error=math.nan, transform=None,
                         error=np.zeros(0), s=np.zeros(0), points=X)
            )
            continue
        fitter = _Fitter(problem.routing, D, {problem.line: X}, starts=starts, seed=seed)
        lam, fit = None, None
        if prev is not None:
            if "lambda" in free:
                lo, hi = max(LAMBDA_BOUNDS[0], prev[0] - window), min(LAMBDA_BOUNDS[1], prev[0] + window)
                lam, fit = fitter.fit_lambda(prev[0], local=(lo, hi), warm=[prev[1]])
            else:
                fit = fitter.pose(None, warm=[prev[1]], full=False)
        if fit is None or math.sqrt(fit.mse) > max(3.0 * prev[2], 0.05 * D):
            warm = [] if prev is None else [prev[1]]
            if "lambda" in free:
                lam0 = prev[0] if prev is not None else float(np.mean(problem.routing.lam))
                lam_g, fit_g = fitter.fit_lambda(lam0, LAMBDA_BOUNDS, warm=warm)
            else:
                lam_g, fit_g = None, fitter.pose(None, warm=warm, full=True)
            if fit is None or fit_g.mse < fit.mse:
                lam, fit = lam_g, fit_g
        result, extras = _finish(fitter, lam, fit.T, free, SPACING)
        m = result.metrics
        prev = (m["lambda"], fit.T, m["rmse"])
        out.append(
            FrameFit(m["lambda"], m["rmse"], ok=True, r2=m["r2"], max_error=m["max_error"], transform=fit.T,
                     error=extras["measured/error"], s=extras["measured/s"], points=X)
        )
    return out


# ---------------------------------------------------------------- free helices (paper Sec. V-A1, Figs. 5(b), 6)


def _frame_from_axis(a):
    """Right-handed orthonormal columns (u, v, a) with a the given axis."""
    a = np.asarray(a, float)
    a = a / np.linalg.norm(a)
    ref = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = ref - np.dot(ref, a) * a
    u /= np.linalg.norm(u)
    return np.column_stack([u, np.cross(a, u), a])


def _fibonacci_hemisphere(n):
    k = np.arange(n) + 0.5
    z = k / n  # z in (0, 1): one of each pair of opposite directions
    r = np.sqrt(1 - z**2)
    phi = math.pi * (1 + 5**0.5) * k
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _circle_fit(xy):
    """Algebraic (Kasa) circle fit: center (2,), radius."""
    A = np.column_stack([2 * xy, np.ones(xy.shape[0])])
    rhs = np.sum(xy**2, axis=1)
    sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    c = sol[:2]
    r2 = sol[2] + c @ c
    return c, math.sqrt(max(r2, 0.0))


def _helix_residuals(p, X, F0, line_idx, nradii, residual="orthogonal"):
    """Residuals of points X against helices sharing axis, pitch and phase.

    p = (alpha, beta, cx, cy, w, phi0, radius_0, ..., radius_{n-1}): the axis frame is
    F0 tilted by the rotation vector (alpha, beta, 0); in its coordinates the helix
    of radius r is h(t) = (cx + r cos(w t + phi0), cy + r sin(w t + phi0), t), w = 1/b.
    Radii are signed (a negative radius is the opposite side of the axis).

    residual="height": the paper's eq. (error_func), the in-plane difference to the
    helix point at the same height t = q_a (2 per point). It multiplies axial noise
    by r/b, which is large for flat helices. residual="orthogonal" (default): the
    difference to the closest point of the helix (3 per point), found per point by
    safeguarded Newton steps in t from the better of the same-height and the
    same-angle point.
    """
    alpha, beta, cx, cy, w, phi0 = p[:6]
    radii = np.asarray(p[6 : 6 + nradii])
    F = F0 @ Rotation.from_rotvec([alpha, beta, 0.0]).as_matrix()
    q = X @ F
    qu, qv, qa = q[:, 0] - cx, q[:, 1] - cy, q[:, 2]
    r = radii[line_idx]
    if residual == "height":
        ang = w * qa + phi0
        return np.concatenate([qu - r * np.cos(ang), qv - r * np.sin(ang)])

    def err(t):
        ang = w * t + phi0
        return qu - r * np.cos(ang), qv - r * np.sin(ang), qa - t, ang

    def dist2(t):
        eu, ev, ea, _ = err(t)
        return eu**2 + ev**2 + ea**2

    t = qa.copy()
    d2 = dist2(t)
    if abs(w) > 1e-12:
        target = np.arctan2(qv, qu) - np.where(r < 0, math.pi, 0.0)
        k = np.round((w * qa + phi0 - target) / (2 * math.pi))
        t_angle = (target + 2 * math.pi * k - phi0) / w
        d2a = dist2(t_angle)
        better = d2a < d2
        t, d2 = np.where(better, t_angle, t), np.where(better, d2a, d2)
    for _ in range(6):
        eu, ev, ea, ang = err(t)
        s_, c_ = np.sin(ang), np.cos(ang)
        hu, hv = -r * w * s_, r * w * c_  # h'(t) = (hu, hv, 1)
        g = eu * hu + ev * hv + ea  # -1/2 d|e|^2/dt
        hh = hu**2 + hv**2 + 1.0
        curv = hh + w * (eu * hv - ev * hu)  # h'.h' - e.h''
        step = g / np.where(curv > 0.1 * hh, curv, hh)
        t_new = t + step
        d2n = dist2(t_new)
        better = d2n <= d2
        t, d2 = np.where(better, t_new, t), np.where(better, d2n, d2)
    eu, ev, ea, _ = err(t)
    return np.concatenate([eu, ev, ea])


def _distances(res, K):
    """Per-point distances from a stacked residual vector (components stacked blockwise)."""
    return np.linalg.norm(res.reshape(-1, K), axis=0)


def _curve_order(X):
    """An order of unordered points along the curve they sample.

    The longest path of the Euclidean minimum spanning tree; every point takes the
    position of its nearest point on that path. Needs samples closer along the curve
    than the curve's turns are to each other (true for tracker traces and for markers
    along a helix with a pitch larger than their spacing).
    """
    from scipy.sparse.csgraph import minimum_spanning_tree, shortest_path

    K = X.shape[0]
    if K < 3:
        return np.arange(K)
    dist = np.linalg.norm(X[:, None, :] - X[None, :, :], axis=2)
    mst = minimum_spanning_tree(dist + 1e-300 * (dist == 0))  # zero distances would drop edges
    mst = mst + mst.T
    d0 = shortest_path(mst, directed=False, indices=0)
    a = int(np.argmax(np.where(np.isfinite(d0), d0, -1)))
    da, pred = shortest_path(mst, directed=False, indices=a, return_predecessors=True)
    b = int(np.argmax(np.where(np.isfinite(da), da, -1)))
    path = [b]
    while path[-1] != a and pred[path[-1]] >= 0:
        path.append(int(pred[path[-1]]))
    path = np.array(path[::-1])
    _, near = cKDTree(X[path]).query(X)
    key = da[path][near] + 1e-9 * np.linalg.norm(X - X[path][near], axis=1)
    return np.argsort(key, kind="stable")


def _unwrapped_rate(psi, z, order):
    """Slope of the phase psi, unwrapped along ``order``, against the height z."""
    ps = np.r_[0.0, np.cumsum(np.angle(np.exp(1j * np.diff(psi[order]))))]
    zs = z[order]
    zc = zs - zs.mean()
    den = float(zc @ zc)
    return float(zc @ (ps - ps.mean()) / den) if den > 0 else 0.0


def _helix_candidates(X, n_dirs=96, max_points=400, residual="orthogonal"):
    """Initial (cost, F0, p) of single-helix fits over many axis directions, best first."""
    rng = np.random.default_rng(0)
    Xs = X if X.shape[0] <= max_points else X[np.sort(rng.choice(X.shape[0], max_points, replace=False))]
    _, V = _principal(Xs)
    dirs = np.concatenate([V.T, _fibonacci_hemisphere(n_dirs)])
    idx = np.zeros(Xs.shape[0], int)
    order = _curve_order(Xs)
    cands = []
    for a in dirs:
        F0 = _frame_from_axis(a)
        q = Xs @ F0
        c, R = _circle_fit(q[:, :2])
        if not np.isfinite(R) or R <= 0:
            continue
        z = q[:, 2]
        psi = np.arctan2(q[:, 1] - c[1], q[:, 0] - c[0])
        # Angular rate: the phase unwrapped along the curve against the height. (A
        # periodogram would let wrong axes win with aliased, fast-winding coils that pass
        # near every point; sorting by height fails on flat helices, where a slightly
        # tilted axis scrambles the heights.)
        w = _unwrapped_rate(psi, z, order)
        phi0 = float(np.angle(np.sum(np.exp(1j * (psi - w * z)))))
        p = np.array([0.0, 0.0, c[0], c[1], w, phi0, R])
        res = _helix_residuals(p, Xs, F0, idx, 1, residual)
        cands.append((float(np.sum(res**2)) / Xs.shape[0], F0, p))
    cands.sort(key=lambda c: c[0])
    return cands


def _solve_helix(X, F0, p0, line_idx, nradii, residual, tol=1e-14, max_nfev=2000):
    sol = least_squares(
        _helix_residuals, p0, args=(X, F0, line_idx, nradii, residual), method="lm", x_scale="jac",
        xtol=tol, ftol=tol, gtol=tol, max_nfev=max_nfev,
    )
    return sol.x, float(np.sum(sol.fun**2)) / X.shape[0]


def _rate_mismatch(p, X, F0, radius, order):
    """How far (in half turns over the points' height span) the fitted angular rate w is
    from the rate of the points' own phase, unwrapped along the curve (``order``).

    A dense coil of the right radius ("slinky": |w| far too large) passes close to every
    point on the cylinder and can beat the true helix in orthogonal distance when the
    noise is comparable to the pitch; its phase does not follow the points, which this
    detects (> 1 means aliased)."""
    alpha, beta, cx, cy, w, _ = p[:6]
    F = F0 @ Rotation.from_rotvec([alpha, beta, 0.0]).as_matrix()
    q = X @ F
    psi = np.arctan2(q[:, 1] - cy, q[:, 0] - cx) + (math.pi if radius < 0 else 0.0)
    Z = float(np.ptp(q[:, 2]))
    if Z <= 0 or X.shape[0] < 3:
        return 0.0
    return abs(w - _unwrapped_rate(psi, q[:, 2], order)) * Z / math.pi


def _fit_helices(Xc, idx, nradii, inits, residual, check_line, keep=2, max_points=200):
    """Refine helix candidates with least squares (first on at most ``max_points``
    points, then the best ``keep`` on all). Aliased results (see
    :func:`_rate_mismatch`, on the points of line ``check_line``) lose to any other."""
    K = Xc.shape[0]
    sub = np.arange(K) if K <= max_points else np.sort(np.random.default_rng(0).choice(K, max_points, replace=False))

    orders = {}

    def score(X, ids, F0, p, mse):
        sel = ids == check_line
        key = (X.shape[0], int(sel.sum()))
        if key not in orders:
            orders[key] = _curve_order(X[sel])
        return (_rate_mismatch(p, X[sel], F0, p[6 + check_line], orders[key]) > 1.0, mse)

    stage = []
    for F0, p0 in inits:
        p, mse = _solve_helix(Xc[sub], F0, p0, idx[sub], nradii, residual, 1e-9, 400)
        stage.append((score(Xc[sub], idx[sub], F0, p, mse), F0, p))
    stage.sort(key=lambda c: c[0])
    best = None
    for _, F0, p in stage[:keep]:
        p, mse = _solve_helix(Xc, F0, p, idx, nradii, residual)
        key = score(Xc, idx, F0, p, mse)
        if best is None or key < best[0]:
            best = (key, F0, p)
    return best[1], best[2]


def _helix_dict(p, F0, mean, nradii):
    """Axis point/direction, signed pitch b and radii in world coordinates from parameters."""
    alpha, beta, cx, cy, w, phi0 = p[:6]
    F = F0 @ Rotation.from_rotvec([alpha, beta, 0.0]).as_matrix()
    return {
        "axis_point": mean + F[:, 0] * cx + F[:, 1] * cy,
        "axis_dir": F[:, 2].copy(),
        "b": 1.0 / w if w != 0 else math.inf,
        "phase": float(phi0),
        "radii": np.asarray(p[6 : 6 + nradii], float),
    }


def best_fit_helix(points, top: int = 6, residual: str = "orthogonal") -> dict:
    """Best circular helix through points in any order (axis, radius, pitch all free).

    Global search over axis directions (the principal axes and a Fibonacci set on
    the hemisphere; for each, a circle fit of the projected points and the angular
    rate of the phase unwrapped along the height), then
    ``scipy.optimize.least_squares`` from the ``top`` best candidates.
    ``residual``: "orthogonal" (distance to the closest helix point, default, the
    same distance the model fit uses) or "height" (the paper's eq. error_func:
    in-plane distance at the same height; it inflates axial noise on flat helices).

    Returns dict(R, b, axis_point, axis_dir, phase, rmse, r2): ``b`` is signed
    (2 pi |b| per turn; b > 0 a right-handed helix, like the model's b for theta > 0),
    ``axis_point`` the axis point closest to the points' centroid; ``rmse`` and
    ``r2`` (:func:`r_squared`) of the chosen residual.
    """
    X = _clean(points, "points")
    mean = X.mean(axis=0)
    Xc = X - mean
    idx = np.zeros(X.shape[0], int)
    inits = [(F0, p0) for _, F0, p0 in _helix_candidates(Xc, residual=residual)[:top]]
    F0, p = _fit_helices(Xc, idx, 1, inits, residual, check_line=0)
    h = _helix_dict(p, F0, mean, 1)
    R = float(h["radii"][0])
    err = _distances(_helix_residuals(p, Xc, F0, idx, 1, residual), X.shape[0])
    return {
        "R": abs(R),
        "b": h["b"],
        "axis_point": h["axis_point"],
        "axis_dir": h["axis_dir"],
        "phase": h["phase"] + (math.pi if R < 0 else 0.0),
        "rmse": float(np.sqrt(np.mean(err**2))),
        "r2": r_squared(X, err),
    }


def best_fit_helix_pair(inner_points, outer_points, top: int = 3, residual: str = "orthogonal") -> dict:
    """Best pair of helices for the inner (actuator) and outer lines (paper Sec. V-A1).

    The two helices share axis, pitch b and phase (they are lines of one tube), with
    their own signed radii R_i, R_o (R_i < 0: the inner line passes the axis, as in
    Table I when lambda > cos 2 theta). Table I's inverse (``helix_inverse``) then
    gives the actuator parameters the fitted helix implies. Candidates come from
    single-helix searches on each line; ``residual`` as in :func:`best_fit_helix`.

    Returns dict(R_i, R_o, b, theta, lam, D, axis_point, axis_dir, phase, rmse,
    rmse_inner, rmse_outer, r2); r2 with each line about its own centroid.
    """
    Xi, Xo = _clean(inner_points, "inner points"), _clean(outer_points, "outer points")
    X = np.concatenate([Xi, Xo])
    K = X.shape[0]
    mean = X.mean(axis=0)
    Xc = X - mean
    idx = np.r_[np.zeros(Xi.shape[0], int), np.ones(Xo.shape[0], int)]
    inits = []
    for Xl in (Xo, Xi):  # candidate axes and rates from each line alone
        for _, F0, p0 in _helix_candidates(Xl - mean, residual=residual)[:top]:
            alpha, beta, cx, cy, w, phi0, _ = p0
            q = Xc @ F0
            ang = w * q[:, 2] + phi0
            radial = (q[:, 0] - cx) * np.cos(ang) + (q[:, 1] - cy) * np.sin(ang)
            r_i, r_o = radial[idx == 0].mean(), radial[idx == 1].mean()
            if r_o < 0:  # outer radius positive: turn the phase by pi
                phi0, r_i, r_o = phi0 + math.pi, -r_i, -r_o
            inits.append((F0, np.array([alpha, beta, cx, cy, w, phi0, r_i, r_o])))
    F0, p = _fit_helices(Xc, idx, 2, inits, residual, check_line=1)
    h = _helix_dict(p, F0, mean, 2)
    R_i, R_o = h["radii"]
    phase = h["phase"]
    if R_o < 0:
        R_i, R_o, phase = -R_i, -R_o, phase + math.pi
    theta, lam, D = helix_inverse(R_o, R_i, h["b"])
    err = _distances(_helix_residuals(p, Xc, F0, idx, 2, residual), K)
    return {
        "R_i": float(R_i),
        "R_o": float(R_o),
        "b": float(h["b"]),
        "theta": float(theta),
        "lam": float(lam),
        "D": float(D),
        "axis_point": h["axis_point"],
        "axis_dir": h["axis_dir"],
        "phase": float(phase),
        "rmse": float(np.sqrt(np.mean(err**2))),
        "rmse_inner": float(np.sqrt(np.mean(err[idx == 0] ** 2))),
        "rmse_outer": float(np.sqrt(np.mean(err[idx == 1] ** 2))),
        "r2": r_squared(X, err, idx),
    }


def parameter_errors(fitted: dict, nominal) -> dict:
    """Best-fit helix against the model helix of the nominal actuator (paper Fig. 6).

    ``fitted``: a :func:`best_fit_helix_pair` result; ``nominal``: (theta, lam, D)
    of the built actuator. For each of R_i, R_o, b (Fig. 6(a)) and theta, lam, D
    (Fig. 6(b)): dict(fitted, model, error = fitted - model, relative = error /
    |model|, percent = 100 relative).
    """
    theta, lam, D = (float(v) for v in nominal)
    h = helix_forward(theta, lam, D)
    model = {"R_i": float(h.R_i), "R_o": float(h.R_o), "b": float(h.b), "theta": theta, "lam": lam, "D": D}
    out = {}
    for key, m in model.items():
        f = float(fitted[key])
        rel = (f - m) / abs(m) if m != 0 else (0.0 if f == m else math.inf)
        out[key] = {"fitted": f, "model": m, "error": f - m, "relative": rel, "percent": 100.0 * rel}
    return out
