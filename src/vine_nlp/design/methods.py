"""The design methods of a plain design problem, by name."""

from __future__ import annotations

from vine_nlp.design.correct import apply_calibration
from vine_nlp.design.greedy import design_greedy
from vine_nlp.design.nlp import design_nlp

METHODS = {"nlp": design_nlp, "greedy": design_greedy}


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
    result = METHODS[method](problem, **kw)
    # a calibrated problem: the design is what the robot should realize, the nominal to build has the
    # builder's systematic errors taken out (design.correct.apply_calibration)
    return apply_calibration(problem, result) if getattr(problem, "calibration", None) is not None else result
