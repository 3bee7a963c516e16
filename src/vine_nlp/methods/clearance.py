"""Inverse design that keeps the tube clear of itself: the plain NLP plus clearance rows.

For chosen pairs of material points (l_a, l_b): |r_c(l_a) - r_c(l_b)|^2 >= (D + min_gap)^2, each point the frame X_j of
its segment times the partial segment (the fraction as data). Which pairs: an active set on the drive (``drive.refine``,
the rule :class:`_Pairs`). Start from design_nlp's result; detect the contact regions of the current design
(analysis.collision.routing_clearance, with a detection margin); constrain, for every sampled point of a region, the
pair with its closest partner, plus each region's continuous minimum; re-solve warm; until the continuous minimum
clearance is >= D + min_gap (to settings.CLEARANCE_TOL D). Pairs are never dropped. Between the rows, and as material points slide
along the tube, the clearance can dip below the target: after a solve the rows' target rises by settings.RAISE_FACTOR
times the shortfall, but only where every short region has a constrained pair near its minimum (a dip between rows that
hold); a region without one is a new contact and gets its pairs instead (raising for it pushed tight coils ever farther
open: the loop ran away). The pairs' segments are structure (a solver per active set, cached), their fractions and the
required distance data."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.analysis.collision import routing_clearance
from vine_nlp.analysis.obstacles import ModelLine
from vine_nlp.methods import drive
from vine_nlp.methods.blocks import BlockType
from vine_nlp.methods.buildable import inherited_bounds
from vine_nlp.methods.common import pair_points
from vine_nlp.methods.nlp import chain_guess, design_nlp, extended_solver, nlp_parameters, result_of, start_x
from vine_nlp.methods.settings import CLEARANCE_DETECT, CLEARANCE_STEP, CLEARANCE_TOL, RAISE_FACTOR, ROUNDS
from vine_nlp.methods.transcription import Chain, segment_point_index
from vine_nlp.methods.variables import POINT
from vine_nlp.model.segment import segment_function
from vine_nlp.problem import DesignProblem, Result


@lru_cache(maxsize=None)
def pair_block(k: int = 1) -> BlockType:
    """k clearance rows between two segments as one block: v = (X, theta, lam, dl of segment a (15), the same
    of segment b (15)), d = (fractions on a (k), fractions on b (k), need); r_i = |r_c(a_i) - r_c(b_i)|^2 - need
    (>= 0), units of D^2. The rows of one segment pair share their segments' helix quantities and one
    30 x 30 Hessian block (fewer instructions and scattered entries than a block per row). f is a structural
    zero: the block stays out of the objective's evaluation and gradient."""
    F = segment_function(k)
    v, d = ca.SX.sym("v", 2 * POINT.size), ca.SX.sym("d", 2 * k + 1)  # variables.POINT of segment a, then of b
    _, pa = F(*POINT.split(v), d[:k])
    _, pb = F(*POINT.split(v, POINT.size), d[k : 2 * k])
    r = ca.sum1((pa - pb) ** 2).T - d[2 * k]
    return BlockType(f"clearance_pairs{k}", ca.Function("pair_block", [v, d], [ca.SX(1, 1), r], {"cse": True}))


@dataclass(frozen=True)
class ClearancePairs:
    """Rows |r_c(a) - r_c(b)|^2 >= need for pairs of points given by their segments (structure), one block per segment
    pair (pair_block); parameters pair_u (2 x P, the fractions) and pair_need (the squared distance, units of D^2)."""

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


def _add_pairs(active, new, tol):
    """Add pairs not within ``tol`` (both coordinates) of one already there."""
    for a, b in new:
        if not _near(active, a, b, tol):
            active.append((a, b))


