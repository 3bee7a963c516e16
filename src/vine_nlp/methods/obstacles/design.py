"""Inverse design among obstacles: the plain NLP plus the obstacle rows, an active-set loop on the drive.

Start from the obstacle-free design (design_nlp) and keep it when it already clears; otherwise solve with
the rows from the pushed start's chain (``push``), check with the report (analysis.obstacles.obstacle_report:
20 points per segment, exact mesh distances, refined minima), refresh the plan, re-solve warm; until the
report is clear or the rounds are done (``drive.refine`` with the rule :class:`Rounds`). A re-solve before
the last round stops after settings.ROUND_MAX_ITER iterations and the next round goes on from where it
stopped, with fresh active sets; a re-solve with the same rows as the round before starts warm (its answer's
multipliers, IPOPT's small first barrier: a cold start's barrier pushed a converged design that missed the
margin by 0.5 mm far off, and the capped re-solves never converged again), and where the warm start fails
(the raise or the new active set violates rows at the start) the same start is solved cold; the first solve is not cut (from the pushed start it may legitimately need
more). The rows' length bounds make room for a segment the pushed start's detour lengthened past its bound
(a start outside the bounds is moved inside by IPOPT, its chain torn apart).

Weights. A target point closer than the margin to an obstacle is *blocked*: no design sits on it. Its fit
weight is scaled, so the detour is shaped more by the points the tube can follow: BLOCKED_WEIGHT for
primitives, MESH_BLOCKED_WEIGHT where the scene has a mesh; heavier blocked points pulled the tube's error
into the target away from the obstacles, lighter ones (with a mesh) sent it round the far side. With a mesh
the weight rises from the margin over MESH_WEIGHT_RAMP (quadratically): points just outside the margin that
the tube cannot follow past its detour pulled the neighbouring segments into a zig-zag. The values were
chosen on the bundled problems and the speed scenes (results/BENCHMARKS.md, "Obstacles").

Buildable (issue 46). Classes (:func:`_classes`): the pushed start's own bends decide where the actuators go next
to the obstacles (target points within settings.NEAR_CLASSES D of the margin, or where the pushed start is more than
settings.NEAR_DETOUR D off the target: its whole detour; and a segment either side), the target's bends elsewhere
(by the margin alone, issue 33's slot scene's detour was cut straight: no clear design in 7 rounds, 56 s): the pushed start's error diffusion carried the detour's bends on along the run, and
away from the walls the design then bent where the target does not (helices at theta_max beside straight runs).
Polish (primitives only): the clear design solved once more (the loop's next round: warm, the same rows, cut at
settings.ROUND_MAX_ITER iterations)
with the fit weights rising from BLOCKED_WEIGHT at the margin to 1 at margin + settings.POLISH_RAMP D (as with a
mesh): the points just outside the margin that a detour cannot follow pulled the design off the target away from
the walls; kept where it converges clear (a round in obstacle_rounds). The figures: results/benchmarks/scenes.md."""

from __future__ import annotations

import dataclasses

import numpy as np

from vine_nlp.analysis.buildability import buildability
from vine_nlp.analysis.obstacles import min_gap, obstacle_metrics
from vine_nlp.methods import drive, settings
from vine_nlp.methods.buildable import Build, chain_bends, classify, lambda_bounds, made_buildable, merge_short, target_bends, unwind
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.nlp import chain_guess, design_bounds, design_nlp, extended_solver, nlp_parameters, result_of, start_x
from vine_nlp.methods.obstacles.plan import Plan
from vine_nlp.methods.obstacles.push import pushed_start
from vine_nlp.methods.settings import BLOCKED_WEIGHT, MESH_BLOCKED_WEIGHT, MESH_WEIGHT_RAMP
from vine_nlp.model import shape_lines
from vine_nlp.problem import DesignProblem, Result

RUN = "nlp"  # the obstacle design is the problem's design (archived as run "nlp"); the obstacle-free start: START_RUN
START_RUN = "nlp_no_obstacles"  # archives before round 4 named it "nlp_free"
METHOD = "nlp_obstacles"


