"""Tip problems among obstacles: the tip formulation (methods.tip, fixed base) plus the obstacle rows.

Starts, tried in order until one is optimal and clear (``drive.multistart``; ``thorough``: every one): the obstacle-free
tip design, its chain pushed out of the obstacles (``push.pushed_chain``: a chain through a sphere's center gives its
rows no direction out), then the tip design's own guesses. Each start runs its own active-set loop (``design.Rounds`` on
``drive.refine``); a start whose solve reaches settings.TIP_MAX_ITER iterations is left there for the next (such a solve
could crawl on to IPOPT's limit where another start converged quickly)."""

from __future__ import annotations

import numpy as np

from vine_nlp.analysis.obstacles import obstacle_metrics
from vine_nlp.methods import drive, settings
from vine_nlp.methods.obstacles.design import Rounds
from vine_nlp.methods.obstacles.plan import Plan
from vine_nlp.methods.obstacles.push import pushed_chain
from vine_nlp.methods.structure import frames12
from vine_nlp.methods.tip import buildable_tip, design_tip, start_guesses, tip_bounds, tip_data, tip_result, tip_spec
from vine_nlp.methods.transcription import get_solver
from vine_nlp.model.chain import chain_frames
from vine_nlp.problem import Result, Routing, TipProblem


def tip_design(problem: TipProblem, starts: int | None = None, progress=None) -> Result:
    """A tip problem's design, as ``vine-nlp design`` makes it: among its obstacles where it has any
    (:func:`design_tip_with_obstacles`), else :func:`vine_nlp.methods.tip.design_tip`; ``starts``
    (default options.starts); ``progress(done, total)`` after every start."""
    if problem.obstacles:
        return design_tip_with_obstacles(problem, starts=starts, progress=progress)
    return design_tip(problem, starts=starts, progress=progress)


def design_tip_with_obstacles(problem: TipProblem, starts: int | None = None, progress=None, thorough: bool = False) -> Result:
    """Least-actuation tip design that keeps the tube ``problem.obstacle_margin`` clear of ``problem.obstacles``.

    ``starts``: the tip design's (default options.starts), after the obstacle-free tip design and its chain
    pushed out (module docstring), each a loop of at most settings.ROUNDS solves;
    ``progress(done, total)`` after every start; ``thorough``: every start, the best kept (a lower
    objective, at several times the cost). Returns the best start by :func:`rank`, metrics as design_tip's
    plus min_obstacle_gap, stats obstacle_* as design_with_obstacles'."""
    stats = drive.Stats()
    free = stats.absorb(design_tip(problem, starts=starts, thorough=True))
    D = problem.diameter
    plan = Plan(problem.obstacles, D, problem.obstacle_margin, problem.growth, np.full(problem.segments, problem.length / problem.segments),
                problem.actuator)
    first = plan.report(free.routing)
    stats0 = {"obstacle_margin": plan.margin, "growth": plan.growth, "start_min_obstacle_gap": float(first["min_gap"]),
              "start_actuation_contraction": float(free.metrics["actuation_contraction"])}
    if not problem.obstacles or (first["clear"] and free.converged):
        free.metrics.update(obstacle_metrics(first))
        free.stats.update(stats0 | {"obstacle_rounds": 0, "obstacle_clear": bool(first["clear"])})
        free.met["obstacles"] = bool(first["clear"])
        return free
    n = max(1, problem.options.starts if starts is None else starts)
    # each made when it is tried: the pushed chain costs a design solve
    guesses = [lambda: free.routing, lambda: pushed_chain(problem, plan, free.routing)]
    guesses += [lambda g=g: Routing(theta=g[0], lam=g[1], length=g[2], initial_pose=problem.initial_pose) for g in start_guesses(problem, n)]
    found = drive.multistart(lambda routing: _tip_start(problem, plan, routing), guesses, key=rank,
                             accept=None if thorough else (lambda r: r.status == "optimal" and r.met["obstacles"]), progress=progress)
    best = drive.record_starts(found, stats, always=True)
    if best.converged and best.met["obstacles"]:  # buildable: the classes' lambda bounds, the rows' loop again
        built = buildable_tip(problem, best, lambda r, lam: _tip_start(problem, plan, r, lam))
        if built is not best and built.met.get("obstacles"):
            built.stats, best = best.stats | built.stats, stats.absorb(built)
    best.method = "tip"
    best.metrics["reachable"] = float(best.converged)
    best.stats.update(stats0 | {"obstacle_samples_per_segment": plan.S, "start_status": [r.status for r in found.results]})
    return stats.stamp(best)


def rank(result: Result) -> tuple:
    """The drive's ranking of tip starts among obstacles: converged and clear by the objective, then converged
    by the objective, then the rest by their tip error."""
    clear = result.converged and result.met["obstacles"]
    return drive.rank(result, clear, result.objective if result.converged else result.metrics["tip_error"])


def _tip_start(problem: TipProblem, plan: Plan, routing: Routing, lam=None) -> Result:
    """One start: the tip NLP with obstacle rows from ``routing`` (its frames on its chain), the active-set loop;
    ``lam``: lambda's bounds (a buildable design's classes)."""
    o, D = problem.options, problem.diameter
    stats = drive.Stats()
    plan.reset_rounds()
    plan.choose_levels(plan.report(routing))
    data = plan.data(routing)

    def solver(round, last):  # cached per spec: new only when the slots grew
        return get_solver(tip_spec(problem.segments, problem.actuator.shared_lambda, problem.direction is not None, problem.objective,
                                   min(o.max_iter, settings.TIP_MAX_ITER), o.tol, hard=True, extra=plan.extra, terms=(plan.term,)))

    first = solver(0, False)
    fr = chain_frames(routing.theta, routing.lam, routing.length, D, problem.initial_pose)
    x = plan.fill_extra(first, first.pack_x(frames12(fr, D)[None], theta=routing.theta, lam=routing.lam, length=routing.length / D), routing)
    rule = Rounds(plan, routing, data, solver, tip_data(problem), tip_bounds(first, problem, lam),
                  lambda sol: tip_result(problem, sol), stop_at_cap=True)
    found = drive.refine(rule, settings.ROUNDS, x, stats)
    best, rep = stats.stamp(found.best), found.verdict.report
    best.metrics.update(obstacle_metrics(rep))
    best.stats.update(obstacle_rounds=found.rounds, obstacle_clear=bool(rep["clear"]), obstacle_after_t=list(plan.ts))
    best.met["obstacles"] = bool(rep["clear"])
    return best
