"""Frame sequences of one actuator (paper Figs. 9(d), 11(c)-(d)): lambda fitted frame by frame."""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.methods.fit.model_fit import FIT_SPACING, LAMBDA_BOUNDS, LineFitter, finish_fit
from vine_nlp.problem import FitProblem


class FrameFit(tuple):
    """``(lambda, rmse)`` of one frame; more as attributes: ``r2``, ``max_error``, ``transform`` (measured -> model),
    ``error`` and ``s`` (per point, for the error-against-length figure), ``points`` (finite measured points), ``ok``. A
    frame that could not be fitted (fewer than ``min_points`` finite points) is ``(nan, nan)`` with ``ok = False``."""

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


def fit_frames(problem: FitProblem, measured_list, starts: int = 24, seed: int = 0, window: float = 0.1, min_points: int = 4):
    """Fit every frame of a sequence of one actuator (paper Fig. 9(d)): a list of :class:`FrameFit`.

    Each frame is one point set of ``problem.line`` (rows with NaN, e.g. occluded markers, are dropped). The first good
    frame gets the full global fit; every later one starts from the previous frame's pose and lambda (Brent over lambda
    within +-``window``), and falls back to the full global fit when that is clearly worse (RMSE above 3x the previous
    frame's or 5 % of D). With lambda not free only the pose is fitted."""
    free = tuple(problem.free)
    D = problem.diameter
    out = []
    prev = None  # (lam, T, rmse)
    for frame in measured_list:
        X = np.asarray(frame, float).reshape(-1, 3)
        X = X[np.all(np.isfinite(X), axis=1)]
        if X.shape[0] < min_points:
            out.append(FrameFit(math.nan, math.nan, ok=False, r2=math.nan, max_error=math.nan, transform=None,
                                error=np.zeros(0), s=np.zeros(0), points=X))
            continue
        fitter = LineFitter(problem.routing, D, {problem.line: X}, starts=starts, seed=seed)
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
        result, extras = finish_fit(fitter, lam, fit.T, free, FIT_SPACING)
        m = result.metrics
        prev = (m["lambda"], fit.T, m["rmse"])
        out.append(FrameFit(m["lambda"], m["rmse"], ok=True, r2=m["r2"], max_error=m["max_error"], transform=fit.T,
                            error=extras["measured/error"], s=extras["measured/s"], points=X))
    return out