class Rounds:
    """The obstacle rows' active set, a rule of ``drive.refine``: solve with the plan's rows (``solver(round, last)``:
    the NLP for the plan's current slots; ``data``: the rows' data for ``routing``, the first round's), judge by the
    report, refresh the plan (plan.next_round). ``params``: the formulation's data beside the rows'; ``bounds``: (lbx,
    ubx); ``result(solver, x, status, st)``: a round's Result; ``stop_at_cap``: a solve that reaches its iteration limit
    ends the loop (a tip start left for the next); ``warm``: a re-solve with the rows of the round before starts from
    its answer's multipliers (``solver(round, last, warm)``; module docstring)."""

    def __init__(self, plan: Plan, routing, data: dict, solver, params: dict, bounds: tuple, result, stop_at_cap: bool = False,
                 warm: bool = False):
        self.plan, self.routing, self.data, self.solver, self.params, self.bounds = plan, routing, data, solver, params, bounds
        self.result, self.stop_at_cap, self.warm, self.offset = result, stop_at_cap, warm, 0

    def solve(self, x, round, last):
        round, last = round + self.offset, last and not self.offset  # a loop that goes on (the polish): warm, cut
        if round:
            self.data = self.plan.data(self.routing)
        warm = self.warm and round > 0
        solver = self.solver(round, last, True) if warm else self.solver(round, last)
        duals = self.duals if warm and len(self.duals[1]) == len(solver.lbg) else None
        if warm and duals is None:  # new slots: rows the last answer has no multipliers for, a cold start
            solver = self.solver(round, last, False)
        self.built = solver
        zero = (np.zeros(len(x)), np.zeros(len(solver.lbg)))
        p, bounds = solver.pack_params(self.params | self.data), self.plan.trust(solver, x, *self.bounds)
        if not self.warm:
            sol = solver.solve(x, p, *bounds)
            return sol.x, self.result(sol)
        sol = solver.solve(x, p, *bounds, duals=duals if duals is not None else zero)
        if duals is not None and sol.status not in ("optimal", "max_iter"):
            # the warm start failed (rows the raise or the new active set violate at the start): cold, from the same x
            solver = self.built = self.solver(round, last, False)
            cold = solver.solve(x, p, *bounds, duals=zero)
            for key in ("iterations", "solve_time_s", "ipopt_time_s"):
                cold.stats[key] += sol.stats[key]
            sol = cold
        # only a converged answer's multipliers start the next round (from a capped solve's, the warm re-solves
        # wandered off: a box scene's RMSE 0.4 -> 94 cm)
        duals = sol.stats.pop("duals", zero)
        self.duals, self.x = (duals if sol.status == "optimal" else (zero[0], np.zeros(0))), sol.x
        return sol.x, self.result(sol)

    def judge(self, res):
        rep = self.plan.report(res.routing)
        done = (rep["clear"] and res.converged) or (self.stop_at_cap and res.status == "max_iter")
        miss = self.plan.margin - min(rep["min_gap"], rep["min_gap_intermediate"])
        return drive.Verdict(done, drive.rank(res, rep["clear"], miss), rep)

    def refresh(self, res, verdict, x):
        self.plan.next_round(res.converged, res.routing, verdict.report)
        self.routing = res.routing
        return self.plan.fill_extra(self.built, x, res.routing)


