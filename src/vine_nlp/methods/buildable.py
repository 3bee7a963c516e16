"""Buildable designs (issue 31): an actuator only where the tube bends, no winding for nothing, room to correct.

Where lambda is 1 the segment is straight and theta only turns the actuator line around it: no actuator is
built there, and the line may take any way to where the next actuated piece needs it. From a free design:

- **Classes** (:func:`classify`): a segment has lambda exactly 1, or an actuator bounded to [lo, 1 - m_j]
  (:func:`lambda_bounds`; lo = lambda_min (pouches: 2/pi) + margin; m_j = max(margin, min_feature over its
  gap's length, alone or joined with its partner's)): room to correct an as-built error both ways. A segment
  whose target bends at least the least an actuated one bends keeps its actuator; along a gentler run the
  bends are summed and a segment actuated each time the sum reaches a share of its least bend (error diffusion:
  fewer, stronger actuated segments with straight ones between; :func:`phases`: several shares, where the
  actuators fall); short pieces merge (:func:`merge_short`). A design missing its target by a corner's share
  of D is classed by its own bends.
- **Unwinding** (:func:`unwind`): on an unactuated run the shape sees only the line's net turning modulo
  2 pi: it is taken the shortest way round at one slope, before each solve and after the last (the same
  shape); a first run's goes into the base roll (free base: no arbitrary roll) or comes from the fixed pose.
- **Build effort** (:class:`BuildEffort`, :func:`effort_data`): weighted (1/L) sum_j tan(theta_j)^2 dl_j.
- **Solves** (issue 46: about the free design's cost): none where the free design lies inside its classes'
  bounds (free base); else the phases' classes (not under a load) raced (:func:`race`: a few iterations each
  from the free design), the lowest objective's solved fully from its iterate (:class:`Reclassify`, a
  ``drive.refine`` rule: warm where the bounds barely move the start); a single phase over the accuracy budget:
  flips from the lambda bounds' multipliers.

sPAM (one lambda, pouches along the whole tube): no classes; the lambda in [max(lambda_min, 2/pi) + margin,
1 - margin], the build effort. Other formulations (obstacles) use the blocks with their own solve.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import casadi as ca
import numpy as np

from vine_nlp.analysis.buildability import MM_PER_UNIT, POUCH_LAMBDA_MIN, buildability, default_min_feature, partners, pieces, wrap_angle
from vine_nlp.methods import drive, settings
from vine_nlp.methods.common import Guess, evaluate, pair_points
from vine_nlp.methods.nlp import design_bounds, design_nlp, nlp_parameters, result_of, start_x
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Chain, Smoothness, SoftTip, Spec, get_solver
from vine_nlp.model.chain import phi_from_theta
from vine_nlp.model.helix import center_rates
from vine_nlp.problem import DesignProblem, Result, Routing, TipProblem


@dataclass(frozen=True)
class Build:
    """A problem's build settings: ``margin``, ``min_feature`` (length units), ``pose`` the fixed base (4 x 4) or None."""

    D: float
    theta_max: float
    kind: str
    lambda_min: float
    margin: float
    min_feature: float
    pose: np.ndarray | None = field(default=None, compare=False)

    @classmethod
    def of(cls, problem: DesignProblem) -> Build:
        o, a = problem.options, problem.actuator
        mf = default_min_feature(problem.units) if o.min_feature is None else o.min_feature
        pose = np.array(o.base_pose, float) if o.base == "fixed" else None
        if isinstance(problem, TipProblem):  # a tip problem grows from its fixed base
            pose = np.array(problem.initial_pose, float)
        return cls(problem.diameter, a.theta_max, a.kind, a.lambda_min, o.correction_margin, mf, pose)

    shared = property(lambda self: self.kind == "spam")  # one lambda: pouches along the whole tube
    lo = property(lambda self: (max(self.lambda_min, POUCH_LAMBDA_MIN) if self.shared else self.lambda_min) + self.margin)


def upper(length, act, build: Build) -> np.ndarray:
    """1 - m_j: an actuated segment's largest lambda, its gap (alone or with its partner's in ``act``) >= min_feature
    (times settings.FEATURE_SLACK: the lengths move in the solve that these bounds are for)."""
    length = np.asarray(length, float)
    mate = partners(act)
    together = length + np.where(mate >= 0, length[np.maximum(mate, 0)], 0.0)
    return 1.0 - np.maximum(build.margin, settings.FEATURE_SLACK * build.min_feature / together)


