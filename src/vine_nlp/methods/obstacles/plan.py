"""What the obstacle rows need, round by round: samples, requirements, active sets, the shapes with rows.

Samples. S per segment, from the longest segment (``settings.SAMPLE_SPACING``, ``settings.LENGTH_SLACK``, ``settings.MAX_SAMPLES``); each
sample's requirement is D/2 + margin + dip(h_j) + the loop's raise (``Plan.need``), from the current
segment lengths times settings.LENGTH_SLACK (dl moves during a solve).

Active sets, refreshed between solves (``Plan.data``; data only: a solver serves every round with the
same slot counts):
  primitives: a column's primitives whose slack (distance - need) at its samples is below settings.ACTIVE_REACH
      + settings.REACH_DL dl_j, nearest first; a column never has fewer slots than it had (the solver stays
      within a design), and a primitive the tube reaches in a solve is caught by the report and gets
      rows in the next round.
  meshes: the ``k`` nearest triangles of every sample (exact, nearest_triangles), on the columns whose
      slack is below settings.MESH_REACH + settings.REACH_DL dl_j. A sample the exact (trimesh) sign finds *inside* the
      mesh gets one linear row instead, the signed distance to the plane of a face (``_exit_planes``:
      one face for a run of samples inside), pushing it out through that face; its triangle rows would
      push it deeper. An outside sample closer than its requirement plus settings.TANGENT_REACH keeps its
      triangle rows and gets the tangent plane at its nearest point too (a half-space the few triangles
      of a fine mesh's active set do not make: the tube slipped past them). Every frame moves at most
      settings.MESH_TRUST per solve (``Plan.trust``): a tube that moved farther could pass triangles no row sees.

Growth "after": the report's grid t = 0, 1/20, ..., 19/20 must clear too; settings.AFTER_SLOTS of its shapes
carry rows at a time (``Plan.choose_levels``): first the worst of the start, then, round by round, a
shape that does not clear replaces the one with rows that clears by the most (t is data).

After a round that does not clear (``Plan.next_round``): where every sample held what its rows asked against the exact
obstacle (``Plan.samples_hold``) the tube dips between samples, and the requirement rises by settings.RAISE_FACTOR times
what the shapes with rows still miss; where a sample did not hold it passed a mesh beside its active set (a fine mesh),
and from then on every sample also has rows to its k nearest faces among those near the samples at every such miss
(``Plan.remember``; raising there sent the tube far round)."""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.analysis.obstacles import (
    DEFAULT_AFTER_STEPS,
    DEFAULT_PER_SEGMENT,
    after_growth_routing,
    curvature_bound,
    dip,
    obstacle_report,
)
from vine_nlp.methods import settings
from vine_nlp.methods.obstacles.rows import MESH_K, PRIM_DATA, ObstacleRows, prim_data_size, primitive_slot
from vine_nlp.methods.structure import frames12
from vine_nlp.model.chain import chain_frames, chain_points
from vine_nlp.model.obstacles import Mesh, mesh_signed_distance, nearest_triangles, point_triangle_distance, sharpness_radius
from vine_nlp.problem import Routing


