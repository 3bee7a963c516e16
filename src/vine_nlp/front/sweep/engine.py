"""The sweep itself: items, resume, the directory lock, archives streamed to disk as items finish.

See the package docstring (:mod:`vine_nlp.front.sweep`) for what a sweep writes and how it
resumes. This module adds two safeguards:

* a lock: ``DIR/.sweep.lock`` is held (``fcntl.flock``) for the whole run, so a second
  sweep started into the same directory stops at once with an InputError (exit 2) instead
  of both writing the same files; the lock goes with the process, however it ends;
* write errors (a full disk, a read-only filesystem, no permission): the sweep stops,
  every archive already written stays, and the error says to run the same command again
  once the cause is fixed (it then resumes).
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from vine_nlp import interrupt
from vine_nlp.errors import InputError
from vine_nlp.front.sweep.executors import InlinePool, error_text, is_broken_pool, make_pool, solve_chunk
from vine_nlp.front.sweep.figure import plot_summary, preload_matplotlib
from vine_nlp.front.sweep.summary import FAILED, SUMMARY_CSV, SUMMARY_PNG, SweepReport, make_row, write_summary
from vine_nlp.io.archive import Archive, OutputError, load_archive, write_archive

LOCK_FILE = ".sweep.lock"
_PARAMETER_OPTIONS = ("smooth_theta", "smooth_lambda", "seed", "method")


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
    try:
        archive = load_archive(path)
    except InputError:  # unreadable, damaged or invalid: redone
        return None
    if archive.kind != "design" or archive.source != pf.source:
        return None
    return archive.runs


class DirectoryLock:
    """An exclusive ``fcntl.flock`` on ``DIR/.sweep.lock`` (advisory; released when the process ends)."""

    def __init__(self, out: Path):
        self.path = out / LOCK_FILE
        self.fd = None

    def acquire(self) -> None:
        """Take the lock or raise InputError naming the sweep that holds it."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not on Windows: no lock there
            return
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise InputError(str(self.path.parent), "-o", f"cannot create the lock file {LOCK_FILE} ({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise InputError(
                str(self.path.parent), "-o",
                f"another sweep (pid {holder}) is writing into this directory; wait for it to end or choose another -o",
            ) from None
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass  # the pid is only informative; a full disk must not stop the lock
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing drops the flock; the file stays (removing it would race)
            self.fd = None


