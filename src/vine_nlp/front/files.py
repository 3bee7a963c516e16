"""What the commands share: checks of the files they name (outputs not overwritten without --force,
figure formats, archives read and validated, runs that exist) and the construction-error options."""

from __future__ import annotations

from pathlib import Path

from vine_nlp.errors import InputError
from vine_nlp.io import limits, outputs
from vine_nlp.io.archive import load_archive
from vine_nlp.io.h5read import open_archive
from vine_nlp.model.routing import Sigmas

FIGURE_FORMATS = ("png", "pdf", "svg")


def check_output(path: str, force: bool, arg: str = "-o") -> Path:
    """An output path: refused if it exists (without ``force``) or its directory does not."""
    return outputs.reserve(path, force, arg)  # checked now, written when the command ends (io/outputs.py)


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


def figure_format(figure_path) -> str:
    """The format of a figure file by its suffix (ValueError for another)."""
    fmt = Path(figure_path).suffix.lower().lstrip(".")
    if fmt not in FIGURE_FORMATS:
        raise ValueError(f"{figure_path}: figure format must be one of {', '.join('.' + f for f in FIGURE_FORMATS)}")
    return fmt


def output_format(path, formats: tuple, what: str) -> str:
    """The extension of ``path`` where it is one of ``formats`` (ValueError naming the ``what`` format otherwise)."""
    ext = Path(path).suffix.lower()
    if ext not in formats:
        raise ValueError(f"unknown {what} format {ext or '(none)'!r}: use {', '.join(formats)}")
    return ext


def read_archive(path, key="ARCHIVE"):
    """The archive at ``path``, validated; any problem is one InputError ``(path, dataset, reason)``
    (``key``: the command-line argument that named it, for a path that is no file at all)."""
    if not Path(path).exists():
        raise InputError(path, key, "no such file")
    return load_archive(path)


def within_limits(command: str, archive, path, runs) -> None:
    """InputError unless ``runs`` of ``archive`` are within what ``command`` handles (io.limits.COMMAND_LIMITS):
    their segments and their tube lengths in diameters, added up."""
    routings = [archive.runs[r].routing for r in runs]
    sizes = (sum(r.segments for r in routings), sum(float(r.length.sum()) for r in routings) / archive.diameter)
    for size, most, what in zip(sizes, limits.COMMAND_LIMITS[command], ("segments", "tube diameters of tube")):
        if size > most:
            raise InputError(path, "runs", f"{f'run {runs[0]}' if len(runs) == 1 else f'{len(runs)} runs'}: {size:.6g} {what}; {command} handles "
                             f"at most {most} (vine_nlp.io.limits.COMMAND_LIMITS)" + ("; choose one with --run" if len(runs) > 1 and command == "view" else ""))


def archive_run(archive, path, run):
    """``run`` (default: the archive's default run), which must be in the archive."""
    if run is None:
        run = archive.default_run()
        if run is None:
            raise InputError(path, "runs", "the archive has no runs")
    if run not in archive.runs:
        raise InputError(path, "--run", f"no run {run!r} (runs: {', '.join(archive.runs) or 'none'})")
    return run


def sigmas(args) -> Sigmas:
    """The construction-error sigmas of the command line's --sigma-* options."""
    relative = args.sigma_length_abs is None
    return Sigmas.from_degrees(args.sigma_theta_deg, args.sigma_lambda, args.sigma_length if relative else args.sigma_length_abs,
                               relative_length=relative)


def bounded(least, most, integer=False, above=False):
    """argparse type: a finite number (an integer) in [least, most] (``above``: > least) as a file's numbers are;
    anything else a usage error (one line, exit 2)."""
    import argparse
    import math
    def convert(text):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {'integer' if integer else 'number'}: {text!r}") from None
        what, low = ("an integer", f">= {least}") if integer else ("a finite number", f"{'>' if above else '>='} {least:g}")
        if not (math.isfinite(value) and (value > least if above else value >= least) and value <= most):
            raise argparse.ArgumentTypeError(f"must be {what} {low} and <= {most if integer else format(most, 'g')}, got {text}")
        return value

    return convert


def run_name(text):
    """argparse type of --run: a run's name (non-empty printable text)."""
    import argparse
    if not text.strip() or not text.isprintable() or len(text) > limits.MAX_NAME_CHARS:
        raise argparse.ArgumentTypeError(f"must be the name of a run (printable, 1 to {limits.MAX_NAME_CHARS} characters), got {text!r}")
    return text


def add_sigma_args(p) -> None:
    """The --sigma-* options (analyze, design --robust, correct)."""
    p.add_argument("--sigma-theta-deg", type=bounded(0, 90), default=1.0, metavar="DEG", help="construction error of theta (default 1)")
    p.add_argument("--sigma-lambda", type=bounded(0, 1), default=0.02, metavar="S", help="construction error of lambda (default 0.02)")
    p.add_argument("--sigma-length", type=bounded(0, 1), default=0.02, metavar="F", help="relative error of segment lengths (default 0.02)")
    p.add_argument("--sigma-length-abs", type=bounded(0, limits.MAX_COORDINATE), metavar="L", help="absolute error of segment lengths instead, in units")


def several_actuators(path) -> bool:
    """Whether ``path`` is an archive of several actuators: its kind attribute alone (the command reads and checks
    the whole archive next)."""
    if not (path and Path(path).suffix.lower() in (".h5", ".hdf5") and Path(path).is_file()):
        return False
    with open_archive(path) as h5:
        kind = h5["problem"].attrs.get("kind") if "problem" in h5 else None
    kind = kind.decode(errors="replace") if isinstance(kind, bytes) else kind
    return isinstance(kind, str) and kind.startswith("actuators")
