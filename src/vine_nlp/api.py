"""The public Python API: inverse design, forward model, fit and archives from a notebook or script.

::

    import vine_nlp as vn
    r = vn.design(points, diameter=2.43)           # points: (N, 3) array-like
    r.rmse, r.max_error, r.status, r.routing.theta, r.routing.lam, r.routing.length
    r.save("out.h5")                               # the archive every command reads
    fig = r.plot()                                 # a matplotlib Figure
    r.template("t.pdf")                            # the 1:1 fabrication template
    a = vn.load("out.h5")                          # a.runs["nlp"], a.run(), a.target

Every argument is checked before any solver runs, with the limits of the problem
files (``vine_nlp.io.problem_file``); bad input raises :class:`ArgumentError`, a
ValueError whose message starts with the argument's name (``"diameter: must be >
0"``). Solvers report trouble through ``status``, not exceptions.

Every entry point is a thin adapter: its arguments checked into a problem, ``vine_nlp.pipeline.run``,
the outcome wrapped as a :class:`Design` (the command line runs the same pipeline).
"""

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

from vine_nlp import __all__ as _API_NAMES
from vine_nlp import pipeline, targets
from vine_nlp.errors import InputError
from vine_nlp.io import limits, problems
from vine_nlp.io import validate as check
from vine_nlp.io.archive import Archive, load_archive, write_atomic
from vine_nlp.io.calibration import read_calibration
from vine_nlp.io.formulations import read_multishape_archive
from vine_nlp.io.problem_text import call_text, problem_source
from vine_nlp.io.problems import ProblemFile, design_problem_of, load_problem
from vine_nlp.model.calibration import Calibration
from vine_nlp.model.routing import MEASURED_LINES, Routing, Sigmas
from vine_nlp.pipeline import Outcome, Request
from vine_nlp.pipeline.correct import correct_files, correct_to_file
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, FitProblem, ForwardProblem, MultiShapeProblem, Result, TipProblem

# the API's names, listed once: the package exports them lazily (vine_nlp.__init__)
__all__ = [n for n in _API_NAMES if n != "__version__"]

_API_FILE = "<vine_nlp API>"  # ProblemFile.path of problems made by this API (no file behind them)
_THETA_MAX_DEG = round(math.degrees(Actuator.theta_max), 9)


class ArgumentError(ValueError):
    """Bad input to the API: ``argument`` names the argument, ``reason`` says what is wrong.

    The message is ``"<argument>: <reason>"``, the command line's ``<key>: <reason>``.
    """

    def __init__(self, argument: str, reason: str):
        self.argument = str(argument)
        self.reason = str(reason)
        super().__init__(f"{self.argument}: {self.reason}")


class _Arguments(check.SourceFile):
    """The "file" the validators of ``io.validate`` and ``io.problems`` read: the same rules and
    reasons as for problem files, reported as ArgumentError naming the API argument (``names``
    maps a problem-file key such as "actuator.theta_max_deg" to it)."""

    def __init__(self, names: dict | None = None):
        super().__init__(_API_FILE)
        self.names = names or {}

    def error(self, key: str, reason: str) -> ArgumentError:
        return ArgumentError(self.names.get(key, key), reason)


# problem-file keys -> the argument that carries them
_DESIGN_ARGUMENTS = {
    "actuator.kind": "actuator", "actuator.lambda_min": "lambda_min", "actuator.theta_max_deg": "theta_max_deg",
    "design.method": "method", "design.points_per_segment": "points_per_segment", "design.starts": "starts",
    "design.hops": "hops", "design.budget": "budget", "design.solver": "solver", "design.seed": "seed",
    "design.max_iter": "max_iter", "design.smoothness": "smoothing", "design.smoothness.theta": "smoothing",
    "design.smoothness.lambda": "smoothing", "design.correction_margin": "correction_margin",
    "design.min_feature": "min_feature", "design.base": "base", "routing.initial_pose": "base",
}


def _plain(value):
    """numpy scalars as Python numbers (the validators take what TOML gives: int, float, bool, str)."""
    return value.item() if isinstance(value, np.generic) else value


