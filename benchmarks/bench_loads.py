"""Design under self-weight and payload (issue 45): the time of a design with [load] against the same design
without it, on the bundled reach (problems/load-reach.toml) and the paper's s-curve (bezier-c) laid flat with a
load whose pressure is 3 % below what its design on the target needs (so the load rows are active).

    python3 benchmarks/bench_loads.py        # -> results/benchmarks/loads.md
"""

from __future__ import annotations

import dataclasses
import statistics
import time

from common import ROOT, table, write_report

from vine_nlp.analysis.loads import load_report
from vine_nlp.io.problems import load_problem
from vine_nlp.pipeline import run
from vine_nlp.problem import Load

REPEATS = 3  # after one warm-up run of each (solvers built, compiled code cached)


def _timed(pf) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = run(pf)
    return time.perf_counter() - t0, out


def cases():
    reach = load_problem(ROOT / "problems" / "load-reach.toml")
    yield "load-reach (8 kPa)", reach
    s = load_problem(ROOT / "problems" / "bezier-c.toml")
    base = Load(pressure=1.0, mass_per_length=0.01, tip_mass=0.005, safety=1.5)
    free = run(dataclasses.replace(s, problem=dataclasses.replace(s.problem, load=None))).runs["nlp"]
    need = load_report(free.routing, s.problem.diameter, s.units, base)["min_pressure"]
    load = dataclasses.replace(base, pressure=round(0.97 * need, 3))
    yield f"bezier-c, flat ({load.pressure:g} kPa; needs {need:.3g} on the target)", dataclasses.replace(s, problem=dataclasses.replace(s.problem, load=load))


def main() -> None:
    rows = []
    for name, pf in cases():
        without = dataclasses.replace(pf, problem=dataclasses.replace(pf.problem, load=None))
        times = {"with": [], "without": []}
        for k in range(REPEATS + 1):
            for key, p in (("without", without), ("with", pf)):
                t, out = _timed(p)
                if k:
                    times[key].append(t)
                if key == "with":
                    r = out.runs["nlp"]
        t1, t0 = statistics.median(times["with"]), statistics.median(times["without"])
        rows.append([name, f"{t0:.2f}", f"{t1:.2f}", f"{t1 / t0:.2f}", r.method, r.stats.get("load_rounds", 0),
                     f"{r.stats.get('start_load_margin', float('nan')):.3f}", f"{r.metrics['load_margin']:.3f}",
                     f"{r.stats.get('start_rmse', r.metrics['rmse']):.4g} -> {r.metrics['rmse']:.4g} {pf.units}", "yes" if out.ok else "no"])
        print(rows[-1])
    write_report("loads", "Design under self-weight and payload",
                 f"The pipeline's design (vine-nlp design) of each problem with its [load] and without it; median of {REPEATS} runs "
                 "after a warm-up of each. The design with [load] is the design without it, then, where that one does not stand "
                 "with the safety factor, a re-solve with the load rows from it (methods.loads). A shared machine (other jobs "
                 "running): compare the ratios, not the seconds.",
                 table(["problem", "without [load], s", "with [load], s", "ratio", "run nlp", "load rounds", "margin on target",
                        "margin", "RMSE", "ok"], rows))


if __name__ == "__main__":
    main()
