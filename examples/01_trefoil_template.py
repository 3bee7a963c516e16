"""Tutorial 1: design the paper's trefoil knot and print its fabrication template.

The problem file ``problems/trefoil-m4.toml`` is the paper's Sec. VI-C case: a trefoil
with m_x = m_y = m_z = 4 cm, 400 target points, a tube of D = 2.43 cm and a
tendon-and-stopper actuator. The paper's greedy fit reached 0.22 mm RMSE in 138 s.

Run:  python3 examples/01_trefoil_template.py [--out DIR]
Makes: trefoil-m4.h5 (archive), trefoil-m4.png (figure), template.pdf (1:1 template),
cuts.csv (one row per segment), template.svg (one sheet, mm), summary.json.
"""

import csv

import h5py
import numpy as np
from _common import PROBLEMS, arguments, vine_nlp, write_summary

args = arguments("01_trefoil_template", __doc__.splitlines()[0])
out = args.out
archive = out / "trefoil-m4.h5"

# Design: one NLP over all 40 segments (n = 10 points per segment).
vine_nlp("design", PROBLEMS / "trefoil-m4.toml", "-o", archive, "--plot", out / "trefoil-m4.png", "--force")
# Template: print at 100 % and check the 10 cm scale bar before cutting.
vine_nlp("template", archive, "-o", out / "template.pdf", "--csv", out / "cuts.csv", "--force")
# The same template as one SVG sheet in millimetres (for a laser or vinyl cutter, or a web page).
vine_nlp("template", archive, "-o", out / "template.svg", "--force")

with h5py.File(archive, "r") as h5:
    run = h5["runs/nlp"]
    metrics = dict(run["metrics"].attrs)
    lengths = run["design/length"][()]
    theta_deg = np.degrees(run["design/theta"][()])
    lam = run["design/lambda"][()]
    status = run.attrs["status"]
    units = h5.attrs["units"]
print(f"routing: {len(lengths)} segments of {lengths.mean():.2f} cm; theta {theta_deg.min():.1f} to {theta_deg.max():.1f} deg, "
      f"lambda {lam.min():.2f} to {lam.max():.2f}")
with open(out / "cuts.csv", newline="") as f:
    cuts = list(csv.DictReader(f))

write_summary(
    out,
    {
        "status": str(status),
        "units": str(units),
        "rmse_mm": float(metrics["rmse"]) * 10.0,  # cm -> mm
        "max_error_mm": float(metrics["max_error"]) * 10.0,
        "segments": int(len(lengths)),
        "tube_length_cm": float(lengths.sum()),
        "theta_deg_range": [float(theta_deg.min()), float(theta_deg.max())],
        "cut_rows": len(cuts),
        "cut_length_cm": float(cuts[-1]["s_end"]),
        "files": ["trefoil-m4.h5", "trefoil-m4.png", "template.pdf", "template.svg", "cuts.csv"],
    },
)
