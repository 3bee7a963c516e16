"""The output files of one command: all written or none, new ones created exclusively.

In ``with run():`` (the command line's ``main``), :func:`reserve` checks an output before any work (an
existing file needs ``force``; a directory, device or pipe is never replaced) and creates its temporary
file beside it; ``io.archive.write_atomic`` fills it, ``io.files`` reads a written output from it. When
the block ends normally each written output is moved onto its path: a new one by a hard link (which
fails if another process created the file meanwhile), a forced one by a rename; a failure undoes the
moves before it (a replaced file comes back); an exception or signal just removes the temporary files.
Outside a run (scripts, sweeps) writes are immediate. Temporary files, ``.<name>.vine-nlp-<pid>-*.tmp``,
of a process that no longer exists (SIGKILL) go with the next write into their directory."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from pathlib import Path

from vine_nlp.errors import InputError

_TEMP = re.compile(r"^\..*\.vine-nlp-(\d+)-[^.]*\.tmp(\.\w+)?$")
_NOT_REGULAR = "not a regular file: a device, pipe or socket is never replaced"
_active: dict | None = None  # output path -> {"temp", "force", "written", "key"} of the current run
_swept: set = set()  # directories this process cleaned of dead processes' temporary files


class OutputError(InputError, OSError):
    """An output file that cannot be written (disk full, no permission, read-only filesystem,
    a directory in the way): ``(file, "write", reason)``; nothing was written. Exit 2."""

    def __init__(self, file, key, reason, errno=None):
        InputError.__init__(self, file, key, reason)
        self.errno, self.strerror, self.filename = errno, reason, str(file)


def output_error(path, exc: OSError) -> OutputError:
    """The one-line error for an OSError met while writing ``path``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if isinstance(exc, IsADirectoryError) or Path(path).is_dir():
        reason = "is a directory"
    return OutputError(path, "write", f"cannot write ({reason}); nothing was written", errno=exc.errno)


def temp_file(path) -> Path:
    """A new temporary file beside ``path`` (the final rename is atomic) with the permissions a plain
    open() gives; OutputError when the directory cannot be written."""
    path = Path(path)
    sweep_stale(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.vine-nlp-{os.getpid()}-", suffix=".tmp", dir=path.parent)
        os.close(fd)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
    except OSError as exc:
        raise output_error(path, exc) from None
    return Path(tmp)


def sweep_stale(directory) -> None:
    """Remove temporary files of processes that no longer exist (once per directory and process)."""
    directory = os.path.abspath(directory)
    if directory not in _swept:
        _swept.add(directory)
        with contextlib.suppress(OSError), os.scandir(directory) as entries:
            for e in (e for e in entries if _TEMP.match(e.name)):
                try:
                    os.kill(int(_TEMP.match(e.name).group(1)), 0)  # PermissionError: another user's process
                except ProcessLookupError:
                    os.unlink(e.path)
                except OSError:
                    pass


def reserve(path, force: bool, key: str = "-o") -> Path:
    """Check the output ``path`` before any work (module docstring); in a run, create its temporary file."""
    out = Path(path)
    try:
        st = os.stat(out) if os.path.lexists(out) else None
    except OSError as exc:
        raise output_error(out, exc) from None
    if st is not None and not force:
        raise InputError(path, key, "exists; pass --force to overwrite it")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise output_error(out, OSError(errno.EEXIST, "is a directory" if stat.S_ISDIR(st.st_mode) else _NOT_REGULAR))
    if not out.parent.is_dir():
        raise InputError(path, key, f"directory {str(out.parent)!r} does not exist")
    if _active is not None:
        name = os.path.abspath(out)
        if name in _active:
            raise InputError(path, key, f"named twice as an output (also {_active[name]['key']})")
        _active[name] = {"temp": temp_file(out), "force": force, "written": False, "key": key}
    return out


def staged(path, written: bool = False) -> Path | None:
    """The temporary file the current run writes ``path`` to (``written``: mark it written), or None."""
    entry = (_active or {}).get(os.path.abspath(path), {})
    entry["written"] = entry.get("written", False) or written
    return entry.get("temp")


def reading(path) -> str:
    """Where to read ``path``: its staged copy when this run has written it, else the path itself."""
    entry = (_active or {}).get(os.path.abspath(path), {})
    return str(entry["temp"] if entry.get("written") else path)


@contextlib.contextmanager
def run():
    """One command's outputs (module docstring): committed together when the block ends normally."""
    global _active
    outer, _active = _active, {}
    entries = _active
    try:
        yield
        _commit(entries)
    finally:
        _active = outer
        for e in entries.values():
            with contextlib.suppress(OSError):
                os.unlink(e["temp"])


def _commit(entries: dict) -> None:
    done = []  # (path, backup of the file it replaced or None), to undo
    path = None
    try:
        for path, e in ((p, e) for p, e in entries.items() if e["written"]):
            backup = None
            if not e["force"]:
                _create(e["temp"], path, e["key"])
            elif os.path.exists(path):
                if not stat.S_ISREG(os.stat(path).st_mode):  # became something else meanwhile
                    raise OSError(errno.EEXIST, _NOT_REGULAR, path)
                backup = temp_file(path)
                os.replace(path, backup)
            if e["force"]:
                os.replace(e["temp"], path)
            done.append((path, backup))
    except BaseException as exc:
        for done_path, backup in reversed(done):
            with contextlib.suppress(OSError):
                os.replace(backup, done_path) if backup else os.unlink(done_path)
        if isinstance(exc, OSError) and not isinstance(exc, InputError):
            raise output_error(path, exc) from None
        raise
    for _, backup in done:
        if backup:
            os.unlink(backup)


def _create(temp, path, key) -> None:
    """Move ``temp`` onto ``path``, which must not exist: a hard link is atomic and exclusive."""
    try:
        os.link(temp, path)  # the run removes temp afterwards
    except FileExistsError:
        raise InputError(path, key, "exists (written meanwhile by another process); pass --force to overwrite it; "
                         "nothing was written") from None
    except OSError:  # a filesystem without hard links: an exclusive placeholder, then the rename
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        os.replace(temp, path)
