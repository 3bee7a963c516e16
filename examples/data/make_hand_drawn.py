"""Make ``hand-drawn.csv``: a curve as someone might sketch it, a few clicks joined smoothly.

Eight control points (cm) traced through a Catmull-Rom spline, sampled at 160 points,
with 0.3 mm of seeded jitter standing in for an unsteady hand. Run once; the CSV is shipped.
"""

from pathlib import Path

import numpy as np

CLICKS = np.array(
    [[0, 0, 0], [15, 0, 0], [30, 3, 2], [42, 10, 8], [48, 22, 15], [44, 33, 22], [34, 37, 28], [24, 33, 33]],
    dtype=float,
)


def catmull_rom(points: np.ndarray, per_span: int) -> np.ndarray:
    """A centripetal-free (uniform) Catmull-Rom spline through ``points``, ``per_span`` samples per span."""
    p = np.vstack([2 * points[0] - points[1], points, 2 * points[-1] - points[-2]])
    t = np.linspace(0.0, 1.0, per_span, endpoint=False)[:, None]
    spans = []
    for i in range(1, len(p) - 2):
        p0, p1, p2, p3 = p[i - 1], p[i], p[i + 1], p[i + 2]
        spans.append(0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2 + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3))
    return np.vstack(spans + [points[-1:]])


if __name__ == "__main__":
    curve = catmull_rom(CLICKS, 23)[:160]
    curve[1:] += np.random.default_rng(7).normal(0.0, 0.03, size=curve[1:].shape)
    path = Path(__file__).with_name("hand-drawn.csv")
    np.savetxt(path, curve, delimiter=",", header="x,y,z", comments="", fmt="%.4f")
    print(f"{len(curve)} points -> {path}")
