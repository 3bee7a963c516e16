"""Obstacles around the tube: signed distances, sampling rule, growth and a report (issue 15).

Shapes (frozen value types, each with a ``kind`` name): :class:`Sphere`,
:class:`Box`, :class:`Capsule`, :class:`Plane` and :class:`Mesh`. The tube of
diameter D clears an obstacle by ``gap = distance(center line, obstacle) - D/2``;
a design asks for gap >= margin everywhere along the tube (formats.md "Obstacles").

Signed distances (positive outside, negative inside, in the obstacle's units)
---------------------------------------------------------------------------
Every primitive's distance is written once against ``vine_nlp.model.ops.lib``: a
numpy point array (..., 3) gives an array (...); a CasADi 3x1 (or 3xN) SX/MX
gives a 1x1 (1xN) expression. All four primitives are convex, and the distance
to a convex set is C^1 (indeed C^{1,1}) everywhere outside the set: the only
kinks of the exact formulas (the clamp of the capsule's segment parameter, the
box's max/abs) either cancel outside (the clamped parameter sits where the
distance along the segment is stationary; the box's |x| kink lies where its
max(q, 0) is identically 0) or lie inside (medial axis). The NLP's rows ask for
distance >= D/2 + margin > 0, so every feasible point lies where the row is C^1.

``sqrt`` at 0 (the sphere's center, the capsule's axis, the box's surface seen
from its exterior term) has an infinite derivative, and CasADi's ``if_else`` and
``fmax`` differentiate every branch: every sqrt here is ``sqrt(x + eps^2)`` with
eps = ``EPS_REL`` (1e-9) times the obstacle's size. The value then differs from
the exact distance d by at most eps^2 / (2 d): below 1e-18 of the size at d of
the order of the size, at most eps at d = 0; gradients stay finite (Hessians
are large, ~1/eps, only within eps of the singular set, which is inside).

Meshes. The exact signed distance of a closed triangle mesh (numpy only) is
trimesh's (``trimesh.proximity.signed_distance``, positive *inside*: negated
here). For the NLP, the sign of a mesh's distance is a global property (inside
or outside) that no finite set of smooth per-triangle expressions gives, so the
rows are the *unsigned* exact distance to each triangle of an active set
(:func:`nearest_triangles`, refreshed between solves): a triangle is convex, so
its distance is C^1 wherever it is positive, continuous everywhere, and the
mesh's unsigned distance is the minimum over its triangles, so rows over the
nearest triangles are exact rows, not an approximation (:func:`mesh_rows`). What
they cannot see is a point deeper inside than the clearance: points that the exact
(trimesh) sign finds inside the mesh at a refresh (:func:`refresh_active_set`
``inside``) also get the face-plane row :func:`triangle_plane_distance` of their
nearest face (signed, linear), which pushes them back out through that face; the
next refresh drops it. The plane row is not used outside: at a convex edge it
over-constrains (the plane of one face runs inside the other face's clearance
region) and it jumps when the nearest face changes.

Sampling rule (:func:`sample_spacing`, :func:`dip`)
---------------------------------------------------
Center-line points at most h apart along the arc, each at distance >= r = D/2 + m
from a convex obstacle K, bound the whole center line: let y be the point of the
chord between two samples nearest to K and k its nearest point on K; the samples
are >= r from k and y - k is normal to the chord, so the chord (length <= h)
stays >= sqrt(r^2 - h^2/4) from K. If K's surface has all radii of curvature
>= R_K (sphere, capsule: their radius; plane: infinite; box, triangle: 0), the
same argument about the center of curvature gives sqrt((r + R_K)^2 - h^2/4) - R_K.
The arc leaves its chord by at most the sagitta (1 - cos(kappa h / 2)) / kappa
(center-line curvature <= kappa), and the distance is 1-Lipschitz, so between
samples the gap drops at most

    dip(h) = (r + R_K) - sqrt((r + R_K)^2 - h^2 / 4) + (1 - cos(kappa h / 2)) / kappa.

No obstacle fits between samples (the chord never reaches K) when h < 2 r = D + 2 m.
To hold gap >= margin - tol on the continuous tube: sample at h with dip(h) <= tol,
or ask the samples for margin + dip(h) (how the NLP rows should use it). With
kappa = 2/D (the limit lambda -> 0 at theta = 0; steeper theta bends more:
:func:`curvature_bound` gives 2.21/D for theta <= 60 deg, lambda >= 0.4) and a sharp
obstacle: dip ~ h^2 / (2 D), so tol = 1e-3 D needs h <= 0.045 D, while h = D/4
costs an inflation of D/32.
A mesh's unsigned distance is the minimum over its (convex) triangles, so the
bound holds for it with R_K = 0.

Growth (paper Sec. VI-D; as in ``vine_nlp.analysis.collision``)
---------------------------------------------------------------
Grown while actuated, the body at every moment is a prefix of the final center
line (material coordinate l <= L_grown), so every intermediate gap is >= the final
shape's gap: checking the final shape covers growth (:func:`grown_prefixes`).
Actuated after full growth, the tube sweeps lambda_t = 1 - t (1 - lambda), theta
fixed, t: 0 -> 1 (:func:`after_growth_shapes`), and every intermediate shape must
clear the obstacles too.

Layer 2: imports vine_nlp.model, numpy, casadi, scipy; trimesh inside functions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.model.chain import chain_frames, chain_points, segment_end_samples
from vine_nlp.model.helix import center_rates
from vine_nlp.model.ops import is_symbolic, lib
from vine_nlp.model.routing import Routing

EPS_REL = 1e-9  # sqrt(x + eps^2), eps = EPS_REL * size: module docstring
GROWTH_MODES = ("while-actuated", "after")
SHAPES = ("sphere", "box", "capsule", "plane", "mesh")
DEFAULT_PER_SEGMENT = 20
DEFAULT_AFTER_STEPS = 20  # t grid of actuation after growth: 0, 1/20, ..., 1


# ------------------------------------------------------------------ vector helpers (numpy or CasADi)


def _xyz(p):
    """Components (x, y, z) of a point argument: numpy (..., 3), CasADi 3xN / Nx3-free 3x1, or a 3-sequence."""
    if isinstance(p, (ca.SX, ca.MX, ca.DM)):
        if p.shape[0] != 3:
            if p.shape[1] == 3:
                p = p.T
            else:
                raise ValueError(f"a CasADi point must be 3x1 or 3xN, got {p.shape}")
        return p[0, :], p[1, :], p[2, :]
    if isinstance(p, (list, tuple)) and len(p) == 3 and is_symbolic(*p):
        return tuple(p)
    a = np.asarray(p, float)
    if a.shape[-1] != 3:
        raise ValueError(f"points must have 3 coordinates in the last axis, got shape {a.shape}")
    return a[..., 0], a[..., 1], a[..., 2]


def _vec(v):
    """Numeric vector parameter (..., 3) as components (broadcast against point components)."""
    a = np.asarray(v, float)
    return a[..., 0], a[..., 1], a[..., 2]


def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _all3(x, y, z):
    if is_symbolic(x, y, z):
        return ca.logic_and(ca.logic_and(x, y), z)
    return np.logical_and(np.logical_and(x, y), z)


def _lib(*args):
    return lib(*[a for a in args if a is not None])


# ------------------------------------------------------------------ primitive distances


def sphere_distance(p, center, radius):
    """Signed distance from ``p`` to the sphere (center, radius): |p - c| - r (exact up to eps, see module)."""
    x = _sub(_xyz(p), _vec(center))
    L = _lib(*x)
    eps = EPS_REL * float(radius)
    return L.sqrt(_dot(x, x) + eps * eps) - float(radius)


def plane_distance(p, point, normal):
    """Signed distance to the half-space behind the plane: n . (p - point), n normalized; positive on the free side."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    return _dot(_sub(_xyz(p), _vec(point)), _vec(n))


