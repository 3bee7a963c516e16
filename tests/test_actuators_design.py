"""Design of a tube with several actuators (methods.actuators_design): targets made by the model from known
routings are met; no state ever has two active lines on a segment; lines that may share a segment keep their
widths apart."""

import dataclasses

import casadi as ca
import numpy as np
import pytest

from vine_nlp.methods import actuators_design as A
from vine_nlp.methods import compiled, settings
from vine_nlp.methods.actuators import ActuatorsProblem, Line, evaluate, sample_states, unbuilt
from vine_nlp.methods.actuators_design import assign, design_actuators, dither, exclusive_pairs, unwound
from vine_nlp.model.actuators import Lines, forward_states, owners, too_close
from vine_nlp.model.routing import actuated
from vine_nlp.pipeline.runs import judge
from vine_nlp.problem import DesignOptions

D, M, N_PER = 2.4, 8, 5


def _problem(lines, states, widths=(0.3, 0.3)):
    T = sample_states(lines, D, states, M * N_PER + 1)
    acts = tuple(Line(nm, width=w) for nm, w in zip(lines.names, widths))
    return ActuatorsProblem("t", D, acts, states, targets=T, options=DesignOptions(points_per_segment=N_PER))


def test_assign_keeps_one_line_of_each_exclusive_pair():
    lam = np.array([[0.6, 0.9, 1.0, 0.8], [0.7, 0.5, 1.0, 1.0], [0.9, 0.9, 0.9, 0.9]])
    keep = assign(lam, [(0, 1)])
    assert keep.tolist() == [[True, False, False, True], [False, True, False, False], [True, True, True, True]]


def test_exclusive_pairs():
    acts = (Line("A", width=0.1), Line("B", width=0.1), Line("C", width=7.5))
    p = ActuatorsProblem("t", 2.4, acts, {"s": ("A", "B"), "t": ("C",)})
    # A, B pulled together; C too wide to share a segment with anything ((0.1 + 7.5) / 2 > pi D / 2)
    assert exclusive_pairs(p) == ([(0, 1), (0, 2), (1, 2)], [])


