"""Make the synthetic measurements bundled with the fit problems (reproducible, seeded).

Stand-ins for the paper's tracker data (Sec. V), which is not published: the model
shape of a known routing, moved to a random pose, sampled at markers and perturbed
by 1.4 mm RMS noise like the paper's magnetic tracker. Run from this folder:
python make_synthetic.py
"""

import numpy as np
from scipy.spatial.transform import Rotation

from vine_nlp.problem import Routing
from vine_nlp.model import shape_lines

NOISE_RMS = 0.14  # cm, 3-D RMS


def markers(routing, D, line, count, seed):
    rng = np.random.default_rng(seed)
    L = routing.length.sum()
    s = np.sort(rng.uniform(0.03 * L, 0.97 * L, count))
    edges = np.concatenate([[0], np.cumsum(routing.length)])
    seg = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, routing.segments - 1)
    frac = (s - edges[seg]) / routing.length[seg]
    lines = dict(zip(("center", "inner", "outer"), shape_lines(routing.theta, routing.lam, routing.length, D, seg, frac)))
    pts = lines[line]
    T = Rotation.random(random_state=seed)
    pts = T.apply(pts) + rng.normal(0, 20, 3)
    pts += rng.normal(0, NOISE_RMS / np.sqrt(3), pts.shape)
    return pts[rng.permutation(count)]


def main():
    # the paper's sinusoidal sPAM routing (Sec. V-B) at lambda = 0.85, 15 outer-line markers
    s = np.arange(100) * 1.0
    r = Routing(np.pi / 12 * np.sin(0.1 * s), 0.85, np.ones(100))
    np.savetxt("sinusoidal-frame.csv", markers(r, 3.31, "outer", 15, 7), delimiter=",", header="x,y,z", comments="", fmt="%.4f")
    # the active sPAM helix (Sec. V-A): theta 4 deg, D 3.23 cm, lambda 0.91, 60 cm, 15 outer markers
    r = Routing(np.full(60, np.radians(4.0)), 0.91, np.ones(60))
    np.savetxt("active-helix-frame.csv", markers(r, 3.23, "outer", 15, 12), delimiter=",", header="x,y,z", comments="", fmt="%.4f")


def frames():
    """Five frames of the sinusoidal sPAM under rising pressure (paper Fig. 9: best-fit lambda 0.98 ... 0.76)."""
    from pathlib import Path

    s = np.arange(100) * 1.0
    Path("sinusoidal-frames").mkdir(exist_ok=True)
    for k, lam in enumerate([0.98, 0.93, 0.87, 0.81, 0.76]):
        r = Routing(np.pi / 12 * np.sin(0.1 * s), lam, np.ones(100))
        pts = markers(r, 3.31, "outer", 15, 100 + k)
        np.savetxt(f"sinusoidal-frames/frame-{k}.csv", pts, delimiter=",", header="x,y,z", comments="", fmt="%.4f")


if __name__ == "__main__":
    frames()
    main()
