"""Ctrl-C and SIGTERM across CasADi solves.

CasADi catches a KeyboardInterrupt raised inside an IPOPT solve and returns with
status "NonIpopt_Exception_Thrown" instead of propagating it. Every solver call is
followed by :func:`check`, which turns that (or a signal recorded by
:func:`install`) back into a KeyboardInterrupt, so interrupted work unwinds and
atomic writers leave nothing partial.
"""

from __future__ import annotations

import signal
import threading

_requested = threading.Event()
INTERRUPTED_STATUS = "NonIpopt_Exception_Thrown"  # no callbacks of ours can throw: only an interrupt


def _handler(signum, frame):
    _requested.set()
    raise KeyboardInterrupt


def install():
    """Route SIGINT and SIGTERM to KeyboardInterrupt (main thread only); returns a restore function."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    _requested.clear()
    old = {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM)}

    def restore():
        for s, h in old.items():
            signal.signal(s, h)

    return restore


def check(return_status: str | None = None) -> None:
    """Raise KeyboardInterrupt if a signal arrived or a solve was interrupted."""
    if _requested.is_set() or return_status == INTERRUPTED_STATUS:
        raise KeyboardInterrupt