def test_base_tip_pair_three_states():
    th = np.array([np.full(M, 0.1), np.full(M, -0.05)])
    lam = np.ones((2, M))
    lam[0, : M // 2], lam[1, M // 2:] = 0.7, 0.75
    truth = Lines(("A", "B"), th, lam, [0, 1.9], np.full(M, 2.5))
    states = {"a": ("A",), "b": ("B",), "ab": ("A", "B")}
    p = _problem(truth, states)
    r = design_actuators(p)
    assert r.converged and r.ok, (r.status, r.shortfall)
    for s in states:
        assert r.state_metrics[s]["rmse"] < 0.01  # cm: 0.1 mm
        owners(r.lines, states[s], s)  # never two active lines on a segment
    # the assignment is exact: where A contracts, B's lambda is exactly 1 and the other way round
    on = actuated(r.lines.lam)
    assert not np.any(on[0] & on[1])
    assert np.all(r.lines.lam[~on] == 1.0)
    assert unbuilt(p, r.lines) == []  # buildable: no pointless turning, every feature at least min_feature


def test_lines_that_share_segments_keep_their_widths():
    th = np.array([np.full(M, 0.05), np.full(M, -0.05)])
    lam = np.array([np.full(M, 0.8), np.full(M, 0.85)])
    truth = Lines(("L", "R"), th, lam, [0, 2.5], np.full(M, 2.5))
    p = _problem(truth, {"left": ("L",), "right": ("R",)}, widths=(0.5, 0.5))
    r = design_actuators(p)
    assert r.ok, r.shortfall
    assert too_close(r.lines, D, p.widths) == []
    assert max(m["rmse"] for m in r.state_metrics.values()) < 0.01


def test_dither_keeps_the_running_contraction():
    lam = np.array([[0.99, 0.99, 0.99, 0.99, 0.9, 1.0]])
    # 1 - lambda accumulates 0.01 per segment; at 0.025 (half the margin) one segment is kept at 1 - margin
    assert dither(lam, np.array([0.05])).tolist() == [[False, False, True, False, True, False]]


def test_buildable_rules_per_actuator_and_unwinding_known_answers():
    lam = np.ones((2, 6))
    lam[0, 2], lam[1, 4] = 0.9, 0.6
    th = np.array([[0.3, -0.2, 0.1, 0.2, -0.3, 0.1], [0.0, 0.2, 0.2, -0.1, 0.05, 0.4]])
    lines, states = Lines(("A", "B"), th, lam, [0.0, 2.0], np.ones(6)), {"a": ("A",), "b": ("B",)}
    p = ActuatorsProblem("t", D, (Line("A"), Line("B")), states, targets=sample_states(lines, D, states, 13),
                         options=DesignOptions(min_feature=0.2))
    gap = "actuator A: not buildable: 1 feature(s) below min_feature 0.2 cm (smallest: 0.100502 cm stopper gap)"  # 0.1 / cos(0.1)
    # A turns (2/D) sum |tan theta| over its five segments without an actuator: 0.937 rad = 0.149 turn; it needs none there
    assert unbuilt(p, lines) == [gap, "actuator A: not buildable: the actuator line turns 0.149 turn(s) where lambda = 1, the routing "
                                 "needs 0 there (pointless turning)", "actuator B: not buildable: the actuator line turns 0.123 turn(s) "
                                 "where lambda = 1, the routing needs 0 there (pointless turning)"]
    r = evaluate(p, lines)
    judge(p, r)  # the pipeline's judge keeps the design's own shortfall: exit 1
    assert not r.ok and r.shortfall[-3:] == tuple(unbuilt(p, lines))
    u = unwound(lines, D, False, np.radians([60, 60]))
    assert unbuilt(p, u) == [gap]
    assert np.array_equal(u.theta != 0, lam != 1)  # straight where no actuator: the base rolled to A's start, B's phi0 to its own
    phi = lines.phi(D)
    assert abs(u.phi0[1] - (phi[1, 4] - phi[0, 2])) < 1e-12
    a, b = forward_states(lines, D, states), forward_states(u, D, states)
    assert max(np.abs(a[s].center - b[s].center).max() for s in states) < 1e-12  # every state's shape unchanged


def test_one_line_on_a_fixed_base_keeps_the_base_exactly():
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]], [1.0, 2.0, 3.0]  # turned 90 deg about z, moved
    lam = np.ones((1, 6))
    lam[0, 2:] = 0.7
    truth, states = Lines(("A",), np.full((1, 6), 0.1), lam, [0.0], np.full(6, 2.5), pose), {"a": ("A",)}
    p = ActuatorsProblem("t", D, (Line("A"),), states, targets=sample_states(truth, D, states, 6 * 4 + 1),
                         options=DesignOptions(points_per_segment=4, base="fixed", base_pose=tuple(map(tuple, pose))))
    r = design_actuators(p)
    assert r.ok, r.shortfall
    assert np.array_equal(r.lines.initial_pose, pose) and r.state_metrics["a"]["rmse"] < 0.01


def test_a_solver_built_for_one_problem_serves_another_of_its_structure():
    """The solvers are kept per structure with the data as parameters: a problem designed on a solver built for
    another (other targets, smoothness, lengths) gets the design a fresh build gives, and at most
    settings.ACTUATORS_KEPT solvers stay."""
    th = np.array([np.full(M, 0.05), np.full(M, -0.05)])
    lam = np.array([np.full(M, 0.8), np.full(M, 0.85)])
    states = {"left": ("L",), "right": ("R",)}
    first = _problem(Lines(("L", "R"), th, lam, [0, 2.5], np.full(M, 2.5)), states, widths=(0.5, 0.5))
    other = _problem(Lines(("L", "R"), 1.5 * th, lam - 0.1, [0, 2.5], np.full(M, 2.0)), states, widths=(0.5, 0.5))
    other = dataclasses.replace(other, options=dataclasses.replace(other.options, smooth_theta=0.01))
    A._BUILT.clear()
    fresh = design_actuators(other)
    A._BUILT.clear()
    design_actuators(first)
    (built,) = A._BUILT.values()
    reused = design_actuators(other)
    assert list(A._BUILT.values()) == [built]  # the same solver
    np.testing.assert_allclose(reused.lines.theta, fresh.lines.theta, rtol=0, atol=1e-9)
    np.testing.assert_allclose(reused.lines.lam, fresh.lines.lam, rtol=0, atol=1e-9)
    np.testing.assert_allclose(reused.lines.length, fresh.lines.length, rtol=0, atol=1e-9)
    assert reused.iterations == fresh.iterations and reused.ok
    truth = Lines(("L", "R"), th, lam, [0, 2.5], np.full(M, 2.5))
    for n in (3, 4):  # other structures (points per segment): the oldest solver goes
        design_actuators(ActuatorsProblem("t", D, first.actuators, states, targets=sample_states(truth, D, states, M * n + 1),
                                          options=DesignOptions(points_per_segment=n)))
    assert settings.ACTUATORS_KEPT == 2 and len(A._BUILT) == 2 and built not in A._BUILT.values()