def _number(args: _Arguments, key: str, value, low=None, high=None, low_open=True, high_open=False) -> float:
    x = check.real_number(args, key, _plain(value))
    lo_ok = low is None or (x > low if low_open else x >= low)
    hi_ok = high is None or (x < high if high_open else x <= high)
    if not (lo_ok and hi_ok):
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        if high is None:
            rule = f"must be {'>' if low_open else '>='} {low:g}"
        elif low is None:
            rule = f"must be {'<' if high_open else '<='} {high:g}"
        else:
            rule = f"must be in {left}{low:g}, {high:g}{right}"
        raise args.error(key, f"{rule}, got {x:g}")
    return x


def _integer(args: _Arguments, key: str, value, least: int) -> int:
    return check.integer(args, key, _plain(value), least)


def _name_units(args: _Arguments, name, units) -> tuple[str, str]:
    name = check.nonempty_text(args, "name", name)
    units = check.nonempty_text(args, "units", units)
    if len(units) > 32:  # the archive reader takes unit names of up to 32 characters
        raise args.error("units", "must be a unit name of at most 32 characters")
    return name, units


def _diameter(diameter) -> float:
    return _number(_Arguments(), "diameter", diameter, low=0.0)


def _points(value, key: str = "points", least: int = 3, ordered: bool = True) -> np.ndarray:
    """(N, 3) float points (2-D columns mean z = 0), with the problem files' rules for targets
    (``ordered``: ``targets.check_points``) or for measured points (finite, at least ``least``)."""
    try:
        p = targets.check_points(value) if ordered else targets._as_3d(value, least=least)
    except ValueError as e:
        raise ArgumentError(key, str(e)) from None
    finite = np.all(np.isfinite(p), axis=1)
    if not finite.all():
        raise ArgumentError(key, f"point {int(np.argmin(finite)) + 1} is not finite")
    if p.shape[0] > limits.MAX_TARGET_POINTS:
        raise ArgumentError(key, f"has {p.shape[0]} points; at most {limits.MAX_TARGET_POINTS}")
    return p


def _smoothness(value) -> dict:
    """``smoothing``: one weight for theta and lambda, a pair (theta, lambda) or a dict with keys theta, lambda."""
    if value is None:
        return {}
    if isinstance(value, dict):
        unknown = [k for k in value if k not in ("theta", "lambda")]
        if unknown:
            raise ArgumentError("smoothing", f"unknown key {unknown[0]!r}; the keys are 'theta' and 'lambda'")
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != 2:
            raise ArgumentError("smoothing", "must be a number, a pair (theta, lambda) or a dict")
        return {"theta": _plain(value[0]), "lambda": _plain(value[1])}
    return {"theta": _plain(value), "lambda": _plain(value)}


def _design_problem(points, diameter, *, actuator, theta_max_deg, lambda_min, points_per_segment, smoothing, starts, hops,
                    method, seed, units, name, budget=DesignOptions.budget, solver=DesignOptions.solver, correction_margin=None,
                    min_feature=None, base="free") -> DesignProblem:
    args = _Arguments(_DESIGN_ARGUMENTS)
    name, units = _name_units(args, name, units)
    D = _diameter(diameter)
    table = {"kind": actuator}
    if lambda_min is not None:
        table["lambda_min"] = _plain(lambda_min)
    if theta_max_deg is not None:
        table["theta_max_deg"] = _plain(theta_max_deg)
    act = problems._actuator(args, table)
    options = {"method": method, "points_per_segment": points_per_segment, "starts": starts, "hops": hops, "seed": seed,
               "budget": budget, "solver": solver}
    options = {k: _plain(v) for k, v in options.items()}
    smooth = _smoothness(smoothing)
    if smooth:
        options["smoothness"] = smooth
    opts = problems._options(args, options)
    # buildable designs: the problem file's [design] keys and rules; a fixed base is given as its pose
    build = {k: _plain(v) for k, v in (("correction_margin", correction_margin), ("min_feature", min_feature)) if v is not None}
    if isinstance(base, str) and base == "fixed":
        raise ArgumentError("base", '"fixed" needs a base pose: pass the pose (4 x 4) as base')
    pose = {} if isinstance(base, str) else {"routing": {"initial_pose": np.asarray(base, dtype=object).tolist()}}
    opts = problems._build_options(args, pose, build | {"base": base if isinstance(base, str) else "fixed"}, act, opts)
    target = _points(points)
    n, N = opts.points_per_segment, target.shape[0]
    if N < n + 1:
        raise ArgumentError("points", f"needs at least points_per_segment + 1 = {n + 1} points, got {N}")
    segments = math.ceil((N - 1) / n)
    if segments > limits.MAX_SEGMENTS:  # the archive readers' limit: a larger design could not be read back
        raise ArgumentError("points", f"{N} points at points_per_segment = {n} give {segments} segments; at most {limits.MAX_SEGMENTS}")
    return DesignProblem(name=name, diameter=D, target=target, actuator=act, options=opts, units=units)


