"""One registry of formulations: name -> problem type, solve, archive writer, report and figure.

The command line, sweeps and the Python API (``vine_nlp.api``) look a formulation
up here, so adding one touches this file only. Every entry has the same calling
conventions, whatever the function behind it:

* ``solve(problem, **options) -> (Result, extra)``: ``extra`` holds arrays to
  archive beside the run, keyed by archive path (the fit's ``measured/...``;
  ``{}`` for the others). Options a formulation does not take raise TypeError.
  It runs with one BLAS thread (``design.blas.limited``: NumPy's and SciPy's
  threads spin beside the solver on problems this small).
* ``write_archive(path, problem_file, runs, extra=None)``: ``problem_file`` has
  ``name``, ``kind``, ``source``, ``units`` and ``problem`` (an
  ``io.problem_file.ProblemFile`` or the API's equivalent); ``runs`` maps run
  names to Results. Written atomically.
* ``report(run, result, problem, units) -> list[str]``: the lines the command
  line prints for one run.
* ``figure(archive) -> matplotlib.figure.Figure``: ``archive`` is an archive
  path or an ``io.archive.Archive`` (formulations with ``figure_needs_path``
  read extra groups from the file and take a path only). The Figure is not
  registered with pyplot.
* ``read_archive(path) -> (Archive, {run: Result})``: the archive with the full
  results of this formulation (multishape: the levels); None where
  ``io.archive.load_archive`` reads everything.

The functions are referred to by dotted name and imported when first called:
looking a formulation up costs nothing (the command line starts fast), and
CasADi or matplotlib load only when a formulation solves or draws.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from vine_nlp.methods import blas
from vine_nlp.problem import DesignProblem, FitProblem, ForwardProblem, MultiShapeProblem, TipProblem

_REFS: list = []  # every function the registry names (tests resolve them all)


class _Ref:
    """A function named by ``"module:attribute"``, imported on first call."""

    def __init__(self, target: str):
        self.target = target
        self._func = None
        _REFS.append(self)

    def resolve(self):
        if self._func is None:
            module, attr = self.target.split(":")
            self._func = getattr(importlib.import_module(module), attr)
        return self._func

    def __call__(self, *args, **kwargs):
        return self.resolve()(*args, **kwargs)

    def __repr__(self):
        return f"<{self.target}>"


def lazy(target: str) -> _Ref:
    """The function named by ``"module:attribute"``, imported on its first call (``.resolve()`` gives
    the object itself, e.g. a constant): for callers that should not load matplotlib or plotly early."""
    return _Ref(target)


@dataclass(frozen=True)
class Formulation:
    """One formulation: what it solves, how it is solved, archived, reported and drawn.

    Attributes
    ----------
    name : str
        Registry key, also the run name it writes (``/runs/<run>``) unless ``run`` says otherwise.
    problem_type : type
        The problem dataclass it solves.
    solve, write_archive, report, figure : callable
        See the module docstring for their calling conventions.
    kind : str
        ``/problem`` attribute ``kind`` of its archives.
    run : str
        Name of the run it writes.
    options : tuple of str
        Keyword options ``solve`` takes (besides the problem).
    figure_needs_path : bool
        ``figure`` reads the archive file itself (extra groups), so it takes a path only.
    read_archive : callable or None
        Reads its archives with everything the generic reader leaves out; None: the generic reader.
    """

    name: str
    problem_type: type
    solve: object
    write_archive: object
    report: object
    figure: object
    kind: str = "design"
    run: str = ""
    options: tuple = ()
    figure_needs_path: bool = False
    read_archive: object = None

    def __post_init__(self):
        if not self.run:
            object.__setattr__(self, "run", self.name)
        object.__setattr__(self, "solve", _one_blas_thread(self.solve))


# ---------------------------------------------------------------- adapters to the common conventions

_ARCHIVE = _Ref("vine_nlp.io.archive:Archive")
_WRITE_ARCHIVE = _Ref("vine_nlp.io.archive:write_archive")
_READ_MULTISHAPE = _Ref("vine_nlp.io.formulations:read_multishape_archive")
_RUN_FORWARD = _Ref("vine_nlp.methods.common:run_forward")
_FIT_PROBLEM = _Ref("vine_nlp.methods.fit:fit_problem")
_DESCRIBE_FIT = _Ref("vine_nlp.methods.fit:describe_fit")
_MULTISHAPE_REPORT = _Ref("vine_nlp.front.reports:multishape_report")
_TIP_REPORT = _Ref("vine_nlp.front.reports:tip_report")


def _one_blas_thread(solve):
    def run(problem, **options):
        with blas.limited():
            return solve(problem, **options)

    return run


def _with_empty_extra(solve):
    def run(problem, **options):
        return solve(problem, **options), {}

    return run


def _solve_fit(problem, **options):
    result, extra = _FIT_PROBLEM(problem, **options)
    return result, extra


def _solve_forward(problem):
    return _RUN_FORWARD(problem), {}


def write_standard_archive(path, problem_file, runs, extra=None) -> None:
    """The contract's archive layout: /problem, /tube, /target (design problems), /runs/<run>, extra datasets."""
    problem = problem_file.problem
    archive = _ARCHIVE(
        name=problem_file.name, kind=problem_file.kind, source=problem_file.source, diameter=problem.diameter,
        units=problem_file.units, target=getattr(problem, "target", None), runs=dict(runs), extra=dict(extra or {}),
    )
    _WRITE_ARCHIVE(path, archive)


