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

Blocks. Rows are per-stage SX blocks (design.transcription) over (shape, segment) instances;
v = (X_j, theta_j, lam_j, dl_j), 15 local variables:
  primitives (sphere, box, capsule, plane): slots per (shape, segment) column, each a primitive
      written as a rounded box (``rounded_box``: its exact smooth distance, analysis.obstacles) whose
      numbers are data; the active set of a column is the primitives whose slack (distance - need)
      at its samples is below ACTIVE_REACH + REACH_DL dl_j, refreshed between solves like a mesh's (a
      primitive the tube reaches in a solve is caught by the report and gets rows in the next round).
      A column has as many slots as its active set (never fewer than it had: the solver stays within
      a design), the columns with P slots share one block type (S, P), and a column with none has no
      rows: neither an iteration nor the linear algebra grows with obstacles far from the tube, nor
      with the busiest segment's count. (P slots on every column, most switched off, made the
      20-primitive speed scene's rows 2080 instead of ~550; an off row still costs IPOPT a slack.)
      The interpreted build of a solver is cheap (the rows are not compiled), so a new slot count
      costs little.
  meshes: the active set, ``k`` nearest triangles of every sample (exact, nearest_triangles),
      refreshed between solves; the triangles are data, so a refresh changes data only, never
      the solver; only the columns with slack below MESH_REACH + REACH_DL dl_j carry a mesh block
      (MESH_REACH). Rows: unsigned point-triangle distances (exact rows: a mesh's unsigned
      distance is the minimum over its triangles, and a triangle is convex, so each row is
      C^1 where it is positive). A sample the exact (trimesh) sign finds *inside* the mesh
      instead gets one linear row, the signed distance to the plane of its nearest face,
      pushing it out through that face, and no triangle rows (they would push it deeper, away
      from the surface); the next refresh gives it triangle rows again. An outside sample closer
      than its requirement plus TANGENT_REACH keeps its triangle rows and gets the plane row too, with
      the tangent plane at its nearest point (a half-space the few triangles of a fine mesh's active
      set do not make: the tube slipped past them). A row switched off by its data weight a = 0 is
      the constant 1 (always satisfied).

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

Weights. A target point closer than the margin to an obstacle is *blocked*: no design sits on it.
Its fit weight is scaled, so the detour is shaped more by the points the tube can follow:
``BLOCKED_WEIGHT`` for primitives, ``MESH_BLOCKED_WEIGHT`` where the scene has a mesh. The price is a
wider detour where the target is blocked; heavier blocked points pulled the tube's error into the
target away from the obstacles, lighter ones (with a mesh) sent it round the far side. With a mesh the
weight does not step back to 1 at the margin but rises over MESH_WEIGHT_RAMP (quadratically): points
just outside the margin that the tube cannot follow past its detour pulled the neighbouring segments
into a zig-zag (a bending angle at its bound) that spread the error 5 segments either way. The values
were chosen on the bundled problems and the speed scenes (results/BENCHMARKS.md, "Obstacles").

Start. A design through an obstacle is a poor start for the rows: IPOPT spends most of its iterations
pushing the tube out. The target is pushed out of the obstacles across itself (``pushed_target``): past
a primitive along the distance gradient, a run of points through one obstacle to one side; through a
mesh, a run along ONE direction across its chord, of PUSH_DIRECTIONS the one with the least total push
(sphere tracing on the exact signed distance: the shortest way round; a gradient push sent the tube
round the long way). The plain NLP designs that from its own geometric guess (one solve), and the rows
start from its chain. Without a mesh, where that chain still does not clear (it cannot follow the pushed
target's corners, and a start inside an obstacle costs the first solve many iterations at a large barrier
parameter regaining feasibility), its own points are pushed out the same way and designed once more
(``REPUSH``): a curve the model can follow, pushed. A second pass, pushing only the chain's points near an
obstacle, and per-solve frame bounds like MESH_TRUST did worse over several random primitive scenes.
The rows start from that chain: the rows' start is a function of the problem alone, and so is the
design (the obstacle-free design only decides whether there is anything to do, the samples per segment and which
primitives get slots: discrete choices that a tiny change of it leaves alone; tests check it). Started
from the obstacle-free design instead, which may cross a mesh deeper than a solve moves a frame
(MESH_TRUST), the first solve's rows contradicted each other (the samples inside asked out through one
face while the samples before the block were held on the other), IPOPT stopped wherever it happened to,
and the rounds after it took routes that changed with a change of 1e-8 in the start.