def lambda_bounds(act, length, build: Build) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment lambda bounds (lo, hi): exactly 1 without an actuator, [build.lo, 1 - m_j] (>= lo) with one."""
    act = np.asarray(act, bool)
    if build.shared:
        return np.full(act.size, build.lo), np.full(act.size, max(build.lo, 1 - build.margin))
    hi = np.maximum(upper(length, act, build), build.lo)
    return np.where(act, build.lo, 1.0), np.where(act, hi, 1.0)


def target_bends(problem: DesignProblem, pairing) -> np.ndarray:
    """The target's turning angle over each segment (rad): the angle between its tangents at the segment's ends."""
    t = np.gradient(problem.target, pairing.chord, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
    b = pairing.bounds
    return np.arccos(np.clip(np.sum(t[b[:-1]] * t[b[1:]], axis=1), -1.0, 1.0))


def chain_bends(routing: Routing, D: float) -> np.ndarray:
    """A chain's turning angle over each segment (rad): kappa l_c of its helix (a start's bends where the target's
    are not the shape to follow: a detour around obstacles)."""
    kappa, _, lc = center_rates(routing.theta, routing.lam, D)
    return np.asarray(kappa * lc * routing.length, float)


def classify(bends, length, build: Build, share: float = 0.5, paired: bool = False) -> np.ndarray:
    """Where an actuator goes (module docstring): ``bends`` the target's turning per segment, ``length`` the
    segment lengths. An actuated segment bends at least its bend at 1 - m_j (theta 0): in a piece with a partner
    (``pair``), or alone (``alone``, the error diffusion's step: a gently bent run gets isolated actuators, one
    where the sum reaches ``share`` of the step; ``paired``: the pair's bend as the step)."""
    bends, length = np.asarray(bends, float), np.asarray(length, float)
    if build.shared:
        return np.ones(bends.size, bool)

    def least_bend(act):
        kappa, _, lc = center_rates(0.0, upper(length, act, build), build.D)
        return kappa * lc * length

    pair, alone = least_bend(np.ones(bends.size, bool)), least_bend(np.zeros(bends.size, bool))
    step = pair if paired else alone
    act, acc = bends >= np.maximum(pair, settings.BEND_TOL), 0.0
    for j in range(bends.size):  # error diffusion along the gently bent runs
        if act[j]:
            acc = 0.0
            continue
        acc += bends[j]
        if acc >= max(share * step[j], settings.BEND_TOL):
            act[j], acc = True, acc - max(acc, step[j])
    return merge_short(act, length, build.min_feature)


def phases(bends, length, build: Build) -> list[np.ndarray]:
    """The classes of every error-diffusion phase (settings.DIFFUSION), each once, the default (share 0.5) first: on
    a gently bent target the design's error depends on where the isolated actuators fall more than on their count."""
    out = []
    for share, paired in settings.DIFFUSION:
        act = classify(bends, length, build, share, paired)
        if not any(np.array_equal(act, a) for a in out):
            out.append(act)
    return out


def band(problem: DesignProblem, pairing=None) -> tuple[np.ndarray, np.ndarray] | None:
    """The buildable design in one solve where nothing is left to decide (issue 46): the lambda box (lo, hi) of the
    classes where every phase actuates every segment by the target's own bends (a helix, a trefoil), the target's
    chords as the lengths; None where a free design decides the classes (straight or gentle runs), and where the
    base is fixed, a load, obstacles or one shared lambda take the design their own way."""
    build = Build.of(problem)
    if build.pose is not None or build.shared or problem.load is not None or getattr(problem, "obstacles", ()):
        return None
    pairing = pairing or pair_points(problem.target, problem.options.points_per_segment)
    found = phases(target_bends(problem, pairing), pairing.segment_chord, build)
    return lambda_bounds(found[0], pairing.segment_chord, build) if len(found) == 1 and found[0].all() else None


def first_design(problem: DesignProblem, **kw) -> Result:
    """The design :func:`design_buildable` starts from: one solve inside the :func:`band` where it gives one (stats
    lambda_band), else the free design; ``kw``: ``design_nlp``'s (starts, workers, warm, progress, hops, budget, note)."""
    return design_nlp(problem, method=settings.Method.of(problem.options).with_(band=band(problem)), **kw)


def merge_short(act, length, min_feature: float) -> np.ndarray:
    """An inner piece shorter than min_feature takes its neighbours' class (the shortest first)."""
    act = np.array(act, bool)
    for p in sorted(pieces(act, length, length), key=lambda p: p.s1 - p.s0):
        if p.s1 - p.s0 < min_feature and 0 < p.start and p.stop < act.size:
            act[p.start:p.stop] = not p.actuated
    return act


def unwind(routing: Routing, act, build: Build) -> Routing:
    """The same shape with every unactuated run's turning the shortest way round at constant slope: a first run's
    into the base roll (free base; theta 0 there) or from the fixed pose, a last run's dropped (module docstring)."""
    theta, T0, D = routing.theta.copy(), routing.initial_pose.copy(), build.D
    phi = phi_from_theta(routing.theta, routing.length, D)
    for p in pieces(act, routing.length, routing.length):
        if p.actuated:
            continue
        run, net = slice(p.start, p.stop), phi[p.stop] - phi[p.start]
        if p.stop == routing.segments:
            theta[run] = 0.0  # nothing downstream
            continue
        if p.start == 0 and build.pose is None:  # a roll about the base's own tangent
            c, s = math.cos(net), math.sin(net)
            T0, theta[run] = T0 @ np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]]), 0.0
            continue
        if p.start == 0:  # the fixed pose differs from this one by a roll rho: the run turns rho further
            R = np.linalg.solve(build.pose[:3, :3], T0[:3, :3])
            net += math.atan2(R[2, 1], R[1, 1])
        theta[run] = np.arctan(0.5 * D * float(wrap_angle(net)) / (p.s1 - p.s0))
    T0 = T0 if build.pose is None else build.pose.copy()
    return Routing(theta=np.clip(theta, -build.theta_max, build.theta_max), lam=routing.lam, length=routing.length, initial_pose=T0)


