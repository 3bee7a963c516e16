"""Free helix fits (paper Sec. V-A1, Figs. 5(b) and 6): a helix of any axis, radius and pitch through measured points.

:func:`best_fit_helix`, :func:`best_fit_helix_pair`, :func:`parameter_errors`. By default they minimize the orthogonal
distance to the helix (as the model fit does, so R^2 values compare); the paper's eq. (error_func), the in-plane
distance at the point's height, is available as ``residual="height"`` (it multiplies axial noise by R/b on flat
helices)."""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.methods.fit.align import clean_points, principal_axes, r_squared
from vine_nlp.model import helix_forward, helix_inverse


def _frame_from_axis(a):
    """Right-handed orthonormal columns (u, v, a) with a the given axis."""
    a = np.asarray(a, float)
    a = a / np.linalg.norm(a)
    ref = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = ref - np.dot(ref, a) * a
    u /= np.linalg.norm(u)
    return np.column_stack([u, np.cross(a, u), a])


def _tilted(F0, alpha, beta):
    """The axis frame F0 tilted by the rotation vector (alpha, beta, 0)."""
    from scipy.spatial.transform import Rotation  # SciPy loads where it is used: the command line starts faster
    return F0 @ Rotation.from_rotvec([alpha, beta, 0.0]).as_matrix()


def _fibonacci_hemisphere(n):
    k = np.arange(n) + 0.5
    z = k / n  # z in (0, 1): one of each pair of opposite directions
    r = np.sqrt(1 - z**2)
    phi = math.pi * (1 + 5**0.5) * k
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _circle_fit(xy):
    """Algebraic (Kasa) circle fit: center (2,), radius."""
    sol, *_ = np.linalg.lstsq(np.column_stack([2 * xy, np.ones(xy.shape[0])]), np.sum(xy**2, axis=1), rcond=None)
    c = sol[:2]
    return c, math.sqrt(max(sol[2] + c @ c, 0.0))