def design_with_clearance(problem: DesignProblem, min_gap: float = 0.0, start: Result | None = None, **kw) -> Result:
    """Inverse design with |r_c(l_a) - r_c(l_b)| >= D + min_gap at the contact pairs (active-set loop).

    ``start``: a design to start from (default: design_nlp(problem, **kw)); returned (a copy) when it is already clear.
    Pairs closer than D + min_gap + settings.CLEARANCE_DETECT D are constrained; points nearer than pi (D + min_gap) / 2
    along the tube are neighbours, never paired. The loop stops when the continuous minimum clearance
    (analysis.collision.routing_clearance) is >= D + min_gap - settings.CLEARANCE_TOL D and no region needs new rows,
    or after settings.ROUNDS solves. stats: clearance_rounds, clearance_pairs, min_clearance, start_rmse,
    start_min_clearance; iterations and ipopt_time_s summed over the rounds."""
    D = problem.diameter
    # neighbours: half a turn of the tightest circle that keeps them D + min_gap apart (analysis.collision,
    # "Neighbours", with D + min_gap for D): nearer points of any tube bent more gently are farther apart
    # than that, and a row between them would ask for a chord longer than their arc
    exclude_arc = 0.5 * math.pi * (D + min_gap)
    stats = drive.Stats()
    start = start or design_nlp(problem, **kw)
    rule = _Pairs(problem, start, min_gap, CLEARANCE_DETECT * D, exclude_arc, CLEARANCE_TOL * D, CLEARANCE_STEP * D)
    first = rule.check
    if first["clearance"] >= rule.need - rule.tol:
        best, check, solves = dataclasses.replace(start, metrics=dict(start.metrics), stats=dict(start.stats), met=dict(start.met)), first, 0
    else:
        found = drive.refine(rule, ROUNDS, stats=stats)
        best, check, solves = stats.stamp(found.best), found.verdict.report, found.rounds
    best.met["clearance"] = bool(check["clearance"] >= rule.need - rule.tol)
    best.stats.update({"clearance_rounds": solves, "clearance_met": best.met["clearance"], "clearance_pairs": len(rule.active),
                       "clearance_row_margin": rule.row_margin, "min_clearance": float(check["clearance"]), "min_gap": float(min_gap),
                       "start_rmse": float(start.metrics["rmse"]), "start_min_clearance": float(first["clearance"])})
    return best


class _Pairs:
    """The clearance's active set, a rule of ``drive.refine``: the pairs of the contact regions (from the start
    and every round), the rows' target raised for dips between rows that hold."""

    def __init__(self, problem, start, min_gap, margin, exclude_arc, tol, step):
        self.problem, self.start, self.D = problem, start, problem.diameter
        self.need, self.tol, self.step, self.exclude_arc = self.D + min_gap, tol, step, exclude_arc
        self.detect = min_gap + margin
        self.pairing = pair_points(problem.target, problem.options.points_per_segment)
        self.R0g = start.routing.initial_pose[:3, :3].copy()
        self.params = nlp_parameters(problem, self.pairing, self.R0g)
        self.active = []
        self.row_margin = 0.0
        self.check = routing_clearance(start.routing, self.D, exclude_arc=exclude_arc, margin=self.detect)

    def _add(self, check, routing):
        """The pairs of every region of ``check``, and each region's minimum where it is short."""
        model = ModelLine(routing, self.D)
        for r in check["regions"]:
            _add_pairs(self.active, _region_pairs(r, check["line"], model, self.exclude_arc, self.step), self.step / 4)
            if r["clearance"] < self.need - self.tol:
                _add_pairs(self.active, [(r["l_i"], r["l_j"])], 1e-6 * self.D)
        self.routing = routing

    def solve(self, x, round, last):
        problem, pairing, D = self.problem, self.pairing, self.D
        if round == 0:
            self._add(self.check, self.start.routing)
        # rows at material points, located on the current segment lengths
        ends = [(locate(a, self.routing.length), locate(b, self.routing.length)) for a, b in self.active]
        solver = extended_solver(problem, pairing, (ClearancePairs(tuple((ea[0], eb[0]) for ea, eb in ends)),))
        p = solver.pack_params(self.params | {"pair_u": np.array([[ea[1], eb[1]] for ea, eb in ends]).T,
                                              "pair_need": ((self.need + self.row_margin) / D) ** 2})
        x0 = start_x(solver, chain_guess(problem, self.start.routing), D, "chain") if x is None else x
        sol = solver.solve(x0, p, *solver.bounds(**inherited_bounds(problem, pairing, self.start)))  # a buildable start's classes kept
        return sol.x, result_of(problem, pairing, sol, self.R0g, "nlp_clearance")

    def judge(self, res):
        check = routing_clearance(res.routing, self.D, exclude_arc=self.exclude_arc, margin=self.detect)
        met = check["clearance"] >= self.need - self.tol
        return drive.Verdict(met and res.converged, drive.rank(res, met, self.need - check["clearance"]), check)

    def refresh(self, res, verdict, x):
        check = verdict.report
        if _covered(check["regions"], self.active, self.need - self.tol, self.step):
            # what is left dips between constrained pairs: raise the rows' target past it (where a region
            # has no pair near its minimum, the tube moved into a new contact: its pairs are added below,
            # and raising every row for it pushed the tube ever farther, the loop running away)
            self.row_margin += RAISE_FACTOR * (self.need - check["clearance"])
        self._add(check, res.routing)
        return x
