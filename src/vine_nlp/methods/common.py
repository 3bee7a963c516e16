"""What every design method shares: the fit error, bounds, initial guesses.

The pairing of target points with model points (the paper's PathError) is
``vine_nlp.model.pairing``, re-exported here for the methods."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vine_nlp.methods import variables
from vine_nlp.model import shape_lines
from vine_nlp.model.helix import center_rates, helix_from_curvature
from vine_nlp.model.pairing import Pairing, pair_points  # noqa: F401  (pair_points: used by every method)
from vine_nlp.model.shape import Shape, error_metrics, forward_shape, routing_metrics
from vine_nlp.problem import DesignProblem, ForwardProblem, Result, Routing


def path_error(model_points, target_points, weights=None):
    """Sum of squared distances between paired points: the smooth form of the paper's PathError."""
    d2 = np.sum((np.asarray(model_points) - np.asarray(target_points)) ** 2, axis=1)
    return float(d2.sum() if weights is None else (weights * d2).sum())


def design_bounds(problem: DesignProblem, pairing: Pairing, D: float | None = None) -> dict:
    """{name: (lower, upper)} per segment of the routing's declared variables (paper Sec. VI-A: |theta| <=
    theta_max, lambda_min <= lam <= 1, lengths within LENGTH_FACTOR of the target's chords), lengths in
    problem units, or in units of ``D``."""
    return variables.box(problem.actuator, pairing.segment_chord if D is None else pairing.segment_chord / D)


def clip_to_bounds(problem: DesignProblem, pairing: Pairing, **values) -> dict:
    """Routing ``values`` by name (problem units) clipped into ``design_bounds``."""
    return variables.clip(values, design_bounds(problem, pairing))


