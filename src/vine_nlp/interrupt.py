"""Ctrl-C and SIGTERM across CasADi solves, and the test hold points.

CasADi catches a KeyboardInterrupt raised inside an IPOPT solve and returns with status "NonIpopt_Exception_Thrown"
instead of propagating it. Every solver call is followed by :func:`check`, which turns that (or a signal recorded by
:func:`install`) back into a KeyboardInterrupt, so interrupted work unwinds and atomic writers leave nothing partial. A
solver that never looks at signals (Fatrop's C loop) runs through :func:`call`, in a thread of its own the main thread
waits for.

Test hold points. Tests that interrupt a run must not guess how long it runs. With the environment variable
``VINE_NLP_TEST_HOLD=<point>=<fifo>`` (``<fifo>`` a named pipe made by the test), the first process that reaches hold
point ``<point>`` claims it (``<fifo>.claimed``, holding its pid, appears), prints ``vine-nlp: test hold at <point> (pid
<pid>)`` on stderr and blocks opening ``<fifo>`` until the test opens it for writing (and reads until the test closes
it). The test waits for the line (or the claim file), then signals or kills the process: it is then certainly mid-run at
that point. Every other process, and later visits, pass through. Hold points: ``solve`` (:func:`check`, after each
solver call, so a run is inside its solve loop), ``sweep-item`` (a sweep wrote an item's archive and its summary),
``archive`` (an archive open in h5py), ``start`` (``python -m vine_nlp`` before its imports). Without the variable the
points cost one dictionary lookup."""

from __future__ import annotations

import _thread
import os
import signal
import sys
import threading

_requested = threading.Event()
_raised = {"once": False, "again": False}  # a KeyboardInterrupt was raised; one more is owed (the first was lost)
INTERRUPTED_STATUS = "NonIpopt_Exception_Thrown"  # no callbacks of ours can throw: only an interrupt
HOLD_ENV = "VINE_NLP_TEST_HOLD"
# the main thread waits for a worker (a solve, a held test point) in joins this long: a signal landing just before a
# blocking system call begins does not interrupt it (the handler, which raises, runs between bytecodes), so one long
# wait could outlast the signal; this is the longest delay in answering it, not a guess of how long anything takes
JOIN_S = 0.1
_passed: set = set()  # hold points this process went past (each holds at most once)


def _handler(signum, frame):
    _requested.set()
    if (_raised["once"] and not _raised["again"]) or _raised.get("hook"):
        return  # unwinding already: a second signal does not break the cleanup (requested() stays true)
    _raised.update(once=True, again=False)
    raise KeyboardInterrupt


def _unraisable(info, previous=sys.unraisablehook):
    """A KeyboardInterrupt raised where Python cannot pass it on (a weakref callback, ``__del__``): no
    traceback; it is raised again in the main thread, where the command ends on it."""
    if not isinstance(info.exc_value, KeyboardInterrupt):
        return previous(info)
    _requested.set()
    if _raised["again"]:
        return None
    # raised in the hook itself, the KeyboardInterrupt would be lost again: a thread raises it once the hook is done
    _raised.update(again=True, hook=True)
    done = threading.Event()
    try:
        threading.Thread(target=lambda: (done.wait(), _thread.interrupt_main()), daemon=True).start()
    finally:
        _raised["hook"] = False
        done.set()
    return None


def requested() -> bool:
    """A signal arrived since :func:`install` (whatever became of the KeyboardInterrupt it raised)."""
    return _requested.is_set()


def quiet() -> None:
    """From here on a signal only sets :func:`requested` (the end of a command: nothing left to interrupt)."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: _requested.set())


def install():
    """Route SIGINT and SIGTERM to KeyboardInterrupt (main thread only): the first signal raises, later ones
    only keep :func:`requested` true; returns a restore function."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    _requested.clear()
    _raised.update(once=False, again=False)
    old = {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM)}
    hook, sys.unraisablehook = sys.unraisablehook, _unraisable

    def restore():
        sys.unraisablehook = hook
        for s, h in old.items():
            signal.signal(s, h)

    return restore


def call(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a daemon thread the main thread waits for, where a signal's handler
    can raise: Ctrl-C and SIGTERM end even C code that never returns to Python (CasADi releases the
    GIL while it solves); the thread is left to end with the process."""
    if threading.current_thread() is not threading.main_thread():
        return fn(*args, **kwargs)
    out = {}

    def run():
        try:
            out["value"] = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001  handed to the caller
            out["error"] = exc

    _join(threading.Thread(target=run, daemon=True))
    if "error" in out:
        raise out["error"]
    return out["value"]


def check(return_status: str | None = None) -> None:
    """Raise KeyboardInterrupt if a signal arrived or a solve was interrupted."""
    if _requested.is_set() or return_status == INTERRUPTED_STATUS:
        raise KeyboardInterrupt
    hold("solve")


def hold(point: str) -> None:
    """Test hold point ``point`` (see the module docstring); does nothing unless a test asked for it."""
    spec = os.environ.get(HOLD_ENV)
    if not spec or point in _passed:
        return
    name, _, fifo = spec.partition("=")
    if name != point or not fifo:
        return
    _passed.add(point)
    if not _claim(fifo):
        return
    sys.stderr.flush()
    os.write(2, f"vine-nlp: test hold at {point} (pid {os.getpid()})\n".encode())  # one write: a signal cannot split the line
    # Blocks until the test opens the pipe for writing and closes it, in a thread waited for in JOIN_S steps: a signal
    # between the marker and a blocking open held a process until the test's deadline (once, the suite at load 8)
    _join(threading.Thread(target=_wait_open, args=(fifo,), daemon=True))


def _join(worker: threading.Thread) -> None:
    """Start ``worker`` and wait for it in JOIN_S steps, so a signal's handler runs (and raises) within JOIN_S."""
    worker.start()
    while worker.is_alive():
        worker.join(JOIN_S)


def _wait_open(fifo: str) -> None:
    with open(fifo, "rb") as fh:
        fh.read()


def _claim(fifo: str) -> bool:
    """The first process to get here (over every process of the run) holds; the claim file says which."""
    tmp = f"{fifo}.{os.getpid()}.tmp"
    try:
        with open(tmp, "w") as fh:
            fh.write(str(os.getpid()))
        os.link(tmp, f"{fifo}.claimed")  # atomic, fails if another process claimed it first
        return True
    except FileExistsError:
        return False
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass
