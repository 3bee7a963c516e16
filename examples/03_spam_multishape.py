"""Tutorial 3: one sPAM routing for several shapes (one shape per pressure level).

An sPAM (series pouch motor) contracts the whole actuator by one lambda that the
pressure sets, so one routing gives a family of shapes. ``problems/multishape-spam.toml``
asks for three helices, the paper's active sPAM helix (D = 3.23 cm, theta = 4 deg) at
lambda = 0.87 (fixed), 0.92 and 0.97 (designed). The design should find |theta| = 4 deg
everywhere and the two free lambdas.

Run:  python3 examples/03_spam_multishape.py [--out DIR]
Makes: multishape.h5, multishape.png, summary.json.
"""

import h5py
import numpy as np
from _common import PROBLEMS, arguments, vine_nlp, write_summary

args = arguments("03_spam_multishape", __doc__.splitlines()[0])
out = args.out
archive = out / "multishape.h5"

vine_nlp("design", PROBLEMS / "multishape-spam.toml", "-o", archive, "--plot", out / "multishape.png", "--force")

with h5py.File(archive, "r") as h5:
    run = h5["runs/multishape"]
    status = str(run.attrs["status"])
    metrics = dict(run["metrics"].attrs)
    theta = run["design/theta"][()]
    levels = run["design/levels"][()]

write_summary(
    out,
    {
        "status": status,
        "rmse_mm": float(metrics["rmse"]) * 10.0,
        "max_error_mm": float(metrics["max_error"]) * 10.0,
        "levels": [float(v) for v in levels],
        "abs_theta_deg_min": float(np.degrees(np.abs(theta)).min()),
        "abs_theta_deg_max": float(np.degrees(np.abs(theta)).max()),
        "files": ["multishape.h5", "multishape.png"],
    },
)
