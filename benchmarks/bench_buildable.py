"""Buildable designs (issue 31): the design a user gets (``vine_nlp.solve(problem file)``, the nlp run, buildable by
default) against today's (``methods.nlp.design_nlp``, what that run was before), in one run, on every bundled paper
problem and the hook.

Measured per problem: RMSE (the goal: at most 10 % or 0.05 mm worse), the actuator line's turning on segments with
lambda = 1 against what the routing needs there (today's design: on the same segments; goal: -80 % or within 30 deg
of the need), margin violations, features below min_feature (analysis.buildability, what ``show`` reports), base
rotation, solves and time. Then: RMSE against the margin (Bezier (a)-(c)); physical builds (1 deg / 0.02 / 2 % per
segment plus a lambda offset 0.02; no lambda error where lambda is 1, built lambda never above 1) corrected in lambda
only with the TRUE deviations (an oracle: the ceiling of any estimate), today's design against the buildable one;
and the Monte Carlo tolerance of the hook (RMS of the RMSE, 1 deg / 0.02 / 2 %) as ``analyze`` computes it today
(lambda error everywhere) and by the physical rule.

Speed first (issue 46): the free design alone against the buildable one as the pipeline makes it, their ratio,
rounds, iterations and both RMSEs (``--speed``: that table alone, printed).

Writes results/benchmarks/buildable.md. Run: python benchmarks/bench_buildable.py [--seeds 20] [--repeats 3] [--quick] [--speed]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import time

import numpy as np
from common import ROOT, table, write_report

import vine_nlp as vn
from vine_nlp.analysis.buildability import MM_PER_UNIT, buildability, turning
from vine_nlp.analysis.tolerance import batch_points, tolerance_report
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import buildable as B
from vine_nlp.methods import settings
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.correct.correction import correction_spec
from vine_nlp.methods.nlp import design_nlp, nlp_parameters
from vine_nlp.methods.structure import frames12
from vine_nlp.methods.transcription import get_solver
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Routing, Sigmas

CASES = ("trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "polyline-d", "spam-helix", "hook")
SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)
LAMBDA_OFFSET = 0.02
MARGINS = ((0.0, 0.0), (0.0, None), (0.02, None), (0.03, None), (0.05, 0.0), (0.05, None), (0.08, None))  # (margin, min_feature)


def rotation_deg(r: Routing) -> float:
    """The base pose's rotation angle, deg (the targets start along +x: 0 is no roll)."""
    return math.degrees(math.acos(np.clip((np.trace(r.initial_pose[:3, :3]) - 1) / 2, -1, 1)))


def figures(pb, build, routing, act):
    """Turning (total, on unactuated, needed; deg), margin violations, features below min_feature, smallest feature."""
    tot, free, need = turning(routing.theta, routing.length, pb.diameter, act)
    rep = buildability(routing, pb.diameter, build.kind, build.lambda_min, build.margin, build.min_feature)
    return {"turn": math.degrees(tot), "free": math.degrees(free), "need": math.degrees(need), "viol": len(rep.violations),
            "below": len(rep.below), "smallest": rep.smallest, "refused": rep.refused}


# ---------------------------------------------------------------- physical builds (issue 32's rule)


def built(nominal: Routing, dev, lambda_min: float) -> Routing:
    """What a robot with deviations ``dev`` realizes: no lambda error where lambda is 1 (no actuator), else within [lambda_min, 1]."""
    lam = np.where(nominal.lam != 1.0, np.clip(nominal.lam + dev[:, 1], lambda_min, 1.0), 1.0)
    return Routing(theta=nominal.theta + dev[:, 0], lam=lam, length=nominal.length * (1 + dev[:, 2]), initial_pose=nominal.initial_pose)


