"""Design among obstacles (issue 15): the one transcription plus rows that keep the tube outside every obstacle.

Rows. The center line must stay at least r = D/2 + margin from every obstacle. Each
segment j carries S samples at fractions u_i = i/S (the last segment i/(S-1), so its tip
is one), at most h_j = dl_j / S apart along the arc (the actuated arc is never longer than
dl). Between samples the distance drops at most ``dip(h_j)`` (analysis.obstacles, "Sampling
rule", with the obstacle's radius of curvature and the curvature bound of the actuator), so
the rows ask every sample for

    distance(point_i) >= D/2 + margin + dip(h_j)          (units of D in the NLP)

and the continuous tube then clears by the margin. The required distance is data, set
from the current segment lengths (times ``LENGTH_SLACK``, since dl moves during a solve) at
every round, so the solver is built once.

Blocks. Rows are per-stage SX blocks (design.transcription) over (shape, segment, obstacle)
instances; v = (X_j, theta_j, lam_j, dl_j), 15 local variables:
  primitives (sphere, box, capsule, plane): one block type per obstacle, its exact smooth
      distance (analysis.obstacles) with the obstacle's numbers (scaled by 1/D) baked in: the
      obstacles are part of the problem, so a built solver serves every target, start and round
      with the same obstacles; d = (u (S), t, need).
  meshes: the active set, ``k`` nearest triangles of every sample (exact, nearest_triangles),
      refreshed between solves; the triangles are data, so a refresh changes data only, never
      the solver. Rows: unsigned point-triangle distances (exact rows: a mesh's unsigned
      distance is the minimum over its triangles, and a triangle is convex, so each row is
      C^1 where it is positive). A sample the exact (trimesh) sign finds *inside* the mesh
      instead gets one linear row, the signed distance to the plane of its nearest face,
      pushing it out through that face, and no triangle rows (they would push it deeper, away
      from the surface); the next refresh gives it triangle rows again. A row switched off by
      its data weight a = 0 is the constant 1 (always satisfied).

Growth. Grown while actuated, every intermediate body is a prefix of the final shape: the
final rows cover it. Actuated after growth ("after"), the tube sweeps lambda_t = 1 - t (1 -
lambda), and the shapes of the report's grid t = 0, 1/20, ..., 19/20 (t = 1 is the final shape)
must clear too. ``AFTER_SLOTS`` (5) of them carry rows at a time: first the worst shapes of the
start, then, round by round, a shape of the grid that does not clear replaces one with rows that
clears by the most (t is data: the solver is built once). Their chains are *extra levels* of the
multiple shooting: 12 extra stage variables per level hold the frames E_j(t) of the intermediate
chain, tied by per-stage continuity blocks E_{j+1}(t) = E_j(t) T(theta_j, lambda_t,j, dl_j) and
E_0(t) = X_0. (With rows on all 19 intermediate shapes at once, the first solve of
obstacle-gap, 20 segments, had not finished after 15 min on a loaded 2-core machine.) Single
shooting through segment_function from the base (global rows on every upstream variable)
would make every row depend on all upstream segments: a dense Jacobian and Hessian, costly
in M (automatic derivatives on the whole chain) and badly conditioned for long chains; extra
levels keep everything banded, at 12 variables per stage and level.

Loop. Start from the obstacle-free design (design_nlp), keep it when it already clears;
otherwise solve with the rows (warm, from the start's chain), check with the report
(analysis.obstacles.obstacle_report: 20 points per segment, exact mesh distances, refined
minima), refresh the mesh active sets, raise the rows' requirement by 1.5x what is still
missing, re-solve warm; until the report is clear or ``rounds`` solves are done.

Tip problems (design.tip) take the same rows on the tip formulation's chain (fixed base):
every start of the tip design (the obstacle-free tip design first) is solved with them,
the best converged start that clears wins.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.analysis.obstacles import (
    DEFAULT_AFTER_STEPS,
    DEFAULT_PER_SEGMENT,
    Mesh,
    after_growth_routing,
    curvature_bound,
    dip,
    mesh_signed_distance,
    nearest_triangles,
    obstacle_report,
    sharpness_radius,
)
from vine_nlp.design.clearance import chain_guess, extended_solver, result_of
from vine_nlp.design.common import pair_points
from vine_nlp.design.nlp import design_bounds, design_nlp, nlp_parameters, start_x
from vine_nlp.design.problem import DesignProblem, Routing, TipProblem
from vine_nlp.design.result import Result
from vine_nlp.design.tip import (
    MIN_LENGTH_FACTOR,
    _perpendicular_pair,
    design_tip,
    evaluate_tip,
    start_guesses,
    tip_spec,
)
from vine_nlp.design.transcription import HARD_ROWS, BlockType, Chain, frames12, get_solver, options_key, pick_best
from vine_nlp.model.chain import chain_frames, chain_points
from vine_nlp.model.segment import segment_function

RUN = "nlp"  # the obstacle design is the problem's design (archived as run "nlp"); the obstacle-free start: FREE_RUN
FREE_RUN = "nlp_free"
METHOD = "nlp_obstacles"
SPACING = 0.25  # target sample spacing h0, units of D: dip(D/4) ~ 0.03 D for a sharp obstacle
LENGTH_SLACK = 1.25  # segment lengths may grow this much during a solve before the rows' dip is too small
MAX_SAMPLES = 40  # samples per segment
AFTER_SLOTS = 5  # growth "after": intermediate shapes with rows at a time (their t are data, chosen from the report)
MESH_K = 6  # nearest triangles per sample
ROUNDS = 6
MESH_ROUNDS = 12  # meshes: each round moves the tube at most MESH_TRUST, the active sets follow
MESH_TRUST = 1.5  # units of D: a frame moves at most this far per solve with a mesh (its nearest triangles stay valid)
RAISE_FACTOR = 1.5  # the rows' requirement grows by this times the remaining shortfall
TRI_EPS = 1e-9  # sqrt(d2 + eps^2) (units of D): finite gradients at distance 0


# ------------------------------------------------------------------ block types


def _lam_t(lam, t):
    return 1 - t * (1 - lam)


@lru_cache(maxsize=64)
def primitive_block(ob, S: int) -> BlockType:
    """Rows distance(point_i) - need >= 0 of S samples of one segment to one primitive ``ob`` (units of D).

    v = (X_j (12), theta, lam, dl); d = (u (S), t, need): points of the shape lambda_t = 1 - t (1 - lam)."""
    v, d = ca.SX.sym("v", 15), ca.SX.sym("d", S + 2)
    _, pts = segment_function(S)(v[:12], v[12], _lam_t(v[13], d[S]), v[14], d[:S])
    r = ca.vec(ob.distance(pts)) - d[S + 1]
    return BlockType(f"obstacle_{ob.kind}{S}", ca.Function("obstacle_block", [v, d], [ca.SX(0), r]))


def _seg_d2(p, a, b):
    ab, ap = b - a, p - a
    t = ca.fmin(ca.fmax(ca.dot(ap, ab) / ca.dot(ab, ab), 0), 1)
    e = ap - t * ab
    return ca.dot(e, e)


def triangle_distance_sx(p, a, b, c):
    """Unsigned distance from p to the triangle (a, b, c), all symbolic (SX 3-vectors): as
    analysis.obstacles.point_triangle_distance (plane inside the prism, else the nearest edge)."""
    ab, ac, ap = b - a, c - a, p - a
    n = ca.cross(ab, ac)
    nn = ca.dot(n, n)
    w_b = ca.dot(ap, ca.cross(ac, n)) / nn
    w_c = ca.dot(ap, ca.cross(n, ab)) / nn
    inside = ca.logic_and(ca.logic_and(w_b >= 0, w_c >= 0), 1 - w_b - w_c >= 0)
    h2 = ca.dot(ap, n) ** 2 / nn
    edges = ca.fmin(_seg_d2(p, a, b), ca.fmin(_seg_d2(p, b, c), _seg_d2(p, c, a)))
    return ca.sqrt(ca.if_else(inside, h2, edges) + TRI_EPS**2)


def mesh_data_size(S: int, k: int) -> int:
    return S + 2 + 9 * k * S + S + 4 * S + S


@lru_cache(maxsize=16)
def mesh_block(S: int, k: int) -> BlockType:
    """Rows of S samples of one segment to a mesh's active set (module docstring), S (k + 1) rows.

    d = (u (S), t, need, triangles (9 k per sample: a, b, c of each), a_tri (S), plane (4 per
    sample: unit normal, offset), a_plane (S)); per sample: the plane row, then k triangle rows."""
    v, d = ca.SX.sym("v", 15), ca.SX.sym("d", mesh_data_size(S, k))
    _, pts = segment_function(S)(v[:12], v[12], _lam_t(v[13], d[S]), v[14], d[:S])
    need = d[S + 1]
    o = S + 2
    tri = d[o : o + 9 * k * S]
    o += 9 * k * S
    a_tri, plane = d[o : o + S], d[o + S : o + 5 * S]
    a_plane = d[o + 5 * S : o + 6 * S]
    rows = []
    for i in range(S):
        p = pts[:, i]
        nrm, off = plane[4 * i : 4 * i + 3], plane[4 * i + 3]
        rows.append(a_plane[i] * (ca.dot(nrm, p) - off - need) + (1 - a_plane[i]))
        for q in range(k):
            t9 = tri[9 * (i * k + q) : 9 * (i * k + q) + 9]
            dist = triangle_distance_sx(p, t9[0:3], t9[3:6], t9[6:9])
            rows.append(a_tri[i] * (dist - need) + (1 - a_tri[i]))
    return BlockType(f"obstacle_mesh{S}x{k}", ca.Function("obstacle_mesh_block", [v, d], [ca.SX(0), ca.vertcat(*rows)]))


@lru_cache(maxsize=1)
def after_block() -> BlockType:
    """Continuity of an intermediate chain: v = (E_j (12), theta, lam, dl, E_{j+1} (12)); d = t."""
    v, d = ca.SX.sym("v", 27), ca.SX.sym("d", 1)
    Xn, _ = segment_function(1)(v[:12], v[12], _lam_t(v[13], d[0]), v[14], ca.SX(0))
    return BlockType("after_growth", ca.Function("after_block", [v, d], [ca.SX(0), Xn - v[15:]]))


# ------------------------------------------------------------------ the term


@dataclass(frozen=True)
class ObstacleRows:
    """Obstacle rows on the chain (module docstring). ``obstacles``: per obstacle, the primitive scaled
    by 1/D, or the string "mesh" (its triangles are data); ``S`` samples per segment; ``levels``:
    intermediate shapes of actuation after growth, each an extra level of 12 stage variables
    (Structure.extra = 12 levels), their t the parameter ``after_t``; ``k`` triangles per mesh
    sample. Parameters: ``obstacle_<q>`` (data of obstacle q's blocks, one column per (shape,
    segment), shape-major: the final shape, then the levels)."""

    obstacles: tuple
    S: int
    levels: int = 0
    k: int = MESH_K

    def apply(self, c: Chain) -> None:
        s, lay = c.s, c.lay
        M = s.M
        x = c.x
        if self.levels:
            ts = c.param("after_t", (1, self.levels))
        for a in range(self.levels):
            E = lay.extra[:, 12 * a : 12 * a + 12]
            c.add_rows(f"after_base_{a}", x[lay.X[0, 0].tolist()] - x[E[0].tolist()], 0.0, 0.0)
            if M > 1:
                idx = np.array([np.r_[E[j], lay.theta[j], lay.lam[j, 0], lay.dl[j], E[j + 1]] for j in range(M - 1)]).T
                c.add_block(after_block(), idx, ca.repmat(ts[0, a], 1, M - 1))
        cols = []
        for a in range(self.levels + 1):
            for j in range(M):
                frame = lay.X[j, 0] if a == 0 else lay.extra[j, 12 * (a - 1) : 12 * a]
                cols.append(np.r_[frame, lay.theta[j], lay.lam[j, 0], lay.dl[j]])
        idx = np.array(cols).T
        for q, ob in enumerate(self.obstacles):
            if ob == "mesh":
                bt, nd = mesh_block(self.S, self.k), mesh_data_size(self.S, self.k)
            else:
                bt, nd = primitive_block(ob, self.S), self.S + 2
            data = c.param(f"obstacle_{q}", (nd, idx.shape[1]))
            c.add_block(bt, idx, data, lb=0.0, ub=np.inf, term="obstacles")


# ------------------------------------------------------------------ the plan: samples, requirements, active sets


class Plan:
    """What the rows of one problem need: samples per segment, shapes (t), the data of every block."""

    def __init__(self, obstacles, D, margin, growth, lengths, actuator, ts=None, k=MESH_K, spacing=SPACING):
        self.obstacles, self.D, self.margin, self.growth = tuple(obstacles), float(D), float(margin), growth
        if growth == "after":
            grid = np.linspace(0.0, 1.0, DEFAULT_AFTER_STEPS + 1) if ts is None else np.asarray(ts, float)
            self.grid = [float(t) for t in grid if t < 1.0]
            self.report_ts = sorted(set(self.grid) | {1.0})
        else:
            self.grid, self.report_ts = [], None
        self.ts = []  # the intermediate shapes with rows (choose_levels)
        self.levels = min(AFTER_SLOTS, len(self.grid))
        self.k = int(min([k] + [len(o.faces) for o in obstacles if isinstance(o, Mesh)]))
        longest = float(np.max(lengths)) / D
        self.S = int(min(MAX_SAMPLES, max(2, math.ceil(LENGTH_SLACK * longest / spacing))))
        self.kappa = curvature_bound(1.0, actuator.theta_max, actuator.lambda_min)
        self.scaled = tuple(o.scaled(1.0 / D) for o in self.obstacles)
        self.term = ObstacleRows(tuple("mesh" if isinstance(o, Mesh) else o for o in self.scaled), self.S, self.levels, self.k)
        self.raised = 0.0  # units of D: added to every requirement by the loop

    @property
    def has_mesh(self) -> bool:
        return any(isinstance(o, Mesh) for o in self.obstacles)

    def trust(self, solver, x, lbx, ubx):
        """Bounds of one solve: with a mesh, every frame position within MESH_TRUST of where it is (the
        active sets are the nearest triangles of the current samples: a tube that moved farther could
        pass through triangles no row sees)."""
        if not self.has_mesh:
            return lbx, ubx
        lbx, ubx = lbx.copy(), ubx.copy()
        idx = solver.layout.X[:, :, 9:].ravel()
        lbx[idx] = np.maximum(lbx[idx], x[idx] - MESH_TRUST)
        ubx[idx] = np.minimum(ubx[idx], x[idx] + MESH_TRUST)
        return lbx, ubx

    @property
    def extra(self) -> int:
        return 12 * self.levels

    def choose_levels(self, rep: dict) -> None:
        """Growth "after": the intermediate shapes (t of the report's grid) that get rows, ``levels`` of them.

        First the worst shapes of the report; later a shape of the grid that does not clear replaces the
        shape with rows that clears by the most (never one that does not clear)."""
        if not self.levels:
            return
        inter = rep["intermediate"]
        gap = {float(t): float(g) for t, g in zip(inter["t"], inter["gaps"].min(axis=1)) if float(t) in self.grid}
        order = sorted(gap, key=lambda t: gap[t])
        if not self.ts:
            self.ts = sorted(order[: self.levels])
            return
        tol = self.margin - 1e-3 * self.D
        for t in order:
            if gap[t] >= tol:
                break
            if t in self.ts:
                continue
            worst_kept = max(self.ts, key=lambda q: gap.get(q, math.inf))
            if gap.get(worst_kept, math.inf) < tol:
                break  # every slot holds a shape that does not clear yet
            self.ts[self.ts.index(worst_kept)] = t
        self.ts = sorted(self.ts)

    def fractions(self, M: int) -> np.ndarray:
        """(S, M) sample fractions: i/S, the last segment i/(S-1) (its tip included)."""
        S = self.S
        u = np.tile((np.arange(S) / S)[:, None], (1, M))
        u[:, -1] = np.arange(S) / (S - 1)
        return u

    def need(self, ob, dl: np.ndarray) -> np.ndarray:
        """Required center distance per segment (units of D): 1/2 + margin + dip(h_j) + raised."""
        M = dl.size
        gaps = np.full(M, self.S, float)
        gaps[-1] = self.S - 1
        h = LENGTH_SLACK * dl / gaps
        m = self.margin / self.D
        sharp = sharpness_radius(ob)
        dips = np.array([dip(hj, 1.0, m, self.kappa, sharp) for hj in h])
        return 0.5 + m + np.minimum(dips, 1.0) + self.raised

    def sample_points(self, routing: Routing, t: float) -> np.ndarray:
        """(M, S, 3) sample points of the shape at t (problem units)."""
        r = routing if t == 1.0 else after_growth_routing(routing, t)
        M = r.segments
        u = self.fractions(M)
        seg = np.repeat(np.arange(M), self.S)
        frac = u.T.ravel()
        frames = chain_frames(r.theta, r.lam, r.length, self.D, r.initial_pose)
        pts, _ = chain_points(r.theta, r.lam, r.length, self.D, seg, frac, r.initial_pose, frames=frames)
        return pts.reshape(M, self.S, 3)

    def data(self, routing: Routing) -> dict:
        """Every block's data for the current design (``routing``, problem units): fractions, t,
        requirements from its segment lengths, and the mesh active sets at its sample points."""
        M, S, k, D = routing.segments, self.S, self.k, self.D
        u = self.fractions(M)
        levels = [1.0] + list(self.ts)
        dl = routing.length / D
        out = {"after_t": np.array(self.ts)} if self.levels else {}
        points = {t: self.sample_points(routing, t) for t in levels} if any(isinstance(o, Mesh) for o in self.obstacles) else {}
        for q, (ob, sc) in enumerate(zip(self.obstacles, self.scaled)):
            need = self.need(ob, dl)
            cols = []
            for t in levels:
                head = np.vstack([u, np.full((1, M), t), need[None, :]])
                if not isinstance(ob, Mesh):
                    cols.append(head)
                    continue
                p = points[t].reshape(-1, 3)
                faces, _ = nearest_triangles(ob, p, k)
                inside = mesh_signed_distance(ob, p) < 0
                tri = sc.triangles  # units of D
                T = tri[faces].reshape(M, S, k * 9)  # per sample: k triangles, a b c each
                nrm, off = _exit_planes(sc, faces, p / D, inside, np.repeat(need, S))
                plane = np.hstack([nrm, off[:, None]]).reshape(M, S * 4)
                a_plane = inside.astype(float).reshape(M, S)
                cols.append(np.vstack([head, T.reshape(M, S * k * 9).T, (1 - a_plane).T, plane.T, a_plane.T]))
            out[f"obstacle_{q}"] = np.hstack(cols)
        return out

    def fill_extra(self, solver, x: np.ndarray, routing: Routing) -> np.ndarray:
        """Set the intermediate chains' frames in x from ``routing`` (problem units)."""
        lay = solver.layout
        for a, t in enumerate(self.ts):
            r = after_growth_routing(routing, t)
            fr = chain_frames(r.theta, r.lam, r.length, self.D, r.initial_pose)
            fr[:, :3, 3] /= self.D
            F = frames12(fr)  # (12, M+1)
            x[lay.extra[:, 12 * a : 12 * a + 12].T] = F[:, :-1]
        return x

    def report(self, routing: Routing, per_segment: int = DEFAULT_PER_SEGMENT) -> dict:
        return obstacle_report(routing, self.D, self.obstacles, self.growth, self.margin, per_segment, self.report_ts)


def _exit_planes(mesh: Mesh, faces, p, inside, need):
    """Per sample, the face plane (unit normal, offset) its plane row uses (``mesh``, ``p``: units of D).

    A run of consecutive samples inside the mesh gets ONE face for the whole run (samples of a run through
    a slab would otherwise pick the faces on both sides and ask the tube to leave both ways): among the
    k nearest faces of the run's samples, the one that asks the least total push sum max(0, need - n.p +
    offset) among those whose push takes every sample of the run outside the mesh (exact sign; on a
    non-convex mesh the front of a face's plane can still be inside), else the least push among faces with
    every sample behind their plane, else each sample keeps its nearest face."""
    tri = mesh.triangles
    planes = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    planes /= np.linalg.norm(planes, axis=1, keepdims=True)
    offsets = np.sum(planes * tri[:, 0], axis=1)
    nrm, off = planes[faces[:, 0]].copy(), offsets[faces[:, 0]].copy()
    m = np.concatenate([[False], inside, [False]]).astype(int)
    starts, ends = np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)
    for i0, i1 in zip(starts, ends):
        run = slice(i0, i1)
        best, best_push, fallback, fallback_push = None, math.inf, None, math.inf
        for q in np.unique(faces[run]):
            h = p[run] @ planes[q] - offsets[q]
            lack = np.maximum(0.0, need[run] - h)
            push = float(np.sum(lack))
            if push >= best_push:
                continue
            moved = p[run] + lack[:, None] * planes[q]
            if np.all(mesh_signed_distance(mesh, moved) > 0):
                best, best_push = q, push
            elif np.all(h < 0) and push < fallback_push:
                fallback, fallback_push = q, push
        q = best if best is not None else fallback
        if q is not None:
            nrm[run], off[run] = planes[q], offsets[q]
    return nrm, off


