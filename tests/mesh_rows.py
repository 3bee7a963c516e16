"""The mesh rows' recipe on one point, for tests: the active set of a mesh at a point, refreshed between solves
(the nearest triangles, and the exact sign), and the rows that keep the point clear (model.obstacles, "Meshes").
The design's own rows are methods.obstacles'; these show the recipe's property (tests/test_obstacles.py)."""

from __future__ import annotations

import numpy as np

from vine_nlp.model.obstacles import Mesh, _dot, _sub, _xyz, mesh_signed_distance, nearest_triangles, point_triangle_distance


def triangle_plane_distance(p, a, b, c):
    """Signed distance to the plane of triangle (a, b, c), positive along its normal (b - a) x (c - a).

    On a closed mesh wound counter-clockwise seen from outside (trimesh's convention),
    the normal points out: the row for a point found inside.
    """
    av, bv, cv = (np.asarray(v, float) for v in (a, b, c))
    n = np.cross(bv - av, cv - av)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return _dot(_sub(_xyz(p), _xyz(av)), _xyz(n))


def refresh_active_set(mesh: Mesh, points, k: int = 4) -> dict:
    """Active set for the NLP's mesh rows at the current center-line points (between solves).

    Returns dict(faces (P, k), distances (P, k) unsigned, signed (P,) exact signed distance,
    inside (P,) bool: points to constrain by the plane row of faces[:, 0] (nearest face, signed)).
    """
    faces, dists = nearest_triangles(mesh, points, k)
    signed = mesh_signed_distance(mesh, np.atleast_2d(np.asarray(points, float)))
    return {"faces": faces, "distances": dists, "signed": signed, "inside": signed < 0}


def mesh_rows(point, mesh: Mesh, faces, inside: bool = False) -> list:
    """Distance expressions of one center-line point to its active triangles (NLP rows, each >= D/2 + margin).

    ``faces``: that point's row of :func:`refresh_active_set` ``faces`` (nearest first);
    ``inside``: its ``inside`` flag, which adds the signed plane row of the nearest face
    first (nearest face, signed). numpy or CasADi ``point``.
    """
    tri = mesh.triangles
    rows = [triangle_plane_distance(point, *tri[int(faces[0])])] if inside else []
    return rows + [point_triangle_distance(point, *tri[int(f)]) for f in faces]
