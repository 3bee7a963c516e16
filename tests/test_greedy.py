"""Greedy Algorithm 1 (paper Sec. VI-B): known answers, bounds, sPAM, filter, shared error."""

import math

import numpy as np
import pytest

from vine_nlp.methods.buildable import missed
from vine_nlp.methods.common import design_bounds, pair_points, path_error
from vine_nlp.methods.greedy import _window_data, _window_solver_for, design_greedy, design_greedy_buildable, lowpass
from vine_nlp.model import chain_points
from vine_nlp.model.chain import chain_frames, segment_end_samples
from vine_nlp.model.shape import total_variation
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, Routing

N_PTS = 5  # points per segment
D = 2.0


def _pose():
    """A non-trivial initial pose, so the first window's pose fit is exercised."""
    from vine_nlp.model.segment import so3_exp

    T = np.eye(4)
    T[:3, :3] = so3_exp(np.array([0.2, -0.1, 0.3]))
    T[:3, 3] = [1.0, -2.0, 0.5]
    return T


def _target(theta, lam, length, pose):
    seg, frac = segment_end_samples(length, N_PTS)
    pts, _ = chain_points(theta, lam, length, D, seg, frac, pose)
    return pts


def _problem(target, kind="tendon", lambda_min=0.4, starts=2, **kw):
    opts = DesignOptions(method="greedy", points_per_segment=N_PTS, lookahead=4, greedy_starts=starts, **kw)
    return DesignProblem("test", D, target, actuator=Actuator(kind, lambda_min=lambda_min), options=opts)


@pytest.fixture(scope="module")
def known():
    """A smooth random routing of 10 segments and its forward-model target."""
    rng = np.random.default_rng(7)
    M = 10
    s = np.linspace(0.0, 1.0, M)
    a, ph = rng.uniform(0.2, 0.4), rng.uniform(0, 2 * np.pi)
    theta = a * np.sin(2 * np.pi * s + ph) + rng.uniform(-0.1, 0.1)
    lam = 0.72 + 0.12 * np.cos(2.5 * s + rng.uniform(0, 1))
    length = rng.uniform(2.5, 3.5) * np.ones(M)
    routing = Routing(theta=theta, lam=lam, length=length, initial_pose=_pose())
    return routing, _target(theta, lam, length, routing.initial_pose)


@pytest.fixture(scope="module")
def known_result(known):
    _, target = known
    prob = _problem(target)
    calls = []
    res = design_greedy(prob, progress=lambda done, total: calls.append((done, total)))
    return prob, res, calls


def test_known_answer_recovered(known, known_result):
    routing, target = known
    prob, res, calls = known_result
    assert res.method == "greedy"
    assert res.status in ("optimal", "acceptable")
    assert res.metrics["rmse"] < 1e-3 * D
    np.testing.assert_allclose(res.routing.theta, routing.theta, atol=1e-3)
    np.testing.assert_allclose(res.routing.lam, routing.lam, atol=1e-3)
    # stats and progress
    M = res.routing.segments
    st = res.stats
    assert st["windows"] == M and st["lookahead"] == 4 and st["starts_per_window"] == 2
    assert st["starts_first_window"] == 8
    assert st["window_solves"] == 8 + 2 * (M - 1)
    assert res.iterations > 0 and res.solve_time_s > 0
    assert [c[0] for c in calls] == list(range(1, M + 1)) and all(c[1] == M for c in calls)


def _assert_in_bounds(prob, res):
    pairing = pair_points(prob.target, prob.options.points_per_segment)
    box = design_bounds(prob, pairing)
    (tl, tu), (ll, lu), (dl, du) = box["theta"], box["lam"], box["length"]
    r = res.routing
    assert np.all(r.theta >= tl) and np.all(r.theta <= tu)
    assert np.all(r.lam >= ll) and np.all(r.lam <= lu)
    assert np.all(r.length >= dl) and np.all(r.length <= du)


def test_bounds_hold(known_result):
    prob, res, _ = known_result
    _assert_in_bounds(prob, res)


