"""Event-driven interruption for tests: run a command, wait until it is held at a hold point.

See vine_nlp.interrupt ("Test hold points"): with VINE_NLP_TEST_HOLD=<point>=<fifo> the first
process that reaches <point> prints a marker line on stderr, writes <fifo>.claimed (its pid) and
blocks until the fifo is opened for writing. Nothing here assumes how long anything takes: the
deadlines only bound a wait for an event so that a broken program fails the test instead of
hanging it.
"""

from __future__ import annotations

import atexit
import os
import selectors
import subprocess
import sys
import time
from pathlib import Path

DEADLINE_S = 300.0  # only a bound on waiting for an event: never reached by a working program


def hold_env(folder: Path, point: str) -> tuple[dict, Path]:
    """Environment that holds the first process reaching ``point``; the fifo lives in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    fifo = folder / "hold.fifo"
    os.mkfifo(fifo)
    env = dict(os.environ, VINE_NLP_TEST_HOLD=f"{point}={fifo}")
    return env, fifo


_spawned: list = []


@atexit.register
def _kill_leftovers():
    # a test that failed before its process ended must not leave it held on a fifo for good
    for proc in _spawned:
        if proc.poll() is None:
            proc.kill()


def spawn(args, env) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "vine_nlp", *map(str, args)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _spawned.append(proc)
    return proc


def wait_for_marker(proc: subprocess.Popen, point: str) -> tuple[int, bytes]:
    """Read ``proc``'s stderr until the hold marker of ``point``; returns (held pid, stderr so far)."""
    marker = f"vine-nlp: test hold at {point} (pid ".encode()
    buf = b""
    sel = selectors.DefaultSelector()
    sel.register(proc.stderr, selectors.EVENT_READ)
    end = time.monotonic() + DEADLINE_S
    try:
        while marker not in buf:
            if not sel.select(timeout=max(0.0, end - time.monotonic())):
                raise AssertionError(f"no hold marker within {DEADLINE_S} s: {buf.decode(errors='replace')}")
            chunk = os.read(proc.stderr.fileno(), 65536)
            if not chunk:
                raise AssertionError(f"exited (rc {proc.wait()}) before the hold point {point}: {buf.decode(errors='replace')}")
            buf += chunk
    finally:
        sel.close()
    tail = buf[buf.index(marker) + len(marker):]
    return int(tail.split(b")")[0]), buf


def wait_for_claim(fifo: Path) -> int:
    """Pid of the process held at the fifo's hold point (any process: a pool or dask worker too)."""
    claimed = Path(f"{fifo}.claimed")
    end = time.monotonic() + DEADLINE_S
    while not claimed.exists():  # waits for the event "a process is held", bounded
        if time.monotonic() > end:
            raise AssertionError(f"nothing reached the hold point within {DEADLINE_S} s")
        time.sleep(0.05)
    return int(claimed.read_text())


def release(fifo: Path) -> None:
    """Let the held process go on (it reads the fifo until it is closed)."""
    end = time.monotonic() + DEADLINE_S
    while True:
        try:
            # non-blocking: ENXIO until the held process has the fifo open (it prints its marker
            # just before), so a process that died instead never hangs the test
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            break
        except OSError:
            if time.monotonic() > end:
                raise AssertionError("the held process never opened the fifo") from None
            time.sleep(0.01)
    os.close(fd)


def finish(proc: subprocess.Popen, before: bytes = b"") -> tuple[int, str]:
    """Wait for ``proc``: (exit code, whole stderr as text); killed if it does not end in time."""
    try:
        _, err = proc.communicate(timeout=DEADLINE_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        raise AssertionError("the process did not end after the signal") from None
    return proc.returncode, (before + err).decode(errors="replace")
