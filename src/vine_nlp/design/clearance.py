"""Inverse design that keeps the tube clear of itself: the NLP of design.nlp plus clearance rows.

Formulation (smooth): for chosen pairs of material points (l_a, l_b) of the tube,

    |r_c(l_a) - r_c(l_b)|^2 >= (D + min_gap)^2,

each point evaluated inside the multiple-shooting NLP as frame X_j of its segment
times the partial segment (design.nlp.segment_function with the fraction fixed).
Which pairs: an active-set outer loop. Start from design_nlp's result; detect the
contact regions of the current design (analysis.collision.routing_clearance with a
detection margin); constrain, for every sampled point of a region, the pair with
its closest partner, plus each region's refined (continuous) minimum; re-solve
warm; repeat until the continuous minimum clearance is >= D + min_gap (to
``tol_gap`` D) or ``rounds`` is exhausted. Pairs are never dropped, so the rounds
only add rows. Rows hold material points apart where they are; between them, and
as the optimizer slides points along the tube (segment lengths are variables), the
clearance can dip ~1e-3 D below the target. From the second solve on, the rows'
target is raised by 1.5x the remaining shortfall (stats clearance_row_margin), which
ends the loop in 2-3 solves with the continuous clearance >= D + min_gap.

:class:`ExtendedNLP` is the shared builder (also used by design.robust): nlp.py's
objective and continuity constraints come from its cached NLPSolver's CasADi oracle
(one formulation, not a copy), its layout through NLPSolver.pack_x / unpack_x /
bounds / pack_params, and callers add objective terms and constraint rows.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.design.common import (
    Pairing,
    evaluate,
    frames12,
    ipopt_options,
    ipopt_status,
    pair_points,
    variable_bounds,
)
from vine_nlp.design.nlp import design_nlp, get_solver, nlp_parameters, segment_function
from vine_nlp.design.problem import DesignProblem, Routing
from vine_nlp.design.result import Result
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.segment import so3_exp


@lru_cache(maxsize=1)
def _pair_function() -> ca.Function:
    """Squared distance of two center points, each (frame, theta, lam, dl, fraction) of its segment (SX)."""
    F = segment_function(1)
    args_a = [ca.SX.sym("Xa", 12), ca.SX.sym("ta"), ca.SX.sym("la"), ca.SX.sym("da"), ca.SX.sym("ua")]
    args_b = [ca.SX.sym("Xb", 12), ca.SX.sym("tb"), ca.SX.sym("lb"), ca.SX.sym("db"), ca.SX.sym("ub")]
    _, pa = F(*args_a)
    _, pb = F(*args_b)
    return ca.Function("pair_d2", args_a + args_b, [ca.sumsqr(pa - pb)])


class ExtendedNLP:
    """nlp.py's NLP for one problem, started from a routing, open to extra terms and rows.

    Symbolic views (units of D) for building extras: ``x`` (decision vector, MX),
    ``theta``, ``lam``, ``dl`` (1 x M), ``frames`` (12 x (M+1): X_0 .. X_M, rotation
    column-major then position), and ``point(l)`` (center point at material coordinate l).
    Numeric: ``p`` (parameters), ``lbx``, ``ubx``, ``x0``.
    """

    def __init__(self, problem: DesignProblem, start: Routing, pairing: Pairing | None = None):
        o = problem.options
        self.problem = problem
        self.D = D = problem.diameter
        self.pairing = pairing = pairing or pair_points(problem.target, o.points_per_segment)
        M, n = pairing.segments, pairing.n
        if start.segments != M:
            raise ValueError(f"the start routing has {start.segments} segments, the problem {M}")
        self.M, self.n = M, n
        self.base = base = get_solver(M, n, problem.actuator.shared_lambda, o.max_iter, o.tol, False)
        size = base.layout.size
        self.R0g = np.asarray(start.initial_pose, float)[:3, :3].copy()
        self.params = nlp_parameters(problem, pairing, self.R0g)
        self.p = base.pack_params(self.params)
        # where each quantity lives in x: from nlp's own pack/unpack, applied to index codes
        iw, ip, ith, ilam, idl = (np.asarray(v).astype(int) for v in base.unpack_x(np.arange(size, dtype=float)))
        codes = np.zeros((12, M + 1))
        codes[:, 1:] = 1 + np.arange(12 * M).reshape(12, M, order="F")
        where = base.pack_x(np.zeros(3), np.zeros(3), np.zeros(M), np.zeros(M), np.zeros(M), codes)
        nz = np.flatnonzero(where)
        flat = np.zeros(12 * M, int)  # column-major: frame 1 entries 0..11, frame 2 ...
        flat[where[nz].astype(int) - 1] = nz
        self.x = x = ca.MX.sym("x", size)
        R0 = ca.mtimes(ca.DM(self.R0g), so3_exp(x[iw.tolist()]))
        X0 = ca.vertcat(ca.vec(R0), x[ip.tolist()])
        self.theta = x[ith.tolist()].T
        self.lam = x[ilam.tolist()].T
        self.dl = x[idl.tolist()].T
        self.frames = ca.horzcat(X0, ca.reshape(x[flat.tolist()], 12, M))
        self.f0, self.g0 = base.solver.oracle()(x, self.p)
        lo, hi = variable_bounds(problem, pairing)
        self.lbx, self.ubx = base.bounds((lo[0], lo[1], lo[2] / D), (hi[0], hi[1], hi[2] / D))
        fr = chain_frames(start.theta, start.lam, start.length, D, start.initial_pose).copy()
        fr[:, :3, 3] /= D
        x0 = base.pack_x(np.zeros(3), start.initial_pose[:3, 3] / D, start.theta, start.lam, start.length / D, frames12(fr))
        self.x0 = np.clip(x0, self.lbx, self.ubx)
        self._point_fn = segment_function(1)

    def locate(self, l, length):
        """(segment, fraction) of material coordinate l on segment lengths ``length`` (problem units)."""
        cum = np.concatenate([[0.0], np.cumsum(length)])
        j = int(np.clip(np.searchsorted(cum, l, side="right") - 1, 0, self.M - 1))
        return j, float(np.clip((l - cum[j]) / length[j], 0.0, 1.0))

    def point(self, seg: int, frac: float):
        """Center point (3-vector MX, units of D) at fraction ``frac`` of segment ``seg``."""
        _, pts = self._point_fn(self.frames[:, seg], self.theta[seg], self.lam[seg], self.dl[seg], frac)
        return pts

    def points(self, segs, fracs):
        """Center points (3 x K MX, units of D) at fractions ``fracs`` of segments ``segs`` (one mapped call)."""
        segs = [int(v) for v in segs]
        F = self._point_fn.map(len(segs), "serial")
        _, pts = F(self.frames[:, segs], self.theta[segs], self.lam[segs], self.dl[segs], ca.DM(np.asarray(fracs, float)).T)
        return pts

    def pair_distances2(self, seg_a, frac_a, seg_b, frac_b):
        """|r_c(a) - r_c(b)|^2 (1 x K MX, units of D^2) for K pairs of (segment, fraction), one mapped SX call."""
        K = len(seg_a)
        F = _pair_function().map(K, "serial")
        ia, ib = [int(v) for v in seg_a], [int(v) for v in seg_b]
        q = [self.frames, self.theta, self.lam, self.dl]
        return F(*[v[:, ia] for v in q], ca.DM(np.asarray(frac_a, float)).T, *[v[:, ib] for v in q], ca.DM(np.asarray(frac_b, float)).T)

    def solve(self, extra_f=0, extra_g=None, lbg=None, ubg=None, x0=None, max_iter=None, z=None, z0=None, expand=False):
        """IPOPT on f0 + extra_f s.t. continuity = 0 and lbg <= extra_g <= ubg.

        ``z``: extra (free) decision variables (an MX symbol) appended to x, started at ``z0``;
        ``x0`` may include them. ``expand``: SX evaluation (fast iterations, slower build).
        Returns (x (the base layout), z values or None, stats dict).
        """
        o = self.problem.options
        g = self.g0 if extra_g is None else ca.vertcat(self.g0, extra_g)
        ng0 = self.g0.numel()
        lb = np.concatenate([np.zeros(ng0), [] if extra_g is None else np.asarray(lbg, float).ravel()])
        ub = np.concatenate([np.zeros(ng0), [] if extra_g is None else np.asarray(ubg, float).ravel()])
        nx, nz = self.x.numel(), (0 if z is None else z.numel())
        xv = self.x if z is None else ca.vertcat(self.x, z)
        start = np.asarray(self.x0 if x0 is None else x0, float).ravel()
        if nz and start.size == nx:
            start = np.concatenate([start, np.zeros(nz) if z0 is None else np.asarray(z0, float).ravel()])
        lbx = np.concatenate([self.lbx, np.full(nz, -np.inf)])
        ubx = np.concatenate([self.ubx, np.full(nz, np.inf)])
        # nlp.py's settings; constraint rows held tightly (a clearance is a hard requirement)
        opts = ipopt_options(max_iter or o.max_iter, o.tol) | {
            "expand": bool(expand),
            "ipopt.acceptable_tol": 1e-6,
            "ipopt.acceptable_iter": 15,
            "ipopt.constr_viol_tol": 1e-10,
            "ipopt.acceptable_constr_viol_tol": 1e-9,
        }
        t0 = time.perf_counter()
        solver = ca.nlpsol("vine_nlp_extended", "ipopt", {"x": xv, "f": self.f0 + extra_f, "g": g}, opts)
        build = time.perf_counter() - t0
        t0 = time.perf_counter()
        sol = solver(x0=start, lbx=lbx, ubx=ubx, lbg=lb, ubg=ub)
        st = solver.stats()
        gv = np.array(sol["g"]).ravel()
        viol = float(max(np.max(np.abs(gv[:ng0]), initial=0.0), np.max(np.maximum(lb[ng0:] - gv[ng0:], 0.0), initial=0.0),
                         np.max(np.maximum(gv[ng0:] - ub[ng0:], 0.0), initial=0.0)))
        xs = np.array(sol["x"]).ravel()
        return xs[:nx], (xs[nx:] if nz else None), {
            "return_status": st.get("return_status", ""),
            "iterations": int(st.get("iter_count", 0)),
            "solve_time_s": time.perf_counter() - t0,
            "build_time_s": build,
            "objective": float(sol["f"]),
            "max_constraint_violation": viol,
        }

    def routing(self, x) -> Routing:
        w_rot, p0, theta, lam, dl = self.base.unpack_x(x)
        T0 = np.eye(4)
        T0[:3, :3] = self.R0g @ so3_exp(w_rot)
        T0[:3, 3] = p0 * self.D
        return Routing(theta, lam, dl * self.D, T0)

    def result(self, x, stats: dict, method: str, **extra_stats) -> Result:
        fit, smooth = (float(v) for v in self.base._terms(x, self.p))
        status = ipopt_status(stats)
        if not np.all(np.isfinite(x)):
            status = "invalid_number"
        o = self.problem.options
        return evaluate(
            self.problem, self.routing(x), self.pairing, method, status=status,
            solve_time_s=stats["solve_time_s"], iterations=stats["iterations"],
            stats={
                "solver": "ipopt", "return_status": stats["return_status"], "build_time_s": stats["build_time_s"],
                "objective": stats["objective"], "objective_fit": fit, "objective_smooth": smooth,
                "segments": self.M, "points_per_segment": self.n, "smooth_theta": o.smooth_theta,
                "smooth_lambda": o.smooth_lambda, "tol": o.tol, "max_iter": o.max_iter,
                "max_constraint_violation": stats["max_constraint_violation"], **extra_stats,
            },
        )


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


def _add_pairs(active, new, tol):
    """Add pairs not within ``tol`` (both coordinates) of one already there."""
    for a, b in new:
        if not any(abs(a - a2) < tol and abs(b - b2) < tol for a2, b2 in active):
            active.append((a, b))


def design_with_clearance(problem: DesignProblem, min_gap: float = 0.0, pairs=None, rounds: int = 6,
                          detect_margin: float | None = None, exclude_arc: float | None = None, start: Result | None = None,
                          tol_gap: float = 1e-7, pair_step: float | None = None, **kw) -> Result:
    """Inverse design with |r_c(l_a) - r_c(l_b)| >= D + min_gap at the contact pairs (active-set loop).

    ``start``: a design to start from (default: design_nlp(problem, **kw)); returned unchanged
    when it is already clear and no ``pairs`` are given. ``pairs``: extra (l_a, l_b)
    material-coordinate pairs (problem units) constrained from the first solve on (at least one).
    ``detect_margin`` (default D/4): pairs closer than D + min_gap + margin are constrained.
    The loop stops when the continuous minimum clearance (analysis.collision.routing_clearance)
    is >= D + min_gap - tol_gap D and no region needs new rows, or after ``rounds`` solves.
    stats: clearance_rounds, clearance_pairs, min_clearance, start_rmse, start_min_clearance.
    """
    from vine_nlp.analysis.collision import _ModelLine, routing_clearance

    D = problem.diameter
    need = D + min_gap
    margin = 0.25 * D if detect_margin is None else float(detect_margin)
    step = 0.5 * D if pair_step is None else float(pair_step)
    exclude_arc = 0.5 * math.pi * D if exclude_arc is None else float(exclude_arc)
    t_all = time.perf_counter()
    start = start or design_nlp(problem, **kw)
    routing = start.routing
    nlp = ExtendedNLP(problem, routing)
    active = [(float(a), float(b)) for a, b in (pairs or [])]
    x, best, solves, row_margin = None, start, 0, 0.0
    first = routing_clearance(routing, D, exclude_arc=exclude_arc, margin=min_gap + margin)
    check = first
    while True:
        short = need - check["clearance"]
        if (short <= tol_gap * D and (solves or not active)) or solves >= rounds:
            break
        if solves:
            # what is left dips between constrained pairs: raise the rows' target past it
            row_margin += MARGIN_FACTOR * short
        model = _ModelLine(routing, D)
        for r in check["regions"]:
            _add_pairs(active, _region_pairs(r, check["line"], model, exclude_arc, step), step / 4)
            if r["clearance"] < need - tol_gap * D:
                _add_pairs(active, [(r["l_i"], r["l_j"])], 1e-6 * D)
        # rows at material points, located on the current segment lengths
        ends = [nlp.locate(v, routing.length) for ab in active for v in ab]
        g = nlp.pair_distances2([e[0] for e in ends[0::2]], [e[1] for e in ends[0::2]],
                                [e[0] for e in ends[1::2]], [e[1] for e in ends[1::2]]).T
        x, _, st = nlp.solve(0, g, np.full(g.numel(), ((need + row_margin) / D) ** 2), np.full(g.numel(), np.inf), x0=x)
        solves += 1
        best = nlp.result(x, st, "nlp_clearance")
        routing = best.routing
        check = routing_clearance(routing, D, exclude_arc=exclude_arc, margin=min_gap + margin)
    best.stats.update({
        "clearance_rounds": solves,
        "clearance_met": bool(check["clearance"] >= need - tol_gap * D),
        "clearance_pairs": len(active),
        "clearance_row_margin": row_margin,
        "min_clearance": float(check["clearance"]),
        "min_gap": float(min_gap),
        "start_rmse": float(start.metrics["rmse"]),
        "start_min_clearance": float(first["clearance"]),
    })
    best.solve_time_s = time.perf_counter() - t_all
    return best
