"""What every method returns: one Result (a routing, its shape, its metrics and solver statistics)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vine_nlp.design.problem import Routing
from vine_nlp.model import phi_from_theta, shape_lines
from vine_nlp.model.chain import segment_end_samples


@dataclass(eq=False)
class Shape:
    center: np.ndarray  # (P, 3)
    inner: np.ndarray  # (P, 3) actuator line
    outer: np.ndarray  # (P, 3)


@dataclass(eq=False)
class Result:
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


def total_variation(v) -> float:
    v = np.asarray(v, float)
    return float(np.abs(np.diff(v)).sum()) if v.size > 1 else 0.0


def error_metrics(model_points, target_points) -> dict:
    """RMSE and max of the distances between paired points (the paper's reported figures)."""
    d = np.linalg.norm(np.asarray(model_points) - np.asarray(target_points), axis=1)
    return {"rmse": float(np.sqrt(np.mean(d**2))), "max_error": float(d.max())}


def routing_metrics(routing: Routing) -> dict:
    return {"tv_theta": total_variation(routing.theta), "tv_lambda": total_variation(routing.lam)}


def forward_shape(routing: Routing, diameter: float, per_segment=None) -> Shape:
    """Shape at every segment end (base first, tip last) and at ``per_segment`` equal
    pieces inside each segment (default: pieces no longer than D/4, so helices look round)."""
    if per_segment is None:
        per_segment = np.maximum(1, np.ceil(routing.length / (0.25 * diameter))).astype(int)
    seg, frac = segment_end_samples(routing.length, per_segment)
    return Shape(*shape_lines(routing.theta, routing.lam, routing.length, diameter, seg, frac, routing.initial_pose))


def run_forward(problem) -> Result:
    """Shape of a given routing (``vine-nlp forward``): a Result with method "forward"."""
    from vine_nlp.design.problem import ForwardProblem

    assert isinstance(problem, ForwardProblem)
    r = problem.routing
    return Result(
        method="forward",
        routing=r,
        shape=forward_shape(r, problem.diameter),
        status="optimal",
        metrics=routing_metrics(r),
        diameter=problem.diameter,
    )
