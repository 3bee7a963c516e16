"""Design sweeps (../shared/spec/formats.md, "Sweep files"): many design problems, one archive per item.

``run_sweep(load_sweep(path), out_dir)`` solves every item of a sweep with every
method it lists and writes

* ``DIR/<item>.h5``: one result archive per item, all its methods as runs
  (``/runs/nlp``, ``/runs/greedy``), written atomically as soon as the item
  finishes, so results stream to disk;
* ``DIR/summary.csv``: one row per item and method, columns ``item``, each grid
  key, ``method``, ``status``, ``rmse``, ``max_error``, ``solve_time_s`` (the
  spec's), then ``iterations``, ``units`` and ``error`` (the exception text of a
  failed run). Rewritten atomically after every finished item (on sweeps so
  large that the rewrite itself takes a while, at most 5% of the time goes to
  it): an interrupted sweep leaves a valid summary of what finished. Rows follow the grid order;
  numbers are written with full precision (``repr``), missing ones as empty cells;
* ``DIR/summary.png``: RMSE and solve-time distributions and NLP against greedy
  item by item (:func:`plot_summary`).

Execution. The worker task is the top-level function :func:`solve_item`; it
returns Results and the parent writes every file, so a cluster needs no shared
filesystem. Three executors share one code path (a small adapter: ``submit``,
``wait_first``, ``cancel``, ``close``):

* ``workers`` > 1 (default ``os.cpu_count()``): a ``ProcessPoolExecutor``
  (forkserver or spawn: no fork of a process that already runs casadi threads)
  whose worker processes live for the whole sweep, so each builds a solver once
  per problem structure (``design.nlp.get_solver`` is an lru_cache) and reuses
  it for every later item. Items are submitted grouped by structure. At most
  ``workers`` items are in flight, so when a worker process dies (a crash in a
  native library, the OOM killer) the suspects are known: they are retried one
  at a time in a fresh pool, and the item that kills its worker alone is failed;
* ``workers`` 0 or 1: in this process, one item after the other;
* ``scheduler`` ADDRESS: ``dask.distributed.Client(ADDRESS)``; dask workers are
  long-lived processes too, so the solver cache works the same way there. The
  workers need vine_nlp installed (the same version), nothing else.

Resume. An item whose archive exists, loads, was made from the same problem
source and holds a run of every method is skipped (its rows are rebuilt from the
archive). An archive from the same source missing some method keeps its runs and
only the missing methods are solved. An archive that does not load or comes from
another source (the base file or the grid changed) is redone and replaced.
``force=True`` redoes everything.

Failures. A method that raises fails only its own row (status ``failed``, the
exception text in ``error``); the item's other methods are kept and archived. An
item whose every method failed has no archive (a stale one is removed). Nothing
that happens to one item stops the others. Solver statuses such as ``max_iter``
are not failures: the run is archived with that status.

Ctrl-C (KeyboardInterrupt): pending items are cancelled, running ones are
stopped (local worker processes are terminated), every finished archive stays
intact, the summary of what finished is written, and the KeyboardInterrupt is
re-raised with the partial :class:`SweepReport` as its ``sweep_report`` attribute.
Running the sweep again continues where it stopped.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import socket
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from vine_nlp.errors import InputError

SPEC_COLUMNS = ("method", "status", "rmse", "max_error", "solve_time_s")
EXTRA_COLUMNS = ("iterations", "units", "error")
SUMMARY_CSV = "summary.csv"
SUMMARY_PNG = "summary.png"
FAILED = "failed"
_CONVERGED = ("optimal", "acceptable")
_MAX_ERROR_TEXT = 500
_PARAMETER_OPTIONS = ("smooth_theta", "smooth_lambda", "seed", "method")
# Length units -> factor to millimetres, for the figure and the report.
_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


# ---------------------------------------------------------------- the worker task


def solve_item(problem_file, methods, remote: bool = False) -> tuple[dict, dict]:
    """Solve one sweep item with each of ``methods`` (runs in a worker process).

    Returns ``(runs, timings)``: ``runs`` maps each method that finished to its
    Result (a picklable dataclass); ``timings`` holds ``{"methods": {method:
    wall seconds}, "total_s", "cpu_s" (this process's CPU time for the item), "errors":
    {method: "Type: message"}, "pid", "host"}``.
    A method that raises is reported in ``timings["errors"]`` and does not stop the
    item's other methods. KeyboardInterrupt propagates, except with ``remote=True``
    (a worker process, which ignores Ctrl-C): there it can only come from a solver
    (vine_nlp.interrupt maps an exception thrown inside IPOPT to KeyboardInterrupt)
    and fails that run instead of stopping the whole sweep.
    """
    from vine_nlp import design

    runs, errors, wall = {}, {}, {}
    t_item, c_item = time.perf_counter(), time.process_time()
    for method in methods:
        t0 = time.perf_counter()
        try:
            # looked up on the module at call time: one place to replace it (tests)
            runs[method] = design.run_design(problem_file.problem, method)
        except Exception as exc:  # noqa: BLE001 - any failure of one run is that run's result
            errors[method] = _error_text(exc)
        except KeyboardInterrupt:
            if not remote:
                raise
            errors[method] = (
                "KeyboardInterrupt from the solver in a worker process, which ignores Ctrl-C "
                "(IPOPT status NonIpopt_Exception_Thrown: an exception inside the solve)"
            )
        wall[method] = time.perf_counter() - t0
    timings = {
        "methods": wall,
        "total_s": time.perf_counter() - t_item,
        "cpu_s": time.process_time() - c_item,
        "errors": errors,
        "pid": os.getpid(),
        "host": socket.gethostname(),
    }
    return runs, timings


def _error_text(exc: BaseException) -> str:
    text = " ".join(traceback.format_exception_only(type(exc), exc)).strip()
    text = " ".join(text.split())  # one line in the CSV
    return text if len(text) <= _MAX_ERROR_TEXT else text[: _MAX_ERROR_TEXT - 3] + "..."


def _worker_init():
    # Ctrl-C reaches the whole process group; only the parent handles it (it stops the workers).
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


# ---------------------------------------------------------------- executors


class _InlinePool:
    """workers 0 or 1: each item runs in this process when submitted."""

    window = 1

    def __init__(self):
        self.description = "in this process"

    def submit(self, fn, args, name):
        from concurrent.futures import Future

        fut = Future()
        try:
            fut.set_result(fn(*args, remote=False))
        except Exception as exc:  # noqa: BLE001 - like an executor: the future carries it
            fut.set_exception(exc)
        return fut

    def wait_first(self, futures):
        return [f for f in futures if f.done()]

    def cancel(self, futures):
        pass

    def close(self, interrupted=False):
        pass


class _LocalPool:
    """A ProcessPoolExecutor whose worker processes live for the whole sweep."""

    def __init__(self, workers: int):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        self.window = workers
        self.description = f"{workers} local worker processes"
        self._make = lambda: ProcessPoolExecutor(workers, mp_context=mp.get_context(method), initializer=_worker_init)
        self.executor = self._make()

    def submit(self, fn, args, name):
        from concurrent.futures import Future
        from concurrent.futures.process import BrokenProcessPool

        try:
            return self.executor.submit(fn, *args, remote=True)
        except BrokenProcessPool as exc:
            # a worker died since the last look: this item never ran, it goes back in the queue
            fut = Future()
            fut.set_exception(exc)
            fut.never_started = True
            return fut

    def wait_first(self, futures):
        from concurrent.futures import FIRST_COMPLETED, wait

        return wait(futures, return_when=FIRST_COMPLETED).done

    def restart(self):
        """A fresh pool after a worker process died (the old one is broken for good)."""
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.executor = self._make()

    def cancel(self, futures):
        for f in futures:
            f.cancel()

    def close(self, interrupted=False):
        if not interrupted:
            self.executor.shutdown(wait=True)
            return
        # Ctrl-C: do not wait for the running items (an item may take minutes).
        processes = list((getattr(self.executor, "_processes", None) or {}).values())
        self.executor.shutdown(wait=False, cancel_futures=True)
        for p in processes:
            if p.is_alive():
                p.terminate()
        for p in processes:
            p.join(timeout=5)


class _DaskPool:
    """A dask.distributed scheduler; the workers need vine_nlp installed, no shared files."""

    def __init__(self, address: str):
        try:
            from dask.distributed import Client, as_completed
        except ImportError as exc:  # pragma: no cover - dask is a dependency
            raise InputError("command line", "--scheduler", f"needs dask.distributed ({exc})") from None
        try:
            from distributed.comm import resolve_address

            # a malformed address fails here, before a Client exists (a half-made one hangs at exit)
            resolve_address(address)
            self.client = Client(address, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise InputError(address, "--scheduler", f"cannot connect to the dask scheduler ({exc})") from None
        self._completed = as_completed(loop=self.client.loop)
        self._window = (0.0, 0)
        threads = sum(self.client.nthreads().values())
        self.description = f"dask scheduler {address} ({len(self.client.nthreads())} workers, {threads} threads)"

    @property
    def window(self) -> int:
        # Keep the cluster busy without shipping the whole sweep at once; follows scaling.
        checked, size = self._window
        if time.monotonic() - checked > 5.0:
            size = max(16, 4 * sum(self.client.nthreads().values()))
            self._window = (time.monotonic(), size)
        return size

    def submit(self, fn, args, name):
        import uuid

        fut = self.client.submit(fn, *args, remote=True, key=f"solve_item-{name}-{uuid.uuid4().hex[:8]}", pure=False)
        self._completed.add(fut)
        return fut

    def wait_first(self, futures):
        return self._completed.next_batch(block=True)

    def cancel(self, futures):
        if futures:
            self.client.cancel(list(futures))

    def close(self, interrupted=False):
        self.client.close()


# ---------------------------------------------------------------- report


@dataclass
class SweepReport:
    name: str
    out_dir: Path
    total: int  # items in the sweep
    done: int = 0  # solved in this run, every method finished (archive written)
    skipped: int = 0  # finished earlier: rows rebuilt from the archive
    failed: int = 0  # solved in this run, at least one method raised
    replaced: int = 0  # existing archives that did not belong to this sweep item (redone)
    wall_time_s: float = 0.0
    item_wall_s: float = 0.0  # sum over the items solved in this run of their time in a worker
    item_cpu_s: float = 0.0  # ... and of the CPU time they used there (less than the wall on a busy machine)
    executor: str = ""
    created_dir: bool = False
    interrupted: bool = False
    summary_csv: Path | None = None
    summary_png: Path | None = None
    archives: list = field(default_factory=list)  # paths of every archive of the sweep in DIR
    rows: list = field(default_factory=list)  # summary rows (dicts), grid order
    failures: list = field(default_factory=list)  # (item, method, error)
    figure_error: str = ""

    @property
    def solved(self) -> int:
        return self.done + self.failed

    @property
    def items_per_s(self) -> float:
        return self.solved / self.wall_time_s if self.wall_time_s > 0 else 0.0

    @property
    def not_converged(self) -> int:
        return sum(1 for r in self.rows if r["status"] not in _CONVERGED and r["status"] != FAILED)


def format_report(report: SweepReport) -> str:
    """A few lines for the command line: counts, time, RMSE per method, where the files are."""
    r = report
    head = f"sweep {r.name}: {r.total} items: {r.done} solved, {r.skipped} skipped (done before), {r.failed} failed"
    if r.interrupted:
        head += f", {r.total - r.done - r.skipped - r.failed} not run (interrupted)"
    lines = [head]
    if r.solved:
        lines.append(
            f"{r.wall_time_s:.1f} s wall, {r.items_per_s:.3g} items/s, {r.executor}; "
            f"items took {r.item_wall_s:.1f} s in the workers ({r.item_cpu_s:.1f} s CPU)"
        )
    elif r.wall_time_s:
        lines.append(f"{r.wall_time_s:.1f} s wall, nothing to solve")
    if r.replaced:
        lines.append(f"{r.replaced} existing archives were from another version of the sweep and were replaced")
    for method, s in method_stats(r.rows).items():
        if not s["count"]:
            lines.append(f"{method}: no finished runs")
            continue
        u = s["units"]
        lines.append(
            f"{method}: RMSE mean {s['rmse_mean']:.3g} {u}, worst {s['rmse_max']:.3g} {u} ({s['worst_item']}), "
            f"{s['converged']}/{s['count']} converged, median solve time {s['time_median']:.3g} s"
        )
    for item, method, error in r.failures[:5]:
        lines.append(f"failed: {item} {method}: {error}")
    if len(r.failures) > 5:
        lines.append(f"... and {len(r.failures) - 5} more failed runs (see the error column)")
    created = " (created)" if r.created_dir else ""
    lines.append(f"archives -> {r.out_dir}{os.sep}<item>.h5{created}")
    if r.summary_csv:
        lines.append(f"summary -> {r.summary_csv}")
    if r.summary_png:
        lines.append(f"figure -> {r.summary_png}")
    if r.figure_error:
        lines.append(f"figure not written: {r.figure_error}")
    return "\n".join(lines)


def method_stats(rows) -> dict:
    """Per method: finished runs, converged runs, RMSE mean/worst (in mm when the units allow), median time."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        ok = [r for r in rows if r["method"] == method and r["rmse"] is not None]
        s = {"count": len(ok), "failed": sum(1 for r in rows if r["method"] == method and r["status"] == FAILED)}
        if ok:
            factor, unit = _mm(ok[0]["units"])
            rmse = [r["rmse"] * factor for r in ok]
            worst = max(range(len(ok)), key=lambda k: rmse[k])
            times = sorted(r["solve_time_s"] for r in ok)
            s.update(
                units=unit,
                rmse_mean=sum(rmse) / len(rmse),
                rmse_max=rmse[worst],
                worst_item=ok[worst]["item"],
                max_error_max=max(r["max_error"] for r in ok) * factor,
                converged=sum(1 for r in ok if r["status"] in _CONVERGED),
                time_median=times[len(times) // 2],
                time_total=sum(times),
            )
        out[method] = s
    return out


def _mm(units: str):
    factor = _TO_MM.get(units)
    return (factor, "mm") if factor else (1.0, units)


# ---------------------------------------------------------------- summary file


def summary_columns(grid_keys) -> list[str]:
    extra = [c for c in EXTRA_COLUMNS if c not in grid_keys]
    return ["item", *grid_keys, *SPEC_COLUMNS, *extra]


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (int, str)):
        return str(value)
    return json.dumps(value)


def write_summary(path, rows, grid_keys) -> None:
    """summary.csv (atomically): spec columns, then iterations, units, error."""
    from vine_nlp.io.archive import write_atomic

    columns = summary_columns(grid_keys)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in columns])
    write_atomic(path, lambda tmp: Path(tmp).write_text(buf.getvalue(), encoding="utf-8"))


