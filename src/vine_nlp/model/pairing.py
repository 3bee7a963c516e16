"""Pairing of target points with model points (shared by every design method and the analyses).

Pairing (the paper's PathError): the N target points are cut into segments of n intervals (the last segment takes the
remainder), M = ceil((N - 1) / n). Target point k = j n + i sits in segment j; it pairs with the model point at the
fraction of segment j given by the target's own chord length inside that segment, so unevenly sampled targets (the
trefoil is equally spaced in t, not in arc length) pair with matching model points. The tip target pairs with the end of
the last segment."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pairing:
    """Which model point each target point pairs with (see :func:`pair_points`)."""

    segments: int  # M
    n: int  # slots per segment (points per segment)
    seg: np.ndarray  # (N,) segment of each target point
    frac: np.ndarray  # (N,) fraction of that segment
    bounds: np.ndarray  # (M+1,) target index of each segment end
    chord: np.ndarray  # (N,) cumulative chord length of the target

    @property
    def segment_chord(self) -> np.ndarray:
        return np.diff(self.chord[self.bounds])


def pair_points(target: np.ndarray, n: int) -> Pairing:
    """Pair the N target points (the center line (N, 3), in order) with model points, ``n`` intervals of the
    target per segment: M = ceil((N - 1) / n) segments (module docstring). The Pairing holds the segment and
    fraction of every target point, the target index of each segment end and the target's cumulative chord
    length. ValueError for a target of fewer than two points."""
    target = np.asarray(target, float)
    N = target.shape[0]
    if N < 2:
        raise ValueError("a target needs at least two points")
    M = math.ceil((N - 1) / n)
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(target, axis=0), axis=1))])
    bounds = np.minimum(np.arange(M + 1) * n, N - 1)
    k = np.arange(N)
    seg = np.minimum(k // n, M - 1)
    start, end = chord[bounds[seg]], chord[bounds[seg + 1]]
    frac = (chord - start) / (end - start)
    return Pairing(M, n, seg, frac, bounds, chord)
