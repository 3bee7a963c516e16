"""The correction: nominal values to build next so that the robot, its deviations kept, matches the target.

The plain NLP on the target with the deviations kept (``deviations``). As-built values are the variables,
inside the nominal bounds shifted by the deviations (lam_ab in [lambda_min + d_lam, 1 + d_lam]; theta fixed
at the as-built values unless theta is adjusted, then in [-theta_max + d_theta, theta_max + d_theta] and
within a trust region of THETA_TRUST sigma_theta around the as-built theta: the estimate holds near the
measured shape); the lengths stay at the as-built lengths (the nominal lengths do not change) and the pose
at the archive's; the nominal to build is the solution minus the deviations. Solved on the drive's Hessian
schedule (settings.CORRECTION_SCHEDULE).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, replace

import numpy as np

from vine_nlp.methods import drive, settings
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.correct.deviations import Deviations, remove_deviations
from vine_nlp.methods.correct.estimate import DEFAULT_SYSTEMATIC_SIGMAS, Estimate, estimate_as_built, unit_scale
from vine_nlp.methods.correct.pairing import in_frame
from vine_nlp.methods.nlp import nlp_parameters
from vine_nlp.methods.settings import Settings
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Smoothness, SoftTip, Spec, get_solver, routing_of
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Routing, Sigmas
from vine_nlp.model.shape import routing_metrics
from vine_nlp.problem import DesignProblem, Result

_log = logging.getLogger(__name__)

ADJUST = (("lambda",), ("lambda", "theta"))
THETA_TRUST = 2.0  # with theta adjusted, the corrected theta stays within this many sigma_theta of the as-built one


def correction_spec(M: int, n: int, shared: bool, max_iter: int, tol: float, hessian: str) -> Spec:
    """The plain NLP with the base pose fixed (the robot's base stays where it was built)."""
    return Spec(Structure(M, n, 1, "shared" if shared else "segment", "fixed"), (Smoothness(), SoftTip()), hessian,
                Settings(max_iter, tol, repeated=True))


def correct_routing(problem: DesignProblem, as_built: Routing, dev: Deviations, adjust=("lambda",),
                    built: Routing | None = None, theta_trust: float | None = None) -> tuple[Routing, Routing, str, dict]:
    """Nominal values to build next so that the robot, its deviations kept, matches the target.

    ``built``: the nominal that was built; its lengths (and, unless theta is adjusted, its theta) are
    copied to the result exactly (default: as_built minus the deviations, equal to round-off).
    ``theta_trust``: with theta adjusted, the bound (rad) on |theta - theta as built| (None: only the
    design's bounds).
    Returns (nominal to build, its predicted as-built routing, status, solver stats).
    """
    adjust = tuple(adjust)
    if adjust not in ADJUST:
        raise ValueError(f"adjust must be one of {', '.join(','.join(a) for a in ADJUST)}")
    D, a, o = problem.diameter, problem.actuator, problem.options
    pairing = pair_points(problem.target, o.points_per_segment)
    M = pairing.segments
    if M != as_built.segments:
        raise ValueError(f"the design has {as_built.segments} segments, the problem's pairing {M}")
    if "theta" in adjust:
        th = (-a.theta_max + dev.theta, a.theta_max + dev.theta)
        if theta_trust is not None:
            th = (np.maximum(th[0], as_built.theta - theta_trust), np.minimum(th[1], as_built.theta + theta_trust))
    else:
        th = (as_built.theta, as_built.theta)
    off = float(np.mean(dev.lam)) if a.shared_lambda else dev.lam
    lam_b = (np.full(M, a.lambda_min) + off, np.full(M, 1.0) + off)
    dl = as_built.length / D
    f12 = frames12(chain_frames(as_built.theta, as_built.lam, as_built.length, D, as_built.initial_pose) * unit_scale(D))

    def step(hessian, cap, previous):
        solver = get_solver(correction_spec(M, pairing.n, a.shared_lambda, min(cap or o.max_iter, o.max_iter), o.tol, hessian))
        p = solver.pack_params(nlp_parameters(problem, pairing, as_built.initial_pose[:3, :3]))
        x0 = solver.pack_x(as_built.theta, as_built.lam, dl, f12[None], lam_global=float(np.mean(as_built.lam)))
        x, status, st = solver.solve(x0, p, *solver.bounds(th, lam_b, (dl, dl), X0=f12[:, 0][None]))
        _log.debug("correction %s: %s, %d iterations, %.2f s", hessian, status, st["iterations"], st["solve_time_s"])
        realized = dataclasses.replace(routing_of(solver, x, D, as_built.initial_pose), length=as_built.length)
        return Result("corrected", realized, None, status, iterations=st.pop("iterations"), stats=st)

    best = drive.schedule(step, settings.CORRECTION_SCHEDULE)
    realized = best.routing
    nominal = remove_deviations(realized, dev)
    base = built if built is not None else remove_deviations(as_built, dev)
    # what the builder does not change stays exactly what was built
    nominal = Routing(base.theta if "theta" not in adjust else nominal.theta, nominal.lam, base.length, base.initial_pose)
    return nominal, realized, best.status, best.stats | {"iterations": best.iterations}


@dataclass
class CorrectionResult:
    """``as_built``: the estimated effective routing (shape at the target's pairing; metrics rmse/max_error
    against the measurements, target_rmse/target_max_error against the target); ``corrected``: the nominal
    to build next (shape: what it will realize; metrics: the predicted error to the target);
    ``built``: the nominal of the build measured last; ``estimate``: the full estimate."""

    built: Routing
    as_built: Result
    corrected: Result
    estimate: Estimate
    measurements: list  # Measurement in the archive frame (free-frame ones moved by the estimated transform)
    adjust: tuple = ("lambda",)


def correct(problem: DesignProblem, nominals: list, measurements: list, *, adjust=("lambda",), sigmas: Sigmas | None = None,
            measurement_sigma: float | None = None, systematic_sigmas=DEFAULT_SYSTEMATIC_SIGMAS, units_per_mm: float = 0.1,
            theta_trust: float | None = None) -> CorrectionResult:
    """Estimate the built robot and correct it (package docstring): the methods layer, no file I/O.

    ``problem``: the target the robot should match (the archive's design problem); ``nominals``: the nominal
    of each build measured so far, oldest first (the last just built); ``measurements``: their points
    (``build`` indexes ``nominals``); ``adjust``: what the builder changes, ("lambda",) or ("lambda",
    "theta"); ``sigmas``: the construction errors, the estimate's prior (default 1 deg, 0.02, 2 %);
    ``theta_trust``: with theta adjusted, how far (rad) the corrected theta may move from the as-built one
    (default THETA_TRUST sigma_theta: the estimate holds near the measured shape, and a line redrawn far
    from it would extrapolate the deviations; "As-built correction").
    """
    t0 = time.perf_counter()
    sigmas = sigmas or Sigmas.from_degrees(1.0, 0.02, 0.02)
    D = problem.diameter
    est = estimate_as_built(nominals, measurements, D, sigmas, problem.actuator.shared_lambda, measurement_sigma, systematic_sigmas,
                            units_per_mm=units_per_mm)
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    ab_res = evaluate(problem, est.routing, pairing, "as_built", status=est.status, solve_time_s=est.solve_time_s,
                      iterations=est.iterations, stats=dict(est.stats) | {"icp_rounds": est.rounds})
    ab_res.metrics = {"target_rmse": ab_res.metrics["rmse"], "target_max_error": ab_res.metrics["max_error"]}
    d = np.concatenate(est.residuals)
    ab_res.metrics.update(rmse=float(np.sqrt(np.mean(d**2))), max_error=float(d.max()), **routing_metrics(est.routing))
    t1 = time.perf_counter()
    trust = THETA_TRUST * sigmas.theta if theta_trust is None else theta_trust
    nominal, realized, status, st = correct_routing(problem, est.routing, est.deviations, adjust, nominals[-1], theta_trust=trust)
    pred = evaluate(problem, realized, pairing, "corrected")
    corr = Result(method="corrected", routing=nominal, shape=pred.shape, status=status, solve_time_s=time.perf_counter() - t1,
                  iterations=st.pop("iterations"), diameter=D, metrics=pred.metrics | routing_metrics(nominal),
                  stats={k: v for k, v in st.items() if k != "solve_time_s"} | {"adjust": ",".join(adjust), "shape": "predicted as built"}
                  | ({"theta_trust_rad": float(trust)} if "theta" in adjust else {}))
    moved = [replace(m, points=in_frame(m.points, m, est.transform), frame="archive", build=m.build % len(nominals)) for m in measurements]
    ab_res.stats["total_time_s"] = time.perf_counter() - t0
    return CorrectionResult(nominals[-1], ab_res, corr, est, moved, tuple(adjust))