@dataclass(frozen=True)
class BuildEffort:
    """sum_j e_j tan(theta_j)^2 dl_j: the line's weighted mean squared slope on the unrolled tube; parameter ``effort`` (M,)."""

    def apply(self, c: Chain) -> None:
        e = c.param("effort", (c.s.M, 1))
        c.add_term("effort", ca.dot(e, ca.tan(c.theta.T) ** 2 * c.dl.T))


def effort_data(act, L: float, base_free: bool = True) -> dict:
    """The build effort's data, e_j = w_j / L (L as ``nlp_parameters``' "L"): settings.EFFORT_ACTUATED with an actuator; settings.EFFORT on
    an unactuated run the shape does not see (the first with a free base, the last); settings.EFFORT_INNER on the others."""
    act = np.asarray(act, bool)
    w = np.where(act, settings.EFFORT_ACTUATED, settings.EFFORT_INNER)
    for p in pieces(act, np.ones(act.size), np.ones(act.size)):
        if not p.actuated and ((p.start == 0 and base_free) or p.stop == act.size):
            w[p.start:p.stop] = settings.EFFORT
    return {"effort": w / L}


def accuracy_budget(problem: DesignProblem, rmse: float) -> float:
    """The RMSE the reclassification may reach from a free design's ``rmse``: settings.ACCURACY_SLACK or settings.ACCURACY_FLOOR_MM
    more, whichever is larger (units without a millimetre equivalent: the floor is 0.002 D)."""
    floor = settings.ACCURACY_FLOOR_MM / MM_PER_UNIT[problem.units] if problem.units in MM_PER_UNIT else 0.002 * problem.diameter
    return max((1 + settings.ACCURACY_SLACK) * rmse, rmse + floor)