def correct_oracle(pb, pairing, nominal: Routing, dev) -> Routing:
    """Lambda-only correction with the true deviations: the realized lambda of an actuated segment within [max(lmin, lmin + e),
    min(1, 1 + e)] (what a nominal in [lmin, 1] builds), 1 without an actuator; the nominal to build next."""
    o, a, D = pb.options, pb.actuator, pb.diameter
    act = nominal.lam != 1.0
    ab = built(nominal, dev, a.lambda_min)
    solver = get_solver(correction_spec(pairing.segments, pairing.n, False, o.max_iter, o.tol, "exact"))
    lo = np.where(act, np.maximum(a.lambda_min, a.lambda_min + dev[:, 1]), 1.0)
    hi = np.where(act, np.minimum(1.0, 1.0 + dev[:, 1]), 1.0)
    f12 = frames12(chain_frames(ab.theta, ab.lam, ab.length, D, ab.initial_pose), D)
    lbx, ubx = solver.bounds(X0=f12[:, 0][None], theta=(ab.theta, ab.theta), lam=(lo, hi), length=(ab.length / D, ab.length / D))
    p = solver.pack_params(nlp_parameters(pb, pairing, ab.initial_pose[:3, :3]))
    x, _, _ = solver.solve(solver.pack_x(f12[None], theta=ab.theta, lam=np.clip(ab.lam, lo, hi), length=ab.length / D), p, lbx, ubx)
    lam = solver.unpack(x)["lam"][:, 0]
    return Routing(theta=nominal.theta, lam=np.where(act, lam - dev[:, 1], 1.0), length=nominal.length, initial_pose=nominal.initial_pose)


def correction(pb, design: Routing, seeds: int):
    """Median RMSE of physical builds of ``design``, and of the builds of its oracle correction (one round: the oracle
    predicts the build exactly, a second round changes nothing)."""
    pairing = pair_points(pb.target, pb.options.points_per_segment)
    out = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        sig = SIGMAS.per_segment(design.length) / np.c_[np.ones(design.segments), np.ones(design.segments), design.length]
        dev = rng.standard_normal((design.segments, 3)) * sig + [0.0, LAMBDA_OFFSET, 0.0]
        e0 = evaluate(pb, built(design, dev, pb.actuator.lambda_min), pairing, "x").metrics["rmse"]
        n1 = correct_oracle(pb, pairing, design, dev)
        out.append((e0, evaluate(pb, built(n1, dev, pb.actuator.lambda_min), pairing, "x").metrics["rmse"]))
    return np.median(np.array(out), axis=0)


def mc(pb, routing: Routing, physical: bool, samples=2000, seed=0) -> float:
    """RMS of the RMSE over Monte Carlo builds: ``analyze``'s (tolerance_report) or by the physical rule."""
    if not physical:
        return tolerance_report(pb, dataclasses.replace(evaluate(pb, routing, pair_points(pb.target, pb.options.points_per_segment), "x")),
                                SIGMAS, samples=samples, seed=seed)["monte_carlo"]["rms_rmse"]
    pairing = pair_points(pb.target, pb.options.points_per_segment)
    dq = np.random.default_rng(seed).standard_normal((samples, routing.segments, 3)) * SIGMAS.per_segment(routing.length)
    lam = np.where(routing.lam == 1.0, 1.0, np.clip(routing.lam + dq[..., 1], pb.actuator.lambda_min, 1.0))
    P = batch_points(routing.theta + dq[..., 0], lam, routing.length + dq[..., 2], pb.diameter, pairing.seg, pairing.frac, routing.initial_pose)
    return float(math.sqrt(np.mean(np.sum((P - pb.target) ** 2, axis=2))))