def _base_tip(fixed=False):
    th = np.array([np.full(M, 0.1), np.full(M, -0.05)])
    lam = np.ones((2, M))
    lam[0, : M // 2], lam[1, M // 2:] = 0.7, 0.75
    p = _problem(Lines(("A", "B"), th, lam, [0, 1.9], np.full(M, 2.5)), {"a": ("A",), "b": ("B",), "ab": ("A", "B")})
    if fixed:
        p = dataclasses.replace(p, options=dataclasses.replace(p.options, base="fixed"))
    return p


@pytest.mark.parametrize("fixed", [False, True])
def test_the_blocks_derivatives_are_casadis_own(fixed):
    """The derivatives IPOPT gets, assembled per (state, segment) block, equal CasADi's automatic ones of the whole
    NLP (the same f and g) at a random point: the gradient, the constraint Jacobian and the Lagrangian's Hessian."""
    p = _base_tip(fixed)
    nlp = A._NLP(p, M, np.eye(3), np.full(M, 2.5 / D))
    problem, derivatives = nlp.assembled.ipopt(nlp.p, per_block=True)
    x, par, f, g = problem["x"], problem["p"], problem["f"], problem["g"]
    rng = np.random.default_rng(4)
    xv, pv = rng.uniform(-0.5, 0.5, x.numel()), rng.uniform(0.1, 1.0, par.numel())
    sigma, lam_g = 0.7, rng.normal(size=g.numel())
    own = ca.Function("own", [x, par], [ca.gradient(f, x), ca.jacobian(g, x), ca.triu(ca.hessian(sigma * f + ca.dot(ca.DM(lam_g), g), x)[0])])
    grad, jac, hess = (np.array(ca.densify(v)) for v in own(xv, pv))
    np.testing.assert_allclose(np.array(derivatives["grad_f"](xv, pv)[1]).ravel(), grad.ravel(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.array(ca.densify(derivatives["jac_g"](xv, pv)[1])), jac, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.array(ca.densify(derivatives["hess_lag"](xv, pv, sigma, lam_g))), hess, rtol=1e-9, atol=1e-9)


def test_compiled_blocks_take_the_interpreted_steps(monkeypatch, tmp_path):
    """One file, one design: the blocks compiled (later runs) give the design of the interpreted ones (a first run,
    while the compiler works) exactly."""
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    monkeypatch.setenv("VINE_NLP_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("VINE_NLP_CFLAGS", "-O0")
    if compiled.compiler() is None:
        pytest.skip("no C compiler on this machine")
    th = np.array([np.full(M, 0.05), np.full(M, -0.05)])
    lam = np.array([np.full(M, 0.8), np.full(M, 0.85)])
    p = _problem(Lines(("L", "R"), th, lam, [0, 2.5], np.full(M, 2.5)), {"left": ("L",), "right": ("R",)}, widths=(0.5, 0.5))
    A._BUILT.clear()
    fast = design_actuators(p)
    assert sorted(tmp_path.rglob("blk-*.so"))  # the segment blocks (the first segment's and the others') compiled
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    A._BUILT.clear()
    slow = design_actuators(p)
    assert fast.ok and fast.iterations == slow.iterations
    for got, want in ((fast.lines.theta, slow.lines.theta), (fast.lines.lam, slow.lines.lam), (fast.lines.length, slow.lines.length)):
        np.testing.assert_array_equal(got, want)
    A._BUILT.clear()
