"""The model fit (``vine-nlp fit``, paper Sec. V-A2 and V-B2): measured points against the model of a known routing.

Measured points in any order and any pose are fitted to the model's center, inner or outer line (:func:`fit_problem`,
:func:`fit_lines`): only the rigid pose (see ``vine_nlp.methods.fit.align``) and, with ``free = ("lambda",)``, the
shared lambda of an sPAM are estimated: an outer 1-D search over lambda (coarse grid, then bounded Brent) re-runs the
pose fit.

The model line is sampled with spacing <= ``FIT_SPACING * D`` and treated as a polyline; distances are to the polyline
(the chord error of that spacing is about ``(D/10)^2 kappa / 8``, far below tracker noise). The archived shape is the
model moved onto the measurement: the routing's initial pose becomes ``inv(T) @ initial_pose``."""

from __future__ import annotations

import math
import time

import numpy as np

from vine_nlp.methods.fit.align import (
    PointSet,
    Polyline,
    PoseFit,
    apply_transform,
    clean_points,
    fit_pose,
    icp_refine,
    invert_transform,
    polish_pose,
    pose_starts,
    r_squared,
    stack_points,
    subsample,
)
from vine_nlp.methods.settings import FIT_SPACING, GRID_POINTS, GRID_POLISH_ITER, LAMBDA_BOUNDS, LAMBDA_GRID_STEP
from vine_nlp.model import shape_lines
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.routing import MEASURED_LINES, Routing
from vine_nlp.model.shape import Shape
from vine_nlp.problem import FitProblem, Result

LINE_CODE = {name: k for k, name in enumerate(MEASURED_LINES)}  # center 0, inner 1, outer 2


def model_lines(routing: Routing, diameter: float, spacing: float = FIT_SPACING):
    """Center, inner and outer lines of ``routing`` sampled at <= spacing * D.

    Returns (dict line -> (P, 3), s_tube (P,), per_segment (M,)): s_tube is the unactuated tube length of every sample;
    every segment end is a sample. The lines' actuated lengths are at most 1/cos(theta) times the unactuated one, which
    the sample count allows for."""
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
    return Routing(theta=routing.theta, lam=np.full(routing.segments, float(lam)), length=routing.length, initial_pose=routing.initial_pose)


class LineFitter:
    """Pose (and lambda) fit of measured lines to the model of one routing."""

    def __init__(self, routing, diameter, measured: dict, starts=24, seed=0, spacing=FIT_SPACING):
        self.routing = routing
        self.D = float(diameter)
        self.measured = {line: clean_points(pts, f"measured {line} line") for line, pts in measured.items()}
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
            self._cache = {key: [PointSet(pts, Polyline(lines[line], s_tube)) for line, pts in self.measured.items()]}
        return self._cache[key]

    def global_starts(self, sets):
        X = stack_points(sets)
        Y = np.concatenate([st.line.p for st in sets])
        return pose_starts(X, Y, self.starts, self.seed)

    def pose(self, lam, warm=(), full=True, polish_iter=50) -> PoseFit:
        sets = self.sets(lam)
        starts = list(warm) + (self.global_starts(sets) if full else [])
        if full:
            # the grid stage (short polish) ranks on a subsample; same points for every lambda
            fit = fit_pose(sets if polish_iter >= 50 else subsample(sets, GRID_POINTS), starts, polish_iter=polish_iter)
        else:  # warm starts only: short ICP then polish, keep the best
            fit = None
            for T0 in starts:
                T, _, it1 = icp_refine(sets, T0, max_iter=10, tol=1e-9)
                T, mse, it2 = polish_pose(sets, T)
                self.iterations += it1 + it2
                if fit is None or mse < fit.mse:
                    fit = PoseFit(T, mse, 0)
        self.iterations += fit.iterations
        if lam is not None:
            self.evaluations.append((float(lam), math.sqrt(fit.mse)))
        return fit

    def fit_lambda(self, lam0, bounds=LAMBDA_BOUNDS, warm=(), local=None):
        """Shared lambda minimizing the pose-fitted RMSE.

        ``local=None``: coarse grid over ``bounds`` (full pose search at every value, warm-started from the best pose so
        far), then bounded Brent between the neighbours of the best grid value. ``local=(lo, hi)``: Brent in that
        interval only, warm-started (for frame sequences)."""
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
            from scipy.optimize import minimize_scalar  # SciPy loads where it is used: the command line starts faster
            minimize_scalar(objective, bounds=(a, b), method="bounded", options={"xatol": 1e-5})
        return best["lam"], best["fit"]