def _sigmas(robust) -> Sigmas:
    """``robust``: a Sigmas, or a dict with any of theta_deg, lambda, length (relative) or length_abs (in units)."""
    if isinstance(robust, Sigmas):
        values = {"theta": robust.theta, "lambda": robust.lam, "length": robust.length}
    elif isinstance(robust, dict):
        keys = ("theta_deg", "lambda", "length", "length_abs")
        unknown = [k for k in robust if k not in keys]
        if unknown:
            raise ArgumentError("robust", f"unknown key {unknown[0]!r}; the keys are {', '.join(keys)}")
        if "length" in robust and "length_abs" in robust:
            raise ArgumentError("robust", "give length (relative) or length_abs (in units), not both")
        values = {k: robust[k] for k in robust}
    else:
        raise ArgumentError("robust", "must be a Sigmas or a dict with keys theta_deg, lambda, length or length_abs")
    args = _Arguments()
    checked = {k: _number(args, f"robust: {k}", v, low=0.0, low_open=False) for k, v in values.items()}
    if not any(v > 0 for v in checked.values()):
        raise ArgumentError("robust", "every sigma is 0: there is no construction error to be robust against")
    if isinstance(robust, Sigmas):
        return robust
    relative = "length_abs" not in checked
    length = checked.get("length_abs", checked.get("length", 0.0))
    return Sigmas.from_degrees(checked.get("theta_deg", 0.0), checked.get("lambda", 0.0), length, relative_length=relative)


# ---------------------------------------------------------------- results


