"""Make problems/data/actuators-base-tip-{A,B,AB}.csv: the targets of problems/actuators-base-tip.toml, in cm.

A known routing of two actuators on one tube (D = 2.43 cm, 20 segments of 2 cm): A contracts the first 8 segments
(lambda 0.7, theta 5 deg), B the last 8 (lambda 0.75, theta -4 deg), drawn on the opposite side of the tube
(phi_B[0] = pi). Each state's center line ({A}, {B}, {A, B}) at 201 points equally spaced in its length, so the
design can meet every state exactly. Run from anywhere: python3 problems/data/make_actuators_base_tip.py
"""

from pathlib import Path

import numpy as np

from vine_nlp.methods.actuators import sample_states
from vine_nlp.model.actuators import Lines

M, D = 20, 2.43


def truth() -> Lines:
    lam = np.ones((2, M))
    lam[0, :8], lam[1, 12:] = 0.7, 0.75
    theta = np.radians([np.full(M, 5.0), np.full(M, -4.0)])
    return Lines(("A", "B"), theta, lam, [0.0, np.pi], np.full(M, 2.0))


if __name__ == "__main__":
    here = Path(__file__).resolve().parent
    for state, pts in sample_states(truth(), D, {"A": ("A",), "B": ("B",), "AB": ("A", "B")}, 201).items():
        np.savetxt(here / f"actuators-base-tip-{state}.csv", pts, fmt="%.6f", delimiter=",",
                   header=f"x,y,z  # cm: state {state} (make_actuators_base_tip.py)", comments="")