def _single_run(writer, run):
    def write(path, problem_file, runs, extra=None):
        if list(runs) != [run] or extra:
            raise ValueError(f"a {problem_file.kind} archive holds exactly one run, {run!r}, and no extra datasets")
        writer(path, problem_file, runs[run])

    return write


def _read_multishape(path):
    archive, result, _targets = _READ_MULTISHAPE(path)
    return archive, {"multishape": result}


def _fmt(v: float, units: str) -> str:
    return f"{v:.4g} {units}"


def design_report(run, result, problem, units) -> list[str]:
    """Status, RMSE, max error, solve time and iterations of a design run (one line)."""
    m = result.metrics
    return [
        f"{run}: {result.status}, RMSE {_fmt(m['rmse'], units)}, max error {_fmt(m['max_error'], units)}, "
        f"solve time {result.solve_time_s:.3f} s, {result.iterations} iterations"
    ]


def forward_report(run, result, problem, units) -> list[str]:
    """Segments, tube length and tip position of a forward run (one line)."""
    r = result.routing
    tip = ", ".join(f"{v:.4g}" for v in result.shape.center[-1])
    return [f"{run}: {r.segments} segments, tube length {_fmt(float(r.length.sum()), units)}, tip at ({tip}) {units}"]


def fit_report(run, result, problem, units) -> list[str]:
    """What was fitted and how well (one line)."""
    return [f"{run}: " + _DESCRIBE_FIT(result, units)]


def _multishape_report(run, result, problem, units) -> list[str]:
    return _MULTISHAPE_REPORT(result, units)


def _tip_report(run, result, problem, units) -> list[str]:
    return _TIP_REPORT(result, problem, units)


_plot_archive = _Ref("vine_nlp.front.plot:plot_archive")

_DESIGN = dict(problem_type=DesignProblem, write_archive=write_standard_archive, report=design_report, figure=_plot_archive)

FORMULATIONS: dict[str, Formulation] = {
    f.name: f
    for f in (
        Formulation("nlp", solve=_with_empty_extra(_Ref("vine_nlp.methods.nlp:design_nlp")),
                    options=("starts", "workers", "warm", "progress", "hops"), **_DESIGN),
        Formulation("greedy", solve=_with_empty_extra(_Ref("vine_nlp.methods.greedy:design_greedy")),
                    options=("progress",), **_DESIGN),
        # clearance and robust start from a design (``start=``, default: design_nlp's)
        Formulation("clearance", run="nlp_clearance",
                    solve=_with_empty_extra(_Ref("vine_nlp.methods.clearance:design_with_clearance")),
                    options=("min_gap", "start", "starts", "workers", "hops"), **_DESIGN),
        Formulation("robust", run="nlp_robust", solve=_with_empty_extra(_Ref("vine_nlp.methods.robust:design_robust")),
                    options=("sigmas", "weight", "samples", "seed", "start", "starts", "workers", "hops"), **_DESIGN),
        Formulation("multishape", problem_type=MultiShapeProblem, kind="multishape",
                    solve=_with_empty_extra(_Ref("vine_nlp.methods.multishape:design_multishape")),
                    write_archive=_single_run(_Ref("vine_nlp.io.formulations:write_multishape_archive"), "multishape"),
                    report=_multishape_report, figure=_Ref("vine_nlp.front.multishape_plot:plot_multishape_figure"),
                    figure_needs_path=True, options=("starts", "progress"), read_archive=_read_multishape),
        Formulation("tip", problem_type=TipProblem, kind="tip", solve=_with_empty_extra(_Ref("vine_nlp.methods.obstacles:tip_design")),
                    write_archive=_single_run(_Ref("vine_nlp.io.formulations:write_tip_archive"), "tip"),
                    report=_tip_report, figure=_plot_archive, options=("starts", "progress")),
        # the fit's own figure (front.fit_plots.plot_fit) writes a file; the archive figure shows
        # the measured points with the fitted model
        Formulation("fit", problem_type=FitProblem, kind="fit", solve=_solve_fit, write_archive=write_standard_archive,
                    report=fit_report, figure=_plot_archive, options=("starts", "seed")),
        Formulation("forward", problem_type=ForwardProblem, kind="forward", solve=_solve_forward,
                    write_archive=write_standard_archive, report=forward_report, figure=_plot_archive),
    )
}

# archive kind -> the formulation that writes and reads such archives
BY_KIND = {"design": "nlp", "forward": "forward", "fit": "fit", "multishape": "multishape", "tip": "tip"}


def formulation(name: str) -> Formulation:
    """The formulation called ``name`` (ValueError listing the names otherwise)."""
    try:
        return FORMULATIONS[name]
    except KeyError:
        raise ValueError(f"unknown formulation {name!r}; one of {', '.join(FORMULATIONS)}") from None


def for_problem(problem) -> Formulation:
    """The default formulation of a problem object: its ``options.method`` for design problems, else by type."""
    if isinstance(problem, DesignProblem):
        return formulation(problem.options.method)
    for f in FORMULATIONS.values():
        if type(problem) is f.problem_type:
            return f
    raise ValueError(f"no formulation solves a {type(problem).__name__}")


def for_kind(kind: str) -> Formulation:
    """The formulation that writes and reads archives of ``kind`` (the design writer for unknown kinds)."""
    return FORMULATIONS[BY_KIND.get(kind, "nlp")]
