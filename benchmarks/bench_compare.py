"""NLP against the paper's greedy Algorithm 1, same problems, same run, default settings; then buildable against
buildable (``vine-nlp compare``'s runs: nlp, nlp_free, greedy_buildable, greedy).

Writes results/benchmarks/compare.md. Run: python benchmarks/bench_compare.py [--buildable]
(``--buildable``: only the buildable section, replacing it in the file and keeping the rest as it was measured)
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time

import numpy as np
from common import ROOT, machine, table, write_section

from vine_nlp import pipeline
from vine_nlp.front.reports import rules_missed
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import corners, transcription
from vine_nlp.methods import greedy as greedy_mod
from vine_nlp.methods.buildable import Build, classify, design_buildable, lambda_bounds, target_bends, unwind
from vine_nlp.methods.common import design_bounds, evaluate, pair_points
from vine_nlp.methods.greedy import lowpass
from vine_nlp.pipeline.request import COMPARE

CASES = ["trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "polyline-d", "spam-helix"]
PAPER = {"trefoil-m4": "0.22 / 0.48 mm, 138 s", "bezier-a": "2.0 / 21.9 mm", "bezier-b": "1.3 / 12.2 mm",
         "bezier-c": "0.9 / 6.8 mm", "polyline-d": "22.3 / 72.0 mm", "spam-helix": "-"}
# corner targets: the NLP with basin hopping as well (design.hops)
HOPS = {"polyline-d": 12}


def clear_caches():
    """Forget every built solver and SX function of both methods: the next run starts cold."""
    transcription.clear_caches()
    corners.clear_caches()
    greedy_mod.get_window_solver.cache_clear()


def run_design(pf, method):
    """The run ``method`` of problem file ``pf`` as `vine-nlp design --method` makes it (the pipeline)."""
    return pipeline.run(pf, pipeline.Request(methods=(method,))).runs[method]


def timed(fn, cpu: dict | None = None):
    """(result, wall seconds); ``cpu["s"]``: the process's CPU seconds (all threads), less noisy under load."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    if cpu is not None:
        cpu["s"] = time.process_time() - c0
    return out, time.perf_counter() - t0


def main():
    rows, verdict, searched = [], [], []
    load_start = os.getloadavg()
    for name in CASES:
        pf = load_problem(ROOT / "problems" / f"{name}.toml")
        pb = pf.problem
        cpu_nlp, cpu_greedy = {}, {}
        clear_caches()
        nlp, t_nlp_cold = timed(lambda: run_design(pf, "nlp"), cpu_nlp)
        _, t_nlp = timed(lambda: run_design(pf, "nlp"))
        clear_caches()
        greedy, t_greedy_cold = timed(lambda: run_design(pf, "greedy"), cpu_greedy)
        _, t_greedy = timed(lambda: run_design(pf, "greedy"))
        filt = lowpass(greedy, pb)
        if "search_rounds" in nlp.stats:
            st = nlp.stats
            searched.append(f"{name}: the first solve was corner-like (design.corners): {st['search_rounds']} rounds, "
                            f"{st['search_windows']} windows ({st['search_window_iterations']} IPOPT iterations in "
                            f"{st['search_workers']} threads), {st['search_accepted']} window changes kept, "
                            f"{st['search_time_s']:.2f} s of the cold run"
                            + (", cut by the budget" if st["search_budget_hit"] else "")
                            + f". CPU time from cold (process time, all threads): nlp {cpu_nlp['s']:.2f} s, greedy "
                            f"{cpu_greedy['s']:.2f} s ({cpu_greedy['s'] / cpu_nlp['s']:.1f}x); wall clock "
                            f"{t_nlp_cold:.2f} s and {t_greedy_cold:.2f} s ({t_greedy_cold / t_nlp_cold:.1f}x).")
        runs = [("nlp", nlp, t_nlp_cold, t_nlp)]
        if name in HOPS:
            hopped = dataclasses.replace(pf, problem=dataclasses.replace(pb, options=dataclasses.replace(pb.options, hops=HOPS[name])))
            hop, t_hop = timed(lambda: run_design(hopped, "nlp"))
            runs.append((f"nlp + {HOPS[name]} hops", hop, None, t_hop))
        runs += [("greedy", greedy, t_greedy_cold, t_greedy), ("greedy + low-pass", filt, t_greedy_cold, t_greedy)]
        for label, r, cold, warm in runs:
            m = r.metrics
            rows.append([name, label, r.status, f"{10 * m['rmse']:.4f}", f"{10 * m['max_error']:.4f}",
                         "-" if cold is None else f"{cold:.2f}", f"{warm:.2f}", r.stats.get("window_solves", r.iterations),
                         f"{m['tv_theta']:.3f}", f"{m['tv_lambda']:.3f}", PAPER[name] if label == "nlp" else ""])
        g = greedy.metrics
        for label, r, cold, warm in runs[:-2]:
            m = r.metrics
            rmse = m["rmse"] / g["rmse"] - 1
            verdict.append([
                name, label,
                ("yes" if rmse <= 0 else "no") + f" ({100 * rmse:+.1f} %)",
                "-" if cold is None else f"{t_greedy_cold / cold:.1f}x",
                f"{t_greedy / warm:.1f}x",
                ("yes" if m["tv_theta"] < g["tv_theta"] else "no") + f" ({100 * (m['tv_theta'] / g['tv_theta'] - 1):+.1f} %)",
            ])
        print(rows[-len(runs):], verdict[-1], flush=True)
    text = [
        "## NLP against the greedy baseline (paper Algorithm 1)",
        "",
        f"Machine: {machine()}",
        "",
        "Both methods at their defaults on the bundled problems, one after the other in the same run; times are wall "
        "clock from the call to the Result. `cold`: every solver and SX function of the method built in the call (as in "
        "a fresh `vine-nlp design`); `built`: the same call again with them built (as in a sweep or a multi-start). "
        "Greedy: look-ahead k = 4, 4 trial starts per window (16 for the first), the same pairing, squared error, "
        "bounds and segment model as the NLP. Errors in mm; `solves` is IPOPT iterations (nlp) or window solves "
        "(greedy). TV: total variation of theta (rad) and lambda over the segments. `nlp` is the default: where the "
        "first solve shows a corner-like target (Gauss-Newton failed and RMSE > 0.05 D) it includes the windowed corner "
        "search (design.corners, default budget 20 s, two threads), from cold like every `cold` time. "
        + ", ".join(f"{k}: also the NLP with {v} rounds of basin hopping (`design.hops`, no corner search)" for k, v in HOPS.items()) + ". "
        f"Load average (1 min) at the start and the end of the run: {load_start[0]:.1f} and {os.getloadavg()[0]:.1f} "
        "(a shared machine: compare the ratios, measured in the same run).",
        "",
        *[line for s in searched for line in (s, "")],
        table(["case", "method", "status", "RMSE", "max", "time cold [s]", "time built [s]", "iter / solves", "TV theta",
               "TV lambda", "paper RMSE / max"], rows),
        "",
        table(["case", "NLP run", "RMSE <= greedy", "speed-up cold", "speed-up built", "TV theta lower"], verdict),
    ]
    write_section("compare", "\n".join(text) + "\n\n" + buildable_section())


