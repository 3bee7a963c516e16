"""Tutorial 5: correct a built robot from points measured on it.

A built robot is never its design: every segment's theta, lambda and length is a little
off, and the errors add up along the tube. This tutorial designs the paper's trefoil,
"builds" it with seeded construction errors (theta 1 deg, lambda 0.02 plus a systematic
+0.01, length 2 %), measures 200 points on its outer line (1 mm noise, any order), and runs
``vine-nlp correct``: it estimates the routing the robot realizes (run ``as_built``) and
the routing to build next (run ``corrected``). Building the correction with the same
construction errors shows what it gained.

Run:  python3 examples/05_correct_built_robot.py [--out DIR]
Makes: trefoil.h5, measured.csv, correction.h5, correction.png, summary.json.
"""

import h5py
import numpy as np
from _common import PROBLEMS, arguments, vine_nlp, write_summary

import vine_nlp as vn

args = arguments("05_correct_built_robot", __doc__.splitlines()[0])
out = args.out
D = 2.43  # cm, the trefoil's tube
SUB = 10  # each segment drawn as SUB equal pieces: a dense line, the same shape


def build(theta, lam, length, pose):
    """The center and outer lines of a robot built with these per-segment values (dense)."""
    d = vn.forward(np.repeat(theta, SUB), np.repeat(lam, SUB), np.repeat(length / SUB, SUB), D, initial_pose=pose)
    return d.shape.center, d.shape.outer


def error_to(target, center):
    """RMS and largest distance from each target point to the nearest point of a built center line."""
    dist = np.linalg.norm(target[:, None, :] - center[None, :, :], axis=2).min(axis=1)
    return float(np.sqrt(np.mean(dist**2))), float(dist.max())


# 1. the design
vine_nlp("design", PROBLEMS / "trefoil-m4.toml", "-o", out / "trefoil.h5", "--force")
with h5py.File(out / "trefoil.h5", "r") as h5:
    target = h5["target/points"][()]
    g = h5["runs/nlp/design"]
    theta, lam, length, pose = g["theta"][()], g["lambda"][()], g["length"][()], g["initial_pose"][()]

# 2. the build: per-segment construction errors that stay with this robot
rng = np.random.default_rng(3)
d_theta = np.radians(1.0) * rng.standard_normal(theta.size)
d_lam = 0.02 * rng.standard_normal(lam.size) + 0.01  # +0.01: a systematic offset of the stoppers
s_len = 1.0 + 0.02 * rng.standard_normal(length.size)


def as_built(th, la, le):
    return th + d_theta, np.clip(la + d_lam, 0.05, 1.0), le * s_len


center, outer = build(*as_built(theta, lam, length), pose)
before_rms, before_max = error_to(target, center)

# 3. the measurement: 200 points of the outer line, shuffled, 1 mm noise
pick = rng.choice(len(outer), 200, replace=False)
measured = outer[pick] + rng.normal(0.0, 0.1, (200, 3))
np.savetxt(out / "measured.csv", measured, delimiter=",", header="x,y,z", comments="", fmt="%.4f")

# 4. the correction
# exit 1 where some stoppers would have to go beyond lambda's bounds [lambda_min, 1]: `correct` says which
# on stderr and still writes the best correction within them (README, "Correcting a built robot")
vine_nlp("correct", out / "trefoil.h5", out / "measured.csv", "-o", out / "correction.h5", "--plot", out / "correction.png", "--force",
         ok=(0, 1))
with h5py.File(out / "correction.h5", "r") as h5:
    c = h5["runs/corrected/design"]
    theta_c, lam_c, length_c = c["theta"][()], c["lambda"][()], c["length"][()]
    a = h5["runs/as_built/design"]
    lam_ab = a["lambda"][()]

# 5. the corrected routing, built with the same construction errors
center_c, _ = build(*as_built(theta_c, lam_c, length_c), pose)
after_rms, after_max = error_to(target, center_c)
print(f"built from the design:     RMS {before_rms * 10:.1f} mm, max {before_max * 10:.1f} mm off the target")
print(f"built from the correction: RMS {after_rms * 10:.1f} mm, max {after_max * 10:.1f} mm off the target")

write_summary(
    out,
    {
        "before_rms_mm": before_rms * 10.0,
        "before_max_mm": before_max * 10.0,
        "after_rms_mm": after_rms * 10.0,
        "after_max_mm": after_max * 10.0,
        "improvement": before_rms / after_rms,
        # the systematic +0.01 of the stoppers, as the estimate sees it
        "lambda_offset_estimated": float(np.mean(lam_ab - lam)),
        "lambda_offset_true": float(np.mean(d_lam)),
        "theta_unchanged": bool(np.allclose(theta_c, theta)),
        "files": ["trefoil.h5", "measured.csv", "correction.h5", "correction.png"],
    },
)
