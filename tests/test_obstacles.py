"""Obstacles (issue 15): distances, meshes, sampling rule, growth, report, problem files, archives, figures."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import casadi as ca
import h5py
import numpy as np
import pytest
import trimesh  # the test extra has it (and rtree, for its proximity queries)
from mesh_rows import mesh_rows, refresh_active_set, triangle_plane_distance

from vine_nlp import targets
from vine_nlp.analysis.obstacles import (
    after_growth_shapes,
    dip,
    grown_prefixes,
    min_gap,
    obstacle_metrics,
    obstacle_report,
    sample_chain,
    sample_spacing,
)
from vine_nlp.errors import InputError
from vine_nlp.io.obstacles import (
    MAX_MESH_FACES,
    load_mesh_file,
    parse_obstacle_design,
    parse_obstacles,
    read_obstacles,
    write_obstacles,
)
from vine_nlp.model.helix import center_rates
from vine_nlp.model.obstacles import (
    Box,
    Capsule,
    Mesh,
    Plane,
    Sphere,
    mesh_signed_distance,
    nearest_triangles,
    point_triangle_distance,
    rotation_from_degrees,
    sharpness_radius,
)
from vine_nlp.model.routing import Routing

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"
RNG = np.random.default_rng(15)

PRIMITIVES = [
    Sphere((1.0, -2.0, 0.5), 1.5),
    Box((0.5, 1.0, -1.0), (2.0, 3.0, 1.0), rotation_from_degrees([20.0, -35.0, 50.0])),
    Capsule((-1.0, 0.0, 0.0), (2.0, 1.0, 1.0), 0.7),
    Plane((0.0, 0.0, -1.0), (0.3, -0.2, 1.0)),
]


def _casadi_eval(ob_or_fn, points):
    x = ca.SX.sym("x", 3)
    expr = ob_or_fn(x)
    f = ca.Function("f", [x], [expr, ca.gradient(expr, x)])
    vals, grads = [], []
    for p in points:
        v, g = f(p)
        vals.append(float(v))
        grads.append(np.asarray(g, float).reshape(3))
    return np.array(vals), np.array(grads)


# ------------------------------------------------------------------ closed forms


def test_sphere_and_plane_are_exact():
    p = RNG.normal(size=(200, 3)) * 4
    s = Sphere((1.0, 2.0, 3.0), 2.0)
    np.testing.assert_allclose(s.distance(p), np.linalg.norm(p - [1, 2, 3], axis=1) - 2.0, atol=1e-12)
    pl = Plane((0.0, 0.0, 1.0), (0.0, 0.0, 5.0))  # normal normalized on construction
    np.testing.assert_allclose(pl.distance(p), p[:, 2] - 1.0, atol=1e-12)
    assert pl.normal == (0.0, 0.0, 1.0)


def test_box_known_points():
    b = Box((1.0, 2.0, 3.0), (2.0, 4.0, 6.0))  # half sizes 1, 2, 3
    c = np.array([1.0, 2.0, 3.0])
    cases = [
        (c, -1.0),  # center: nearest face is 1 away
        (c + [0.0, 0.0, 2.5], -0.5),  # inside, 0.5 below the top face
        (c + [3.0, 0.0, 0.0], 2.0),  # outside a face
        (c + [2.0, 3.0, 0.0], math.sqrt(2.0)),  # beside an edge
        (c + [-2.0, -3.0, 4.0], math.sqrt(3.0)),  # beyond a corner
        (c + [1.0, 0.5, 0.5], 0.0),  # on a face
    ]
    for p, d in cases:
        assert float(b.distance(p)) == pytest.approx(d, abs=1e-8)


def test_rotated_box_is_the_box_in_its_own_frame():
    R = rotation_from_degrees([30.0, 10.0, -70.0])
    b = Box((1.0, -1.0, 0.5), (1.0, 2.0, 3.0), R)
    local = RNG.normal(size=(300, 3)) * 2
    world = np.array(b.center) + local @ R.T
    np.testing.assert_allclose(b.distance(world), Box((0, 0, 0), (1.0, 2.0, 3.0)).distance(local), atol=1e-12)


def test_capsule_known_points():
    c = Capsule((0.0, 0.0, 0.0), (4.0, 0.0, 0.0), 1.0)
    assert float(c.distance([2.0, 3.0, 4.0])) == pytest.approx(4.0, abs=1e-12)  # beside the middle: 5 - 1
    assert float(c.distance([7.0, 4.0, 0.0])) == pytest.approx(4.0, abs=1e-12)  # beyond p1: |(3, 4)| - 1
    assert float(c.distance([-1.0, 0.0, 0.0])) == pytest.approx(0.0, abs=1e-12)  # on the end cap
    assert float(c.distance([1.0, 0.0, 0.0])) == pytest.approx(-1.0, abs=1e-8)  # on the axis


@pytest.mark.parametrize("ob", PRIMITIVES, ids=lambda o: o.kind)
def test_numpy_and_casadi_agree_and_gradients_are_right(ob):
    p = RNG.normal(size=(60, 3)) * 3
    vals, grads = _casadi_eval(ob.distance, p)
    np.testing.assert_allclose(vals, ob.distance(p), atol=1e-12, rtol=0)
    assert np.all(np.isfinite(grads))
    # away from kinks (inside only) the gradient of a distance is the finite difference
    # and a unit vector outside
    h = 1e-6
    outside = ob.distance(p) > 0.05
    for q, g in zip(p[outside], grads[outside]):
        fd = [(float(ob.distance(q + h * e)) - float(ob.distance(q - h * e))) / (2 * h) for e in np.eye(3)]
        np.testing.assert_allclose(g, fd, atol=1e-6)
        assert np.linalg.norm(g) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("ob", PRIMITIVES[:3], ids=lambda o: o.kind)
def test_gradients_finite_at_singular_points(ob):
    # sphere center, box center and surface, capsule axis: sqrt(0) is kept finite by eps
    if ob.kind == "sphere":
        special = [ob.center]
    elif ob.kind == "box":
        special = [ob.center, np.array(ob.center) + np.array(ob.rotation)[:, 0] * ob.size[0] / 2]
    else:
        special = [ob.p0, 0.5 * (np.array(ob.p0) + np.array(ob.p1))]
    vals, grads = _casadi_eval(ob.distance, np.array(special, float))
    assert np.all(np.isfinite(vals)) and np.all(np.isfinite(grads))
    x = ca.SX.sym("x", 3)
    H = ca.Function("H", [x], [ca.hessian(ob.distance(x), x)[0]])
    for q in special:
        assert np.all(np.isfinite(np.asarray(H(q), float)))


# ------------------------------------------------------------------ triangles and meshes


def test_point_triangle_distance_matches_trimesh_closest_point():
    tri = RNG.normal(size=(400, 3, 3)) * 2
    p = RNG.normal(size=(400, 3)) * 3
    closest = trimesh.triangles.closest_point(tri, p)
    want = np.linalg.norm(p - closest, axis=1)
    got = point_triangle_distance(p, tri[:, 0], tri[:, 1], tri[:, 2])
    np.testing.assert_allclose(got, want, atol=1e-9)
    for k in range(40):
        vals, grads = _casadi_eval(lambda x, k=k: point_triangle_distance(x, *tri[k]), p[k:k + 1])
        assert vals[0] == pytest.approx(got[k], abs=1e-12)
        assert np.all(np.isfinite(grads))
        # gradient of an unsigned distance: the unit vector from the closest point
        np.testing.assert_allclose(grads[0], (p[k] - closest[k]) / want[k], atol=1e-7)


def test_triangle_plane_distance_numpy_casadi():
    a, b, c = np.array([0.0, 0, 0]), np.array([2.0, 0, 0]), np.array([0.0, 3, 0])
    p = RNG.normal(size=(20, 3))
    np.testing.assert_allclose(triangle_plane_distance(p, a, b, c), p[:, 2], atol=1e-12)
    vals, _ = _casadi_eval(lambda x: triangle_plane_distance(x, a, b, c), p)
    np.testing.assert_allclose(vals, p[:, 2], atol=1e-12)


@pytest.fixture(scope="module")
def icosphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    return Mesh(m.vertices, m.faces)


def test_mesh_signed_distance_is_the_sphere_within_its_facets(icosphere):
    # the facets lie between the inscribed and the circumscribed sphere
    tri = icosphere.triangles
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inradius = float(np.min(np.abs(np.sum(n / np.linalg.norm(n, axis=1)[:, None] * tri[:, 0], axis=1))))
    tol = 2.0 - inradius
    assert 0 < tol < 0.02
    dirs = RNG.normal(size=(300, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    radii = RNG.uniform(0.2, 5.0, size=300)
    radii = radii[np.abs(radii - 2.0) > 2 * tol]
    p = dirs[: len(radii)] * radii[:, None]
    d = mesh_signed_distance(icosphere, p)
    exact = Sphere((0, 0, 0), 2.0).distance(p)
    assert np.array_equal(d > 0, exact > 0)
    np.testing.assert_allclose(d, exact, atol=tol)


def test_nearest_triangles_are_exact(icosphere):
    p = RNG.normal(size=(30, 3)) * 3
    faces, dists = nearest_triangles(icosphere, p, k=5)
    tri = icosphere.triangles
    for i in range(len(p)):
        all_d = point_triangle_distance(p[i][None], tri[:, 0], tri[:, 1], tri[:, 2])
        np.testing.assert_allclose(dists[i], np.sort(all_d)[:5], atol=1e-12)
        np.testing.assert_allclose(all_d[faces[i]], dists[i], atol=1e-12)
    # the nearest triangle's distance is the mesh's unsigned distance
    np.testing.assert_allclose(dists[:, 0], np.abs(mesh_signed_distance(icosphere, p)), atol=1e-9)


def test_refresh_active_set_flags_points_inside(icosphere):
    p = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 3.0]])
    act = refresh_active_set(icosphere, p, k=3)
    assert act["inside"].tolist() == [True, False]
    # the plane row of the nearest face is negative inside and positive outside
    a, b, c = icosphere.triangles[act["faces"][:, 0]].transpose(1, 0, 2)
    assert np.all(np.sign(triangle_plane_distance(p, a, b, c)) == [-1, 1])


def test_mesh_rows_with_refreshes_reach_the_exact_clearance():
    # the NLP recipe on one point: nearest of (target inside the bent block) at clearance r, rows
    # on the active set refreshed between solves; ends exactly r outside by the exact distance
    v, f = load_mesh_file(PROBLEMS / "data" / "bent-block.stl")
    m = Mesh(v, f)
    r = 1.5
    for target in (np.array([30.0, 12.0, 0.5]), np.array([30.0, 9.5, 0.0]), np.array([16.0, 20.0, 3.9])):
        p = target.copy()
        for _ in range(6):
            act = refresh_active_set(m, p[None], k=6)
            x = ca.SX.sym("x", 3)
            g = ca.vertcat(*mesh_rows(x, m, act["faces"][0], bool(act["inside"][0])))
            solver = ca.nlpsol("s", "ipopt", {"x": x, "f": ca.sumsqr(x - target), "g": g},
                               {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes"})
            p = np.asarray(solver(x0=p, lbg=r, ubg=np.inf)["x"]).reshape(3)
            assert solver.stats()["success"]
            exact = float(mesh_signed_distance(m, p[None])[0])
            if not act["inside"][0] and exact >= r - 1e-6:
                break
        assert exact >= r - 1e-6
        # nearest such point: on the offset surface unless the target was already clear
        assert exact == pytest.approx(max(r, float(mesh_signed_distance(m, target[None])[0])), abs=1e-5)


# ------------------------------------------------------------------ sampling rule


def test_sample_spacing_matches_dip():
    D = 2.0
    h = sample_spacing(D, 0.3, tol=1e-3 * D)
    assert dip(h, D, 0.3) == pytest.approx(1e-3 * D, rel=1e-6)
    assert dip(0.5 * D, D, 0.0) < dip(0.9 * D, D, 0.0) < math.inf
    assert dip(2.0 * D, D, 0.0) == math.inf  # a point obstacle fits between samples 2 (D/2) apart
    assert sample_spacing(D, 0.3, sharpness=sharpness_radius(Box((0, 0, 0), (1, 1, 1)))) == h  # a box's edges are sharp
    # a round obstacle allows sparser samples than a sharp one
    assert sample_spacing(D, 0.3, sharpness=sharpness_radius(Sphere((0, 0, 0), 5.0))) > h


def _straight(length, M=4, pose=None):
    return Routing(theta=np.zeros(M), lam=np.ones(M), length=np.full(M, length / M), initial_pose=np.eye(4) if pose is None else pose)


def test_dip_bounds_the_gap_between_samples():
    # random bent routings sampled ~0.6 D apart, a small ball just off the line between two samples:
    # the dense minimum gap is never below the sampled one by more than dip(h) (the routing's own
    # spacing and curvature), and the bound is not loose (some trials use over half of it)
    D = 2.0
    used = []
    for trial in range(40):
        rng = np.random.default_rng(trial)
        M = 6
        r = Routing(theta=rng.uniform(-0.6, 0.6, M), lam=rng.uniform(0.4, 1.0, M), length=rng.uniform(3.0, 8.0, M))
        coarse = sample_chain(r, D, per_segment=np.ceil(r.length / (0.6 * D)).astype(int))
        dense = sample_chain(r, D, per_segment=200)
        P = len(dense["points"])
        i = int(rng.integers(P))
        tangent = dense["points"][min(i + 1, P - 1)] - dense["points"][max(i - 1, 0)]
        n = np.cross(tangent, rng.normal(size=3))
        sph = Sphere(dense["points"][i] + n / np.linalg.norm(n) * (D / 2 + 0.25), 0.05)
        gs = float(min_gap(coarse["points"], D, [sph]).min())
        gd = float(min_gap(dense["points"], D, [sph]).min())
        h = float(np.max(np.diff(coarse["s"])))
        kc, _, _ = center_rates(r.theta, r.lam, D)
        bound = dip(h, D, gs, float(np.max(np.abs(kc))), 0.05)
        assert gd >= gs - bound - 1e-12
        used.append((gs - gd) / bound)
    assert max(used) > 0.5


# ------------------------------------------------------------------ growth and report


def test_after_growth_shapes_start_straight_and_end_final():
    D = 2.43
    r = Routing(theta=[0.3, -0.2, 0.5], lam=[0.5, 0.7, 0.6], length=[10.0, 12.0, 8.0])
    shapes = after_growth_shapes(r, D, ts=[0.0, 0.5, 1.0], per_segment=10)
    p0 = shapes[0]["points"]
    assert np.allclose(shapes[0]["routing"].lam, 1.0)
    # t = 0: the unactuated tube, straight along the base tangent x, as long as the tube
    np.testing.assert_allclose(p0[:, 1:], 0.0, atol=1e-9)
    assert p0[-1, 0] == pytest.approx(30.0, abs=1e-9)
    np.testing.assert_allclose(shapes[2]["points"], sample_chain(r, D, 10)["points"], atol=1e-12)
    np.testing.assert_allclose(shapes[1]["routing"].lam, 1 - 0.5 * (1 - r.lam))


def test_grown_prefixes_never_come_closer_than_the_final_shape():
    D = 2.43
    r = Routing(theta=[0.4, 0.4, -0.3, 0.2], lam=[0.5, 0.6, 0.5, 0.7], length=[8.0, 8.0, 8.0, 8.0])
    full = sample_chain(r, D)
    obs = [Sphere(full["points"][50] + [0, 0, 3.0], 1.0), Plane((0, 0, -2.0), (0, 0, 1))]
    final = min_gap(full["points"], D, obs).min(axis=0)
    for pre in grown_prefixes(r, D, [0.0, 5.0, 13.3, 24.0, 32.0]):
        # a prefix of the final line: same points, so at least the final gap
        keep = full["l"] <= pre["length"]
        np.testing.assert_allclose(pre["points"][: keep.sum()], full["points"][keep], atol=1e-12)
        assert np.all(min_gap(pre["points"], D, obs).min(axis=0) >= final - 1e-12)
    assert grown_prefixes(r, D, [32.0])[0]["points"][-1] == pytest.approx(full["points"][-1])


def test_obstacle_report_refines_every_minimum_between_samples():
    # straight tube along x (samples every 0.25), D = 2: a sphere of radius r centred d off the axis at x = xc, none
    # of them at a sample, has its smallest gap d - r - 1 at x = xc; the samples alone miss it by up to ~1e-3
    D = 2.0
    r = _straight(20.0)
    spheres = [(3.07, 3.0, 1.0), (10.11, 2.5, 0.5), (12.37, 4.0, 1.5), (17.9, 3.3, 0.8)]
    obs = [Sphere((xc, 0.0, d), rad) for xc, d, rad in spheres]
    rep = obstacle_report(r, D, obs)
    sampled = obstacle_report(r, D, obs, refine=False)
    for (xc, d, rad), f, g in zip(spheres, rep["final"], sampled["final"]):
        assert f["min_gap"] == pytest.approx(d - rad - 1.0, abs=1e-9)
        assert f["l"] == pytest.approx(xc, abs=1e-4)
        assert g["min_gap"] - f["min_gap"] > 1e-4  # the refinement did the work
    assert rep["min_gap"] == pytest.approx(min(d - rad - 1.0 for _, d, rad in spheres), abs=1e-9)


def test_obstacle_report_finds_a_known_contact():
    # straight tube along x, D = 2, a sphere of radius 1 at distance 3 from the axis at x = 10:
    # gap = 3 - 1 - 1 = 1 at s = 10; below margin 1.5 where |x - 10| < sqrt(3.5^2 - 9)
    D = 2.0
    r = _straight(20.0)
    ob = Sphere((10.0, 3.0, 0.0), 1.0)
    rep = obstacle_report(r, D, [ob, Plane((0, 0, -5.0), (0, 0, 1))], margin=1.5)
    f = rep["final"][0]
    assert f["min_gap"] == pytest.approx(1.0, abs=1e-7)
    assert f["s"] == pytest.approx(10.0, abs=1e-3)
    (c,) = f["contacts"]
    half = math.sqrt(3.5**2 - 9.0)
    spacing = 20.0 / 4 / 20
    assert c["s"][0] == pytest.approx(10 - half, abs=spacing) and c["s"][1] == pytest.approx(10 + half, abs=spacing)
    assert rep["final"][1]["contacts"] == [] and rep["final"][1]["min_gap"] == pytest.approx(4.0)
    assert rep["min_gap"] == pytest.approx(1.0, abs=1e-7) and rep["clear"] is False
    assert rep["intermediate"][0]["first_contact_length"] == pytest.approx(c["l"][0])
    assert obstacle_report(r, D, [ob], margin=0.5)["clear"] is True


def test_obstacle_report_after_growth_sees_the_sweep():
    # a quarter-circle-ish bend; an obstacle on the straight (t = 0) line but clear of the final shape
    D = 1.0
    r = Routing(theta=np.zeros(4), lam=np.full(4, 0.5), length=np.full(4, 5.0))
    straight_tip = 20.0
    final = sample_chain(r, D)["points"]
    assert np.linalg.norm(final[-1] - [straight_tip, 0, 0]) > 5
    ob = Sphere((straight_tip - 2.0, 0.0, 0.0), 1.0)
    rep = obstacle_report(r, D, [ob], growth="after", margin=0.0)
    assert rep["min_gap"] > 0
    assert rep["intermediate"]["worst"][0]["t"] == 0.0 and rep["min_gap_intermediate"] < 0
    assert rep["clear"] is False
    m = obstacle_metrics(rep)
    assert m["min_obstacle_gap"] == pytest.approx(rep["min_gap"]) and m["min_obstacle_gap_after"] < 0


# ------------------------------------------------------------------ problem files


def _err(tables, base=None):
    with pytest.raises(InputError) as e:
        parse_obstacles(tables, "p.toml", base)
    return f"{e.value.key}: {e.value.reason}"


BAD = [
    ({"shape": "sphere", "center": [0, 0, 0], "radius": 1, "colour": 1}, "obstacles[0].colour: unknown key"),
    ({"shape": "sphere", "center": [0, 0, 0], "raduis": 1}, "obstacles[0].raduis: unknown key; did you mean 'radius'?"),
    ({"shape": "sphere", "center": [0, 0, 0], "size": [1, 1, 1]}, "obstacles[0].size: not used by a sphere (a key of box)"),
    ({"shape": "sphere", "center": [0, 0, 0]}, "obstacles[0].radius: missing (required)"),
    ({"center": [0, 0, 0]}, "obstacles[0].shape: missing (required)"),
    ({"shape": "sphre"}, "obstacles[0].shape: must be one of 'sphere', 'box', 'capsule', 'plane', 'mesh'; did you mean 'sphere'?"),
    ({"shape": "cone"}, "obstacles[0].shape: must be one of 'sphere', 'box', 'capsule', 'plane', 'mesh'"),
    ({"shape": "sphere", "center": [0, 0, 0], "radius": 0}, "obstacles[0].radius: must be > 0"),
    ({"shape": "sphere", "center": [0, 0, 0], "radius": float("inf")}, "obstacles[0].radius: must be finite"),
    ({"shape": "sphere", "center": [0, float("nan"), 0], "radius": 1}, "obstacles[0].center: must be finite (entry 2)"),
    ({"shape": "sphere", "center": [0, 0], "radius": 1}, "obstacles[0].center: must be a list of 3 numbers"),
    ({"shape": "sphere", "center": [0, "a", 0], "radius": 1}, "obstacles[0].center: must be a list of 3 numbers"),
    ({"shape": "box", "center": [0, 0, 0], "size": [1, 0, 1]}, "obstacles[0].size: must be > 0 (entry 2)"),
    ({"shape": "box", "center": [0, 0, 0], "size": [1, 1, 1], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]},
     "obstacles[0].rotation: must be a proper rotation matrix (orthonormal rows, determinant +1, within 0.001)"),
    ({"shape": "box", "center": [0, 0, 0], "size": [1, 1, 1], "rotation": [[1, 0], [0, 1]]},
     "obstacles[0].rotation: must be a 3 x 3 matrix (a list of 3 rows of 3 numbers)"),
    ({"shape": "box", "center": [0, 0, 0], "size": [1, 1, 1], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "rotation_deg": [0, 0, 0]},
     "obstacles[0].rotation_deg: give rotation or rotation_deg, not both"),
    ({"shape": "plane", "point": [0, 0, 0], "normal": [0, 0, 0]}, "obstacles[0].normal: must not be zero"),
    ({"shape": "capsule", "p0": [1, 2, 3], "p1": [1, 2, 3], "radius": 1}, "obstacles[0].p1: must differ from p0 (for a ball use shape = \"sphere\")"),
    ({"shape": "mesh", "file": "part.step"}, "obstacles[0].file: unsupported file type '.step' (use .stl, .obj or .ply)"),
    ({"shape": "sphere", "center": [0, 0, 0], "radius": 1, "name": 3}, "obstacles[0].name: must be a string"),
]


@pytest.mark.parametrize("table,message", BAD, ids=[m.split(":")[0] + str(i) for i, (_, m) in enumerate(BAD)])
def test_parse_errors(table, message):
    good = {"shape": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}
    if message.startswith("obstacles[0]"):
        assert _err([table]) == message
    # the index counts from 0 in file order
    assert _err([good, table]) == message.replace("obstacles[0]", "obstacles[1]")


def test_parse_errors_of_the_array_and_mesh_files(tmp_path):
    assert _err({"shape": "sphere"}) == "obstacles: must be an array of tables ([[obstacles]])"
    assert _err([{"shape": "mesh", "file": "nope.stl"}], tmp_path) == f"obstacles[0].file: no such file: {tmp_path / 'nope.stl'}"
    open_mesh = trimesh.creation.icosphere(1)
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) != 0)
    open_mesh.export(tmp_path / "open.stl")
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat nonsense\n\x00\x01")
    trimesh.creation.icosphere(5).export(tmp_path / "big.stl")
    for name, reason in [
        ("open.stl", "is not closed (watertight): inside and outside are undefined"),
        ("junk.ply", None),
        ("big.stl", f"has 20480 faces; at most {MAX_MESH_FACES}"),
    ]:
        with pytest.raises(InputError) as e:
            parse_obstacles([{"shape": "mesh", "file": name}], tmp_path / "p.toml")
        assert e.value.file == str(tmp_path / name) and e.value.key == "mesh"
        if reason is None:
            assert e.value.reason.startswith("cannot read the mesh (") or e.value.reason == "no triangles"
        else:
            assert e.value.reason == reason


def test_parse_every_shape_and_mesh_orientation(tmp_path):
    inside_out = trimesh.creation.box(extents=(2, 2, 2))
    inside_out.invert()
    inside_out.export(tmp_path / "cube.obj")
    obs = parse_obstacles([
        {"shape": "sphere", "center": [0, 0, 0], "radius": 1, "name": "ball"},
        {"shape": "box", "center": [0, 0, 0], "size": [1, 2, 3], "rotation_deg": [0, 0, 90]},
        {"shape": "capsule", "p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5},
        {"shape": "plane", "point": [0, 0, 0], "normal": [0, 0, 2]},
        {"shape": "mesh", "file": "cube.obj"},
    ], tmp_path / "p.toml")
    assert [o.kind for o in obs] == ["sphere", "box", "capsule", "plane", "mesh"]
    assert obs[0].name == "ball"
    np.testing.assert_allclose(np.array(obs[1].rotation), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    # an inside-out file is turned around: the center is inside
    assert float(obs[4].distance(np.zeros((1, 3)))[0]) == pytest.approx(-1.0)
    assert obs[4].source == "cube.obj"
    # a hand-written rotation (4 digits) is accepted and made orthonormal
    (b,) = parse_obstacles([{"shape": "box", "center": [0, 0, 0], "size": [1, 1, 1],
                             "rotation": [[0.7071, -0.7071, 0], [0.7071, 0.7071, 0], [0, 0, 1]]}], "p.toml")
    np.testing.assert_allclose(np.array(b.rotation), rotation_from_degrees([0, 0, 45]), atol=1e-12)


def test_design_keys():
    assert parse_obstacle_design({}, "p.toml") == (0.0, "while-actuated")
    assert parse_obstacle_design({"obstacle_margin": 0.3, "growth": "after"}, "p.toml") == (0.3, "after")
    for table, message in [
        ({"obstacle_margin": -0.1}, "design.obstacle_margin: must be >= 0"),
        ({"obstacle_margin": "1"}, "design.obstacle_margin: must be a number"),
        ({"obstacle_margin": float("nan")}, "design.obstacle_margin: must be finite"),
        ({"growth": "later"}, "design.growth: must be one of 'while-actuated', 'after'"),
    ]:
        with pytest.raises(InputError) as e:
            parse_obstacle_design(table, "p.toml")
        assert f"{e.value.key}: {e.value.reason}" == message


# ------------------------------------------------------------------ archives


def _all_shapes(icosphere):
    return [PRIMITIVES[0], PRIMITIVES[1], PRIMITIVES[2], Plane((0, 0, 1.0), (0, 1.0, 0), name="floor"),
            Mesh(icosphere.vertices, icosphere.faces, source="ball.stl")]


def test_archive_round_trip(tmp_path, icosphere):
    obs = _all_shapes(icosphere)
    with h5py.File(tmp_path / "a.h5", "w") as h5:
        write_obstacles(h5.create_group("obstacles"), obs)
    with h5py.File(tmp_path / "a.h5", "r") as h5:
        assert h5["obstacles/1"].attrs["shape"] == "box" and h5["obstacles/4/vertices"].shape == icosphere.vertices.shape
        back = read_obstacles(h5["obstacles"], tmp_path / "a.h5")
    assert back == obs


@pytest.mark.parametrize("damage,key,reason", [
    (lambda g: g["0"].attrs.__delitem__("shape"), "/obstacles/0", "missing attribute 'shape'"),
    (lambda g: g["0"].attrs.__setitem__("shape", "cone"), "/obstacles/0", "unknown shape 'cone'"),
    (lambda g: g["0"].__delitem__("radius"), "/obstacles/0/radius", "missing"),
    (lambda g: (g["2"].__delitem__("p0"), g["2"].create_dataset("p0", data=[1.0, 2.0])), "/obstacles/2/p0", "must have shape (3,), got (2,)"),
    (lambda g: (g["0"].__delitem__("radius"), g["0"].create_dataset("radius", data=-1.0)), "/obstacles/0", "radius must be > 0"),
    (lambda g: (g["1"].__delitem__("rotation"), g["1"].create_dataset("rotation", data=2 * np.eye(3))), "/obstacles/1",
     "rotation must be a proper rotation matrix (orthonormal, det 1)"),
    (lambda g: (g["4"].__delitem__("faces"), g["4"].create_dataset("faces", data=np.full((5, 3), 9999))), "/obstacles/4",
     "faces must be a (F, 3) array of vertex indices, F >= 4"),
    (lambda g: g.move("3", "7"), "/obstacles", "groups must be numbered 0 to 4"),
])
def test_archive_read_validates(tmp_path, icosphere, damage, key, reason):
    path = tmp_path / "a.h5"
    with h5py.File(path, "w") as h5:
        write_obstacles(h5.create_group("obstacles"), _all_shapes(icosphere))
        damage(h5["obstacles"])
    with h5py.File(path, "r") as h5, pytest.raises(InputError) as e:
        read_obstacles(h5["obstacles"], path)
    assert (e.value.file, e.value.key, e.value.reason) == (str(path), key, reason)


# ------------------------------------------------------------------ bundled problems


BUNDLED = ["obstacle-gap", "obstacle-pipe-bend", "obstacle-wrap-cylinder", "obstacle-tip-wall", "obstacle-mesh"]


@pytest.mark.parametrize("name", BUNDLED)
def test_bundled_obstacle_problems_parse(name):
    path = PROBLEMS / f"{name}.toml"
    data = tomllib.loads(path.read_text())
    obs = parse_obstacles(data["obstacles"], path)
    margin, growth = parse_obstacle_design(data["design"], path)
    assert obs and margin > 0 and growth in ("while-actuated", "after")
    if "target" in data:
        # the problems mean something: the target comes closer to some obstacle than the margin
        t = dict(data["target"])
        pts = getattr(targets, t.pop("curve"))(**t)
        assert min_gap(pts, data["tube"]["diameter"], obs).min() < margin


def test_bundled_mesh_is_the_script_output():
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_obstacle_mesh", PROBLEMS / "data" / "make_obstacle_mesh.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    made = mod.bent_block()
    v, f = load_mesh_file(PROBLEMS / "data" / "bent-block.stl")
    assert len(f) == len(made.faces) == 360
    # STL stores float32 coordinates
    assert Mesh(v, f).trimesh.volume == pytest.approx(made.volume, rel=1e-5)
    np.testing.assert_allclose(np.sort(v, axis=0), np.sort(made.vertices, axis=0), atol=1e-5)


# ------------------------------------------------------------------ figures


def test_draw_obstacles_cuts_walls_to_the_view(icosphere):
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from vine_nlp.front.plot import _halfspace_polytope, draw_obstacles

    A = np.vstack([np.eye(3), -np.eye(3)])
    pts, tris = _halfspace_polytope(A, np.ones(6))
    assert len(pts) == 8 and np.allclose(np.abs(pts), 1.0) and len(tris) == 12
    assert _halfspace_polytope(A, np.r_[np.ones(3), -2 * np.ones(3)]) is None  # empty

    fig = Figure()
    ax = fig.add_subplot(projection="3d")
    view = (np.array([-5.0, -5, -5]), np.array([5.0, 5, 5]))
    obs = [Box((0, 0, 0), (2, 100, 2)), Plane((0, 0, -1.0), (0, 0, 1)), Sphere((3, 3, 3), 1), Capsule((0, 0, 0), (1, 1, 1), 0.2),
           Mesh(icosphere.vertices, icosphere.faces), Box((50, 50, 50), (1, 1, 1))]
    drawn = draw_obstacles(ax, obs, view=view)
    assert len(drawn) == 5  # the far box is outside the view
    polys = [c for c in ax.collections if isinstance(c, Poly3DCollection)]
    assert len(polys) >= 3
    wall, floor = drawn[0], drawn[1]
    assert wall[:, 1].min() == pytest.approx(-5) and wall[:, 1].max() == pytest.approx(5)  # cut to the view
    assert floor[:, 2].max() == pytest.approx(-1) and floor[:, 2].min() == pytest.approx(-5)