BUILDABLE_CASES = ["bezier-a", "polyline-d"]
BUILDABLE_HEAD = "### Buildable against buildable"


def greedy_with_target_classes(problem):
    """The alternative classes for the buildable greedy: the nlp's (classify on the target's bends), not its own design's."""
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    build = Build.of(problem)
    act = classify(target_bends(problem, pairing), pairing.segment_chord, build)
    theta = [np.where(greedy_mod._carriers(act, True), v, 0.0) for v in design_bounds(problem, pairing)["theta"]]
    res = greedy_mod.design_greedy(problem, pairing, bounds={"lam": lambda_bounds(act, pairing.segment_chord, build), "theta": theta})
    r = unwind(res.routing, act, build)
    return evaluate(problem, r, pairing, "greedy_buildable", status=res.status, solve_time_s=res.solve_time_s)


def buildable_section() -> str:
    """``vine-nlp compare``'s runs (pipeline.run with COMPARE, from cold), and the alternative not taken for the greedy's
    buildable figure: the nlp's buildable design (classes, reclassification) started from the greedy's routing."""
    rows, load_start = [], os.getloadavg()
    for name in BUILDABLE_CASES:
        pf = load_problem(ROOT / "problems" / f"{name}.toml")
        clear_caches()
        runs = pipeline.run(pf, pipeline.Request(methods=COMPARE)).runs
        g = runs["greedy"]
        polished, t = timed(lambda: design_buildable(pf.problem, g))
        polished.solve_time_s = g.solve_time_s + t
        targeted = greedy_with_target_classes(pf.problem)
        for label, r in [*runs.items(), ("greedy, the target's classes (not used)", targeted),
                         ("greedy + nlp's buildable polish (not used)", polished)]:
            missed = rules_missed(pf.problem, r)
            rows.append([name, label, r.status, f"{10 * r.metrics['rmse']:.4f}", f"{10 * r.metrics['max_error']:.4f}",
                         f"{r.solve_time_s:.2f}", int((r.routing.lam != 1.0).sum()), "yes" if not missed else f"no ({len(missed)} rules)"])
        print(rows[-7:], flush=True)
    return "\n".join([
        BUILDABLE_HEAD, "",
        f"Machine: {machine()}", "",
        "`vine-nlp compare`'s runs, one `pipeline.run` per problem from cold (solvers built in the call): `nlp` the "
        "buildable design (its time from the free design's start), `nlp_free` the free design it starts from, "
        "`greedy` the paper's greedy, `greedy_buildable` the greedy again with the lambda bounds of the classes its own "
        "design bends for (methods.buildable.classify on its chain_bends; the line turned only on the last straight "
        "segment before each actuated piece, then unwound; its time from the free greedy's start). The last two rows "
        "are the alternatives not taken: the greedy with the classes the nlp starts from (classify on the target's "
        "bends; its own time), and the nlp's buildable design started from the greedy's routing (time: the greedy's "
        "plus its own). Errors in mm; "
        "`actuated`: segments with lambda != 1; `buildable`: the rules (methods.buildable.missed) met. Load average "
        f"(1 min) at the start and the end: {load_start[0]:.1f} and {os.getloadavg()[0]:.1f} (a shared machine).", "",
        table(["case", "run", "status", "RMSE", "max", "time [s]", "actuated", "buildable"], rows),
    ])


if __name__ == "__main__":
    if "--buildable" in sys.argv[1:]:  # only this section: the rest of the file as it was measured
        old = (ROOT / "results/benchmarks/compare.md").read_text()
        write_section("compare", old.split(BUILDABLE_HEAD)[0].rstrip() + "\n\n" + buildable_section())
    else:
        main()
