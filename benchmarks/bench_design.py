"""Inverse-design NLP benchmarks: the paper's design cases, scaling with segments, initialization.

Writes results/benchmarks/design.md, scaling.md, init.md and results/figures/nlp-scaling.png.
Run: python benchmarks/bench_design.py [--quick]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time

import numpy as np
from common import FIGURES, ROOT, machine, table, write_section

from vine_nlp import targets
from vine_nlp.design.common import Guess, geometric_guess, pair_points
from vine_nlp.design.nlp import design_nlp, get_solver, solve_from
from vine_nlp.design.problem import DesignOptions, DesignProblem
from vine_nlp.io.problem_file import load_problem
from vine_nlp.model import chain_frames

# (problem file, paper RMSE [cm], paper max [cm], goal RMSE [cm])
CASES = [
    ("trefoil-m4", 0.022, 0.048, 0.010),
    ("bezier-a", 0.20, 2.19, 0.10),
    ("bezier-b", 0.13, 1.22, 0.065),
    ("bezier-c", 0.09, 0.68, 0.045),
    ("polyline-d", 2.23, 7.20, 1.2),
    ("spam-helix", None, None, None),
]


def _best_of(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def paper_cases(repeat):
    rows = []
    for name, p_rmse, p_max, goal in CASES:
        pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
        get_solver.cache_clear()
        t0 = time.perf_counter()
        first = design_nlp(pb)
        cold = time.perf_counter() - t0
        solve, r = _best_of(lambda: design_nlp(pb), repeat)
        m = r.metrics
        ok = "" if goal is None else ("yes" if m["rmse"] <= goal else "NO")
        rows.append([
            name, r.status, f"{10 * m['rmse']:.4f}", f"{10 * m['max_error']:.4f}",
            "-" if p_rmse is None else f"{10 * p_rmse:.2f} / {10 * p_max:.2f}",
            "-" if goal is None else f"<= {10 * goal:.2f} {ok}",
            r.iterations, f"{first.stats['build_time_s']:.3f}", f"{solve:.3f}", f"{cold:.3f}",
        ])
        print(name, rows[-1], flush=True)
    # command start to archive written, trefoil
    with tempfile.TemporaryDirectory() as d:
        walls = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "vine_nlp", "design", str(ROOT / "problems/trefoil-m4.toml"), "-o", f"{d}/t.h5", "--force"],
                           check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
    text = [
        "## Inverse design: the paper's cases (NLP, default settings)",
        "",
        f"Machine: {machine()}",
        "",
        "Errors in mm. Paper: greedy Algorithm 1 in MATLAB (fmincon sqp + GlobalSearch), trefoil 138 s, "
        "Bezier about 199 s each. `build` is constructing the CasADi/IPOPT solver (once per structure), `solve` the "
        f"best of {repeat} solves with the solver reused (geometric guess included), `cold` build + first solve.",
        "",
        table(["case", "status", "RMSE", "max", "paper RMSE / max", "goal RMSE", "iter", "build [s]", "solve [s]", "cold [s]"], rows),
        "",
        f"`vine-nlp design problems/trefoil-m4.toml` from command start to archive written: {min(walls):.2f} s (best of {repeat}; goal <= 2 s).",
    ]
    write_section("design", "\n".join(text))


def scaling(sizes, repeat):
    rows, pts = [], []
    for N in sizes:
        pb = DesignProblem("trefoil-n1", 2.43, targets.trefoil(samples=N + 1), options=DesignOptions(points_per_segment=1))
        get_solver.cache_clear()
        t0 = time.perf_counter()
        r = design_nlp(pb)
        total = time.perf_counter() - t0
        build = r.stats["build_time_s"]
        solve, r2 = _best_of(lambda: design_nlp(pb), repeat)
        per_it = solve / max(r2.iterations, 1)
        rows.append([N, r.status, f"{10 * r.metrics['rmse']:.4f}", f"{build:.3f}", f"{solve:.3f}", r2.iterations, f"{1e3 * per_it:.1f}", f"{total:.3f}"])
        pts.append((N, build, solve, per_it, total))
        print(rows[-1], flush=True)
    pts = np.array(pts)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 3.4))
    ax.loglog(pts[:, 0], pts[:, 1], "o-", label="build NLP + solver")
    ax.loglog(pts[:, 0], pts[:, 2], "s-", label="solve (reused solver)")
    ax.loglog(pts[:, 0], pts[:, 4], "^-", label="total, first design")
    ax.loglog(pts[:, 0], pts[:, 3] * 10, "x--", label="time per iteration x 10")
    ref = pts[0, 4] * pts[:, 0] / pts[0, 0]
    ax.loglog(pts[:, 0], ref, "k:", lw=0.8, label="linear")
    ax.set_xlabel("segments M (n = 1)")
    ax.set_ylabel("time [s]")
    ax.set_title("trefoil m = 4, one segment per target point", fontsize=8)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / "nlp-scaling.png", dpi=150)
    slope_b = np.polyfit(np.log(pts[:, 0]), np.log(pts[:, 1]), 1)[0]
    slope_i = np.polyfit(np.log(pts[:, 0]), np.log(pts[:, 3]), 1)[0]
    text = [
        "## NLP scaling with the number of segments",
        "",
        f"Machine: {machine()}",
        "",
        "Trefoil m = 4 sampled with M + 1 points, n = 1 (one segment per target point). Goals: 400 segments <= 2 s, "
        "1600 segments <= 8 s, building included (`total`).",
        "",
        table(["segments", "status", "RMSE [mm]", "build [s]", "solve [s]", "iterations", "ms / iteration", "total [s]"], rows),
        "",
        f"Fitted log-log slopes: build {slope_b:.2f}, time per iteration {slope_i:.2f} (1 = linear).",
        "",
        "![scaling](figures/nlp-scaling.png)",
    ]
    write_section("scaling", "\n".join(text))


def _paper_guess(pb, pairing):
    """The paper's initial values: lambda 0.75, theta 0, dl = target chord; frames on that chain."""
    g = geometric_guess(pb, pairing)
    M = pairing.segments
    theta, lam, length = np.zeros(M), np.full(M, 0.75), pairing.segment_chord.copy()
    if pb.actuator.shared_lambda:
        lam = np.full(M, max(0.75, pb.actuator.lambda_min))
    return Guess(theta, lam, length, g.initial_pose, chain_frames(theta, lam, length, pb.diameter, g.initial_pose))


