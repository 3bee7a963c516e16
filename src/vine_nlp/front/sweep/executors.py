"""Where sweep items run: the worker task and three executors with one small interface.

The worker task is the top-level function :func:`solve_item`; it returns Results and
the parent writes every file, so a cluster needs no shared filesystem. An executor has
``window`` (tasks to keep in flight), ``synchronous`` (``submit`` runs the task before it
returns), ``description``, ``chunk_size(pending)``, ``submit(fn, args, name)``,
``wait_first(futures)``, ``cancel(futures)`` and ``close(interrupted=False)``:

* :class:`InlinePool` (workers 0 or 1): each item runs in this process;
* :class:`LocalPool`: a ProcessPoolExecutor whose worker processes live for the whole
  sweep; ``restart()`` after a worker process died. The first pool forks this process
  when that is safe (no thread but the main one, no solver built here yet: a fork of a
  process that runs casadi or IPOPT threads can hang), so the workers start at once with
  every module already imported; otherwise, and for every restart, the workers come from
  a forkserver that imported the solver modules once (spawn where there is none);
* :class:`DaskPool`: a dask.distributed scheduler. dask is imported only here, when a
  scheduler address is given.

Items travel in chunks (:func:`solve_chunk`, ``chunk_size``): a local worker gets a few
items per task, so the round trip to the parent (which writes every archive) is paid per
chunk, not per item. Chunks shrink towards the end of a sweep (the last tasks are single
items, so no worker idles while another finishes a long chunk) and stay small enough that
results reach the disk within about a second. The in-process and dask executors take one
item per task (dask's own KilledWorker must fail one item, not a chunk).
"""

from __future__ import annotations

import os
import socket
import sys
import threading
import time
import traceback

from vine_nlp.errors import InputError

_MAX_ERROR_TEXT = 500
MAX_CHUNK = 8  # items per local task at most: results still stream to disk every second or so
# imported once by the forkserver, so its workers start with them (and the main module, the default)
_WORKER_MODULES = ("vine_nlp.front.sweep.executors", "vine_nlp.methods.methods")


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
    from vine_nlp.methods import methods as design

    runs, errors, wall = {}, {}, {}
    t_item, c_item = time.perf_counter(), time.process_time()
    for method in methods:
        t0 = time.perf_counter()
        try:
            # looked up on the module at call time: one place to replace it (tests)
            runs[method] = design.run_design(problem_file.problem, method)
        except Exception as exc:  # noqa: BLE001 - any failure of one run is that run's result
            errors[method] = error_text(exc)
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


def error_text(exc: BaseException) -> str:
    text = " ".join(traceback.format_exception_only(type(exc), exc)).strip()
    text = " ".join(text.split())  # one line in the CSV
    return text if len(text) <= _MAX_ERROR_TEXT else text[: _MAX_ERROR_TEXT - 3] + "..."


def solve_chunk(chunk, remote: bool = False) -> list:
    """:func:`solve_item` for each ``(problem_file, methods)`` of ``chunk``, in order; a list of its returns."""
    return [solve_item(problem_file, methods, remote=remote) for problem_file, methods in chunk]


def _worker_init(inherited_fd=None):
    # Ctrl-C reaches the whole process group; only the parent handles it (it stops the workers).
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A forked worker inherits the parent's handlers (vine_nlp.interrupt turns SIGTERM into
    # KeyboardInterrupt): the parent ends its workers with SIGTERM, and they are to go quietly.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if inherited_fd is not None:
        # the parent's directory lock, inherited by fork: the lock must end with the parent, not with a worker
        try:
            os.close(inherited_fd)
        except OSError:
            pass


def _warm_up():
    """The first task of every local worker: the solver modules imported before the first item arrives."""
    import vine_nlp.methods.methods  # noqa: F401

    return os.getpid()


def fork_is_safe() -> bool:
    """True when this process can be forked for workers: POSIX fork (not macOS), only the main thread
    running, and no design solver used here (IPOPT/casadi threads do not survive a fork)."""
    import multiprocessing as mp

    return (
        "fork" in mp.get_all_start_methods()
        and sys.platform != "darwin"
        and threading.active_count() == 1
        and "vine_nlp.methods.transcription" not in sys.modules
    )


class InlinePool:
    """workers 0 or 1: each item runs in this process when submitted."""

    window = 1
    synchronous = True  # submit() runs the item: the engine writes what finished before it submits more

    def __init__(self):
        self.description = "in this process"

    def chunk_size(self, pending: int) -> int:
        return 1  # nothing to save in this process; an interrupt keeps every finished item

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


class LocalPool:
    """A ProcessPoolExecutor whose worker processes live for the whole sweep."""

    synchronous = False

    def __init__(self, workers: int, inherited_fd: int | None = None):
        """``workers`` processes, started now (they import and warm up while the parent goes on);
        ``inherited_fd`` is closed in forked workers (the directory lock)."""
        self.window = workers
        self.workers = workers
        self.description = f"{workers} local worker processes"
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
        fd = inherited_fd if method == "fork" else None
        executor = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_worker_init, initargs=(fd,))
        # Start every worker now (a fork happens here, while this process has one thread): they
        # import the solver modules while the parent sets up; the futures are not looked at.
        self._warm = [executor.submit(_warm_up) for _ in range(self.workers)]
        return executor

    def chunk_size(self, pending: int) -> int:
        """Items for the next task: a quarter of a fair share, at most MAX_CHUNK, single items at the end."""
        return max(1, min(MAX_CHUNK, pending // (4 * self.workers)))

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
        # threads run in this process now (the old pool's manager): no fork, a forkserver's workers
        self.executor = self._make(None if self.start_method == "fork" else self.start_method)

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


class DaskPool:
    """A dask.distributed scheduler; the workers need vine_nlp installed, no shared files."""

    synchronous = False

    def __init__(self, address: str):
        try:
            from dask.distributed import Client, as_completed
        except ImportError:  # the [cluster] extra
            raise InputError("command line", "--scheduler", "needs dask.distributed: python3 -m pip install 'vine_nlp[cluster]'") from None
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

    def chunk_size(self, pending: int) -> int:
        return 1  # an item that keeps killing workers ends as KilledWorker: that item's failure alone

    def wait_first(self, futures):
        return self._completed.next_batch(block=True)

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


def is_broken_pool(exc) -> bool:
    """True when a local worker process died (the pool is broken, every item in flight is lost)."""
    from concurrent.futures.process import BrokenProcessPool

    return isinstance(exc, BrokenProcessPool)
