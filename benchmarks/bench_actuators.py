"""Several actuators on one tube (issue 44): the design of one tube for several states against single-actuator
designs of the same targets, in one run.

1. Reachable targets: made by the model from known several-actuator routings (40 segments, 10 points per segment):
   a base/tip pair, states {A}, {B}, {A, B}; a tube that reaches left, right or up. Goal: every state within
   0.1 mm RMS; the three states designed in at most 2x the time of the three single-actuator designs
   (``vine_nlp.design`` of each target alone, the design a user gets).
2. The paper's Bezier (a) and its mirror image (y -> -y) as two states {A}, {B} of one tube. Goal: each state
   within 2x its own single-actuator design's RMSE, or within 0.5 mm.

Writes results/benchmarks/actuators.md. Run: python benchmarks/bench_actuators.py
"""

from __future__ import annotations

import time

import numpy as np
from common import table, write_report

import vine_nlp as vn
from vine_nlp import targets
from vine_nlp.methods.actuators import ActuatorsProblem, Line, sample_states
from vine_nlp.methods.actuators_design import design_actuators
from vine_nlp.model.actuators import Lines
from vine_nlp.problem import DesignOptions

D, M, N_PER = 2.43, 40, 10


def base_tip() -> tuple:
    s = np.arange(M) / M
    th = np.array([0.15 * np.sin(3 * s), -0.1 + 0.05 * s])
    lam = np.ones((2, M))
    lam[0, :18] = 0.75 - 0.1 * np.sin(np.pi * s[:18] / 0.45)
    lam[1, 22:] = 0.7 + 0.1 * s[22:]
    return Lines(("A", "B"), th, lam, [0.0, 2.2], np.full(M, 1.5)), {"A": ("A",), "B": ("B",), "AB": ("A", "B")}


def three_ways() -> tuple:
    s = np.arange(M) / M
    lam = np.ones((3, M))
    lam[:, 15:] = [[0.8], [0.85], [0.75]]
    th = np.array([0.05 * s, -0.05 * s, 0.08 * np.ones(M)])
    lines = Lines(("left", "right", "up"), th, lam, [0.0, np.pi, np.pi / 2], np.full(M, 1.5))
    return lines, {"left": ("left",), "right": ("right",), "up": ("up",)}


def compare(name, tgts: dict, states: dict, widths=0.3):
    names = tuple(dict.fromkeys(a for act in states.values() for a in act))
    p = ActuatorsProblem(name, D, tuple(Line(n, width=widths) for n in names), states, targets=tgts,
                         options=DesignOptions(points_per_segment=N_PER))
    t = time.perf_counter()
    r = design_actuators(p)
    t_multi = time.perf_counter() - t
    singles, t_single = {}, 0.0
    for s, pts in tgts.items():
        t = time.perf_counter()
        singles[s] = vn.design(pts, diameter=D, points_per_segment=N_PER)
        t_single += time.perf_counter() - t
    rows = [[s, ", ".join(states[s]), f"{10 * r.state_metrics[s]['rmse']:.4f}", f"{10 * singles[s].rmse:.4f}"] for s in tgts]
    return r, singles, t_multi, t_single, rows


def main():
    blocks, summary = [], []
    for name, make in (("base/tip pair", base_tip), ("left/right/up", three_ways)):
        truth, states = make()
        r, singles, tm, ts, rows = compare(name, sample_states(truth, D, states, M * N_PER + 1), states)
        worst = max(m["rmse"] for m in r.state_metrics.values()) * 10
        blocks.append(f"### {name}: targets made by the model ({M} segments, {N_PER} points per segment)\n\n"
                      + table(["state", "active", "RMSE [mm], one tube", "RMSE [mm], single design"], rows)
                      + f"\n\nOne tube: {r.status}, {r.iterations} iterations, {r.stats['rounds']} solves, shortfall: "
                      + (("; ".join(r.shortfall)) or "none") + f". Time: one tube {tm:.1f} s; the single designs {ts:.1f} s in all"
                      + f" (ratio {tm / ts:.2f}; goal <= 2). Worst state {worst:.4f} mm (goal < 0.1 mm).")
        summary.append([name, f"{worst:.4f} mm", f"{tm / ts:.2f}", "yes" if worst < 0.1 and tm <= 2 * ts else "no"])
    a = targets.bezier([[0, 0, 0], [76, 0, 0], [-4, 19, 42], [34, -52, 13], [16, 19, 48]])
    mirror = a * np.array([1.0, -1.0, 1.0])
    r, singles, tm, ts, rows = compare("bezier-a and mirror", {"A": a, "mirror": mirror}, {"A": ("A",), "mirror": ("B",)})
    ok = all(r.state_metrics[s]["rmse"] <= max(2 * singles[s].rmse, 0.05) for s in ("A", "mirror"))
    blocks.append("### The paper's Bezier (a) and its mirror image, two states of one tube\n\n"
                  + table(["state", "active", "RMSE [mm], one tube", "RMSE [mm], single design"], rows)
                  + f"\n\nOne tube: {r.status}, {r.iterations} iterations, {tm:.1f} s; the single designs {ts:.1f} s. "
                  + f"Goal (each state within 2x its single design's RMSE or 0.5 mm): {'met' if ok else 'NOT met'}.")
    summary.append(["bezier-a + mirror", "-", f"{tm / ts:.2f}", "yes" if ok else "no"])
    write_report("actuators", "Several actuators on one tube (issue 44)",
                 "Every design in this run; times are wall-clock on a machine shared with other work (ratios measured "
                 "in the same run). Single designs: `vine_nlp.design` of each state's target alone (buildable, as a user "
                 "gets it). The one-tube RMSE pairs each target point with the model by the design's own pairing (where "
                 "each segment's ends fall on the target is designed too); a single design pairs by equal chord per "
                 "segment: the two RMSEs are not measured with the same pairing.", table(["case", "worst state RMSE", "time ratio (one tube / singles)", "goals met"], summary), *blocks)


if __name__ == "__main__":
    main()