def initialization(repeat):
    rows = []
    for name, *_ in CASES:
        pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
        pairing = pair_points(pb.target, pb.options.points_per_segment)
        variants = {
            "geometric, frames on target": lambda: solve_from(pb, geometric_guess(pb, pairing), pairing, "target"),
            "geometric, frames on its chain": lambda: solve_from(pb, geometric_guess(pb, pairing), pairing, "chain"),
            "paper's (theta 0, lambda 0.75), frames on target": lambda: solve_from(pb, _with_target_frames(_paper_guess(pb, pairing), geometric_guess(pb, pairing)), pairing, "target"),
            "4 starts": lambda: design_nlp(pb, starts=4),
            "geometric, exact Hessian only": lambda: solve_from(_with_hessian(pb, "exact"), geometric_guess(pb, pairing), pairing),
            "geometric, Gauss-Newton only": lambda: solve_from(_with_hessian(pb, "gauss-newton"), geometric_guess(pb, pairing), pairing),
        }
        for label, fn in variants.items():
            t, r = _best_of(fn, repeat)
            rows.append([name, label, r.status, f"{10 * r.metrics['rmse']:.4f}", r.iterations, f"{t:.3f}"])
            print(rows[-1], flush=True)
    text = [
        "## Initialization and multi-start (NLP)",
        "",
        f"Machine: {machine()}",
        "",
        "Same solver and options, different starts; the first four rows of each case use the default Hessian "
        "(`auto`: Gauss-Newton, exact if it does not converge in 50 iterations), the last two force one Hessian. "
        "RMSE in mm; time includes the guess and, the first time a solver variant is used, building it.",
        "",
        table(["case", "start", "status", "RMSE [mm]", "iterations", "time [s]"], rows),
    ]
    write_section("init", "\n".join(text))


def _with_hessian(pb, hessian):
    import dataclasses

    return dataclasses.replace(pb, options=dataclasses.replace(pb.options, hessian=hessian))


def _with_target_frames(guess, geo):
    guess.frames = geo.frames
    return guess


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer repeats and sizes")
    ap.add_argument("--only", choices=["cases", "scaling", "init"])
    a = ap.parse_args()
    repeat = 1 if a.quick else 3
    if a.only in (None, "cases"):
        paper_cases(repeat)
    if a.only in (None, "scaling"):
        scaling([100, 200, 400, 800, 1600] if not a.quick else [100, 400], repeat)
    if a.only in (None, "init"):
        initialization(1)


if __name__ == "__main__":
    main()