def _row(item, overrides, method, units, result=None, error=None) -> dict:
    row = {"item": item, **overrides, "method": method, "units": units}
    if result is None:
        row.update(status=FAILED, rmse=None, max_error=None, solve_time_s=None, iterations=None, error=error or "")
    else:
        m = result.metrics
        row.update(
            status=result.status,
            rmse=float(m["rmse"]) if "rmse" in m else None,
            max_error=float(m["max_error"]) if "max_error" in m else None,
            solve_time_s=float(result.solve_time_s),
            iterations=int(result.iterations),
            error="",
        )
    return row


# ---------------------------------------------------------------- the sweep


@dataclass
class _Job:
    item: str
    overrides: dict
    pf: object  # ProblemFile
    methods: list  # to solve now
    previous: dict  # runs kept from an existing archive of the same source
    strikes: int = 0  # times a worker process died while this item was running


def _structure(pf, methods) -> tuple:
    """Items with equal keys reuse the same built solvers (nlp: M segments, n, shared lambda, options)."""
    p = pf.problem
    o = p.options
    segments = math.ceil((p.target.shape[0] - 1) / o.points_per_segment)
    # every option but the weights and the seed, which are parameters of a built solver
    options = tuple((f.name, repr(getattr(o, f.name))) for f in dataclasses.fields(o) if f.name not in _PARAMETER_OPTIONS)
    return (tuple(methods), segments, p.actuator.shared_lambda, options)


