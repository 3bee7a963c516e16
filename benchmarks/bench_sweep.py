"""Sweep benchmark: the paper's 125-knot trefoil study, and a 1000-knot study at 1 against 2 workers.

    python benchmarks/bench_sweep.py [--study 125|1000|all] [--workers 2] [--repeat 3] [--baseline REF]
                                     [--no-executors] [--keep DIR]

``--study 1000`` (issue 36): the trefoil grid of problems/sweeps/trefoil125.toml refined to
10 x 10 x 10 scales (m_x, m_y, m_z each in 2..6 cm), compiled functions cached; a fresh process
runs ``load_sweep`` + ``run_sweep`` as ``vine-nlp sweep`` does, at 1 worker (in the process) and
at 2 worker processes, alternating, ``--repeat`` times each (with ``--baseline``: the same for
the sweep code at REF too). Recorded: the wall time of each run, the speed-up, and the parent
process's own CPU time per item (all its threads: between its first and last finished item,
and over the whole run_sweep including the summary and the figure). Each study rewrites its own
part of results/benchmarks/sweep.md; the other part is kept.

The 125-knot study (the default, ``--study 125``):

1. The real command, ``vine-nlp sweep problems/sweeps/trefoil125.toml --workers 2 -o FRESH``,
   from command start to summary.csv written (its last write, from its mtime) and to the
   command's end (summary.png written), ``--repeat`` runs each, before and after in the
   same run: "before" is this checkout with src/vine_nlp/front/sweep/ as in ``--baseline``
   (default HEAD), "after" the working tree, the runs alternating. The CPU seconds of the
   whole process tree (command, workers, forkserver: this script is their subreaper, so
   every descendant is waited for) are recorded beside the wall time: on a shared machine
   the wall time stretches with the load, the CPU time much less.
2. Where the time goes (the working tree): interpreter and command-line imports, reading
   the sweep file, what a worker imports before its first item (a forkserver or spawned
   worker; a forked one pays nothing), the solver builds, the items in the workers against
   IPOPT's own time, writing the 125 archives and summary.csv, the summary figure.
3. Unless ``--no-executors``: throughput on ``--subset`` items with 1 worker (in this
   process), 2 local worker processes and a dask LocalCluster of 2 single-thread worker
   processes, best of 2 runs each (in-process ``run_sweep``).

Writes results/benchmarks/sweep.md and results/figures/sweep-trefoil125.png.
Goals (issue 18, 2-core machine): command start to summary <= 5 s on 2 workers; mean and
worst RMSE no worse than before (0.046 / 0.162 mm).
Paper (greedy Algorithm 1, MATLAB): mean 0.65 mm, worst 1.57 mm, 157 s per knot.
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import importlib.util
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import FIGURES, ROOT, SECTIONS, machine, table, write_section

from vine_nlp.front.sweep import format_report, method_stats, read_summary, run_sweep
from vine_nlp.io.problem_file import load_sweep

SWEEP = ROOT / "problems" / "sweeps" / "trefoil125.toml"
SWEEP_PKG = Path("src") / "vine_nlp" / "front" / "sweep"
# what "before" takes from --baseline: the sweep package, the archive writer and sweep files, the plain NLP
BASELINE_PATHS = (SWEEP_PKG, Path("src/vine_nlp/io/archive.py"), Path("src/vine_nlp/io/sweep_file.py"),
                  Path("src/vine_nlp/methods/nlp.py"), Path("src/vine_nlp/methods/common.py"))
GOAL_WALL_S = 5.0
BEFORE_MEAN_MM, BEFORE_WORST_MM = 0.046, 0.162  # issue 18: "no worse than today"
PAPER = "mean 0.65 mm, worst 1.57 mm, 157 s per knot (greedy Algorithm 1, MATLAB)"
_PR_SET_CHILD_SUBREAPER = 36


def _load() -> str:
    try:
        return " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "?"


def _subreaper() -> bool:
    """Orphaned descendants (a forkserver and its workers) become our children: their CPU time is counted."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _reap(deadline_s: float = 30.0) -> None:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            time.sleep(0.01)  # a forkserver ends right after the command: bounded wait for that event


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _baseline_tree(ref: str, root: Path) -> Path:
    """A copy of src/ with BASELINE_PATHS as in ``ref`` (everything else as in the working tree)."""
    src = root / "src"
    shutil.copytree(ROOT / "src", src, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for rel in BASELINE_PATHS:
        names = subprocess.run(["git", "ls-tree", "-r", "--name-only", f"{ref}", "--", rel.as_posix()], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.split()
        if (ROOT / rel).is_dir():
            shutil.rmtree(root / rel)
            (root / rel).mkdir()
        for name in names:
            text = subprocess.run(["git", "show", f"{ref}:{name}"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
            (root / name).write_text(text)
    return src


def _cli() -> list[str]:
    exe = Path(sys.executable).with_name("vine-nlp")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "vine_nlp"]


def run_cli(src: Path, out: Path, workers: int) -> dict:
    """One ``vine-nlp sweep`` into the fresh directory ``out``, with ``src`` first on the path."""
    env = dict(os.environ, PYTHONPATH=str(src))
    env.pop("VINE_NLP_TEST_HOLD", None)
    load = os.getloadavg()[0]
    cpu0 = _children_cpu()
    t0_epoch = time.time()
    t0 = time.perf_counter()
    proc = subprocess.run([*_cli(), "sweep", str(SWEEP), "-o", str(out), "--workers", str(workers)],
                          env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    _reap()
    cpu = _children_cpu() - cpu0
    if proc.returncode != 0:
        raise SystemExit(f"vine-nlp sweep failed ({proc.returncode}):\n{proc.stderr}")
    rows = read_summary(out / "summary.csv")
    s = method_stats(rows)["nlp"]
    m = re.search(r"items took ([\d.]+) s in the workers \(([\d.]+) s CPU\)", proc.stdout)
    archives = sorted(out.glob("*.h5"))
    return {
        "wall_s": wall,
        "summary_s": (out / "summary.csv").stat().st_mtime - t0_epoch,
        "png_s": (out / "summary.png").stat().st_mtime - t0_epoch,
        "cpu_s": cpu,
        "items_cpu_s": float(m.group(2)) if m else float("nan"),
        "items_wall_s": float(m.group(1)) if m else float("nan"),
        "load": load,
        "rows": rows,
        "stats": s,
        "archives": archives,
        "stdout": proc.stdout,
    }


def _fresh_python(code: str, src: Path, repeat: int = 3) -> tuple[float, float]:
    """Best wall and CPU seconds of a fresh interpreter running ``code``."""
    best = (float("inf"), float("inf"))
    for _ in range(repeat):
        cpu0 = _children_cpu()
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=str(src)), check=True)
        best = (min(best[0], time.perf_counter() - t0), min(best[1], _children_cpu() - cpu0))
    return best


def _cpu(fn, *args, **kw):
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn(*args, **kw)
    return out, time.process_time() - c0, time.perf_counter() - t0


def _figure_cpu(src: Path, csv: Path, tmp: Path) -> tuple[float, float]:
    """Wall and CPU seconds of ``plot_summary`` (imports done, second call) with ``src`` first on the path."""
    code = ("import sys, time; from vine_nlp.front.sweep import plot_summary, read_summary; "
            f"rows = read_summary({str(csv)!r}); plot_summary(rows, {str(tmp / 'a.png')!r}); "
            "t, c = time.perf_counter(), time.process_time(); "
            f"plot_summary(rows, {str(tmp / 'b.png')!r}, title='sweep trefoil125'); "
            "print(time.perf_counter() - t, time.process_time() - c)")
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=str(src)),
                         capture_output=True, text=True, check=True).stdout.split()
    return float(out[0]), float(out[1])


