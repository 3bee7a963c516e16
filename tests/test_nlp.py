"""Inverse design as one NLP: known answers, bounds, the symmetry trap, smoothing, warm start."""

import numpy as np
import pytest

import vine_nlp as vn
from vine_nlp import targets
from vine_nlp.methods.common import geometric_guess, pair_points
from vine_nlp.methods.nlp import design_nlp, start_guesses
from vine_nlp.model.shape import total_variation
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem

NO_SMOOTH = dict(smooth_theta=0.0, smooth_lambda=0.0)


def _problem(target, D=2.0, kind="tendon", n=5, **opts):
    return DesignProblem("t", D, target, actuator=Actuator(kind=kind, lambda_min=0.4), options=DesignOptions(points_per_segment=n, **opts))


def test_pairing_covers_every_point_and_ends_at_the_tip():
    tgt = targets.trefoil(samples=400)
    p = pair_points(tgt, 10)
    assert p.segments == 40  # 399 intervals, 10 per segment, the last takes 9
    assert p.seg[0] == 0 and p.frac[0] == 0.0
    assert p.seg[-1] == 39 and p.frac[-1] == pytest.approx(1.0)
    assert np.all(np.diff(p.seg) >= 0)
    assert np.all((p.frac >= 0) & (p.frac <= 1))
    np.testing.assert_array_equal(np.bincount(p.seg), [10] * 39 + [10])  # 9 slots + the tip


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_known_answer_per_segment_lambda(make_target, seed):
    tgt, truth = make_target(seed=seed)
    r = design_nlp(_problem(tgt, **NO_SMOOTH))
    assert r.status == "optimal"
    assert r.metrics["rmse"] < 1e-6
    np.testing.assert_allclose(r.routing.theta, truth.theta, atol=1e-4)
    np.testing.assert_allclose(r.routing.lam, truth.lam, atol=1e-4)
    np.testing.assert_allclose(r.routing.length, truth.length, atol=1e-4)
    np.testing.assert_allclose(r.routing.initial_pose, truth.initial_pose, atol=1e-5)
    assert r.shape.center.shape == tgt.shape  # row i pairs with target row i


def test_known_answer_spam_recovers_its_one_lambda(make_target):
    tgt, truth = make_target(seed=4, spam=True)
    r = design_nlp(_problem(tgt, kind="spam", **NO_SMOOTH))
    assert r.converged
    assert np.ptp(r.routing.lam) == 0.0
    assert r.routing.lam[0] == pytest.approx(0.7, abs=1e-5)
    assert r.metrics["rmse"] < 1e-6


def test_bounds_always_hold():
    # an unreachable target: a tight helix needs lambda and theta beyond the box
    tgt = targets.helix(radius=0.8, pitch=0.2, length=40.0, samples=121)
    pb = DesignProblem("tight", 2.0, tgt, actuator=Actuator("tendon", 0.6, np.radians(30)), options=DesignOptions(points_per_segment=4))
    r = design_nlp(pb)
    assert np.all(np.abs(r.routing.theta) <= np.radians(30) + 1e-9)
    assert np.all((r.routing.lam >= 0.6 - 1e-9) & (r.routing.lam <= 1 + 1e-9))
    assert np.all(r.routing.length > 0)
    assert r.metrics["rmse"] > 0.05  # it really could not follow


def test_planar_s_curve_is_solved_not_stuck_in_the_plane():
    tgt = targets.bezier([[0, 0], [50, 0], [24, -24], [0, -50], [50, -50]], 400)
    pb = DesignProblem("c", 2.43, tgt)
    r = design_nlp(pb)
    assert r.converged
    assert r.metrics["rmse"] < 0.045  # half of the paper's 0.09 cm
    # the bending direction reverses: the actuator crosses over with a steep section
    assert np.abs(r.routing.theta).max() > np.radians(20)
    phi = r.phi
    assert abs(phi[-1] - phi[0]) > 0.8 * np.pi


def test_theta_zero_start_is_a_stationary_point_for_planar_targets():
    """Why the symmetry breaking matters: from theta = 0 the gradient keeps the design planar."""
    tgt = targets.bezier([[0, 0], [50, 0], [24, -24], [0, -50], [50, -50]], 200)
    pb = DesignProblem("c", 2.43, tgt)
    pairing = pair_points(tgt, 10)
    g = geometric_guess(pb, pairing)
    g.theta[:] = 0.0
    from vine_nlp.model import chain_frames

    g.frames = chain_frames(g.theta, g.lam, g.length, 2.43, g.initial_pose)
    from vine_nlp.methods.nlp import solve_from

    stuck = solve_from(pb, g, pairing, frames="chain")
    assert np.abs(stuck.routing.theta).max() < 1e-6
    good = design_nlp(pb)
    assert good.metrics["rmse"] < 0.2 * stuck.metrics["rmse"]


