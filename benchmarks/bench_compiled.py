"""Compiled NLP functions (design.compiled) against the interpreted ones, measured in the same run.

Writes results/benchmarks/compiled.md.
Run: python benchmarks/bench_compiled.py [--quick] [--only calls]
(--only calls: the whole design call table alone, printed, not written; a few minutes, most of it compiling the trefoil's solvers)

For each case: the same Spec built twice, once interpreted (VINE_NLP_CODEGEN=off) and once
compiled into a fresh cache (the compile is timed, then a second build loads the library);
both solve from the same start. Then the whole design call and the command line, each with
the solver (or the cached library) already there, and the scaling with the segment count.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
from common import ROOT, table, write_report

from vine_nlp import targets
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import compiled, settings
from vine_nlp.methods.common import geometric_guess, pair_points
from vine_nlp.methods.nlp import design_bounds, design_nlp, nlp_parameters, nlp_spec, start_x
from vine_nlp.methods.transcription import Solver, clear_caches
from vine_nlp.problem import DesignOptions, DesignProblem

CASES = ["trefoil-m4", "bezier-a", "bezier-b", "polyline-d", "spam-helix"]


def _setup(pb, hessian):
    o = pb.options
    pairing = pair_points(pb.target, o.points_per_segment)
    spec = nlp_spec(pairing.segments, pairing.n, pb.actuator.shared_lambda, o.max_iter, o.tol, False, hessian)
    return pairing, spec


def _solves(solver, pb, pairing, repeat):
    guess = geometric_guess(pb, pairing)
    p = solver.pack_params(nlp_parameters(pb, pairing, guess.initial_pose[:3, :3]))
    lbx, ubx = solver.bounds(**design_bounds(pb, pairing))
    x0 = start_x(solver, guess, pb.diameter)
    times, iters, x = [], 0, None
    for _ in range(repeat):
        x, status, st = solver.solve(x0, p, lbx, ubx)
        times.append(st["ipopt_time_s"])
        iters = st["iterations"]
    return min(times), iters, status, x


def per_iteration(repeat, hessians):
    rows = []
    for name in CASES:
        pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
        for hessian in hessians:
            pairing, spec = _setup(pb, hessian)
            os.environ["VINE_NLP_CODEGEN"] = "off"
            t0 = time.perf_counter()
            slow = Solver(spec)
            build_slow = time.perf_counter() - t0
            os.environ["VINE_NLP_CODEGEN"] = "on"
            t0 = time.perf_counter()
            Solver(spec)  # compiles into the fresh cache
            compile_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            fast = Solver(spec)  # loads the library
            load_s = time.perf_counter() - t0
            t_slow, it_slow, st_slow, x_slow = _solves(slow, pb, pairing, repeat)
            t_fast, it_fast, st_fast, x_fast = _solves(fast, pb, pairing, repeat)
            same = "yes" if it_slow == it_fast and np.allclose(x_slow, x_fast, rtol=0, atol=1e-8) else "no"
            rows.append([
                name, pairing.segments, hessian, f"{it_slow} / {it_fast}", same,
                f"{1e3 * t_slow / max(it_slow, 1):.2f}", f"{1e3 * t_fast / max(it_fast, 1):.2f}",
                f"{(t_slow / max(it_slow, 1)) / (t_fast / max(it_fast, 1)):.2f}x",
                f"{1e3 * t_slow:.1f}", f"{1e3 * t_fast:.1f}", f"{build_slow:.3f}", f"{compile_s:.2f}", f"{load_s:.3f}",
            ])
            print(rows[-1], flush=True)
    return table(["case", "segments", "Hessian", "iterations (interp. / compiled)", "same iterates", "ms / iter interpreted",
                  "ms / iter compiled", "speed-up", "solve interpreted [ms]", "solve compiled [ms]", "build interpreted [s]",
                  "compile, once [s]", "build from cache [s]"], rows)


def _calls(pb, repeat):
    """``repeat`` timed design_nlp calls (solvers built): wall times, IPOPT times, the last Result."""
    design_nlp(pb)  # builds (and compiles or loads)
    times, ipopt = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = design_nlp(pb)
        times.append(time.perf_counter() - t0)
        ipopt.append(r.stats.get("ipopt_time_s", float("nan")))
    return times, ipopt, r


def design_calls(repeat):
    """``design_nlp`` at the problem's defaults, solvers built: the whole call (guesses, starts, evaluation);
    compiled.

    Then, compiled, the plain NLP's Gauss-Newton IPOPT settings (methods.settings.GAUSS_NEWTON) against
    CHAIN alone, the two alternating in blocks of 5 calls (a shared machine drifts)."""
    rows = []
    for name in ["trefoil-m4", "bezier-b"]:
        pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
        out = []
        for m in ("off", "on"):
            os.environ["VINE_NLP_CODEGEN"] = m
            clear_caches()
            out.append(_calls(pb, repeat))
        (a, ai, ra), (b, bi, rb) = out
        rows.append([name, f"{1e3 * min(a):.1f} ({1e3 * statistics.median(a):.1f})", f"{1e3 * min(b):.1f} ({1e3 * statistics.median(b):.1f})",
                     f"{1e3 * min(ai):.1f}", f"{1e3 * min(bi):.1f} ({1e3 * statistics.median(bi):.1f})", f"{ra.iterations} / {rb.iterations}",
                     f"{statistics.median(a) / statistics.median(b):.2f}x", f"{10 * ra.metrics['rmse']:.4f} / {10 * rb.metrics['rmse']:.4f}"])
        print(rows[-1], flush=True)
    text = table(["problem", "design call interpreted, best (median) [ms]", "compiled, best (median) [ms]", "of it IPOPT, interpreted [ms]",
                  "IPOPT, compiled, best (median) [ms]", "iterations interp. / compiled", "speed-up (medians)",
                  "RMSE [mm] interp. / compiled"], rows)

    os.environ["VINE_NLP_CODEGEN"] = "on"
    pb = load_problem(ROOT / "problems" / "trefoil-m4.toml").problem
    pb = dataclasses.replace(pb, options=dataclasses.replace(pb.options, solver="ipopt"))  # GAUSS_NEWTON is IPOPT's
    variants = {"CHAIN + GAUSS_NEWTON (default)": dict(settings.GAUSS_NEWTON), "CHAIN alone": {}}
    runs = {k: ([], [], None) for k in variants}
    for _ in range(max(1, repeat // 5)):
        for k, opts in variants.items():
            settings.GAUSS_NEWTON = opts
            times, ipopt, r = _calls(pb, 5)
            runs[k] = (runs[k][0] + times, runs[k][1] + ipopt, r)
    settings.GAUSS_NEWTON = variants["CHAIN + GAUSS_NEWTON (default)"]
    rows = [[k, f"{1e3 * min(t):.1f}", f"{1e3 * statistics.median(t):.1f}", f"{1e3 * min(i):.1f}", f"{1e3 * statistics.median(i):.1f}",
             r.iterations, f"{10 * r.metrics['rmse']:.5f}"] for k, (t, i, r) in runs.items()]
    return text + (f"\n\nTrefoil (m = 4), compiled, {len(runs[k][0])} calls per variant, alternating in blocks of 5; the plain NLP's "
                   "first solve is Gauss-Newton:\n\n") + table(
        ["Gauss-Newton IPOPT settings", "design call best [ms]", "median [ms]", "IPOPT best [ms]", "IPOPT median [ms]", "iterations",
         "RMSE [mm]"], rows)


def command_line(repeat):
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for m in ("off", "auto"):
            env = dict(os.environ, VINE_NLP_CODEGEN=m)
            cmd = [sys.executable, "-m", "vine_nlp", "design", str(ROOT / "problems/trefoil-m4.toml"), "-o", f"{d}/t.h5", "--force"]
            subprocess.run(cmd, env=env, check=True, capture_output=True)  # compiles once where auto
            times = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                subprocess.run(cmd, env=env, check=True, capture_output=True)
                times.append(time.perf_counter() - t0)
            rows.append([{"off": "interpreted", "auto": "compiled (library cached)"}[m], f"{min(times):.3f}",
                         f"{statistics.median(times):.3f}"])
            print(rows[-1], flush=True)
    return table(["`vine-nlp design problems/trefoil-m4.toml`", "best [s]", "median [s]"], rows)


def scaling(sizes):
    """The whole design call from cold (solvers built in the call; the compiled library already cached)."""
    rows = []
    for M in sizes:
        pb = DesignProblem(f"trefoil-{M}", 2.43, targets.trefoil(samples=M + 1), options=DesignOptions(points_per_segment=1))
        os.environ["VINE_NLP_CODEGEN"] = "on"
        clear_caches()
        design_nlp(pb)  # compiles its structures once
        out = []
        for m in ("off", "on"):
            os.environ["VINE_NLP_CODEGEN"] = m
            clear_caches()
            t0 = time.perf_counter()
            r = design_nlp(pb)
            out.append((time.perf_counter() - t0, r))
        (t_off, r_off), (t_on, r_on) = out
        per = [1e3 * r.stats["ipopt_time_s"] / max(r.iterations, 1) for r in (r_off, r_on)]
        rows.append([M, r_on.status, f"{r_off.iterations} / {r_on.iterations}", f"{per[0]:.1f}", f"{per[1]:.1f}", f"{t_off:.3f}", f"{t_on:.3f}"])
        print(rows[-1], flush=True)
    ms = np.array([r[0] for r in rows], float)
    per = np.array([float(r[4]) for r in rows])
    slope = np.polyfit(np.log(ms), np.log(per), 1)[0] if len(rows) > 1 else float("nan")
    return table(["segments", "status", "iterations (interp. / compiled)", "ms / iter interpreted", "ms / iter compiled",
                  "design call, cold, interpreted [s]", "compiled (library cached) [s]"], rows) + (
        f"\n\nFitted log-log slope of the compiled time per iteration: {slope:.2f} (1 = linear). Goal: 1600 segments within 2 s.")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", choices=["calls"], help="calls: only the whole design call table, printed (nothing written)")
    a = ap.parse_args()
    repeat = 2 if a.quick else 5
    cache = tempfile.mkdtemp(prefix="vine_nlp-bench-cache-")
    os.environ["VINE_NLP_CACHE_DIR"] = cache
    cc = compiled.compiler()
    load = os.getloadavg()
    if a.only == "calls":
        text = design_calls(20 if a.quick else 40)
        print(f"\n{text}\n\nLoad average before {load[0]:.2f}, after {os.getloadavg()[0]:.2f}.")
        return
    blocks = [
        "### Time per IPOPT iteration, interpreted against compiled\n\n" + per_iteration(repeat, ["gauss-newton", "exact"] if not a.quick else ["exact"]),
        "### The whole design call at the defaults (solvers built)\n\n" + design_calls(20 if a.quick else 40),
        "### The command line, from command start to archive\n\n" + command_line(repeat),
        "### Scaling with the segment count (trefoil, one point per segment, default settings)\n\n" + scaling([100, 400, 1600] if not a.quick else [100, 400]),
    ]
    after = os.getloadavg()
    desc = (
        f"Compiler: `{' '.join(cc) if cc else 'none'}` (VINE_NLP_CFLAGS). Cache: a fresh directory per run, so `compile, once` is a "
        "first run's cost; `build from cache` is every later process's. Times are IPOPT's wall time per solve from the geometric "
        "guess (best of the repeats), same start, same options. `same iterates`: equal iteration counts and solutions within 1e-8. "
        f"Load average before {load[0]:.2f}, after {after[0]:.2f}."
    )
    write_report("compiled", "Compiled NLP functions (C code generation, cached on disk)", desc, *blocks)


if __name__ == "__main__":
    main()