class Plan:
    """What the rows of one problem need: samples per segment, shapes (t), the data of every block."""

    def __init__(self, obstacles, D, margin, growth, lengths, actuator, spacing=settings.SAMPLE_SPACING):
        self.obstacles, self.D, self.margin, self.growth = tuple(obstacles), float(D), float(margin), growth
        if growth == "after":
            self.grid = [float(t) for t in np.linspace(0.0, 1.0, DEFAULT_AFTER_STEPS + 1) if t < 1.0]
            self.report_ts = sorted(set(self.grid) | {1.0})
        else:
            self.grid, self.report_ts = [], None
        self.levels = min(settings.AFTER_SLOTS, len(self.grid))
        self.k = int(min([MESH_K] + [len(o.faces) for o in obstacles if isinstance(o, Mesh)]))
        longest = float(np.max(lengths)) / D
        self.S = int(min(settings.MAX_SAMPLES, max(2, math.ceil(settings.LENGTH_SLACK * longest / spacing))))
        self.kappa = curvature_bound(1.0, actuator.theta_max, actuator.lambda_min)
        self.scaled = tuple(o.scaled(1.0 / D) for o in self.obstacles)
        self.prims = [q for q, o in enumerate(self.obstacles) if not isinstance(o, Mesh)]
        self.meshes = [q for q, o in enumerate(self.obstacles) if isinstance(o, Mesh)]
        self.slots = np.array([primitive_slot(self.scaled[q]) for q in self.prims]).reshape(len(self.prims), 17)
        self.reset_rounds()

    def reset_rounds(self) -> None:
        """Forget what a loop of rounds learned (every start of a tip design begins anew)."""
        self.ts = []  # the intermediate shapes with rows (choose_levels)
        self.mesh_cols = [() for _ in self.meshes]  # per mesh, the columns near it (grow, never shrink)
        self.col_slots = None  # primitive slots per (shape, segment) column: grow (never shrink) with the active sets
        self.raised = 0.0  # units of D: added to every requirement by the loop
        # meshes: after a sample passed its active set (``samples_hold``), every sample gets k more rows,
        # its nearest faces among those nearest to the samples at every such miss (``remember``): the
        # tube cannot dive again where it dived once (on the torus scene it went in and out 6 times)
        self.k_mem = 0
        self.memory = {}  # (mesh, t) -> the faces of the misses so far
        self._remember = False

    def next_round(self, converged: bool, routing: Routing, rep: dict) -> None:
        """After a solve whose tube does not clear (``rep``: its report): where every sample held, the tube
        dips between samples and the requirement is raised; where one did not, it passed a mesh beside
        its active set and the faces there get rows from now on; then the shapes with rows are chosen."""
        if converged and self.samples_hold(routing):
            self.raised += settings.RAISE_FACTOR * _shortfall(self, rep)
        elif converged:
            self.remember()
        self.choose_levels(rep)

    def remember(self) -> None:
        """The next ``data`` keeps its mesh active sets as the memory (the samples passed a mesh)."""
        if self.meshes:
            self._remember, self.k_mem = True, self.k

    @property
    def term(self) -> ObstacleRows:
        return ObstacleRows(tuple(int(v) for v in self.col_slots) if self.col_slots is not None else (),
                            tuple(tuple(int(c) for c in cols) for cols in self.mesh_cols), self.S,
                            self.levels, self.k + self.k_mem)

    @property
    def P(self) -> int:
        """Most primitive slots of a column."""
        return int(max(self.col_slots, default=0)) if self.col_slots is not None else 0

    @property
    def has_mesh(self) -> bool:
        return any(isinstance(o, Mesh) for o in self.obstacles)

    def trust(self, solver, x, lbx, ubx):
        """Bounds of one solve: with a mesh, every frame position within settings.MESH_TRUST of where it is (the
        active sets are the nearest triangles of the current samples: a tube that moved farther could
        pass through triangles no row sees)."""
        if not self.has_mesh:
            return lbx, ubx
        lbx, ubx = lbx.copy(), ubx.copy()
        idx = solver.layout.X[:, :, 9:].ravel()
        lbx[idx] = np.maximum(lbx[idx], x[idx] - settings.MESH_TRUST)
        ubx[idx] = np.minimum(ubx[idx], x[idx] + settings.MESH_TRUST)
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
        gap = {t: g for t, g in _intermediate_gaps(rep).items() if t in self.grid}
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
        h = settings.LENGTH_SLACK * dl / gaps
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
        requirements from its segment lengths, the primitives near every segment (``settings.ACTIVE_REACH``)
        and the mesh active sets at its sample points. May raise ``P`` (then ``term`` changes)."""
        M, D = routing.segments, self.D
        u = self.fractions(M)
        levels = [1.0] + list(self.ts)
        dl = routing.length / D
        out = {"after_t": np.array(self.ts)} if self.levels else {}
        points = {t: self.sample_points(routing, t) for t in levels}
        needs = {q: self.need(self.obstacles[q], dl) for q in range(len(self.obstacles))}
        self.needs = needs  # what the rows ask (samples_hold)
        if self.prims:
            out |= self._prim_data(points, levels, needs, u, dl)
        for m, q in enumerate(self.meshes):
            out[f"obstacle_mesh_{m}"] = self._mesh_data(m, q, points, levels, needs[q], u, dl)
        self._remember = False
        return out

    def _mesh_data(self, m: int, q: int, points, levels, need, u, dl) -> np.ndarray:
        """Mesh q's block data (its m-th): per column near it (slack below settings.MESH_REACH + settings.REACH_DL dl_j: the tube
        can reach the mesh within one solve), per sample its triangles, the plane row of a sample inside (or
        closer than its requirement plus settings.TANGENT_REACH: the tangent plane) and the switches."""
        ob, sc, M, S, k, D = self.obstacles[q], self.scaled[q], dl.size, self.S, self.k, self.D
        cols, near = [], []
        for t in levels:
            head = np.vstack([u, np.full((1, M), t), need[None, :]])
            p = points[t].reshape(-1, 3)
            faces, dist = nearest_triangles(ob, p, k)
            inside = mesh_signed_distance(ob, p) < 0
            if self._remember:
                self.memory[m, t] = np.union1d(self.memory.get((m, t), []), faces).astype(np.int64)
            rows = _with_memory(ob, p, faces, self.memory.get((m, t)), nearest_triangles(ob, p, 2 * k)[0]) if self.k_mem else faces
            kr = rows.shape[1]
            slack = (np.where(inside, -dist[:, 0], dist[:, 0]) / D).reshape(M, S).min(axis=1) - need
            near.append(slack < settings.MESH_REACH + settings.REACH_DL * dl)
            T = sc.triangles[rows].reshape(M, S, kr * 9)  # per sample: kr triangles, a b c each (units of D)
            nrm, off = _exit_planes(sc, faces, p / D, inside, np.repeat(need, S))
            close = ~inside & (dist[:, 0] / D < np.repeat(need, S) + settings.TANGENT_REACH)
            if close.any():
                c, _, _ = ob.trimesh.nearest.on_surface(p[close])
                n = (p[close] - c) / np.maximum(np.linalg.norm(p[close] - c, axis=1, keepdims=True), 1e-300)
                nrm[close], off[close] = n, np.sum(n * c / D, axis=1)
            a_tri, a_plane = (~inside).astype(float).reshape(M, S), (inside | close).astype(float).reshape(M, S)
            plane = np.hstack([nrm, off[:, None]]).reshape(M, S * 4)
            cols.append(np.vstack([head, T.reshape(M, S * kr * 9).T, a_tri.T, plane.T, a_plane.T]))
        chosen = sorted(set(self.mesh_cols[m]) | set(np.flatnonzero(np.concatenate(near)).tolist()))
        self.mesh_cols[m] = tuple(chosen)
        return np.hstack(cols)[:, chosen]

    def _prim_data(self, points, levels, needs, u, dl) -> dict:
        """The primitive slots of every (shape, segment) column: the primitives within settings.ACTIVE_REACH + settings.REACH_DL dl_j
        of the segment's samples (beyond their requirement), nearest first. A column keeps at least the
        slots it had (the solver stays), filled with the next nearest primitives; a column with none has
        no rows. Returns the data of each group of columns with P slots (``obstacle_prims_<P>``)."""
        M, S, D = dl.size, self.S, self.D
        need = np.array([needs[q] for q in self.prims])  # (Q, M)
        order, counts = [], []
        for t in levels:
            p = points[t].reshape(-1, 3)
            dist = np.array([np.asarray(self.obstacles[q].distance(p), float).reshape(M, S).min(axis=1) for q in self.prims]) / D
            slack = dist - need  # (Q, M)
            near = slack < settings.ACTIVE_REACH + settings.REACH_DL * dl[None, :]
            order += [np.argsort(slack[:, j], kind="stable") for j in range(M)]
            counts += [int(near[:, j].sum()) for j in range(M)]
        counts = np.array(counts)
        if self.col_slots is not None and len(self.col_slots) == counts.size:
            counts = np.maximum(counts, self.col_slots)
        self.col_slots = counts
        out = {}
        for P in sorted(set(counts.tolist()) - {0}):
            cols = np.flatnonzero(counts == P)
            data = np.zeros((prim_data_size(S, P), cols.size))
            for m, col in enumerate(cols):
                a, j = divmod(int(col), M)
                data[:S, m], data[S, m] = u[:, j], levels[a]
                for slot in range(P):
                    o = S + 1 + PRIM_DATA * slot
                    i = order[col][slot]
                    data[o : o + 17, m] = self.slots[i]
                    data[o + 17, m], data[o + 18, m] = need[i, j], 1.0
            out[f"obstacle_prims_{P}"] = data
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

    def samples_hold(self, routing: Routing, tol: float = 1e-4) -> bool:
        """Whether every sample of the rows clears the requirement its rows asked (the last ``data``) against the exact
        obstacle (units of D, within ``tol``). A converged solve whose report still finds the tube too close then dips
        between samples (raise the requirement); a sample that does not hold passed a mesh where its active set had no
        triangle, or a primitive its column had no slot for (the next ``data`` adds it; raising would only push the tube
        farther than needed). Not the requirement of the new segment lengths: their growth in the solve raises it,
        samples that held their rows' seemed not to, and a design short by its dips was never raised (CHANGELOG)."""
        for t in [1.0] + list(self.ts):
            p = self.sample_points(routing, t).reshape(-1, 3)
            for q, ob in enumerate(self.obstacles):
                d = np.asarray(ob.distance(p), float).reshape(-1, self.S) / self.D
                if np.any(d < (self.needs[q] - tol)[:, None]):
                    return False
        return True

    def report(self, routing: Routing, per_segment: int = DEFAULT_PER_SEGMENT) -> dict:
        return obstacle_report(routing, self.D, self.obstacles, self.growth, self.margin, per_segment, self.report_ts)


