"""The sweep itself: resume, the directory lock, the run (see :mod:`vine_nlp.front.sweep`).

The parent plans (what is finished), keeps the workers busy, keeps the summary rows and
writes summary.csv and summary.png; the workers write the archives."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import secrets
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from vine_nlp import interrupt
from vine_nlp.errors import InputError
from vine_nlp.front.sweep.executors import LOCK_FILE, InlinePool, archive_outcome, error_text, make_pool, solve_chunk
from vine_nlp.front.sweep.figure import plot_summary, preload_matplotlib
from vine_nlp.front.sweep.summary import FAILED, SUMMARY_CSV, SUMMARY_PNG, SweepReport, cells, make_row, write_summary
from vine_nlp.io.archive import OutputError, load_archive
from vine_nlp.pipeline.request import Request, check_request

_PARAMETER_OPTIONS = ("smooth_theta", "smooth_lambda", "seed", "method")


@dataclass
class _Job:
    item: str
    overrides: dict
    pf: object  # ProblemFile
    previous: dict  # runs kept from an existing archive of the same source
    seen: tuple | None  # (inode, mtime) of the archive there was at the start, if any
    strikes: int = 0  # times the item's task was lost with a dying worker


def _structure(pf, methods) -> tuple:
    """Items with equal keys reuse the same built solvers (nlp: M segments, n, shared lambda, options)."""
    p, o = pf.problem, pf.problem.options
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


def _identity(path: Path):
    with contextlib.suppress(OSError):
        st = path.stat()
        return (st.st_ino, st.st_mtime_ns)  # a new archive is a new file (renamed onto the path)
    return None


def _remove_temporaries(out: Path, items) -> None:
    """Temporary files of this sweep's archives (``.<item>.h5.*.tmp``), left by a worker killed mid-write."""
    for p in out.glob(".*.h5.*.tmp"):
        if p.name[1 : p.name.rindex(".h5.")] in items:
            p.unlink(missing_ok=True)


class DirectoryLock:
    """An exclusive ``fcntl.flock`` on ``DIR/.sweep.lock`` (advisory; released when the process ends).
    The file says ``<pid> <token>``: a worker that reads this sweep's token there writes in place."""

    def __init__(self, out: Path):
        self.path, self.fd, self.token = out / LOCK_FILE, None, secrets.token_hex(8)

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
            holder = (os.pread(fd, 64, 0).decode(errors="replace").split() or ["?"])[0]
            os.close(fd)
            raise InputError(str(self.path.parent), "-o", f"another sweep (pid {holder}) is writing into this directory; "
                             "wait for it to end or choose another -o") from None
        with contextlib.suppress(OSError):  # a full disk must not stop the lock (the workers then send their results)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()} {self.token}\n".encode(), 0)
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing drops the flock; the file stays (removing it would race)
            self.fd = None


def run_sweep(sweep, out_dir, workers: int | None = None, scheduler: str | None = None, progress: bool = True, force: bool = False,
              callback: Callable[[str, list], None] | None = None) -> SweepReport:
    """Solve every item of ``sweep`` (from ``load_sweep``) into ``out_dir`` (see :mod:`vine_nlp.front.sweep`).

    ``workers``: local processes (default ``os.cpu_count()``; 0 or 1: this one), ignored with ``scheduler`` (a dask
    scheduler's address); ``progress``: a tqdm bar on a terminal; ``force``: redo finished items; ``callback(item,
    rows)`` after each item this run finished. Raises InputError (bad arguments or output directory, a locked one, no
    scheduler, obstacles), OutputError (a file could not be written: the sweep stopped, the same command resumes) and
    KeyboardInterrupt (Ctrl-C, SIGTERM; its ``sweep_report`` is the partial report)."""
    t_start = time.perf_counter()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "-o", "exists and is not a directory")
    workers = (os.cpu_count() or 1) if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise InputError("command line", "--workers", f"must be an integer >= 0, got {workers!r}")
    run = _Run(sweep, out, callback, t_start)
    for _, _, pf in run.items:  # what a problem cannot be asked for is bad input, before any work
        check_request(pf, Request(methods=tuple(sweep.methods)))
    lock, pool = DirectoryLock(out), None
    try:
        if out.is_dir():
            lock.acquire()  # before reading what is there: another sweep may be writing it
        run.plan(force)
        # Connect (a bad scheduler address is bad input) before anything is created.
        pool = make_pool(workers, scheduler, len(run.pending), inherited_fd=lock.fd) if run.pending else None
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
        _remove_temporaries(out, run.order)
        run.solve(pool, progress, lock.token if scheduler else None)
        return run.finish()
    finally:
        lock.release()


