"""Inverse design that keeps the tube clear of itself: the plain NLP plus clearance rows.

Formulation (smooth): for chosen pairs of material points (l_a, l_b) of the tube,

    |r_c(l_a) - r_c(l_b)|^2 >= (D + min_gap)^2,

each point evaluated inside the multiple-shooting transcription as frame X_j of its
segment times the partial segment (model.segment.segment_function with the fraction
as data). Which pairs: an active-set outer loop. Start from design_nlp's result;
detect the contact regions of the current design (analysis.collision.routing_clearance
with a detection margin); constrain, for every sampled point of a region, the pair with
its closest partner, plus each region's refined (continuous) minimum; re-solve warm;
repeat until the continuous minimum clearance is >= D + min_gap (to ``tol_gap`` D) or
``rounds`` is exhausted. Pairs are never dropped, so the rounds only add rows. Rows hold
material points apart where they are; between them, and as the optimizer slides points
along the tube (segment lengths are variables), the clearance can dip ~1e-3 D below the
target. From the second solve on, the rows' target is raised by 1.5x the remaining
shortfall (stats clearance_row_margin), which ends the loop in 2-3 solves with the
continuous clearance >= D + min_gap; but only where every region short of the clearance has
a constrained pair near its minimum (a dip between rows that hold). A region without one is
a new contact (the tube moved into it): it gets its pairs and the target stays. Raising every
row for it pushed tight coils ever farther open, into new contacts: the loop ran away (a
helix of pitch D/8 asked for 0.3 D; tests/test_collision.py). A solve that does not converge
does not end the loop, and the design returned is the best round's: converged first, then
meeting the clearance, then the lower objective (else the larger clearance).

The pairs' segments are structure (the solver is built once per active set and cached);
their fractions and the required distance are data.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.analysis.collision import _ModelLine, routing_clearance
from vine_nlp.methods.common import Guess, pair_points
from vine_nlp.methods.nlp import design_bounds, design_nlp, nlp_parameters, nlp_spec, result_of, start_x
from vine_nlp.methods.transcription import HARD_ROWS, BlockType, Chain, get_solver, options_key, segment_point_index
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.segment import segment_function
from vine_nlp.problem import DesignProblem, Result, Routing


@lru_cache(maxsize=None)
def pair_block(k: int = 1) -> BlockType:
    """k clearance rows between two segments as one block: v = (X, theta, lam, dl of segment a (15), the same
    of segment b (15)), d = (fractions on a (k), fractions on b (k), need); r_i = |r_c(a_i) - r_c(b_i)|^2 - need
    (>= 0), units of D^2. The rows of one segment pair share their segments' helix quantities and one
    30 x 30 Hessian block (fewer instructions and scattered entries than a block per row). f is a structural
    zero: the block stays out of the objective's evaluation and gradient."""
    F = segment_function(k)
    v, d = ca.SX.sym("v", 30), ca.SX.sym("d", 2 * k + 1)
    _, pa = F(v[:12], v[12], v[13], v[14], d[:k])
    _, pb = F(v[15:27], v[27], v[28], v[29], d[k : 2 * k])
    r = ca.sum1((pa - pb) ** 2).T - d[2 * k]
    return BlockType(f"clearance_pairs{k}", ca.Function("pair_block", [v, d], [ca.SX(1, 1), r], {"cse": True}))


@dataclass(frozen=True)
class ClearancePairs:
    """Rows |r_c(a) - r_c(b)|^2 >= need for pairs of points given by their segments (structure), one block
    per segment pair (pair_block); parameters pair_u (2 x P, the fractions) and pair_need (the squared
    distance, units of D^2)."""

    segments: tuple  # ((j_a, j_b), ...)
    # the pairs are an active set, a new structure nearly every solve: the structure runs interpreted,
    # its block types (a segment, k pairs of two segments) compiled on their own and reused by every active set
    compile: ClassVar[bool | str] = "blocks"

    def apply(self, c: Chain) -> None:
        P = len(self.segments)
        u, need = c.param("pair_u", (2, P)), c.param("pair_need", (1, 1))
        groups: dict = {}
        for i, key in enumerate(self.segments):
            groups.setdefault(tuple(key), []).append(i)
        by_size: dict = {}
        for key, rows in groups.items():
            by_size.setdefault(len(rows), []).append((key, rows))
        for k, gs in sorted(by_size.items()):
            idx = np.array([np.r_[segment_point_index(c, ja), segment_point_index(c, jb)] for (ja, jb), _ in gs]).T
            cols = [i for _, rows in gs for i in rows]  # k per group, group-major
            ua, ub = (ca.reshape(u[side, cols], k, len(gs)) for side in (0, 1))
            c.add_block(pair_block(k), idx, ca.vertcat(ua, ub, ca.repmat(need, 1, len(gs))), lb=0.0, ub=np.inf)