def _with_memory(mesh: Mesh, p, faces: np.ndarray, memory, more: np.ndarray) -> np.ndarray:
    """Per sample (``p``), its k nearest ``faces``, then its nearest faces of ``memory`` that are not among
    them (then the next nearest of ``more``): 2 k distinct faces, no duplicate row."""
    k = faces.shape[1]
    if memory is not None and len(memory):
        tri = mesh.triangles[memory]
        d = point_triangle_distance(p[:, None, :], tri[None, :, 0], tri[None, :, 1], tri[None, :, 2])
        mem = memory[np.argsort(d, axis=1, kind="stable")[:, : 2 * k]]
    else:
        mem = np.zeros((len(p), 0), np.int64)
    out = np.empty((len(faces), 2 * k), np.int64)
    for i in range(len(faces)):
        row = list(faces[i])
        for f in list(mem[i]) + list(more[i]):
            if len(row) == 2 * k:
                break
            if f not in row:
                row.append(f)
        while len(row) < 2 * k:  # a mesh with fewer than 2 k faces: repeat the nearest (the same row twice)
            row.append(row[0])
        out[i] = row
    return out


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


def _shortfall(plan: Plan, rep: dict) -> float:
    """What the shapes with rows (the final one, the intermediate ones at ``plan.ts``) miss of the margin, units of D:
    their dips between samples. An intermediate shape without rows that misses gets rows (``choose_levels``); raising
    every requirement by its miss pushed a growth "after" scene's tube ever farther out (CHANGELOG)."""
    worst = rep["min_gap"]
    if plan.ts:
        worst = min([worst] + [g for t, g in _intermediate_gaps(rep).items() if t in plan.ts])
    return max(plan.margin - worst, 0.0) / plan.D


def _intermediate_gaps(rep: dict) -> dict:
    """t -> the smallest gap of the intermediate shape at t, from a growth "after" report."""
    inter = rep["intermediate"]
    return {float(t): float(g) for t, g in zip(inter["t"], inter["gaps"].min(axis=1))}