class _Run:
    """One run of a sweep: what is left to solve, the tasks in flight, the rows of finished items."""

    def __init__(self, sweep, out: Path, callback, t_start: float):
        self.sweep, self.out, self.callback, self.t_start = sweep, out, callback, t_start
        self.items = sweep.items()
        self.methods = list(sweep.methods)
        self.order = {item: k for k, (item, _, _) in enumerate(self.items)}
        self.report = SweepReport(sweep.name, out, len(self.items), created_dir=not out.exists())
        self.rows_of: dict[str, list] = {}  # item -> rows, for the items finished (or skipped) so far
        self.jobs: list[_Job] = []  # the items to solve
        self.pending: deque = deque()
        self.inflight: dict = {}  # future -> the jobs of its task
        self.bar = self.preload = None

    def plan(self, force: bool) -> None:
        """Resume: an item whose archive holds every method is skipped (rows from the archive); one
        missing some keeps its runs; one of another source (or unreadable) is redone."""
        for item, overrides, pf in self.items:
            path = self.out / f"{item}.h5"
            previous, seen = {}, _identity(path)
            if seen is not None and not force:
                runs = _existing_runs(path, pf)
                if runs is None:
                    self.report.replaced += 1
                else:
                    previous = {m: runs[m] for m in self.methods if m in runs}
            if len(previous) == len(self.methods):
                self.rows_of[item] = [make_row(item, overrides, m, pf.units, cells(previous[m])) for m in self.methods]
                self.report.skipped += 1
                continue
            self.jobs.append(_Job(item, overrides, pf, previous, seen))
        # grouped by structure (a worker reuses its built solver), groups in order of first appearance
        groups: dict[tuple, list] = {}
        for job in self.jobs:
            groups.setdefault(_structure(job.pf, [m for m in self.methods if m not in job.previous]), []).append(job)
        self.pending = deque(job for group in groups.values() for job in group)

    def solve(self, pool, progress: bool, token) -> None:
        """Every pending item, ``pool`` keeping the workers busy; on any exception: :meth:`stopped`."""
        if pool is None:
            return
        self.report.executor = pool.description
        if progress and getattr(sys.stderr, "isatty", lambda: False)():  # no bar in logs and pipes: tqdm not even imported
            from tqdm import tqdm

            self.bar = tqdm(total=len(self.items), initial=self.report.skipped, desc=self.sweep.name, unit="item",
                            file=sys.stderr, dynamic_ncols=True, smoothing=0.1)
            self.bar.set_postfix(failed=0)
        # This process mostly waits: it imports the figure's modules meanwhile (a thread started after
        # the workers were forked), so the figure does not wait for them at the end.
        if not isinstance(pool, InlinePool):
            self.preload = threading.Thread(target=preload_matplotlib, name="vine-nlp-preload", daemon=True)
            self.preload.start()
        where = str(self.out.resolve()) if token else self.out
        try:
            while self.pending or self.inflight:
                self._fill(pool, where, token)
                lost, finished = [], False
                for fut in pool.wait_first(list(self.inflight)):
                    chunk = self.inflight.pop(fut)
                    try:
                        records = fut.result()
                    except Exception as exc:  # noqa: BLE001 - the whole task failed, or its worker died
                        if pool.lost(exc):
                            lost.append((fut, chunk))
                            continue
                        text = error_text(exc)
                        records = [{"errors": dict.fromkeys(self.methods, text), "cells": {}} for _ in chunk]
                    for job, record in zip(chunk, records):
                        self._record(job, record)
                        finished = True
                if lost:
                    self._retry(pool, lost)
                if finished:
                    interrupt.hold("sweep-item")  # tests: a finished item is on disk, more are to come
            pool.close()
        except BaseException as exc:
            stop = self.stopped(pool, exc)
            if stop is exc:
                raise
            raise stop from None

    def _fill(self, pool, where, token) -> None:
        """Keep every worker busy. An item whose task was lost with a dying worker runs alone, and
        where workers share their fate (a local pool) with nothing else in flight: then it is to blame."""
        while self.pending and len(self.inflight) < pool.window:
            if pool.shared_fate and any(j.strikes for c in self.inflight.values() for j in c):
                return
            if self.pending[0].strikes:
                if pool.shared_fate and self.inflight:
                    return
                chunk = [self.pending.popleft()]
            else:
                chunk, size = [], pool.chunk_size(len(self.pending))
                while self.pending and len(chunk) < size and not self.pending[0].strikes:
                    chunk.append(self.pending.popleft())
            task = [(job.item, job.pf, self.methods, job.previous) for job in chunk]
            self.inflight[pool.submit(solve_chunk, (task, where, token), chunk[0].item)] = chunk

    def _retry(self, pool, lost) -> None:
        """Items whose worker died: run them again, one per task; an item that kills its worker while it
        runs alone has failed (a crash in a native library, the OOM killer)."""
        if pool.shared_fate:  # the pool is broken: every task in flight comes back here
            lost += list(self.inflight.items())
            self.inflight.clear()
        suspects = sum(len(chunk) for fut, chunk in lost if not getattr(fut, "never_started", False))
        again = []
        for fut, chunk in lost:
            alone = suspects == 1 if pool.shared_fate else len(chunk) == 1  # dask ran it alone a few times already
            for job in chunk:
                if getattr(fut, "never_started", False):
                    again.append(job)
                elif alone and (job.strikes or not pool.shared_fate):
                    text = "the worker process died while solving this item (crash or out of memory)"
                    self._record(job, {"errors": dict.fromkeys(self.methods, text), "cells": {}})
                else:
                    job.strikes += 1
                    again.append(job)
        self.pending.extendleft(sorted(again, key=lambda j: self.order[j.item], reverse=True))
        if pool.shared_fate:
            pool.restart()

    def _record(self, job: _Job, record: dict) -> None:
        """The rows of an item that came back (its archive written here if the worker could not)."""
        if "runs" in record:  # the worker does not see the sweep's directory: the archive is written here
            archive_outcome(self.out, job.item, job.pf, record)
            self.report.archived_here += "stop" not in record
        if "stop" in record:
            raise OutputError(*record["stop"])
        report, rows, numbers = self.report, [], record["cells"]
        for m in self.methods:
            if m in numbers:
                rows.append(make_row(job.item, job.overrides, m, job.pf.units, numbers[m]))
                continue
            error = record["errors"].get(m) or "not run"
            rows.append(make_row(job.item, job.overrides, m, job.pf.units, error=error))
            report.failures.append((job.item, m, error))
            if self.bar is not None:
                self.bar.write(f"{job.item} {m} failed: {error}")
        self.rows_of[job.item] = rows
        failed = any(r["status"] == FAILED for r in rows)
        report.failed += failed
        report.done += not failed
        report.item_wall_s += record.get("total_s", 0.0)
        report.item_cpu_s += record.get("cpu_s", 0.0)
        if self.bar is not None:
            self.bar.set_postfix(failed=report.failed, refresh=False)
            self.bar.update(1)
        if self.callback is not None:
            self.callback(job.item, rows)

    def stopped(self, pool, exc: BaseException) -> BaseException:
        """Ctrl-C, a write error, anything: the workers stopped, what finished kept and summarized;
        the exception to raise."""
        pool.cancel(list(self.inflight))
        pool.close(interrupted=True)
        _remove_temporaries(self.out, self.order)
        self.callback = None
        # an archive a worker wrote and did not report (stopped in between) is finished all the same
        for job in self.jobs:
            path = self.out / f"{job.item}.h5"
            if job.item not in self.rows_of and _identity(path) not in (None, job.seen):
                runs = _existing_runs(path, job.pf) or {}
                if all(m in runs for m in self.methods):
                    self._record(job, {"cells": {m: cells(runs[m]) for m in self.methods}, "errors": {}})
        report = self.report
        report.interrupted = isinstance(exc, KeyboardInterrupt)
        try:
            self._summarize()
        except OutputError:
            pass  # the disk is full: what finished is in the archives, the next run summarizes it
        if report.interrupted:
            exc.sweep_report = report
        if not isinstance(exc, OutputError):
            return exc
        kept = report.done + report.failed + report.skipped
        return OutputError(exc.file, exc.key, f"{exc.reason.replace('; nothing was written', '')}; the sweep stopped, "
                           f"finished items kept: {kept}; run the same command again to resume", errno=exc.errno)

    def _summarize(self) -> None:
        r = self.report
        r.wall_time_s = time.perf_counter() - self.t_start
        if self.bar is not None:
            self.bar.close()
        r.archives = [self.out / f"{item}.h5" for item in self.order if (self.out / f"{item}.h5").exists()]
        r.rows = [row for item in sorted(self.rows_of, key=self.order.__getitem__) for row in self.rows_of[item]]
        write_summary(self.out / SUMMARY_CSV, r.rows, list(self.sweep.grid))
        r.summary_csv = self.out / SUMMARY_CSV

    def finish(self) -> SweepReport:
        """summary.csv and summary.png, once."""
        self._summarize()
        if self.preload is not None:
            self.preload.join()  # imports are done or nearly so; no import races the drawing
        png = self.out / SUMMARY_PNG
        try:
            plot_summary(self.report.rows, png, title=f"sweep {self.sweep.name}")
            self.report.summary_png = png
        except OutputError:
            raise
        except Exception as exc:  # noqa: BLE001 - the results are on disk already; say what went wrong
            self.report.figure_error = error_text(exc)
        self.report.wall_time_s = time.perf_counter() - self.t_start
        return self.report
