"""What every method returns: one Result (a routing, its shape, its metrics and solver statistics)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vine_nlp.design.problem import ForwardProblem
from vine_nlp.model import phi_from_theta
from vine_nlp.model.routing import Routing
from vine_nlp.model.shape import (  # noqa: F401  (re-exported: their old home)
    Shape,
    error_metrics,
    forward_shape,
    routing_metrics,
    total_variation,
)


@dataclass(eq=False)
class Result:
    """What every method returns: one routing, its shape, its metrics and solver statistics.

    Parameters
    ----------
    method : str
        The run's name ("nlp", "greedy", "multishape", "tip", "nlp_robust", ...).
    routing : Routing
        The design (per segment theta, lambda, length) and its base pose.
    shape : Shape
        The modeled center, actuator and opposite lines; design runs: row i pairs with target row i.
    status : str
        "optimal", "acceptable", "max_iter", "failed", ... (IPOPT's return status, archived).
    solve_time_s : float
        Time of the method, in seconds.
    iterations : int
        IPOPT iterations (summed over starts, hops and rounds).
    metrics : dict
        rmse, max_error (problem units), tv_theta, tv_lambda and formulation-specific figures.
    stats : dict
        Solver statistics and options, archived as attributes of ``/runs/<run>/solver``.
    diameter : float
        Tube diameter D.
    """

    method: str
    routing: Routing
    shape: Shape
    status: str = "optimal"  # optimal | acceptable | max_iter | failed | ...
    solve_time_s: float = 0.0
    iterations: int = 0
    metrics: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)  # solver statistics and options, archived as attributes
    diameter: float = 1.0

    @property
    def phi(self) -> np.ndarray:
        return phi_from_theta(self.routing.theta, self.routing.length, self.diameter)

    @property
    def converged(self) -> bool:
        return self.status in ("optimal", "acceptable")


def run_forward(problem) -> Result:
    """Shape of a given routing (``vine-nlp forward``): a Result with method "forward"."""
    assert isinstance(problem, ForwardProblem)
    r = problem.routing
    return Result(method="forward", routing=r, shape=forward_shape(r, problem.diameter), status="optimal", metrics=routing_metrics(r),
                  diameter=problem.diameter)