class Reclassify:
    """The reclassification, a ``drive.refine`` rule (x: the routing to start from; ``trials + settings.BUILDABLE_REPAIRS`` rounds) for
    any formulation: ``solve(act, start, round)`` solves with the classes ``act`` from ``start`` (unwound here): (Result,
    the lambda bounds' multipliers (M,)). ``limit``: the RMSE budget. ``flips``: over the budget, the multipliers' flips
    (not after the phases' race: it was the search). After refine: ``act``, the best round's."""

    def __init__(self, solve: Callable, act, build: Build, limit: float, trials: int = settings.BUILDABLE_ROUNDS - settings.BUILDABLE_REPAIRS,
                 flips: bool = True):
        self._solve, self.build, self.limit, self.trials, self.flips = solve, build, limit, trials, flips
        self.act = self.trial = np.asarray(act, bool)
        self.best, self.mult, self.cand, self.k = None, None, np.zeros(0, int), 0
        self.taken, self.repairs, self.solves = 0, 0, 0

    def solve(self, x: Routing, round: int, last: bool):
        res, self._trial_mult = self._solve(self.trial, unwind(x, self.trial, self.build), round)
        self.solves += 1
        return x, res

    def judge(self, res: Result) -> drive.Verdict:
        rmse = res.metrics["rmse"]
        taken = self.best is None or self.repairs or rmse < self.best.metrics["rmse"] * (1 - 1e-3) and (res.converged or not self.best.converged)
        if taken:
            self.best, self.act, self.mult, self.taken = res, self.trial, self._trial_mult, self.taken + 1
            self._candidates()
        else:
            self.k //= 2
        self.trial = self._next()
        return drive.Verdict(self.trial is None, (not taken, -float(self.taken)), {"actuated": int(self.act.sum())})

    def refresh(self, res: Result, verdict: drive.Verdict, x) -> Routing:
        return self.best.routing

    def _candidates(self) -> None:
        """To flip over the budget (within it: done), the most eager first: actuated at the top asking for less (> 0),
        unactuated asking for more."""
        r, act, mult = self.best.routing, self.act, self.mult
        at_top = act & (r.lam >= upper(r.length, act, self.build) - 1e-6) & (mult > 1e-9)
        asks = ~act & (mult < -1e-9)
        stop = self.build.shared or self.repairs or self.best.metrics["rmse"] <= self.limit or not self.flips
        self.cand = np.zeros(0, int) if stop else np.flatnonzero(at_top | asks)
        self.cand = self.cand[np.argsort(-np.abs(mult[self.cand]), kind="stable")]
        self.k = self.cand.size

    def _next(self):
        """The next trial's classes, or None: done."""
        while self.k >= 1 and self.solves < self.trials:
            trial = self.act.copy()
            trial[self.cand[: self.k]] = ~trial[self.cand[: self.k]]
            trial = merge_short(trial, self.best.routing.length, self.build.min_feature)
            if not np.array_equal(trial, self.act):
                return trial
            self.k //= 2
        b, r = self.build, self.best.routing
        if self.repairs < settings.BUILDABLE_REPAIRS and buildability(r, b.D, b.kind, b.lambda_min, b.margin, b.min_feature).below:
            self.repairs += 1  # the lengths moved: bounds from the new ones
            return self.act.copy()
        return None


def race(solve: Callable, candidates, start: Routing, build: Build, stats: drive.Stats) -> list[tuple[np.ndarray, Routing]]:
    """The error diffusion's phases raced (issue 46): each phase's classes ``solve(act, start, cap)`` for settings.PHASE_ITER
    iterations from ``start`` (unwound); [(classes, iterate unwound)] of the lowest RMSE and of the lowest objective (one
    where they agree): the ones to solve fully (an iterate's RMSE and objective each ranked some phases unlike the full
    solves: results/benchmarks/buildable.md). Every solve counts in ``stats``."""
    found = [stats.absorb(solve(act, unwind(start, act, build), settings.PHASE_ITER)) for act in candidates]
    keys = ([r.metrics["rmse"] for r in found], [r.objective for r in found])
    best = dict.fromkeys(int(np.argmin(np.where(np.isfinite(k), k, np.inf))) for k in keys)
    return [(candidates[k], unwind(found[k].routing, candidates[k], build)) for k in best]


def buildable_spec(problem: DesignProblem, pairing, build: Build) -> Spec:
    """The plain NLP plus the build effort; the base pose free, or fixed (``build.pose``); exact Hessian."""
    o = problem.options
    s = Structure(pairing.segments, pairing.n, 1, "shared" if build.shared else "segment", "free" if build.pose is None else "fixed")
    return Spec(s, (Smoothness(), SoftTip(), BuildEffort()), "exact", settings.Settings(o.max_iter, o.tol))