def design_with_obstacles(problem: DesignProblem, start: Result | None = None, rounds: int = settings.ROUNDS,
                          spacing: float = settings.SAMPLE_SPACING, **kw) -> Result:
    """Inverse design that keeps the tube ``problem.obstacle_margin`` clear of ``problem.obstacles``.

    ``start``: the obstacle-free design (default design_nlp(problem, **kw)), returned (with the obstacle metrics) when
    it already clears; ``rounds``: solves of the active-set loop at most (settings.MESH_ROUNDS at least with a mesh);
    ``spacing``: target sample spacing, units of D. Returns the best round (method "nlp_obstacles";
    ``drive.rank``) with metrics min_obstacle_gap (and min_obstacle_gap_after) and stats obstacle_rounds,
    obstacle_clear, obstacle_samples_per_segment, obstacle_margin, growth, start_rmse, start_min_obstacle_gap,
    obstacle_raise (the rows' extra requirement, units), obstacle_slots (primitive slots per segment); iterations,
    ipopt_iterations and ipopt_time_s summed over the solves with rows (not the obstacle-free or pushed starts)."""
    stats = drive.Stats()
    start = start or design_nlp(problem, **kw)
    D = problem.diameter
    plan = Plan(problem.obstacles, D, problem.obstacle_margin, problem.growth, start.routing.length, problem.actuator, spacing)
    first = plan.report(start.routing)
    stats0 = {"obstacle_margin": plan.margin, "growth": plan.growth, "start_rmse": float(start.metrics["rmse"]),
              "start_min_obstacle_gap": float(first["min_gap"])}
    if not problem.obstacles or first["clear"]:
        best = dataclasses.replace(start, metrics=dict(start.metrics), stats=dict(start.stats), met=dict(start.met))
        best.metrics.update(obstacle_metrics(first))
        best.stats.update(stats0 | {"obstacle_rounds": 0, "obstacle_clear": bool(first["clear"])})
        best.met["obstacles"] = bool(first["clear"])
        return best
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    plan.choose_levels(first)
    plan.data(start.routing)  # the slots near the obstacle-free design stay
    rounds = max(rounds, settings.MESH_ROUNDS) if plan.has_mesh else rounds
    build, routing = Build.of(problem), pushed_start(problem, plan)

    def finish(res, routing):  # the same shape, its unactuated runs unwound
        return evaluate(problem, routing, pairing, METHOD, status=res.status, iterations=res.iterations, stats=res.stats,
                        objective=res.objective, hessian=res.hessian, solve_time_s=res.solve_time_s, met=res.met)

    # one loop of the buildable problem: the classes (module docstring, "Buildable"), their lambda bounds
    act = _classes(problem, pairing, routing, build)
    lam = lambda_bounds(act, routing.length, build)
    r0 = unwind(dataclasses.replace(routing, lam=np.clip(routing.lam, *lam)), act, build)
    best, found, rule = _rounds(problem, plan, pairing, r0, rounds, stats, lam)
    how = "classes of the pushed start near the obstacles"
    if best.converged and found.verdict.report["clear"]:
        if not plan.has_mesh:  # the polish: one solve more, warm, cut at settings.ROUND_MAX_ITER
            rule.params, rule.routing, rule.offset = rule.params | {"cells": rule.polish}, best.routing, 1
            again = drive.refine(rule, 1, rule.x, stats)
            again.rounds += found.rounds
            if again.best.converged and again.verdict.report["clear"]:
                best, how = again.best, how + ", polished"
            found = again if best is again.best else dataclasses.replace(found, rounds=again.rounds)
        best = finish(best, unwind(best.routing, act, build))
        best.buildable = True
    else:  # the free loop from the pushed start, then made buildable from its answer
        how = "free loop, then its classes"
        plan.reset_rounds()
        plan.choose_levels(first)
        plan.data(start.routing)
        best, found, _ = _rounds(problem, plan, pairing, routing, rounds, stats)
    rep = buildability(best.routing, build.D, build.kind, build.lambda_min, build.margin, build.min_feature, build.pose is None)
    if best.converged and found.verdict.report["clear"] and (not best.buildable or rep.below):  # (again: the lengths moved)
        built = made_buildable(best, build, lambda r, lam: _again(problem, plan, pairing, r, rounds, lam), finish)
        if built is not best:
            stats.absorb(built)
            best, found = built, dataclasses.replace(found, verdict=drive.Verdict(True, (), plan.report(built.routing)))
    best, rep = stats.stamp(best), found.verdict.report
    best.stats["obstacle_buildable"] = how if best.buildable else "not buildable"
    best.metrics.update(obstacle_metrics(rep))
    best.met["obstacles"] = bool(rep["clear"])
    best.stats.update(stats0 | {"obstacle_rounds": found.rounds, "obstacle_clear": bool(rep["clear"]),
                                "obstacle_samples_per_segment": plan.S, "obstacle_raise": plan.raised * problem.diameter, "obstacle_slots": plan.P,
                                "obstacle_after_t": list(plan.ts)})
    return best


def _again(problem: DesignProblem, plan: Plan, pairing, routing, rounds: int, lam) -> Result:
    """The loop from a design with lambda's bounds ``lam``: its best round, status "not clear" where it does not clear."""
    res, found, _ = _rounds(problem, plan, pairing, routing, rounds, drive.Stats(), lam)
    res.stats["obstacle_rounds"], res.met["obstacles"] = found.rounds, bool(found.verdict.report["clear"])
    return res if res.met["obstacles"] else dataclasses.replace(res, status="not clear")


