"""Where sweep items run: the worker task and three executors with one small interface.

The worker task :func:`solve_chunk` solves a few items (:func:`solve_item`, the seam with the design methods), writes
each item's archive (:func:`write_item`) and sends back a small record per item; where the sweep directory is not the
one it sees (a dask worker on another machine: the lock file's token differs), it sends the Results and the parent
writes them. Executors: :class:`InlinePool` (this process), :class:`LocalPool` (long-lived worker processes: each builds
a solver once per problem structure; forked when this process is safe to fork, else from a forkserver) and
:class:`DaskPool`. Items travel in chunks of up to MAX_CHUNK (a task costs more than a short item), single items at the
end so that no worker waits for another."""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
import traceback
from pathlib import Path

from vine_nlp.errors import InputError
from vine_nlp.front.sweep.summary import cells
from vine_nlp.io.archive import OutputError

LOCK_FILE = ".sweep.lock"  # DIR's lock; its second word is the sweep's token (see _reaches)
MAX_CHUNK = 8  # items per task at most
_MAX_ERROR_TEXT = 500
# imported once by the forkserver, so its workers start with them (and the main module, the default)
_WORKER_MODULES = ("vine_nlp.front.sweep.executors", "vine_nlp.pipeline.runs")
_PR_SET_PDEATHSIG = 1
_ONE_SOLVE = threading.Lock()


def solve_item(problem_file, methods, remote: bool = False) -> tuple[dict, dict]:
    """Solve one sweep item with each of ``methods`` (in a worker process): ``(runs, timings)``.

    Each method is one request to the pipeline, as `vine-nlp design --method M` makes it (obstacles, calibration and the
    judgement of every hard requirement included). ``runs``: run name -> Result of each method that finished, with the
    runs it brings along (an obstacle design's ``nlp_no_obstacles``); ``timings``: ``total_s``, ``cpu_s`` and ``errors``
    (method -> "Type: message": a method that raises fails alone). KeyboardInterrupt propagates unless ``remote`` (a
    worker ignores Ctrl-C: there it comes from inside IPOPT and fails that run)."""
    runs, errors = {}, {}
    t_item, c_item = time.perf_counter(), time.process_time()
    for method in methods:
        try:
            runs |= design_item(problem_file, method)
        except Exception as exc:  # noqa: BLE001 - any failure of one run is that run's result
            errors[method] = error_text(exc)
        except KeyboardInterrupt:
            if not remote:
                raise
            errors[method] = ("KeyboardInterrupt from the solver in a worker process, which ignores Ctrl-C "
                              "(IPOPT status NonIpopt_Exception_Thrown: an exception inside the solve)")
    return runs, {"total_s": time.perf_counter() - t_item, "cpu_s": time.process_time() - c_item, "errors": errors}


def design_item(problem_file, method: str) -> dict:
    """The runs of one method of one item: the pipeline's (run name -> Result)."""
    from vine_nlp import pipeline  # the solvers load in the worker (fork_is_safe: none in the parent)
    return pipeline.run(problem_file, pipeline.Request(methods=(method,))).runs


def write_item(out_dir, item: str, problem_file, runs: dict) -> dict:
    """Write ``DIR/<item>.h5`` atomically with ``runs`` (method -> Result, in the sweep's order)
    and return the summary's numbers of each run, ``{method: cells}`` (:func:`summary.cells`).

    No runs: the item has no archive (a stale one is removed). Raises OutputError (disk full,
    ...) and whatever HDF5 refuses to store. The pipeline's outcome of an item feeds this."""
    from vine_nlp.pipeline import Outcome  # the solvers load with it: in a worker, or in a parent that forks no more

    path = Path(out_dir) / f"{item}.h5"
    if not runs:
        path.unlink(missing_ok=True)
        return {}
    # the archive every door writes for the problem's kind (several actuators: its one run, "nlp")
    Outcome(problem_file, runs, ("nlp",) if problem_file.kind == "actuators" else tuple(runs)).write(path)
    return {m: cells(r) for m, r in runs.items()}


def archive_outcome(out_dir, item: str, problem_file, outcome: dict) -> dict:
    """:func:`write_item` for an item's ``outcome`` (its ``runs`` replaced by their ``cells``). A failed write stops the
    sweep (``stop``: the OutputError's arguments, which pickle); a value HDF5 refuses fails this item's runs alone."""
    runs, outcome["cells"] = outcome.pop("runs"), {}
    try:
        outcome["cells"] = write_item(out_dir, item, problem_file, runs)
    except OutputError as exc:
        outcome["stop"] = (exc.file, exc.key, exc.reason, exc.errno)
    except Exception as exc:  # noqa: BLE001 - e.g. a text with NUL: this item's failure, not the sweep's
        outcome["errors"].update({m: f"cannot archive the result ({error_text(exc)})" for m in runs})
    return outcome