BY_HAND = "<!-- measured by hand below: kept when this script rewrites the file -->"
SPEED = ("trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "hook", "polyline-d")


def speed(names, repeats: int):
    """Per problem: the free design (design_nlp) alone against the buildable one as the pipeline makes it
    (``B.first_design``: one solve inside the band where it gives one, else the free design; then design_buildable), alternating
    ``repeats`` times after one unmeasured run each (compiled code cached): median times, their ratio, the buildable
    design's rounds, solves and IPOPT iterations, and both RMSEs."""
    rows = []
    for name in names:
        pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
        mm, tf, tb = MM_PER_UNIT[pb.units], [], []
        B.design_buildable(pb, B.first_design(pb))
        for _ in range(repeats):
            t0 = time.perf_counter()
            free = design_nlp(pb)
            t1 = time.perf_counter()
            start = B.first_design(pb)
            b = B.design_buildable(pb, start)
            t2 = time.perf_counter()
            tf.append(t1 - t0)
            tb.append(t2 - t1)
        f, m = float(np.median(tf)), float(np.median(tb))
        extra = b.stats["ipopt_iterations"] - start.iterations
        rows.append([name, f"{f:.3f}", f"{m:.3f}", f"{m / f:.2f}", b.stats["buildable_rounds"], f"{start.iterations} + {extra}",
                     f"{mm * free.metrics['rmse']:.3f}", f"{mm * b.metrics['rmse']:.3f}", f"{mm * b.stats['buildable_budget']:.3f}",
                     f"{b.stats['buildable_actuated']} of {b.routing.segments}", b.status])
        print(rows[-1], flush=True)
    return table(["problem", "free s", "free + buildable s", "ratio", "rounds", "iterations free + buildable", "RMSE free mm",
                  "RMSE buildable mm", "budget mm", "actuated", "status"], rows)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20, help="simulated builds per design (correction)")
    ap.add_argument("--quick", action="store_true", help="trefoil-m4, bezier-b and the hook, 3 seeds (a smoke run)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per problem (speed table; medians)")
    ap.add_argument("--speed", action="store_true", help="print the speed table only (nothing written)")
    args = ap.parse_args()
    if args.speed:
        print(speed(SPEED, args.repeats))
        return
    cases = ("trefoil-m4", "bezier-b", "hook") if args.quick else CASES
    seeds = 3 if args.quick else args.seeds
    load0, t_start = os.getloadavg()[0], time.perf_counter()
    speed_table = speed(("trefoil-m4", "bezier-b", "hook") if args.quick else SPEED, 1 if args.quick else args.repeats)
    rows, designs = [], {}
    for name in cases:
        path = ROOT / "problems" / f"{name}.toml"
        pb = load_problem(path).problem
        mm, build = MM_PER_UNIT[pb.units], B.Build.of(pb)
        t0 = time.perf_counter()
        today = design_nlp(pb)
        t1 = time.perf_counter()
        new = vn.solve(path).result  # the nlp run a user gets: the free design, then the buildable one
        t2 = time.perf_counter()
        designs[name] = (pb, today, new)
        act = new.routing.lam != 1.0
        f0, f1 = figures(pb, build, today.routing, act), figures(pb, build, new.routing, act)
        r0, r1 = mm * today.metrics["rmse"], mm * new.metrics["rmse"]
        budget = mm * B.accuracy_budget(pb, today.metrics["rmse"])
        ok_turn = f1["free"] <= 0.2 * f0["free"] + 1e-9 or f1["free"] <= f1["need"] + 30.0
        ok = [r1 <= budget + 1e-9, ok_turn, f1["viol"] == 0, f1["below"] == 0]
        sm = f1["smallest"]
        rows.append([name, f"{r0:.3f}", f"{r1:.3f} / {budget:.3f}", f"{f0['free']:.0f} -> {f1['free']:.0f} / {f1['need']:.0f}",
                     f"{f0['turn']:.0f} / {f1['turn']:.0f}", f"{f0['viol']} / {f1['viol']}", f"{f0['below']} / {f1['below']}",
                     f"{int((~act).sum())} of {act.size}", f"{mm * sm[0]:.1f} mm {sm[1]}" if sm else "-",
                     f"{rotation_deg(today.routing):.1f} / {rotation_deg(new.routing):.1f}", new.stats.get("solves"),
                     f"{t1 - t0:.2f} / {t2 - t1:.2f}", new.status, " ".join("yes" if g else "NO" for g in ok)])
        print(rows[-1], f1["refused"], flush=True)

    mrows = []
    for name in [c for c in ("bezier-a", "bezier-b", "bezier-c") if c in designs]:
        pb, today, _ = designs[name]
        mm = MM_PER_UNIT[pb.units]
        row = [name, f"{mm * today.metrics['rmse']:.3f}"]
        for m, mf in MARGINS:
            p2 = dataclasses.replace(pb, options=dataclasses.replace(pb.options, correction_margin=m, min_feature=mf))
            r = B.design_buildable(p2, today)
            row.append(f"{mm * r.metrics['rmse']:.3f} ({int((r.routing.lam == 1.0).sum())})")
        mrows.append(row)
        print(mrows[-1], flush=True)

    crows = []
    for name in [c for c in ("trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "hook") if c in designs]:
        pb, today, new = designs[name]
        mm = MM_PER_UNIT[pb.units]
        for label, res in (("today's", today), ("buildable", new)):
            e0, e1 = correction(pb, res.routing, seeds)
            crows.append([name, label, f"{mm * res.metrics['rmse']:.3f}", f"{mm * e0:.2f}", f"{mm * e1:.2f}", f"{e0 / e1:.1f}x"])
            print(crows[-1], flush=True)

    trows = []
    if "hook" in designs:
        pb, today, new = designs["hook"]
        mm = MM_PER_UNIT[pb.units]
        a = [mm * mc(pb, r.routing, phys) for r in (today, new) for phys in (False, True)]
        trows = [["analyze today (lambda error everywhere, as drawn)", f"{a[0]:.2f}", f"{a[2]:.2f}", f"{a[0] / a[2]:.1f}x"],
                 ["physical rule (no lambda error where lambda = 1)", f"{a[1]:.2f}", f"{a[3]:.2f}", f"{a[1] / a[3]:.1f}x"],
                 ["today's design by analyze today, buildable by the physical rule", f"{a[0]:.2f}", f"{a[3]:.2f}", f"{a[0] / a[3]:.1f}x"]]
        print(trows, flush=True)
    elapsed = time.perf_counter() - t_start
    desc = (f"benchmarks/bench_buildable.py: today's design (design_nlp, defaults) against the buildable one (vine_nlp.solve, "
            f"defaults: margin {B.Build.of(designs[cases[0]][0]).margin:g}, min_feature 2 mm, effort weights {settings.EFFORT:g} / "
            f"{settings.EFFORT_ACTUATED:g}); {seeds} simulated builds per design; load average {load0:.2f} at the start, "
            f"{os.getloadavg()[0]:.2f} at the end; {elapsed / 60:.1f} min in all.")
    blocks = [
        f"Speed (issue 46: the buildable design at most 1.3x the free design's time): the free design alone against the buildable "
        "one as the pipeline makes it (where the target's bends actuate every segment, trefoil-m4: one solve inside the band, "
        "no free design; else the free design followed by the rounds), medians of "
        f"{1 if args.quick else args.repeats} alternating runs after one unmeasured run each; iterations: the first solve's + "
        "the buildable rounds'; the machine was shared: compare ratios, not seconds.",
        speed_table,
        "Goals per problem (issue 31): RMSE within budget (10 % or 0.05 mm over today's); turning of the line on the segments "
        "with lambda = 1 (today's design: on the same segments) down 80 % or within 30 deg of what the routing needs; no margin "
        "violation; no feature below min_feature. Times: today's design / the whole buildable run (its free design included).",
        table(["problem", "RMSE today mm", "RMSE buildable / budget mm", "turning on lambda = 1: today -> buildable / needed deg",
               "total turning today / buildable deg", "violations today / buildable", "below min_feature today / buildable",
               "no actuator", "smallest feature", "base rotation today / buildable deg", "solves", "time s", "status",
               "goals met (RMSE, turning, margin, features)"], rows),
        "RMSE (mm) of the buildable design against the margin and min_feature (in brackets: segments without an actuator); "
        "from today's design, the same run:",
        table(["problem", "today"] + [f"margin {m:g}, min_feature {'2 mm' if mf is None else mf}" for m, mf in MARGINS], mrows),
        "Built and corrected (median over the builds, RMSE mm at the design's pairing): physical builds, then lambda-only "
        "correction with the true deviations (bounds on what is built), one round:",
        table(["problem", "design", "designed", "built", "built after correction", "gain"], crows),
        "Monte Carlo tolerance of the hook (RMS of the RMSE, 2000 builds, 1 deg / 0.02 / 2 %), mm:",
        table(["rule", "today's design", "buildable design", "ratio"], trows),
    ]
    kept = (ROOT / "results" / "benchmarks" / "buildable.md").read_text().partition(BY_HAND)  # measured by hand (the sweep, compare): kept
    print(write_report("buildable", "Buildable designs (issue 31)", desc, *blocks, *([BY_HAND + kept[2]] if kept[1] else [])))


if __name__ == "__main__":
    main()