def run_sweep(
    sweep,
    out_dir,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    force: bool = False,
    callback: Callable[[str, list], None] | None = None,
) -> SweepReport:
    """Solve every item of ``sweep`` (from ``load_sweep``) into ``out_dir`` (see :mod:`vine_nlp.front.sweep`).

    Parameters
    ----------
    sweep : Sweep
        From ``vine_nlp.io.problem_file.load_sweep``.
    out_dir : path-like
        The directory of the archives and the summary (created when missing).
    workers : int, optional
        Local processes (default ``os.cpu_count()``; 0 or 1: in this process); ignored
        with ``scheduler``.
    scheduler : str, optional
        The address of a dask scheduler.
    progress : bool
        A tqdm bar on stderr (on a terminal).
    force : bool
        Redo items that have an archive already.
    callback : callable, optional
        ``callback(item, rows)`` after each item finished in this run, once its archive
        and the summary are on disk (on sweeps so large that rewriting the summary takes
        a while, the summary may lag a few items behind).

    Returns
    -------
    SweepReport

    Raises
    ------
    InputError
        Bad arguments, an unusable output directory, a directory locked by another
        sweep, a scheduler that cannot be reached, a base problem with obstacles.
    OutputError
        A file could not be written (disk full, ...): the sweep stopped, what finished
        is kept, the same command resumes.
    KeyboardInterrupt
        Ctrl-C or SIGTERM; its ``sweep_report`` attribute is the partial report.
    """
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
    if any(getattr(pf.problem, "obstacles", ()) for _, _, pf in items):
        # `vine-nlp design` adds a step after run_design for obstacles (front.cli); a sweep that
        # solved around it would archive designs that ignore them
        raise InputError(sweep.path, "base", "[[obstacles]] are not supported in sweeps yet; design such problems "
                         "with vine-nlp design")
    grid_keys = list(sweep.grid)
    methods = list(sweep.methods)
    report = SweepReport(sweep.name, out, len(items), created_dir=created)
    order = {item: k for k, (item, _, _) in enumerate(items)}
    rows_of: dict[str, list] = {}  # item -> rows, for the items finished (or skipped) so far
    phases = report.phases

    lock = DirectoryLock(out)
    if out.is_dir():
        lock.acquire()  # before reading what is there: another sweep may be writing it
    pool = None
    try:
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
                rows_of[item] = [make_row(item, overrides, m, pf.units, previous[m]) for m in methods]
                report.skipped += 1
                continue
            jobs.append(_Job(item, overrides, pf, todo, previous))

        # grouped by structure, groups in order of first appearance, grid order inside a group
        groups: dict[tuple, list] = {}
        for job in jobs:
            groups.setdefault(_structure(job.pf, job.methods), []).append(job)
        pending = deque(job for group in groups.values() for job in group)

        # Connect (a bad scheduler address is bad input) before anything is created.
        pool = make_pool(workers, scheduler, len(pending), inherited_fd=lock.fd) if pending else None
        phases["setup_s"] = time.perf_counter() - t_start
        report.executor = pool.description if pool is not None else ""
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(str(out), "-o", f"cannot create the directory ({exc.strerror or exc})") from None
        if lock.fd is None:
            lock.acquire()
    except BaseException:
        if pool is not None:
            pool.close(interrupted=True)
        lock.release()
        raise

    try:  # the lock is held from here on, however the run ends
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
        if progress and jobs and getattr(sys.stderr, "isatty", lambda: False)():  # no bar in logs and pipes: tqdm is not even imported
            from tqdm import tqdm

            bar = tqdm(
                total=len(items), initial=report.skipped, desc=sweep.name, unit="item",
                file=sys.stderr, dynamic_ncols=True, smoothing=0.1,
            )
            bar.set_postfix(failed=0)

        # While the workers solve, this process mostly waits: it imports the figure's modules meanwhile
        # (a thread started after the workers were forked), so the figure does not wait for them at the end.
        preload = None
        if jobs and not isinstance(pool, InlinePool):
            preload = threading.Thread(target=preload_matplotlib, name="vine-nlp-preload", daemon=True)
            preload.start()

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
                write_archive(path, archive)  # OutputError (disk full, ...) stops the sweep: see below
            elif not job.previous:
                path.unlink(missing_ok=True)  # a failed item has no archive; an old one is stale
            rows = []
            for m in methods:
                if m in ordered:
                    rows.append(make_row(job.item, job.overrides, m, job.pf.units, ordered[m]))
                else:
                    error = errors.get(m) or "not run"
                    rows.append(make_row(job.item, job.overrides, m, job.pf.units, error=error))
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

        inflight: dict = {}  # future -> the jobs of its chunk

        def fill():
            # Keep every worker busy; an item suspected of killing its worker runs alone (a chunk of one).
            while pending and len(inflight) < pool.window and not any(j.strikes for c in inflight.values() for j in c):
                if pending[0].strikes:
                    if inflight:
                        break
                    chunk = [pending.popleft()]
                else:
                    chunk = []
                    size = pool.chunk_size(len(pending))
                    while pending and len(chunk) < size and not pending[0].strikes:
                        chunk.append(pending.popleft())
                task = [(job.pf, job.methods) for job in chunk]
                inflight[pool.submit(solve_chunk, (task,), chunk[0].item)] = chunk

        try:
            while pending or inflight:
                fill()
                t_wait = time.perf_counter()
                done = pool.wait_first(list(inflight))
                phases["waiting_s"] += time.perf_counter() - t_wait
                if phases["first_result_s"] is None:
                    phases["first_result_s"] = time.perf_counter() - t_start
                results, crashed = [], []
                for fut in done:
                    chunk = inflight.pop(fut)
                    try:
                        outs = fut.result()
                    except Exception as exc:  # noqa: BLE001 - the whole task failed (or its worker died)
                        if is_broken_pool(exc):
                            crashed += [(job, fut) for job in chunk]
                        else:
                            text = error_text(exc)
                            results += [(job, {}, {m: text for m in job.methods}) for job in chunk]
                        continue
                    for job, (runs, timings) in zip(chunk, outs):
                        results.append((job, runs, timings["errors"]))
                        report.item_wall_s += timings.get("total_s", 0.0)
                        report.item_cpu_s += timings.get("cpu_s", 0.0)
                if crashed:
                    # The pool is broken: every item in flight comes back here. Retry them one at a time
                    # in a fresh pool; one that kills its worker while running alone has failed.
                    crashed += [(job, f) for f in list(inflight) for job in inflight.pop(f)]
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
                elif not pool.synchronous:
                    fill()  # the next chunks go out before the archives are written: no worker waits for the disk
                t_finish = time.perf_counter()
                finished = [finish(job, runs, errors) for job, runs, errors in results]
                phases["archives_s"] += time.perf_counter() - t_finish
                if finished:
                    write_summary_now(throttle=True)
                if callback is not None:
                    for item, rows in finished:
                        callback(item, rows)
                if finished:
                    interrupt.hold("sweep-item")  # tests: a finished item is on disk, more are to come
        except BaseException as exc:
            if pool is not None:
                pool.cancel(list(inflight))
                pool.close(interrupted=True)
                pool = None
            report.interrupted = isinstance(exc, KeyboardInterrupt)
            try:
                write_summary_now()  # what finished, so far as the disk allows
            except OutputError:
                pass
            report.rows = all_rows()
            report.archives = _archives(out, items)
            report.wall_time_s = time.perf_counter() - t_start
            if bar is not None:
                bar.close()
            if report.interrupted:
                exc.sweep_report = report
            if isinstance(exc, OutputError):
                kept = report.done + report.failed + report.skipped
                raise OutputError(
                    exc.file, exc.key,
                    f"{exc.reason.replace('; nothing was written', '')}; the sweep stopped, finished items kept: {kept}; "
                    "run the same command again to resume",
                    errno=exc.errno,
                ) from None
            raise
        finally:
            if pool is not None:
                pool.close()

        if bar is not None:
            bar.close()
        write_summary_now()
        report.rows = all_rows()
        report.archives = _archives(out, items)
        phases["summary_csv_s"] = time.perf_counter() - t_start
        png = out / SUMMARY_PNG
        t_figure = time.perf_counter()
        if preload is not None:
            preload.join()  # imports are done or nearly so; no import races the drawing
        try:
            plot_summary(report.rows, png, title=f"sweep {sweep.name}")
            report.summary_png = png
        except OutputError:
            raise
        except Exception as exc:  # noqa: BLE001 - the results are on disk already; say what went wrong
            report.figure_error = error_text(exc)
        phases["figure_s"] = time.perf_counter() - t_figure
        report.wall_time_s = time.perf_counter() - t_start
        return report
    finally:
        lock.release()


def _archives(out: Path, items) -> list:
    return [out / f"{item}.h5" for item, _, _ in items if (out / f"{item}.h5").exists()]