def obstacle_stats(report: dict) -> dict:
    """The run metrics of a report: min_obstacle_gap (and min_obstacle_gap_after for growth "after")."""
    out = {"min_obstacle_gap": float(report["min_gap"])}
    if report["growth"] == "after":
        out["min_obstacle_gap_after"] = float(report["min_gap_intermediate"])
    return out


def _shortfall(plan: Plan, rep: dict) -> float:
    worst = min(rep["min_gap"], rep["min_gap_intermediate"])
    return max(plan.margin - worst, 0.0) / plan.D


# ------------------------------------------------------------------ design problems


def design_with_obstacles(problem: DesignProblem, start: Result | None = None, rounds: int = ROUNDS, ts=None,
                          k: int = MESH_K, spacing: float = SPACING, **kw) -> Result:
    """Inverse design that keeps the tube ``problem.obstacle_margin`` clear of ``problem.obstacles``.

    Parameters
    ----------
    problem : DesignProblem
        With obstacles, obstacle_margin and growth.
    start : Result, optional
        The obstacle-free design to start from (default design_nlp(problem, **kw)); returned
        (with the obstacle metrics) when it already clears.
    rounds : int
        Most solves of the active-set loop.
    ts : sequence of float, optional
        Growth "after": the shapes t with rows (default the report's grid 0, 1/20, ..., 19/20).
    k : int
        Nearest triangles per mesh sample.
    spacing : float
        Target sample spacing, units of D.

    Returns
    -------
    Result
        method "nlp_obstacles"; metrics min_obstacle_gap (and min_obstacle_gap_after); stats
        obstacle_rounds, obstacle_clear, obstacle_samples_per_segment, obstacle_margin, growth,
        start_rmse, start_min_obstacle_gap, obstacle_raise (the rows' extra requirement, units).
    """
    t_all = time.perf_counter()
    start = start or design_nlp(problem, **kw)
    D = problem.diameter
    plan = Plan(problem.obstacles, D, problem.obstacle_margin, problem.growth, start.routing.length, problem.actuator, ts, k, spacing)
    first = plan.report(start.routing)
    stats0 = {"obstacle_margin": plan.margin, "growth": plan.growth, "start_rmse": float(start.metrics["rmse"]),
              "start_min_obstacle_gap": float(first["min_gap"])}
    if not problem.obstacles or first["clear"]:
        best = dataclasses.replace(start, metrics=dict(start.metrics), stats=dict(start.stats))
        best.metrics.update(obstacle_stats(first))
        best.stats.update(stats0 | {"obstacle_rounds": 0, "obstacle_clear": bool(first["clear"])})
        return best
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    R0g = start.routing.initial_pose[:3, :3].copy()
    params = nlp_parameters(problem, pairing, R0g)
    solver = extended_solver(problem, pairing, (plan.term,), extra=plan.extra)
    lbx, ubx = solver.bounds(*design_bounds(problem, pairing))
    plan.choose_levels(first)
    x = plan.fill_extra(solver, start_x(solver, chain_guess(problem, start.routing), D, "chain"), start.routing)
    routing, best, rep, solves = start.routing, None, first, 0
    if plan.has_mesh:
        rounds = max(rounds, MESH_ROUNDS)
    while solves < rounds:
        p = solver.pack_params(params | plan.data(routing))
        x, status, st = solver.solve(x, p, *plan.trust(solver, x, lbx, ubx))
        solves += 1
        res = result_of(problem, pairing, solver, x, status, st, R0g, METHOD)
        rep = plan.report(res.routing)
        best, routing = res, res.routing
        if rep["clear"] and res.converged:
            break
        if res.converged:  # the rows held, yet the tube dips between samples: ask the samples for more
            plan.raised += RAISE_FACTOR * _shortfall(plan, rep)
        plan.choose_levels(rep)
        x = plan.fill_extra(solver, x, routing)
    best.metrics.update(obstacle_stats(rep))
    best.stats.update(stats0 | {"obstacle_rounds": solves, "obstacle_clear": bool(rep["clear"]),
                                "obstacle_samples_per_segment": plan.S, "obstacle_raise": plan.raised * D,
                                "obstacle_after_t": list(plan.ts)})
    best.solve_time_s = time.perf_counter() - t_all
    return best


