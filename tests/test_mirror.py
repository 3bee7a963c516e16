"""Mirror images (issue 33): a problem and its mirror image get mirror-image designs."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import model_target

import vine_nlp as vn
from vine_nlp import targets
from vine_nlp.methods.mirror import M3, handedness, mirrored_obstacle, mirrored_problem, mirrored_routing
from vine_nlp.model import shape_lines
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.obstacles import Box, Capsule, Mesh, Plane, Sphere
from vine_nlp.problem import DesignOptions, DesignProblem

OBSTACLES = (Sphere((1.0, 2.0, 3.0), 1.5), Box((1.0, -2.0, 0.5), (1.0, 2.0, 3.0), ((0.6, -0.8, 0.0), (0.8, 0.6, 0.0), (0.0, 0.0, 1.0))),
             Capsule((0.0, 1.0, 2.0), (3.0, -1.0, 0.0), 0.5), Plane((0.0, 0.5, -1.0), (0.0, 0.6, 0.8)))


def _same_design(a, b, atol=0.0):
    """``b`` is the mirror image of ``a`` (routing, base pose, shape): bit for bit, one is solved as the other."""
    m = mirrored_routing(a.routing)
    np.testing.assert_allclose(m.theta, b.routing.theta, rtol=0, atol=atol)
    np.testing.assert_allclose(m.lam, b.routing.lam, rtol=0, atol=atol)
    np.testing.assert_allclose(m.length, b.routing.length, rtol=0, atol=atol)
    np.testing.assert_allclose(m.initial_pose, b.routing.initial_pose, rtol=0, atol=atol)
    np.testing.assert_allclose(a.shape.center @ M3, b.shape.center, rtol=0, atol=atol)
    assert a.metrics["rmse"] == pytest.approx(b.metrics["rmse"], rel=1e-9, abs=1e-15)


def test_the_mirror_of_a_routing_models_the_mirrored_shape_exactly():
    _, r = model_target(seed=3)
    seg, frac = segment_end_samples(r.length, 5)
    m = mirrored_routing(r)
    for a, b in zip(shape_lines(r.theta, r.lam, r.length, 2.0, seg, frac, r.initial_pose),
                    shape_lines(m.theta, m.lam, m.length, 2.0, seg, frac, m.initial_pose)):
        assert np.array_equal(a @ M3, b)


def test_mirror_images_of_obstacles_and_problems_are_exact_and_flip_the_handedness():
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=1, radius=2.0)
    mesh = Mesh(ball.vertices + [1.0, 2.0, 0.5], ball.faces)
    p = np.random.default_rng(0).normal(size=(50, 3)) * 3
    for ob in OBSTACLES + (mesh,):
        # exact for the primitives; a mesh's distance to rounding (the mirror reverses each face's winding)
        np.testing.assert_allclose(mirrored_obstacle(ob).distance(p @ M3), ob.distance(p), rtol=0, atol=0 if ob is not mesh else 1e-12)
        assert mirrored_obstacle(mirrored_obstacle(ob)) == ob
    target, _ = model_target(seed=4)
    pb = DesignProblem("t", 2.0, target, obstacles=OBSTACLES)
    mp = mirrored_problem(pb)
    assert np.array_equal(mp.target, target @ M3) and handedness(pb) in (-1.0, 1.0) and handedness(mp) == -handedness(pb)
    back = mirrored_problem(mp)
    assert np.array_equal(back.target, pb.target) and back.obstacles == pb.obstacles
    # a planar target (no handedness of its own): the side of y = 0 decides; its own mirror: nothing does
    line = targets.bezier([[0, 0, 0], [4, 2, 0], [8, -1, 0], [12, 0, 0]], samples=40)
    flat = DesignProblem("t", 2.0, line)
    assert handedness(mirrored_problem(flat)) == -handedness(flat) != 0
    assert handedness(DesignProblem("t", 2.0, line[:, [0, 2, 1]])) == 0


def test_obstacle_free_designs_of_mirror_images_are_mirror_images():
    target, _ = model_target(M=8, seed=5)
    pb = DesignProblem("t", 2.0, target, options=DesignOptions(points_per_segment=5))
    a, b = (vn.solve(p).result for p in (pb, mirrored_problem(pb)))
    assert a.converged and a.metrics["rmse"] < 0.01  # D = 2: the buildable design of a model shape
    _same_design(a, b)
    assert a.stats.get("solved_mirrored", False) != b.stats.get("solved_mirrored", False)  # one of them solved as the other


def test_obstacle_designs_of_mirror_images_are_mirror_images():
    # the target bends in 3-D past a sphere on its concave side: the free design cuts into it
    target = targets.bezier([[0, 0, 0], [8, 0, 1], [16, 3, -1], [24, 0, 0]], samples=61)
    pb = DesignProblem("t", 1.0, target, options=DesignOptions(points_per_segment=10), obstacles=(Sphere((12.0, 0.8, 0.0), 2.0),),
                       obstacle_margin=0.2)
    da, db = (vn.solve(p) for p in (pb, mirrored_problem(pb)))
    a, b = da.result, db.result
    assert a.stats["obstacle_rounds"] > 0 and a.ok and b.ok
    _same_design(a, b)
    _same_design(da.runs["nlp_no_obstacles"].result, db.runs["nlp_no_obstacles"].result)
