"""Tutorial 4: fit the model to a measured prototype.

``problems/fit-active-helix.toml`` is the paper's active sPAM helix (Sec. V-A): a known
routing (theta = 4 deg, D = 3.23 cm, 60 cm of tube) and 15 markers measured on its outer
line, in any order and any pose. The markers are synthetic (``problems/data/make_synthetic.py``:
the model's shape at lambda = 0.91, a random pose, 1.4 mm of noise), standing in for the
paper's unpublished tracker data. The fit finds the pose and lambda.

Run:  python3 examples/04_fit_prototype.py [--out DIR]
Makes: fit.h5, fit.png, summary.json.
"""

import h5py
from _common import PROBLEMS, arguments, vine_nlp, write_summary

args = arguments("04_fit_prototype", __doc__.splitlines()[0])
out = args.out
archive = out / "fit.h5"

vine_nlp("fit", PROBLEMS / "fit-active-helix.toml", "-o", archive, "--plot", out / "fit.png", "--force")

with h5py.File(archive, "r") as h5:
    run = h5["runs/fit"]
    status = str(run.attrs["status"])
    metrics = dict(run["metrics"].attrs)
    lam = run["design/lambda"][()]
    measured = h5["measured/points"][()]

write_summary(
    out,
    {
        "status": status,
        "markers": int(len(measured)),
        "lambda": float(lam.mean()),
        "lambda_true": 0.91,
        "rmse_mm": float(metrics["rmse"]) * 10.0,
        "r2": float(metrics["r2"]),
        "files": ["fit.h5", "fit.png"],
    },
)
