"""The output files of one command: all written or none, new ones created exclusively.

Inside ``with run():`` (the command line wraps every command in one), :func:`reserve` checks each
output path before any work: an existing file needs ``force``; what is not a regular file
(a directory, a device such as /dev/null, a pipe) is never replaced; and it creates the
temporary file the output is written to, so a directory that cannot be written is found
at once. Writers (``vine_nlp.io.archive.write_atomic``) fill that temporary file; readers
(``vine_nlp.io.files``) read a written output from it. When the command ends normally every
written output is moved onto its path: a new one by a hard link, which fails if another
process created the file meanwhile (two runs to one new file: one of them exits 2), one
allowed to replace a file by a rename. A failure there undoes the outputs moved before it
(a replaced file comes back), and an exception or signal before it removes the temporary
files: nothing was written. Outside a run (scripts, sweeps) writes are immediate.

Temporary files are named ``.<name>.vine-nlp-<pid>-<random>.tmp``; those of a process that no
longer exists (killed with SIGKILL) are removed by the next write into their directory.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from pathlib import Path

from vine_nlp.errors import InputError

_TEMP = re.compile(r"\.vine-nlp-(\d+)-[^.]*\.tmp$")
_active: dict | None = None  # output path -> {"temp", "force", "written", "key"} of the current run
_swept: set = set()  # directories this process cleaned of dead processes' temporary files


class OutputError(InputError, OSError):
    """An output file that cannot be written (disk full, no permission, read-only filesystem,
    a directory in the way): ``(file, "write", reason)``; nothing was written. Exit 2."""

    def __init__(self, file, key, reason, errno=None):
        InputError.__init__(self, file, key, reason)
        self.errno = errno
        self.strerror = reason
        self.filename = str(file)


def output_error(path, exc: OSError, key: str = "write") -> OutputError:
    """The one-line error for an OSError met while writing ``path``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if isinstance(exc, IsADirectoryError) or Path(path).is_dir():
        reason = "is a directory"
    return OutputError(path, key, f"cannot write ({reason}); nothing was written", errno=exc.errno)


def temp_file(path) -> Path:
    """A new temporary file beside ``path`` (same directory: the final rename is atomic), with the
    permissions a plain open() would give; OutputError when the directory cannot be written."""
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
    if directory in _swept:
        return
    _swept.add(directory)
    with contextlib.suppress(OSError), os.scandir(directory) as entries:
        for e in entries:
            m = _TEMP.search(e.name)
            if m and e.name.startswith(".") and not _alive(int(m.group(1))):
                with contextlib.suppress(OSError):
                    os.unlink(e.path)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


def reserve(path, force: bool, key: str = "-o") -> Path:
    """Check the output ``path`` before any work (module docstring); in a run, create its temporary file."""
    out = Path(path)
    try:
        st = os.stat(out)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise output_error(out, exc) from None
    if st is not None and not force:
        raise InputError(path, key, "exists; pass --force to overwrite it")
    if st is not None and not stat.S_ISREG(st.st_mode):
        what = "is a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file: a device, pipe or socket is never replaced"
        raise output_error(out, OSError(errno.EEXIST, what))
    if not out.parent.is_dir():
        raise InputError(path, key, f"directory {str(out.parent)!r} does not exist")
    if _active is not None:
        name = os.path.abspath(out)
        if name in _active:
            raise InputError(path, key, f"named twice as an output (also {_active[name]['key']})")
        _active[name] = {"temp": temp_file(out), "force": force, "written": False, "key": key}
    return out


def staged(path, written: bool = False):
    """The temporary file the current run writes ``path`` to (``written``: mark it written), or None."""
    entry = _active.get(os.path.abspath(path)) if _active else None
    if entry is None:
        return None
    entry["written"] |= written
    return entry["temp"]


def reading(path) -> str:
    """Where to read ``path``: its staged copy when this run has written it, else the path itself."""
    entry = _active.get(os.path.abspath(path)) if _active else None
    return str(entry["temp"]) if entry and entry["written"] else str(path)


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
    done = []  # (path, backup of the file it replaced or None)
    try:
        for path, e in entries.items():
            if not e["written"]:
                continue
            backup = None
            if not e["force"]:
                _create(e["temp"], path, e["key"])
                done.append((path, None))
                continue
            if os.path.exists(path):
                if not stat.S_ISREG(os.stat(path).st_mode):  # became something else meanwhile
                    raise OSError(errno.EEXIST, "not a regular file: a device, pipe or socket is never replaced", path)
                backup = temp_file(path)
                os.replace(path, backup)
            os.replace(e["temp"], path)
            done.append((path, backup))
    except BaseException as exc:
        for path, backup in reversed(done):
            with contextlib.suppress(OSError):
                os.replace(backup, path) if backup else os.unlink(path)
        if isinstance(exc, OSError):
            raise output_error(getattr(exc, "filename", None) or path, exc) from None
        raise
    for _, backup in done:
        if backup:
            with contextlib.suppress(OSError):
                os.unlink(backup)


def _create(temp, path, key) -> None:
    """Move ``temp`` onto ``path``, which must not exist: a hard link is atomic and exclusive."""
    try:
        os.link(temp, path)
    except FileExistsError:
        raise InputError(path, key, "exists (written meanwhile by another process); pass --force to overwrite it; "
                         "nothing was written") from None
    except OSError:  # a filesystem without hard links: an exclusive placeholder, then the rename
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        os.replace(temp, path)
        return
    os.unlink(temp)