def _helix_residuals(p, X, F0, line_idx, nradii, residual="orthogonal"):
    """Residuals of points X against helices sharing axis, pitch and phase.

    p = (alpha, beta, cx, cy, w, phi0, radius_0, ..., radius_{n-1}): the axis frame is F0 tilted by the rotation vector
    (alpha, beta, 0); in its coordinates the helix of radius r is h(t) = (cx + r cos(w t + phi0), cy + r sin(w t +
    phi0), t), w = 1/b. Radii are signed (a negative radius is the opposite side of the axis).

    residual="height": the paper's eq. (error_func), the in-plane difference to the helix point at the same height t =
    q_a (2 per point). It multiplies axial noise by r/b, which is large for flat helices. residual="orthogonal"
    (default): the difference to the closest point of the helix (3 per point), found per point by safeguarded Newton
    steps in t from the better of the same-height and the same-angle point."""
    alpha, beta, cx, cy, w, phi0 = p[:6]
    radii = np.asarray(p[6 : 6 + nradii])
    q = X @ _tilted(F0, alpha, beta)
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

    The longest path of the Euclidean minimum spanning tree; every point takes the position of its nearest point on that
    path. Needs samples closer along the curve than the curve's turns are to each other (true for tracker traces and for
    markers along a helix with a pitch larger than their spacing)."""
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
    from scipy.spatial import cKDTree  # SciPy loads where it is used: the command line starts faster
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
    _, V = principal_axes(Xs)
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
    from scipy.optimize import least_squares  # SciPy loads where it is used: the command line starts faster
    sol = least_squares(_helix_residuals, p0, args=(X, F0, line_idx, nradii, residual), method="lm", x_scale="jac",
                        xtol=tol, ftol=tol, gtol=tol, max_nfev=max_nfev)
    return sol.x, float(np.sum(sol.fun**2)) / X.shape[0]


def _rate_mismatch(p, X, F0, radius, order):
    """How far (in half turns over the points' height span) the fitted angular rate w is
    from the rate of the points' own phase, unwrapped along the curve (``order``).

    A dense coil of the right radius ("slinky": |w| far too large) passes close to every point on the cylinder and can
    beat the true helix in orthogonal distance when the noise is comparable to the pitch; its phase does not follow the
    points, which this detects (> 1 means aliased)."""
    alpha, beta, cx, cy, w, _ = p[:6]
    q = X @ _tilted(F0, alpha, beta)
    psi = np.arctan2(q[:, 1] - cy, q[:, 0] - cx) + (math.pi if radius < 0 else 0.0)
    Z = float(np.ptp(q[:, 2]))
    if Z <= 0 or X.shape[0] < 3:
        return 0.0
    return abs(w - _unwrapped_rate(psi, q[:, 2], order)) * Z / math.pi


def _fit_helices(Xc, idx, nradii, inits, residual, check_line, keep=2, max_points=200):
    """Refine helix candidates with least squares (first on at most ``max_points`` points, then the best ``keep`` on
    all). Aliased results (see :func:`_rate_mismatch`, on the points of line ``check_line``) lose to any other."""
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
    F = _tilted(F0, alpha, beta)
    return {"axis_point": mean + F[:, 0] * cx + F[:, 1] * cy, "axis_dir": F[:, 2].copy(),
            "b": 1.0 / w if w != 0 else math.inf, "phase": float(phi0), "radii": np.asarray(p[6 : 6 + nradii], float)}


def best_fit_helix(points, top: int = 6, residual: str = "orthogonal") -> dict:
    """Best circular helix through points in any order (axis, radius, pitch all free).

    Global search over axis directions (the principal axes and a Fibonacci set on the hemisphere; for each, a circle fit
    of the projected points and the angular rate of the phase unwrapped along the height), then
    ``scipy.optimize.least_squares`` from the ``top`` best candidates. ``residual``: "orthogonal" (distance to the
    closest helix point, default, the same distance the model fit uses) or "height" (the paper's eq. error_func:
    in-plane distance at the same height; it inflates axial noise on flat helices).

    Returns dict(R, b, axis_point, axis_dir, phase, rmse, r2): ``b`` is signed (2 pi |b| per turn; b > 0 a right-handed
    helix, like the model's b for theta > 0), ``axis_point`` the axis point closest to the points' centroid; ``rmse``
    and ``r2`` (:func:`r_squared`) of the chosen residual."""
    X = clean_points(points, "points")
    mean, idx = X.mean(axis=0), np.zeros(X.shape[0], int)
    Xc = X - mean
    inits = [(F0, p0) for _, F0, p0 in _helix_candidates(Xc, residual=residual)[:top]]
    F0, p = _fit_helices(Xc, idx, 1, inits, residual, check_line=0)
    h = _helix_dict(p, F0, mean, 1)
    R = float(h["radii"][0])
    err = _distances(_helix_residuals(p, Xc, F0, idx, 1, residual), X.shape[0])
    return {"R": abs(R), "b": h["b"], "axis_point": h["axis_point"], "axis_dir": h["axis_dir"],
            "phase": h["phase"] + (math.pi if R < 0 else 0.0), "rmse": float(np.sqrt(np.mean(err**2))), "r2": r_squared(X, err)}


def best_fit_helix_pair(inner_points, outer_points, top: int = 3, residual: str = "orthogonal") -> dict:
    """Best pair of helices for the inner (actuator) and outer lines (paper Sec. V-A1).

    The two helices share axis, pitch b and phase (they are lines of one tube), with their own signed radii R_i, R_o
    (R_i < 0: the inner line passes the axis, as in Table I when lambda > cos 2 theta). Table I's inverse
    (``helix_inverse``) then gives the actuator parameters the fitted helix implies. Candidates come from single-helix
    searches on each line; ``residual`` as in :func:`best_fit_helix`.

    Returns dict(R_i, R_o, b, theta, lam, D, axis_point, axis_dir, phase, rmse,
    rmse_inner, rmse_outer, r2); r2 with each line about its own centroid."""
    Xi, Xo = clean_points(inner_points, "inner points"), clean_points(outer_points, "outer points")
    X = np.concatenate([Xi, Xo])
    K, mean = X.shape[0], X.mean(axis=0)
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
    return {"R_i": float(R_i), "R_o": float(R_o), "b": float(h["b"]), "theta": float(theta), "lam": float(lam),
            "D": float(D), "axis_point": h["axis_point"], "axis_dir": h["axis_dir"], "phase": float(phase),
            "rmse": float(np.sqrt(np.mean(err**2))), "rmse_inner": float(np.sqrt(np.mean(err[idx == 0] ** 2))),
            "rmse_outer": float(np.sqrt(np.mean(err[idx == 1] ** 2))), "r2": r_squared(X, err, idx)}


def parameter_errors(fitted: dict, nominal) -> dict:
    """Best-fit helix against the model helix of the nominal actuator (paper Fig. 6).

    ``fitted``: a :func:`best_fit_helix_pair` result; ``nominal``: (theta, lam, D)
    of the built actuator. For each of R_i, R_o, b (Fig. 6(a)) and theta, lam, D
    (Fig. 6(b)): dict(fitted, model, error = fitted - model, relative = error /
    |model|, percent = 100 relative)."""
    theta, lam, D = (float(v) for v in nominal)
    h = helix_forward(theta, lam, D)
    model = {"R_i": float(h.R_i), "R_o": float(h.R_o), "b": float(h.b), "theta": theta, "lam": lam, "D": D}
    out = {}
    for key, m in model.items():
        f = float(fitted[key])
        rel = (f - m) / abs(m) if m != 0 else (0.0 if f == m else math.inf)
        out[key] = {"fitted": f, "model": m, "error": f - m, "relative": rel, "percent": 100.0 * rel}
    return out
