"""Obstacle shapes and their signed distances: ONE formula per shape for numpy and CasADi.

Shapes (frozen value types, each with a ``kind`` name): :class:`Sphere`,
:class:`Box`, :class:`Capsule`, :class:`Plane` and :class:`Mesh`. The tube of
diameter D clears an obstacle by ``gap = distance(center line, obstacle) - D/2``.

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.model.ops import is_symbolic, lib

EPS_REL = 1e-9  # sqrt(x + eps^2), eps = EPS_REL * size: module docstring
SHAPES = ("sphere", "box", "capsule", "plane", "mesh")


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