# ------------------------------------------------------------------ tip problems


def _tip_solver(problem: TipProblem, plan: Plan):
    o, a = problem.options, problem.actuator
    spec = tip_spec(problem.segments, a.shared_lambda, problem.direction is not None, problem.objective, o.max_iter, o.tol)
    opts = dict(spec.options) | HARD_ROWS
    return get_solver(dataclasses.replace(spec, structure=dataclasses.replace(spec.structure, extra=plan.extra),
                                          terms=spec.terms + (plan.term,), options=options_key(opts)))


def _tip_solve(problem: TipProblem, plan: Plan, solver, routing: Routing, rounds: int):
    """The tip NLP with obstacle rows from ``routing`` (its frames on its chain), the active-set loop."""
    o, a, D, M, L = problem.options, problem.actuator, problem.diameter, problem.segments, problem.length
    T0 = problem.initial_pose
    X0 = frames12(T0[None])[:, 0].copy()
    X0[9:] /= D
    d = problem.direction if problem.direction is not None else np.array([1.0, 0.0, 0.0])
    e1, e2 = _perpendicular_pair(d)
    base = {"cells": np.zeros((5, M)), "smooth": [o.smooth_theta, o.smooth_lambda], "h": np.full(max(M - 1, 1), L / M / D),
            "L": L / D, "tip_position": problem.position / D, "tip_frame": np.column_stack([d, e1, e2]), "tube_length": L / D}
    lbx, ubx = solver.bounds((-a.theta_max, a.theta_max), (a.lambda_min, 1.0), (MIN_LENGTH_FACTOR * L / M / D, L / D), X0=X0)
    fr = chain_frames(routing.theta, routing.lam, routing.length, D, T0)
    fr[:, :3, 3] /= D
    x = plan.fill_extra(solver, solver.pack_x(routing.theta, routing.lam, routing.length / D, frames12(fr)[None]), routing)
    plan.raised, plan.ts = 0.0, []
    plan.choose_levels(plan.report(routing))
    x = plan.fill_extra(solver, x, routing)
    res, rep, solves, iters = None, None, 0, 0
    while solves < rounds:
        p = solver.pack_params(base | plan.data(routing))
        x, status, st = solver.solve(x, p, *plan.trust(solver, x, lbx, ubx))
        solves += 1
        v = solver.unpack(x)
        routing = Routing(v["theta"], v["lam"][:, 0], v["dl"] * D, T0)
        iters += st.pop("iterations")
        res = evaluate_tip(problem, routing, status=status, solve_time_s=st.pop("solve_time_s"), iterations=iters,
                           stats=st | {"objective_kind": problem.objective, "segments": M, "tube_length": L})
        rep = plan.report(routing)
        if rep["clear"] and res.converged:
            break
        if res.converged:  # the rows held, yet the tube dips between samples: ask the samples for more
            plan.raised += RAISE_FACTOR * _shortfall(plan, rep)
        plan.choose_levels(rep)
        x = plan.fill_extra(solver, x, routing)
    res.stats["obstacle_rounds"] = solves
    return res, rep


