"""The Python API's results: :class:`Design` (one run with its problem context) and :class:`Project` (an
archive's runs), views of a pipeline outcome whose figures and files are the commands' own (``plot``,
``template``, ``view``; ``save`` writes the archive ``vine-nlp design`` writes)."""

from __future__ import annotations

import dataclasses
import functools
import html
import importlib.util
import io
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from vine_nlp.errors import ArgumentError
from vine_nlp.io.archive import Archive, load_archive, write_atomic
from vine_nlp.io.archived import problem_of_archive
from vine_nlp.io.formulations import read_multishape_archive
from vine_nlp.io.problems import ProblemFile
from vine_nlp.pipeline import Outcome
from vine_nlp.problem import Result


@dataclasses.dataclass(eq=False)
class Context:
    """What the runs of one design share: the pipeline's outcome (problem, runs, archive extras); for a
    loaded archive also the archive as read and its file (saving copies it)."""

    outcome: Outcome
    archive: Archive | None = None
    path: str | None = None

    @property
    def problem_file(self) -> ProblemFile:
        return self.outcome.problem_file

    @property
    def runs(self) -> dict:
        return self.outcome.runs

    def as_archive(self) -> Archive:
        return self.archive if self.archive is not None else self.outcome.archive()


def _of(holder: str, name: str, doc: str) -> property:
    """A read-only attribute that is ``getattr(self.<holder>, name)``, documented ``doc``."""

    def get(self):
        return getattr(getattr(self, holder), name)

    get.__doc__ = doc
    return property(get)


