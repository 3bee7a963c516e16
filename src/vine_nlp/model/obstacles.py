"""Obstacle shapes and their signed distances: ONE formula per shape for numpy and CasADi.

Shapes (frozen value types, each with a ``kind`` name): :class:`Sphere`, :class:`Box`, :class:`Capsule`, :class:`Plane`
and :class:`Mesh`. The tube of diameter D clears an obstacle by ``gap = distance(center line, obstacle) - D/2``.

Signed distances (positive outside, negative inside, in the obstacle's units)
---------------------------------------------------------------------------
Every primitive's distance is written once against ``vine_nlp.model.ops.lib``: a numpy point array (..., 3) gives an
array (...); a CasADi 3x1 (or 3xN) SX/MX gives a 1x1 (1xN) expression. All four primitives are convex, and the distance
to a convex set is C^1 (indeed C^{1,1}) everywhere outside the set: the only kinks of the exact formulas (the clamp of
the capsule's segment parameter, the box's max/abs) either cancel outside (the clamped parameter sits where the distance
along the segment is stationary; the box's |x| kink lies where its max(q, 0) is identically 0) or lie inside (medial
axis). The NLP's rows ask for distance >= D/2 + margin > 0, so every feasible point lies where the row is C^1.

``sqrt`` at 0 (the sphere's center, the capsule's axis, the box's surface seen from its exterior term) has an infinite
derivative, and CasADi's ``if_else`` and ``fmax`` differentiate every branch: every sqrt here is ``sqrt(x + eps^2)``
with eps = ``EPS_REL`` (1e-9) times the obstacle's size. The value then differs from the exact distance d by at most
eps^2 / (2 d): below 1e-18 of the size at d of the order of the size, at most eps at d = 0; gradients stay finite
(Hessians are large, ~1/eps, only within eps of the singular set, which is inside).

Sphere, box and capsule are one formula, a rounded box (:func:`rounded_box_distance`: a box, possibly flat or a point,
rounded by a radius), whose parameters may be symbolic: the NLP's rows take them as data (``Obstacle.rounded_box()``),
so one block serves every primitive. A plane's own formula is its half-space distance; its rows take it as a box
PLANE_HALF deep behind it and as wide (exact within ~1e-10 of the obstacle's units).

Meshes. The exact signed distance of a closed triangle mesh (numpy only) is trimesh's
(``trimesh.proximity.signed_distance``, positive *inside*: negated here). For the NLP, the sign of a mesh's distance is
a global property (inside or outside) that no finite set of smooth per-triangle expressions gives, so the rows are the
*unsigned* exact distance to each triangle of an active set (:func:`nearest_triangles`, refreshed between solves;
:func:`point_triangle_distance`, whose vertices may be symbolic data): a triangle is convex, so its distance is C^1
wherever it is positive, continuous everywhere, and the mesh's unsigned distance is the minimum over its triangles, so
rows over the nearest triangles are exact rows, not an approximation. What they cannot see is a point deeper inside than
the clearance: the NLP gives such points a row on the plane of a face instead (methods.obstacles).
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
PLANE_HALF = 1e6  # a plane's rows take it as a box this deep behind it and this wide (module docstring)
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


def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _all3(x, y, z):
    if is_symbolic(x, y, z):
        return ca.logic_and(ca.logic_and(x, y), z)
    return np.logical_and(np.logical_and(x, y), z)


def _lib(*args):
    return lib(*[a for a in args if a is not None])


# ------------------------------------------------------------------ primitive distances


def rounded_box_distance(p, center, rotation, half, radius=0.0, eps=0.0):
    """Signed distance from ``p`` to a box (``center``, world-from-box ``rotation``, ``half`` edge lengths)
    rounded by ``radius``: with q = |R^T (p - c)| - half, sqrt(|max(q, 0)|^2 + eps^2) + min(max q, 0) - radius.

    The exact distance (up to eps: module docstring) of a box (radius 0), a sphere (a point: half 0, R = I)
    and a capsule (a segment along the box's first axis). Outside it is C^1 (distance to a convex set):
    where a local coordinate crosses 0 (|.| kink), that q is -half < 0 and clamped away; the max q kinks
    (medial axis) and the exterior/interior switch are inside or on the surface. Any argument may be CasADi
    (the NLP's rows take the parameters as data); numpy points (..., 3), CasADi 3 x N."""
    w = _sub(_xyz(p), _xyz(center))
    L = _lib(*w)
    local = [w[0] * rotation[0, i] + w[1] * rotation[1, i] + w[2] * rotation[2, i] for i in range(3)]
    q = [L.fabs(local[i]) - half[i] for i in range(3)]
    o = [L.fmax(qi, 0.0) for qi in q]
    outside = L.sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + eps * eps)
    inside = L.fmin(L.fmax(q[0], L.fmax(q[1], q[2])), 0.0)
    return outside + inside - radius


def plane_distance(p, point, normal):
    """Signed distance to the half-space behind the plane: n . (p - point), n normalized; positive on the free side."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    return _dot(_sub(_xyz(p), _xyz(point)), _xyz(n))


def _frame(axis) -> np.ndarray:
    """A rotation whose first column is the unit vector ``axis``."""
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.column_stack([axis, e1, np.cross(axis, e1)])


def _segment_d2(p, a, b):
    ab, ap = _sub(b, a), _sub(p, a)
    L = _lib(*ap)
    t = L.fmin(L.fmax(_dot(ap, ab) / _dot(ab, ab), 0.0), 1.0)
    diff = (ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2])
    return _dot(diff, diff)


def point_triangle_distance(p, a, b, c, eps=None):
    """Unsigned exact distance from ``p`` to the triangle (a, b, c), numpy (vectorized) or CasADi.

    If the projection of p onto the triangle's plane falls inside the triangle (barycentric weights >= 0), the plane
    distance; otherwise the nearest of the three edges (segments). A triangle is convex, so the distance is C^1 wherever
    it is > 0; both branches agree (value and gradient) on the switch (the prism's side walls), and the three edge
    distances tie only where they share a vertex region. numpy: p (..., 3) with a, b, c (..., 3) broadcast against it;
    CasADi: any argument (the NLP's rows take the vertices as data). sqrt(d^2 + eps^2): ``eps`` default EPS_REL times
    the longest edge (numpy). Triangles must not be degenerate (zero area)."""
    P, A, B, C = _xyz(p), _xyz(a), _xyz(b), _xyz(c)
    ab, ac, ap = _sub(B, A), _sub(C, A), _sub(P, A)
    L = _lib(*P, *A, *B, *C)
    n = _cross(ab, ac)
    nn = _dot(n, n)
    if not is_symbolic(*A, *B, *C) and np.any(nn <= 0):
        raise ValueError("degenerate triangle (zero area)")
    w_b = _dot(ap, _cross(ac, n)) / nn
    w_c = _dot(ap, _cross(n, ab)) / nn
    inside = _all3(w_b >= 0, w_c >= 0, 1 - w_b - w_c >= 0)
    h2 = _dot(ap, n) ** 2 / nn
    edges = L.fmin(_segment_d2(P, A, B), L.fmin(_segment_d2(P, B, C), _segment_d2(P, C, A)))
    if eps is None:
        eps = EPS_REL * float(np.sqrt(np.max(_dot(ab, ab))))
    return L.sqrt(L.where(inside, h2, edges) + eps**2)


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


class _RoundedBox:
    """A shape whose distance is :func:`rounded_box_distance` with the parameters of its ``rounded_box()``."""

    def distance(self, p):
        return rounded_box_distance(p, *self.rounded_box())


@dataclass(frozen=True)
class Sphere(_RoundedBox):
    center: tuple
    radius: float
    name: str = ""
    kind: ClassVar[str] = "sphere"

    def __post_init__(self):
        object.__setattr__(self, "center", _tuple3(self.center, "center"))
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError("radius must be > 0")
        object.__setattr__(self, "radius", float(self.radius))

    def rounded_box(self) -> tuple:
        """(center, rotation, half sizes, radius, eps) of :func:`rounded_box_distance`: a point rounded by the radius."""
        return np.array(self.center), np.eye(3), np.zeros(3), self.radius, EPS_REL * self.radius

    def parameters(self) -> dict:
        return {"center": np.array(self.center), "radius": np.float64(self.radius)}

    def scaled(self, f: float) -> "Sphere":
        return Sphere(tuple(f * np.array(self.center)), f * self.radius, self.name)

    def bounds(self):
        c = np.array(self.center)
        return c - self.radius, c + self.radius


@dataclass(frozen=True)
class Box(_RoundedBox):
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

    def rounded_box(self) -> tuple:
        """(center, rotation, half sizes, radius, eps) of :func:`rounded_box_distance`: the box itself."""
        return np.array(self.center), np.array(self.rotation), 0.5 * np.array(self.size), 0.0, EPS_REL * float(np.linalg.norm(self.size))

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
class Capsule(_RoundedBox):
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

    def rounded_box(self) -> tuple:
        """(center, rotation, half sizes, radius, eps) of :func:`rounded_box_distance`: a segment along the first axis."""
        a, b = np.array(self.p0), np.array(self.p1)
        length = float(np.linalg.norm(b - a))
        return 0.5 * (a + b), _frame((b - a) / length), np.array([0.5 * length, 0.0, 0.0]), self.radius, EPS_REL * max(self.radius, length)

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

    def rounded_box(self) -> tuple:
        """(center, rotation, half sizes, radius, eps) of :func:`rounded_box_distance`: a box PLANE_HALF deep behind
        the plane and as wide, the NLP's rows' form of a plane (module docstring)."""
        n = np.array(self.normal)
        return np.array(self.point) - PLANE_HALF * n, _frame(n), np.full(3, PLANE_HALF), 0.0, EPS_REL

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
        v, f = np.array(self.vertices, dtype=float), np.array(self.faces, dtype=np.int64)
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
    # trimesh: positive inside, negative outside; in chunks: its candidate pairs (up to points x faces) stay below ~2e5
    step = max(1, 200_000 // max(1, len(mesh.faces)))
    d = np.concatenate([-np.asarray(trimesh.proximity.signed_distance(mesh.trimesh, flat[i:i + step]), float)
                        for i in range(0, len(flat), step)] or [np.empty(0)])
    return d.reshape(p.shape[:-1])


def nearest_triangles(mesh: Mesh, points, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` triangles nearest to each point (exact unsigned distances): the active set.

    Returns (faces (P, k) face indices, nearest first; distances (P, k)). Exact: candidates come from a k-d tree on the
    centroids, and every triangle that could be nearer than the k-th candidate (centroid closer than that distance plus
    the largest centroid-to-vertex radius) is measured too."""
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
