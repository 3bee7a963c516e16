"""The command line's checks of the files it names: outputs not overwritten without --force, figure
formats, archives read and validated, runs that exist."""

from __future__ import annotations

from pathlib import Path

from vine_nlp.errors import InputError
from vine_nlp.front.plot import figure_format
from vine_nlp.io.archive import load_archive


def check_output(path: str, force: bool, arg: str = "-o") -> Path:
    """An output path: refused if it exists (without ``force``) or its directory does not."""
    out = Path(path)
    if out.exists() and not force:
        raise InputError(path, arg, "exists; pass --force to overwrite it")
    if not out.parent.exists():
        raise InputError(path, arg, f"directory {str(out.parent)!r} does not exist")
    return out


def check_figure(path, force, key="--plot"):
    """A figure output (png, pdf or svg by suffix), or None where none is asked for."""
    if not path:
        return None
    out = check_output(path, force, key)
    try:
        figure_format(out)
    except ValueError as e:
        raise InputError(path, key, str(e)) from None
    return out


def read_archive(path, key="ARCHIVE"):
    """The archive at ``path``, validated; any problem is one InputError ``(path, dataset, reason)``
    (``key``: the command-line argument that named it, for a path that is no file at all)."""
    if not Path(path).exists():
        raise InputError(path, key, "no such file")
    return load_archive(path)


def archive_run(archive, path, run):
    """``run`` (default: the archive's default run), which must be in the archive."""
    if run is None:
        run = archive.default_run()
        if run is None:
            raise InputError(path, "runs", "the archive has no runs")
    if run not in archive.runs:
        raise InputError(path, "--run", f"no run {run!r} (runs: {', '.join(archive.runs) or 'none'})")
    return run