def _existing_runs(path: Path, pf) -> dict | None:
    """Runs of a usable archive at ``path`` (same problem source), or None (absent, unreadable, stale)."""
    from vine_nlp.io.archive import load_archive

    try:
        archive = load_archive(path)
    except Exception:  # noqa: BLE001 - any unreadable file is redone
        return None
    if archive.kind != "design" or archive.source != pf.source:
        return None
    return archive.runs


def _make_pool(workers, scheduler, jobs):
    if scheduler:
        return _DaskPool(scheduler)
    if workers <= 1:
        return _InlinePool()
    return _LocalPool(min(workers, jobs))


def run_sweep(
    sweep,
    out_dir,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    force: bool = False,
    callback: Callable[[str, list], None] | None = None,
) -> SweepReport:
    """Solve every item of ``sweep`` (from ``load_sweep``) into ``out_dir``; see the module docstring.

    ``workers``: local processes (default ``os.cpu_count()``; 0 or 1: in this
    process); ignored with ``scheduler``, the address of a dask scheduler.
    ``progress``: a tqdm bar on stderr (on a terminal). ``force``: redo items that
    have an archive already. ``callback(item, rows)`` is called after each item
    finished in this run, once its archive and the summary are on disk (on sweeps so
    large that rewriting the summary takes a while, it may lag a few items behind).
    """
    from vine_nlp.io.archive import Archive, write_archive

    t_start = time.perf_counter()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "-o", "exists and is not a directory")
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise InputError("command line", "--workers", f"must be an integer >= 0, got {workers!r}")
    created = not out.exists()

    items = sweep.items()
    grid_keys = list(sweep.grid)
    methods = list(sweep.methods)
    report = SweepReport(sweep.name, out, len(items), created_dir=created)
    order = {item: k for k, (item, _, _) in enumerate(items)}
    rows_of: dict[str, list] = {}  # item -> rows, for the items finished (or skipped) so far

    # ---- what is finished already
    jobs = []
    for item, overrides, pf in items:
        path = out / f"{item}.h5"
        previous = {}
        if path.exists() and not force:
            runs = _existing_runs(path, pf)
            if runs is None:
                report.replaced += 1
            else:
                previous = {m: runs[m] for m in methods if m in runs}
        todo = [m for m in methods if m not in previous]
        if not todo:
            rows_of[item] = [_row(item, overrides, m, pf.units, previous[m]) for m in methods]
            report.skipped += 1
            continue
        jobs.append(_Job(item, overrides, pf, todo, previous))

    # grouped by structure, groups in order of first appearance, grid order inside a group
    groups: dict[tuple, list] = {}
    for job in jobs:
        groups.setdefault(_structure(job.pf, job.methods), []).append(job)
    pending = deque(job for group in groups.values() for job in group)

    # Connect (a bad scheduler address is bad input) before anything is created.
    pool = _make_pool(workers, scheduler, len(pending)) if pending else None
    report.executor = pool.description if pool is not None else ""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if pool is not None:
            pool.close()
        raise InputError(str(out), "-o", f"cannot create the directory ({exc.strerror or exc})") from None

    summary_path = out / SUMMARY_CSV

    def all_rows():
        return [row for item in sorted(rows_of, key=order.__getitem__) for row in rows_of[item]]

    clock = {"end": -math.inf, "cost": 0.0}

    def write_summary_now(throttle=False):
        # Rewritten after every batch of finished items; on huge sweeps at most 5% of the time goes to it.
        start = time.perf_counter()
        if throttle and start - clock["end"] < 20 * clock["cost"]:
            return
        write_summary(summary_path, all_rows(), grid_keys)
        report.summary_csv = summary_path
        clock["end"] = time.perf_counter()
        clock["cost"] = clock["end"] - start

    bar = None
    if progress and jobs:
        import sys

        from tqdm import tqdm

        bar = tqdm(
            total=len(items), initial=report.skipped, desc=sweep.name, unit="item",
            file=sys.stderr, dynamic_ncols=True, disable=None, smoothing=0.1,
        )
        bar.set_postfix(failed=0)

    def finish(job: _Job, runs: dict, errors: dict):
        """Archive and rows of one item that came back (``runs`` new Results, ``errors`` method -> text)."""
        path = out / f"{job.item}.h5"
        merged = dict(job.previous)
        merged.update(runs)
        ordered = {m: merged[m] for m in methods if m in merged}
        if runs:
            pf = job.pf
            archive = Archive(
                name=pf.name, kind=pf.kind, source=pf.source, diameter=pf.problem.diameter,
                units=pf.units, target=pf.problem.target, runs=ordered,
            )
            write_archive(path, archive)
        elif not job.previous:
            path.unlink(missing_ok=True)  # a failed item has no archive; an old one is stale
        rows = []
        for m in methods:
            if m in ordered:
                rows.append(_row(job.item, job.overrides, m, job.pf.units, ordered[m]))
            else:
                error = errors.get(m) or "not run"
                rows.append(_row(job.item, job.overrides, m, job.pf.units, error=error))
                report.failures.append((job.item, m, error))
                if bar is not None:
                    bar.write(f"{job.item} {m} failed: {error}")
        rows_of[job.item] = rows
        if any(r["status"] == FAILED for r in rows):
            report.failed += 1
        else:
            report.done += 1
        if bar is not None:
            bar.set_postfix(failed=report.failed, refresh=False)
            bar.update(1)
        return job.item, rows

    inflight: dict = {}
    try:
        while pending or inflight:
            # fill the window; an item suspected of killing its worker runs alone
            while pending and len(inflight) < pool.window and not any(j.strikes for j in inflight.values()):
                if pending[0].strikes and inflight:
                    break
                job = pending.popleft()
                inflight[pool.submit(solve_item, (job.pf, job.methods), job.item)] = job
            done = pool.wait_first(list(inflight))
            results, crashed = [], []
            for fut in done:
                job = inflight.pop(fut)
                try:
                    runs, timings = fut.result()
                    results.append((job, runs, timings["errors"]))
                    report.item_wall_s += timings.get("total_s", 0.0)
                    report.item_cpu_s += timings.get("cpu_s", 0.0)
                except Exception as exc:  # noqa: BLE001 - the whole item failed (or its worker died)
                    if _is_broken_pool(exc):
                        crashed.append((job, fut))
                    else:
                        text = _error_text(exc)
                        results.append((job, {}, {m: text for m in job.methods}))
            if crashed:
                # The pool is broken: every item in flight comes back here. Retry them one at a time
                # in a fresh pool; one that kills its worker while running alone has failed.
                crashed += [(inflight.pop(f), f) for f in list(inflight)]
                suspects = [job for job, f in crashed if not getattr(f, "never_started", False)]
                for job, f in sorted(crashed, key=lambda c: order[c[0].item], reverse=True):
                    if getattr(f, "never_started", False):
                        pending.appendleft(job)
                    elif job.strikes and len(suspects) == 1:
                        text = "the worker process died while solving this item (crash or out of memory)"
                        results.append((job, {}, {m: text for m in job.methods}))
                    else:
                        job.strikes += 1
                        pending.appendleft(job)
                pool.restart()
            finished = [finish(job, runs, errors) for job, runs, errors in results]
            if finished:
                write_summary_now(throttle=True)
            if callback is not None:
                for item, rows in finished:
                    callback(item, rows)
    except BaseException as exc:
        if pool is not None:
            pool.cancel(list(inflight))
            pool.close(interrupted=True)
            pool = None
        report.interrupted = isinstance(exc, KeyboardInterrupt)
        write_summary_now()
        report.rows = all_rows()
        report.archives = _archives(out, items)
        report.wall_time_s = time.perf_counter() - t_start
        if bar is not None:
            bar.close()
        if report.interrupted:
            exc.sweep_report = report
        raise
    finally:
        if pool is not None:
            pool.close()

    if bar is not None:
        bar.close()
    write_summary_now()
    report.rows = all_rows()
    report.archives = _archives(out, items)
    png = out / SUMMARY_PNG
    try:
        plot_summary(report.rows, png, title=f"sweep {sweep.name}")
        report.summary_png = png
    except Exception as exc:  # noqa: BLE001 - the results are on disk already; say what went wrong
        report.figure_error = _error_text(exc)
    report.wall_time_s = time.perf_counter() - t_start
    return report


