"""The design methods of a plain design problem, by name."""

from __future__ import annotations

from vine_nlp.methods.buildable import design_buildable
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.greedy import design_greedy
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.model.calibration import nominal_of, realized_of
from vine_nlp.model.shape import routing_metrics
from vine_nlp.problem import DesignProblem, Result

# nlp: the buildable design from the free one (methods.buildable), as the pipeline's nlp run; greedy as the paper has it
METHODS = {"nlp": lambda problem, **kw: design_buildable(problem, design_nlp(problem, **kw)), "greedy": design_greedy}


def run_design(problem, method: str | None = None, **kw):
    """Design ``problem`` with ``method`` ("nlp" or "greedy"; default: the problem's ``options.method``).

    Parameters
    ----------
    problem : DesignProblem
        The target, tube and actuator.
    method : str, optional
        "nlp" (one NLP) or "greedy" (the paper's Algorithm 1).
    **kw
        Passed to the method (e.g. ``starts``, ``progress``).

    Returns
    -------
    Result

    Raises
    ------
    ValueError
        For an unknown method.
    """
    method = method or problem.options.method
    if method not in METHODS:
        raise ValueError(f"unknown design method {method!r}")
    # a calibrated problem: the design is what the robot should realize, the nominal to build has the
    # builder's systematic errors taken out (apply_calibration)
    return apply_calibration(problem, METHODS[method](problem, **kw))


def apply_calibration(problem: DesignProblem, result: Result) -> Result:
    """A design made with a calibration (``problem.calibration``): the result's routing becomes the nominal
    to build (model.calibration.nominal_of: the systematic parts taken out, clipped to the bounds), its shape
    and metrics what that nominal realizes on a robot with the calibration's systematic errors.
    stats: calibration_* (the values and the number of clipped entries). Without a calibration: ``result``."""
    from_cal = getattr(problem, "calibration", None)
    if from_cal is None:
        return result
    a = problem.actuator
    nominal, clipped = nominal_of(result.routing, from_cal, a.theta_max, a.lambda_min)
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    realized = evaluate(problem, realized_of(nominal, from_cal, a.lambda_min), pairing, result.method)
    out = Result(method=result.method, routing=nominal, shape=realized.shape, status=result.status,
                 solve_time_s=result.solve_time_s, iterations=result.iterations,
                 metrics=dict(result.metrics) | realized.metrics | routing_metrics(nominal), stats=dict(result.stats),
                 diameter=result.diameter)
    out.stats.update(calibration_lambda_offset=from_cal.lambda_offset, calibration_theta_offset_deg=from_cal.theta_offset_deg,
                     calibration_length_scale=from_cal.length_scale, calibration_clipped=clipped,
                     calibration_shape="realized by the nominal on the calibrated robot")
    return out
