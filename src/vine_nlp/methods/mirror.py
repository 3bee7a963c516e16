"""Mirror images: a design problem solved in the handedness its geometry picks (issue 33).

The mirror y -> -y (M = diag(1, -1, 1)) maps a routing's shape to the shape of the mirrored routing: theta -> -theta,
lambda and lengths kept, each frame T -> M T S with S = diag(1, 1, -1) (the Frenet frame's binormal is t x n; the
segment's torsion is odd in theta, its curvature even). Negation is exact in floating point and the model's functions
are exactly odd or even, so the mirror of a design is exact. A solve is not: IPOPT's sums over a variable's two bound
multipliers run in another order once the variable's sign flips, and the local solve from exactly mirrored starts, with
exactly mirrored derivatives, amplifies that last bit into a different local optimum (1e-13 after one iteration, 1e-5
after 40, 0.1 after 120 on a random scene; designs 3 % apart in RMSE, 0.4 % without obstacles). So a problem is solved
in ONE of its two handednesses, the one :func:`handedness` picks, and a problem of the other handedness is solved as its
mirror and the design mirrored back: a scene and its mirror image are the same numbers for the solver, and their designs
are mirror images bit for bit.

:func:`handedness` is odd under the mirror, exactly: the target's torsion (the sum of the triple products of consecutive
chords: a property of its shape, unchanged by a rotation, so that a mirror in any plane is solved as a rotated copy);
for a target planar to round-off, where the shape has no handedness, the side of the world's y = 0 plane the target lies
on, then the obstacles; 0 (solved as given) where nothing decides, a problem that is its own mirror."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vine_nlp.methods.settings import PLANAR
from vine_nlp.model.obstacles import Box, Capsule, Mesh, Plane, Sphere
from vine_nlp.model.shape import Shape
from vine_nlp.problem import DesignProblem, Result, Routing

M3 = np.diag([1.0, -1.0, 1.0])
_M4 = np.diag([1.0, -1.0, 1.0, 1.0])
_S4 = np.diag([1.0, 1.0, -1.0, 1.0])


def mirrored_pose(T) -> np.ndarray:
    """The mirror of a frame (4 x 4): M T S (exact: sign flips)."""
    return _M4 @ np.asarray(T, float) @ _S4


def mirrored_routing(r: Routing) -> Routing:
    """The routing whose shape is the mirror of ``r``'s: theta -> -theta, the base pose mirrored."""
    return Routing(theta=-np.asarray(r.theta, float), lam=np.array(r.lam, float), length=np.array(r.length, float), initial_pose=mirrored_pose(r.initial_pose))


def _y(p) -> tuple:
    x, y, z = (float(v) for v in p)
    return (x, -y, z)


def mirrored_obstacle(ob):
    """The mirror image of an obstacle (exact)."""
    if isinstance(ob, Sphere):
        return Sphere(_y(ob.center), ob.radius, ob.name)
    if isinstance(ob, Box):
        return Box(_y(ob.center), ob.size, tuple(map(tuple, M3 @ np.array(ob.rotation) @ M3)), ob.name)
    if isinstance(ob, Capsule):
        return Capsule(_y(ob.p0), _y(ob.p1), ob.radius, ob.name)
    if isinstance(ob, Plane):
        return Plane(_y(ob.point), _y(ob.normal), ob.name)
    if isinstance(ob, Mesh):  # the winding reversed: the faces still turn counter-clockwise seen from outside
        return Mesh(ob.vertices @ M3, ob.faces[:, [0, 2, 1]], ob.source, ob.name)
    raise TypeError(f"no mirror image of {type(ob).__name__}")


def mirrored_problem(problem: DesignProblem) -> DesignProblem:
    """The mirror image of a design problem: its target and obstacles, a fixed base pose, gravity."""
    o = problem.options
    if o.base_pose is not None:
        o = dataclasses.replace(o, base_pose=tuple(map(tuple, mirrored_pose(o.base_pose))))
    load = problem.load and dataclasses.replace(problem.load, gravity=_y(problem.load.gravity))  # gravity mirrored too
    return dataclasses.replace(problem, target=np.asarray(problem.target, float) @ M3, options=o, load=load,
                               obstacles=tuple(mirrored_obstacle(ob) for ob in problem.obstacles))


def mirrored_result(r: Result) -> Result:
    """A design's result for the mirror image of its problem: routing and shape mirrored, the figures kept."""
    s = r.shape
    shape = Shape(*(None if v is None else np.asarray(v, float) @ M3 for v in (s.center, s.inner, s.outer)))
    return dataclasses.replace(r, routing=mirrored_routing(r.routing), shape=shape, metrics=dict(r.metrics),
                               stats=dict(r.stats) | {"solved_mirrored": True})


def _reference(ob) -> np.ndarray:
    if isinstance(ob, Plane):
        return np.array(ob.point)
    lo, hi = ob.bounds()
    return 0.5 * (np.asarray(lo, float) + np.asarray(hi, float))


def handedness(problem: DesignProblem) -> float:
    """+1, -1 or 0, odd under the mirror y -> -y exactly (module docstring): the sign of the target's torsion
    sum unless the target is planar to round-off; then the sign of the target's summed y, then of the
    obstacles' (their boxes' middles); 0 where all vanish."""
    p = np.asarray(problem.target, float)
    d = np.diff(p, axis=0)
    if len(d) >= 3:
        a, b, c = d[:-2], d[1:-1], d[2:]
        # a . (b x c) term by term: each product flips its sign exactly with y, so the sum does
        bxc = np.stack([b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1], b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2], b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]], axis=1)
        torsion = math.fsum((a * bxc).ravel())
        scale = math.fsum((np.linalg.norm(d, axis=1) ** 3).tolist())
        if abs(torsion) > PLANAR * scale:
            return math.copysign(1.0, torsion)
    for v in (math.fsum(p[:, 1].tolist()), math.fsum(_reference(ob)[1] for ob in problem.obstacles)):
        if v != 0:
            return math.copysign(1.0, v)
    return 0.0
