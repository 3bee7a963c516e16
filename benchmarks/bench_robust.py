"""Robust design against construction errors, on the paper's trefoil (m = 4).

Nominal design (design_nlp) vs robust design (design_robust: nominal MSE + first-order
expected increase under the construction errors), both checked by Monte Carlo on the
same seeded samples of the true (nonlinear) chain. Also the self-clearance of both.

Writes results/benchmarks/robust.md and results/figures/robust-tolerance-{nominal,robust}.png.
Run: python benchmarks/bench_robust.py [--samples 2000] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

from common import FIGURES, ROOT, machine, table, write_section

from vine_nlp.analysis.collision import collision_metrics, growth_contacts
from vine_nlp.analysis.tolerance import Sigmas, tolerance_report
from vine_nlp.front.analysis_plots import tolerance_figure
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.methods.robust import design_robust
from vine_nlp.methods.transcription import clear_caches

SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)  # theta 1 deg, lambda 0.02, length 2 % (relative)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pb = load_problem(ROOT / "problems" / "trefoil-m4.toml").problem
    u = pb.units
    clear_caches()
    t0 = time.perf_counter()
    nom = design_nlp(pb)
    t_nom = time.perf_counter() - t0
    t0 = time.perf_counter()
    rob = design_robust(pb, SIGMAS, start=nom)
    t_rob = time.perf_counter() - t0
    t0 = time.perf_counter()
    half = design_robust(pb, SIGMAS, start=nom, weight=0.25)
    t_half = time.perf_counter() - t0
    rows, reports = [], {}
    designs = (("nominal (design_nlp)", nom, t_nom), ("robust (design_robust)", rob, t_rob),
               ("robust, weight 0.25", half, t_half))
    for name, r, t in designs:
        t1 = time.perf_counter()
        rep = tolerance_report(pb, r, SIGMAS, samples=args.samples, seed=args.seed)
        t_mc = time.perf_counter() - t1
        reports[name] = rep
        col = collision_metrics(r)
        fo, mc = rep["first_order"], rep["monte_carlo"]
        rows.append([
            name, r.status, f"{10 * r.metrics['rmse']:.3f}", f"{10 * fo['rmse']:.2f}", f"{10 * mc['mean_rmse']:.2f}",
            f"{10 * mc['rms_rmse']:.2f}", f"{10 * fo['tip_std']:.1f} / {10 * mc['tip_std']:.1f}",
            f"{col['min_clearance']:.2f}", f"{t:.2f}", f"{t_mc:.2f}",
        ])
        print(rows[-1], flush=True)
        if "weight" not in name:
            tolerance_figure(rep, FIGURES / f"robust-tolerance-{name.split()[0]}.png", title=f"trefoil m = 4, {name}")
    FIGURES.mkdir(parents=True, exist_ok=True)
    transient = [c for c in growth_contacts(nom.routing, pb.diameter) if c["transient"]]
    rel = 1 - reports["robust (design_robust)"]["monte_carlo"]["mean_rmse"] / reports["nominal (design_nlp)"]["monte_carlo"]["mean_rmse"]
    ps = reports["nominal (design_nlp)"]["per_segment"]
    text = [
        "## Robust design against construction errors (trefoil m = 4)",
        "",
        f"Machine: {machine()}",
        "",
        f"Errors: theta {SIGMAS.as_dict()['sigma_theta_deg']:.3g} deg, lambda {SIGMAS.lam:.3g} (absolute), "
        f"segment length {100 * SIGMAS.length:.3g} % (relative), independent per segment. "
        f"Monte Carlo: {args.samples} samples, seed {args.seed}, the same samples for both designs, "
        "on the numpy chain (nonlinear). First order: sqrt(MSE_0 + sum_k tr(J_k Sigma J_k^T) / N) "
        "from CasADi Jacobians. Errors in mm; tip std = sqrt(trace of the tip covariance), first order / MC. "
        f"`design` is the design time (robust: from the nominal design, including building its NLP), "
        f"`MC` the time of the tolerance report. Min clearance in {u} (D = {pb.diameter} {u}).",
        "",
        table(["design", "status", "nominal RMSE", "1st-order RMSE", "MC mean RMSE", "MC RMS RMSE", "tip std [mm]",
               f"min clearance [{u}]", "design [s]", "MC [s]"], rows),
        "",
        "`weight` scales the expected-increase term (design_robust(weight=...)): the trade-off between the "
        "nominal fit and the sensitivity.",
        "",
        f"The robust design lowers the Monte Carlo mean RMSE by {100 * rel:.0f} %, at the price of a nominal "
        f"RMSE of {10 * rob.metrics['rmse']:.2f} mm instead of {10 * nom.metrics['rmse']:.3f} mm: with these "
        "tolerances the construction errors, not the fit, set the error of a built robot (the paper measured "
        "6.88 mm RMSE on its built trefoil). Where errors matter most (nominal design): the segment at "
        f"{ps['l_mid'][ps['tip_var'].argmax()]:.0f} {u} of tube carries the largest share of the tip variance, "
        f"{100 * ps['tip_var'].max() / ps['tip_var'].sum():.0f} % of {len(ps['tip_var'])} segments' "
        "(results/figures/robust-tolerance-nominal.png).",
        "",
        f"Self-contact (analysis.collision): the nominal design's closest approach is "
        f"{collision_metrics(nom)['min_clearance']:.2f} {u} (no contact, so growing while actuated meets none); "
        f"actuated after full growth (lambda_t = 1 - t (1 - lambda)) it passes through {len(transient)} contact(s) on the way: "
        + "; ".join(f"from t = {c['actuation_fraction']:.2f} between {c['l_early']:.0f} and {c['l_late']:.0f} {u} of tube"
                    for c in transient)
        + " (the paper, Sec. VI-D: actuated after growth, the knot fails on two self-collisions; grown while "
        "actuated, it ties).",
    ]
    path = write_section("robust", "\n".join(text))
    print(path)


if __name__ == "__main__":
    main()
