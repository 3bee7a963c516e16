"""Tutorial 5: correct a built robot from points measured on it.

A built robot is never its design: every segment's theta, lambda and length is a little
off, and the errors add up along the tube. This tutorial designs the paper's trefoil,
"builds" it with seeded construction errors (theta 1 deg, lambda 0.02 plus a systematic
+0.01, length 2 %; a segment without an actuator, lambda exactly 1, stays at 1: the physical
rule), measures 200 points on its outer line (1 mm noise, any order), and runs
``vine-nlp correct``: it estimates the routing the robot realizes (run ``as_built``) and
predicts two routes to build next: ``lambda`` (stoppers or pouches moved on this robot, its
line kept) and ``lambda,theta`` (the line drawn anew on a new tube). The recommended one is
run ``corrected``. Building each route with the same construction errors shows what it gained.

Run:  python3 examples/05_correct_built_robot.py [--out DIR]
Makes: trefoil.h5, measured.csv, correction.h5, correction.png, summary.json.
"""

import h5py
import numpy as np
from _common import PROBLEMS, arguments, vine_nlp, write_summary

import vine_nlp as vn
from vine_nlp.model.routing import built_lambda

args = arguments("05_correct_built_robot", __doc__.splitlines()[0])
out = args.out
D = 2.43  # cm, the trefoil's tube
SUB = 10  # each segment drawn as SUB equal pieces: a dense line, the same shape
LAMBDA_MIN = 0.4  # the trefoil's actuator: it cannot contract beyond this


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
    """The physical rule: no actuator where lambda is 1 (it stays 1), else nominal + error within [LAMBDA_MIN, 1]."""
    return th + d_theta, built_lambda(la, d_lam, LAMBDA_MIN), le * s_len


center, outer = build(*as_built(theta, lam, length), pose)
before_rms, before_max = error_to(target, center)

# 3. the measurement: 200 points of the outer line, shuffled, 1 mm noise
pick = rng.choice(len(outer), 200, replace=False)
measured = outer[pick] + rng.normal(0.0, 0.1, (200, 3))
np.savetxt(out / "measured.csv", measured, delimiter=",", header="x,y,z", comments="", fmt="%.4f")

# 4. the correction: both routes predicted, the recommended one written as run `corrected`
# (exit 1 where the route taken cannot reach the target within lambda's bounds: `correct` says which
# segments on stderr and still writes the best correction; README, "Correcting a built robot")
vine_nlp("correct", out / "trefoil.h5", out / "measured.csv", "-o", out / "correction.h5", "--plot", out / "correction.png", "--force",
         ok=(0, 1))
with h5py.File(out / "correction.h5", "r") as h5:
    recommended, taken = h5["correction"].attrs["recommended"], h5["correction"].attrs["adjust"]
    routes = {name: (h5[f"runs/{run}/design/theta"][()], h5[f"runs/{run}/design/lambda"][()], h5[f"runs/{run}/design/length"][()])
              for name, run in (("corrected", "corrected"), ("lambda", "corrected_lambda"), ("lambda,theta", "corrected_lambda_theta"))}
    lam_ab = h5["runs/as_built/design/lambda"][()]

# 5. each route, built with the same construction errors
after = {name: error_to(target, build(*as_built(*r), pose)[0]) for name, r in routes.items()}
print(f"recommended route: {recommended} (taken: {taken})")
for label, (rms, mx) in (("the design", (before_rms, before_max)), ("the lambda route", after["lambda"]),
                         ("the lambda,theta route", after["lambda,theta"])):
    print(f"built from {label + ':':<24} RMS {rms * 10:.1f} mm, max {mx * 10:.1f} mm off the target")
theta_l, lam_l, length_l = routes["lambda"]
actuated = lam < 1.0  # lambda exactly 1: no actuator on the robot that was built
write_summary(
    out,
    {
        "before_rms_mm": before_rms * 10.0,
        "before_max_mm": before_max * 10.0,
        "after_rms_mm": after["corrected"][0] * 10.0,
        "after_max_mm": after["corrected"][1] * 10.0,
        "improvement": before_rms / after["corrected"][0],
        "after_lambda_rms_mm": after["lambda"][0] * 10.0,
        "after_lambda_theta_rms_mm": after["lambda,theta"][0] * 10.0,
        "recommended": str(recommended),
        "taken_is_recommended": str(taken) == str(recommended),
        # the systematic +0.01 of the stoppers, as the estimate sees it (where there are stoppers)
        "lambda_offset_estimated": float(np.mean((lam_ab - lam)[actuated])),
        "lambda_offset_true": float(np.mean(d_lam[actuated])),
        # the lambda route moves stoppers only: the line drawn on the tube stays, and no actuator is added
        "lambda_route_keeps_theta": bool(np.allclose(theta_l, theta)),
        "lambda_route_adds_no_actuator": bool(np.all(lam_l[~actuated] == 1.0)),
        "lambda_theta_route_changes_theta": bool(not np.allclose(routes["lambda,theta"][0], theta)),
        "files": ["trefoil.h5", "measured.csv", "correction.h5", "correction.png"],
    },
)
