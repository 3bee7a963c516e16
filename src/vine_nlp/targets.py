"""Target curves for inverse design (paper Sec. VII): sampled center lines as (N, 3) arrays.

Pure numpy; reading curves from files is ``vine_nlp.io.problems``'s job. Every
generator returns points in the order the tube should pass through them."""

from __future__ import annotations

import math

import numpy as np

DEFAULT_SAMPLES = 400  # the paper samples its trefoils and Bezier targets with 400 points
MAX_BEZIER_POINTS = 1000  # binomial coefficients of higher degrees overflow a float


def trefoil(scale=(4.0, 4.0, 4.0), t_range=(-0.2 * math.pi, 1.5 * math.pi), samples: int = DEFAULT_SAMPLES) -> np.ndarray:
    """Trefoil knot of eq. (knot), ``samples`` points equally spaced in t.

    r(t) = [m_x (sin t + 2 sin 2t), m_y (cos t - 2 cos 2t), -m_z sin 3t] with
    (m_x, m_y, m_z) = ``scale``; the paper uses t in [-0.2 pi, 1.5 pi]."""
    mx, my, mz = (float(m) for m in scale)
    t = np.linspace(float(t_range[0]), float(t_range[1]), _samples(samples))
    return np.column_stack([mx * (np.sin(t) + 2 * np.sin(2 * t)), my * (np.cos(t) - 2 * np.cos(2 * t)), -mz * np.sin(3 * t)])


def bezier(control_points, samples: int = DEFAULT_SAMPLES) -> np.ndarray:
    """Bezier curve of the K control points (Bernstein form), ``samples`` points equally spaced in t in [0, 1].

    2-D control points mean z = 0. The first and last samples are the first and last control points."""
    p = as_3d(control_points, least=2)
    if p.shape[0] > MAX_BEZIER_POINTS:
        raise ValueError(f"at most {MAX_BEZIER_POINTS} control points")
    degree = p.shape[0] - 1
    t = np.linspace(0.0, 1.0, _samples(samples))[:, None]
    i = np.arange(degree + 1)
    binomial = np.array([math.comb(degree, k) for k in i], dtype=float)
    basis = binomial * t**i * (1.0 - t) ** (degree - i)
    return basis @ p


def polyline(control_points, samples: int = DEFAULT_SAMPLES) -> np.ndarray:
    """Straight lines through the control points, ``samples`` points equally spaced in arc length.

    The first and last control points are the first and last samples; inner corners are generally not sampled. Repeated
    consecutive control points are ignored."""
    p = as_3d(control_points, least=2)
    keep = np.concatenate([[True], np.any(np.diff(p, axis=0) != 0, axis=1)])
    p = p[keep]
    if p.shape[0] < 2:
        raise ValueError("the control points are all the same point")
    s = arc_length(p)
    u = np.linspace(0.0, s[-1], _samples(samples))
    return np.column_stack([np.interp(u, s, p[:, k]) for k in range(3)])


def helix(radius: float, pitch: float, length: float, samples: int = DEFAULT_SAMPLES) -> np.ndarray:
    """Helix of radius R and pitch parameter b (rise 2 pi b per turn), arc length ``length``.

    Eq. (Helix) moved to start at the origin: r(u) = [R sin u, R (cos u - 1), b u], u in [0, length / sqrt(R^2 + b^2)],
    so samples equally spaced in u are equally spaced in arc length. The axis is the line x = 0, y = -R, parallel to z;
    b < 0 gives the mirrored (opposite-handed) helix, R = 0 a straight line along z."""
    radius, pitch, length = float(radius), float(pitch), float(length)
    if radius < 0:
        raise ValueError("radius must be >= 0")
    if not length > 0:
        raise ValueError("length must be > 0")
    speed = math.hypot(radius, pitch)  # |dr/du|
    if speed == 0:
        raise ValueError("radius and pitch cannot both be 0")
    u = np.linspace(0.0, length / speed, _samples(samples))
    return np.column_stack([radius * np.sin(u), radius * (np.cos(u) - 1.0), pitch * u])


def check_points(points) -> np.ndarray:
    """A user's target points as a float (N, 3) array (2-D columns mean z = 0), or ValueError.

    Needs at least 3 finite points and no two consecutive identical points (a
    zero-length step has no direction to fit); indices in messages count from 1."""
    p = as_3d(points, least=3)
    if not np.all(np.isfinite(p)):
        row = int(np.argmax(~np.all(np.isfinite(p), axis=1)))
        raise ValueError(f"point {row + 1} is not finite")
    same = np.all(np.diff(p, axis=0) == 0, axis=1)
    if same.any():
        j = int(np.argmax(same))
        raise ValueError(f"points {j + 1} and {j + 2} are identical")
    return p


def arc_length(points) -> np.ndarray:
    """Cumulative chord length along the points, (N,), starting at 0."""
    p = np.asarray(points, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def as_3d(points, least: int) -> np.ndarray:
    """Points as a float (N, 3) array, N >= ``least`` (2-D columns mean z = 0), or ValueError."""
    try:
        p = np.array(points, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("points must be an N x 3 (or N x 2) array of numbers") from None
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError(f"points must be an N x 3 (or N x 2) array, got shape {p.shape}")
    if p.shape[0] < least:
        raise ValueError(f"needs at least {least} points, got {p.shape[0]}")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(p.shape[0])])
    return p


def _samples(samples) -> int:
    if isinstance(samples, bool) or int(samples) != samples or samples < 2:
        raise ValueError("samples must be an integer >= 2")
    return int(samples)