class Design:
    """One run (a routing, its shape, metrics and solver statistics) with its problem context.

    Returned by :func:`design`, :func:`forward`, :func:`fit`, :func:`solve` and, for each run of
    an archive, by :func:`load`. It has the attributes of a ``Result`` (``method``, ``routing``,
    ``shape``, ``status``, ``solve_time_s``, ``iterations``, ``metrics``, ``stats``, ``phi``,
    ``converged``, ``diameter``) and the context: ``name``, ``run``, ``kind``, ``units``,
    ``target``, ``problem``, ``source``, ``runs`` (the runs made or read together, as Designs)."""

    #: plotly.js in the notebook view (``_repr_html_``): True embeds it (about 4.5 MB per shown
    #: design, works offline), "cdn" links it, None shows the table of key numbers only
    html_plotlyjs = True

    def __init__(self, context: Context, run: str):
        self._context = context
        self.run = run

    @property
    def result(self) -> Result:
        """The design layer's Result of this run."""
        return self._context.runs[self.run]

    # -- the run's figures (the Result's, a few from its routing)
    method = _of("result", "method", "The method that made this run (nlp, greedy, forward, fit, multishape, tip, ...).")
    status = _of("result", "status", 'Solver status: "optimal", "acceptable", "max_iter", "failed", ...')
    converged = _of("result", "converged", "Whether the solver reached its tolerance (status optimal or acceptable).")
    clear = _of("result", "clear", "Whether the design meets every hard requirement of its problem (bounds, obstacle margin, clearance).")
    ok = _of("result", "ok", "Converged and clear: what the command line's exit status 0 means.")
    shortfall = _of("result", "shortfall", "What the design misses of its problem's hard requirements, one line each (empty when clear).")
    routing = _of("result", "routing", "theta (rad), lam, length per segment and initial_pose (4 x 4).")
    phi = _of("result", "phi", "Actuator angle around the tube at the segment ends (M + 1,), phi[0] = 0.")
    shape = _of("result", "shape", "The modeled lines ``center``, ``inner`` (actuator), ``outer``, each (P, 3).")
    metrics = _of("result", "metrics", "The run's metrics as archived: rmse, max_error, tv_theta, tv_lambda, ...")
    stats = _of("result", "stats", "Solver statistics as archived: IPOPT return status, build time, objective terms, options.")
    solve_time_s = _of("result", "solve_time_s", "Wall time of the solve, in seconds.")
    iterations = _of("result", "iterations", "Solver iterations.")
    theta = _of("routing", "theta", "Drawn angle of the actuator per segment (M,), rad.")
    lam = _of("routing", "lam", "Contraction ratio lambda per segment (M,).")
    length = _of("routing", "length", "Unactuated center-line length of each segment (M,), in ``units``.")
    initial_pose = _of("routing", "initial_pose", "Base pose T^0_w (4, 4).")
    segments = _of("routing", "segments", "Number of segments M.")

    @property
    def rmse(self) -> float:
        """Root mean square distance to the paired target (or measured) points, in ``units``; nan without a target."""
        return float(self.metrics.get("rmse", math.nan))

    @property
    def max_error(self) -> float:
        """Largest distance to a paired target (or measured) point, in ``units``; nan without a target."""
        return float(self.metrics.get("max_error", math.nan))

    # -- the context
    name = _of("_problem_file", "name", "The problem's name (archived as ``/problem`` attribute ``name``).")
    kind = _of("_problem_file", "kind", "The archive kind: design, forward, fit, multishape or tip.")
    units = _of("_problem_file", "units", "Length unit of every length of this design.")
    source = _of("_problem_file", "source", "The problem text archived in /problem attrs source.")
    problem = _of("_problem_file", "problem", "The problem object solved (loaded archives: rebuilt from the archive, without solver settings).")

    @property
    def _problem_file(self) -> ProblemFile:
        return self._context.problem_file

    @property
    def diameter(self) -> float:
        """Tube diameter D, in ``units``."""
        return float(self.problem.diameter)

    @property
    def target(self) -> np.ndarray | None:
        """The target points (N, 3) of design runs (row i pairs with ``shape.center`` row i), else None."""
        return getattr(self.problem, "target", None)

    @property
    def runs(self) -> dict:
        """Every run made or read together with this one, as Designs (``design(..., clearance=...)``: nlp and nlp_clearance)."""
        return {name: Design(self._context, name) for name in self._context.runs}

    # -- output
    def save(self, path, overwrite: bool = False) -> Path:
        """Write the archive (every run in ``runs``) to ``path``, atomically.

        Parameters
        ----------
        path : str or Path
            The .h5 file. Every command (show, plot, template, analyze, view, ...) reads it.
        overwrite : bool
            Replace an existing file (else FileExistsError, as the command line without --force).

        Returns
        -------
        Path
        """
        out = output_path(path, overwrite)
        ctx = self._context
        if ctx.path is not None:  # a loaded archive: the file as it was (extra groups and attributes included)
            write_atomic(out, lambda tmp: shutil.copyfile(ctx.path, tmp))
        else:
            ctx.outcome.write(out)
        return out

    def plot(self, path=None, overwrite: bool = False):
        """The archive's figure (every run; ``vine-nlp plot``), also written to ``path`` (.png, .pdf, .svg) if given.

        Parameters
        ----------
        path : str or Path, optional
            Also write the figure there; the suffix picks the format.
        overwrite : bool
            Replace an existing file (else FileExistsError, as the command line without --force).

        Returns
        -------
        matplotlib.figure.Figure
            Not registered with pyplot: a notebook shows it once, and no backend is changed.
        """
        from vine_nlp.front import figures, plot  # matplotlib loads when a figure is asked for
        if path is not None:
            try:
                plot.figure_format(path)
            except ValueError as e:
                raise ArgumentError("path", str(e)) from None
            out = output_path(path, overwrite)
        archive = self._context.as_archive()
        # a multi-shape archive is drawn from its file (its levels are groups of their own)
        fig = self._with_file(lambda p: figures.figure(archive, p)) if archive.kind == "multishape" else figures.figure(archive)
        # a notebook shows the Figure as the cell's value even where pyplot (and with it the
        # inline backend's formatter) was never imported; with that formatter, it takes precedence
        fig._repr_png_ = functools.partial(_figure_png, fig)
        if path is not None:
            plot.save_figure(fig, out)
        return fig

    def template(self, path, paper: str = "A4", csv=None, overwrite: bool = False) -> dict:
        """The 1:1 fabrication template of this run (``vine-nlp template``): a PDF (SVG and DXF as the command allows).

        Parameters
        ----------
        path : str or Path
        paper : {"A4", "Letter"}
        csv : str or Path, optional
            Also the cut list, one row per segment.
        overwrite : bool

        Returns
        -------
        dict
            pages, strips, paper, orientation, run, segments, tube_length, ...
        """
        from vine_nlp.front import template  # matplotlib loads when a template is asked for
        if paper not in template.PAPERS_MM:
            raise ArgumentError("paper", f"must be one of {', '.join(template.PAPERS_MM)}, got {paper!r}")
        out = output_path(path, overwrite)
        csv_out = output_path(csv, overwrite, "csv") if csv is not None else None
        try:
            return template.write_template(self._context.as_archive(), out, csv_path=csv_out, paper=paper, run=self.run)
        except ValueError as e:  # what ``vine-nlp template`` refuses too (a format, units other than cm and mm)
            raise ArgumentError("template", str(e)) from None

    def _with_file(self, func):
        """``func(path)`` on this design's archive: the loaded file, or a temporary one."""
        if self._context.path is not None:
            return func(self._context.path)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "design.h5"
            self.save(path)
            return func(path)

    def summary(self) -> dict:
        """The key numbers: run, method, status, segments, tube length, RMSE, max error, solve time, iterations."""
        return {"name": self.name, "run": self.run, "method": self.method, "status": self.status, "segments": self.segments,
                "tube length": f"{float(self.length.sum()):.4g} {self.units}", "diameter": f"{self.diameter:.4g} {self.units}",
                "rmse": f"{self.rmse:.4g} {self.units}" if "rmse" in self.metrics else "-",
                "max error": f"{self.max_error:.4g} {self.units}" if "max_error" in self.metrics else "-",
                "solve time": f"{self.solve_time_s:.3f} s", "iterations": self.iterations}

    def __repr__(self) -> str:
        s = self.summary()
        err = f", rmse {s['rmse']}, max error {s['max error']}" if "rmse" in self.metrics else ""
        return f"<Design {self.name!r} run {self.run!r}: {self.status}, {self.segments} segments{err}>"

    def _repr_html_(self) -> str:
        rows = "".join(f"<tr><th style='text-align:left'>{html.escape(str(k))}</th><td style='text-align:left'>"
                       f"{html.escape(str(v))}</td></tr>" for k, v in self.summary().items())
        table = f"<table>{rows}</table>"
        if self.html_plotlyjs is None or importlib.util.find_spec("plotly") is None:
            return table
        from vine_nlp.front.view import view_html  # plotly loads when a view is shown
        return table + view_html(self._context.as_archive(), run=self.run, full_html=False, include_plotlyjs=self.html_plotlyjs)