def solve_chunk(chunk, out_dir=None, token=None, remote: bool = False) -> list[dict]:
    """Solve and archive each ``(item, problem_file, methods, previous)`` of ``chunk`` (``previous``: runs
    kept from its archive). One record per item: ``cells``, ``errors``, ``total_s``, ``cpu_s``; ``runs``
    instead of ``cells`` where ``out_dir`` is not the sweep's here (:func:`_reaches`); ``stop`` ends it."""
    here = out_dir is not None and (token is None or _reaches(out_dir, token))
    records = []
    for item, problem_file, methods, previous in chunk:
        with _ONE_SOLVE:  # a dask worker's threads share its solvers, which are not thread-safe (two crashed)
            solved, timings = solve_item(problem_file, [m for m in methods if m not in previous], remote=remote)
        runs = {m: solved.get(m) or previous[m] for m in methods if m in solved or m in previous}
        runs |= {name: r for name, r in solved.items() if name not in runs}  # brought along: nlp_no_obstacles
        record = {"runs": runs, "errors": timings["errors"], "total_s": timings["total_s"], "cpu_s": timings["cpu_s"]}
        records.append(archive_outcome(out_dir, item, problem_file, record) if here else record)
        if "stop" in record:
            break
    return records


def _reaches(out_dir, token: str) -> bool:
    """True when ``out_dir`` here is the sweep's directory: its lock file holds the sweep's token."""
    try:
        return (Path(out_dir) / LOCK_FILE).read_text().split()[1:2] == [token]
    except (OSError, UnicodeError):
        return False


def error_text(exc: BaseException) -> str:
    text = " ".join(traceback.format_exception_only(type(exc), exc)).strip()
    text = " ".join(text.split())  # one line in the CSV
    return text if len(text) <= _MAX_ERROR_TEXT else text[: _MAX_ERROR_TEXT - 3] + "..."


def _worker_init(close_fds=(), watch_fd=None, parent=None):
    # Ctrl-C reaches the whole process group; only the parent handles it (it stops the workers).
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A forked worker inherits the parent's handlers (vine_nlp.interrupt turns SIGTERM into
    # KeyboardInterrupt): the parent ends its workers with SIGTERM, and they are to go quietly.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    for fd in close_fds:  # inherited by fork: the directory lock, the watch pipe's write end
        with contextlib.suppress(OSError):
            os.close(fd)
    _die_with_parent(watch_fd, parent)


def _die_with_parent(watch_fd, parent) -> None:
    """End this worker with the sweep, kill -9 too: Linux sends SIGKILL when the parent (or the forkserver,
    which ends with the sweep) is gone; a forked worker also reads the parent's pipe, which ends then."""
    import ctypes
    import signal
    with contextlib.suppress(OSError, AttributeError):  # not Linux
        ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent is not None and os.getppid() != parent:  # gone before prctl
        os._exit(1)
    if watch_fd is not None:
        threading.Thread(target=_exit_at_eof, args=(watch_fd,), name="vine-nlp-parent", daemon=True).start()


def _exit_at_eof(fd: int) -> None:
    while os.read(fd, 1):
        pass
    os._exit(1)  # the parent's end of the pipe closed: the sweep is gone


def _warm_up():
    """The first task of every local worker: the solver modules imported before the first item arrives."""
    import vine_nlp.pipeline.runs  # noqa: F401


def fork_is_safe() -> bool:
    """True when this process can be forked for workers: POSIX fork (not macOS), only the main thread
    running, and no design solver used here (IPOPT/casadi threads do not survive a fork)."""
    import multiprocessing as mp
    return ("fork" in mp.get_all_start_methods() and sys.platform != "darwin" and threading.active_count() == 1
            and "vine_nlp.methods.transcription" not in sys.modules)


