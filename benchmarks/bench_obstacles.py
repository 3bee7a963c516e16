"""Design among obstacles (issue 15) on every bundled obstacle problem.

Per problem: the obstacle-free design (design_nlp, or design_tip for tip problems) and the design
among the obstacles (design_with_obstacles / design_tip_with_obstacles, started from it). Goals:
Clearance: the smallest gap to every obstacle >= margin - 1e-3 D, checked at 20 points per
segment with exact distances (trimesh for meshes), final shape and, for growth "after", every
intermediate shape of the grid t = 0, 0.05, ..., 1. Accuracy: away from the obstacles (target
points whose gap to every obstacle is > AWAY D), the RMSE to the target within 10 % of the
obstacle-free design's.

Writes results/benchmarks/obstacles.md. Run: python benchmarks/bench_obstacles.py [--only NAME ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import ROOT, table, write_report

from vine_nlp.analysis.obstacles import after_growth_shapes, min_gap, sample_chain
from vine_nlp.design.nlp import design_nlp
from vine_nlp.design.obstacles import design_tip_with_obstacles, design_with_obstacles
from vine_nlp.design.tip import design_tip
from vine_nlp.io.problem_file import load_problem

NAMES = ["obstacle-gap", "obstacle-pipe-bend", "obstacle-wrap-cylinder", "obstacle-mesh", "obstacle-tip-wall"]
AWAY = (2.0, 4.0)  # target points farther than this many D from every obstacle (gap) count as "away"


def checked_gap(routing, D, obstacles, growth) -> float:
    """Smallest gap at 20 points per segment, exact distances; growth "after": every shape of the grid."""
    shapes = [sample_chain(routing, D, 20)["points"]]
    if growth == "after":
        shapes += [s["points"] for s in after_growth_shapes(routing, D, per_segment=20)]
    return float(min(min_gap(p, D, obstacles).min() for p in shapes))


def away_rmse(result, target, mask) -> float:
    return float(np.sqrt(np.mean(np.sum((result.shape.center[mask] - target[mask]) ** 2, axis=1))))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", nargs="*", default=NAMES)
    args = ap.parse_args()
    rows, notes = [], []
    for name in args.only:
        pf = load_problem(ROOT / "problems" / f"{name}.toml")
        pb, u = pf.problem, pf.units
        D, m = pb.diameter, pb.obstacle_margin
        t0 = time.perf_counter()
        free = design_tip(pb) if pf.kind == "tip" else design_nlp(pb)
        t_free = time.perf_counter() - t0
        t0 = time.perf_counter()
        if pf.kind == "tip":
            r = design_tip_with_obstacles(pb)
        else:
            r = design_with_obstacles(pb, start=free)
        t_obs = time.perf_counter() - t0
        g0 = checked_gap(free.routing, D, pb.obstacles, pb.growth)
        g = checked_gap(r.routing, D, pb.obstacles, pb.growth)
        ok_gap = g >= m - 1e-3 * D
        if pf.kind == "tip":
            acc = f"tip error {r.metrics['tip_error']:.2e} {u}"
            rms = ["-", "-", "-"]
        else:
            tg = pb.target
            far = min_gap(tg, D, pb.obstacles).min(axis=1)
            rms = []
            for a in AWAY:
                mask = far > a * D
                if not mask.any():
                    rms.append("no such points")
                    continue
                e0, e1 = away_rmse(free, tg, mask), away_rmse(r, tg, mask)
                rms.append(f"{e0:.3g} / {e1:.3g} ({mask.sum()} pts)")
            mask = far > AWAY[0] * D
            if mask.any():
                e0, e1 = away_rmse(free, tg, mask), away_rmse(r, tg, mask)
                acc = "yes" if e1 <= 1.1 * e0 else f"no ({e1 / max(e0, 1e-300):.3g}x; {e1 / D:.2g} D)"
            else:
                acc = "n/a (no target point away)"
            rms.append(f"{free.metrics['rmse']:.3g} / {r.metrics['rmse']:.3g}")
        rows.append([name, pb.growth, r.status, r.stats.get("obstacle_rounds", "-"), f"{g0:.3g}", f"{g:.4g}", f"{m:g}",
                     "yes" if ok_gap else "NO", *rms, acc, f"{t_free:.1f}", f"{t_obs:.1f}"])
        print(rows[-1], flush=True)
        if pf.kind != "tip":
            notes.append(f"- {name}: samples per segment {r.stats.get('obstacle_samples_per_segment')}, "
                         f"rows' extra requirement {r.stats.get('obstacle_raise', 0):.3g} {u}"
                         + (f", intermediate shapes with rows t = {[round(t, 3) for t in r.stats.get('obstacle_after_t', [])]}"
                            if pb.growth == "after" else ""))
    header = ["problem", "growth", "status", "rounds", "gap free", "gap", "margin", "clearance goal",
              f"RMSE away > {AWAY[0]:g} D free / obstacles", f"RMSE away > {AWAY[1]:g} D free / obstacles", "RMSE all free / obstacles",
              "accuracy goal (10 %)", "time free s", "time obstacles s"]
    write_report(
        "obstacles", "Obstacles",
        "Bundled obstacle problems (problems/obstacle-*.toml). Gaps in the problem's units (cm), tube surface to "
        "the nearest obstacle, checked at 20 points per segment with exact distances (meshes: trimesh) and, for "
        "growth \"after\", on every intermediate shape t = 0, 0.05, ..., 1. \"gap free\": the obstacle-free "
        "design's. RMSE away: over target points whose gap to every obstacle exceeds the given number of D. "
        "Time of the obstacle design excludes the obstacle-free start.",
        table(header, rows), "\n".join(notes),
        "The obstacle-free designs follow these targets to about 1e-4 cm, so the accuracy goal read literally "
        "(within 10 % of that) asks for sub-micron errors away from the obstacles; the table gives the RMSE "
        "away from the obstacles in absolute terms too (the least-squares fit spreads the detour around an "
        "obstacle over its neighbourhood).",
    )


if __name__ == "__main__":
    main()
