"""One BLAS thread while designing: the OpenBLAS copies in the process run single-threaded.

A designing process holds up to three OpenBLAS libraries: CasADi's private one (MUMPS's dense fronts),
NumPy's and SciPy's. Each starts a thread per core; on these small systems the extra threads mostly spin
and doubled the CPU time of the designs (results/BENCHMARKS.md, "Solver threads"). Unless the environment
sets OpenBLAS's thread count (ENV_VARS; the user's choice wins): ``one_thread`` sets CasADi's copy to one
thread when the first solver is built; ``limited`` is a context in which NumPy's and SciPy's copies run one
thread (threadpoolctl), around every solve; ``own_process``, for processes vine_nlp owns (the command line,
sweep workers, benchmarks), sets the environment so copies loaded later read it too."""

from __future__ import annotations

import contextlib
import ctypes
import os
from functools import lru_cache

__all__ = ["one_thread", "limited", "own_process", "openblas_threads", "ENV_VARS"]

ENV_VARS = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
_set_here = False  # own_process set OPENBLAS_NUM_THREADS: not the user's choice


@lru_cache(maxsize=1)
def _casadi_openblas():
    import casadi as ca  # loaded where solvers are built: the command line checks its input without it
    path = os.path.join(os.path.dirname(ca.__file__), "libcasadi-tp-openblas.so.0")
    if not os.path.exists(path):
        return None
    try:
        # the soname MUMPS links: the same loaded copy, or the one MUMPS will find already loaded
        return ctypes.CDLL(path)
    except OSError:
        return None


def openblas_threads() -> int | None:
    """The thread count of CasADi's OpenBLAS, or None where CasADi has no such library."""
    lib = _casadi_openblas()
    return None if lib is None else int(lib.openblas_get_num_threads())


@lru_cache(maxsize=1)
def one_thread() -> None:
    """Set CasADi's OpenBLAS to one thread, once per process, unless the environment chose a count."""
    if _user_chose():
        return
    lib = _casadi_openblas()
    if lib is not None:
        lib.openblas_set_num_threads(1)


def _user_chose() -> bool:
    return not _set_here and any(os.environ.get(v) for v in ENV_VARS)


def limited():
    """A context in which the BLAS libraries loaded in the process (NumPy's, SciPy's) run one thread, restored on exit;
    a no-op where the environment chose a thread count. (CasADi's copy is set where a solver is built: ``one_thread``.)"""
    if _user_chose():
        return contextlib.nullcontext()
    import threadpoolctl  # loaded where a solve runs: the command line checks its input without it

    # the cached controller: a fresh one scans the loaded libraries (a tenth of a small design)
    return threadpoolctl.get_cached_controller().limit(limits=1, user_api="blas")


def own_process() -> None:
    """One BLAS thread for the rest of a process vine_nlp owns (the command line, a benchmark): the
    libraries loaded now are set, the ones loaded later read ``OPENBLAS_NUM_THREADS=1`` from the
    environment (child processes inherit it). A no-op where the environment chose a thread count."""
    global _set_here
    if _user_chose():
        return
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    _set_here = True
    import threadpoolctl
    threadpoolctl.get_cached_controller().limit(limits=1, user_api="blas")
