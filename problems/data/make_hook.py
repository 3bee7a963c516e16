"""Make problems/data/hook.csv: the hook target of problems/hook.toml, in cm.

60 cm straight along x, then a half circle of radius 10 cm (in the x-y plane, turning towards +y),
400 points equally spaced in arc length (60 + 10 pi cm). Run from anywhere: python3 problems/data/make_hook.py
"""

from pathlib import Path

import numpy as np

STRAIGHT, RADIUS, SAMPLES = 60.0, 10.0, 400


def hook(samples: int = SAMPLES) -> np.ndarray:
    s = np.linspace(0.0, STRAIGHT + np.pi * RADIUS, samples)
    a = np.clip(s - STRAIGHT, 0.0, None) / RADIUS  # angle turned on the half circle
    x = np.minimum(s, STRAIGHT) + RADIUS * np.sin(a)
    return np.column_stack([x, RADIUS * (1.0 - np.cos(a)), np.zeros_like(s)])


if __name__ == "__main__":
    out = Path(__file__).resolve().parent / "hook.csv"
    np.savetxt(out, hook(), fmt="%.6f", delimiter=",", header="x,y,z  # cm: 60 cm straight, half circle R 10 cm (make_hook.py)", comments="")