def capsule_distance(p, p0, p1, radius):
    """Signed distance to the capsule: distance to segment p0-p1 minus the radius.

    The segment parameter is clamped to [0, 1]; the clamp's kinks are where the
    distance along the segment is stationary, so the result is C^1 outside.
    """
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    d = b - a
    dd = float(d @ d)
    if dd == 0.0:
        raise ValueError("capsule: p0 and p1 are the same point")
    ap = _sub(_xyz(p), _vec(a))
    L = _lib(*ap)
    t = L.fmin(L.fmax(_dot(ap, _vec(d)) / dd, 0.0), 1.0)
    diff = (ap[0] - t * d[0], ap[1] - t * d[1], ap[2] - t * d[2])
    eps = EPS_REL * max(float(radius), math.sqrt(dd))
    return L.sqrt(_dot(diff, diff) + eps * eps) - float(radius)


def box_distance(p, center, size, rotation=None):
    """Signed distance to the box (center, full edge lengths ``size``, world-from-box ``rotation``).

    q = |R^T (p - c)| - size/2; exterior sqrt(sum max(q, 0)^2) + interior min(max q, 0):
    the exact distance. Outside it is C^1 (distance to a convex set): where a local
    coordinate crosses 0 (|.| kink), that q is -size/2 < 0 and clamped away; the max q
    kinks (medial axis) and the exterior/interior switch are inside or on the surface.
    The exterior sqrt carries + eps^2 (finite gradient from inside, where its argument is 0).
    """
    R = np.eye(3) if rotation is None else np.asarray(rotation, float)
    h = 0.5 * np.asarray(size, float)
    w = _sub(_xyz(p), _vec(center))
    L = _lib(*w)
    local = [w[0] * R[0, i] + w[1] * R[1, i] + w[2] * R[2, i] for i in range(3)]
    q = [L.fabs(local[i]) - h[i] for i in range(3)]
    o = [L.fmax(qi, 0.0) for qi in q]
    eps = EPS_REL * float(np.linalg.norm(size))
    outside = L.sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + eps * eps)
    inside = L.fmin(L.fmax(q[0], L.fmax(q[1], q[2])), 0.0)
    return outside + inside


def _segment_d2(p, a, b):
    ab = _sub(b, a)
    ap = _sub(p, a)
    L = _lib(*ap)
    t = L.fmin(L.fmax(_dot(ap, ab) / _dot(ab, ab), 0.0), 1.0)
    diff = (ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2])
    return _dot(diff, diff)


