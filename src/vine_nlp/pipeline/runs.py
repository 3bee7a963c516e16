"""A problem -> every run it asks for -> an :class:`Outcome` (runs, status, shortfall, archive).

The one place that decides which runs a problem makes, in which order, from which start:

- design problems: the design method(s) (``nlp``, a buildable design made from the free one:
  methods.buildable; ``greedy``, as the paper has it; ``compare``: nlp, greedy and the paper's
  low-pass-filtered greedy); among ``[[obstacles]]`` the obstacle design as run ``nlp``
  with the design of the target without the obstacles it started from as ``nlp_no_obstacles`` (buildable where
  the free design clears the obstacles, else the free design: the obstacle design starts from a pushed target);
  with a ``[load]`` (no obstacles) the design that stands under it (methods.loads; ``nlp_load`` beside the design
  on the target where it stands only far off it); then, if asked, the robust
  (``nlp_robust``) and self-clearing (``nlp_clearance``) designs, started from ``nlp`` (keeping its
  actuated segments and margins). Every run is designed for what the robot should realize; with a
  ``[calibration]`` every run then becomes the nominal to build (the systematic errors taken out,
  :func:`calibrated`);
- tip, multi-shape, forward and fit problems: their one run.

Every run is then judged against the hard requirements of its problem (:func:`judge`: the
actuator's bounds, the obstacle margin checked densely against the exact shapes, the clearance
asked for, a [load]'s sections): ``Result.shortfall`` says what it misses. The exit status is 0 only where every run
the request asked for converged and misses nothing (:attr:`Outcome.ok`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from vine_nlp.analysis.loads import fold_line, load_metrics, load_report
from vine_nlp.analysis.obstacles import obstacle_metrics, obstacle_report
from vine_nlp.io.actuators import write_actuators_archive
from vine_nlp.io.archive import Archive, write_archive
from vine_nlp.io.formulations import write_multishape_archive, write_tip_archive
from vine_nlp.io.problems import ProblemFile
from vine_nlp.methods import actuators, blas, drive, mirror, settings
from vine_nlp.methods.actuators_design import design_actuators
from vine_nlp.methods.buildable import design_buildable, first_design, missed
from vine_nlp.methods.clearance import design_with_clearance
from vine_nlp.methods.common import evaluate, pair_points, run_forward
from vine_nlp.methods.fit import fit_frames, fit_problem
from vine_nlp.methods.greedy import design_greedy, design_greedy_buildable, lowpass
from vine_nlp.methods.loads import load_runs
from vine_nlp.methods.multishape import design_multishape
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.methods.obstacles import START_RUN, design_with_obstacles, tip_design
from vine_nlp.methods.robust import design_robust
from vine_nlp.model.calibration import nominal_of, realized_of
from vine_nlp.model.shape import routing_metrics
from vine_nlp.pipeline.request import Request, check_request
from vine_nlp.problem import DesignProblem, Result

# the archived bounds hold to rounding: a design at a bound may sit this far (relative) beyond it
BOUND_TOL = 1e-9


@dataclass(eq=False)
class Outcome:
    """Every run a problem asked for, with what the archive keeps beside them.

    Attributes
    ----------
    problem_file : ProblemFile
        The problem as read (name, kind, units, source text, problem object).
    runs : dict
        Run name -> Result, in the archive's order.
    decisive : tuple of str
        The runs the request asked for: their status and requirements decide :attr:`ok`.
    extra : dict
        Further datasets of the archive (the fit's ``measured/...``, ``frames/...``).
    details : dict
        What the doors may show but the archive does not keep (the fit's per-frame results).
    """

    problem_file: ProblemFile
    runs: dict
    decisive: tuple
    extra: dict = field(default_factory=dict)
    details: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Every decisive run converged and meets every hard requirement of its problem."""
        return all(self.runs[r].ok for r in self.decisive)

    @property
    def exit_code(self) -> int:
        """0 ok, 1 otherwise (the archive is written either way)."""
        return 0 if self.ok else 1

    @property
    def last(self) -> str:
        """The last decisive run (the API's returned design)."""
        return self.decisive[-1]

    def shortfalls(self) -> list[str]:
        """One line per decisive run that is not ok: its status and what it misses."""
        out = []
        for name in self.decisive:
            r = self.runs[name]
            if not r.ok:
                why = f", the budget cut {r.stats['budget_cut']}" if "budget_cut" in r.stats else ", did not converge"
                out.append(f"{name}: {r.status}" + ("; " + "; ".join(r.shortfall) if r.shortfall else why))
        return out

    def archive(self) -> Archive:
        """The archive every door writes (its standard part: kinds with their own layout extend it on writing)."""
        pf, problem = self.problem_file, self.problem_file.problem
        return Archive(name=pf.name, kind=pf.kind, source=pf.source, diameter=problem.diameter, units=pf.units,
                       target=getattr(problem, "target", None), runs=dict(self.runs), extra=dict(self.extra),
                       obstacles=list(getattr(problem, "obstacles", ())))

    def write(self, path) -> None:
        """Write the archive atomically (the layout of the problem's kind)."""
        if self.problem_file.kind == "multishape":
            write_multishape_archive(path, self.problem_file, self.runs["multishape"])
        elif self.problem_file.kind in ("actuators", "actuators-forward"):
            write_actuators_archive(path, self.problem_file, {self.last: self.runs[self.last]})
        elif self.problem_file.kind == "tip":
            write_tip_archive(path, self.problem_file, self.runs["tip"])
        else:
            write_archive(path, self.archive())


# ---------------------------------------------------------------- the runs of each kind


def _design(problem: DesignProblem, rq: Request) -> tuple[dict, tuple, dict, dict]:
    """The design runs, in the handedness the problem's geometry picks (methods.mirror): a problem of the
    other one is designed as its mirror image and every run mirrored back, so that a problem and its mirror
    image get mirror-image designs (a calibrated problem as given: its systematic errors have a side). Among
    obstacles, where a decisive run of that handedness is not ok (not converged or not clear), the other
    handedness is designed too and the better kept (:func:`_better`): both images of a scene try the same two."""
    if problem.calibration is not None:
        return _design_as_given(problem, rq)
    flip = mirror.handedness(problem) < 0
    first = _design_in(problem, rq, flip)
    if not problem.obstacles or _all_ok(problem, first):
        return first
    second = _design_in(problem, rq, not flip)
    # the canonical handedness's try first: a tie keeps it
    tries = (first, second) if not flip else (second, first)
    best = tries[min((0, 1), key=lambda k: _better(problem, tries[k]))]
    for r in best[0].values():
        r.stats["handedness_tries"] = 2
    return best


def _design_in(problem: DesignProblem, rq: Request, flip: bool) -> tuple[dict, tuple, dict, dict]:
    """The design runs of ``problem`` (``flip``: designed as its mirror image, every run mirrored back)."""
    if not flip:
        return _design_as_given(problem, rq)
    warm = None if rq.warm is None else mirror.mirrored_routing(rq.warm)
    runs, decisive, extra, details = _design_as_given(mirror.mirrored_problem(problem), dataclasses.replace(rq, warm=warm))
    return {name: mirror.mirrored_result(r) for name, r in runs.items()}, decisive, extra, details


def _all_ok(problem, found) -> bool:
    runs, decisive = found[0], found[1]
    for name in decisive:
        judge(problem, runs[name])
    return all(runs[name].ok for name in decisive)


def _better(problem, found) -> tuple:
    """Ranks one handedness's runs: fewer decisive runs not ok, then the last decisive run's RMSE."""
    runs, decisive = found[0], found[1]
    return sum(not runs[n].ok for n in decisive), float(runs[decisive[-1]].metrics.get("rmse", np.inf))


def _design_as_given(problem: DesignProblem, rq: Request) -> tuple[dict, tuple, dict, dict]:
    methods = rq.methods or (problem.options.method,)
    runs = {}
    for m in methods:
        if m == "nlp":
            # the buildable problem in one solve where the target leaves no class to decide (issue 46), else a free design first
            kw = dict(starts=rq.starts, workers=rq.workers, warm=rq.warm, progress=rq.progress, hops=rq.hops, budget=rq.budget, note=rq.note)
            start = first_design(problem, **kw)
            if "nlp_free" in methods:  # compare: the free design kept before it, a figure only (not decisive)
                runs["nlp_free"] = design_nlp(problem, **kw) if start.stats.get("lambda_band") else start
            # the buildable design from its start (issue 31; robust and clearance keep its classes); among obstacles a
            # design that cuts one only starts theirs
            runs[m] = design_buildable(problem, start) if not problem.obstacles or _clears(problem, start) else start
        elif m == "greedy":
            runs[m] = design_greedy(problem, progress=rq.progress)
        elif m == "greedy_buildable":  # from the greedy's own design where it was made
            runs[m] = design_greedy_buildable(problem, progress=rq.progress, start=runs.get("greedy"))
        elif m == "greedy_filtered":
            runs[m] = lowpass(runs["greedy"], problem)
    decisive = tuple(r for r in runs if r != "nlp_free")
    if problem.obstacles:  # the obstacle design is run nlp; the design without obstacles it started from is kept beside it
        start = runs.pop("nlp")
        runs = {"nlp": design_with_obstacles(problem, start=start), START_RUN: start} | runs
    if problem.load is not None and "nlp" in runs and not problem.obstacles:  # among obstacles the load is judged only
        runs = load_runs(problem, runs.pop("nlp")) | runs
    if rq.robust is not None:
        runs["nlp_robust"] = _kept(problem, lambda s: design_robust(problem, rq.robust, start=s, weight=rq.robust_weight), runs["nlp"])
    if rq.clearance is not None:
        runs["nlp_clearance"] = _kept(problem, lambda s: design_with_clearance(problem, min_gap=rq.clearance, start=s), runs["nlp"])
    decisive += tuple(r for r in ("nlp_robust", "nlp_clearance") if r in runs)
    if problem.calibration is not None:
        runs = {name: calibrated(problem, r) for name, r in runs.items()}
    return runs, decisive, {}, {}


def _clears(problem: DesignProblem, result: Result) -> bool:
    return bool(obstacle_report(result.routing, problem.diameter, problem.obstacles, problem.growth, problem.obstacle_margin)["clear"])


def _kept(problem: DesignProblem, design, start: Result) -> Result:
    """``design(start)`` keeping a buildable start's classes (methods.buildable.inherited_bounds); again from its own
    answer (its lengths: the gaps' lambda bounds follow them) while the lengths it moved leave a feature below
    min_feature (settings.BUILDABLE_REPAIRS at most)."""
    res = design(start)
    for _ in range(settings.BUILDABLE_REPAIRS):
        if not (start.buildable and res.converged and any("min_feature" in line for line in missed(problem, res))):
            break
        res.buildable = True
        again = design(res)
        res = again if again.converged else res
    res.buildable = start.buildable
    return res


def _fit(problem, rq: Request):
    result, extra = fit_problem(problem, starts=rq.fit_starts, seed=rq.seed)
    details = {}
    if rq.frames:
        fits = fit_frames(problem, list(rq.frames), starts=rq.fit_starts, seed=rq.seed)
        frames = {"lambda": np.array([f.lam for f in fits]), "rmse": np.array([f.rmse for f in fits]),
                  "r2": np.array([getattr(f, "r2", np.nan) for f in fits])}
        extra = extra | {f"frames/{k}": v for k, v in frames.items()}
        details["frames"] = fits
    return {"fit": result}, ("fit",), extra, details


KINDS = {
    "design": _design,
    "forward": lambda problem, rq: ({"forward": run_forward(problem)}, ("forward",), {}, {}),
    "fit": _fit,
    "tip": lambda problem, rq: ({"tip": tip_design(problem, starts=rq.starts, progress=rq.progress)}, ("tip",), {}, {}),
    "multishape": lambda problem, rq: (
        {"multishape": design_multishape(problem, starts=rq.starts, progress=rq.progress)}, ("multishape",), {}, {}),
    "actuators": lambda problem, rq: ({"nlp": design_actuators(problem, starts=rq.starts)}, ("nlp",), {}, {}),
    "actuators-forward": lambda problem, rq: ({"forward": actuators.run_forward(problem)}, ("forward",), {}, {}),
}


def run(pf: ProblemFile, request: Request | None = None) -> Outcome:
    """Every run ``pf``'s problem asks for (module docstring), judged against its hard requirements.

    Parameters
    ----------
    pf : ProblemFile
        A problem as read from a file (``io.problems.load_problem``) or made by the API.
    request : Request, optional
        What the door asks beyond the problem (default: nothing more).

    Returns
    -------
    Outcome

    Raises
    ------
    InputError
        The request asks for something this problem cannot do.
    """
    rq = request or Request()
    check_request(pf, rq)
    with blas.limited(), drive.budget(rq.budget) as cut:  # one BLAS thread while solving (methods.blas); the caller's restored after
        runs, decisive, extra, details = KINDS[pf.kind](pf.problem, rq)
    for r in (runs[name] for name in decisive if cut):  # the budget ended a loop: the best so far, not "optimal"
        r.status, r.stats["budget_cut"] = "max_time" if r.converged else r.status, "; ".join(cut)
    for r in runs.values():
        judge(pf.problem, r)
    return Outcome(pf, runs, decisive, extra, details)


# ---------------------------------------------------------------- calibration and requirements


def calibrated(problem: DesignProblem, result: Result) -> Result:
    """A design of a calibrated problem as the nominal to build: the systematic parts taken out, clipped to
    the bounds (model.calibration.nominal_of); its shape and metrics what that nominal realizes on the
    calibrated robot. stats calibration_* (the values and the number of clipped entries)."""
    cal, a = problem.calibration, problem.actuator
    nominal, clipped = nominal_of(result.routing, cal, a.theta_max, a.lambda_min)
    realized = evaluate(problem, realized_of(nominal, cal, a.lambda_min), pair_points(problem.target, problem.options.points_per_segment), result.method)
    stats = dict(result.stats) | {
        "calibration_lambda_offset": cal.lambda_offset, "calibration_theta_offset_deg": cal.theta_offset_deg,
        "calibration_length_scale": cal.length_scale, "calibration_clipped": clipped,
        "calibration_shape": "realized by the nominal on the calibrated robot"}
    return dataclasses.replace(result, routing=nominal, shape=realized.shape, stats=stats,
                               metrics=dict(result.metrics) | realized.metrics | routing_metrics(nominal))


def judge(problem, result: Result) -> None:
    """Set ``result.shortfall``: every hard requirement of ``problem`` the result misses, one line each
    (the actuator's bounds, a several-actuator design's own: methods.actuators.shortfall; the obstacle margin, checked densely on the shape the robot realizes; the
    clearance a clearance run was asked for; a [load]: every section holds with its safety factor). Adds the
    obstacle and load metrics of problems with obstacles and loads."""
    short = list(actuators.shortfall(problem, result.lines)) if isinstance(result, actuators.ActuatorsResult) and result.method == "nlp" else []
    a, r = getattr(problem, "actuator", None), result.routing
    if a is not None and result.method not in ("forward", "fit"):
        if np.any(np.abs(r.theta) > a.theta_max * (1 + BOUND_TOL)):
            short.append(f"|theta| above its bound {np.degrees(a.theta_max):g} deg")
        if np.any(r.lam < a.lambda_min * (1 - BOUND_TOL)) or np.any(r.lam > 1 + BOUND_TOL):
            short.append(f"lambda outside [{a.lambda_min:g}, 1]")
    cal = getattr(problem, "calibration", None)
    realized = realized_of(r, cal, a.lambda_min if a else 0.0) if cal is not None else r
    short += judge_load(problem, result, realized)
    obstacles = getattr(problem, "obstacles", ())
    if obstacles:
        rep = obstacle_report(realized, problem.diameter, obstacles, problem.growth, problem.obstacle_margin)
        result.metrics.update(obstacle_metrics(rep))
        if not rep["clear"]:
            worst = min(rep["min_gap"], rep["min_gap_intermediate"])
            short.append(f"obstacle margin not kept: min gap {worst:.4g} {problem.units} < margin {problem.obstacle_margin:g}")
    short += [f"not buildable: {line}" for line in missed(problem, result)]  # the buildable rules, one line each
    if result.met.get("clearance") is False:
        need = problem.diameter + result.stats.get("min_gap", 0.0)
        short.append(f"clearance not kept: min {result.stats['min_clearance']:.4g} {problem.units} < D + min_gap = {need:.4g}")
    result.shortfall = tuple(short)


def judge_load(problem, result: Result, routing=None) -> list[str]:
    """A [load] problem's run: its load metrics (analysis.loads: load_margin, collapse_at, min_pressure) on
    ``routing`` (default the run's; the shape the robot realizes), and the line where it folds, if it does."""
    load = getattr(problem, "load", None)
    if load is None or result.method == "fit":
        return []
    rep = load_report(result.routing if routing is None else routing, problem.diameter, problem.units, load,
                      getattr(problem, "growth", "while-actuated"))
    result.metrics.update(load_metrics(rep))
    return [] if rep["holds"] else [fold_line(rep, load, problem.units)]
