"""As-built correction on the paper's trefoil (m = 4): simulated builds with known construction errors.

The trefoil is designed with design_nlp (problems/trefoil-m4.toml). Each seed draws per-segment
construction errors at sigma 1 deg / 0.02 / 2 % plus systematic parts (theta offset, lambda offset,
length scale); the robot built from a nominal realizes nominal + deviations (the contract's rule),
measured through the forward model: points along the outer line, Gaussian noise 0.5 mm per
coordinate, shuffled. Round 1 estimates and corrects; the corrected nominal is built with the SAME
deviations and measured again; round 2 uses both measurements. Errors are the RMSE of the built robot
to the target at the design's pairing (as the design's rmse), in mm.

Writes results/benchmarks/correct.md. Run: python benchmarks/bench_correct.py [--seeds 3] [--points 400]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from common import ROOT, table, write_report

from vine_nlp.design import correct as C
from vine_nlp.design.common import evaluate, pair_points
from vine_nlp.design.nlp import design_nlp
from vine_nlp.io.problem_file import load_problem
from vine_nlp.model.routing import Sigmas

SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)
SYSTEMATIC = (math.radians(0.5), 0.015, 1.01)  # theta offset, lambda offset, length scale
NOISE_MM = 0.5


def built_rmse(pb, pairing, nominal, dev):
    return evaluate(pb, C.apply_deviations(nominal, dev), pairing, "x").metrics["rmse"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--points", type=int, default=400)
    args = ap.parse_args()
    pb = load_problem(ROOT / "problems" / "trefoil-m4.toml").problem
    mm = 10.0  # cm -> mm
    noise = NOISE_MM / mm
    design = design_nlp(pb)
    nom = design.routing
    pairing = pair_points(pb.target, pb.options.points_per_segment)
    D = pb.diameter
    rows, rec_rows, times = [], [], []
    for seed in range(args.seeds):
        dev = C.draw_deviations(nom, SIGMAS, SYSTEMATIC, seed=seed)
        e0 = built_rmse(pb, pairing, nom, dev)
        m1 = C.Measurement(C.simulate_build(nom, dev, D, "outer", args.points, noise, seed=100 + seed), "outer", 0)
        for adjust in (("lambda",), ("lambda", "theta")):
            t = time.perf_counter()
            r1 = C.correct(pb, [nom], [m1], adjust=adjust, sigmas=SIGMAS)
            t1 = time.perf_counter() - t
            e1 = built_rmse(pb, pairing, r1.corrected.routing, dev)
            n1 = r1.corrected.routing
            m2 = C.Measurement(C.simulate_build(n1, dev, D, "outer", args.points, noise, seed=200 + seed), "outer", 1)
            t = time.perf_counter()
            r2 = C.correct(pb, [nom, n1], [m1, m2], adjust=adjust, sigmas=SIGMAS)
            t2 = time.perf_counter() - t
            e2 = built_rmse(pb, pairing, r2.corrected.routing, dev)
            times += [t1, t2]
            rows.append([seed, ",".join(adjust), f"{mm * e0:.2f}", f"{mm * r1.corrected.metrics['rmse']:.2f}", f"{mm * e1:.2f}",
                         f"{mm * e2:.2f}", f"{e0 / e1:.1f}x", f"{t1:.1f} ({r1.estimate.solve_time_s:.1f})",
                         f"{t2:.1f} ({r2.estimate.solve_time_s:.1f})"])
            if adjust == ("lambda",):
                e = r1.estimate
                truth = np.array(SYSTEMATIC)
                z = (e.systematic - truth) / e.systematic_std
                corr = [np.corrcoef(e.deviations.theta, dev.theta)[0, 1], np.corrcoef(e.deviations.lam, dev.lam)[0, 1],
                        np.corrcoef(e.deviations.length_ratio, dev.length_ratio)[0, 1]]
                rmse_th = math.degrees(float(np.sqrt(np.mean((e.deviations.theta - dev.theta) ** 2))))
                rmse_la = float(np.sqrt(np.mean((e.deviations.lam - dev.lam) ** 2)))
                rec_rows.append([
                    seed,
                    f"{math.degrees(e.systematic[0]):+.3f} +- {math.degrees(e.systematic_std[0]):.3f}",
                    f"{e.systematic[1]:+.4f} +- {e.systematic_std[1]:.4f}",
                    f"{e.systematic[2]:.4f} +- {e.systematic_std[2]:.4f}",
                    " / ".join(f"{v:+.1f}" for v in z),
                    " / ".join(f"{v:.2f}" for v in corr),
                    f"{rmse_th:.2f} deg / {rmse_la:.4f}",
                    f"{mm * r1.as_built.metrics['rmse']:.2f}", e.rounds, e.iterations,
                ])
            print(rows[-1], flush=True)
    desc = (
        f"Trefoil m = 4 (problems/trefoil-m4.toml, design_nlp: RMSE {mm * design.metrics['rmse']:.3f} mm, "
        f"{nom.segments} segments). Construction errors per segment at sigma 1 deg / 0.02 / 2 % plus systematic parts "
        f"theta offset {math.degrees(SYSTEMATIC[0]):g} deg, lambda offset {SYSTEMATIC[1]:g}, length scale {SYSTEMATIC[2]:g}; "
        f"{args.points} points measured along the outer line, noise {NOISE_MM} mm per coordinate, any order. "
        "Errors: RMSE of the built robot to the target at the design's pairing, in mm. Round 1: one measurement; "
        "round 2: the corrected nominal built with the same deviations and measured again, both measurements used. "
        "`predicted` is the corrected run's own metric (what the estimate expects the correction to realize). "
        "Times per correction (estimate + correction, warm caches after the first)."
    )
    t1 = table(["seed", "adjust", "uncorrected", "predicted", "after round 1", "after round 2", "gain round 1", "time 1 [s] (estimate)", "time 2 [s] (estimate)"], rows)
    t2 = table(["seed", "theta offset [deg]", "lambda offset", "length scale", "z (est - true) / std", "corr. theta / lambda / length",
                "RMSE of theta / lambda deviations (prior: 1 deg / 0.02)", "fit RMSE [mm]", "ICP rounds", "iterations"], rec_rows)
    note = (
        f"Median time per correction {np.median(times):.1f} s (max {max(times):.1f} s). With lambda alone (stopper positions) "
        "the error left is the part lambda cannot undo: theta and length deviations stay. Redrawing the line "
        "(--adjust lambda,theta) removes most of it. Per-segment length deviations are weakly observable on a smooth "
        "curve (a segment boundary is not visible): their estimate is the prior's (the shared scale), as the low "
        "correlation shows; theta and lambda deviations are recovered."
    )
    write_report("correct", "As-built correction (trefoil)", desc, "Built error, mm:", t1, "Recovery of the construction errors "
                 "(round 1, adjust lambda; true theta offset, lambda offset and scale above):", t2, note)


if __name__ == "__main__":
    main()
