"""Measurements and their pairing with the model lines: closest points, ICP-style (numpy model).

A measured point pairs with the point of its line (center, or the inner/outer line at D/2 along the normal)
at its cross-section of the current estimate (the closest center-line point), at a (segment, fraction); the
estimate's residual is the part of the
difference across the line (the tangent at the pair projected out: point-to-line, so the pairing itself
does not pin material points along the tube), except for points beyond an end of the line, which keep the
full residual (their tangent is zero). Free-frame measurements start from a rigid ICP alignment onto their
builds' lines (:func:`rigid_start`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vine_nlp.methods.fit.align import PointSet, Polyline, fit_pose, polish_pose, pose_starts
from vine_nlp.methods.settings import SAMPLES_PER_SEGMENT
from vine_nlp.model.chain import chain_frames, chain_points, segment_end_samples
from vine_nlp.model.routing import MEASURED_LINES, Routing

# offset of each line from the center line along the frame's normal, in units of D
LINE_SIDE = {"center": 0.0, "inner": 0.5, "outer": -0.5}


@dataclass(frozen=True)
class Measurement:
    """Points measured on one line of one build, in any order.

    ``frame``: "archive" (points in the archive's world frame) or "free" (an unknown rigid
    frame, estimated)."""

    points: np.ndarray  # (K, 3), problem units
    line: str = "outer"
    build: int = -1  # index into the builds; -1: the latest
    frame: str = "archive"
    file: str = ""
    state: str = ""  # a tube of several actuators: the state it was measured in

    def __post_init__(self):
        object.__setattr__(self, "points", np.asarray(self.points, float).reshape(-1, 3))
        if self.line not in MEASURED_LINES:
            raise ValueError(f"line must be one of {MEASURED_LINES}, not {self.line!r}")
        if self.frame not in ("archive", "free"):
            raise ValueError("frame must be 'archive' or 'free'")


def in_frame(points: np.ndarray, m: Measurement, T: np.ndarray) -> np.ndarray:
    """``points`` of measurement ``m`` moved by the rigid transform T where its frame is free (else as they are)."""
    return points @ T[:3, :3].T + T[:3, 3] if m.frame == "free" else points


def line_points(routing: Routing, D: float, seg, frac, side: float, frames=None):
    """Points of the line at (seg, frac) and the unit tangents of the center frames there (``frames``: the
    routing's chain frames, when known)."""
    c, rot = chain_points(routing.theta, routing.lam, routing.length, D, seg, frac, routing.initial_pose, frames)
    return c + side * D * rot[:, :, 1], rot[:, :, 0]


@dataclass
class Pairs:
    seg: np.ndarray
    frac: np.ndarray
    tangent: np.ndarray  # zero rows: beyond an end of the line (full residual)
    l: np.ndarray  # material coordinate
    point: np.ndarray  # the paired points of the model line


def pair_with_line(points: np.ndarray, routing: Routing, D: float, side: float, per_segment: int = SAMPLES_PER_SEGMENT, line=None) -> Pairs:
    """Pairs of measured points with the model line (``side``: offset along the normal in D): each point's place
    along the tube is the closest point of the center line (its cross-section: the line on the surface may wind
    around the tube where theta is large, and a wrong roll would pair it with the wrong turn), its pair the line's
    point there. ``line(seg, frac, side)``: (points, tangents) of another chain on the routing's lengths (a state of
    several actuators, model.actuators.state_line); default the routing's own."""
    seg, frac = segment_end_samples(routing.length, per_segment)
    if line is None:
        F = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)
        line = lambda s, f, sd: line_points(routing, D, s, f, sd, F)  # noqa: E731
    P, _ = line(seg, frac, 0.0)
    cum = np.concatenate([[0.0], np.cumsum(routing.length)])
    lmat = cum[seg] + frac * routing.length[seg]
    d = np.diff(P, axis=0)
    n2 = np.maximum(np.sum(d * d, axis=1), 1e-300)
    from scipy.spatial import cKDTree  # SciPy loads only where measurements are paired

    k = min(4, P.shape[0])
    _, idx = cKDTree(P).query(points, k=k)
    idx = idx.reshape(points.shape[0], k)
    cand = np.clip(np.concatenate([idx - 1, idx], axis=1), 0, d.shape[0] - 1)
    u = np.clip(np.einsum("kcj,kcj->kc", points[:, None, :] - P[cand], d[cand]) / n2[cand], 0.0, 1.0)
    q = P[cand] + u[..., None] * d[cand]
    best = np.argmin(np.sum((points[:, None, :] - q) ** 2, axis=2), axis=1)
    rows = np.arange(points.shape[0])
    piece, uu = cand[rows, best], u[rows, best]
    l = lmat[piece] + uu * (lmat[piece + 1] - lmat[piece])
    j = np.clip(np.searchsorted(cum, l, side="right") - 1, 0, routing.segments - 1)
    f = np.clip((l - cum[j]) / routing.length[j], 0.0, 1.0)
    Pj, t = line(j, f, side)
    end = ((piece == 0) & (uu <= 0.0)) | ((piece == d.shape[0] - 1) & (uu >= 1.0))
    t[end] = 0.0
    return Pairs(j, f, t, l, Pj)


def rigid_start(measurements, routings, D):
    """A rigid transform (4x4) of the free-frame measurements onto the model lines of their builds (ICP)."""
    sets = []
    for ms in measurements:
        if ms.frame != "free":
            continue
        r = routings[ms.build]
        seg, frac = segment_end_samples(r.length, 8)
        P, _ = line_points(r, D, seg, frac, LINE_SIDE[ms.line])
        sets.append(PointSet(ms.points, Polyline(P)))
    if not sets:
        return np.eye(4)
    X = np.concatenate([s.points for s in sets])
    Y = np.concatenate([s.line.p for s in sets])
    return polish_pose(sets, fit_pose(sets, pose_starts(X, Y, 24, 0)).T)[0]
