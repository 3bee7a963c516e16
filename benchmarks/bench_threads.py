"""Solver threads: the designs with one BLAS thread (design.blas) against OpenBLAS's default, one per core.

Each workload runs in a child process twice per round, once with OPENBLAS_NUM_THREADS=1 and once
with OPENBLAS_NUM_THREADS=<cores> (OpenBLAS's default; a thread count in the environment is the
user's choice, which design.blas leaves alone), alternating, so a shared machine's load hits both
alike. In the child, one call builds the solvers, then the timed calls run (wall and CPU time of
the process, medians).

Writes results/benchmarks/threads.md. Run: python benchmarks/bench_threads.py [--rounds N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

from common import ROOT, table, write_report

CHILD = r"""
import dataclasses, json, sys, tempfile, time
from pathlib import Path
sys.path.insert(0, sys.argv[2])
from vine_nlp import targets
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem
from vine_nlp.io.problem_file import load_problem
root = Path(sys.argv[3])
name = sys.argv[1]
if name == "trefoil":
    from vine_nlp.methods.nlp import design_nlp
    pb = load_problem(root / "problems/trefoil-m4.toml").problem
    run = lambda: design_nlp(pb)
elif name == "trefoil-1600":
    from vine_nlp.methods.nlp import design_nlp
    pb = DesignProblem("trefoil-n1", 2.43, targets.trefoil(samples=1601), options=DesignOptions(points_per_segment=1))
    run = lambda: design_nlp(pb)
elif name == "tip-target":
    from vine_nlp.methods.tip import design_tip
    pb = load_problem(root / "problems/tip-target.toml").problem
    run = lambda: design_tip(pb)
elif name == "clearance":
    from vine_nlp.methods.clearance import design_with_clearance
    from vine_nlp.methods.nlp import design_nlp
    pb = DesignProblem("tight-helix", 2.0, targets.helix(radius=3.0, pitch=0.25, length=50.0, samples=101),
                       actuator=Actuator("tendon", 0.4), options=DesignOptions(points_per_segment=5, hessian="exact", starts=1, hops=0))
    free = design_nlp(pb)
    run = lambda: design_with_clearance(pb, start=free)
elif name == "obstacles":
    from bench_obstacles import primitive_scene
    from vine_nlp.methods.obstacles import design_with_obstacles
    pb = load_problem(primitive_scene(Path(tempfile.mkdtemp()))).problem
    run = lambda: design_with_obstacles(pb)
run()
wall, cpu = [], []
for _ in range(int(sys.argv[4])):
    t, c = time.perf_counter(), time.process_time()
    run()
    wall.append(time.perf_counter() - t)
    cpu.append(time.process_time() - c)
print(json.dumps({"wall": min(wall), "cpu": min(cpu)}))
"""

WORKLOADS = {
    "trefoil": "trefoil-m4, design_nlp (defaults)",
    "trefoil-1600": "trefoil, 1600 segments, n = 1, design_nlp (IPOPT)",
    "tip-target": "tip-target, design_tip",
    "clearance": "tight helix, design_with_clearance (3 solves)",
    "obstacles": "20-primitive scene (bench_obstacles), design_with_obstacles",
}
CALLS = {"trefoil": 5, "trefoil-1600": 2, "tip-target": 3, "clearance": 3, "obstacles": 1}


def child(name: str, threads: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")}
    env["OPENBLAS_NUM_THREADS"] = str(threads)
    p = subprocess.run([sys.executable, "-c", CHILD, name, str(ROOT / "benchmarks"), str(ROOT), str(CALLS[name])],
                       capture_output=True, text=True, env=env, check=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    load0 = os.getloadavg()
    rows = []
    for name, what in WORKLOADS.items():
        got = {1: [], cores: []}
        for _ in range(args.rounds):
            for n in (1, cores):
                got[n].append(child(name, n))
        med = {n: {k: statistics.median(g[k] for g in got[n]) for k in ("wall", "cpu")} for n in got}
        one, many = med[1], med[cores]
        rows.append([what, f"{one['wall']:.3f} / {one['cpu']:.3f}", f"{many['wall']:.3f} / {many['cpu']:.3f}",
                     f"{many['wall'] / one['wall']:.2f}", f"{many['cpu'] / one['cpu']:.2f}"])
        print(rows[-1], flush=True)
    load1 = os.getloadavg()
    write_report(
        "threads",
        "Solver threads",
        f"Each workload in a child process with OPENBLAS_NUM_THREADS=1 (what design.blas sets) and with "
        f"OPENBLAS_NUM_THREADS={cores} (OpenBLAS's default, one per core), alternating, {args.rounds} rounds; per child "
        f"the solvers built by a first call, then the best of the timed calls; medians over the rounds of wall and CPU "
        f"seconds. Compiled code: VINE_NLP_CODEGEN={os.environ.get('VINE_NLP_CODEGEN', 'auto')}. Load average (1, 5, "
        f"15 min) at the start {', '.join(f'{v:.1f}' for v in load0)}, at the end {', '.join(f'{v:.1f}' for v in load1)}.",
        table(["workload", "1 thread wall / CPU s", f"{cores} threads wall / CPU s", "wall ratio", "CPU ratio"], rows),
    )


if __name__ == "__main__":
    main()