def test_bounds_hold_on_unreachable_target():
    # a circle tighter than lambda_min allows: lambda must saturate at the bound, not beyond it
    t = np.linspace(0.0, 1.5 * np.pi, 31)
    R = 1.0 * D
    target = np.column_stack([R * np.sin(t), R * (1 - np.cos(t)), 0.3 * t])
    prob = _problem(target, starts=1)
    res = design_greedy(prob)
    _assert_in_bounds(prob, res)
    assert res.routing.lam.min() == pytest.approx(prob.actuator.lambda_min, abs=1e-6)


@pytest.fixture(scope="module")
def spam():
    M = 9
    s = np.linspace(0.0, 1.0, M)
    theta = 0.3 * np.sin(2 * np.pi * s + 0.3) + 0.1
    lam_true = 0.73
    length = np.full(M, 3.0)
    target = _target(theta, np.full(M, lam_true), length, np.eye(4))
    prob = _problem(target, kind="spam", lambda_min=0.5, starts=1)
    return prob, design_greedy(prob), lam_true


def test_spam_recovers_shared_lambda(spam):
    prob, res, lam_true = spam
    lam = res.routing.lam
    assert np.all(lam == lam[0])
    assert abs(lam[0] - lam_true) < 0.02
    assert res.stats["lambda"] == lam[0]
    assert res.metrics["rmse"] < 0.05 * D
    grid = list(np.linspace(0.5, 1.0, 11))
    assert res.stats["lambda_candidates"][:11] == pytest.approx(grid)
    assert 11 < res.stats["lambda_candidates_tried"] <= 16  # plus the refinement pass
    _assert_in_bounds(prob, res)


def test_spam_early_abandonment(spam):
    prob, res, _ = spam
    st = res.stats
    # lambda = 1 is a straight tube: hopeless for a curved target, abandoned early
    assert 1.0 in st["abandoned_lambdas"]
    assert st["lambda_candidates_abandoned"] == len(st["abandoned_lambdas"]) >= 1
    assert st["abandon_threshold"] == pytest.approx(N_PTS * 4 * D / 2)
    i = st["lambda_candidates"].index(1.0)
    assert st["lambda_candidate_errors"][i] is None
    # abandoned candidates stop early: fewer solves than 1 full pass per candidate
    M = res.routing.segments
    full = (4 + (M - 1)) * st["lambda_candidates_tried"]
    assert st["window_solves"] < full


def test_lowpass_reduces_theta_variation(known, known_result):
    prob, res, _ = known_result
    # add high-frequency wiggle to theta, as the paper sees at the ends of its designs
    r = res.routing
    wiggle = 0.05 * (-1.0) ** np.arange(r.segments)
    noisy = Routing(theta=r.theta + wiggle, lam=r.lam, length=r.length, initial_pose=r.initial_pose)
    filt = lowpass(noisy, prob)
    assert filt.method == "greedy_filtered"
    assert filt.stats["filtered"] and filt.stats["cutoff"] == 0.5
    assert total_variation(filt.routing.theta) < total_variation(noisy.theta)
    # and on the greedy result itself
    filt2 = lowpass(res, prob)
    assert total_variation(filt2.routing.theta) < total_variation(res.routing.theta)
    assert "rmse" in filt2.metrics and filt2.status == res.status
    _assert_in_bounds(prob, filt2)


def test_lowpass_short_chain_unfiltered(spam):
    prob, res, _ = spam  # 9 segments: too short for filtfilt's padding
    filt = lowpass(res, prob)
    assert not filt.stats["filtered"]
    np.testing.assert_array_equal(filt.routing.theta, res.routing.theta)


