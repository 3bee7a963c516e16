"""The geometric model: closed forms against the chain, the paper's numbers, finiteness."""

import math

import casadi as ca
import numpy as np
import pytest
from paper_model import line_offset_angles, paper_segment_transform

from vine_nlp.model import (
    center_rates,
    chain_frames,
    helix_forward,
    helix_inverse,
    helix_self_collides,
    phi_from_theta,
    segment_transform,
    shape_lines,
)
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.helix import helix_from_curvature, helix_turns

rng = np.random.default_rng(1)
CASES = [(math.radians(t), lam, D) for t, lam, D in [
    (10, 0.7, 2.62), (-10, 0.7, 2.62), (2.5, 0.4, 2.62), (50, 0.75, 2.62), (59.9, 0.45, 3.3),
    (-59.9, 0.9, 1.0), (30, 0.99, 4.77), (-45, 0.5, 2.43), (1e-3, 0.95, 2.0), (0.0, 0.6, 2.0),
]]


def test_paper_check_value_pitch():
    # Paper check value (model notes): theta 2.5 deg, lambda 0.4, D 2.62 cm -> b = 0.252 cm.
    h = helix_forward(math.radians(2.5), 0.4, 2.62)
    assert h.b == pytest.approx(0.252, abs=5e-4)


@pytest.mark.parametrize("theta,lam,D", CASES)
def test_table_identities(theta, lam, D):
    h = helix_forward(theta, lam, D)
    assert h.R_o - h.R_i == pytest.approx(D)
    assert h.R_c == pytest.approx(0.5 * (h.R_o + h.R_i))
    # curvature/torsion form of Table I against the R, b form (eq. Rb_to_kT)
    for R, k, t in [(h.R_o, h.kappa_o, h.tau_o), (h.R_i, h.kappa_i, h.tau_i), (h.R_c, h.kappa_c, h.tau_c)]:
        assert k == pytest.approx(R / (R**2 + h.b**2), rel=1e-12, abs=1e-12)
        assert t == pytest.approx(h.b / (R**2 + h.b**2), rel=1e-12, abs=1e-12)
    # the outer line keeps its length (model notes)
    lc = math.sqrt(h.b**2 + h.R_c**2) / (math.sqrt(h.b**2 + h.R_o**2) * math.cos(theta))
    assert h.lambda_c == pytest.approx(lc, rel=1e-12)
    # eq. act_len_constraint
    assert math.sqrt(h.b**2 + h.R_i**2) / math.sqrt(h.b**2 + h.R_o**2) == pytest.approx(lam)


@pytest.mark.parametrize("theta,lam,D", CASES)
def test_inverse_of_forward_is_identity(theta, lam, D):
    h = helix_forward(theta, lam, D)
    t2, l2, d2 = helix_inverse(h.R_o, h.R_i, h.b)
    assert (t2, l2, d2) == pytest.approx((theta, lam, D), abs=1e-12)
    t3, l3 = helix_from_curvature(h.kappa_c, h.tau_c, D)
    assert (t3, l3) == pytest.approx((theta, lam), abs=1e-12)


def test_inverse_straight_tube():
    assert helix_from_curvature(0.0, 0.0, 2.0) == (0.0, 1.0)


def test_vectorized_over_designs():
    th = rng.uniform(-1, 1, (4, 5))
    lam = rng.uniform(0.4, 1, (4, 5))
    h = helix_forward(th, lam, 2.0)
    assert h.kappa_c.shape == (4, 5)
    assert h.b[2, 3] == pytest.approx(helix_forward(th[2, 3], lam[2, 3], 2.0).b)
    T = segment_transform(th, lam, 3.0, 2.0)
    assert T.shape == (4, 5, 4, 4)
    np.testing.assert_allclose(T[1, 2], segment_transform(th[1, 2], lam[1, 2], 3.0, 2.0), atol=1e-14)


def test_straight_tube_lambda_one():
    # lambda = 1: kappa_c = 0, tau_c = 2 tan(theta)/D, lambda_c = 1 (model notes)
    th = np.radians([-40, -5, 0, 5, 40])
    k, t, lc = center_rates(th, 1.0, 2.5)
    np.testing.assert_allclose(k, 0, atol=1e-15)
    np.testing.assert_allclose(t, 2 * np.tan(th) / 2.5, rtol=1e-13)
    np.testing.assert_allclose(lc, 1, rtol=1e-14)
    # the chain is straight with the unactuated length and its frame turns by 2 tan(theta)/D per length
    for theta in th:
        frames = chain_frames(np.full(7, theta), 1.0, np.full(7, 1.5), 2.5)
        np.testing.assert_allclose(frames[-1, :3, 3], [10.5, 0, 0], atol=1e-12)
        turn = math.atan2(frames[-1, 2, 1], frames[-1, 1, 1])
        expect = (2 * math.tan(theta) / 2.5 * 10.5 + math.pi) % (2 * math.pi) - math.pi
        assert turn == pytest.approx(expect, abs=1e-12)


