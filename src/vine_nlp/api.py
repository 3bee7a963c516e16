"""The public Python API (``import vine_nlp as vn``; docs/reference/api.md): :func:`design`, :func:`forward`,
:func:`fit`, :func:`solve`, :func:`correct` and :func:`load` from a notebook or script.

Every entry point is a thin adapter: its arguments read by the problem files' reader (``vine_nlp.io``: the same
rules; bad input raises :class:`ArgumentError`, a ValueError whose message starts with the argument's name),
``vine_nlp.pipeline.run`` (the command line's), the outcome wrapped as a :class:`Design` (``vine_nlp.front.design``).
Solvers report trouble through ``status``, not exceptions."""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib

import numpy as np

from vine_nlp import __all__ as _API_NAMES
from vine_nlp import pipeline
from vine_nlp.errors import ArgumentError, InputError
from vine_nlp.front.design import Context, Design, Project, read_project
from vine_nlp.io import limits
from vine_nlp.io import validate as check
from vine_nlp.io.calibration import read_calibration
from vine_nlp.io.data_files import points_of
from vine_nlp.io.problem_text import call_text, problem_source
from vine_nlp.io.problems import FREE_CHOICES, ProblemFile, design_problem, load_problem
from vine_nlp.model.calibration import Calibration
from vine_nlp.model.routing import MEASURED_LINES, Routing, Sigmas
from vine_nlp.pipeline import Request
from vine_nlp.pipeline.correct import correct_files, correct_to_file
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, FitProblem, ForwardProblem, Load, MultiShapeProblem, Result, TipProblem  # noqa: F401, E501 (Load: re-exported)

# the API's names, listed once: the package exports them lazily (vine_nlp.__init__)
__all__ = [n for n in _API_NAMES if n != "__version__"]
_EXPORTED = (Design, Project, ArgumentError, Actuator, Calibration, DesignOptions, Result, Routing, Sigmas)  # re-exported

_API_FILE = "<vine_nlp API>"  # ProblemFile.path of problems made by this API (no file behind them)
_THETA_MAX_DEG = round(math.degrees(Actuator.theta_max), 9)
_KIND = {DesignProblem: "design", ForwardProblem: "forward", FitProblem: "fit", MultiShapeProblem: "multishape", TipProblem: "tip"}


class _Arguments(check.SourceFile):
    """The "file" the validators of ``io.validate`` and ``io.problems`` read: the same rules and
    reasons as for problem files, reported as ArgumentError naming the API argument (``names``
    maps a problem-file key such as "actuator.theta_max_deg" to it, or ``prefix`` goes before it)."""

    def __init__(self, names: dict | None = None, prefix: str = ""):
        super().__init__(_API_FILE)
        self.names, self.prefix = names or {}, prefix

    def error(self, key: str, reason: str) -> ArgumentError:  # a key inside a mapped table: the table's argument
        return ArgumentError(self.prefix + self.names.get(key, self.names.get(key.rpartition(".")[0], key)), reason)


# problem-file keys -> the argument that carries them
_DESIGN_ARGUMENTS = {"actuator.kind": "actuator", "actuator.lambda_min": "lambda_min", "actuator.theta_max_deg": "theta_max_deg",
                     "design.method": "method", "design.points_per_segment": "points_per_segment", "design.starts": "starts",
                     "design.hops": "hops", "design.budget": "budget", "design.solver": "solver", "design.seed": "seed",
                     "design.max_iter": "max_iter", "design.smoothness": "smoothing", "design.smoothness.theta": "smoothing",
                     "design.smoothness.lambda": "smoothing", "design.correction_margin": "correction_margin",
                     "design.min_feature": "min_feature", "design.base": "base", "routing.initial_pose": "base"}
_ROUTING_ARGUMENTS = {"theta": "theta", "lam": "lam", "length": "length", "initial_pose": "initial_pose"}


def _plain(value):
    """numpy scalars as Python numbers (the validators take what TOML gives: int, float, bool, str)."""
    return value.item() if isinstance(value, np.generic) else value


def _at_least(args: _Arguments, key: str, value, low: float = 0.0, strict: bool = False) -> float:
    x = check.real_number(args, key, _plain(value))
    check.check(args, key, x > low if strict else x >= low, f"must be {'>' if strict else '>='} {low:g}, got {x:g}")
    return x