def window_error(problem: DesignProblem, routing: Routing, j: int, K: int, pairing):
    """(sum of squared distances, sum of distances) of ``routing`` on the window j..j+K-1,
    evaluated with the window NLP's own CasADi expression (unscaled, in problem units).

    The first number is what the window solves minimize; it equals
    ``common.path_error`` of the paired points bounds[j] .. bounds[j+K].
    """
    D = problem.diameter
    solver = _window_solver_for(problem, pairing.n, K, j == 0)
    T = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)[j]
    tgt, w, u, end = _window_data(problem, pairing, j, K)
    lam_fixed = float(routing.lam[0]) if problem.actuator.shared_lambda else 0.0
    p = solver.pack_params(T[:3, :3], T[:3, 3] / D, tgt, w, u, end, lam_fixed)
    sl = slice(j, j + K)
    x = solver.pack_x(routing.theta[sl], routing.lam[sl], routing.length[sl] / D)
    sq, dist = solver.terms(x, p)
    return float(sq) * D**2, float(dist) * D



@pytest.mark.parametrize("j,K", [(0, 4), (3, 4), (7, 3), (9, 1)])
def test_window_error_is_the_shared_path_error(known, j, K):
    routing, target = known
    rng = np.random.default_rng(j)
    # a routing that does not fit, so the errors are not all zero
    r = Routing(theta=routing.theta + rng.normal(0, 0.05, routing.segments), lam=routing.lam * 0.97,
                length=routing.length * 1.02, initial_pose=routing.initial_pose)
    prob = _problem(target)
    pairing = pair_points(target, N_PTS)
    sq, dist = window_error(prob, r, j, K, pairing)
    idx = np.arange(pairing.bounds[j], pairing.bounds[j + K] + 1)
    pts, _ = chain_points(r.theta, r.lam, r.length, D, pairing.seg[idx], pairing.frac[idx], r.initial_pose)
    assert sq == pytest.approx(path_error(pts, target[idx]), rel=1e-10)
    assert dist == pytest.approx(np.linalg.norm(pts - target[idx], axis=1).sum(), rel=1e-10)
    assert sq > 0


def test_single_segment_chain():
    target = np.column_stack([np.linspace(0, 4, 6), np.zeros(6), np.zeros(6)])
    prob = _problem(target, starts=1)
    res = design_greedy(prob)
    assert res.routing.segments == 1
    assert res.metrics["rmse"] < 1e-4
    assert math.isfinite(res.metrics["max_error"])


def test_buildable_greedy_recovers_a_buildable_routing():
    # a buildable routing: straight (lambda exactly 1) on 0-2, 7-8 (its line turning at one slope, 0.2 rad: 1.2 rad
    # net, the shortest way) and 12-13, actuated inside the correction margin's band elsewhere; its model target
    M = 14
    act = np.zeros(M, bool)
    act[3:7] = act[9:12] = True
    theta = np.where(act, 0.35 * np.cos(np.arange(M)), 0.0)
    theta[7:9] = 0.2
    lam = np.where(act, 0.7 + 0.1 * np.sin(np.arange(M)), 1.0)
    routing = Routing(theta=theta, lam=lam, length=np.full(M, 3.0), initial_pose=_pose())
    prob = _problem(_target(theta, lam, routing.length, routing.initial_pose))
    free = design_greedy(prob)
    res = design_greedy_buildable(prob, start=free)  # classes from the bends of the greedy's own design
    assert res.method == "greedy_buildable" and res.buildable and res.status == "optimal"
    assert res.stats["buildable_actuated"] == act.sum()
    assert res.metrics["rmse"] < 1e-4 * D
    np.testing.assert_array_equal(res.routing.lam == 1.0, ~act)  # exactly 1 without an actuator
    np.testing.assert_allclose(res.routing.lam[act], lam[act], atol=1e-4)
    np.testing.assert_allclose(res.routing.theta[3:12], theta[3:12], atol=1e-4)  # the middle run unwound to its one slope
    np.testing.assert_array_equal(res.routing.theta[12:], 0.0)  # nothing downstream: no turning
    np.testing.assert_array_equal(res.routing.theta[:3], 0.0)  # a free base rolls instead
    np.testing.assert_allclose(res.routing.initial_pose, routing.initial_pose, atol=1e-4)
    assert missed(prob, res) == []  # judged by the buildable rules (the greedy's own run is not)
    assert missed(prob, free) == [] and res.solve_time_s > free.solve_time_s  # the free design's time counted