def solve_classes(problem: DesignProblem, pairing, build: Build, act, start: Routing, round: int = 0, cap: int | None = None) -> tuple[Result, np.ndarray]:
    """One solve of the plain NLP with the build effort and the classes' lambda bounds, from ``start`` (frames on
    its chain; its base pose, or the fixed one); (Result "nlp", the lambda bounds' multipliers). The first round
    (``round`` 0) from a start the bounds move by at most settings.WARM_CLIP in lambda: IPOPT's warm start (near
    the answer); a later round (a trial of other classes) at most settings.ROUND_ITER iterations; ``cap``: a race's
    (:func:`race`: cold, at most ``cap`` iterations)."""
    D, act = problem.diameter, np.asarray(act, bool)
    lo, hi = lambda_bounds(act, start.length, build)
    spec = buildable_spec(problem, pairing, build)
    near = round == 0 and cap is None and float(np.max(np.abs(np.clip(start.lam, lo, hi) - start.lam))) <= settings.WARM_CLIP
    cap = min(spec.settings.max_iter, cap or (spec.settings.max_iter if round == 0 else settings.ROUND_ITER))
    solver = get_solver(dataclasses.replace(spec, settings=dataclasses.replace(spec.settings, warm=near, max_iter=cap)))
    T0 = start.initial_pose if build.pose is None else build.pose
    guess = Guess(start.theta, np.clip(start.lam, lo, hi), start.length, T0, None)
    data = nlp_parameters(problem, pairing, T0[:3, :3])
    data |= effort_data(act, data["L"], build.pose is None)
    lbx, ubx = solver.bounds(X0=None if build.pose is None else frames12(T0[None], D).T, **design_bounds(problem, pairing) | {"lam": (lo, hi)})
    sol = solver.solve(start_x(solver, guess, D, "chain"), solver.pack_params(data), lbx, ubx, multipliers=True)
    # lambda exactly 1 without an actuator: IPOPT holds a variable whose bounds are equal at its value
    return result_of(problem, pairing, sol, T0[:3, :3] if build.pose is None else T0, "nlp"), sol.lam_x[solver.layout.lam[:, 0]]


def design_buildable(problem: DesignProblem, start: Result, pairing=None) -> Result:
    """The buildable design from the free design ``start`` (design_nlp's; its solves counted): ``start`` itself (unwound; no
    solve, rounds 0) where it lies inside its classes' lambda bounds with every feature at min_feature (the margins force no
    winding) and the base is free, else the reclassification's rounds. stats buildable (True), buildable_actuated, buildable_free_rmse,
    buildable_budget, buildable_rounds, correction_margin, min_feature."""
    stats = drive.Stats()
    stats.started -= start.solve_time_s  # the wall time from the free design's start
    stats.absorb(start)
    pairing = pairing or pair_points(problem.target, problem.options.points_per_segment)
    build = Build.of(problem)
    # a design that misses the target by a corner's share of D follows its own shape, not the target's (polyline (d))
    own = start.metrics["rmse"] > settings.CORNER_RMSE * problem.diameter
    act, *others = phases(chain_bends(start.routing, problem.diameter) if own else target_bends(problem, pairing), start.routing.length, build)
    # flips over the budget for a single phase or under a load; no race there (under a load where the actuators fall
    # decides where the tube is weak: not the RMSE alone) nor on a design classed by its own bends (polyline (d): raced,
    # the same 9.165 mm in 65 iterations against 14)
    flips = not others or problem.load is not None
    others = [] if problem.load is not None or own else others
    limit, r0 = accuracy_budget(problem, start.metrics["rmse"]), start.routing
    lo, hi = lambda_bounds(act, r0.length, build)
    if build.pose is None and np.all((r0.lam >= lo) & (r0.lam <= hi)) and not buildability(r0, build.D, build.kind, build.lambda_min, build.margin, build.min_feature).below:
        best, rounds = dataclasses.replace(start, stats=dict(start.stats)), 0  # inside its classes' bounds: the margins force nothing
    else:
        raced = len(others) + 1 if others else 0
        starts = [(act, r0)]
        if others:  # the phases raced: the best's iterates solved fully (warm), no flips after them
            starts = race(lambda a, r, cap: solve_classes(problem, pairing, build, a, r, cap=cap)[0], [act, *others], r0, build, stats)
        done = []
        for a, r in starts:
            rule = Reclassify(lambda a, r, k: solve_classes(problem, pairing, build, a, r, k), a, build, limit, flips=flips)
            found = drive.refine(rule, settings.BUILDABLE_ROUNDS, r, stats)
            done.append((not found.best.converged, found.best.metrics["rmse"], len(done), found.best, rule.act, found.rounds))
        _, _, _, best, act, rounds = min(done, key=lambda d: d[:3])
        rounds = sum(d[5] for d in done) + raced
    # a solve may leave an unactuated run's turning beyond half a turn: the same shape the shortest way round
    r = unwind(best.routing, act, build)
    short = evaluate(problem, Routing(theta=r.theta, lam=best.routing.lam, length=r.length, initial_pose=r.initial_pose), pairing, "nlp", status=best.status,
                     iterations=best.iterations, stats=best.stats, objective=best.objective, hessian=best.hessian)
    best = short if short.metrics["rmse"] <= best.metrics["rmse"] * (1 + 1e-9) else best
    best.stats |= {k: v for k, v in start.stats.items() if k.startswith(("start", "best_start", "hops", "corner"))}
    best.buildable = True
    # a start solved inside the band (:func:`band`) is the buildable problem's own answer, not a free design
    first = {"buildable_one_solve": True} if start.stats.get("lambda_band") else {"buildable_free_rmse": float(start.metrics["rmse"])}
    best.stats |= first | {"buildable": True, "buildable_actuated": int(act.sum()), "buildable_budget": float(limit), "buildable_rounds": rounds,
                           "correction_margin": build.margin, "min_feature": build.min_feature}
    return stats.stamp(best)


