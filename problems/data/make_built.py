"""Make problems/data/trefoil-built.csv: points measured on a simulated build of the trefoil.

The trefoil of problems/trefoil-m4.toml is designed (vine_nlp.solve: what ``vine-nlp design`` makes) and
built physically (tests/simulate.py: no lambda error without an actuator, built lambda within
[lambda_min, 1]) with known construction errors: per segment theta, lambda and length errors at sigma
1 deg / 0.02 / 2 % (seed 14) plus systematic parts, a theta offset of +0.5 deg, a lambda offset of
+0.015 and a length scale of 1.01. 400 points along the outer line, equally spaced along the tube,
with Gaussian noise of 0.5 mm per coordinate (seed 15), shuffled, in cm, in the design archive's
frame. Try: vine-nlp design problems/trefoil-m4.toml -o t.h5 && vine-nlp correct t.h5
problems/data/trefoil-built.csv -o c.h5. Run from anywhere: python3 problems/data/make_built.py
"""

import math
import sys
from pathlib import Path

import numpy as np

import vine_nlp as vn
from vine_nlp.io.problem_file import load_problem
from vine_nlp.model.routing import Sigmas

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "tests"))
from simulate import draw_deviations, simulate_build  # noqa: E402  (the simulated builds of tests and benchmarks)

SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)
SYSTEMATIC = (math.radians(0.5), 0.015, 1.01)  # theta offset, lambda offset, length scale
NOISE = 0.05  # cm (0.5 mm)


def main():
    pb = load_problem(HERE.parent / "trefoil-m4.toml").problem
    nominal = vn.solve(HERE.parent / "trefoil-m4.toml").routing
    dev = draw_deviations(nominal, SIGMAS, SYSTEMATIC, seed=14, lambda_min=pb.actuator.lambda_min)
    pts = simulate_build(nominal, dev, pb.diameter, "outer", 400, NOISE, seed=15)
    out = HERE / "trefoil-built.csv"
    np.savetxt(out, pts, delimiter=",", fmt="%.4f", header="x,y,z  # cm, outer line, simulated build (make_built.py)", comments="")
    print(f"{pts.shape[0]} points -> {out}")


if __name__ == "__main__":
    main()
