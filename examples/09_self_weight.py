"""Tutorial 9: will it stand? A horizontal reach with a payload under its own weight.

``problems/load-reach.toml``: a 1.5 m reach rising to a shelf, 8 cm tube, 30 g/m, 50 g at the tip, safety
factor 1.5, at 8 kPa. The design on the target would need a little more; the design with [load] keeps every
section's bending moment below its capacity / 1.5 and stands a few millimetres off the target. At half the
pressure no design near the target stands: the design on the target is kept, judged to fold (exit 1, one
line: where it folds and the pressure it needs), and the one that stands is kept beside it (run nlp_load).

Run:  python3 examples/09_self_weight.py [--out DIR]
Makes: reach.h5, reach-load.png, half.toml, half.h5, half-load.png, summary.json.
"""

import h5py
from _common import PROBLEMS, arguments, vine_nlp, write_summary

args = arguments("09_self_weight", __doc__.splitlines()[0])
out = args.out
problem = PROBLEMS / "load-reach.toml"

vine_nlp("design", problem, "-o", out / "reach.h5", "--force")
vine_nlp("analyze", out / "reach.h5", "--samples", "20", "--load-figure", out / "reach-load.png")

half = out / "half.toml"
half.write_text(problem.read_text().replace("pressure = 8.0", "pressure = 4.0"))
vine_nlp("design", half, "-o", out / "half.h5", "--force", ok=(1,))  # exit 1: it folds
vine_nlp("analyze", out / "half.h5", "--samples", "20", "--load-figure", out / "half-load.png")


def runs(path):
    with h5py.File(path, "r") as h5:
        return {name: (dict(g["metrics"].attrs), dict(g["solver"].attrs)) for name, g in h5["runs"].items()}


(m, st), = runs(out / "reach.h5").values()
half_runs = runs(out / "half.h5")
folds, stands = half_runs["nlp"][0], half_runs["nlp_load"][0]
print(f"at 8 kPa: on the target it would need {8.0 * 1.5 / st['start_load_margin']:.2f} kPa; the design stands "
      f"(margin {m['load_margin']:.3f}) at RMSE {10 * m['rmse']:.2f} mm, {10 * st['start_rmse']:.2f} mm on the target")
print(f"at 4 kPa: the design on the target folds at s = {folds['collapse_at']:g} cm and needs {folds['min_pressure']:.2f} kPa; "
      f"the one that stands is {stands['rmse']:.1f} cm RMSE off the target")

write_summary(out, {
    "need_on_target_kpa": 8.0 * 1.5 / float(st["start_load_margin"]),
    "load_margin": float(m["load_margin"]),
    "rmse_mm": 10.0 * float(m["rmse"]),
    "half_min_pressure_kpa": float(folds["min_pressure"]),
    "half_load_margin": float(folds["load_margin"]),
    "half_standing_rmse_cm": float(stands["rmse"]),
    "files": ["reach.h5", "reach-load.png", "half.toml", "half.h5", "half-load.png"],
})