def fit_lines(routing: Routing, diameter: float, measured: dict, free=(), starts: int = 24, seed: int = 0):
    """Fit the model of ``routing`` to measured lines sharing one rigid pose.

    ``measured``: {"center" | "inner" | "outer": (K, 3) points in any order}; several lines are fitted together, as the
    paper does for the inner and outer lines of its static helices. ``free``: () or ("lambda",) (one shared lambda).

    Returns (Result, extras): see :func:`fit_problem`."""
    t0 = time.perf_counter()
    free = tuple(free)
    unknown = set(free) - {"lambda"}
    if unknown:
        raise ValueError(f"free parameters must be () or ('lambda',), not {free}")
    fitter = LineFitter(routing, diameter, measured, starts=starts, seed=seed)
    lam_fit = None
    if "lambda" in free:
        lam_fit, pose = fitter.fit_lambda(float(np.mean(routing.lam)))
    else:
        pose = fitter.pose(None)
    result, extras = finish_fit(fitter, lam_fit, pose.T, free, FIT_SPACING)
    result.solve_time_s = time.perf_counter() - t0
    result.iterations = fitter.iterations
    result.stats.update(starts=starts, seed=seed)
    if "lambda" in free:
        grid, costs = fitter.grid
        result.stats.update(lambda_bounds=list(LAMBDA_BOUNDS), lambda_grid=grid.tolist(), lambda_grid_rmse=costs.tolist())
    return result, extras


def finish_fit(fitter: LineFitter, lam_fit, T, free, spacing):
    """Result and extras of a fitted pose (and lambda)."""
    routing = _with_lambda(fitter.routing, lam_fit)
    D = fitter.D
    lines, s_tube, _ = model_lines(routing, D, spacing)
    polylines = {name: Polyline(pts, s_tube) for name, pts in lines.items()}
    Tinv = invert_transform(T)
    fitted = Routing(theta=routing.theta, lam=routing.lam, length=routing.length, initial_pose=Tinv @ routing.initial_pose)
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
    metrics = {"rmse": rmse, "max_error": float(err.max()), "r2": r_squared(pts, err, code),
               "lambda": float(lam_fit) if lam_fit is not None else float(np.mean(routing.lam))}
    stats = {"line": ",".join(fitter.measured), "free": list(free), "points": int(pts.shape[0]), "spacing": spacing * D,
             "transform": T.tolist(), "lambda_evaluations": len(fitter.evaluations),
             "model_line_length": {name: polylines[name].length for name in MEASURED_LINES}}
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
    extras = {"measured/points": pts, "measured/closest": closest, "measured/error": err, "measured/s": s,
              "measured/s_tube": s_tube_pts, "measured/line": code.astype(np.int8)}
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
      tube length, ``measured/line`` (K,) 0 center, 1 inner, 2 outer."""
    return fit_lines(problem.routing, problem.diameter, {problem.line: problem.measured}, free=problem.free, starts=starts, seed=seed)


def describe_fit(result: Result, units: str = "cm") -> str:
    """One line for the command line: what was fitted and how well."""
    m, st = result.metrics, result.stats
    free = st.get("free", [])
    lam = f", lambda {m['lambda']:.4f}" + (" (fitted)" if "lambda" in free else " (given)")
    return (f"fit of the {st.get('line', '?')} line to {st.get('points', '?')} points: rmse {m['rmse']:.4g} {units}, "
            f"max {m['max_error']:.4g} {units}, R^2 {m['r2']:.4f}{lam}")