def locate(l: float, length) -> tuple[int, float]:
    """(segment, fraction) of material coordinate l on segment lengths ``length`` (problem units)."""
    cum = np.concatenate([[0.0], np.cumsum(length)])
    M = len(length)
    j = int(np.clip(np.searchsorted(cum, l, side="right") - 1, 0, M - 1))
    return j, float(np.clip((l - cum[j]) / length[j], 0.0, 1.0))


def extended_solver(problem: DesignProblem, pairing, terms: tuple, hard: bool = True, extra: int = 0):
    """The plain NLP of ``problem``'s structure plus ``terms`` (the formulations built on it) and ``extra``
    variables per stage, exact Hessian; ``hard``: rows held tightly (HARD_ROWS)."""
    o = problem.options
    spec = nlp_spec(pairing.segments, pairing.n, problem.actuator.shared_lambda, o.max_iter, o.tol, terms=terms)
    opts = dict(spec.options) | (HARD_ROWS if hard else {})
    return get_solver(dataclasses.replace(spec, structure=dataclasses.replace(spec.structure, extra=extra), options=options_key(opts)))


def chain_guess(problem: DesignProblem, routing: Routing) -> Guess:
    """A start on a routing's own chain (frames where the routing puts them)."""
    return Guess(routing.theta, routing.lam, routing.length, routing.initial_pose,
                 chain_frames(routing.theta, routing.lam, routing.length, problem.diameter, routing.initial_pose))


MARGIN_FACTOR = 1.5


def _nearest_partner(model, la, lb, half_width, zooms: int = 6):
    """For each material point la[k], the closest point of the center line within
    lb[k] +- half_width (vectorized grid zoom + parabola): returns (lb*, distance)."""
    la, lb = np.asarray(la, float), np.asarray(lb, float)
    pa = model.points(la)
    lo, hi = 0.0, float(model.cum[-1])
    w = np.full(la.shape, float(half_width))
    g = np.linspace(-1.0, 1.0, 9)
    for _ in range(zooms):
        z = np.clip(lb[:, None] + w[:, None] * g, lo, hi)
        d2 = np.sum((model.points(z.ravel()).reshape(*z.shape, 3) - pa[:, None]) ** 2, axis=2)
        k = np.clip(np.argmin(d2, axis=1), 1, len(g) - 2)
        r = np.arange(len(la))
        y0, y1, y2 = d2[r, k - 1], d2[r, k], d2[r, k + 1]
        den = y0 - 2 * y1 + y2
        step = np.where(den > 0, 0.5 * (y0 - y2) / np.where(den > 0, den, 1.0), 0.0)
        lb = np.clip(z[r, k] + np.clip(step, -1, 1) * (z[r, k + 1] - z[r, k]), lo, hi)
        w = w / 4
    return lb, np.linalg.norm(model.points(lb) - pa, axis=1)


def _region_pairs(region, line, model, exclude_arc, step):
    """Material-coordinate pairs to constrain for one contact region: sampled points of either
    side about ``step`` apart, each with its closest partner on the continuous center line."""
    pr = region["pairs"]
    pts, s, l = line["points"], line["s"], line["l"]
    hl = float(np.max(np.diff(l)))
    d = np.linalg.norm(pts[pr[:, 0]] - pts[pr[:, 1]], axis=1)
    la, lb = [], []
    for side in (0, 1):
        vals = np.unique(pr[:, side])
        last = -np.inf
        for v in vals:
            if s[v] - last >= step or v == vals[-1]:
                last = s[v]
                m = pr[:, side] == v
                k = np.flatnonzero(m)[np.argmin(d[m])]
                la.append(l[v])
                lb.append(l[pr[k, 1 - side]])
    lb, _ = _nearest_partner(model, la, lb, 2 * hl)
    out = []
    for a, b in zip(la, lb):
        a, b = sorted((float(a), float(b)))
        if abs(float(model.arc([b])[0]) - float(model.arc([a])[0])) > exclude_arc:
            out.append((a, b))
    return out


def _near(active, a, b, tol) -> bool:
    """Whether a pair of ``active`` lies within ``tol`` of (a, b) in both coordinates."""
    return any(abs(a - a2) < tol and abs(b - b2) < tol for a2, b2 in active)


def _covered(regions, active, need, step) -> bool:
    """Whether every region closer than ``need`` has a constrained pair within ``step`` of its minimum (both
    material coordinates, either order): its shortfall then dips between rows that hold."""
    return all(_near(active, r["l_i"], r["l_j"], step) or _near(active, r["l_j"], r["l_i"], step)
               for r in regions if r["clearance"] < need)


def _rank(res, check, need) -> tuple:
    """The order of the rounds' designs: converged first, then those that meet the clearance (the lower
    objective first), then the larger clearance."""
    met = check["clearance"] >= need
    return (not res.converged, not met, res.stats.get("objective", 0.0) if met else -check["clearance"])


def _add_pairs(active, new, tol):
    """Add pairs not within ``tol`` (both coordinates) of one already there."""
    for a, b in new:
        if not _near(active, a, b, tol):
            active.append((a, b))