class Project:
    """The runs of an archive (:func:`load`): ``runs`` (name -> Design), ``run()``, ``target`` and the archive's attributes."""

    def __init__(self, context: Context):
        self._context = context

    @property
    def runs(self) -> dict:
        """Every run of the archive: name -> Design."""
        return {name: Design(self._context, name) for name in self._context.runs}

    def run(self, name: str | None = None) -> Design:
        """The run ``name``, by default the one every command uses (nlp, nlp_robust, ..., forward, fit).

        Parameters
        ----------
        name : str, optional
            A run of the archive (a key of ``runs``).

        Returns
        -------
        Design

        Raises
        ------
        ArgumentError
            The archive has no run ``name``.
        """
        archive = self._context.archive
        name = name if name is not None else archive.default_run()
        if name not in self._context.runs:
            raise ArgumentError("name", f"no run {name!r} in the archive (runs: {', '.join(self._context.runs) or 'none'})")
        return Design(self._context, name)

    @property
    def archive(self) -> Archive:
        """The archive as ``vine_nlp.io.archive.load_archive`` reads it."""
        return self._context.archive

    target = _of("archive", "target", "The target points (N, 3) of a design archive, else None.")
    name = _of("archive", "name", "The problem's name.")
    kind = _of("archive", "kind", "The archive kind: design, forward, fit, multishape or tip.")
    units = _of("archive", "units", "Length unit of every length in the archive.")
    diameter = _of("archive", "diameter", "Tube diameter D, in ``units``.")
    source = _of("archive", "source", "The problem text archived in ``/problem`` attribute ``source``.")
    extra = _of("archive", "extra", 'Datasets beyond the contract\'s core layout ("measured/points", "tip/position", ...).')

    def __repr__(self) -> str:
        return f"<Project {self.name!r} ({self.kind}) from {self._context.path}: runs {', '.join(self._context.runs) or 'none'}>"


def read_project(path) -> Project:
    """The runs of the archive file ``path`` (``vine_nlp.load``): ArgumentError ``path`` when it is no archive."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        archive = load_archive(path)
        runs = dict(archive.runs)
        if archive.kind == "multishape":  # its levels are groups the generic reader leaves out
            runs["multishape"] = read_multishape_archive(path)[1]
    except (OSError, KeyError, ValueError) as e:
        raise ArgumentError("path", f"cannot read the archive {str(path)!r} ({e})") from None
    pf = ProblemFile(path=str(path), source=archive.source, kind=archive.kind, name=archive.name, units=archive.units,
                     problem=problem_of_archive(archive, runs, path))
    return Project(Context(Outcome(pf, runs, tuple(runs), dict(archive.extra)), archive=archive, path=str(path)))


def _figure_png(fig, dpi: int = 110) -> bytes:
    """PNG bytes of a Figure, for notebooks (IPython's ``_repr_png_``)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def output_path(path, overwrite: bool, argument: str = "path") -> Path:
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ArgumentError(argument, "must be a file name")
    out = Path(path)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass overwrite=True to replace it")
    if not out.parent.is_dir():
        raise ArgumentError(argument, f"directory {str(out.parent)!r} does not exist")
    return out