def _integer(args: _Arguments, key: str, value, least: int) -> int:
    return check.integer(args, key, _plain(value), least)


def _common(args: _Arguments, name, units, diameter) -> tuple[str, str, float]:
    """name and units (the problem files' rules) and the diameter (> 0)."""
    name = check.nonempty_text(args, "name", name, limits.MAX_NAME_CHARS)
    units = check.nonempty_text(args, "units", units, limits.MAX_UNITS_CHARS)
    return name, units, _at_least(args, "diameter", diameter, strict=True)


def _smoothness(value) -> dict:
    """``smoothing``: one weight for theta and lambda, a pair (theta, lambda) or a dict with keys theta, lambda."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    pair = [value, value] if np.ndim(value) == 0 else list(value)
    if len(pair) != 2:
        raise ArgumentError("smoothing", "must be a number, a pair (theta, lambda) or a dict")
    return {"theta": _plain(pair[0]), "lambda": _plain(pair[1])}


def _design_problem(points, diameter, *, actuator, theta_max_deg, lambda_min, smoothing=None, units, name, correction_margin=None,
                    min_feature=None, base="free", calibration=None, **options) -> DesignProblem:
    """The arguments as the tables of a design problem file, read by the problem files' reader."""
    args = _Arguments(_DESIGN_ARGUMENTS)
    name, units, D = _common(args, name, units, diameter)
    given = {"lambda_min": lambda_min, "theta_max_deg": theta_max_deg, "correction_margin": correction_margin, "min_feature": min_feature}
    given = {k: _plain(v) for k, v in given.items() if v is not None}
    design = {k: _plain(v) for k, v in options.items()} | {k: given[k] for k in ("correction_margin", "min_feature") if k in given}
    if smoothing is not None:
        design["smoothness"] = _smoothness(smoothing)
    data = {"actuator": {"kind": actuator} | {k: given[k] for k in ("lambda_min", "theta_max_deg") if k in given}, "design": design}
    if isinstance(base, str):
        check.check(args, "base", base != "fixed", '"fixed" needs a base pose: pass the pose (4 x 4) as base')
        design["base"] = base
    else:
        design["base"], data["routing"] = "fixed", {"initial_pose": np.asarray(base, dtype=object).tolist()}
    problem = design_problem(args, data, name, units, D, points_of(args, "points", points, ordered=True), "points")
    return problem if calibration is None else dataclasses.replace(problem, calibration=_calibration(calibration))


def _sigmas(robust) -> Sigmas:
    """``robust``: a Sigmas, or a dict with any of theta_deg, lambda, length (relative) or length_abs (in units)."""
    keys = ("theta_deg", "lambda", "length", "length_abs")
    if isinstance(robust, Sigmas):
        values = {"theta_deg": robust.theta, "lambda": robust.lam, "length": robust.length}
    elif isinstance(robust, dict):
        unknown = [k for k in robust if k not in keys]
        if unknown:
            raise ArgumentError("robust", f"unknown key {unknown[0]!r}; the keys are {', '.join(keys)}")
        if "length" in robust and "length_abs" in robust:
            raise ArgumentError("robust", "give length (relative) or length_abs (in units), not both")
        values = dict(robust)
    else:
        raise ArgumentError("robust", "must be a Sigmas or a dict with keys theta_deg, lambda, length or length_abs")
    checked = {k: _at_least(_Arguments(prefix="robust: "), k, v) for k, v in values.items()}
    if not any(v > 0 for v in checked.values()):
        raise ArgumentError("robust", "every sigma is 0: there is no construction error to be robust against")
    if isinstance(robust, Sigmas):
        return robust
    length = checked.get("length_abs", checked.get("length", 0.0))
    return Sigmas.from_degrees(checked.get("theta_deg", 0.0), checked.get("lambda", 0.0), length, relative_length="length_abs" not in checked)


