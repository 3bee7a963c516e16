"""The correction: nominal values to build next so that the robot, its deviations kept, matches the target.

The plain NLP on the target; its variables are what is built, bounded by what the robot can realize (spec "Physical
builds", :func:`lambda_bounds`; no actuator is added: a new stopper or pouch has an error of its own, and the design
needed none there). Theta stays as built unless adjusted, then within theta_max and THETA_TRUST sigma_theta of the
as-built theta (the estimate holds near the measured shape); lengths and pose stay. The nominal is the solution
minus the deviations; its prediction what the physical rule makes of it. On the drive's Hessian schedule.

Two routes, both predicted: ``lambda`` (stoppers or pouches on this robot) and ``lambda,theta`` (the line drawn
anew on a new tube). A route cannot reach the target where its solution sits at a bound and the same NLP without
the bounds predicts materially less error (REACH_TOL): ``Result.shortfall`` names the segments and the bound.
Recommended: the route that reaches the target where only one does, else lambda,theta where it predicts ROUTE_GAIN
times less error than lambda alone by more than the measurement noise, else lambda (the robot is kept).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from vine_nlp.analysis.buildability import correction_missed
from vine_nlp.methods import drive, settings
from vine_nlp.methods.buildable import Build, upper
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.correct.deviations import TOP, Deviations, apply_deviations, remove_deviations
from vine_nlp.methods.correct.estimate import Estimate, estimate_as_built
from vine_nlp.methods.correct.pairing import in_frame
from vine_nlp.methods.nlp import nlp_parameters
from vine_nlp.methods.settings import REACH_TOL, ROUTE_GAIN, THETA_TRUST, Settings
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Smoothness, SoftTip, Spec, get_solver
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Routing, Sigmas, actuated, built_lambda
from vine_nlp.model.shape import routing_metrics
from vine_nlp.problem import DesignProblem, Result

_log = logging.getLogger(__name__)

ADJUST = (("lambda",), ("lambda", "theta"))


def correction_spec(M: int, n: int, shared: bool, max_iter: int, tol: float, hessian: str) -> Spec:
    """The plain NLP with the base pose fixed (the robot's base stays where it was built)."""
    return Spec(Structure(M, n, 1, "shared" if shared else "segment", "fixed"), (Smoothness(), SoftTip()), hessian,
                Settings(max_iter, tol, repeated=True))


def lambda_bounds(problem: DesignProblem, built: Routing, dev: Deviations) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of the lambda the robot realizes from the next nominal where ``built`` has an actuator: its nominal
    within [lambda_min, top] (the buildable rules for a correction, analysis.buildability.correction_missed: top
    keeps the actuator and its gap at least min_feature, methods.buildable.upper without margin; TOP for pouches),
    i.e. [lambda_min + max(d_lam, 0), min(1, top + d_lam)]; exactly 1 where it has none, what it realizes now where
    ``dev.held``. sPAM: one lambda."""
    a, act, build = problem.actuator, actuated(built.lam), replace(Build.of(problem), margin=0.0)
    d = np.full(built.segments, float(np.mean(dev.lam))) if a.shared_lambda else dev.lam
    top = np.full(built.segments, TOP) if a.shared_lambda else np.minimum(TOP, upper(built.length, act, build))
    lo, now = np.where(act, a.lambda_min + np.maximum(d, 0.0), 1.0), built_lambda(built.lam, d, a.lambda_min)
    hi = np.where(act, np.minimum(1.0, top + d), 1.0)
    held = dev.held if dev.held is not None else False
    return np.where(held, now, np.minimum(lo, hi)), np.where(held, now, hi)


def correct_routing(problem: DesignProblem, as_built: Routing, dev: Deviations, adjust=("lambda",), built: Routing | None = None,
                    theta_trust: float | None = None, unbounded: bool = False) -> tuple[Routing, Routing, str, dict]:
    """(nominal to build next, what it realizes, status, solver stats) (module docstring). ``built``: the nominal
    that was built (default: as_built minus the deviations), its lengths (and theta, unless adjusted) kept exactly;
    ``theta_trust``: the bound (rad) on |theta - theta as built|; ``unbounded``: without the builder's bounds."""
    adjust = tuple(adjust)
    if adjust not in ADJUST:
        raise ValueError(f"adjust must be one of {', '.join(','.join(a) for a in ADJUST)}")
    D, a, o = problem.diameter, problem.actuator, problem.options
    dev = replace(dev, lambda_min=a.lambda_min)
    built = built if built is not None else remove_deviations(as_built, dev, actuated(as_built.lam))
    pairing = pair_points(problem.target, o.points_per_segment)
    M = pairing.segments
    if M != as_built.segments:
        raise ValueError(f"the design has {as_built.segments} segments, the problem's pairing {M}")
    th = (as_built.theta, as_built.theta)
    if "theta" in adjust:
        th = (-a.theta_max + dev.theta, a.theta_max + dev.theta) if not unbounded else (-1.45, 1.45)
        if theta_trust is not None:
            th = (np.maximum(th[0], as_built.theta - theta_trust), np.minimum(th[1], as_built.theta + theta_trust))
    lam_b = lambda_bounds(problem, built, dev)
    if unbounded:
        lam_b = tuple(np.where(lam_b[0] < lam_b[1], v, lam_b[0]) for v in (0.05, 2.0))
    dl = as_built.length / D
    f12 = frames12(chain_frames(as_built.theta, as_built.lam, as_built.length, D, as_built.initial_pose), D)

    def step(hessian, cap, previous):
        solver = get_solver(correction_spec(M, pairing.n, a.shared_lambda, min(cap or o.max_iter, o.max_iter), o.tol, hessian))
        p = solver.pack_params(nlp_parameters(problem, pairing, as_built.initial_pose[:3, :3]))
        x0 = solver.pack_x(f12[None], lam_global=float(np.mean(as_built.lam)), theta=as_built.theta, lam=as_built.lam, length=dl)
        sol = solver.solve(x0, p, *solver.bounds(X0=f12[:, 0][None], theta=th, lam=lam_b, length=(dl, dl)))
        st = sol.stats
        _log.debug("correction %s: %s, %d iterations, %.2f s", hessian, sol.status, st["iterations"], st["solve_time_s"])
        realized = dataclasses.replace(sol.routing(D, as_built.initial_pose), length=as_built.length)
        return Result("corrected", realized, None, sol.status, iterations=st.pop("iterations"), stats=st, objective=sol.objective)

    best = drive.schedule(step, settings.CORRECTION_SCHEDULE)
    if unbounded:
        return best.routing, best.routing, best.status, best.stats | {"iterations": best.iterations}
    nominal = remove_deviations(best.routing, dev, actuated(built.lam))
    # what the builder does not change stays exactly what was built
    nominal = Routing(theta=nominal.theta if "theta" in adjust else built.theta, lam=nominal.lam, length=built.length, initial_pose=built.initial_pose)
    return nominal, apply_deviations(nominal, dev), best.status, best.stats | {"iterations": best.iterations}


def at_bounds(problem: DesignProblem, realized: Routing, built: Routing, dev: Deviations, adjust) -> str:
    """The segments whose predicted values sit at a bound of what the robot can realize, and the bound ("" if none)."""
    a, eps = problem.actuator, 1e-6
    lo, hi = lambda_bounds(problem, built, replace(dev, lambda_min=a.lambda_min))
    act, lam = actuated(built.lam) & (lo < hi), realized.lam  # a held lambda is no bound of the builder's
    parts = []
    for mask, what in ((act & (lam <= lo + eps), f"lambda at lambda_min {a.lambda_min:g}"),
                       (act & (lam >= hi - eps) & (hi >= 1.0 - eps), "lambda at 1 (an actuator cannot lengthen the tube)"),
                       (act & (lam >= hi - eps) & (hi < 1.0 - eps), "lambda at the actuator's least contraction (its nominal's gap at min_feature)"),
                       (np.abs(realized.theta - dev.theta) >= a.theta_max - eps if "theta" in adjust else act & False,
                        f"|theta| at theta_max {math.degrees(a.theta_max):g} deg")):
        if mask.any():
            j = np.flatnonzero(mask)
            parts.append(f"{what}: segment{'s' if j.size > 1 else ''} {', '.join(map(str, j[:10]))}{' ...' if j.size > 10 else ''}")
    return "; ".join(parts)


@dataclass
class CorrectionResult:
    """``as_built``: the estimate (metrics rmse/max_error against the measurements, target_* against the target);
    ``corrected``: the nominal to build next on the route ``adjust`` (shape and metrics: what it will realize;
    ``shortfall``: why it cannot reach the target), one of ``routes`` ("lambda", "lambda,theta");
    ``recommended``: the route to take; ``built``: the nominal measured last."""

    built: Routing
    as_built: Result
    corrected: Result
    estimate: Estimate
    measurements: list  # Measurement in the archive frame (free-frame ones moved by the estimated transform)
    adjust: tuple = ("lambda",)
    routes: dict = field(default_factory=dict)
    recommended: str = "lambda"


def correct(problem: DesignProblem, nominals: list, measurements: list, *, adjust=None, sigmas: Sigmas | None = None,
            measurement_sigma: float | None = None, systematic_sigmas=settings.DEFAULT_SYSTEMATIC_SIGMAS, units_per_mm: float = 0.1,
            theta_trust: float | None = None, start: Deviations | None = None, start_systematic=None) -> CorrectionResult:
    """Estimate the built robot and correct it on both routes (module docstring), no file I/O. ``nominals``: of
    each build measured so far, oldest first; ``measurements``: their points (``build`` indexes ``nominals``);
    ``adjust``: the route taken (None: the recommended one); ``sigmas``: the estimate's prior (default 1 deg,
    0.02, 2 %); ``theta_trust`` default THETA_TRUST sigma_theta; ``start``, ``start_systematic``: a warm start
    (the previous round's deviations and systematic parts)."""
    t0 = time.perf_counter()
    sigmas = sigmas or Sigmas.from_degrees(1.0, 0.02, 0.02)
    D = problem.diameter
    est = estimate_as_built(nominals, measurements, D, sigmas, problem.actuator.shared_lambda, measurement_sigma, systematic_sigmas,
                            units_per_mm=units_per_mm, lambda_min=problem.actuator.lambda_min, start=start,
                            start_systematic=start_systematic)
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    ab_res = evaluate(problem, est.routing, pairing, "as_built", status=est.status, solve_time_s=est.solve_time_s,
                      iterations=est.iterations, stats=dict(est.stats) | {"icp_rounds": est.rounds})
    ab_res.metrics = {"target_rmse": ab_res.metrics["rmse"], "target_max_error": ab_res.metrics["max_error"]}
    d = np.concatenate(est.residuals)
    ab_res.metrics.update(rmse=float(np.sqrt(np.mean(d**2))), max_error=float(d.max()), **routing_metrics(est.routing))
    trust = THETA_TRUST * sigmas.theta if theta_trust is None else theta_trust
    routes = {",".join(r): _route(problem, pairing, est, nominals[-1], r, trust) for r in ADJUST}
    moved = [replace(m, points=in_frame(m.points, m, est.transform), frame="archive", build=m.build % len(nominals)) for m in measurements]
    ab_res.stats["total_time_s"] = time.perf_counter() - t0
    return recommend(CorrectionResult(nominals[-1], ab_res, None, est, moved, (), routes), adjust)


def recommend(result: CorrectionResult, adjust=None) -> CorrectionResult:
    """``result`` with its recommended route and the route taken (``adjust``, None: the recommended one) among its
    ``routes`` (module docstring)."""
    lo, lt = result.routes["lambda"], result.routes["lambda,theta"]
    if lo.clear != lt.clear:
        recommended = "lambda" if lo.clear else "lambda,theta"
    else:
        gain = lt.metrics["rmse"] * ROUTE_GAIN <= lo.metrics["rmse"] and lo.metrics["rmse"] - lt.metrics["rmse"] > result.estimate.stats["measurement_sigma"]
        recommended = "lambda,theta" if gain else "lambda"
    chosen = recommended if adjust is None else ",".join(adjust)
    for name, r in result.routes.items():
        r.stats |= {"route": name, "recommended": recommended}
    return replace(result, corrected=result.routes[chosen], adjust=tuple(chosen.split(",")), recommended=recommended)


def _route(problem, pairing, est: Estimate, built: Routing, adjust, trust) -> Result:
    """One route's correction, its prediction and whether it reaches the target (module docstring)."""
    t1 = time.perf_counter()
    nominal, realized, status, st = correct_routing(problem, est.routing, est.deviations, adjust, built, theta_trust=trust)
    pred = evaluate(problem, realized, pairing, "corrected")
    stats = {k: v for k, v in st.items() if k != "solve_time_s"} | {"adjust": ",".join(adjust), "shape": "predicted as built"}
    res = Result(method="corrected", routing=nominal, shape=pred.shape, status=status, iterations=stats.pop("iterations"),
                 diameter=problem.diameter, metrics=pred.metrics | routing_metrics(nominal),
                 stats=stats | ({"theta_trust_rad": float(trust)} if "theta" in adjust else {}))
    pinned = at_bounds(problem, realized, built, est.deviations, adjust)
    if pinned and res.converged:
        free, _, _, _ = correct_routing(problem, est.routing, est.deviations, adjust, built, theta_trust=trust, unbounded=True)
        rmse, rmse_free = pred.metrics["rmse"], evaluate(problem, free, pairing, "x").metrics["rmse"]
        res.metrics["rmse_without_bounds"] = rmse_free
        if rmse - rmse_free > REACH_TOL * rmse and rmse - rmse_free > 0.1 * est.stats["measurement_sigma"]:
            res.shortfall = (f"cannot reach the target within the bounds (predicted RMSE {rmse:.4g}, {rmse_free:.4g} without them): "
                             f"{pinned}",)
    elif not res.converged:
        res.shortfall = (f"the correction did not converge ({status})",)
    b = Build.of(problem)  # the buildable rules' variant for a correction (analysis.buildability.correction_missed)
    res.shortfall += tuple(f"not buildable: {line}" for line in correction_missed(nominal, built.lam, b.D, b.kind, b.lambda_min,
                                                                                  b.min_feature, problem.units))
    res.solve_time_s = time.perf_counter() - t1
    return res