@dataclasses.dataclass(eq=False)
class _Context:
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
    ``target``, ``problem``, ``source``, ``runs`` (the runs made or read together, as Designs).
    """

    #: plotly.js in the notebook view (``_repr_html_``): True embeds it (about 4.5 MB per shown
    #: design, works offline), "cdn" links it, None shows the table of key numbers only
    html_plotlyjs = True

    def __init__(self, context: _Context, run: str):
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
        out = _output(path, overwrite)
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
            out = _output(path, overwrite)
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
        out = _output(path, overwrite)
        csv_out = _output(csv, overwrite, "csv") if csv is not None else None
        if self.units not in ("cm", "mm"):
            raise ArgumentError("units", f"a 1:1 template needs lengths in cm or mm, not {self.units!r}")
        return template.write_template(self._context.as_archive(), out, csv_path=csv_out, paper=paper, run=self.run)

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
        return {
            "name": self.name, "run": self.run, "method": self.method, "status": self.status, "segments": self.segments,
            "tube length": f"{float(self.length.sum()):.4g} {self.units}",
            "diameter": f"{self.diameter:.4g} {self.units}",
            "rmse": f"{self.rmse:.4g} {self.units}" if "rmse" in self.metrics else "-",
            "max error": f"{self.max_error:.4g} {self.units}" if "max_error" in self.metrics else "-",
            "solve time": f"{self.solve_time_s:.3f} s", "iterations": self.iterations,
        }

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

    def __init__(self, context: _Context):
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


def _figure_png(fig, dpi: int = 110) -> bytes:
    """PNG bytes of a Figure, for notebooks (IPython's ``_repr_png_``)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _output(path, overwrite: bool, argument: str = "path") -> Path:
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ArgumentError(argument, "must be a file name")
    out = Path(path)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass overwrite=True to replace it")
    if not out.parent.is_dir():
        raise ArgumentError(argument, f"directory {str(out.parent)!r} does not exist")
    return out


def _calibration(value):
    """A Calibration from a Calibration or the path of a CAL.toml (``vine-nlp calibrate``)."""
    if isinstance(value, Calibration):
        return value
    if isinstance(value, (str, os.PathLike)):
        try:
            return read_calibration(value)
        except InputError as e:
            raise ArgumentError("calibration", str(e)) from None
    raise ArgumentError("calibration", f"must be a Calibration or the path of a calibration TOML file, got {type(value).__name__}")


def _run(problem, call: str, request: Request | None = None, notes=()) -> Design:
    """The pipeline on a problem object made by this API: its outcome as a Design of the last run asked for.
    A request the problem cannot take is an ArgumentError naming the option (the command line's error)."""
    pf = ProblemFile(path=_API_FILE, source=problem_source(problem, call, notes), kind=_KIND[type(problem)], name=problem.name,
                     units=problem.units, problem=problem)
    try:
        outcome = pipeline.run(pf, request)
    except InputError as e:
        raise ArgumentError(e.key, e.reason) from None
    return Design(_Context(outcome), outcome.last)


_KIND = {DesignProblem: "design", ForwardProblem: "forward", FitProblem: "fit", MultiShapeProblem: "multishape", TipProblem: "tip"}


# ---------------------------------------------------------------- entry points


def design(points, diameter, *, actuator: str = Actuator.kind, theta_max_deg: float = _THETA_MAX_DEG, lambda_min: float | None = None,
           points_per_segment: int = DesignOptions.points_per_segment, smoothing=None, starts: int = DesignOptions.starts,
           hops: int = DesignOptions.hops, budget: float = DesignOptions.budget, solver: str = DesignOptions.solver,
           method: str = DesignOptions.method, clearance: float | None = None, robust=None, robust_weight: float = 1.0,
           seed: int = DesignOptions.seed, workers: int = 1, units: str = "cm", name: str = "design", calibration=None,
           correction_margin: float | None = None, min_feature: float | None = None, base="free") -> Design:
    """Inverse design: the actuator routing whose tube follows ``points`` (``vine-nlp design``).

    Parameters
    ----------
    points : array_like, (N, 3) or (N, 2)
        Target center line in order, finite, no two consecutive points equal; 2-D points mean z = 0.
        N >= points_per_segment + 1.
    diameter : float
        Tube diameter D (> 0), in ``units``.
    actuator : {"tendon", "programmed", "spam"}
        "spam": one lambda for the whole actuator.
    theta_max_deg : float
        Bound on |theta|, in (0, 90) degrees.
    lambda_min : float, optional
        Lower bound on lambda, in (0, 1]; default 0.4 (spam: 0.5), as in problem files.
    points_per_segment : int
        n, target points per segment (>= 1): M = ceil((N - 1) / n) segments.
    smoothing : float or (float, float) or dict, optional
        Smoothness weights of theta and lambda (>= 0); default that of ``DesignOptions``.
    starts, hops : int
        nlp: multi-start count (>= 1) and rounds of basin hopping (>= 0).
    budget : float
        nlp: seconds for the corner search that runs where the first solve finds a corner-like
        target (>= 0; 0 turns it off), as ``[design] budget`` and ``--budget``.
    solver : {"auto", "ipopt"}
        Both IPOPT (``[design] solver``; the key is kept for existing files).
    method : {"nlp", "greedy"}
    clearance : float, optional
        Also a design keeping the tube clear of itself by this gap beyond D (>= 0, ``units``):
        run ``nlp_clearance`` (the returned one).
    robust : Sigmas or dict, optional
        Also a design minimizing the expected error under construction errors: run ``nlp_robust``
        (the returned one). Dict keys: ``theta_deg``, ``lambda``, ``length`` (relative) or
        ``length_abs`` (``units``).
    robust_weight : float
        Weight of the expected error increase (>= 0).
    seed : int
        Seed of the multi-start and basin hopping (>= 0).
    workers : int
        nlp: processes for the starts (>= 1).
    units : str
        Length units of points and diameter, archived ("cm" for templates; "mm" works too).
    name : str
        Problem name in the archive.
    calibration : Calibration or str or Path, optional
        The systematic construction errors of the builder (``vine-nlp calibrate``'s CAL.toml, or a
        ``vine_nlp.model.calibration.Calibration``): the nlp or greedy run is then the nominal to build,
        its shape what that nominal realizes on the calibrated robot (as ``vine-nlp design`` with a
        ``[calibration]`` table).
    correction_margin : float, optional
        nlp: every lambda is exactly 1 (no actuator) or inside [lambda_min + margin, 1 - margin] (>= 0, leaving
        room); default 0.05, at most (1 - lambda_min) / 2 (``[design] correction_margin``).
    min_feature : float, optional
        nlp: no stopper gap, pinch or piece shorter (>= 0, ``units``); default 2 mm (``[design] min_feature``).
    base : "free" or array_like (4, 4)
        nlp: "free", the design chooses the base pose with no arbitrary roll; a pose: the base is fixed there
        (``[design] base = "fixed"`` with ``[routing] initial_pose``).

    Returns
    -------
    Design
        The last run made (nlp or greedy; nlp_clearance with ``clearance``; nlp_robust with
        ``robust``); ``runs`` holds all of them, ``save`` writes them all.

    Raises
    ------
    ArgumentError
        A ValueError naming the bad argument, before any solver runs.
    """
    problem = _design_problem(points, diameter, actuator=actuator, theta_max_deg=theta_max_deg, lambda_min=lambda_min,
                              points_per_segment=points_per_segment, smoothing=smoothing, starts=starts, hops=hops,
                              method=method, seed=seed, units=units, name=name, budget=budget, solver=solver,
                              correction_margin=correction_margin, min_feature=min_feature, base=base)
    args = _Arguments()
    workers = _integer(args, "workers", workers, 1)
    min_gap = None if clearance is None else _number(args, "clearance", clearance, low=0.0, low_open=False)
    sigmas = None if robust is None else _sigmas(robust)
    weight = _number(args, "robust_weight", robust_weight, low=0.0, low_open=False)
    if calibration is not None:
        problem = dataclasses.replace(problem, calibration=_calibration(calibration))

    notes = []
    if min_gap is not None:
        notes.append(f"clearance: min_gap = {min_gap!r} (run nlp_clearance)")
    if sigmas is not None:
        notes.append(f"robust: weight = {weight!r}, sigmas {sigmas.as_dict()} (run nlp_robust)")
    call = call_text("design", diameter=problem.diameter, actuator=problem.actuator.kind, method=problem.options.method)
    return _run(problem, call, Request(robust=sigmas, robust_weight=weight, clearance=min_gap, workers=workers), notes)


def _per_segment(args, key, value, m):
    v = np.asarray(_plain(value) if np.ndim(value) == 0 else value, dtype=object)
    if v.ndim > 1:
        raise ArgumentError(key, f"must be a number or a 1-D array (one value per segment), got shape {v.shape}")
    items = [v.item()] if v.ndim == 0 else list(v)
    out = np.array([check.real_number(args, key, _plain(x)) for x in items], dtype=float)
    if v.ndim == 0:
        return np.full(m, out[0])
    if out.size != m:
        raise ArgumentError(key, f"needs {m} values (one per segment), got {out.size}")
    return out


def _routing(theta, lam, length, *, segments=None, initial_pose=None, argument_prefix="") -> Routing:
    """A Routing from scalars or per-segment arrays, with the rules of [routing] in problem files."""
    args = _Arguments()

    def key(k):
        return f"{argument_prefix}{k}"

    sizes = {k: np.size(v) for k, v in (("theta", theta), ("lam", lam), ("length", length)) if np.ndim(v) > 0}
    if segments is not None:
        m = _integer(args, key("segments"), segments, 1)
    elif sizes:
        m = next(iter(sizes.values()))
    else:
        m = 1
    if m < 1:
        raise ArgumentError(key(next(iter(sizes))), "needs at least one value (one per segment)")
    if m > limits.MAX_SEGMENTS:
        raise ArgumentError(key("segments"), f"gives more than {limits.MAX_SEGMENTS} segments")
    th = _per_segment(args, key("theta"), theta, m)
    la = _per_segment(args, key("lam"), lam, m)
    dl = _per_segment(args, key("length"), length, m)
    for k, ok, rule, shown, unit in (
        ("theta", np.abs(th) < math.pi / 2, "|theta| must be < 90 deg", np.degrees(th), " deg"),
        ("lam", (la > 0) & (la <= 1), "must be in (0, 1]", la, ""),
        ("length", dl > 0, "must be > 0", dl, ""),
    ):
        if not ok.all():
            j = int(np.argmin(ok))
            raise ArgumentError(key(k), f"{rule} (segment {j + 1}: {shown[j]:.6g}{unit})")
    pose = np.eye(4)
    if initial_pose is not None:
        a = np.asarray(initial_pose, dtype=object)
        value = [[_plain(x) for x in row] for row in a.tolist()] if a.ndim == 2 else a.tolist()
        pose = check.rigid_pose(args, key("initial_pose"), value)
    return Routing(theta=th, lam=la, length=dl, initial_pose=pose)


def forward(theta, lam, length, diameter, *, segments: int | None = None, initial_pose=None, units: str = "cm",
            name: str = "forward") -> Design:
    """The shape of a given routing (``vine-nlp forward``).

    ``theta``, ``lam`` and ``length`` are per segment, each a number or a 1-D array; numbers
    are repeated over the segments, so ``length`` is each segment's length (not the tube's).
    The number of segments M is the arrays' common size, or ``segments`` when all three are
    numbers (default 1). Example: 60 segments of 1 cm, theta 5 deg, lambda 0.8:
    ``vn.forward(np.radians(5), 0.8, 1.0, 2.43, segments=60)``.

    Parameters
    ----------
    theta : float or array_like (M,)
        Actuator angle to the tube axis, rad, |theta| < pi/2.
    lam : float or array_like (M,)
        Contraction, in (0, 1].
    length : float or array_like (M,)
        Unactuated center-line length of each segment (> 0), in ``units``.
    diameter : float
        Tube diameter (> 0).
    segments : int, optional
        M when theta, lam and length are all numbers.
    initial_pose : array_like (4, 4), optional
        T^0_w, a rigid transform (default identity).
    units, name : str

    Returns
    -------
    Design
        Run ``forward``: shape at every segment end (and inside), no rmse (nan).

    Raises
    ------
    ArgumentError
    """
    args = _Arguments()
    name, units = _name_units(args, name, units)
    D = _diameter(diameter)
    routing = _routing(theta, lam, length, segments=segments, initial_pose=initial_pose)
    # the forward shape is sampled in pieces of at most D/4 (model.shape.forward_shape); the archive
    # readers take at most MAX_SHAPE_POINTS rows
    rows = int(np.maximum(1, np.ceil(routing.length / (0.25 * D))).sum()) + 1
    if rows > limits.MAX_SHAPE_POINTS:
        raise ArgumentError("length", f"a tube {float(routing.length.sum()) / D:.4g} diameters long has a shape of {rows} "
                                      f"points (pieces of D/4); at most {limits.MAX_SHAPE_POINTS}")
    problem = ForwardProblem(name=name, diameter=D, routing=routing, units=units)
    return _run(problem, call_text("forward", diameter=D, segments=routing.segments))


def fit(points, routing, diameter, *, line: str = "outer", free=("lambda",), starts: int = 24, seed: int = 0,
        units: str = "cm", name: str = "fit") -> Design:
    """Fit the model of a known routing to measured points: the rigid pose and, if free, lambda (``vine-nlp fit``).

    Parameters
    ----------
    points : array_like, (K, 3) or (K, 2)
        Measured points along ``line``, in any order and any pose, finite, at least 3.
    routing : Routing or Design or dict
        The routing that was built; a dict has keys theta, lam, length (and optionally
        segments, initial_pose) as :func:`forward` takes them. Its lambda starts the fit.
    diameter : float
    line : {"center", "inner", "outer"}
        Which line of the tube was measured.
    free : sequence of str
        What is estimated besides the pose: () or ("lambda",).
    starts : int
        Starting orientations of the global pose search (>= 1).
    seed : int
    units, name : str

    Returns
    -------
    Design
        Run ``fit``: metrics rmse, max_error, r2, lambda; ``save`` archives the measured points.

    Raises
    ------
    ArgumentError
    """
    args = _Arguments()
    name, units = _name_units(args, name, units)
    D = _diameter(diameter)
    measured = _points(points, least=3, ordered=False)
    if isinstance(routing, Design):
        routing = routing.routing
    elif isinstance(routing, dict):
        unknown = [k for k in routing if k not in ("theta", "lam", "length", "segments", "initial_pose")]
        if unknown:
            raise ArgumentError("routing", f"unknown key {unknown[0]!r}; the keys are theta, lam, length, segments, initial_pose")
        missing = [k for k in ("theta", "lam", "length") if k not in routing]
        if missing:
            raise ArgumentError("routing", f"missing key {missing[0]!r}")
        routing = _routing(routing["theta"], routing["lam"], routing["length"], segments=routing.get("segments"),
                           initial_pose=routing.get("initial_pose"), argument_prefix="routing: ")
    elif not isinstance(routing, Routing):
        raise ArgumentError("routing", "must be a Routing, a Design or a dict with theta, lam, length")
    line = check.choice(args, "line", line, MEASURED_LINES)
    free = (free,) if isinstance(free, str) else tuple(free)
    for item in free:
        check.choice(args, "free", item, problems._FREE_CHOICES)
    if len(set(free)) != len(free):
        raise ArgumentError("free", "lists a parameter twice")
    starts = _integer(args, "starts", starts, 1)
    seed = _integer(args, "seed", seed, 0)
    problem = FitProblem(name=name, diameter=D, measured=measured, line=line, routing=routing, free=free, units=units)
    try:
        return _run(problem, call_text("fit", diameter=D, line=line, free=free), Request(fit_starts=starts, seed=seed))
    except ValueError as e:  # too few usable points for the model (the command line's measured.file error)
        if isinstance(e, ArgumentError):
            raise
        raise ArgumentError("points", str(e)) from None


def solve(problem, method: str | None = None, *, starts: int | None = None, hops: int | None = None, budget: float | None = None,
          workers: int = 1, robust=None, robust_weight: float = 1.0, clearance: float | None = None) -> Design:
    """What ``vine-nlp design PROBLEM`` runs (``forward``, ``fit`` for those problems), from a problem file or object.

    Every run the problem asks for (obstacles, calibration; robust and clearance when asked), judged
    against its hard requirements; ``save`` writes the archive the command line writes.

    Parameters
    ----------
    problem : str or Path or DesignProblem or ForwardProblem or FitProblem or MultiShapeProblem or TipProblem
        A problem file (TOML, as the command line reads it) or a problem object.
    method : {"nlp", "greedy"}, optional
        Design problems: the design method (default: the problem's).
    starts, hops, budget, workers
        The nlp design's multi-start, basin hopping, corner-search budget and processes (default: the problem's).
    robust : Sigmas or dict, optional
        Also a robust design (run ``nlp_robust``), as :func:`design`.
    robust_weight : float
        Weight of the robust design's expected error increase.
    clearance : float, optional
        Also a design clear of itself by this gap beyond D (run ``nlp_clearance``).

    Returns
    -------
    Design
        The last run asked for (``runs`` holds every run).

    Raises
    ------
    ArgumentError
        A bad problem file (the argument ``problem``, with the file's key and reason) or object, or an
        option the problem cannot take (named).
    """
    args = _Arguments()
    rq = Request(methods=(method,) if method is not None else (), robust=None if robust is None else _sigmas(robust),
                 robust_weight=_number(args, "robust_weight", robust_weight, low=0.0, low_open=False),
                 clearance=None if clearance is None else _number(args, "clearance", clearance, low=0.0, low_open=False),
                 starts=None if starts is None else _integer(args, "starts", starts, 1),
                 hops=None if hops is None else _integer(args, "hops", hops, 0),
                 budget=None if budget is None else _number(args, "budget", budget, low=0.0, low_open=False),
                 workers=_integer(args, "workers", workers, 1))
    if isinstance(problem, (str, os.PathLike)):
        try:
            pf = load_problem(problem)
            outcome = pipeline.run(pf, rq)
        except InputError as e:
            raise ArgumentError("problem", str(e)) from None
        return Design(_Context(outcome), outcome.last)
    if type(problem) not in _KIND:
        raise ArgumentError("problem", f"must be a problem file or a problem object ({', '.join(k.__name__ for k in _KIND)}), "
                                       f"got {type(problem).__name__}")
    _diameter(problem.diameter)
    if isinstance(problem, DesignProblem):
        # the rules of vine_nlp.design(...) and of problem files; the problem is solved as given
        a, o = problem.actuator, problem.options
        _design_problem(problem.target, problem.diameter, actuator=a.kind, theta_max_deg=math.degrees(a.theta_max),
                        lambda_min=a.lambda_min, points_per_segment=o.points_per_segment,
                        smoothing=(o.smooth_theta, o.smooth_lambda), starts=o.starts, hops=o.hops, method=o.method,
                        seed=o.seed, units=problem.units, name=problem.name, budget=o.budget, solver=o.solver,
                        correction_margin=o.correction_margin, min_feature=o.min_feature,
                        base=o.base if o.base_pose is None else o.base_pose)
    if isinstance(problem, (ForwardProblem, FitProblem)):
        r = problem.routing
        _routing(r.theta, r.lam, r.length, initial_pose=r.initial_pose, argument_prefix="routing: ")
    return _run(problem, call_text("solve", problem=type(problem).__name__, method=method), rq)


def load(path) -> Project:
    """The runs of an archive written by any command or by ``Design.save``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Project
        ``runs`` (name -> Design), ``run()`` (the default run), ``target``, ``archive``.

    Raises
    ------
    FileNotFoundError
        No such file.
    ArgumentError
        Not a vine_nlp result archive.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise ArgumentError("path", "must be a file name")
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
                     problem=_problem_of(archive, runs, path))
    outcome = Outcome(pf, runs, tuple(runs), dict(archive.extra))
    return Project(_Context(outcome, archive=archive, path=str(path)))


def _problem_of(archive: Archive, runs: dict, path):
    """A problem object for a loaded archive: what the archive holds of it (solver settings stay in ``source``)."""
    first = next(iter(runs.values()), None)
    if archive.kind == "design" and archive.target is not None:
        return design_problem_of(archive, path)
    if archive.kind == "forward" and first is not None:
        return ForwardProblem(archive.name, archive.diameter, first.routing, units=archive.units)
    if archive.kind == "fit" and first is not None and "measured/points" in archive.extra:
        line = first.stats.get("line")
        return FitProblem(archive.name, archive.diameter, np.asarray(archive.extra["measured/points"]),
                          line if line in MEASURED_LINES else "outer", first.routing, units=archive.units)
    # other kinds: the parts every archive has
    return _Loaded(name=archive.name, diameter=archive.diameter, units=archive.units, target=archive.target)


@dataclasses.dataclass(frozen=True)
class _Loaded:
    """The problem of an archive whose problem type is not rebuilt (multishape, tip, unknown kinds)."""

    name: str
    diameter: float
    units: str
    target: np.ndarray | None = None


def correct(archive, measured, *, run=None, lines=("outer",), adjust=None, free_pose=False, sigmas=None,
            measurement_sigma=None, output=None):
    """Measure-and-correct a built robot (``vine-nlp correct``): estimate what was built, then the routing to build next.

    Parameters
    ----------
    archive : str or Path
        The design archive whose run was built, or a correction archive (its earlier measurements are used too).
    measured : list
        CSV files of points measured on the built robot (rows x y z, any order), or (K, 3) arrays.
    run : str, optional
        The run that was built (default: the archive's default run; ``corrected`` in a correction archive).
    lines : tuple of str
        The measured line ("center", "inner" or "outer"): one for all, or one per measurement.
    adjust : tuple of str, optional
        The route taken: ("lambda",) (stoppers or pinches on this robot) or ("lambda", "theta") (the line drawn anew);
        default: the recommended one (both routes are in ``routes``).
    free_pose : bool
        Also estimate the rigid pose of the measurement.
    sigmas : Sigmas, optional
        The construction errors' standard deviations (the estimate's prior).
    measurement_sigma : float, optional
        Standard deviation of the measurement noise, in the archive's units.
    output : str or Path, optional
        Where to write the correction archive (``/runs/as_built``, ``/runs/corrected``, every measurement).

    Returns
    -------
    CorrectionResult
        ``estimate`` (deviations, systematic parts and their standard errors), ``as_built`` and ``corrected``
        (Results), ``built`` (the routing that was built).

    Raises
    ------
    vine_nlp.errors.InputError
        A bad archive or measurement file, an unknown run, mismatched lines (the command line's errors).
    """
    kw = dict(run=run, lines=tuple(lines), adjust=adjust and tuple(adjust), free_pose=free_pose, sigmas=sigmas, measurement_sigma=measurement_sigma)
    if output is not None:
        return correct_to_file(archive, list(measured), output, **kw)
    return correct_files(archive, list(measured), **kw)[0]