def _write_cost(src: Path, folder: Path, tmp: Path) -> tuple[float, float]:
    """Wall and CPU seconds per archive of ``write_archive`` (``src`` first on the path) rewriting the archives of
    ``folder`` into ``tmp`` (loaded first; temporary file, fsync, rename included)."""
    code = ("import sys, time; from pathlib import Path; from vine_nlp.io.archive import load_archive, write_archive; "
            f"a = [load_archive(p) for p in sorted(Path({str(folder)!r}).glob('*.h5'))]; t = Path({str(tmp)!r}); t.mkdir(); "
            "w, c = time.perf_counter(), time.process_time(); [write_archive(t / f'{k}.h5', x) for k, x in enumerate(a)]; "
            "print((time.perf_counter() - w) / len(a), (time.process_time() - c) / len(a))")
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=str(src)),
                         capture_output=True, text=True, check=True).stdout.split()
    return float(out[0]), float(out[1])


def breakdown(after: dict, workers: int, baseline: Path | None) -> list[list[str]]:
    """Where the time of the working tree's command goes, each part measured on its own (see the module)."""
    from vine_nlp.front.sweep import write_summary
    from vine_nlp.io.archive import load_archive

    src = ROOT / "src"
    rows = []
    bare = _fresh_python("pass", src)
    cli = _fresh_python("import vine_nlp.front.cli, vine_nlp.io.problem_file, vine_nlp.front.sweep", src)
    rows.append(["interpreter start", f"{bare[0]:.2f}", f"{bare[1]:.2f}", "`python -c pass`, best of 3"])
    rows.append(["command-line imports", f"{cli[0] - bare[0]:.2f}", f"{cli[1] - bare[1]:.2f}", "what `vine-nlp sweep` imports (cli, problem files, the sweep package; numpy, casadi, h5py) beyond that"])
    _, c, w = _cpu(load_sweep, SWEEP)
    rows.append(["reading the sweep (125 problems)", f"{w:.2f}", f"{c:.2f}", "`load_sweep`, in this process (imports done)"])
    worker = _fresh_python("import vine_nlp.front.sweep.executors, vine_nlp.pipeline.runs, vine_nlp.io.problems", src)
    rows.append(["a worker's imports (forkserver/spawn)", f"{worker[0] - bare[0]:.2f}", f"{worker[1] - bare[1]:.2f}",
                 "per spawned worker; a forked worker (the default now) has them already; a forkserver imports them once"])
    archives = [load_archive(p) for p in after["archives"]]
    runs = [a.runs["nlp"] for a in archives]
    builds = [r.stats.get("build_time_s", 0.0) for r in runs]
    ipopt = sum(r.stats.get("ipopt_time_s", 0.0) for r in runs)
    rows.append(["solver builds", f"{sum(builds):.2f}", "",
                 f"{sum(b > 0 for b in builds)} builds (one per worker and Hessian variant), from the archives"])
    rows.append(["items in the workers", f"{after['items_wall_s']:.1f}", f"{after['items_cpu_s']:.1f}",
                 f"sum over items; IPOPT's own wall time {ipopt:.1f} s, solve_time_s {sum(r.solve_time_s for r in runs):.1f} s; "
                 f"CPU / {workers} workers = {after['items_cpu_s'] / workers:.1f} s"])
    with tempfile.TemporaryDirectory(prefix="bench-sweep-parts-") as tmp:
        folder = after["archives"][0].parent
        writes = {"after": [], "before": []}
        for k in range(3):  # alternating, fresh processes, best of 3
            for name in (["after", "before"] if k % 2 == 0 else ["before", "after"]):
                if name == "after" or baseline is not None:
                    writes[name].append(_write_cost(src if name == "after" else baseline, folder, Path(tmp) / f"{name}{k}"))
        for name, label in (("after", "writing the archives (workers)"), ("before", "writing the archives, before")):
            if writes[name]:
                w, c = min(writes[name])
                rows.append([label, f"{w * len(archives):.2f}", f"{c * len(archives):.2f}",
                             f"{len(archives)} archives, {1000 * w:.2f} ms wall, {1000 * c:.2f} ms CPU each (best of 3; "
                             f"write_archive{' at --baseline: in the parent' if name == 'before' else ': in the workers now'})"])
        grid = list(load_sweep(SWEEP).grid)
        _, c, w = _cpu(write_summary, Path(tmp) / "summary.csv", after["rows"], grid)
        rows.append(["summary.csv", f"{w:.3f}", f"{c:.3f}", "one write (written once, at the end)"])
        code = ("import time, sys; t = time.perf_counter(); c = time.process_time(); "
                "import matplotlib.figure, matplotlib.backends.backend_agg, matplotlib.ticker; "
                "print(time.perf_counter() - t, time.process_time() - c)")
        imp = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
        rows.append(["matplotlib imports", f"{float(imp[0]):.2f}", f"{float(imp[1]):.2f}", "now in a thread while the workers solve"])
        csv = after["archives"][0].parent / "summary.csv"
        w, c = _figure_cpu(src, csv, Path(tmp))
        rows.append(["summary figure", f"{w:.2f}", f"{c:.2f}", "`plot_summary` (Agg Figure, fixed margins), imports done"])
        if baseline is not None:
            w, c = _figure_cpu(baseline, csv, Path(tmp))
            rows.append(["summary figure, before", f"{w:.2f}", f"{c:.2f}", "the same with BASELINE_PATHS as in --baseline"])
    return rows


