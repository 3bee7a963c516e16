"""Active sets on compiled blocks against interpreted ones, measured in the same run.

Writes results/benchmarks/blocks.md.
Run: python benchmarks/bench_blocks.py [--rounds 3] [--repeat 3]

A structure built from an active set (clearance pairs, obstacle rows) changes from solve to solve,
so it is never compiled as a whole: with a compiler its block types are compiled on their own
(design.compiled.block_functions; an obstacle block as a map of its one-sample block), without one
(or VINE_NLP_CODEGEN=off) everything runs interpreted. Each case runs in child processes, the two
settings alternating, ``--rounds`` rounds; each child builds its solvers with a first call, then
times ``--repeat`` calls (medians). The first compiled child starts from an empty code cache: its
first call's compiles are the cost a machine pays once.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from bench_transcription import ONLY_TERM, cpu_clock, function_share, ms_per_iteration
from common import ROOT, table, write_report

CASES = {
    "clearance": "clearance, tight helix (M = 20, n = 5)",
    "obstacle-pipe-bend": "obstacles, pipe bend (5 capsules)",
    "obstacle-mesh": "obstacles, mesh (360 triangles)",
}


def child(case: str, repeat: int) -> dict:
    from vine_nlp import targets
    from vine_nlp.io.problem_file import load_problem
    from vine_nlp.methods import compiled
    from vine_nlp.methods.clearance import design_with_clearance
    from vine_nlp.methods.nlp import design_nlp
    from vine_nlp.methods.obstacles import design_with_obstacles
    from vine_nlp.problem import Actuator, DesignProblem

    cpu_clock(True)
    tre = load_problem(ROOT / "problems/trefoil-m4.toml").problem
    if case == "clearance":
        # the tight helix of bench_transcription: turns closer than D
        coil = DesignProblem("tight-helix", 2.0, targets.helix(radius=3.0, pitch=0.25, length=50.0, samples=101),
                             actuator=Actuator("tendon", 0.4),
                             options=dataclasses.replace(tre.options, points_per_segment=5, hessian="exact"))
        free = design_nlp(coil)
        run = lambda: design_with_clearance(coil, start=free)  # noqa: E731
        quality = lambda r: {"objective": r.stats["objective"], "min_clearance_D": r.stats["min_clearance"] / coil.diameter}  # noqa: E731
    else:
        pb = load_problem(ROOT / f"problems/{case}.toml").problem
        free = design_nlp(pb)
        ONLY_TERM[0] = "obstacles"  # the solves with rows
        run = lambda: design_with_obstacles(pb, start=free)  # noqa: E731
        quality = lambda r: {"objective": r.stats["objective"], "min_gap": r.metrics["min_obstacle_gap"]}  # noqa: E731
    t0, c0 = time.perf_counter(), time.process_time()
    r, _ = function_share(run)
    first = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "compiled": compiled.stats["compiled"],
             "compile_s": compiled.stats["compile_time_s"]}
    ms, cpu, shares = [], [], []
    for _ in range(repeat):
        c0 = time.process_time()
        r, share = function_share(run)
        cpu.append(time.process_time() - c0)
        ms.append(ms_per_iteration(r))
        shares.append(share)
    return {"first": first, "ms_per_iteration": statistics.median(ms), "call_cpu_s": statistics.median(cpu),
            "share": statistics.median(shares), "iterations": r.stats.get("ipopt_iterations", r.iterations)} | quality(r)


def spawn(case: str, mode: str, cache: str, repeat: int) -> dict:
    env = dict(os.environ, VINE_NLP_CODEGEN=mode, VINE_NLP_CACHE_DIR=cache)
    out = subprocess.run([sys.executable, __file__, "--child", case, "--repeat", str(repeat)], env=env, capture_output=True,
                         text=True, check=True, cwd=os.path.dirname(os.path.abspath(__file__)))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--child")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.repeat)))
        return
    load0 = os.getloadavg()
    rows = []
    for case, label in CASES.items():
        runs = {"off": [], "on": []}
        with tempfile.TemporaryDirectory(prefix="vine_nlp-bench-blocks-") as cache:
            for _ in range(args.rounds):
                for mode in ("off", "on"):
                    runs[mode].append(spawn(case, mode, cache, args.repeat))
                    print(case, mode, runs[mode][-1], flush=True)
        off, on = runs["off"], runs["on"]

        def med(rs, key):
            return statistics.median(r[key] for r in rs)

        ratio = statistics.median(a["ms_per_iteration"] / b["ms_per_iteration"] for a, b in zip(off, on))
        same = "yes" if off[-1]["iterations"] == on[-1]["iterations"] else "no"
        metric = "min_clearance_D" if case == "clearance" else "min_gap"
        rows.append((label, f"{off[-1]['iterations']} / {on[-1]['iterations']} ({same})",
                     f"{med(off, 'ms_per_iteration'):.2f}", f"{med(on, 'ms_per_iteration'):.2f}", f"{ratio:.2f}x",
                     f"{100 * med(off, 'share'):.0f} % / {100 * med(on, 'share'):.0f} %",
                     f"{med(off, 'call_cpu_s'):.3f} / {med(on, 'call_cpu_s'):.3f}",
                     f"{off[-1]['objective']:.6g} / {on[-1]['objective']:.6g}", f"{off[-1][metric]:.5g} / {on[-1][metric]:.5g}",
                     f"{on[0]['first']['compiled']} in {on[0]['first']['compile_s']:.1f} s"))
    load1 = os.getloadavg()
    write_report("blocks", "Active sets on compiled blocks", (
        "Clearance pairs and obstacle rows are active sets: the structure changes from solve to solve and is never "
        "compiled as a whole. Interpreted: every function in CasADi's virtual machine (VINE_NLP_CODEGEN=off, or no "
        "compiler). Compiled blocks: the structure interpreted, each block type compiled on its own and cached per "
        "block type (design.compiled.block_functions; an obstacle block, over BLOCK_BUDGET, as a map of its "
        f"one-sample block). Child processes, the two settings alternating, {args.rounds} rounds; each child builds "
        f"its solvers with a first call, then times {args.repeat} calls (medians). ms / iteration: IPOPT's CPU time "
        "over its iterations, the solves with rows only (clearance: its rounds; obstacles: not the start's solves); "
        "in functions: the share of it in the NLP's functions; call CPU: the whole design call, start given. "
        "Iterations (same?): of the last child of each setting; rounding differences in the sums of the blocks may "
        "send IPOPT another way. Compiled once: the libraries the first compiled child built into an empty cache, "
        "and the compiler's time (gcc -O1), the start's own whole-structure solvers (the obstacle-free design, "
        "compiled as a whole) among them: a machine's one-time cost, every later process loads them. "
        f"Load average (1, 5, 15 min) at the start {', '.join(f'{x:.1f}' for x in load0)}, at the end "
        f"{', '.join(f'{x:.1f}' for x in load1)} (2 cores)."),
        table(("case", "iterations interpreted / compiled (same)", "ms / iteration interpreted", "ms / iteration compiled blocks",
               "speed-up per iteration", "in functions", "call CPU s", "objective", "min clearance (D) / min gap (units)",
               "compiled once"), rows))


if __name__ == "__main__":
    main()