def inherited_bounds(problem: DesignProblem, pairing, start: Result | None):
    """``design_bounds``, with a buildable start's classes kept (lambda exactly 1 where it has no actuator, the
    margins elsewhere): robust and clearance designs started from a buildable design stay buildable."""
    box = design_bounds(problem, pairing)
    if start is None or not start.buildable:
        return box
    build, r = Build.of(problem), start.routing
    return box | {"lam": lambda_bounds(np.ones(r.segments, bool) if build.shared else r.lam != 1.0, r.length, build)}


JUDGED = ("nlp", "nlp_obstacles", "tip", "multishape", "nlp_robust", "nlp_clearance", "greedy_buildable")


def missed(problem, result: Result) -> list[str]:
    """The buildable rules (analysis.buildability.Report.missed) a design of ``problem`` misses, one line each, judged
    with the problem's own margin, min_feature and base; every level of a multi-shape design ("level k: ..."). Runs
    of other methods (the greedy, forward, fit, a correction's nominal) are not judged: [] for them."""
    if result.method not in JUDGED or getattr(problem, "actuator", None) is None:
        return []
    b, r = Build.of(problem), result.routing
    hi = max(b.lo, 1 - b.margin)
    levels = getattr(result, "levels", None)
    if levels is None or not np.size(levels):
        return buildability(r, b.D, b.kind, b.lambda_min, b.margin, b.min_feature, b.pose is None).missed(b.lo, hi, problem.units)
    out = []
    for k, lam in enumerate(np.asarray(levels, float)):
        level = Routing(theta=r.theta, lam=np.full(r.segments, lam), length=r.length, initial_pose=r.initial_pose)
        rep = buildability(level, b.D, b.kind, b.lambda_min, b.margin, b.min_feature, b.pose is None)
        if not b.lo - 1e-9 <= lam <= hi + 1e-9:  # one lambda along the whole line: the band is the sPAM's
            rep.violations = []
            out.append(f"level {k}: lambda {lam:.6g} outside [{b.lo:.6g}, {hi:.6g}] (correction margin)")
        out += [f"level {k}: {line}" for line in rep.missed(b.lo, hi, problem.units)]
    return out


def made_buildable(result: Result, build: Build, solve: Callable, finish: Callable) -> Result:
    """A design of another formulation (tip targets, obstacles) made buildable by one solve more: lambda exactly 1
    where it is within margin / 2 of 1, the classes' bounds (:func:`lambda_bounds`) elsewhere, from the design
    unwound; again while the lengths moved a feature below min_feature (settings.BUILDABLE_REPAIRS at most).
    ``solve(start: Routing, lam: (lo, hi)) -> Result``; ``finish(result, routing) -> Result``: the result with the
    same shape's unwound routing. The design as it was where no solve converges (the judge then says why)."""
    r, best, solves, time = result.routing, None, 0, 0.0
    act = merge_short(r.lam < 1 - 0.5 * build.margin, r.length, build.min_feature) if not build.shared else np.ones(r.segments, bool)
    for _ in range(1 + settings.BUILDABLE_REPAIRS):
        lo, hi = lambda_bounds(act, r.length, build)
        start = unwind(r, act, build)
        res = solve(Routing(theta=start.theta, lam=np.clip(r.lam, lo, hi), length=r.length, initial_pose=start.initial_pose), (lo, hi))
        solves, time = solves + 1, time + float(res.stats.get("ipopt_time_s", res.solve_time_s))
        if not res.converged:
            break
        best, r = res, res.routing
        if not buildability(r, build.D, build.kind, build.lambda_min, build.margin, build.min_feature, build.pose is None).below:
            break
    if best is None:
        return result
    best.stats |= {"solves": solves, "ipopt_time_s": time}
    best = finish(best, unwind(best.routing, act, build))
    best.buildable = True
    best.stats |= {"buildable": True, "buildable_actuated": int(act.sum()), "correction_margin": build.margin, "min_feature": build.min_feature}
    return best