def _is_broken_pool(exc) -> bool:
    from concurrent.futures.process import BrokenProcessPool

    return isinstance(exc, BrokenProcessPool)


def _archives(out: Path, items) -> list:
    return [out / f"{item}.h5" for item, _, _ in items if (out / f"{item}.h5").exists()]


# ---------------------------------------------------------------- figure


def read_summary(path) -> list[dict]:
    """Rows of a summary.csv, numbers as floats (None where empty), for :func:`plot_summary`."""
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            for key in ("rmse", "max_error", "solve_time_s"):
                row[key] = float(row[key]) if row.get(key) not in (None, "") else None
            rows.append(row)
    return rows


def plot_summary(rows, path, title: str | None = None) -> Path:
    """Summary figure of a sweep: RMSE and solve-time distributions per method, NLP against greedy.

    ``rows`` as in summary.csv (dicts with item, method, status, rmse, solve_time_s,
    units). RMSE is shown in mm when the units are a length unit (cm, mm, m, in).
    ``title`` goes before the item count at the top.
    The file is written atomically; its format follows the suffix.
    """
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter

    from vine_nlp.io.archive import write_atomic

    path = Path(path)
    ok = [r for r in rows if r.get("rmse") is not None and r.get("status") != FAILED]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    units = next((r.get("units") for r in ok if r.get("units")), "cm")
    factor, unit = _mm(units)
    by_method = {m: [r for r in ok if r["method"] == m] for m in methods}
    paired = {}
    if "nlp" in by_method and "greedy" in by_method:
        greedy = {r["item"]: r["rmse"] for r in by_method["greedy"]}
        paired = {r["item"]: (greedy[r["item"]], r["rmse"]) for r in by_method["nlp"] if r["item"] in greedy}

    panels = 3 if paired else 2
    fig = Figure(figsize=(4.6 * panels, 4.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, panels)
    colors = {m: f"C{k}" for k, m in enumerate(methods)}

    def hist(ax, key, scale, label, unit):
        values = {m: np.array([r[key] * scale for r in by_method[m]]) for m in methods if by_method[m]}
        finite = [v[np.isfinite(v) & (v > 0)] for v in values.values()]
        allv = np.concatenate(finite) if finite else np.array([])
        if allv.size == 0:
            ax.text(0.5, 0.5, "no finished runs", ha="center", va="center", transform=ax.transAxes)
            ax.set_xlabel(label)
            return
        lo, hi = allv.min(), allv.max()
        if hi > 20 * lo:
            bins = np.geomspace(lo, hi, 25)
            ax.set_xscale("log")
        else:
            bins = np.linspace(lo, hi if hi > lo else lo + 1e-12, 25)
        for m, v in values.items():
            v = v[np.isfinite(v) & (v > 0)]
            ax.hist(v, bins=bins, alpha=0.6, color=colors[m], label=f"{m} (n = {v.size}, mean {v.mean():.3g} {unit})")
        ax.set_xlabel(label)
        ax.set_ylabel("runs")
        # few, unclipped tick labels: minor log labels and long decimals collide at this width
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.xaxis.set_major_locator(MaxNLocator(5) if ax.get_xscale() == "linear" else LogLocator())
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend(fontsize="small")

    hist(axes[0], "rmse", factor, f"RMSE [{unit}]", unit)
    axes[0].set_title("Error")
    hist(axes[1], "solve_time_s", 1.0, "solve time [s]", "s")
    axes[1].set_title("Solve time")
    if paired:
        ax = axes[2]
        g = np.array([v[0] for v in paired.values()]) * factor
        n = np.array([v[1] for v in paired.values()]) * factor
        ax.scatter(g, n, s=14, color="C0")
        lo, hi = min(g.min(), n.min()), max(g.max(), n.max())
        ax.plot([lo, hi], [lo, hi], "k--", lw=1, label="y = x")
        if hi > 20 * lo > 0:
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.set_xlabel(f"greedy RMSE [{unit}]")
        ax.set_ylabel(f"NLP RMSE [{unit}]")
        better = int(np.sum(n < g))
        ax.set_title(f"Item by item: NLP better on {better}/{len(g)}")
        ax.legend(fontsize="small")
        ax.set_aspect("equal", adjustable="datalim")
    failed = sum(1 for r in rows if r.get("status") == FAILED)
    head = f"{len(dict.fromkeys(r['item'] for r in rows))} items"
    if failed:
        head += f", {failed} failed run" + ("s" if failed != 1 else "")
    fig.suptitle(f"{title}: {head}" if title else head)
    fmt = path.suffix.lstrip(".").lower() or "png"
    write_atomic(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=120))
    return path