Loop. Start from the obstacle-free design (design_nlp), keep it when it already clears;
otherwise solve with the rows (warm, from the pushed start's chain), check with the report
(analysis.obstacles.obstacle_report: 20 points per segment, exact mesh distances, refined
minima), refresh the mesh active sets, re-solve warm; until the report is clear or ``rounds`` solves
are done. A re-solve before the last round stops after ROUND_MAX_ITER iterations and the next round
goes on from where it stopped, with fresh active sets: after new primitive slots, a warm re-solve could
crawl to IPOPT's max_iter where the next round, from an iterate ROUND_MAX_ITER in, converged quickly to
the same gap (CHANGELOG). The first solve is not cut: from the pushed start it may legitimately need
more, and cut it turned into rounds of restarts ending at max_iter. The rows' length bounds make room
for a segment the pushed start's detour lengthened past its bound. The rows' requirement is raised by
1.5x what is still missing only where every sample held its requirement against the exact obstacle (``Plan.samples_hold``): then the tube dips between samples.
A sample that did not hold passed a mesh where its active set had no triangle (a fine mesh: the torus
scene's 6 nearest triangles span a fraction of D): from then on every sample also has rows to its k
nearest faces among those near the samples at every such miss (``Plan.remember``). Raising there (as
before) asked every sample for 2 D more after such a miss and sent the tube far round.

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
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.analysis.obstacles import (
    DEFAULT_AFTER_STEPS,
    DEFAULT_PER_SEGMENT,
    after_growth_routing,
    curvature_bound,
    dip,
    min_gap,
    obstacle_report,
    sample_chain,
)
from vine_nlp.methods import drive
from vine_nlp.methods.blocks import BlockType, Samples
from vine_nlp.methods.common import pair_points
from vine_nlp.methods.nlp import chain_guess, design_bounds, design_nlp, extended_solver, nlp_parameters, result_of, solve_from, start_x
from vine_nlp.methods.structure import frames12
from vine_nlp.methods.tip import (
    MIN_LENGTH_FACTOR,
    _perpendicular_pair,
    design_tip,
    evaluate_tip,
    start_guesses,
    tip_spec,
)
from vine_nlp.methods.transcription import Chain, get_solver
from vine_nlp.model.chain import chain_frames, chain_points
from vine_nlp.model.obstacles import (
    EPS_REL,
    Box,
    Capsule,
    Mesh,
    Plane,
    Sphere,
    mesh_signed_distance,
    nearest_triangles,
    point_triangle_distance,
    sharpness_radius,
)
from vine_nlp.model.segment import segment_function
from vine_nlp.problem import DesignOptions, DesignProblem, Result, Routing, TipProblem

RUN = "nlp"  # the obstacle design is the problem's design (archived as run "nlp"); the obstacle-free start: FREE_RUN
FREE_RUN = "nlp_free"
METHOD = "nlp_obstacles"
SPACING = 0.25  # target sample spacing h0, units of D: dip(D/4) ~ 0.03 D for a sharp obstacle
LENGTH_SLACK = 1.25  # segment lengths may grow this much during a solve before the rows' dip is too small
MAX_SAMPLES = 40  # samples per segment
AFTER_SLOTS = 5  # growth "after": intermediate shapes with rows at a time (their t are data, chosen from the report)
MESH_K = 6  # nearest triangles per sample
BLOCKED_WEIGHT = 0.1  # weight of the target points closer than the margin to an obstacle (their fit cannot be exact)
MESH_BLOCKED_WEIGHT = 0.01  # the same where the scene has a mesh (module docstring, "Weights")
MESH_WEIGHT_RAMP = 1.0  # units of D: with a mesh, weights rise from MESH_BLOCKED_WEIGHT at the margin to 1 at margin + this
ACTIVE_REACH = 1.0  # units of D: a primitive gets rows on a segment when its slack is below this plus REACH_DL times the segment's length
REACH_DL = 0.5
ROUNDS = 6
TIP_MAX_ITER = 1200  # IPOPT iterations of a tip solve with rows; a start that needs more is left for the next
ROUND_MAX_ITER = 400  # IPOPT iterations of a solve with rows before the last round (module docstring, "Loop")
MESH_ROUNDS = 12  # meshes: each round moves the tube at most MESH_TRUST, the active sets follow
MESH_TRUST = 1.5  # units of D: a frame moves at most this far per solve with a mesh (its nearest triangles stay valid)
# units of D: a column carries a mesh's rows when its slack is below this plus REACH_DL dl_j. Far fewer
# rows than every column, with the same end on obstacle-mesh; a reach as short as the primitives' sent
# obstacle-mesh round a far wider detour (the study: results/BENCHMARKS.md, "Obstacles")
MESH_REACH = 8.0
# units of D: an outside sample closer than its requirement plus this also gets its plane row, the tangent
# plane at its nearest point on the mesh (a half-space: the tube cannot slip past the few triangles of its
# active set, as it did between the 6 nearest of the torus scene's 10 000, diving 1.2 D deep and out again
# for 4 to 8 rounds); on obstacle-mesh and the torus scene one round instead of 3 and 4
TANGENT_REACH = 0.5
RAISE_FACTOR = 1.5  # the rows' requirement grows by this times the remaining shortfall
PUSHED_START = True  # start from the plain design of the target pushed out of the obstacles (pushed_target)
PUSH_EXTRA = 0.25  # units of D: the pushed target clears by this much more than the rows ask
MESH_PUSH_EXTRA = 0.05  # the same where the scene has a mesh (module docstring, "Weights")
PUSH_PASSES = 8
REPUSH = 1  # primitives: times the designed chain of the pushed target is pushed and designed again where it does not clear
PUSH_DIRECTIONS = 16  # meshes: directions tried around a run's chord
PUSH_PROBES = 9  # meshes: points of a run that choose its direction
MARCH_STEPS = 80
TRI_EPS = 1e-9  # sqrt(d2 + eps^2) (units of D): finite gradients at distance 0


# ------------------------------------------------------------------ block types


def _lam_t(lam, t):
    return 1 - t * (1 - lam)


PRIM_DATA = 19  # per slot: center (3), R (9, world from local, column-major), half sizes (3), radius, eps, need, a
PLANE_HALF = 1e6  # units of D: a plane is a box this deep and wide (its distance exact within ~1e-10 D)


def rounded_box(ob) -> np.ndarray:
    """One primitive (units of D) as a rounded box: distance = |max(|R^T (p - c)| - h, 0)| + min(max(...), 0) - radius.

    A sphere is a point (h = 0) rounded by its radius, a capsule a segment (h = (L/2, 0, 0) along its axis),
    a box itself (radius 0), a plane a box PLANE_HALF deep behind it and PLANE_HALF wide; each is then
    the exact distance of analysis.obstacles (same eps). Returns the slot's first 17 numbers."""
    if isinstance(ob, Sphere):
        c, R, h, r, eps = np.array(ob.center), np.eye(3), np.zeros(3), ob.radius, EPS_REL * ob.radius
    elif isinstance(ob, Capsule):
        a, b = np.array(ob.p0), np.array(ob.p1)
        L = float(np.linalg.norm(b - a))
        ex = (b - a) / L
        ey = np.cross(ex, [1.0, 0.0, 0.0] if abs(ex[0]) < 0.9 else [0.0, 1.0, 0.0])
        ey /= np.linalg.norm(ey)
        c, R, h, r = 0.5 * (a + b), np.column_stack([ex, ey, np.cross(ex, ey)]), np.array([0.5 * L, 0, 0]), ob.radius
        eps = EPS_REL * max(ob.radius, L)
    elif isinstance(ob, Box):
        c, R, h, r = np.array(ob.center), np.array(ob.rotation), 0.5 * np.array(ob.size), 0.0
        eps = EPS_REL * float(np.linalg.norm(ob.size))
    elif isinstance(ob, Plane):
        n = np.array(ob.normal)
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        c, R, h, r = np.array(ob.point) - PLANE_HALF * n, np.column_stack([n, e1, np.cross(n, e1)]), np.full(3, PLANE_HALF), 0.0
        eps = EPS_REL
    else:
        raise TypeError(f"not a primitive: {ob!r}")
    return np.r_[c, R.ravel(order="F"), h, r, eps]


def rounded_box_sx(p, q):
    """The rounded-box distance of points p (3 x S, SX) to the slot q (17 numbers of :func:`rounded_box`)."""
    c, R, h, r, eps = q[0:3], ca.reshape(q[3:12], 3, 3), q[12:15], q[15], q[16]
    w = p - ca.repmat(c, 1, p.shape[1])
    qv = ca.fabs(ca.mtimes(R.T, w)) - ca.repmat(h, 1, p.shape[1])
    o = ca.fmax(qv, 0)
    outside = ca.sqrt(ca.sum1(o * o) + eps * eps)
    inside = ca.fmin(ca.fmax(qv[0, :], ca.fmax(qv[1, :], qv[2, :])), 0)
    return outside + inside - r


def prim_data_size(S: int, P: int) -> int:
    return S + 1 + PRIM_DATA * P


@lru_cache(maxsize=16)
def primitive_block(S: int, P: int) -> BlockType:
    """Rows distance - need >= 0 of S samples of one segment to P primitive slots (units of D).

    v = (X_j (12), theta, lam, dl); d = (u (S), t, then per slot the 17 numbers of :func:`rounded_box`,
    need, a): points of the shape lambda_t = 1 - t (1 - lam); a slot switched off (a = 0) gives the
    constant rows 1. The obstacles are data: one built solver serves every scene with P slots or fewer
    obstacles near a segment."""
    v, d = ca.SX.sym("v", 15), ca.SX.sym("d", prim_data_size(S, P))
    _, pts = segment_function(S)(v[:12], v[12], _lam_t(v[13], d[S]), v[14], d[:S])
    rows = []
    for q in range(P):
        sl = d[S + 1 + PRIM_DATA * q : S + 1 + PRIM_DATA * (q + 1)]
        need, a = sl[17], sl[18]
        rows.append(a * (rounded_box_sx(pts, sl[:17]).T - need) + (1 - a))
    # as a map of one sample's block: sample i reads u_i, t and the slots; rows are slot-major
    index = [[i, *range(S, prim_data_size(S, P))] for i in range(S)]
    samples = Samples(primitive_block(1, P), tuple(zip(*index)), tuple(i * P + q for q in range(P) for i in range(S))) if S > 1 else None
    return BlockType(f"obstacle_prims{S}x{P}", ca.Function("obstacle_block", [v, d], [ca.SX(0), ca.vertcat(*rows)]), samples=samples)


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
    # as a map of one sample's block: u_i, t, need, then the sample's own triangles, switches and plane
    o, o2 = S + 2, S + 2 + 9 * k * S
    index = [[i, S, S + 1, *range(o + 9 * k * i, o + 9 * k * (i + 1)), o2 + i, *range(o2 + S + 4 * i, o2 + S + 4 * i + 4), o2 + 5 * S + i]
             for i in range(S)]
    samples = Samples(mesh_block(1, k), tuple(zip(*index)), tuple(range(S * (k + 1)))) if S > 1 else None
    return BlockType(f"obstacle_mesh{S}x{k}", ca.Function("obstacle_mesh_block", [v, d], [ca.SX(0), ca.vertcat(*rows)]), samples=samples)


@lru_cache(maxsize=1)
def after_block() -> BlockType:
    """Continuity of an intermediate chain: v = (E_j (12), theta, lam, dl, E_{j+1} (12)); d = t."""
    v, d = ca.SX.sym("v", 27), ca.SX.sym("d", 1)
    Xn, _ = segment_function(1)(v[:12], v[12], _lam_t(v[13], d[0]), v[14], ca.SX(0))
    return BlockType("after_growth", ca.Function("after_block", [v, d], [ca.SX(0), Xn - v[15:]]))


# ------------------------------------------------------------------ the term


@dataclass(frozen=True)
class ObstacleRows:
    """Obstacle rows on the chain (module docstring). ``slots``: primitive slots of every (shape, segment)
    column (0: no rows), shape-major (the final shape, then the levels); ``meshes``: per mesh obstacle, the
    columns with its rows (their triangles are data); ``S`` samples per segment; ``levels``: intermediate
    shapes of actuation after growth, each an extra level of 12 stage variables (Structure.extra = 12
    levels), their t the parameter ``after_t``; ``k`` triangles per mesh sample. Parameters:
    ``obstacle_prims_<P>`` (one column per (shape, segment) column with P slots) and ``obstacle_mesh_<q>``
    (one per column of mesh q), the data of the blocks."""

    slots: tuple  # primitive slots of every (shape, segment) column, shape-major
    meshes: tuple  # per mesh obstacle, the columns with its rows (the others are far from it)
    S: int
    levels: int = 0
    k: int = MESH_K
    # an active set: the structure runs interpreted, its small block types (segment, pose, intermediate
    # shapes) compiled on their own; an obstacle block of S samples is large (compiling it would take 8-90 s
    # with gcc -O1), so it runs as a map of its one-sample block (Samples), compiled once for every S
    compile: ClassVar[bool | str] = "blocks"

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
        self.levels = min(AFTER_SLOTS, len(self.grid))
        self.k = int(min([k] + [len(o.faces) for o in obstacles if isinstance(o, Mesh)]))
        longest = float(np.max(lengths)) / D
        self.S = int(min(MAX_SAMPLES, max(2, math.ceil(LENGTH_SLACK * longest / spacing))))
        self.kappa = curvature_bound(1.0, actuator.theta_max, actuator.lambda_min)
        self.scaled = tuple(o.scaled(1.0 / D) for o in self.obstacles)
        self.prims = [q for q, o in enumerate(self.obstacles) if not isinstance(o, Mesh)]
        self.meshes = [q for q, o in enumerate(self.obstacles) if isinstance(o, Mesh)]
        self.slots = np.array([rounded_box(self.scaled[q]) for q in self.prims]).reshape(len(self.prims), 17)
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
            self.raised += RAISE_FACTOR * _shortfall(self, rep)
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

    @property
    def push_need(self) -> float:
        """Center distance (units) a pushed start clears by: D/2 + margin + PUSH_EXTRA D (MESH_PUSH_EXTRA with a mesh)."""
        return self.D * (0.5 + (MESH_PUSH_EXTRA if self.has_mesh else PUSH_EXTRA)) + self.margin

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
        requirements from its segment lengths, the primitives near every segment (``ACTIVE_REACH``)
        and the mesh active sets at its sample points. May raise ``P`` (then ``term`` changes)."""
        M, S, k, D = routing.segments, self.S, self.k, self.D
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
            ob, sc, need = self.obstacles[q], self.scaled[q], needs[q]
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
                # a column gets rows where the tube can reach the mesh within one solve (MESH_TRUST)
                near.append(slack < MESH_REACH + REACH_DL * dl)
                tri = sc.triangles  # units of D
                T = tri[rows].reshape(M, S, kr * 9)  # per sample: kr triangles, a b c each
                nrm, off = _exit_planes(sc, faces, p / D, inside, np.repeat(need, S))
                a_tri = (~inside).astype(float).reshape(M, S)
                a_plane = inside.astype(float).reshape(M, S)
                if TANGENT_REACH > 0:
                    close = ~inside & (dist[:, 0] / D < np.repeat(need, S) + TANGENT_REACH)
                    if close.any():
                        c, _, _ = ob.trimesh.nearest.on_surface(p[close])
                        n = (p[close] - c) / np.maximum(np.linalg.norm(p[close] - c, axis=1, keepdims=True), 1e-300)
                        nrm[close], off[close] = n, np.sum(n * c / D, axis=1)
                        a_plane = (inside | close).astype(float).reshape(M, S)
                plane = np.hstack([nrm, off[:, None]]).reshape(M, S * 4)
                cols.append(np.vstack([head, T.reshape(M, S * kr * 9).T, a_tri.T, plane.T, a_plane.T]))
            chosen = sorted(set(self.mesh_cols[m]) | set(np.flatnonzero(np.concatenate(near)).tolist()))
            self.mesh_cols[m] = tuple(chosen)
            out[f"obstacle_mesh_{m}"] = np.hstack(cols)[:, chosen]
        self._remember = False
        return out

    def _prim_data(self, points, levels, needs, u, dl) -> dict:
        """The primitive slots of every (shape, segment) column: the primitives within ACTIVE_REACH + REACH_DL dl_j
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
            near = slack < ACTIVE_REACH + REACH_DL * dl[None, :]
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
        """Whether every sample of the rows clears the requirement its rows asked (the last ``data``)
        against the exact obstacle (units of D, within ``tol``). A converged solve whose report still finds
        the tube too close then dips between samples (raise the requirement); a sample that does not hold
        passed a mesh where its active set had no triangle, or a primitive its column had no slot for
        (the next ``data`` adds it; raising would only push the tube farther than needed). Not the
        requirement of the new segment lengths: their growth in the solve raises it, samples that held
        their rows' seemed not to, and a design short by its dips was never raised (CHANGELOG)."""
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


def _march(mesh: Mesh, p, w, need: float, tmax: float) -> np.ndarray:
    """Per row of p, the first t >= 0 with signed distance(p + t w) >= need (a hair beyond: a second pass
    finds the point clear), sphere tracing along w: the signed distance is 1-Lipschitz, so a step of
    need - distance never passes that point; at most tmax."""
    t = np.zeros(len(p))
    act = np.ones(len(p), bool)
    tol = 1e-6 * tmax
    for _ in range(MARCH_STEPS):
        idx = np.flatnonzero(act)
        if not idx.size:
            break
        step = need + tol - mesh_signed_distance(mesh, p[idx] + t[idx, None] * w[idx])
        go = step > 0
        t[idx[go]] += step[go] + tol
        act[idx[~go]] = False
        act &= t < tmax
    return np.minimum(t, tmax)


def _push_mesh(p: np.ndarray, mesh: Mesh, d: np.ndarray, need: float) -> np.ndarray:
    """Every run of points closer than ``need`` to ``mesh`` (``d``: their signed distances) moved out along
    ONE direction across the run's chord: of PUSH_DIRECTIONS directions around it, the one whose pushes
    (each point the least that clears it, :func:`_march`) sum least over PUSH_PROBES points of the run,
    the shortest way round the mesh. It depends on the target and the mesh alone, never on a design."""
    p = p.copy()
    lo, hi = mesh.bounds()
    tmax = float(np.linalg.norm(hi - lo)) + 2 * need
    m = np.concatenate([[False], d < need, [False]]).astype(int)
    for i0, i1 in zip(np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)):
        c = p[min(i1, len(p) - 1)] - p[max(i0 - 1, 0)]
        c /= max(float(np.linalg.norm(c)), 1e-300)
        e1 = np.cross(c, [1.0, 0.0, 0.0] if abs(c[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        ang = 2 * np.pi * np.arange(PUSH_DIRECTIONS) / PUSH_DIRECTIONS
        W = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * np.cross(c, e1)
        probe = p[np.unique(np.linspace(i0, i1 - 1, PUSH_PROBES).round().astype(int))]
        n = len(probe)
        t = _march(mesh, np.tile(probe, (PUSH_DIRECTIONS, 1)), np.repeat(W, n, axis=0), need, tmax).reshape(PUSH_DIRECTIONS, n)
        w = W[int(np.argmin(t.sum(axis=1)))]
        q = p[i0:i1]
        p[i0:i1] = q + _march(mesh, q, np.broadcast_to(w, q.shape), need, tmax)[:, None] * w
    return p


def pushed_target(target: np.ndarray, obstacles, need: float, passes: int = PUSH_PASSES) -> np.ndarray:
    """The target with every point closer than ``need`` (center distance, units) to an obstacle moved out
    across the target: along the distance gradient with its component along the target's tangent taken
    out (a target through an obstacle is pushed to one side of it, not back along itself), a run of
    points through one obstacle to ONE side (their mean direction) unless their directions cancel (a run
    along the obstacle, a helix round a cylinder: each point along its own); a run through a mesh along
    the one direction across its chord that pushes least (:func:`_push_mesh`); repeated ``passes`` times
    (a point pushed out of one obstacle may land in another)."""
    p = np.array(target, float)
    tan = np.gradient(p, axis=0)
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-300)
    h = 1e-6 * max(1.0, float(np.ptp(p)))
    for _ in range(passes):
        moved = False
        for ob in obstacles:
            d = np.asarray(ob.distance(p), float).reshape(-1)
            low = d < need
            if not low.any():
                continue
            moved = True
            if isinstance(ob, Mesh):
                p = _push_mesh(p, ob, d, need)
                continue
            g = np.zeros_like(p)
            q = p[low]  # the gradient only where a point moves (a mesh's distance is not cheap)
            steps = np.concatenate([q + h * e for e in np.eye(3)] + [q - h * e for e in np.eye(3)])
            f = np.asarray(ob.distance(steps), float).reshape(6, -1)
            g[low] = ((f[:3] - f[3:]) / (2 * h)).T
            g -= np.sum(g * tan, axis=1, keepdims=True) * tan
            m = np.concatenate([[False], low, [False]]).astype(int)
            for i0, i1 in zip(np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)):
                run = slice(i0, i1)
                gn = np.linalg.norm(g[run], axis=1)
                w = g[run].mean(axis=0)
                n = float(np.linalg.norm(w))
                if n >= 0.5 * float(gn.mean()) and n > 1e-12:  # a pass through the obstacle: all to one side
                    dirs = np.broadcast_to(w / n, g[run].shape)
                elif np.all(gn > 1e-12):  # a run along the obstacle (a helix round a cylinder): each point outward
                    dirs = g[run] / gn[:, None]
                else:  # dead center: any side across the tangent
                    w = np.cross(tan[i0], [0.0, 0.0, 1.0] if abs(tan[i0, 2]) < 0.9 else [1.0, 0.0, 0.0])
                    dirs = np.broadcast_to(w / np.linalg.norm(w), g[run].shape)
                rate = np.maximum(np.sum(dirs * g[run], axis=1), 0.2)  # the distance's rate along the push: a Newton step
                p[run] += ((need - d[run]) / rate)[:, None] * dirs
        if not moved:
            break
    return p


def _pushed_start(problem: DesignProblem, plan: Plan) -> Routing:
    """A start around the obstacles: the plain design of the pushed target (:func:`pushed_target`, center
    distance D/2 + margin + PUSH_EXTRA D, MESH_PUSH_EXTRA with a mesh) from its own geometric guess; without
    a mesh, where it does not clear, the plain design of its own chain pushed out (REPUSH times); a
    function of the problem alone (module docstring, "Start")."""
    need = plan.push_need
    tg, passes = problem.target, 0 if plan.has_mesh else REPUSH
    # the exact Hessian from the start: Gauss-Newton does not converge on a pushed target's corners, and
    # "auto" then solves the same start again with it (the same design, ~100 Gauss-Newton iterations later)
    options = dataclasses.replace(problem.options, hessian="exact") if problem.options.hessian == "auto" else problem.options
    for k in range(passes + 1):
        tg = pushed_target(tg, problem.obstacles, need)
        res = solve_from(dataclasses.replace(problem, target=tg, obstacles=(), options=options), None,
                         pair_points(tg, problem.options.points_per_segment), frames="target")
        if k == passes or plan.report(res.routing)["min_gap"] >= plan.margin:
            break
        # the chain cuts an obstacle where it could not follow the pushed target's corners: push the
        # chain itself (a curve the model follows) and design that
        tg = np.asarray(res.shape.center, float)
    return res.routing


def _pushed_chain(problem: TipProblem, plan: Plan, routing: Routing) -> Routing:
    """A tip problem's start around the obstacles: the chain of ``routing`` pushed out of them
    (:func:`pushed_target`, as the design's pushed start) and followed by the plain design of as many
    segments, from the problem's base pose. A chain through an obstacle's center gives its rows no
    direction out (the distance's gradient vanishes there); the push picks a side."""
    D, n = problem.diameter, DesignOptions().points_per_segment
    tg = pushed_target(sample_chain(routing, D, n)["points"], problem.obstacles, plan.push_need)
    fit = DesignProblem(problem.name, D, tg, problem.actuator, DesignOptions(points_per_segment=n, hessian="exact"), problem.units)
    r = solve_from(fit, None, pair_points(tg, n), frames="target").routing
    return Routing(r.theta, r.lam, r.length, routing.initial_pose)


def obstacle_stats(report: dict) -> dict:
    """The run metrics of a report: min_obstacle_gap (and min_obstacle_gap_after for growth "after")."""
    out = {"min_obstacle_gap": float(report["min_gap"])}
    if report["growth"] == "after":
        out["min_obstacle_gap_after"] = float(report["min_gap_intermediate"])
    return out


def _shortfall(plan: Plan, rep: dict) -> float:
    """What the shapes with rows (the final one, the intermediate ones at ``plan.ts``) miss of the margin,
    units of D: their dips between samples. An intermediate shape without rows that misses gets rows
    (``choose_levels``); raising every requirement by its miss pushed a growth "after" scene's tube
    ever farther out (CHANGELOG)."""
    worst = rep["min_gap"]
    if plan.ts:
        worst = min([worst] + [g for t, g in _intermediate_gaps(rep).items() if t in plan.ts])
    return max(plan.margin - worst, 0.0) / plan.D


def _intermediate_gaps(rep: dict) -> dict:
    """t -> the smallest gap of the intermediate shape at t, from a growth "after" report."""
    inter = rep["intermediate"]
    return {float(t): float(g) for t, g in zip(inter["t"], inter["gaps"].min(axis=1))}


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
        start_rmse, start_min_obstacle_gap, obstacle_raise (the rows' extra requirement, units),
        obstacle_slots (primitive slots per segment); iterations, ipopt_iterations and ipopt_time_s
        summed over the solves with rows (not the obstacle-free or pushed starts).
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
    plan.choose_levels(first)
    routing = start.routing
    if PUSHED_START:
        plan.data(routing)  # the slots near the obstacle-free design stay
        routing = _pushed_start(problem, plan)
    R0g = routing.initial_pose[:3, :3].copy()
    params = nlp_parameters(problem, pairing, R0g)
    factor, ramp = (MESH_BLOCKED_WEIGHT, MESH_WEIGHT_RAMP) if plan.has_mesh else (BLOCKED_WEIGHT, 0.0)
    params["cells"] = _weigh_blocked(problem, pairing, params["cells"], factor, ramp)
    data = plan.data(routing)
    solver = _design_solver(problem, pairing, plan)  # the loop's first solver (its layout and bounds)
    theta_b, lam_b, (dl_lo, dl_hi) = design_bounds(problem, pairing)
    # the pushed start's detour may lengthen a segment past LENGTH_FACTOR of its chord on the target: there the
    # bound makes room for it (a start outside the bounds is moved inside by IPOPT, its chain torn apart: a
    # 20-primitive scene with growth "after" then crawled through IPOPT's regularization for minutes)
    dl0 = routing.length / D
    lbx, ubx = solver.bounds(theta_b, lam_b, (dl_lo, np.where(dl0 > dl_hi, LENGTH_SLACK * dl0, dl_hi)))
    x = plan.fill_extra(solver, start_x(solver, chain_guess(problem, routing), D, "chain"), routing)
    best, rep, solves, ipopt_time, ipopt_iterations = None, first, 0, 0.0, 0
    if plan.has_mesh:
        rounds = max(rounds, MESH_ROUNDS)
    while solves < rounds:
        if solves:
            data = plan.data(routing)
        # cached; new only when P grew. A re-solve before the last stops at ROUND_MAX_ITER: the next round goes
        # on from its iterate with fresh active sets (a re-solve after new slots could crawl to max_iter)
        solver = _design_solver(problem, pairing, plan, ROUND_MAX_ITER if 0 < solves < rounds - 1 else None)
        p = solver.pack_params(params | data)
        x, status, st = solver.solve(x, p, *plan.trust(solver, x, lbx, ubx))
        solves += 1
        ipopt_time += st["ipopt_time_s"]
        ipopt_iterations += st["iterations"]
        res = result_of(problem, pairing, solver, x, status, st, R0g, METHOD)
        rep = plan.report(res.routing)
        best, routing = res, res.routing
        if rep["clear"] and res.converged:
            break
        plan.next_round(res.converged, routing, rep)
        x = plan.fill_extra(solver, x, routing)
    best.metrics.update(obstacle_stats(rep))
    best.stats.update(stats0 | {"obstacle_rounds": solves, "obstacle_clear": bool(rep["clear"]),
                                "obstacle_samples_per_segment": plan.S, "obstacle_raise": plan.raised * D, "obstacle_slots": plan.P,
                                "obstacle_after_t": list(plan.ts), "ipopt_time_s": ipopt_time, "ipopt_iterations": ipopt_iterations})
    best.iterations = ipopt_iterations
    best.solve_time_s = time.perf_counter() - t_all
    return best


# ------------------------------------------------------------------ tip problems


def _design_solver(problem: DesignProblem, pairing, plan: Plan, max_iter: int | None = None):
    """The plain NLP plus the plan's rows (cached per spec: a new one only when the plan's slots grew)."""
    return extended_solver(problem, pairing, (plan.term,), extra=plan.extra, max_iter=max_iter)


def _tip_solver(problem: TipProblem, plan: Plan):
    o = problem.options
    return get_solver(tip_spec(problem.segments, problem.actuator.shared_lambda, problem.direction is not None, problem.objective,
                               min(o.max_iter, TIP_MAX_ITER), o.tol, hard=True, extra=plan.extra, terms=(plan.term,)))


def _tip_solve(problem: TipProblem, plan: Plan, routing: Routing, rounds: int):
    """The tip NLP with obstacle rows from ``routing`` (its frames on its chain), the active-set loop."""
    o, a, D, M, L = problem.options, problem.actuator, problem.diameter, problem.segments, problem.length
    T0 = problem.initial_pose
    X0 = frames12(T0[None])[:, 0].copy()
    X0[9:] /= D
    d = problem.direction if problem.direction is not None else np.array([1.0, 0.0, 0.0])
    e1, e2 = _perpendicular_pair(d)
    base = {"cells": np.zeros((5, M)), "smooth": [o.smooth_theta, o.smooth_lambda], "h": np.full(max(M - 1, 1), L / M / D),
            "L": L / D, "tip_position": problem.position / D, "tip_frame": np.column_stack([d, e1, e2]), "tube_length": L / D}
    plan.reset_rounds()
    plan.choose_levels(plan.report(routing))
    data = plan.data(routing)
    solver = _tip_solver(problem, plan)
    lbx, ubx = solver.bounds((-a.theta_max, a.theta_max), (a.lambda_min, 1.0), (MIN_LENGTH_FACTOR * L / M / D, L / D), X0=X0)
    fr = chain_frames(routing.theta, routing.lam, routing.length, D, T0)
    fr[:, :3, 3] /= D
    x = plan.fill_extra(solver, solver.pack_x(routing.theta, routing.lam, routing.length / D, frames12(fr)[None]), routing)
    res, rep, solves, iters = None, None, 0, 0
    while solves < rounds:
        if solves:
            data = plan.data(routing)
        solver = _tip_solver(problem, plan)  # cached; new only when P grew
        p = solver.pack_params(base | data)
        x, status, st = solver.solve(x, p, *plan.trust(solver, x, lbx, ubx))
        solves += 1
        v = solver.unpack(x)
        routing = Routing(v["theta"], v["lam"][:, 0], v["dl"] * D, T0)
        iters += st.pop("iterations")
        res = evaluate_tip(problem, routing, status=status, solve_time_s=st.pop("solve_time_s"), iterations=iters,
                           stats=st | {"objective_kind": problem.objective, "segments": M, "tube_length": L})
        rep = plan.report(routing)
        if (rep["clear"] and res.converged) or status == "max_iter":
            break  # a start that crawls to TIP_MAX_ITER is left for the next
        plan.next_round(res.converged, routing, rep)
        x = plan.fill_extra(solver, x, routing)
    res.stats["obstacle_rounds"] = solves
    return res, rep


def tip_design(problem: TipProblem, starts: int | None = None, progress=None) -> Result:
    """A tip problem's design, as ``vine-nlp design`` makes it: among its obstacles where it has any
    (:func:`design_tip_with_obstacles`), else :func:`vine_nlp.methods.tip.design_tip`.

    Parameters
    ----------
    problem : TipProblem
    starts : int, optional
        Starts (default options.starts).
    progress : callable, optional
        progress(done, total) after every start.

    Returns
    -------
    Result
    """
    if problem.obstacles:
        return design_tip_with_obstacles(problem, starts=starts, progress=progress)
    return design_tip(problem, starts=starts, progress=progress)


def design_tip_with_obstacles(problem: TipProblem, starts: int | None = None, rounds: int = ROUNDS, ts=None, k: int = MESH_K,
                              spacing: float = SPACING, progress=None, thorough: bool = False) -> Result:
    """Least-actuation tip design that keeps the tube ``problem.obstacle_margin`` clear of ``problem.obstacles``.

    Parameters
    ----------
    problem : TipProblem
    starts : int, optional
        Starts of the tip design (default options.starts). Solved with the obstacle rows, in order,
        after the obstacle-free tip design and its chain pushed out of the obstacles
        (:func:`_pushed_chain`), until one is optimal and clear: the later starts are fallbacks, as
        in design_tip, and each runs its own active-set loop of hundreds of iterations. A start whose
        solve reaches TIP_MAX_ITER iterations is left there for the next (such a solve could crawl on
        to IPOPT's limit where another start converged quickly; CHANGELOG).
    rounds, ts, k, spacing
        As :func:`design_with_obstacles`.
    progress : callable, optional
        progress(done, total) after every start.
    thorough : bool
        Solve every start and keep the best (a lower objective, at several times the cost).

    Returns
    -------
    Result
        The best converged start that clears (else the best converged, else the lowest tip error);
        metrics as design_tip's plus min_obstacle_gap; stats obstacle_* as design_with_obstacles'.
    """
    t_all = time.perf_counter()
    free = design_tip(problem, starts=starts, thorough=True)
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
    n = max(1, problem.options.starts if starts is None else starts)
    # each made when it is tried: the pushed chain costs a design solve
    guesses = [lambda: free.routing, lambda: _pushed_chain(problem, plan, free.routing)]
    guesses += [lambda g=g: Routing(g[0], g[1], g[2], problem.initial_pose) for g in start_guesses(problem, n)]
    results = []
    for g in guesses:
        results.append(_tip_solve(problem, plan, g(), rounds))
        if progress:
            progress(len(results), len(guesses))
        r, rep = results[-1]
        if r.status == "optimal" and rep["clear"] and not thorough:
            break
    score = [(0 if (r.converged and rep["clear"]) else 1 if r.converged else 2,
              r.stats["objective"] if r.converged else r.metrics["tip_error"]) for r, rep in results]
    kbest = drive.pick_best(list(range(len(results))), key=lambda i: (score[i][0] != 0, score[i][1]))
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