def _request(*, robust=None, robust_weight=1.0, clearance=None, workers=1, starts=None, hops=None, budget=None, **more) -> Request:
    """The runs and options asked for beside the problem's own (``vine-nlp design``'s options), checked."""
    args = _Arguments()
    return Request(robust=None if robust is None else _sigmas(robust), robust_weight=_at_least(args, "robust_weight", robust_weight),
                   clearance=None if clearance is None else _at_least(args, "clearance", clearance),
                   starts=None if starts is None else _integer(args, "starts", starts, 1),
                   hops=None if hops is None else _integer(args, "hops", hops, 0),
                   budget=None if budget is None else _at_least(args, "budget", budget), workers=_integer(args, "workers", workers, 1), **more)


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


def _routing(theta, lam, length, *, segments=None, initial_pose=None, prefix="", diameter=None) -> Routing:
    """A Routing from numbers or per-segment arrays: ``io.validate.validate_routing``, the problem files' and archives' check."""
    args = _Arguments(prefix=prefix)
    values = {}
    for key, v in (("theta", theta), ("lam", lam), ("length", length)):
        a = np.asarray(_plain(v) if np.ndim(v) == 0 else v, dtype=object)
        check.check(args, key, a.ndim <= 1, f"must be a number or a 1-D array (one value per segment), got shape {a.shape}")
        values[key] = np.array([check.real_number(args, key, _plain(x)) for x in a.reshape(-1)]).reshape(a.shape)
    m = _integer(args, "segments", segments, 1) if segments is not None else next((v.size for v in values.values() if v.ndim), 1)
    return check.validate_routing(args, **values, initial_pose=initial_pose, keys=_ROUTING_ARGUMENTS, segments=m, diameter=diameter)


def _run(problem, call: str, request: Request | None = None, notes=()) -> Design:
    """The pipeline on a problem object made by this API: its outcome as a Design of the last run asked for.
    A request the problem cannot take is an ArgumentError naming the option (the command line's error)."""
    pf = ProblemFile(path=_API_FILE, source=problem_source(problem, call, notes), kind=_KIND[type(problem)], name=problem.name,
                     units=problem.units, problem=problem)
    try:
        outcome = pipeline.run(pf, request)
    except InputError as e:
        raise ArgumentError(e.key, e.reason) from None
    return Design(Context(outcome), outcome.last)


# ---------------------------------------------------------------- entry points


def design(points, diameter, *, actuator: str = Actuator.kind, theta_max_deg: float = _THETA_MAX_DEG, lambda_min: float | None = None,
           points_per_segment: int = DesignOptions.points_per_segment, smoothing=None, starts: int = DesignOptions.starts,
           hops: int = DesignOptions.hops, budget: float | None = None, solver: str = DesignOptions.solver,
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
    budget : float, optional
        Seconds for the whole design (>= 0), as ``--budget``: no start, hop or round begins after it (the first
        start always runs) and the corner search ends within it; a design it cut short has status "max_time".
        Default: no bound, the corner search within ``[design] budget``'s default (20 s).
    solver : {"auto", "ipopt"}
        Both IPOPT (``[design] solver``; the key is kept for existing files).
    method : {"nlp", "greedy"}
    clearance : float, optional
        Also a design keeping the tube clear of itself by this gap beyond D (>= 0, ``units``):
        run ``nlp_clearance`` (the returned one).
    robust : Sigmas or dict, optional
        Also a design minimizing the expected error under construction errors: run ``nlp_robust`` (the returned one).
        Dict keys: ``theta_deg``, ``lambda``, ``length`` (relative) or ``length_abs`` (``units``).
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
        ``vine_nlp.model.calibration.Calibration``): the nlp or greedy run is then the nominal to build, its shape what
        that nominal realizes on the calibrated robot (as ``vine-nlp design`` with a ``[calibration]`` table).
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
                              method=method, seed=seed, units=units, name=name, budget=DesignOptions.budget if budget is None else budget,
                              solver=solver, correction_margin=correction_margin, min_feature=min_feature, base=base, calibration=calibration)
    rq = _request(robust=robust, robust_weight=robust_weight, clearance=clearance, workers=workers, budget=budget)
    notes = [f"clearance: min_gap = {rq.clearance!r} (run nlp_clearance)"] if rq.clearance is not None else []
    if rq.robust is not None:
        notes.append(f"robust: weight = {rq.robust_weight!r}, sigmas {rq.robust.as_dict()} (run nlp_robust)")
    call = call_text("design", diameter=problem.diameter, actuator=problem.actuator.kind, method=problem.options.method)
    return _run(problem, call, rq, notes)


