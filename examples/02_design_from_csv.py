"""Tutorial 2: design a routing for your own curve, given as a CSV of points (Python API).

``examples/data/hand-drawn.csv`` holds 160 points (x, y, z in cm, base to tip) of a curve
sketched by hand, with 0.3 mm of jitter. This script designs for it through the Python
API; ``examples/data/hand-drawn.toml`` is the same problem as a file for the command
line (``vine-nlp design examples/data/hand-drawn.toml -o hand-drawn.h5``).

Run:  python3 examples/02_design_from_csv.py [--out DIR]
Makes: hand-drawn.h5, hand-drawn.png, summary.json.
"""

import h5py
import numpy as np
from _common import DATA, arguments, write_summary

import vine_nlp as vn

args = arguments("02_design_from_csv", __doc__.splitlines()[0])
out = args.out

points = np.loadtxt(DATA / "hand-drawn.csv", delimiter=",", skiprows=1)  # header row x,y,z
d = vn.design(
    points,
    diameter=2.43,  # cm, like the points
    actuator="tendon",
    lambda_min=0.4,
    theta_max_deg=60.0,
    points_per_segment=8,  # 160 points -> 20 segments of about 5 cm
    starts=2,  # also the mirrored start; the better design is kept
    name="hand-drawn",
)
print(d)
print(f"{d.status}: RMSE {d.rmse * 10:.3f} mm, max error {d.max_error * 10:.3f} mm, {d.segments} segments")
print("theta [deg]:", np.round(np.degrees(d.routing.theta), 1) + 0.0)  # + 0.0: a rounded -0.04 prints 0., not -0.
print("lambda:     ", np.round(d.routing.lam, 3))

d.save(out / "hand-drawn.h5", overwrite=True)  # an archive every command reads
d.plot(out / "hand-drawn.png", overwrite=True)

# The archive holds the target as given and the model's paired points (row i with row i).
with h5py.File(out / "hand-drawn.h5", "r") as h5:
    target = h5["target/points"][()]
    center = h5["runs/nlp/shape/center"][()]

write_summary(
    out,
    {
        "status": d.status,
        "points": int(len(target)),
        "target_equals_csv": bool(np.allclose(target, points)),
        "rmse_mm": float(d.rmse) * 10.0,
        # the RMSE recomputed from the archive's paired rows
        "rmse_recomputed_mm": float(np.sqrt(np.mean(np.sum((center - target) ** 2, axis=1)))) * 10.0,
        "max_error_mm": float(d.max_error) * 10.0,
        "segments": int(d.segments),
        "max_abs_theta_deg": float(np.degrees(np.abs(d.routing.theta)).max()),
        "lambda_range": [float(d.routing.lam.min()), float(d.routing.lam.max())],
        "files": ["hand-drawn.h5", "hand-drawn.png"],
    },
)
