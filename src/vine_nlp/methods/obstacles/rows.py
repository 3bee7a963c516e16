"""The obstacle rows: per-stage blocks that keep the samples of the tube's center line clear of every obstacle.

The center line must stay at least r = D/2 + margin from every obstacle. Each segment j carries S
samples (``Plan.fractions``), at most h_j = dl_j / S apart along the arc; between samples the distance
drops at most ``dip(h_j)`` (analysis.obstacles, "Sampling rule"), so the rows ask every sample for

    distance(point_i) >= D/2 + margin + dip(h_j)          (units of D in the NLP)

and the continuous tube then clears by the margin. Everything that changes between rounds (the requirement, the active
sets, the obstacles' numbers, t) is data: a solver serves every round with the same slot counts.

Rows are per-stage SX blocks (methods.blocks) over (shape, segment) columns; v = (X_j, theta_j,
lam_j, dl_j), 15 local variables:
  primitives: slots per column, each a primitive as a rounded box (``model.obstacles.rounded_box_distance``,
      the primitives' own formula) whose numbers are data. A column has as many slots as its active set
      (``Plan``), the columns with P slots share one block type (S, P), and a column with none has no
      rows: neither an iteration nor the linear algebra grows with obstacles far from the tube (an off
      row still costs IPOPT a slack).
  meshes: per sample, the plane row, then k rows to its active triangles (exact unsigned distances,
      ``model.obstacles.point_triangle_distance`` with the vertices as data). A row switched off by
      its data weight a = 0 is the constant 1 (always satisfied).
  growth "after": the intermediate shapes with rows are *extra levels* of the multiple shooting, 12
      stage variables per level holding the frames E_j(t) of the intermediate chain, tied by per-stage
      continuity blocks E_{j+1}(t) = E_j(t) T(theta_j, lambda_t,j, dl_j) and E_0(t) = X_0 (single
      shooting from the base would make every row depend on all upstream segments: dense derivatives)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.methods.blocks import BlockType, Samples
from vine_nlp.methods.settings import MESH_K, TRI_EPS
from vine_nlp.methods.transcription import Chain
from vine_nlp.methods.variables import CELL, POINT
from vine_nlp.model.obstacles import point_triangle_distance, rounded_box_distance
from vine_nlp.model.segment import segment_function

PRIM_DATA = 19  # per slot: center (3), R (9, world from local, column-major), half sizes (3), radius, eps, need, a


def primitive_slot(ob) -> np.ndarray:
    """A primitive's first 17 numbers of a slot: its rounded box (model.obstacles), units of the obstacle."""
    c, R, h, r, eps = ob.rounded_box()
    return np.r_[c, R.ravel(order="F"), h, r, eps]


def _lam_t(lam, t):
    return 1 - t * (1 - lam)


def prim_data_size(S: int, P: int) -> int:
    return S + 1 + PRIM_DATA * P


@lru_cache(maxsize=16)
def primitive_block(S: int, P: int) -> BlockType:
    """Rows distance - need >= 0 of S samples of one segment to P primitive slots (units of D).

    v = (X_j (12), theta, lam, dl); d = (u (S), t, then per slot the 17 numbers of :func:`primitive_slot` (the
    primitive as a rounded box), need, a): points of the shape lambda_t = 1 - t (1 - lam); a slot switched
    off (a = 0) gives the constant rows 1. The obstacles are data: one built solver serves every scene with P slots or fewer
    obstacles near a segment."""
    v, d = ca.SX.sym("v", POINT.size), ca.SX.sym("d", prim_data_size(S, P))
    X, th, la, dl = POINT.split(v)
    _, pts = segment_function(S)(X, th, _lam_t(la, d[S]), dl, d[:S])
    rows = []
    for q in range(P):
        sl = d[S + 1 + PRIM_DATA * q : S + 1 + PRIM_DATA * (q + 1)]
        need, a = sl[17], sl[18]
        dist = rounded_box_distance(pts, sl[0:3], ca.reshape(sl[3:12], 3, 3), sl[12:15], sl[15], sl[16])
        rows.append(a * (dist.T - need) + (1 - a))
    # as a map of one sample's block: sample i reads u_i, t and the slots; rows are slot-major
    index = [[i, *range(S, prim_data_size(S, P))] for i in range(S)]
    samples = Samples(primitive_block(1, P), tuple(zip(*index)), tuple(i * P + q for q in range(P) for i in range(S))) if S > 1 else None
    return BlockType(f"obstacle_prims{S}x{P}", ca.Function("obstacle_block", [v, d], [ca.SX(0), ca.vertcat(*rows)]), samples=samples)


def mesh_data_size(S: int, k: int) -> int:
    return S + 2 + 9 * k * S + S + 4 * S + S