@pytest.mark.parametrize("theta,lam,D", CASES)
def test_uniform_chain_is_the_closed_form_helix(theta, lam, D):
    h = helix_forward(theta, lam, D)
    m = 40
    length = rng.uniform(0.2, 1.5, m)  # non-uniform segments of one uniform routing
    frames = chain_frames(np.full(m, theta), lam, length, D)
    pts = frames[:, :3, 3]
    # helix axis direction is the Darboux vector (tau, 0, kappa) in the start frame; the axis
    # passes through the start point offset by R_c along the normal
    w = np.array([h.tau_c, 0.0, h.kappa_c]) / math.hypot(h.tau_c, h.kappa_c)
    c0 = np.array([0.0, h.R_c, 0.0])
    rel = pts - c0
    along = rel @ w
    radial = rel - np.outer(along, w)
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), abs(h.R_c), rtol=1e-10, atol=1e-10)
    # pitch: the rise along the axis per radian turned around it is b
    s_act = np.concatenate([[0], np.cumsum(length)]) * h.lambda_c
    turned = s_act / math.hypot(h.R_c, h.b)
    np.testing.assert_allclose(along, h.b * turned, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("theta,lam,D", CASES)
def test_paper_matrices_agree_with_exp_form(theta, lam, D):
    if theta == 0.0 and lam == 1.0:
        pytest.skip("paper form is 0/0 on a straight tube")
    for dl in (0.01, 0.7, 5.0, 40.0):
        np.testing.assert_allclose(segment_transform(theta, lam, dl, D), paper_segment_transform(theta, lam, dl, D), atol=1e-11 * max(1, dl))


def test_paper_chain_agrees_with_exp_chain_for_general_routing():
    m = 30
    th = rng.uniform(-1.0, 1.0, m)
    lam = rng.uniform(0.4, 0.99, m)
    length = rng.uniform(0.3, 2.0, m)
    T0 = np.eye(4)
    T0[:3, 3] = [1, 2, 3]
    ours = chain_frames(th, lam, length, 2.43, T0)
    theirs = [T0]
    for j in range(m):
        theirs.append(theirs[-1] @ paper_segment_transform(th[j], lam[j], length[j], 2.43))
    np.testing.assert_allclose(ours, np.array(theirs), atol=1e-11)
    # frames stay proper rotations
    R = ours[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1, atol=1e-12)


def test_shapes_scale_with_diameter():
    th = rng.uniform(-1, 1, 12)
    lam = rng.uniform(0.4, 1, 12)
    length = rng.uniform(0.5, 2, 12)
    a = chain_frames(th, lam, length, 2.0)[:, :3, 3]
    b = chain_frames(th, lam, 3.0 * length, 6.0)[:, :3, 3]
    np.testing.assert_allclose(b, 3.0 * a, atol=1e-12)


def test_points_inside_segments_and_lines():
    th = rng.uniform(-1, 1, 8)
    lam = rng.uniform(0.4, 1, 8)
    length = rng.uniform(0.5, 2, 8)
    D = 2.43
    seg, frac = segment_end_samples(length, 4)
    assert seg.size == 8 * 4 + 1
    c, i, o = shape_lines(th, lam, length, D, seg, frac)
    frames = chain_frames(th, lam, length, D)
    np.testing.assert_allclose(c[::4], frames[:, :3, 3], atol=1e-12)  # segment ends included, base to tip
    np.testing.assert_allclose(np.linalg.norm(i - o, axis=1), D, rtol=1e-12)
    np.testing.assert_allclose(0.5 * (i + o), c, atol=1e-12)


@pytest.mark.parametrize("theta,lam,D", CASES[:6])
def test_inner_line_is_the_inner_helix(theta, lam, D):
    # The inner line of a uniform chain has radius |R_i| about the same axis and the
    # tangent offset alpha_ci given by T^c_i.
    h = helix_forward(theta, lam, D)
    length = np.full(60, 0.5)
    seg, frac = segment_end_samples(length, 1)
    _, inner, outer = shape_lines(np.full(60, theta), lam, length, D, seg, frac)
    w = np.array([h.tau_c, 0.0, h.kappa_c]) / math.hypot(h.tau_c, h.kappa_c)
    c0 = np.array([0.0, h.R_c, 0.0])
    for pts, R in ((inner, h.R_i), (outer, h.R_o)):
        rel = pts - c0
        radial = rel - np.outer(rel @ w, w)
        np.testing.assert_allclose(np.linalg.norm(radial, axis=1), abs(R), rtol=1e-9, atol=1e-9)
    a_ci, a_co = line_offset_angles(theta, lam)
    assert a_ci + a_co == pytest.approx(2 * theta, abs=1e-13)


def test_phi_theta_round_trip():
    D = 4.77
    th = rng.uniform(-1.2, 1.2, 25)
    length = rng.uniform(0.2, 3, 25)
    phi = phi_from_theta(th, length, D)
    assert phi[0] == 0 and phi.shape == (26,)
    s = np.concatenate([[0], np.cumsum(length)])
    # theta_j = arctan((D/2) (phi(s_{j+1}) - phi(s_j)) / (s_{j+1} - s_j)) (paper Sec. V-B)
    np.testing.assert_allclose(np.arctan(0.5 * D * np.diff(phi) / np.diff(s)), th, atol=1e-13)


def cosserat(theta, lam, D):
    """Cosserat-rod rates per unit of unactuated length (paper Sec. II-C): (u_x, u_y, u_z, v_z) in the actuator-attached
    frame; u_z less the reference torsion 2 tan(theta)/D of the unactuated routing."""
    kappa_c, tau_c, lambda_c = center_rates(theta, lam, D)
    return 0 * kappa_c, kappa_c * lambda_c, tau_c * lambda_c - 2 * math.tan(theta) / D, lambda_c


def test_cosserat_quantities():
    theta, lam, D = math.radians(20), 0.6, 3.0
    ux, uy, uz, vz = cosserat(theta, lam, D)
    dp = lam**2 + 2 * lam * math.cos(2 * theta) + 1
    lc = math.sqrt(dp / (2 * (1 + math.cos(2 * theta))))
    assert vz == pytest.approx(lc)
    assert math.hypot(ux, uy) == pytest.approx(2 * (1 - lam**2) / (D * dp) * lc)
    tau = 4 * lam * math.sin(2 * theta) / (D * dp) * lc
    assert uz == pytest.approx(tau - 2 * math.sin(2 * theta) / (D * (1 + math.cos(2 * theta))))
    # the unactuated tube has no material torsion
    assert cosserat(theta, 1.0, D)[2] == pytest.approx(0, abs=1e-14)


def test_self_collision_condition():
    # condition against 2 pi b < D directly
    th = np.radians(rng.uniform(-60, 60, 300))
    lam = rng.uniform(0.3, 0.999, 300)
    h = helix_forward(th, lam, 2.0)
    np.testing.assert_array_equal(helix_self_collides(th, lam, 2.0), 2 * np.pi * np.abs(h.b) < 2.0)
    assert not helix_self_collides(0.0, 1.0, 2.0)
    # needs a whole turn: a short section cannot collide
    t, l = math.radians(1), 0.5
    assert helix_self_collides(t, l, 2.0)
    one_turn = 1.0 / helix_turns(t, l, 2.0, 1.0)
    assert not helix_self_collides(t, l, 2.0, 0.9 * one_turn)
    assert helix_self_collides(t, l, 2.0, 1.1 * one_turn)


def _casadi_segment_functions():
    x = ca.SX.sym("x", 4)  # theta, lambda, length, D
    T = segment_transform(x[0], x[1], x[2], x[3])
    out = ca.vertcat(ca.vec(T[:3, :]), *center_rates(x[0], x[1], x[3]), *line_offset_angles(x[0], x[1]))
    f = ca.Function("f", [x], [out])
    jac = ca.Function("j", [x], [ca.jacobian(out, x)])
    w = ca.SX.sym("w", out.numel())
    hess = ca.Function("h", [x, w], [ca.hessian(ca.dot(w, out), x)[0]])
    return f, jac, hess


def test_casadi_values_match_numpy():
    f, _, _ = _casadi_segment_functions()
    for theta, lam, D in CASES:
        v = np.array(f([theta, lam, 1.7, D])).ravel()
        np.testing.assert_allclose(v[:12], segment_transform(theta, lam, 1.7, D)[:3, :].T.ravel(), atol=1e-14)


def test_casadi_derivatives_finite_over_the_whole_box():
    f, jac, hess = _casadi_segment_functions()
    thetas = np.radians([-89, -60, -1e-6, 0.0, 1e-6, 30, 89])
    lams = [1e-3, 0.4, 0.999999, 1.0]
    w = rng.normal(size=f.size1_out(0))
    for theta in thetas:
        for lam in lams:
            for length in (0.0, 1e-8, 1.0, 50.0):
                x = [theta, lam, length, 2.43]
                for val in (f(x), jac(x), hess(x, w)):
                    assert np.all(np.isfinite(np.array(val))), (theta, lam, length)


def test_derivatives_at_straight_tube_match_finite_differences():
    f, jac, _ = _casadi_segment_functions()
    x0 = np.array([0.0, 1.0, 1.3, 2.43])
    J = np.array(jac(x0))
    h = 1e-6
    for k in range(3):
        e = np.zeros(4)
        e[k] = h
        fd = (np.array(f(x0 + e)) - np.array(f(x0 - e))).ravel() / (2 * h)
        np.testing.assert_allclose(J[:, k], fd, atol=1e-7)


def test_symbolic_chain_matches_numeric_chain():
    m = 5
    th = ca.SX.sym("th", m)
    lam = ca.SX.sym("lam", m)
    ln = ca.SX.sym("l", m)
    T = ca.SX.eye(4)
    for j in range(m):  # the symbolic segment motion (the NLP's) chained by hand
        T = ca.mtimes(T, segment_transform(th[j], lam[j], ln[j], 2.0))
    f = ca.Function("c", [th, lam, ln], [T])
    v = (rng.uniform(-1, 1, m), rng.uniform(0.4, 1, m), rng.uniform(0.5, 2, m))
    np.testing.assert_allclose(np.array(f(*v)), chain_frames(*v, 2.0)[-1], atol=1e-13)