def _chunk(pending: int, slots: int) -> int:
    """Items for the next task: a quarter of a fair share, at most MAX_CHUNK, single items at the end."""
    return max(1, min(MAX_CHUNK, pending // (4 * slots)))


class InlinePool:
    """workers 0 or 1: each item runs in this process when submitted."""

    window = 1
    shared_fate = False
    description = "in this process"

    def chunk_size(self, pending: int) -> int:
        return 1  # an interrupt keeps every finished item

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

    def lost(self, exc) -> bool:
        return False

    def cancel(self, futures):
        pass

    def close(self, interrupted=False):
        pass


class LocalPool:
    """A ProcessPoolExecutor whose worker processes live for the whole sweep."""

    shared_fate = True  # a worker that dies breaks the pool: every task in flight is lost

    def __init__(self, workers: int, inherited_fd: int | None = None):
        """``workers`` processes, started now; forked ones close ``inherited_fd`` (the directory lock)."""
        self.workers = workers
        self.window = workers + 1  # one task waits in the pool's queue: a worker that finishes starts the next at once
        self.description = f"{workers} local worker processes"
        self.watch = os.pipe()  # forked workers read it; it ends with this process (_die_with_parent)
        self.start_method = "fork" if fork_is_safe() else None
        self.executor = self._make(self.start_method, inherited_fd)

    def _make(self, method, inherited_fd=None):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        if method is None:
            method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
            self.start_method = method
        ctx = mp.get_context(method)
        if method == "forkserver":
            # no effect once this process's forkserver runs (it then has its own list)
            ctx.set_forkserver_preload(["__main__", *_WORKER_MODULES])
        # file descriptors mean something only in a fork of this process
        fork = ((inherited_fd, self.watch[1]) if inherited_fd is not None else (self.watch[1],), self.watch[0], os.getpid())
        executor = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_worker_init,
                                       initargs=fork if method == "fork" else ())
        # Start every worker now (a fork happens here, while this process has one thread): they
        # import the solver modules while the parent sets up; the futures are not looked at.
        self._warm = [executor.submit(_warm_up) for _ in range(self.workers)]
        return executor

    def chunk_size(self, pending: int) -> int:
        return _chunk(pending, self.workers)

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

    def lost(self, exc) -> bool:
        from concurrent.futures.process import BrokenProcessPool
        return isinstance(exc, BrokenProcessPool)

    def restart(self):
        """A fresh pool after a worker process died (the old one is broken for good)."""
        self.executor.shutdown(wait=False, cancel_futures=True)
        # threads run in this process now (the old pool's manager): no fork, a forkserver's workers
        self.executor = self._make(None if self.start_method == "fork" else self.start_method)

    def cancel(self, futures):
        for f in futures:
            f.cancel()

    def close(self, interrupted=False):
        if not interrupted:
            self.executor.shutdown(wait=True)
        else:  # Ctrl-C: do not wait for the running items (an item may take minutes)
            processes = list((getattr(self.executor, "_processes", None) or {}).values())
            self.executor.shutdown(wait=False, cancel_futures=True)
            for p in processes:
                if p.is_alive():
                    p.terminate()
            for p in processes:
                p.join(timeout=5)
        for fd in self.watch:
            os.close(fd)
        self.watch = ()


class DaskPool:
    """A dask.distributed scheduler; the workers need vine_nlp installed, no shared files."""

    shared_fate = False  # dask reruns a task whose worker died; KilledWorker after a few deaths

    def __init__(self, address: str):
        try:
            from dask.distributed import Client, as_completed
            from distributed.comm import resolve_address
        except ImportError:  # the [cluster] extra
            raise InputError("command line", "--scheduler", "needs dask.distributed: python3 -m pip install 'vine_nlp[cluster]'") from None

        try:
            # a malformed address fails here, before a Client exists (a half-made one hangs at exit)
            resolve_address(address)
            self.client = Client(address, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise InputError(address, "--scheduler", f"cannot connect to the dask scheduler ({exc})") from None
        self._completed = as_completed(loop=self.client.loop)
        self._threads = (-math.inf, 1)
        self.description = f"dask scheduler {address} ({len(self.client.nthreads())} workers, {self.threads} threads)"

    @property
    def threads(self) -> int:
        """Worker threads of the cluster, looked up every few seconds (it may scale)."""
        if time.monotonic() - self._threads[0] > 5.0:
            self._threads = (time.monotonic(), max(1, sum(self.client.nthreads().values())))
        return self._threads[1]

    @property
    def window(self) -> int:
        return max(16, 4 * self.threads)  # the cluster busy without shipping the whole sweep at once

    def chunk_size(self, pending: int) -> int:
        return _chunk(pending, self.threads)

    def submit(self, fn, args, name):
        import uuid
        fut = self.client.submit(fn, *args, remote=True, key=f"solve_item-{name}-{uuid.uuid4().hex[:8]}", pure=False)
        self._completed.add(fut)
        return fut

    def wait_first(self, futures):
        return self._completed.next_batch(block=True)

    def lost(self, exc) -> bool:
        return type(exc).__name__ == "KilledWorker"

    def cancel(self, futures):
        if futures:
            self.client.cancel(list(futures))

    def close(self, interrupted=False):
        self.client.close()


def make_pool(workers: int, scheduler: str | None, jobs: int, inherited_fd: int | None = None):
    """The executor for ``workers`` local processes or the dask ``scheduler`` address (see the module).

    ``inherited_fd``: a file descriptor forked local workers close at once (the directory lock)."""
    if scheduler:
        return DaskPool(scheduler)
    if workers <= 1:
        return InlinePool()
    return LocalPool(min(workers, jobs), inherited_fd)