def point_triangle_distance(p, a, b, c):
    """Unsigned exact distance from ``p`` to the triangle (a, b, c), numpy (vectorized) or CasADi.

    If the projection of p onto the triangle's plane falls inside the triangle
    (barycentric weights >= 0), the plane distance; otherwise the nearest of the three
    edges (segments). A triangle is convex, so the distance is C^1 wherever it is > 0;
    both if_else branches agree (value and gradient) on the switch (the prism's side
    walls), and the three edge distances tie only where they share a vertex region.
    numpy: p (..., 3) with a, b, c (..., 3) broadcast against it; CasADi: p symbolic,
    a, b, c numbers. Triangles must not be degenerate (zero area).
    """
    pc = _xyz(p)
    av, bv, cv = (np.asarray(v, float) for v in (a, b, c))
    ab, ac = bv - av, cv - av
    n = np.cross(ab, ac)
    nn = np.sum(n * n, axis=-1)
    if np.any(nn <= 0):
        raise ValueError("degenerate triangle (zero area)")
    e_b = np.cross(ac, n) / nn[..., None]  # w_b = (p - a) . e_b
    e_c = np.cross(n, ab) / nn[..., None]  # w_c = (p - a) . e_c
    ap = _sub(pc, _vec(av))
    L = _lib(*ap)
    w_b = _dot(ap, _vec(e_b))
    w_c = _dot(ap, _vec(e_c))
    w_a = 1.0 - w_b - w_c
    inside = _all3(w_a >= 0, w_b >= 0, w_c >= 0)
    h = _dot(ap, _vec(n / np.sqrt(nn)[..., None]))
    A, B, C = _vec(av), _vec(bv), _vec(cv)
    edges = L.fmin(_segment_d2(pc, A, B), L.fmin(_segment_d2(pc, B, C), _segment_d2(pc, C, A)))
    d2 = L.where(inside, h * h, edges)
    scale = float(np.sqrt(np.max(np.sum(ab * ab, axis=-1))))
    eps = EPS_REL * scale
    return L.sqrt(d2 + eps * eps)


def triangle_plane_distance(p, a, b, c):
    """Signed distance to the plane of triangle (a, b, c), positive along its normal (b - a) x (c - a).

    On a closed mesh wound counter-clockwise seen from outside (trimesh's convention),
    the normal points out: the row for a point found inside (module docstring).
    """
    av, bv, cv = (np.asarray(v, float) for v in (a, b, c))
    n = np.cross(bv - av, cv - av)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return _dot(_sub(_xyz(p), _vec(av)), _vec(n))


# ------------------------------------------------------------------ obstacle value types


def _tuple3(v, name):
    a = np.asarray(v, float).reshape(-1)
    if a.size != 3 or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers")
    return tuple(float(x) for x in a)


def rotation_from_degrees(angles_deg) -> np.ndarray:
    """Rotation matrix of extrinsic x, then y, then z rotations (degrees): R = Rz Ry Rx."""
    ax, ay, az = np.radians(np.asarray(angles_deg, float).reshape(3))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


# |R^T R - I| and |det R - 1| allowed for a given rotation matrix: a hand-written matrix with
# four significant digits (0.7071) passes; it is then made exactly orthonormal (nearest_rotation).
ROTATION_TOL = 1e-3


def is_rotation(R, tol: float = ROTATION_TOL) -> bool:
    """Whether R is a proper rotation matrix (orthonormal, determinant +1) within ``tol``."""
    R = np.asarray(R, float)
    return (R.shape == (3, 3) and bool(np.all(np.isfinite(R))) and float(np.max(np.abs(R.T @ R - np.eye(3)))) <= tol
            and abs(float(np.linalg.det(R)) - 1.0) <= tol)


