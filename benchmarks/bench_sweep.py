"""Sweep benchmark: the paper's 125-knot trefoil study as one NLP per knot.

    python benchmarks/bench_sweep.py [--workers 2] [--subset 10] [--keep DIR]

1. the whole sweep (problems/sweeps/trefoil125.toml, nlp) into a temporary
   directory with ``--workers`` local processes, best of ``--full-repeat`` runs
   from cold: wall time, items/s, CPU time, mean and worst RMSE in mm, the knots
   worse than 0.3 mm;
2. throughput on the same ``--subset`` items with 1 worker (in this process),
   2 local worker processes and a dask LocalCluster of 2 single-thread worker
   processes, best of ``--repeat`` runs each (wall times include starting the
   worker processes and building the solver).

Writes results/benchmarks/sweep.md and results/figures/sweep-trefoil125.png.
Goals (2-core machine): whole sweep <= 60 s wall, mean RMSE <= 0.1 mm, worst <= 0.3 mm.
Paper (greedy Algorithm 1, MATLAB): mean 0.65 mm, worst 1.57 mm, 157 s per knot.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import shutil
import sys
import tempfile
from pathlib import Path

from common import FIGURES, ROOT, machine, table, write_section

from vine_nlp.front.sweep import format_report, method_stats, plot_summary, run_sweep
from vine_nlp.io.problem_file import load_sweep

SWEEP = ROOT / "problems" / "sweeps" / "trefoil125.toml"
GOAL_WALL_S, GOAL_MEAN_MM, GOAL_WORST_MM = 60.0, 0.1, 0.3
PAPER = "mean 0.65 mm, worst 1.57 mm, 157 s per knot (greedy Algorithm 1, MATLAB)"


def _load() -> str:
    try:
        return " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "?"


def _subset(sweep, count):
    items = sweep.items()
    step = max(1, len(items) // count)
    return dataclasses.replace(sweep, _items=items[::step][:count])


def _throughput(sweep, root: Path, label: str, **kw):
    report = run_sweep(sweep, root / label, progress=False, **kw)
    assert report.failed == 0, format_report(report)
    return report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--subset", type=int, default=25)
    ap.add_argument("--full-repeat", type=int, default=2, help="runs of the whole sweep; the best wall time counts")
    ap.add_argument("--repeat", type=int, default=2, help="subset runs per executor; the best counts")
    ap.add_argument("--keep", metavar="DIR", help="also copy the full sweep's output here")
    args = ap.parse_args(argv)

    sweep = load_sweep(SWEEP)
    load_before = _load()
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        root = Path(tmp)
        # ---- 1. the whole sweep, --full-repeat times from cold (the machine is shared: the best wall counts)
        fulls = []
        for k in range(args.full_repeat):
            fulls.append(run_sweep(sweep, root / f"full-{k}", workers=args.workers, progress=True))
            print(format_report(fulls[-1]))
        full = min(fulls, key=lambda r: r.wall_time_s)
        # the designs do not depend on timing: every repeat gives the same errors
        assert all([r["rmse"] for r in f.rows] == [r["rmse"] for r in full.rows] for f in fulls)
        if args.keep:
            shutil.copytree(full.out_dir, args.keep, dirs_exist_ok=True)
        FIGURES.mkdir(parents=True, exist_ok=True)
        figure = plot_summary(full.rows, FIGURES / "sweep-trefoil125.png", title="trefoil125, nlp")

        # ---- 2. throughput on a subset, the same items for every executor; best of --repeat
        # (the machine is shared), every repeat from cold: new processes, solvers built again
        part = _subset(sweep, args.subset)
        from vine_nlp.design.transcription import clear_caches

        def local(workers, label):
            if workers <= 1:
                clear_caches()  # the in-process run pays for its solver build like the others
            return _throughput(part, root, label, workers=workers)

        def on_dask(label):
            from dask.distributed import LocalCluster

            with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
                return _throughput(part, root, label, scheduler=cluster.scheduler_address)

        executors = [("1 worker (in process)", lambda k: local(1, f"w1-{k}")),
                     ("2 local worker processes", lambda k: local(2, f"w2-{k}"))]
        if importlib.util.find_spec("distributed") is not None:
            executors.append(("dask LocalCluster, 2 workers", lambda k: on_dask(f"dask-{k}")))
        else:
            print("dask.distributed not installed: no cluster run", file=sys.stderr)
        best = {}
        for k in range(args.repeat):
            for name, run in executors:
                r = run(k)
                if name not in best or r.wall_time_s < best[name].wall_time_s:
                    best[name] = r
        runs = list(best.items())
    load_after = _load()

    s = method_stats(full.rows)["nlp"]
    rows = sorted(full.rows, key=lambda r: r["item"])
    bad = [r for r in rows if r["rmse"] is None or r["rmse"] * 10 > GOAL_WORST_MM]
    scale_keys = [k for k in sweep.grid]

    def ok(flag):
        return "yes" if flag else "**no**"

    text = [
        "## Sweep: the paper's 125 trefoil knots",
        "",
        f"Machine: {machine()}. Load average (1/5/15 min) before {load_before}, after {load_after} "
        "(the machine is shared: other jobs ran at the same time).",
        "",
        f"`python benchmarks/bench_sweep.py`: `problems/sweeps/trefoil125.toml` (m_x, m_y, m_z each in 2..6 cm, "
        f"400 points, n = 10, D = 2.43 cm), method nlp, {full.executor}. Paper: {PAPER}.",
        "",
        table(
            ["quantity", "measured", "goal", "met"],
            [
                ["wall time, 125 knots", f"{full.wall_time_s:.1f} s (best of {len(fulls)}: "
                 f"{', '.join(f'{f.wall_time_s:.1f}' for f in fulls)} s)", f"<= {GOAL_WALL_S:.0f} s",
                 ok(full.wall_time_s <= GOAL_WALL_S)],
                ["throughput", f"{full.items_per_s:.2f} items/s", "", ""],
                ["work in the workers", f"{full.item_wall_s:.1f} s wall, {full.item_cpu_s:.1f} s CPU "
                 f"(CPU / {args.workers} workers = {full.item_cpu_s / args.workers:.1f} s)", "", ""],
                ["mean RMSE", f"{s['rmse_mean']:.3f} mm", f"<= {GOAL_MEAN_MM} mm", ok(s["rmse_mean"] <= GOAL_MEAN_MM)],
                ["worst RMSE", f"{s['rmse_max']:.3f} mm ({s['worst_item']})", f"<= {GOAL_WORST_MM} mm", ok(s["rmse_max"] <= GOAL_WORST_MM)],
                ["worst max error", f"{s['max_error_max']:.3f} mm", "", ""],
                ["converged", f"{s['converged']}/{s['count']} ({full.failed} failed)", "", ""],
                ["IPOPT solve time per knot", f"median {s['time_median']:.2f} s (paper: 157 s), sum {s['time_total']:.1f} s", "", ""],
            ],
        ),
        "",
    ]
    if bad:
        text += [
            f"Knots with RMSE above {GOAL_WORST_MM} mm:",
            "",
            table(
                ["item", *(k.replace("target.", "") for k in scale_keys), "status", "RMSE [mm]", "max error [mm]", "iterations"],
                [
                    [r["item"], *(r[k] for k in scale_keys), r["status"],
                     "" if r["rmse"] is None else f"{r['rmse'] * 10:.3f}",
                     "" if r["max_error"] is None else f"{r['max_error'] * 10:.3f}", r["iterations"]]
                    for r in bad
                ],
            ),
            "",
        ]
    base = runs[0][1].items_per_s
    text += [
        f"Throughput on the same {len(part.items())} knots (every {max(1, 125 // args.subset)}th), best of {args.repeat} "
        "runs each; wall times include starting the worker processes (not the dask cluster) and building the solver "
        "once per worker:",
        "",
        table(
            ["executor", "wall [s]", "items/s", "speed-up", "CPU in workers [s]"],
            [[name, f"{r.wall_time_s:.1f}", f"{r.items_per_s:.2f}", f"{r.items_per_s / base:.2f}x", f"{r.item_cpu_s:.1f}"]
             for name, r in runs],
        ),
        "",
        f"Figure: `{figure.relative_to(ROOT)}`.",
        "",
        "Wall times on a loaded machine stretch with the load; the CPU seconds do not: CPU / workers is "
        "the wall time the sweep would take with both cores to itself (plus about 1 s to start the workers).",
    ]
    path = write_section("sweep", "\n".join(text))
    print("\n".join(text))
    print(f"-> {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