def _executors(args, root: Path):
    sweep = load_sweep(SWEEP)
    items = sweep.items()
    step = max(1, len(items) // args.subset)
    part = dataclasses.replace(sweep, _items=items[::step][: args.subset])
    from vine_nlp.methods.transcription import clear_caches

    def local(workers, label):
        if workers <= 1:
            clear_caches()  # the in-process run pays for its solver build like the others
        r = run_sweep(part, root / label, workers=workers, progress=False)
        assert r.failed == 0, format_report(r)
        return r

    def on_dask(label):
        from dask.distributed import LocalCluster

        with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
            return run_sweep(part, root / label, scheduler=cluster.scheduler_address, progress=False)

    executors = [("1 worker (in process)", lambda k: local(1, f"w1-{k}")),
                 ("2 local worker processes", lambda k: local(2, f"w2-{k}"))]
    if importlib.util.find_spec("distributed") is not None:
        executors.append(("dask LocalCluster, 2 workers", lambda k: on_dask(f"dask-{k}")))
    best = {}
    for k in range(2):
        for name, run in executors:
            r = run(k)
            if name not in best or r.wall_time_s < best[name].wall_time_s:
                best[name] = r
    return part, list(best.items())


def study_125(args, root: Path, variants: dict, reaper: bool) -> str:
    """The 125-knot study from the command line (module docstring, 1-3); the section's text."""
    load_before = _load()
    runs = {name: [] for name in variants}
    for k in range(args.repeat):
        order = list(variants) if k % 2 == 0 else list(reversed(variants))
        for name in order:
            r = run_cli(variants[name], root / f"{name}-{k}", args.workers)
            runs[name].append(r)
            print(f"{name} #{k}: {r['wall_s']:.1f} s wall (summary at {r['summary_s']:.1f} s), "
                  f"{r['cpu_s']:.1f} s CPU, load {r['load']:.1f}", flush=True)
    best = {name: min(rs, key=lambda r: r["wall_s"]) for name, rs in runs.items()}
    after = best["after"]
    for name, rs in runs.items():  # a variant's designs do not depend on timing
        assert all([x["rmse"] for x in r["rows"]] == [x["rmse"] for x in best[name]["rows"]] for r in rs), name
    if args.keep:
        shutil.copytree(after["archives"][0].parent, args.keep, dirs_exist_ok=True)
    FIGURES.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(after["archives"][0].parent / "summary.png", FIGURES / "sweep-trefoil125.png")
    parts = breakdown(after, args.workers, variants.get("before"))
    executors = None if args.no_executors else _executors(args, root)
    load_after = _load()
    ok = _ok

    def walls(rs, key):
        return ", ".join(f"{r[key]:.1f}" for r in rs)

    s = after["stats"]
    rows = []
    for name, rs in runs.items():
        b = best[name]
        label = f"before (BASELINE_PATHS at {args.baseline})" if name == "before" else "after (working tree)"
        rows.append([label, f"{b['summary_s']:.1f} ({walls(rs, 'summary_s')})", f"{b['wall_s']:.1f} ({walls(rs, 'wall_s')})",
                     f"{statistics.median(r['cpu_s'] for r in rs):.1f}", f"{statistics.median(r['items_cpu_s'] for r in rs):.1f}",
                     f"{statistics.median(r['cpu_s'] - r['items_cpu_s'] for r in rs):.1f}",
                     f"{statistics.median(r['wall_s'] - r['summary_s'] for r in rs):.1f}",
                     f"{statistics.median(r['load'] for r in rs):.1f}",
                     f"{b['stats']['rmse_mean']:.4f} / {b['stats']['rmse_max']:.4f}"])
    text = [
        "## Sweep: the paper's 125 trefoil knots",
        "",
        f"Machine: {machine()}. Load average (1/5/15 min) before {load_before}, after {load_after} "
        "(the machine is shared: other jobs ran at the same time).",
        "",
        f"`python benchmarks/bench_sweep.py`: `vine-nlp sweep problems/sweeps/trefoil125.toml --workers {args.workers} -o FRESH` "
        "(m_x, m_y, m_z each in 2..6 cm, 400 points, n = 10, D = 2.43 cm, method nlp), from command start; "
        f"{args.repeat} runs per variant, alternating, the best wall time shown first. CPU: the whole process tree "
        f"(command, workers, forkserver{'' if reaper else '; no subreaper here: orphans not counted'}). "
        f"Paper: {PAPER}.",
        "",
        table(["variant", "to summary.csv [s]", "to command end [s]", "CPU, all processes [s]", "CPU in items [s]",
               "CPU outside items [s]", "summary.csv to end [s]", "load (1 min)", "RMSE mean / worst [mm]"], rows),
        "",
        "Best run first, every run in brackets; CPU and the last two columns: medians over the runs. \"CPU outside "
        "items\" is everything but solve_item's own work: interpreter, imports, reading the sweep, starting the "
        "workers, sending items and results, writing archives and the summary, the figure.",
        "",
        table(
            ["quantity", "measured", "goal", "met"],
            [
                ["command start to summary (after)", f"{after['summary_s']:.1f} s (command end {after['wall_s']:.1f} s)",
                 f"<= {GOAL_WALL_S:.0f} s", ok(after["summary_s"] <= GOAL_WALL_S)],
                ["mean RMSE", f"{s['rmse_mean']:.4f} mm", f"<= {BEFORE_MEAN_MM} mm (before)", ok(round(s["rmse_mean"], 3) <= BEFORE_MEAN_MM)],
                ["worst RMSE", f"{s['rmse_max']:.4f} mm ({s['worst_item']})", f"<= {BEFORE_WORST_MM} mm (before)",
                 ok(round(s["rmse_max"], 3) <= BEFORE_WORST_MM)],
                ["worst max error", f"{s['max_error_max']:.3f} mm", "", ""],
                ["converged", f"{s['converged']}/{s['count']}", "", ""],
                ["solve time per knot", f"median {s['time_median']:.3f} s, sum {s['time_total']:.1f} s", "", ""],
            ],
        ),
        "",
        "\"before\" and \"after\" differ in BASELINE_PATHS only (front/sweep/, io/archive.py, io/sweep_file.py, "
        f"methods/nlp.py, methods/common.py at {args.baseline} against the working tree). The items' CPU (now with their archives, written by "
        "the workers) is most of the command's: on 2 cores the command takes about (CPU in items + the parent's "
        "imports and figure) / 2 plus the serial start and the last items; see the CPU columns.",
        "",
        "Where the time goes (working tree; each part measured on its own, wall and CPU seconds):",
        "",
        table(["part", "wall [s]", "CPU [s]", "note"], parts),
        "",
    ]
    if executors is not None:
        part, ex = executors
        base = ex[0][1].items_per_s
        text += [
            f"Throughput on {len(part.items())} of the knots (every {max(1, 125 // args.subset)}th), `run_sweep` in "
            "this process, best of 2 runs each; wall times include starting the worker processes (not the dask "
            "cluster) and building the solver once per worker:",
            "",
            table(["executor", "wall [s]", "items/s", "speed-up", "CPU in workers [s]"],
                  [[name, f"{r.wall_time_s:.1f}", f"{r.items_per_s:.2f}", f"{r.items_per_s / base:.2f}x", f"{r.item_cpu_s:.1f}"]
                   for name, r in ex]),
            "",
        ]
    text += [
        f"Figure: `{(FIGURES / 'sweep-trefoil125.png').relative_to(ROOT)}`.",
        "",
        "Wall times on a loaded machine stretch with the load; the CPU seconds much less. With the machine to "
        f"itself, the command takes about max(CPU in items / {args.workers}, ...) plus the serial parts above "
        "(interpreter, imports, reading the sweep, the last items, the figure).",
    ]
    return "\n".join(text)


# ---------------------------------------------------------------- the 1000-knot study (issue 36)

SCALES_1000 = [2 + 4 * k / 9 for k in range(10)]  # m_x, m_y, m_z each in 2..6 cm, 10 values
GOAL_SPEEDUP, GOAL_PARENT_MS = 1.7, 1.0
# a fresh process: load_sweep + run_sweep as `vine-nlp sweep` runs them; the parent's own CPU (all its threads)
# is read at each finished item (the callback) and around run_sweep
DRIVER = """
import json, sys, time
from vine_nlp.methods import blas
blas.own_process()
from vine_nlp.front.sweep import run_sweep
from vine_nlp.io.problem_file import load_sweep
marks = []
t0, c0 = time.perf_counter(), time.process_time()
r = run_sweep(load_sweep(sys.argv[1]), sys.argv[2], workers=int(sys.argv[3]), progress=False,
              callback=lambda item, rows: marks.append(time.process_time()))
print(json.dumps({"sweep_s": time.perf_counter() - t0, "sweep_cpu_s": time.process_time() - c0,
                  "steady_cpu_s": marks[-1] - marks[0], "n": len(marks), "failed": r.failed,
                  "rmse": [row["rmse"] for row in r.rows], "items_cpu_s": r.item_cpu_s}))
"""


def _sweep_1000(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    scales = ", ".join(repr(v) for v in SCALES_1000)
    base = (ROOT / "problems" / "trefoil-m4.toml").as_posix()
    path = folder / "trefoil1000.toml"
    path.write_text(f'name = "trefoil1000"\nbase = "{base}"\nmethods = ["nlp"]\n[grid]\n'
                    + "".join(f'"target.scale.{k}" = [{scales}]\n' for k in range(3)))
    return path


def _run_1000(src: Path, sweep: Path, out: Path, workers: int) -> dict:
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(sweep), str(out), str(workers)],
                          env=dict(os.environ, PYTHONPATH=str(src)), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    _reap()
    if proc.returncode != 0:
        raise SystemExit(f"the 1000-knot sweep failed ({proc.returncode}):\n{proc.stderr}")
    r = __import__("json").loads(proc.stdout.splitlines()[-1])
    assert r["failed"] == 0 and r["n"] == 1000, r
    shutil.rmtree(out)
    return {**r, "wall_s": wall, "load": load}


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return f"load average {_load()}"


def study_1000(args, root: Path, variants: dict) -> str:
    """1 against 2 workers on the 1000-knot study, alternating (module docstring); the section's text."""
    sweep = _sweep_1000(root / "in1000")
    uptime_before = _uptime()
    configs = [(name, w) for name in variants for w in (1, args.workers)]
    runs = {c: [] for c in configs}
    for k in range(args.repeat):
        for name, w in configs if k % 2 == 0 else list(reversed(configs)):
            r = _run_1000(variants[name], sweep, root / f"o1000-{name}-{w}-{k}", w)
            runs[(name, w)].append(r)
            print(f"1000 knots, {name}, {w} worker(s) #{k}: {r['wall_s']:.1f} s, parent "
                  f"{1000 * r['steady_cpu_s'] / (r['n'] - 1):.2f} ms CPU per item, load {r['load']:.1f}", flush=True)
    uptime_after = _uptime()
    rmse = {c: rs[0]["rmse"] for c, rs in runs.items()}
    same = all(v == rmse[configs[0]] for v in rmse.values())  # the designs do not depend on the executor
    rows, summary = [], []
    for name in variants:
        one, two = runs[(name, 1)], runs[(name, args.workers)]
        best1, best2 = min(r["wall_s"] for r in one), min(r["wall_s"] for r in two)
        med1, med2 = statistics.median(r["wall_s"] for r in one), statistics.median(r["wall_s"] for r in two)
        for w, rs in ((1, one), (args.workers, two)):
            steady = statistics.median(1000 * r["steady_cpu_s"] / (r["n"] - 1) for r in rs)
            total = statistics.median(1000 * r["sweep_cpu_s"] / r["n"] for r in rs)
            every = ", ".join(f"{r['wall_s']:.1f}" for r in rs)
            rows.append([name, str(w), f"{min(r['wall_s'] for r in rs):.1f} ({every})",
                         f"{steady:.2f}", f"{total:.2f}", f"{statistics.median(r['items_cpu_s'] for r in rs):.1f}",
                         f"{statistics.median(r['load'] for r in rs):.1f}"])
        summary.append((name, best1 / best2, med1 / med2, statistics.median(1000 * r["steady_cpu_s"] / (r["n"] - 1) for r in two)))
    after = next(x for x in summary if x[0] == "after")
    label = "before = BASELINE_PATHS at " + str(args.baseline) + "; " if "before" in variants else ""
    text = [
        f"## Sweep: 1000 trefoil knots, 1 against {args.workers} workers",
        "",
        f"Machine: {machine()}. `uptime` before: `{uptime_before}`; after: `{uptime_after}` (the machine is shared: "
        "other jobs ran at the same time; a quiet machine gives the figures that count).",
        "",
        "`python benchmarks/bench_sweep.py --study 1000`: the trefoil grid of problems/sweeps/trefoil125.toml refined "
        "to 10 x 10 x 10 scales (m_x, m_y, m_z each 2..6 cm; 400 points, n = 10, method nlp), compiled functions "
        f"cached; a fresh process runs load_sweep + run_sweep as `vine-nlp sweep` does, at 1 worker (in the process) "
        f"and {args.workers} worker processes, alternating, {args.repeat} runs each ({label}after = the working tree). "
        "Parent CPU per item: the sweep process's own CPU time (all its threads), between its first and last finished "
        "item (steady), and over the whole run_sweep with the summary and the figure (total); at 1 worker it is the "
        "items themselves.",
        "",
        table(["variant", "workers", "wall [s] (every run)", "parent CPU per item, steady [ms]",
               "parent CPU per item, total [ms]", "CPU in items [s]", "load (1 min)"], rows),
        "",
        table(["variant", f"speed-up {args.workers} : 1 (best walls)", "(median walls)", "parent CPU per item [ms]"],
              [[n, f"{b:.2f}x", f"{m:.2f}x", f"{c:.2f}"] for n, b, m, c in summary]),
        "",
        table(["quantity", "measured", "goal", "met"], [
            [f"{args.workers} workers against 1 (after, best walls)", f"{after[1]:.2f}x", f">= {GOAL_SPEEDUP}x", _ok(after[1] >= GOAL_SPEEDUP)],
            ["parent CPU per item (after, steady)", f"{after[3]:.2f} ms", f"<= {GOAL_PARENT_MS} ms", _ok(after[3] <= GOAL_PARENT_MS)],
            ["same designs at every worker count and variant", "yes" if same else "**no**", "yes", _ok(same)],
        ]),
    ]
    return "\n".join(text)


def _ok(flag) -> str:
    return "yes" if flag else "**no**"


def _write_parts(parts: dict) -> Path:
    """results/benchmarks/sweep.md: the studies run now replace their part, the others are kept."""
    old = (SECTIONS / "sweep.md").read_text() if (SECTIONS / "sweep.md").exists() else ""
    kept = {}
    for chunk in filter(str.strip, old.split("\n## ")):
        chunk = chunk if chunk.startswith("## ") else "## " + chunk
        kept["1000" if "1000 trefoil knots" in chunk.splitlines()[0] else "125"] = chunk.rstrip()
    kept.update(parts)
    return write_section("sweep", "\n\n".join(kept[k] for k in ("125", "1000") if k in kept))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", choices=("125", "1000", "all"), default="125")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="runs per variant; the best wall time counts")
    ap.add_argument("--baseline", metavar="REF", help="git ref of BASELINE_PATHS for 'before' runs (default: none)")
    ap.add_argument("--no-executors", action="store_true", help="skip the executor comparison on a subset")
    ap.add_argument("--subset", type=int, default=25)
    ap.add_argument("--keep", metavar="DIR", help="also copy the working tree's sweep output here")
    args = ap.parse_args(argv)

    reaper = _subreaper()
    parts = {}
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        root = Path(tmp)
        variants = {"after": ROOT / "src"}
        if args.baseline:
            variants = {"before": _baseline_tree(args.baseline, root / "baseline"), **variants}
        # caches every variant shares (compiled NLP functions on disk) are made before the first timed run
        from vine_nlp.front.sweep import solve_item

        solve_item(load_sweep(SWEEP).items()[0][2], ["nlp"])
        if args.study in ("125", "all"):
            parts["125"] = study_125(args, root, variants, reaper)
        if args.study in ("1000", "all"):
            parts["1000"] = study_1000(args, root, variants)
    path = _write_parts(parts)
    print("\n\n".join(parts.values()))
    print(f"-> {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