def design_tip_with_obstacles(problem: TipProblem, starts: int | None = None, rounds: int = ROUNDS, ts=None, k: int = MESH_K,
                              spacing: float = SPACING, progress=None) -> Result:
    """Least-actuation tip design that keeps the tube ``problem.obstacle_margin`` clear of ``problem.obstacles``.

    Parameters
    ----------
    problem : TipProblem
    starts : int, optional
        Starts of the tip design (default options.starts); each is solved with the obstacle rows,
        after the obstacle-free tip design itself.
    rounds, ts, k, spacing
        As :func:`design_with_obstacles`.
    progress : callable, optional
        progress(done, total) after every start.

    Returns
    -------
    Result
        The best converged start that clears (else the best converged, else the lowest tip error);
        metrics as design_tip's plus min_obstacle_gap; stats obstacle_* as design_with_obstacles'.
    """
    t_all = time.perf_counter()
    free = design_tip(problem, starts=starts)
    D = problem.diameter
    plan = Plan(problem.obstacles, D, problem.obstacle_margin, problem.growth, np.full(problem.segments, problem.length / problem.segments),
                problem.actuator, ts, k, spacing)
    first = plan.report(free.routing)
    stats0 = {"obstacle_margin": plan.margin, "growth": plan.growth, "start_min_obstacle_gap": float(first["min_gap"]),
              "start_actuation_contraction": float(free.metrics["actuation_contraction"])}
    if not problem.obstacles or (first["clear"] and free.converged):
        free.metrics.update(obstacle_stats(first))
        free.stats.update(stats0 | {"obstacle_rounds": 0, "obstacle_clear": bool(first["clear"])})
        return free
    solver = _tip_solver(problem, plan)
    n = max(1, problem.options.starts if starts is None else starts)
    guesses = [free.routing] + [Routing(th, lam, dl, problem.initial_pose) for th, lam, dl, _ in start_guesses(problem, n)]
    results = []
    for g in guesses:
        results.append(_tip_solve(problem, plan, solver, g, rounds))
        if progress:
            progress(len(results), len(guesses))
    score = [(0 if (r.converged and rep["clear"]) else 1 if r.converged else 2,
              r.stats["objective"] if r.converged else r.metrics["tip_error"]) for r, rep in results]
    kbest = pick_best(list(range(len(results))), objective=lambda i: score[i][1], converged=lambda i: score[i][0] == 0)
    if score[kbest][0] == 2 and any(s[0] == 1 for s in score):
        kbest = min((i for i in range(len(score)) if score[i][0] == 1), key=lambda i: score[i][1])
    best, rep = results[kbest]
    best.method = "tip"
    best.metrics.update(obstacle_stats(rep))
    best.metrics["reachable"] = float(best.converged)
    best.stats.update(stats0 | {"obstacle_clear": bool(rep["clear"]), "obstacle_samples_per_segment": plan.S,
                                "obstacle_after_t": list(plan.ts), "starts": len(results), "best_start": kbest,
                                "start_status": [r.status for r, _ in results]})
    best.iterations = free.iterations + sum(r.iterations for r, _ in results)
    best.solve_time_s = time.perf_counter() - t_all
    return best
