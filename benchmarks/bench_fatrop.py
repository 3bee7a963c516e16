"""Fatrop on the transcription's stage form against IPOPT on the plain chain, measured in the same run.

Writes results/benchmarks/fatrop.md.
Run: python benchmarks/bench_fatrop.py [--quick]

Compiled functions (VINE_NLP_CODEGEN=on, a fresh cache compiled first). For each paper case the
whole ``design_nlp`` call at the defaults with its solvers built, ``[design] solver = "auto"``
(Fatrop for the first Gauss-Newton solve) and ``"ipopt"`` alternating call by call; then the
solvers' set-up per segment count, and the command line on the trefoil.
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

from common import ROOT, table, write_report

from vine_nlp import targets
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import compiled
from vine_nlp.methods import nlp as nlp_module
from vine_nlp.methods.nlp import FATROP_MAX_SEGMENTS, design_nlp, get_fatrop, get_solver
from vine_nlp.methods.transcription import clear_caches
from vine_nlp.problem import DesignOptions, DesignProblem

CASES = ["trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "polyline-d", "spam-helix"]


def _ms(values, how=min) -> str:
    return f"{1e3 * how(values):.1f}"


def calls(repeat: int) -> str:
    rows = []
    for name in CASES:
        pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
        variants = {s: dataclasses.replace(pb, options=dataclasses.replace(pb.options, solver=s)) for s in ("auto", "ipopt")}
        for q in variants.values():
            design_nlp(q)  # builds (compiles into the fresh cache)
        runs = {s: ([], [], None) for s in variants}
        for _ in range(repeat):
            for s, q in variants.items():
                t0 = time.perf_counter()
                r = design_nlp(q)
                wall = time.perf_counter() - t0
                runs[s][0].append(wall)
                runs[s][1].append(r.stats["ipopt_time_s"])
                runs[s] = (runs[s][0], runs[s][1], r)
        (wa, sa, ra), (wi, si, ri) = runs["auto"], runs["ipopt"]
        fa, fi = ra.stats["objective"], ri.stats["objective"]
        rows.append([name, ra.stats["solver"], f"{_ms(wa)} ({_ms(wa, statistics.median)})", f"{_ms(wi)} ({_ms(wi, statistics.median)})",
                     f"{_ms(sa)} ({_ms(sa, statistics.median)})", f"{_ms(si)} ({_ms(si, statistics.median)})",
                     f"{statistics.median(wi) / statistics.median(wa):.2f}x", f"{ra.iterations} / {ri.iterations}",
                     f"{(fa - fi) / abs(fi):.1e}", f"{10 * ra.metrics['rmse']:.4f} / {10 * ri.metrics['rmse']:.4f}"])
        print(rows[-1], flush=True)
    return table(["case", "first solve on", "design call, auto: best (median) [ms]", "ipopt: best (median) [ms]",
                  "last solve's solver time, auto [ms]", "ipopt [ms]", "speed-up (medians)", "iterations auto / ipopt",
                  "objective (auto - ipopt) / ipopt", "RMSE [mm] auto / ipopt"], rows)


def setup(sizes) -> str:
    """Each solver built from the cached library, in a process that built it before (clear_caches)."""
    rows = []
    for M in sizes:
        pb = DesignProblem(f"trefoil-{M}", 2.43, targets.trefoil(samples=M + 1), options=DesignOptions(points_per_segment=1))
        get_fatrop(M, 1), get_solver(M, 1, False, hessian="gauss-newton")  # compiles both
        times = {"fatrop": [], "ipopt": []}
        for _ in range(3):
            clear_caches()
            t0 = time.perf_counter()
            get_fatrop(M, 1)
            times["fatrop"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            get_solver(M, 1, False, hessian="gauss-newton")
            times["ipopt"].append(time.perf_counter() - t0)
        per = []
        for s in ("auto", "ipopt"):
            q = dataclasses.replace(pb, options=dataclasses.replace(pb.options, solver=s))
            nlp_module.FATROP_MAX_SEGMENTS = max(M, FATROP_MAX_SEGMENTS)  # here Fatrop at every size
            try:
                r = design_nlp(q)
            finally:
                nlp_module.FATROP_MAX_SEGMENTS = FATROP_MAX_SEGMENTS
            per.append(1e3 * r.stats["ipopt_time_s"] / max(r.iterations, 1))
        rows.append([M, _ms(times["fatrop"]), _ms(times["ipopt"]), f"{per[0]:.2f}", f"{per[1]:.2f}"])
        print(rows[-1], flush=True)
    return table(["segments", "Fatrop set-up, best [ms]", "IPOPT set-up, best [ms]", "Fatrop ms / iteration", "IPOPT ms / iteration"], rows)


def command_line(repeat: int) -> str:
    rows = {}
    with tempfile.TemporaryDirectory() as d:
        base = (ROOT / "problems" / "trefoil-m4.toml").read_text()
        files = {"auto": f"{d}/auto.toml", "ipopt": f"{d}/ipopt.toml"}
        for s, path in files.items():
            with open(path, "w") as fh:
                fh.write(base.replace("lookahead = 4\n", f'lookahead = 4\nsolver = "{s}"\n'))
        cmd = lambda s: [sys.executable, "-m", "vine_nlp", "design", files[s], "-o", f"{d}/{s}.h5", "--force"]  # noqa: E731
        env = dict(os.environ, VINE_NLP_CODEGEN="auto")
        for s in files:
            subprocess.run(cmd(s), env=env, check=True, capture_output=True)
            rows[s] = []
        for _ in range(repeat):
            for s in files:
                t0 = time.perf_counter()
                subprocess.run(cmd(s), env=env, check=True, capture_output=True)
                rows[s].append(time.perf_counter() - t0)
    return table(["`vine-nlp design problems/trefoil-m4.toml`, design.solver", "best [s]", "median [s]"],
                 [[s, f"{min(t):.3f}", f"{statistics.median(t):.3f}"] for s, t in rows.items()])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    os.environ["VINE_NLP_CACHE_DIR"] = tempfile.mkdtemp(prefix="vine_nlp-bench-cache-")
    os.environ["VINE_NLP_CODEGEN"] = "on"
    cc = compiled.compiler()
    load = os.getloadavg()
    blocks = [
        "### The design call at the defaults (solvers built), solver auto against ipopt\n\n" + calls(10 if a.quick else 30),
        "### Set-up and time per iteration by segment count (trefoil, one point per segment)\n\n" + setup([40, 100, 200] if a.quick else [40, 100, 200, 400]),
        "### The command line, from command start to archive (library cached)\n\n" + command_line(3 if a.quick else 7),
    ]
    after = os.getloadavg()
    desc = (
        f"Compiler: `{' '.join(cc) if cc else 'none'}`. `auto`: the first Gauss-Newton solve on Fatrop (the stage form, "
        f"objective x 100, mu_init 1e-6), IPOPT where it fails; `ipopt`: IPOPT only. Alternating call by call; the solver "
        f"time is the solver's own wall time of the design's last solve (stats `ipopt_time_s`). Fatrop runs only up to "
        f"{FATROP_MAX_SEGMENTS} segments by default: its set-up (CasADi's interface) grows about as M^2 (second table). "
        f"Load average before {load[0]:.2f}, after {after[0]:.2f}."
    )
    write_report("fatrop", "Fatrop: the stage form of the plain NLP", desc, *blocks)


if __name__ == "__main__":
    main()