@lru_cache(maxsize=16)
def mesh_block(S: int, k: int) -> BlockType:
    """Rows of S samples of one segment to a mesh's active set (module docstring), S (k + 1) rows.

    d = (u (S), t, need, triangles (9 k per sample: a, b, c of each), a_tri (S), plane (4 per
    sample: unit normal, offset), a_plane (S)); per sample: the plane row, then k triangle rows."""
    v, d = ca.SX.sym("v", POINT.size), ca.SX.sym("d", mesh_data_size(S, k))
    X, th, la, dl = POINT.split(v)
    _, pts = segment_function(S)(X, th, _lam_t(la, d[S]), dl, d[:S])
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
            dist = point_triangle_distance(p, t9[0:3], t9[3:6], t9[6:9], TRI_EPS)
            rows.append(a_tri[i] * (dist - need) + (1 - a_tri[i]))
    # as a map of one sample's block: u_i, t, need, then the sample's own triangles, switches and plane
    o, o2 = S + 2, S + 2 + 9 * k * S
    index = [[i, S, S + 1, *range(o + 9 * k * i, o + 9 * k * (i + 1)), o2 + i, *range(o2 + S + 4 * i, o2 + S + 4 * i + 4), o2 + 5 * S + i]
             for i in range(S)]
    samples = Samples(mesh_block(1, k), tuple(zip(*index)), tuple(range(S * (k + 1)))) if S > 1 else None
    return BlockType(f"obstacle_mesh{S}x{k}", ca.Function("obstacle_mesh_block", [v, d], [ca.SX(0), ca.vertcat(*rows)]), samples=samples)


@lru_cache(maxsize=1)
def after_block() -> BlockType:
    """Continuity of an intermediate chain: v = (E_j (12), theta, lam, dl, E_{j+1} (12)); d = t."""
    v, d = ca.SX.sym("v", CELL.size), ca.SX.sym("d", 1)
    X, th, la, dl, _ = CELL.split(v)
    Xn, _ = segment_function(1)(X, th, _lam_t(la, d[0]), dl, ca.SX(0))
    return BlockType("after_growth", ca.Function("after_block", [v, d], [ca.SX(0), Xn - v[CELL["next"]]]))


@dataclass(frozen=True)
class ObstacleRows:
    """Obstacle rows on the chain (module docstring). ``slots``: primitive slots of every (shape, segment) column (0: no
    rows), shape-major (the final shape, then the levels); ``meshes``: per mesh obstacle, the columns with its rows
    (their triangles are data); ``S`` samples per segment; ``levels``: intermediate shapes of actuation after growth,
    each an extra level of 12 stage variables (Structure.extra = 12 levels), their t the parameter ``after_t``; ``k``
    triangles per mesh sample. Parameters: ``obstacle_prims_<P>`` (one column per (shape, segment) column with P slots)
    and ``obstacle_mesh_<q>`` (one per column of mesh q), the data of the blocks."""

    slots: tuple  # primitive slots of every (shape, segment) column, shape-major
    meshes: tuple  # per mesh obstacle, the columns with its rows (the others are far from it)
    S: int
    levels: int = 0
    k: int = MESH_K
    # an active set: the structure runs interpreted, its small block types compiled on their own; an obstacle
    # block of S samples is too large to compile, so it runs as a map of its one-sample block (Samples)
    compile: ClassVar[bool | str] = "blocks"

    def apply(self, c: Chain) -> None:
        s, lay = c.s, c.lay
        M, x = s.M, c.x
        if self.levels:
            ts = c.param("after_t", (1, self.levels))
        for a in range(self.levels):
            E = lay.extra[:, 12 * a : 12 * a + 12]
            c.add_rows(f"after_base_{a}", x[lay.X[0, 0].tolist()] - x[E[0].tolist()], 0.0, 0.0)
            if M > 1:
                idx = np.array([np.r_[E[j], lay.routing_at(j), E[j + 1]] for j in range(M - 1)]).T
                c.add_block(after_block(), idx, ca.repmat(ts[0, a], 1, M - 1))
        cols = []
        for a in range(self.levels + 1):
            for j in range(M):
                frame = lay.X[j, 0] if a == 0 else lay.extra[j, 12 * (a - 1) : 12 * a]
                cols.append(np.r_[frame, lay.routing_at(j)])
        idx = np.array(cols).T
        slots = np.asarray(self.slots, int)
        for P in sorted(set(self.slots) - {0}):
            # columns with P slots share one block type: no row for a primitive far from a segment
            cols_P = np.flatnonzero(slots == P)
            data = c.param(f"obstacle_prims_{P}", (prim_data_size(self.S, P), cols_P.size))
            c.add_block(primitive_block(self.S, P), idx[:, cols_P], data, lb=0.0, ub=np.inf, term="obstacles")
        for q, cols_q in enumerate(self.meshes):
            if not cols_q:
                continue
            data = c.param(f"obstacle_mesh_{q}", (mesh_data_size(self.S, self.k), len(cols_q)))
            c.add_block(mesh_block(self.S, self.k), idx[:, list(cols_q)], data, lb=0.0, ub=np.inf, term="obstacles")