def test_smoothness_weight_lowers_total_variation_of_theta():
    tgt = targets.trefoil(samples=200)
    tv = []
    for w in (0.0, 1e-1):
        r = design_nlp(DesignProblem("k", 2.43, tgt, options=DesignOptions(points_per_segment=5, smooth_theta=w, smooth_lambda=w)))
        tv.append(total_variation(r.routing.theta))
    assert tv[1] < tv[0]


def test_trefoil_beats_the_paper_by_far():
    pb = DesignProblem("trefoil", 2.43, targets.trefoil(samples=400))
    r = vn.solve(pb, "nlp").result  # what `vine-nlp design` makes: the buildable design
    assert r.status == "optimal"
    assert r.metrics["rmse"] < 0.010  # cm: 0.1 mm, the paper reached 0.22 mm
    assert r.metrics["max_error"] < 0.048


def test_multistart_is_deterministic_and_keeps_the_best(make_target):
    tgt, _ = make_target(seed=5)
    pb = _problem(tgt, starts=4, seed=7)
    a = design_nlp(pb)
    b = design_nlp(pb)
    np.testing.assert_allclose(a.routing.theta, b.routing.theta, atol=1e-9)
    assert a.stats["starts"] == 4
    from vine_nlp.methods.nlp import TIE_RTOL

    assert a.stats["objective"] <= min(a.stats["start_objectives"]) * (1 + TIE_RTOL)
    # iterations: every start's once, then every hop's (the winner's were once counted twice)
    assert a.iterations == sum(a.stats["start_iterations"]) and len(a.stats["start_iterations"]) == 4
    h = design_nlp(pb, hops=1)
    assert h.iterations == sum(h.stats["start_iterations"]) + sum(h.stats["hop_iterations"])
    g = start_guesses(pb, pair_points(tgt, 5), 4)
    assert len(g) == 4 and not np.allclose(g[2].theta, g[0].theta)


def test_warm_start_from_an_earlier_design(make_target):
    tgt, truth = make_target(seed=6)
    pb = _problem(tgt, **NO_SMOOTH)
    r = design_nlp(pb, warm=truth)
    assert r.stats["warm_start"]
    assert r.iterations <= 5
    assert r.metrics["rmse"] < 1e-6


def test_solver_is_built_once_per_structure(make_target):
    from vine_nlp.methods.transcription import get_solver

    tgt, _ = make_target(seed=8, M=9)
    design_nlp(_problem(tgt))
    before = get_solver.cache_info().hits
    tgt2, _ = make_target(seed=9, M=9)
    design_nlp(_problem(tgt2))
    assert get_solver.cache_info().hits == before + 1


def test_gauss_newton_hessian_is_the_exact_one_at_a_perfect_fit(make_target):
    # f = |r|^2: the exact Hessian is 2 J^T J + sum r_i Hess(r_i); the second part vanishes where r = 0
    from vine_nlp.methods.common import Guess
    from vine_nlp.methods.nlp import get_solver, nlp_parameters, start_x
    from vine_nlp.model import chain_frames

    tgt, truth = make_target(seed=3, M=6)
    pb = _problem(tgt)
    pairing = pair_points(tgt, 5)
    ex, gn = get_solver(6, 5, False, hessian="exact"), get_solver(6, 5, False, hessian="gauss-newton")
    p = ex.pack_params(nlp_parameters(pb, pairing, truth.initial_pose[:3, :3]))
    fr = chain_frames(truth.theta, truth.lam, truth.length, pb.diameter, truth.initial_pose)
    x = start_x(ex, Guess(truth.theta, truth.lam, truth.length, truth.initial_pose, fr), pb.diameter, "chain")
    assert ex.terms(x, p)["fit"] < 1e-20
    zero = np.zeros(ex.nlpsol.size_out("g")[0])
    H_ex = np.array(ex.nlpsol.get_function("nlp_hess_l")(x, p, 1.0, zero))
    H_gn = np.array(gn.nlpsol.get_function("nlp_hess_l")(x, p, 1.0, zero))
    np.testing.assert_allclose(H_gn, H_ex, atol=1e-9 * np.abs(H_ex).max())
    # away from the fit they differ (the test can tell them apart): move a target point inside a segment
    p_off = p.copy()
    p_off[5 + 3 * 2 : 5 + 3 * 3] += 1.0  # cells come first: u (5), then the slots' targets of segment 0
    H_ex, H_gn = (np.array(s.nlpsol.get_function("nlp_hess_l")(x, p_off, 1.0, zero)) for s in (ex, gn))
    assert np.abs(H_ex - H_gn).max() > 1e-3 * np.abs(H_ex).max()