def nearest_rotation(R) -> np.ndarray:
    """The rotation matrix nearest to R (Frobenius norm): U V^T of R's SVD, for det(R) > 0."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    return U @ Vt


@dataclass(frozen=True)
class Sphere:
    center: tuple
    radius: float
    name: str = ""
    kind: ClassVar[str] = "sphere"

    def __post_init__(self):
        object.__setattr__(self, "center", _tuple3(self.center, "center"))
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError("radius must be > 0")
        object.__setattr__(self, "radius", float(self.radius))

    def distance(self, p):
        return sphere_distance(p, self.center, self.radius)

    def parameters(self) -> dict:
        return {"center": np.array(self.center), "radius": np.float64(self.radius)}

    def scaled(self, f: float) -> "Sphere":
        return Sphere(tuple(f * np.array(self.center)), f * self.radius, self.name)

    def bounds(self):
        c = np.array(self.center)
        return c - self.radius, c + self.radius


@dataclass(frozen=True)
class Box:
    center: tuple
    size: tuple  # full edge lengths along the box's own axes
    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # world from box
    name: str = ""
    kind: ClassVar[str] = "box"

    def __post_init__(self):
        object.__setattr__(self, "center", _tuple3(self.center, "center"))
        size = _tuple3(self.size, "size")
        if min(size) <= 0:
            raise ValueError("size must be > 0")
        object.__setattr__(self, "size", size)
        R = np.asarray(self.rotation, float)
        if not is_rotation(R):
            raise ValueError("rotation must be a proper rotation matrix (orthonormal, det 1)")
        R = R if is_rotation(R, 1e-12) else nearest_rotation(R)  # exact input kept bit for bit
        object.__setattr__(self, "rotation", tuple(tuple(float(x) for x in row) for row in R))

    def distance(self, p):
        return box_distance(p, self.center, self.size, np.array(self.rotation))

    def parameters(self) -> dict:
        return {"center": np.array(self.center), "size": np.array(self.size), "rotation": np.array(self.rotation)}

    def scaled(self, f: float) -> "Box":
        return Box(tuple(f * np.array(self.center)), tuple(f * np.array(self.size)), self.rotation, self.name)

    def corners(self) -> np.ndarray:
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        return np.array(self.center) + (signs * 0.5 * np.array(self.size)) @ np.array(self.rotation).T

    def bounds(self):
        c = self.corners()
        return c.min(axis=0), c.max(axis=0)


@dataclass(frozen=True)
class Capsule:
    p0: tuple
    p1: tuple
    radius: float
    name: str = ""
    kind: ClassVar[str] = "capsule"

    def __post_init__(self):
        object.__setattr__(self, "p0", _tuple3(self.p0, "p0"))
        object.__setattr__(self, "p1", _tuple3(self.p1, "p1"))
        if self.p0 == self.p1:
            raise ValueError("p0 and p1 must differ (a sphere is a shape of its own)")
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError("radius must be > 0")
        object.__setattr__(self, "radius", float(self.radius))

    def distance(self, p):
        return capsule_distance(p, self.p0, self.p1, self.radius)

    def parameters(self) -> dict:
        return {"p0": np.array(self.p0), "p1": np.array(self.p1), "radius": np.float64(self.radius)}

    def scaled(self, f: float) -> "Capsule":
        return Capsule(tuple(f * np.array(self.p0)), tuple(f * np.array(self.p1)), f * self.radius, self.name)

    def bounds(self):
        a, b = np.array(self.p0), np.array(self.p1)
        return np.minimum(a, b) - self.radius, np.maximum(a, b) + self.radius


@dataclass(frozen=True)
class Plane:
    point: tuple
    normal: tuple  # unit; the free side is along it
    name: str = ""
    kind: ClassVar[str] = "plane"

    def __post_init__(self):
        object.__setattr__(self, "point", _tuple3(self.point, "point"))
        n = np.array(_tuple3(self.normal, "normal"))
        norm = float(np.linalg.norm(n))
        if norm == 0.0:
            raise ValueError("normal must not be zero")
        object.__setattr__(self, "normal", tuple(float(x) for x in n / norm))

    def distance(self, p):
        return plane_distance(p, self.point, self.normal)

    def parameters(self) -> dict:
        return {"point": np.array(self.point), "normal": np.array(self.normal)}

    def scaled(self, f: float) -> "Plane":
        return Plane(tuple(f * np.array(self.point)), self.normal, self.name)

    def bounds(self):
        return None


@dataclass(frozen=True, eq=False)
class Mesh:
    """A closed (watertight) triangle mesh; faces wound counter-clockwise seen from outside."""

    vertices: np.ndarray = field(repr=False)  # (V, 3)
    faces: np.ndarray = field(repr=False)  # (F, 3) int, indices into vertices
    source: str | None = None  # the file it was read from, as named in the problem file
    name: str = ""
    kind: ClassVar[str] = "mesh"

    def __post_init__(self):
        v = np.array(self.vertices, dtype=float)
        f = np.array(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 4 or not np.all(np.isfinite(v)):
            raise ValueError("vertices must be a (V, 3) array of finite numbers, V >= 4")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 4 or f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError("faces must be a (F, 3) array of vertex indices, F >= 4")
        tri = v[f]
        if np.any(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) == 0):
            raise ValueError("faces must not be degenerate (zero area)")
        v.setflags(write=False)
        f.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @property
    def triangles(self) -> np.ndarray:
        return self.vertices[self.faces]

    @cached_property
    def trimesh(self):
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, process=False)

    def distance(self, p):
        if is_symbolic(p) or (isinstance(p, (list, tuple)) and is_symbolic(*p)):
            raise TypeError("a mesh has no CasADi distance: use point_triangle_distance on nearest_triangles")
        return mesh_signed_distance(self, p)

    def parameters(self) -> dict:
        return {"vertices": np.array(self.vertices), "faces": np.array(self.faces)}

    def scaled(self, f: float) -> "Mesh":
        return Mesh(f * self.vertices, self.faces, self.source, self.name)

    def bounds(self):
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def __eq__(self, other):
        return (isinstance(other, Mesh) and self.source == other.source and self.name == other.name
                and np.array_equal(self.vertices, other.vertices) and np.array_equal(self.faces, other.faces))

    __hash__ = object.__hash__


OBSTACLE_TYPES = {c.kind: c for c in (Sphere, Box, Capsule, Plane, Mesh)}


def signed_distance(obstacle, p):
    """Signed distance from ``p`` to ``obstacle`` (positive outside): numpy for every shape, CasADi for primitives."""
    return obstacle.distance(p)


def sharpness_radius(obstacle) -> float:
    """Smallest radius of curvature of the obstacle's surface (sampling rule): sphere and capsule
    their radius, plane inf, box and mesh 0 (edges)."""
    if isinstance(obstacle, (Sphere, Capsule)):
        return obstacle.radius
    if isinstance(obstacle, Plane):
        return math.inf
    return 0.0


# ------------------------------------------------------------------ meshes


def mesh_signed_distance(mesh: Mesh, points) -> np.ndarray:
    """Exact signed distance from points (..., 3) to a closed mesh, positive outside (trimesh's sign flipped)."""
    import trimesh

    p = np.asarray(points, float)
    flat = p.reshape(-1, 3)
    # trimesh: positive inside, negative outside
    d = -trimesh.proximity.signed_distance(mesh.trimesh, flat)
    return np.asarray(d, float).reshape(p.shape[:-1])


def nearest_triangles(mesh: Mesh, points, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` triangles nearest to each point (exact unsigned distances): the active set.

    Returns (faces (P, k) face indices, nearest first; distances (P, k)). Exact: candidates
    come from a k-d tree on the centroids, and every triangle that could be nearer than the
    k-th candidate (centroid closer than that distance plus the largest centroid-to-vertex
    radius) is measured too.
    """
    p = np.atleast_2d(np.asarray(points, float))
    tri = mesh.triangles
    F = len(tri)
    k = int(min(k, F))
    cent = tri.mean(axis=1)
    reach = float(np.max(np.linalg.norm(tri - cent[:, None, :], axis=2)))
    from scipy.spatial import cKDTree  # SciPy loads only where a mesh is queried

    tree = cKDTree(cent)
    _, first = tree.query(p, k=min(F, max(2 * k, k + 8)))
    first = first.reshape(len(p), -1)
    d0 = point_triangle_distance(p[:, None, :], tri[first, 0], tri[first, 1], tri[first, 2])
    bound = np.sort(d0, axis=1)[:, k - 1] + reach
    lists = tree.query_ball_point(p, bound)
    counts = np.array([len(c) for c in lists])
    pi = np.repeat(np.arange(len(p)), counts)
    fi = np.concatenate([np.asarray(c, np.int64) for c in lists])
    d = point_triangle_distance(p[pi], tri[fi, 0], tri[fi, 1], tri[fi, 2])
    order = np.lexsort((fi, d, pi))  # by point, then distance (ties: lower face index)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    take = order[(start[:, None] + np.arange(k)[None, :])]
    faces, dists = fi[take], d[take]
    return faces, dists


def refresh_active_set(mesh: Mesh, points, k: int = 4) -> dict:
    """Active set for the NLP's mesh rows at the current center-line points (between solves).

    Returns dict(faces (P, k), distances (P, k) unsigned, signed (P,) exact signed distance,
    inside (P,) bool: points to constrain by the plane row of faces[:, 0] (module docstring)).
    """
    faces, dists = nearest_triangles(mesh, points, k)
    signed = mesh_signed_distance(mesh, np.atleast_2d(np.asarray(points, float)))
    return {"faces": faces, "distances": dists, "signed": signed, "inside": signed < 0}


def mesh_rows(point, mesh: Mesh, faces, inside: bool = False) -> list:
    """Distance expressions of one center-line point to its active triangles (NLP rows, each >= D/2 + margin).

    ``faces``: that point's row of :func:`refresh_active_set` ``faces`` (nearest first);
    ``inside``: its ``inside`` flag, which adds the signed plane row of the nearest face
    first (module docstring). numpy or CasADi ``point``.
    """
    tri = mesh.triangles
    rows = [triangle_plane_distance(point, *tri[int(faces[0])])] if inside else []
    return rows + [point_triangle_distance(point, *tri[int(f)]) for f in faces]


# ------------------------------------------------------------------ gaps along a tube


def min_gap(center_points, diameter: float, obstacles) -> np.ndarray:
    """Gap between the tube surface and every obstacle at every center point.

    Parameters
    ----------
    center_points : (P, 3) array
        Center-line points.
    diameter : float
        Tube diameter D.
    obstacles : sequence of Sphere, Box, Capsule, Plane, Mesh

    Returns
    -------
    (P, K) array
        Signed distance minus D/2 (negative: the tube cuts into the obstacle); meshes exact (trimesh).
    """
    p = np.atleast_2d(np.asarray(center_points, float))
    out = np.empty((len(p), len(obstacles)))
    for k, ob in enumerate(obstacles):
        out[:, k] = np.asarray(ob.distance(p), float).reshape(-1) - 0.5 * float(diameter)
    return out


@lru_cache(maxsize=64)
def curvature_bound(diameter: float, theta_max: float = math.radians(60.0), lambda_min: float = 0.0) -> float:
    """Largest center-line curvature over |theta| <= theta_max, lambda_min <= lambda <= 1 (model.center_rates).
    Cached: a grid of 362 000 evaluations, asked again by every obstacle design of the same actuator."""
    lam = np.linspace(max(lambda_min, 0.0), 1.0, 2001)
    th = np.linspace(0.0, min(theta_max, math.radians(89.0)), 181)
    kc, _, _ = center_rates(th[:, None], lam[None, :], float(diameter))
    return float(np.max(np.abs(kc)))


def dip(h: float, diameter: float, margin: float = 0.0, kappa: float | None = None, sharpness: float = 0.0) -> float:
    """How far the gap can fall between center-line samples h apart (module docstring, "Sampling rule").

    kappa: largest center-line curvature (default 2/D); sharpness: the obstacle's smallest
    radius of curvature (0 for edges and corners). inf if h >= 2 (D/2 + margin + sharpness).
    """
    r = 0.5 * float(diameter) + float(margin) + float(sharpness)
    kappa = 2.0 / float(diameter) if kappa is None else float(kappa)
    if math.isinf(sharpness):
        chord = 0.0
    elif h >= 2 * r:
        return math.inf
    else:
        chord = r - math.sqrt(r * r - 0.25 * h * h)
    sag = (1 - math.cos(0.5 * kappa * h)) / kappa if kappa > 0 else 0.0
    return chord + sag


def sample_spacing(diameter: float, margin: float = 0.0, tol: float | None = None, kappa: float | None = None,
                   sharpness: float = 0.0) -> float:
    """Largest spacing h of center-line samples (arc length) with dip(h) <= tol.

    Parameters
    ----------
    diameter, margin : float
    tol : float, optional
        Allowed drop of the gap between samples (default 1e-3 D).
    kappa : float, optional
        Largest center-line curvature (default 2/D; see :func:`curvature_bound`).
    sharpness : float
        The obstacle's smallest radius of curvature (:func:`sharpness_radius`).

    Returns
    -------
    float
        h, by bisection on :func:`dip`.
    """
    tol = 1e-3 * diameter if tol is None else float(tol)
    lo, hi = 0.0, 2 * (0.5 * diameter + margin + (0.0 if math.isinf(sharpness) else sharpness))
    if math.isinf(sharpness):
        hi = 4 * diameter
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if dip(mid, diameter, margin, kappa, sharpness) <= tol:
            lo = mid
        else:
            hi = mid
    return lo


def samples_needed(length: float, diameter: float, margin: float, obstacles, tol: float | None = None,
                   kappa: float | None = None) -> int:
    """Center-line samples needed so that the sampled gap bounds the continuous one within ``tol``.

    Parameters
    ----------
    length : float
        Arc length of the center line (the unactuated length is an upper bound).
    diameter, margin : float
    obstacles : sequence of obstacles
        The sharpest (smallest :func:`sharpness_radius`) decides.
    tol : float, optional
        Default 1e-3 D.
    kappa : float, optional
        Largest center-line curvature (default 2/D).

    Returns
    -------
    int
        Samples, both ends included, equally spaced at most :func:`sample_spacing` apart (2 without obstacles).
    """
    if not obstacles:
        return 2
    sharp = min(sharpness_radius(o) for o in obstacles)
    h = sample_spacing(diameter, margin, tol, kappa, sharp)
    return int(math.ceil(float(length) / h)) + 1


# ------------------------------------------------------------------ sampling the model


def sample_chain(routing: Routing, diameter: float, per_segment=DEFAULT_PER_SEGMENT) -> dict:
    """Center line of ``routing`` at ``per_segment`` equal pieces of every segment, base to tip.

    Parameters
    ----------
    routing : Routing
    diameter : float
    per_segment : int or (M,) ints
        Pieces per segment (default 20, as the obstacle goals are checked).

    Returns
    -------
    dict
        points (P, 3), s (actuated arc length), l (material coordinate), seg, frac; the
        segment ends are included, P = sum(per_segment) + 1.
    """
    D = float(diameter)
    th, lam, ln = routing.theta, routing.lam, routing.length
    seg, frac = segment_end_samples(ln, per_segment)
    frames = chain_frames(th, lam, ln, D, routing.initial_pose)
    pts, _ = chain_points(th, lam, ln, D, seg, frac, routing.initial_pose, frames=frames)
    _, _, lc = center_rates(th, lam, D)
    arc = ln * lc
    s = np.concatenate([[0.0], np.cumsum(arc)])[seg] + frac * arc[seg]
    l = np.concatenate([[0.0], np.cumsum(ln)])[seg] + frac * ln[seg]
    return {"points": pts, "s": s, "l": l, "seg": seg, "frac": frac}


def _points_at(routing: Routing, D: float, l, frames) -> np.ndarray:
    """(P, 3) center-line points at material lengths ``l`` (clipped to the tube), one chain evaluation."""
    cum = np.concatenate([[0.0], np.cumsum(routing.length)])
    l = np.clip(np.asarray(l, float).reshape(-1), 0.0, float(cum[-1]))
    j = np.clip(np.searchsorted(cum, l, side="right") - 1, 0, routing.segments - 1)
    pts, _ = chain_points(routing.theta, routing.lam, routing.length, D, j, (l - cum[j]) / routing.length[j],
                          routing.initial_pose, frames=frames)
    return pts


def _point_at(routing: Routing, D: float, l: float, frames) -> np.ndarray:
    return _points_at(routing, D, [l], frames)[0]


def grown_prefixes(routing: Routing, diameter: float, lengths, per_segment=DEFAULT_PER_SEGMENT) -> list[dict]:
    """Bodies grown while actuated to material lengths ``lengths``: prefixes of the final center line.

    Each: dict(length, points, s, l): the final shape's samples with l < length plus the
    exact point at l = length. Every prefix is a subset of the final line, so its gap to
    any obstacle is >= the final shape's (module docstring).
    """
    D = float(diameter)
    full = sample_chain(routing, D, per_segment)
    frames = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)
    _, _, lc = center_rates(routing.theta, routing.lam, D)
    cum_l = np.concatenate([[0.0], np.cumsum(routing.length)])
    cum_s = np.concatenate([[0.0], np.cumsum(routing.length * lc)])
    out = []
    for Lg in np.atleast_1d(np.asarray(lengths, float)):
        Lg = float(min(max(Lg, 0.0), cum_l[-1]))
        keep = full["l"] < Lg
        end = _point_at(routing, D, Lg, frames)
        out.append({
            "length": Lg,
            "points": np.vstack([full["points"][keep], end]),
            "s": np.append(full["s"][keep], np.interp(Lg, cum_l, cum_s)),
            "l": np.append(full["l"][keep], Lg),
        })
    return out


def after_growth_routing(routing: Routing, t: float) -> Routing:
    """The intermediate routing of actuation after growth: lambda_t = 1 - t (1 - lambda), theta fixed."""
    return Routing(routing.theta, 1.0 - float(t) * (1.0 - routing.lam), routing.length, routing.initial_pose)


def after_growth_shapes(routing: Routing, diameter: float, ts=None, per_segment=DEFAULT_PER_SEGMENT) -> list[dict]:
    """Center lines of the intermediate shapes of actuation after full growth, one per t.

    Parameters
    ----------
    routing : Routing
        The final routing (theta, lambda).
    diameter : float
    ts : sequence of float, optional
        Actuation fractions; default 0, 1/20, ..., 1. t = 0 is the unactuated straight
        tube (lambda_t = 1), t = 1 the final shape.
    per_segment : int or (M,) ints

    Returns
    -------
    list of dict
        One per t: t, routing (lambda_t = 1 - t (1 - lambda)), points, s, l.
    """
    ts = np.linspace(0.0, 1.0, DEFAULT_AFTER_STEPS + 1) if ts is None else np.atleast_1d(np.asarray(ts, float))
    out = []
    for t in ts:
        rt = after_growth_routing(routing, t)
        smp = sample_chain(rt, diameter, per_segment)
        out.append({"t": float(t), "routing": rt, **{k: smp[k] for k in ("points", "s", "l")}})
    return out


# ------------------------------------------------------------------ report


def _runs(mask) -> list[tuple[int, int]]:
    """Runs of True in a boolean array as (first, last) index pairs."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


REFINE_GRID = 17  # points per bracket and round of the refined minima
REFINE_ROUNDS = 8  # each round shrinks every bracket 8-fold: 8 rounds leave ~1e-7 of two sample spacings


def _refined_minima(routing, D, obstacles, l, gaps, frames) -> list[tuple[float, float]]:
    """Per obstacle, (gap, material length) of the minimum of the gap over the material interval around its
    smallest sample: a grid search whose bracket shrinks round by round to the best point's neighbours, every
    obstacle's grid in one chain evaluation per round (a search per obstacle, point by point, paid the chain's
    evaluation for every point). Never above the smallest sample."""
    n = len(l)
    idx = np.argmin(gaps, axis=0)
    best = [(float(gaps[i, k]), float(l[i])) for k, i in enumerate(idx)]
    lo = np.array([l[max(i - 1, 0)] for i in idx], float)
    hi = np.array([l[min(i + 1, n - 1)] for i in idx], float)
    live = np.flatnonzero(hi > lo)
    u = np.linspace(0.0, 1.0, REFINE_GRID)
    for _ in range(REFINE_ROUNDS):
        if live.size == 0:
            break
        x = lo[live, None] + (hi - lo)[live, None] * u  # (K, G)
        pts = _points_at(routing, D, x, frames).reshape(live.size, REFINE_GRID, 3)
        for m, k in enumerate(live):
            f = np.asarray(obstacles[k].distance(pts[m]), float).reshape(-1) - 0.5 * D
            b = int(np.argmin(f))
            if f[b] < best[k][0]:
                best[k] = (float(f[b]), float(x[m, b]))
            lo[k], hi[k] = x[m, max(b - 1, 0)], x[m, min(b + 1, REFINE_GRID - 1)]
    return best


def _shape_gaps(routing, D, obstacles, margin, smp, refine) -> list[dict]:
    gaps = min_gap(smp["points"], D, obstacles)
    frames = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose) if refine else None
    _, _, lc = center_rates(routing.theta, routing.lam, D)
    cum_l = np.concatenate([[0.0], np.cumsum(routing.length)])
    cum_s = np.concatenate([[0.0], np.cumsum(routing.length * lc)])
    out = []
    refined = _refined_minima(routing, D, obstacles, smp["l"], gaps, frames) if refine and len(obstacles) else None
    for k, ob in enumerate(obstacles):
        g = gaps[:, k]
        i = int(np.argmin(g))
        gmin, lmin = refined[k] if refine else (float(g[i]), float(smp["l"][i]))
        contacts = []
        for a, b in _runs(g < margin):
            j = a + int(np.argmin(g[a:b + 1]))
            contacts.append({
                "s": (float(smp["s"][a]), float(smp["s"][b])), "l": (float(smp["l"][a]), float(smp["l"][b])),
                "min_gap": float(g[j]), "at_s": float(smp["s"][j]),
            })
        if refine and contacts == [] and gmin < margin:
            # the refined minimum dips below the margin between two samples
            contacts.append({"s": (float(np.interp(lmin, cum_l, cum_s)),) * 2, "l": (lmin, lmin), "min_gap": gmin,
                             "at_s": float(np.interp(lmin, cum_l, cum_s))})
        out.append({
            "index": k, "kind": ob.kind, "name": ob.name, "min_gap": gmin, "l": lmin,
            "s": float(np.interp(lmin, cum_l, cum_s)), "gaps": g, "contacts": contacts,
        })
    return out


def obstacle_report(routing: Routing, diameter: float, obstacles, growth: str = "while-actuated", margin: float = 0.0,
                    per_segment=DEFAULT_PER_SEGMENT, ts=None, refine: bool = True) -> dict:
    """Distance from the tube to every obstacle along the tube, and the contacts (gap < margin).

    Final shape: sampled at ``per_segment`` points per segment, each obstacle's minimum
    refined on the continuous model (bounded 1-D search around the smallest sample).
    Intermediate shapes: grown while actuated they are prefixes (covered by the final
    shape; each obstacle's ``first_contact_length`` is the material length grown when its
    first contact appears); with growth "after", the shapes lambda_t on the grid ``ts``
    (default 21 values of t) are checked at the samples.

    Parameters
    ----------
    routing : Routing
    diameter : float
    obstacles : sequence of Sphere, Box, Capsule, Plane, Mesh
    growth : {"while-actuated", "after"}
    margin : float
        Required gap; a contact is a run of samples with gap < margin.
    per_segment : int or (M,) ints
        Samples per segment (default 20).
    ts : sequence of float, optional
        Actuation fractions for growth "after" (default 0, 0.05, ..., 1).
    refine : bool
        Refine each obstacle's minimum on the continuous final shape.

    Returns
    -------
    dict
        growth, margin, final: list per obstacle of dict(index, kind, name,
        min_gap, s, l (where), gaps (P,) per sample, contacts: list of dict(s (from, to),
        l (from, to), min_gap, at_s))), s (P,), l (P,) the final samples, min_gap (over
        all obstacles, final shape; inf without obstacles), intermediate: while-actuated:
        list per obstacle of dict(index, min_gap, first_contact_length); after: dict(t
        (T,), gaps (T, K) per-shape minima, worst: list per obstacle of dict(index,
        min_gap, t, s, l), contacts: list per t of the per-obstacle contact lists),
        min_gap_intermediate, clear (every gap >= margin - 1e-3 D, final and intermediate).

    Raises
    ------
    ValueError
        ``growth`` is not one of GROWTH_MODES.
    """
    if growth not in GROWTH_MODES:
        raise ValueError(f"growth must be one of {GROWTH_MODES}, not {growth!r}")
    D = float(diameter)
    smp = sample_chain(routing, D, per_segment)
    final = _shape_gaps(routing, D, obstacles, margin, smp, refine)
    gmin = min((f["min_gap"] for f in final), default=math.inf)
    out = {"growth": growth, "margin": float(margin), "final": final, "s": smp["s"], "l": smp["l"], "min_gap": gmin}
    if growth == "while-actuated":
        out["intermediate"] = [{
            "index": f["index"], "min_gap": f["min_gap"],
            "first_contact_length": (f["contacts"][0]["l"][0] if f["contacts"] else None),
        } for f in final]
        out["min_gap_intermediate"] = gmin
    else:
        shapes = after_growth_shapes(routing, D, ts, per_segment)
        T, K = len(shapes), len(obstacles)
        gaps = np.empty((T, K))
        worst = [{"index": k, "min_gap": math.inf, "t": None, "s": None, "l": None} for k in range(K)]
        contacts = []
        for a, sh in enumerate(shapes):
            if sh["t"] == 1.0:
                per = final
            else:
                per = _shape_gaps(sh["routing"], D, obstacles, margin, sh, False)
            contacts.append([p["contacts"] for p in per])
            for k, p in enumerate(per):
                gaps[a, k] = p["min_gap"]
                if p["min_gap"] < worst[k]["min_gap"]:
                    worst[k].update(min_gap=p["min_gap"], t=sh["t"], s=p["s"], l=p["l"])
        out["intermediate"] = {"t": np.array([sh["t"] for sh in shapes]), "gaps": gaps, "worst": worst, "contacts": contacts}
        out["min_gap_intermediate"] = float(gaps.min()) if gaps.size else math.inf
    out["clear"] = bool(min(gmin, out["min_gap_intermediate"]) >= margin - 1e-3 * D)
    return out


def obstacle_metrics(routing: Routing, diameter: float, obstacles, growth: str = "while-actuated", margin: float = 0.0,
                     per_segment=DEFAULT_PER_SEGMENT) -> dict:
    """Floats for the run's metrics attributes: ``min_obstacle_gap`` (final shape, formats.md), and
    with growth "after" also ``min_obstacle_gap_after`` (smallest over the intermediate shapes)."""
    rep = obstacle_report(routing, diameter, obstacles, growth, margin, per_segment)
    out = {"min_obstacle_gap": float(rep["min_gap"])}
    if growth == "after":
        out["min_obstacle_gap_after"] = float(rep["min_gap_intermediate"])
    return out


def report_rows(report: dict) -> list[dict]:
    """One flat row per obstacle (index, kind, name, min_gap, s, contacts, and for growth "after"
    min_gap_after, t_worst): for tables (``vine-nlp analyze``)."""
    rows = []
    for f in report["final"]:
        row = {"index": f["index"], "kind": f["kind"], "name": f["name"], "min_gap": f["min_gap"], "s": f["s"],
               "contacts": len(f["contacts"])}
        inter = report["intermediate"]
        if report["growth"] == "after":
            w = inter["worst"][f["index"]]
            row.update(min_gap_after=w["min_gap"], t_worst=w["t"])
        else:
            row.update(first_contact_length=inter[f["index"]]["first_contact_length"])
        rows.append(row)
    return rows
