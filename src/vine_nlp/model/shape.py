"""The modelled shape of a routing (center, actuator and opposite lines) and its error figures."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vine_nlp.model.chain import segment_end_samples, shape_lines
from vine_nlp.model.routing import Routing


@dataclass(eq=False)
class Shape:
    center: np.ndarray  # (P, 3)
    inner: np.ndarray  # (P, 3) actuator line
    outer: np.ndarray  # (P, 3)


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