def forward(theta, lam, length, diameter, *, segments: int | None = None, initial_pose=None, units: str = "cm",
            name: str = "forward") -> Design:
    """The shape of a given routing (``vine-nlp forward``).

    ``theta``, ``lam`` and ``length`` are per segment, each a number or a 1-D array; numbers are repeated over the
    segments, so ``length`` is each segment's length (not the tube's). The number of segments M is the arrays' common
    size, or ``segments`` when all three are numbers (default 1). Example: 60 segments of 1 cm, theta 5 deg, lambda 0.8:
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
    name, units, D = _common(_Arguments(), name, units, diameter)
    routing = _routing(theta, lam, length, segments=segments, initial_pose=initial_pose, diameter=D)
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
    name, units, D = _common(args, name, units, diameter)
    measured = points_of(args, "points", points, ordered=False)
    if isinstance(routing, Design):
        routing = routing.routing
    elif isinstance(routing, dict):
        inside = _Arguments(prefix="routing: ")
        check.check_keys(inside, routing, "", ("theta", "lam", "length", "segments", "initial_pose"))
        routing = _routing(*(check.required_value(inside, routing, k, "") for k in ("theta", "lam", "length")),
                           segments=routing.get("segments"), initial_pose=routing.get("initial_pose"), prefix="routing: ")
    elif not isinstance(routing, Routing):
        raise ArgumentError("routing", "must be a Routing, a Design or a dict with theta, lam, length")
    line = check.choice(args, "line", line, MEASURED_LINES)
    free = (free,) if isinstance(free, str) else tuple(free)
    for item in free:
        check.choice(args, "free", item, FREE_CHOICES)
    check.check(args, "free", len(set(free)) == len(free), "lists a parameter twice")
    starts, seed = _integer(args, "starts", starts, 1), _integer(args, "seed", seed, 0)
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
        The nlp design's multi-start, basin hopping, processes (default: the problem's) and seconds for the whole
        design, as ``--budget`` (default: none; a design it cut short has status "max_time").
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
    rq = _request(methods=(method,) if method is not None else (), robust=robust, robust_weight=robust_weight, clearance=clearance,
                  starts=starts, hops=hops, budget=budget, workers=workers)
    if isinstance(problem, (str, os.PathLike)):
        try:
            outcome = pipeline.run(load_problem(problem), rq)
        except InputError as e:
            raise ArgumentError("problem", str(e)) from None
        return Design(Context(outcome), outcome.last)
    if type(problem) not in _KIND:
        raise ArgumentError("problem", f"must be a problem file or a problem object ({', '.join(k.__name__ for k in _KIND)}), "
                                       f"got {type(problem).__name__}")
    _at_least(_Arguments(), "diameter", problem.diameter, strict=True)
    if isinstance(problem, DesignProblem):  # read as the problem file it is archived as; solved as given
        args = _Arguments(_DESIGN_ARGUMENTS)
        data = tomllib.loads(problem_source(problem, "solve"))
        design_problem(args, data, *_common(args, problem.name, problem.units, problem.diameter),
                       points_of(args, "points", problem.target, ordered=True), "points")
    if isinstance(problem, (ForwardProblem, FitProblem)):
        r = problem.routing
        _routing(r.theta, r.lam, r.length, initial_pose=r.initial_pose, prefix="routing: ")
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
    return read_project(path)


def correct(archive, measured, *, run=None, lines=("outer",), adjust=None, free_pose=False, sigmas=None,
            measurement_sigma=None, output=None, states=None):
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
    states : list of str, optional
        An archive of several actuators: the state each measurement was taken in, one per measurement or one for all
        (``--state``; not needed where the archive has one state).

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
    kw = dict(run=run, lines=tuple(lines), adjust=adjust and tuple(adjust), free_pose=free_pose, sigmas=sigmas, measurement_sigma=measurement_sigma,
              states=states)
    if output is not None:
        return correct_to_file(archive, list(measured), output, **kw)
    return correct_files(archive, list(measured), **kw)[0]
