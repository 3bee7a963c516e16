"""One transcription for every formulation: time per IPOPT iteration of each, against the plain NLP's.

Same target and structure for each pair, measured in the same run, solvers built before
timing (the build is reported apart), IPOPT's own iteration count:

- nlp (trefoil m = 4, 40 segments x 10 points; tendon and sPAM), exact and Gauss-Newton Hessian;
- multishape with K = 1 (the trefoil, sPAM) against the plain sPAM NLP;
- clearance (a helix whose turns are closer than D) against the plain NLP on the same helix;
- robust (trefoil and Bezier (b), sigmas 1 deg, 0.02, 2 %) against the plain NLP;
- tip (the trefoil's tip position and direction, 40 segments) against the plain NLP with 40 segments.

Also: command start to archive for trefoil, multishape-spam and tip-target (whole processes).
Writes results/benchmarks/transcription.md. Run: python benchmarks/bench_transcription.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import ROOT, table, write_report

from vine_nlp import targets
from vine_nlp.design.clearance import design_with_clearance
from vine_nlp.design.multishape import design_multishape
from vine_nlp.design.nlp import design_nlp
from vine_nlp.design.problem import Actuator, DesignProblem, MultiShapeProblem, TipProblem
from vine_nlp.design.robust import design_robust
from vine_nlp.design.tip import design_tip
from vine_nlp.io.problem_file import load_problem
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Sigmas

SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)


def per_iteration(run, repeat):
    """(median ms per IPOPT iteration, iterations, result): the solvers built by a first call, then ``repeat``
    timed calls; IPOPT's time and iterations summed over every solve of the call (clearance: its rounds)."""
    r = run()
    times = []
    for _ in range(repeat):
        r = run()
        times.append(r.stats["ipopt_time_s"] / max(r.stats.get("ipopt_iterations", r.iterations), 1))
    return 1e3 * statistics.median(times), r.stats.get("ipopt_iterations", r.iterations), r


class Rows(list):
    """Rows of the table, printed as they come (a long run shows its progress)."""

    def append(self, row):
        print(" | ".join(map(str, row)), flush=True)
        super().append(row)


def exact(pb):
    return dataclasses.replace(pb, options=dataclasses.replace(pb.options, hessian="exact", starts=1, hops=0))


def command_time(problem, repeat):
    out = []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(repeat):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "vine_nlp", "design", str(problem), "-o", str(Path(d) / "o.h5"), "--force"],
                           check=True, capture_output=True)
            out.append(time.perf_counter() - t0)
    return statistics.median(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rep = args.repeat
    rows = Rows()

    tre = exact(load_problem(ROOT / "problems/trefoil-m4.toml").problem)
    base_ms, base_it, base = per_iteration(lambda: design_nlp(tre), rep)
    rows.append(("nlp (exact Hessian)", "trefoil, M = 40, n = 10", f"{base_ms:.2f}", base_it, "1.00"))
    gn = dataclasses.replace(tre, options=dataclasses.replace(tre.options, hessian="gauss-newton"))
    ms, it, _ = per_iteration(lambda: design_nlp(gn), rep)
    rows.append(("nlp (Gauss-Newton)", "trefoil", f"{ms:.2f}", it, f"{ms / base_ms:.2f}"))

    spam = dataclasses.replace(tre, actuator=Actuator("spam", tre.actuator.lambda_min, tre.actuator.theta_max))
    spam_ms, it, _ = per_iteration(lambda: design_nlp(spam), rep)
    rows.append(("nlp, sPAM", "trefoil", f"{spam_ms:.2f}", it, "1.00"))
    ms1 = MultiShapeProblem(tre.name, tre.diameter, [tre.target], [None], spam.actuator, spam.options)
    ms, it, _ = per_iteration(lambda: design_multishape(ms1, starts=1), rep)
    rows.append(("multishape, K = 1", "trefoil, sPAM", f"{ms:.2f}", it, f"{ms / spam_ms:.2f} (vs sPAM nlp)"))

    # clearance: a helix whose turns are closer than D (the tube following it would collide)
    coil = DesignProblem("tight-helix", 2.0, targets.helix(radius=3.0, pitch=0.25, length=50.0, samples=101),
                         actuator=Actuator("tendon", 0.4), options=dataclasses.replace(tre.options, points_per_segment=5))
    coil_ms, it, free = per_iteration(lambda: design_nlp(coil), rep)
    rows.append(("nlp (exact Hessian)", "tight helix, M = 20, n = 5", f"{coil_ms:.2f}", it, "1.00"))
    ms, it, r = per_iteration(lambda: design_with_clearance(coil, start=free), rep)
    rows.append(("clearance", f"tight helix ({r.stats['clearance_pairs']} pairs, {r.stats['clearance_rounds']} solves)", f"{ms:.2f}", it,
                 f"{ms / coil_ms:.2f}"))

    ms, it, _ = per_iteration(lambda: design_robust(tre, SIGMAS, start=base), rep)
    rows.append(("robust", "trefoil", f"{ms:.2f}", it, f"{ms / base_ms:.2f}"))
    bez = exact(load_problem(ROOT / "problems/bezier-b.toml").problem)
    bez_ms, bez_it, bez_base = per_iteration(lambda: design_nlp(bez), rep)
    rows.append(("nlp (exact Hessian)", "Bezier (b)", f"{bez_ms:.2f}", bez_it, "1.00"))
    ms, it, _ = per_iteration(lambda: design_robust(bez, SIGMAS, start=bez_base), rep)
    rows.append(("robust", "Bezier (b)", f"{ms:.2f}", it, f"{ms / bez_ms:.2f}"))

    end = chain_frames(base.routing.theta, base.routing.lam, base.routing.length, tre.diameter, base.routing.initial_pose)
    T0 = end[0]
    tip = TipProblem("tip", tre.diameter, end[-1][:3, 3], float(base.routing.length.sum()), base.routing.segments,
                     direction=end[-1][:3, 0], initial_pose=T0, actuator=tre.actuator, options=tre.options)
    ms, it, r = per_iteration(lambda: design_tip(tip, starts=1), rep)
    rows.append(("tip", f"trefoil's tip, M = 40 ({r.status})", f"{ms:.2f}", it, f"{ms / base_ms:.2f}"))

    cmd = [(p, command_time(ROOT / f"problems/{p}.toml", rep)) for p in ("trefoil-m4", "multishape-spam", "tip-target")]
    t_tre = cmd[0][1]
    cmd_rows = [(p, f"{t:.2f}", f"{t / t_tre:.2f}") for p, t in cmd]
    write_report(
        "transcription",
        "One transcription: time per iteration of every formulation",
        "Each formulation is terms, rows and blocks on design.transcription; per-stage blocks carry their own SX "
        "derivatives. Median over the timed calls of (IPOPT time / IPOPT iterations), the solvers already built, same "
        "start (clearance: summed over its active-set solves); ratio against the plain NLP on the same target and structure, measured in the same run. Goals: "
        "<= 1.5x (robust <= 4x).",
        table(("formulation", "target", "ms / iteration", "iterations", "ratio"), rows),
        "Command start to archive (`vine-nlp design P.toml`, whole process, median of "
        f"{rep}; goal: multishape and tip <= 2x the trefoil):",
        table(("problem", "s", "ratio to trefoil"), cmd_rows),
    )
    print("\n".join(" | ".join(map(str, r)) for r in cmd_rows))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
