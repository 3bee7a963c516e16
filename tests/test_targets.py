"""Target curves (paper Sec. VII): trefoil eq. (knot), Bezier, polyline, helix eq. (Helix)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vine_nlp import targets

BEZIER_A = [[0, 0, 0], [76, 0, 0], [-4, 19, 42], [34, -52, 13], [16, 19, 48]]
BEZIER_C = [[0, 0], [50, 0], [24, -24], [0, -50], [50, -50]]


def _knot(t, m):
    return np.array([m[0] * (math.sin(t) + 2 * math.sin(2 * t)), m[1] * (math.cos(t) - 2 * math.cos(2 * t)), -m[2] * math.sin(3 * t)])


def test_trefoil_defaults_are_the_papers():
    p = targets.trefoil()
    assert p.shape == (400, 3)
    np.testing.assert_allclose(p[0], _knot(-0.2 * math.pi, (4, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(p[-1], _knot(1.5 * math.pi, (4, 4, 4)), atol=1e-12)
    # about 100 cm long for m = 4 cm (the paper quotes 980 mm)
    assert 95 < targets.arc_length(p)[-1] < 105


def test_trefoil_points_are_equally_spaced_in_t():
    p = targets.trefoil((1, 2, 3), (0.0, 2.0), samples=21)
    for i, t in enumerate(np.linspace(0.0, 2.0, 21)):
        np.testing.assert_allclose(p[i], _knot(t, (1, 2, 3)), atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.tuples(*[st.floats(-10, 10)] * 3))
def test_trefoil_scales_each_axis(m):
    np.testing.assert_allclose(targets.trefoil(m, samples=50), targets.trefoil((1, 1, 1), samples=50) * np.array(m), atol=1e-12)


@pytest.mark.parametrize("control", [BEZIER_A, BEZIER_C])
def test_bezier_endpoints_are_the_end_control_points(control):
    p = targets.bezier(control, 400)
    c = np.array(control, dtype=float)
    assert p.shape == (400, 3)
    np.testing.assert_allclose(p[0][: c.shape[1]], c[0], atol=1e-12)
    np.testing.assert_allclose(p[-1][: c.shape[1]], c[-1], atol=1e-12)
    if c.shape[1] == 2:
        assert np.all(p[:, 2] == 0)


def _de_casteljau(control, t):
    p = np.array(control, dtype=float)
    while len(p) > 1:
        p = (1 - t) * p[:-1] + t * p[1:]
    return p[0]


def test_bezier_matches_de_casteljau_at_equally_spaced_t():
    p = targets.bezier(BEZIER_A, 11)
    for i, t in enumerate(np.linspace(0, 1, 11)):
        np.testing.assert_allclose(p[i], _de_casteljau(BEZIER_A, t), atol=1e-10)


def test_polyline_samples_are_equally_spaced_in_arc_length():
    # L-shape 3 + 4 long: spacing 0.5 puts a sample exactly on the corner.
    p = targets.polyline([[0, 0], [3, 0], [3, 4]], samples=15)
    expected = [[x, 0, 0] for x in np.arange(0, 3.01, 0.5)] + [[3, y, 0] for y in np.arange(0.5, 4.01, 0.5)]
    np.testing.assert_allclose(p, expected, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(*[st.integers(-20, 20)] * 3), min_size=2, max_size=6), st.integers(3, 60))
def test_polyline_endpoints_and_spacing(control, samples):
    c = np.array(control, dtype=float)
    if np.all(c == c[0]):
        with pytest.raises(ValueError):
            targets.polyline(c, samples)
        return
    p = targets.polyline(c, samples)
    step = targets.arc_length(c)[-1] / (samples - 1)
    np.testing.assert_allclose(p[0], c[0])
    np.testing.assert_allclose(p[-1], c[-1])
    # chords are at most the arc-length spacing (shorter only across a corner)
    assert np.all(np.diff(targets.arc_length(p)) <= step * (1 + 1e-9))


def test_polyline_of_collinear_points_is_uniform():
    p = targets.polyline([[0, 0, 0], [1, 1, 1], [1, 1, 1], [5, 5, 5]], samples=9)
    d = np.linalg.norm(np.diff(p, axis=0), axis=1)
    np.testing.assert_allclose(d, d[0])


@pytest.mark.parametrize("radius, pitch", [(3.0, 1.2), (2.0, -0.5), (0.0, 1.0), (1.5, 0.0)])
def test_helix_radius_pitch_and_length(radius, pitch):
    length = 60.0
    p = targets.helix(radius, pitch, length, samples=2001)
    np.testing.assert_allclose(p[0], 0, atol=1e-15)
    # axis: x = 0, y = -R, along z
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1] + radius), radius, atol=1e-12)
    d = np.linalg.norm(np.diff(p, axis=0), axis=1)
    np.testing.assert_allclose(d, d[0], rtol=1e-9)
    assert targets.arc_length(p)[-1] == pytest.approx(length, rel=1e-4)  # chords of a curve are a little shorter
    if radius > 0:
        angle = np.unwrap(np.arctan2(p[:, 0], p[:, 1] + radius))
        turns = (angle - angle[0]) / (2 * np.pi)
        np.testing.assert_allclose(p[:, 2], 2 * np.pi * pitch * turns, atol=1e-9)


@pytest.mark.parametrize("args", [(0.0, 0.0, 10.0), (-1.0, 1.0, 10.0), (1.0, 1.0, 0.0)])
def test_helix_rejects_degenerate_input(args):
    with pytest.raises(ValueError):
        targets.helix(*args)


def test_check_points_accepts_2d_and_returns_float_3d():
    p = targets.check_points([[0, 0], [1, 0], [0, 0]])  # revisiting a point is fine, just not consecutively
    assert p.shape == (3, 3) and p.dtype == float and np.all(p[:, 2] == 0)


@pytest.mark.parametrize(
    "points, reason",
    [
        ([[0, 0, 0], [1, 0, 0]], "needs at least 3 points, got 2"),
        ([[0, 0, 0], [1, 0, 0], [2, np.nan, 0]], "point 3 is not finite"),
        ([[0, 0, 0], [1, 0, 0], [1, 0, 0]], "points 2 and 3 are identical"),
        ([1, 2, 3], "points must be an N x 3 (or N x 2) array, got shape (3,)"),
        ([[0, 0, 0, 0]] * 3, "points must be an N x 3 (or N x 2) array, got shape (3, 4)"),
        ([[0, 0], [1, 2, 3]], "points must be an N x 3 (or N x 2) array of numbers"),
        ([["a", "b", "c"]] * 3, "points must be an N x 3 (or N x 2) array of numbers"),
    ],
)
def test_check_points_reasons(points, reason):
    with pytest.raises(ValueError) as info:
        targets.check_points(points)
    assert str(info.value) == reason


def test_arc_length():
    s = targets.arc_length([[0, 0, 0], [3, 4, 0], [3, 4, 2]])
    np.testing.assert_allclose(s, [0, 5, 7])