def test_basin_hopping_lowers_the_objective_on_a_corner_target():
    # corners: each can be taken on several sides, separate local minima of the one NLP
    cp = np.array([[0, 0, 0], [20, 0, 0], [22, -20, 8], [0, -22, 8], [8, 0, 14.0]])
    tgt = targets.polyline(cp, samples=81)
    pb = DesignProblem("corners", 2.43, tgt, actuator=Actuator("tendon", 0.4), options=DesignOptions(points_per_segment=8, seed=1))
    single = design_nlp(pb, budget=0)  # the first solve alone (no corner search: design.corners)
    hopped = design_nlp(pb, hops=6)
    st = hopped.stats
    assert st["hops"] == 6 and len(st["hop_objectives"]) == len(st["hop_iterations"]) == 6
    assert hopped.converged
    assert hopped.stats["objective"] < single.stats["objective"] * (1 - 1e-3)  # measured: 0.1034 vs 0.1094
    assert hopped.metrics["rmse"] < single.metrics["rmse"]
    # the kept design is the best one seen, up to the tie rule (all hops converge here)
    from vine_nlp.methods.drive import TIE_RTOL

    assert st["hops_accepted"] >= 1 and hopped.stats["objective"] <= min(st["hop_objectives"]) * (1 + TIE_RTOL)
    assert hopped.iterations == single.iterations + sum(st["hop_iterations"])
    # deterministic for a seed
    again = design_nlp(pb, hops=6)
    np.testing.assert_array_equal(again.routing.theta, hopped.routing.theta)


def test_guess_vector_helpers_give_numpys_bits():
    """geometric_guess's scalar 3-vector helpers round exactly as the numpy calls they replace: the guess must
    not move in its last bit (IPOPT's path from it would)."""
    from vine_nlp.methods.common import _cross3, _reject, _unit, _unit3

    rng = np.random.default_rng(7)
    for scale in (1e-9, 1.0, 1e4):
        for _ in range(2000):
            a, b = rng.normal(size=3) * scale, rng.normal(size=3)
            assert np.array_equal(_cross3(a, b), np.cross(a, b))
            assert np.array_equal(_unit3(_reject(a, b)), _unit(a - np.dot(a, b) * b))
            assert np.array_equal(_unit3(a.tolist()), _unit(a))
    assert np.array_equal(_unit3([0.0, 0.0, 0.0]), _unit(np.zeros(3)))  # no direction: left as it is


def test_a_solution_evaluates_any_expression_of_the_chain_at_its_answer(make_target):
    """rockit's sol.value: the tip view at the solution is the routing's chain end (units of D), theta the routing's,
    the fit term the objective's share; the Result carries the solution's objective as a typed field."""
    from vine_nlp.methods.nlp import design_bounds, get_solver, nlp_parameters, result_of, start_x
    from vine_nlp.model.chain import chain_frames

    target, _ = make_target(M=6, n=3, seed=3)
    problem = _problem(target, n=3)
    pairing = pair_points(problem.target, 3)
    guess = geometric_guess(problem, pairing)
    solver = get_solver(pairing.segments, 3, False)
    p = solver.pack_params(nlp_parameters(problem, pairing, guess.initial_pose[:3, :3]))
    sol = solver.solve(start_x(solver, guess, problem.diameter), p, *solver.bounds(**design_bounds(problem, pairing)))
    assert sol.status == "optimal"
    r = sol.routing(problem.diameter, guess.initial_pose[:3, :3])
    end = chain_frames(r.theta, r.lam, r.length, problem.diameter, r.initial_pose)[-1, :3, 3]
    np.testing.assert_allclose(sol.value(solver.chain.tip(0)) * problem.diameter, end, atol=1e-6 * problem.diameter)
    np.testing.assert_array_equal(sol.value(solver.chain.theta), r.theta)
    assert sol.value(solver.chain.terms["smooth"]) == pytest.approx(sol.stats["objective_smooth"], rel=1e-12)
    assert result_of(problem, pairing, sol, guess.initial_pose[:3, :3], "nlp").objective == sol.objective == sol.stats["objective"]