def design_with_clearance(problem: DesignProblem, min_gap: float = 0.0, pairs=None, rounds: int = 6,
                          detect_margin: float | None = None, exclude_arc: float | None = None, start: Result | None = None,
                          tol_gap: float = 1e-7, pair_step: float | None = None, **kw) -> Result:
    """Inverse design with |r_c(l_a) - r_c(l_b)| >= D + min_gap at the contact pairs (active-set loop).

    ``start``: a design to start from (default: design_nlp(problem, **kw)); returned unchanged
    when it is already clear and no ``pairs`` are given. ``pairs``: extra (l_a, l_b)
    material-coordinate pairs (problem units) constrained from the first solve on (at least one).
    ``detect_margin`` (default D/4): pairs closer than D + min_gap + margin are constrained.
    ``exclude_arc`` (default pi (D + min_gap) / 2): nearer points along the tube are neighbours, never paired.
    The loop stops when the continuous minimum clearance (analysis.collision.routing_clearance)
    is >= D + min_gap - tol_gap D and no region needs new rows, or after ``rounds`` solves.
    stats: clearance_rounds, clearance_pairs, min_clearance, start_rmse, start_min_clearance.
    """
    D = problem.diameter
    need = D + min_gap
    margin = 0.25 * D if detect_margin is None else float(detect_margin)
    step = 0.5 * D if pair_step is None else float(pair_step)
    # neighbours: half a turn of the tightest circle that keeps them ``need`` apart (analysis.collision,
    # "Neighbours", with D + min_gap for D): nearer points of any tube bent more gently are farther apart
    # than need, and a row between them would ask for a chord longer than their arc
    exclude_arc = 0.5 * math.pi * need if exclude_arc is None else float(exclude_arc)
    t_all = time.perf_counter()
    start = start or design_nlp(problem, **kw)
    routing = start.routing
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    R0g = routing.initial_pose[:3, :3].copy()
    params = nlp_parameters(problem, pairing, R0g)
    active = [(float(a), float(b)) for a, b in (pairs or [])]
    x, best, solves, row_margin = None, start, 0, 0.0
    best_check, converged = None, True
    ipopt_time, ipopt_iterations = 0.0, 0
    check = first = routing_clearance(routing, D, exclude_arc=exclude_arc, margin=min_gap + margin)
    while True:
        short = need - check["clearance"]
        if (short <= tol_gap * D and (solves or not active) and converged) or solves >= rounds:
            break
        if solves and _covered(check["regions"], active, need - tol_gap * D, step):
            # what is left dips between constrained pairs: raise the rows' target past it (where a region
            # has no pair near its minimum, the tube moved into a new contact: its pairs are added below,
            # and raising every row for it pushed the tube ever farther, the loop running away)
            row_margin += MARGIN_FACTOR * short
        model = _ModelLine(routing, D)
        for r in check["regions"]:
            _add_pairs(active, _region_pairs(r, check["line"], model, exclude_arc, step), step / 4)
            if r["clearance"] < need - tol_gap * D:
                _add_pairs(active, [(r["l_i"], r["l_j"])], 1e-6 * D)
        # rows at material points, located on the current segment lengths
        ends = [(locate(a, routing.length), locate(b, routing.length)) for a, b in active]
        solver = extended_solver(problem, pairing, (ClearancePairs(tuple((ea[0], eb[0]) for ea, eb in ends)),))
        p = solver.pack_params(params | {"pair_u": np.array([[ea[1], eb[1]] for ea, eb in ends]).T,
                                         "pair_need": ((need + row_margin) / D) ** 2})
        lbx, ubx = solver.bounds(*design_bounds(problem, pairing))
        x0 = start_x(solver, chain_guess(problem, start.routing), D, "chain") if x is None else x
        x, status, st = solver.solve(x0, p, lbx, ubx)
        ipopt_time += st["ipopt_time_s"]
        ipopt_iterations += st["iterations"]
        solves += 1
        res = result_of(problem, pairing, solver, x, status, st, R0g, "nlp_clearance")
        routing, converged = res.routing, res.converged
        check = routing_clearance(routing, D, exclude_arc=exclude_arc, margin=min_gap + margin)
        if solves == 1 or _rank(res, check, need - tol_gap * D) < _rank(best, best_check, need - tol_gap * D):
            best, best_check = res, check
    if best_check is not None:  # the stats of the design returned
        check = best_check
    best.stats.update({
        "clearance_rounds": solves, "clearance_met": bool(check["clearance"] >= need - tol_gap * D), "clearance_pairs": len(active),
        "clearance_row_margin": row_margin, "min_clearance": float(check["clearance"]), "min_gap": float(min_gap),
        "start_rmse": float(start.metrics["rmse"]), "start_min_clearance": float(first["clearance"]),
        "ipopt_time_s": ipopt_time, "ipopt_iterations": ipopt_iterations,
    })
    best.solve_time_s = time.perf_counter() - t_all
    return best