def _classes(problem: DesignProblem, pairing, routing, build: Build) -> np.ndarray:
    """Where the obstacle design has actuators (module docstring, "Buildable"): the bends of the pushed start
    ``routing`` near the obstacles, the target's elsewhere."""
    tg, D = problem.target, problem.diameter
    i = np.arange(tg.shape[0] - 1)
    off = np.linalg.norm(shape_lines(routing.theta, routing.lam, routing.length, D, pairing.seg, pairing.frac, routing.initial_pose)[0] - tg, axis=1)
    near = np.zeros(routing.segments, bool)
    near[pairing.seg[i[(min_gap(tg[i], D, problem.obstacles).min(axis=1) < problem.obstacle_margin + settings.NEAR_CLASSES * D)
                       | (off[i] > settings.NEAR_DETOUR * D)]]] = True
    near = np.convolve(near, np.ones(3), "same") > 0
    act = np.where(near, classify(chain_bends(routing, D), routing.length, build), classify(target_bends(problem, pairing), routing.length, build))
    return merge_short(act, routing.length, build.min_feature)


def _rounds(problem: DesignProblem, plan: Plan, pairing, routing, rounds: int, stats: drive.Stats, lam=None):
    """The active-set loop from ``routing`` (its frames on its chain): (the best round, drive.refine's answer, the
    rule: its ``polish`` the fit's cells for the polish); ``lam``: lambda's bounds (a buildable design's classes)."""
    D = problem.diameter
    R0g = routing.initial_pose[:3, :3].copy()
    params = nlp_parameters(problem, pairing, R0g)
    factor, ramp = (MESH_BLOCKED_WEIGHT, MESH_WEIGHT_RAMP) if plan.has_mesh else (BLOCKED_WEIGHT, 0.0)
    cells = params["cells"]
    params["cells"] = _weigh_blocked(problem, pairing, cells, factor, ramp)

    def solver(round, last, warm=False):  # cached per spec: new only when the slots grew; a re-solve before the last is cut
        return extended_solver(problem, pairing, (plan.term,), plan.extra, settings.ROUND_MAX_ITER if 0 < round and not last else None,
                               warm=warm)

    def result(sol):
        return result_of(problem, pairing, sol, R0g, METHOD)

    data = plan.data(routing)  # the first round's: it fixes the first solver's slots
    first_solver = solver(0, rounds == 1)
    box = design_bounds(problem, pairing) | ({} if lam is None else {"lam": lam})
    dl_hi = box["length"][1]
    # the pushed start's detour may lengthen a segment past LENGTH_FACTOR of its chord on the target: there the
    # bound makes room for it (module docstring)
    dl0 = routing.length / D
    bounds = first_solver.bounds(**box | {"length": (box["length"][0], np.where(dl0 > dl_hi, settings.LENGTH_SLACK * dl0, dl_hi))})
    x = plan.fill_extra(first_solver, start_x(first_solver, chain_guess(problem, routing), D, "chain"), routing)
    rule = Rounds(plan, routing, data, solver, params, bounds, result, warm=True)
    rule.polish = _weigh_blocked(problem, pairing, cells, factor, settings.POLISH_RAMP)
    found = drive.refine(rule, rounds, x, stats)
    return found.best, found, rule

def _weigh_blocked(problem: DesignProblem, pairing, cells: np.ndarray, factor: float, ramp: float = 0.0) -> np.ndarray:
    """The cells with the weights of the blocked target points (where the tube cannot be: closer than
    the margin to an obstacle) times ``factor``; with ``ramp`` > 0 (units of D) the weight then rises
    as s^2 to 1, s = (gap - margin) / ramp in [0, 1] (module docstring, "Weights")."""
    tg = problem.target
    i = np.arange(tg.shape[0] - 1)
    gap = min_gap(tg[i], problem.diameter, problem.obstacles).min(axis=1)
    s = np.clip((gap - problem.obstacle_margin) / (ramp * problem.diameter), 0, 1) ** 2 if ramp > 0 else (gap >= problem.obstacle_margin)
    w = factor + (1 - factor) * s
    blocked = np.flatnonzero(w < 1)
    cells = cells.copy()
    cells[4 * pairing.n + blocked - pairing.bounds[pairing.seg[blocked]], pairing.seg[blocked]] *= w[blocked]
    return cells