def evaluate(problem: DesignProblem, routing: Routing, pairing: Pairing, method: str, **kw) -> Result:
    """Model the routing at the paired points and measure it against the target."""
    center, inner, outer = shape_lines(routing.theta, routing.lam, routing.length, problem.diameter, pairing.seg, pairing.frac,
                                       routing.initial_pose)
    metrics = error_metrics(center, problem.target) | routing_metrics(routing)
    return Result(method=method, routing=routing, shape=Shape(center, inner, outer), metrics=metrics, diameter=problem.diameter, **kw)


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _perpendicular(t):
    """Some unit vector perpendicular to t (for straight targets where no normal is defined)."""
    a = np.array([0.0, 0.0, 1.0]) if abs(t[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    return _unit(a - np.dot(a, t) * t)


def _reject(v: np.ndarray, axis: np.ndarray) -> list:
    """v minus its component along ``axis`` as floats, as ``v - np.dot(v, axis) * axis`` rounds it."""
    d = float(np.dot(v, axis))
    return [x - d * a for x, a in zip(v.tolist(), axis.tolist())]


def _unit3(v: list) -> np.ndarray:
    """``_unit`` of one 3-vector given as floats, bit-identical (norm's sum of squares runs left to right)."""
    x, y, z = v
    n = math.sqrt(x * x + y * y + z * z)
    if not n > 0:
        n = 1.0
    return np.array([x / n, y / n, z / n])


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross of two 3-vectors, written out (the same products and differences, so the same bits)."""
    (a0, a1, a2), (b0, b1, b2) = a.tolist(), b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


@dataclass
class Guess:
    theta: np.ndarray
    lam: np.ndarray
    length: np.ndarray
    initial_pose: np.ndarray  # (4, 4)
    frames: np.ndarray  # (M+1, 4, 4) target-based frames at the segment ends

    def routing(self) -> Routing:
        return Routing(theta=self.theta, lam=self.lam, length=self.length, initial_pose=self.initial_pose)


def geometric_guess(problem: DesignProblem, pairing: Pairing, flip_sign: float = 1.0) -> Guess:
    """Initial design from the target's own geometry.

    Per segment: the turning angle of the target's tangents gives the curvature, the rotation of the bending direction
    about the tangent between neighbouring segments gives the torsion, and Table I's inverse (helix_from_curvature)
    turns both into theta and lambda, clipped to the bounds. A bending direction that flips (an inflection, where the
    actuator must move to the other side of the tube) is a rotation of +-pi about the tangent: ``flip_sign`` picks the
    side, which breaks the theta -> -theta symmetry of planar targets (model notes, symmetry trap)."""
    D, tgt = problem.diameter, problem.target
    M, b = pairing.segments, pairing.bounds
    tangent = _unit(np.gradient(tgt, pairing.chord, axis=0))
    arc = np.maximum(pairing.segment_chord, 1e-12)
    t0, t1 = tangent[b[:-1]], tangent[b[1:]]
    turn = np.arccos(np.clip(np.sum(t0 * t1, axis=1), -1.0, 1.0))
    kappa = turn / arc
    # bending direction at each segment's middle: where the tangent turns to
    tmid = _unit(t0 + t1)
    bend = t1 - t0
    bend = bend - np.sum(bend * tmid, axis=1, keepdims=True) * tmid
    straight = np.linalg.norm(bend, axis=1) < 1e-9
    normal = _unit(bend)
    last = None
    for j in range(M):  # straight segments keep the previous bending direction
        if straight[j]:
            normal[j] = _perpendicular(tmid[j]) if last is None else _unit(last - np.dot(last, tmid[j]) * tmid[j])
        last = normal[j]
    # torsion: rotation of the bending direction about the tangent from one segment middle to the next.
    # The loops below work on 3-vectors one at a time: in Python floats (IEEE doubles, one rounding per
    # operation, the order numpy uses: bit-identical to np.cross and to np.linalg.norm(v, axis=-1)), and
    # np.dot for dot products (its BLAS kernel may fuse multiply-adds: only np.dot itself gives its bits).
    # The guess must not change in its last bit: IPOPT's path from it does (hundreds of iterations on
    # obstacle-mesh).
    psi = np.zeros(M + 1)
    for j in range(M - 1):
        axis = tangent[b[j + 1]]
        n0 = _unit3(_reject(normal[j], axis))
        n1 = _unit3(_reject(normal[j + 1], axis))
        ang = math.atan2(float(np.dot(_cross3(n0, n1), axis)), float(np.dot(n0, n1)))
        if abs(ang) > 0.8 * math.pi:
            # a near-reversal: the sign is arbitrary for planar targets, so choose it
            ang = flip_sign * abs(ang)
        psi[j + 1] = ang
    # half of each boundary rotation belongs to each neighbouring segment
    tau = 0.5 * (psi[:-1] + psi[1:]) / arc
    theta, lam = helix_from_curvature(kappa, tau, D)
    _, _, lambda_c = center_rates(theta, lam, D)
    length = arc / lambda_c
    theta, lam, length = clip_to_bounds(problem, pairing, theta=theta, lam=lam, length=length).values()
    # frames at the segment ends, on the target: normal rotated back from the segment middle
    frames = np.zeros((M + 1, 4, 4))
    t_end = tangent[b]
    n_end = np.empty((M + 1, 3))
    for j in range(M + 1):
        t = t_end[j]
        nn = _unit3(_reject(normal[min(j, M - 1)], t))
        n_end[j] = _perpendicular(t) if math.sqrt(float(np.dot(nn, nn))) < 0.5 else nn
    frames[:, :3, 0], frames[:, :3, 1] = t_end, n_end
    # np.cross(t, n) written out: the same products and differences, so the same bits
    (t0x, t0y, t0z), (nx, ny, nz) = t_end.T, n_end.T
    frames[:, 0, 2] = t0y * nz - t0z * ny
    frames[:, 1, 2] = t0z * nx - t0x * nz
    frames[:, 2, 2] = t0x * ny - t0y * nx
    frames[:, :3, 3] = tgt[b]
    frames[:, 3, 3] = 1.0
    return Guess(theta, lam, length, frames[0].copy(), frames)


def run_forward(problem) -> Result:
    """Shape of a given routing (``vine-nlp forward``): a Result with method "forward"."""
    assert isinstance(problem, ForwardProblem)
    r = problem.routing
    return Result(method="forward", routing=r, shape=forward_shape(r, problem.diameter), status="optimal", metrics=routing_metrics(r),
                  diameter=problem.diameter)
