"""Manufacturing tolerance (first order vs Monte Carlo) and robust design."""

import math

import numpy as np
import pytest

from vine_nlp.analysis.tolerance import (
    Sigmas,
    batch_points,
    point_jacobian,
    tolerance_metrics,
    tolerance_report,
)
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.model import chain_points
from vine_nlp.problem import DesignOptions, DesignProblem

D = 2.0


@pytest.fixture(scope="module")
def designed():
    from conftest import model_target

    tgt, _ = model_target(M=12, n=5, seed=0)
    pb = DesignProblem("tol", D, tgt, options=DesignOptions(points_per_segment=5))
    return pb, design_nlp(pb)


def test_sigmas():
    s = Sigmas.from_degrees(1.0, 0.02, 0.02)
    assert s.theta == pytest.approx(math.radians(1.0))
    np.testing.assert_allclose(s.per_segment([1.0, 3.0]), [[s.theta, 0.02, 0.02], [s.theta, 0.02, 0.06]])
    np.testing.assert_allclose(Sigmas(0, 0, 0.1, relative_length=False).per_segment([1.0, 3.0])[:, 2], [0.1, 0.1])


def test_point_jacobian_matches_finite_differences(designed):
    pb, res = designed
    r = res.routing
    seg = np.array([0, 2, 5, 11, 11])
    frac = np.array([0.3, 0.0, 0.7, 0.5, 1.0])
    P, J = point_jacobian(r, D, seg, frac)
    np.testing.assert_allclose(P, chain_points(r.theta, r.lam, r.length, D, seg, frac, r.initial_pose)[0], atol=1e-12)
    q = np.column_stack([r.theta, r.lam, r.length]).ravel()
    h = 1e-6
    for c in (0, 1, 2, 7, 16, 33, 35):
        qp, qm = q.copy(), q.copy()
        qp[c] += h
        qm[c] -= h
        fp = batch_points(qp[0::3], qp[1::3], qp[2::3], D, seg, frac, r.initial_pose)[0]
        fm = batch_points(qm[0::3], qm[1::3], qm[2::3], D, seg, frac, r.initial_pose)[0]
        np.testing.assert_allclose(J[:, :, c], (fp - fm) / (2 * h), atol=1e-6)


def test_first_order_tip_covariance_matches_monte_carlo(designed):
    pb, res = designed
    rep = tolerance_report(pb, res, Sigmas.from_degrees(0.2, 0.004, 0.004), samples=4000, seed=3)
    fo, mc = rep["first_order"], rep["monte_carlo"]
    assert np.linalg.norm(mc["tip_cov"] - fo["tip_cov"]) < 0.1 * np.linalg.norm(fo["tip_cov"])
    assert mc["tip_std"] == pytest.approx(fo["tip_std"], rel=0.05)
    assert mc["rms_rmse"] == pytest.approx(fo["rmse"], rel=0.05)
    ps = rep["per_segment"]
    assert ps["tip_var"].sum() == pytest.approx(np.trace(fo["tip_cov"]))
    assert ps["mse"].sum() == pytest.approx(fo["mse_increase"])
    assert ps["tip_var"][-1] < ps["tip_var"].max()  # errors near the base move the tip the most
    m = tolerance_metrics(rep)
    assert all(isinstance(v, float) for v in m.values())
    # same seed, same samples
    again = tolerance_report(pb, res, Sigmas.from_degrees(0.2, 0.004, 0.004), samples=50, seed=3)["monte_carlo"]["rmse"]
    np.testing.assert_array_equal(again, tolerance_report(pb, res, Sigmas.from_degrees(0.2, 0.004, 0.004), samples=50, seed=3)["monte_carlo"]["rmse"])


@pytest.mark.parametrize("sigmas", [Sigmas.from_degrees(1.0, 0.02, 0.02), Sigmas(0.01, 0.0, 0.05, relative_length=False)])
def test_robust_term_is_the_first_order_expected_increase(designed, sigmas):
    from vine_nlp.methods.common import pair_points
    from vine_nlp.methods.robust import _robust_start, expected_increase, robust_solver

    pb, res = designed
    expected = tolerance_report(pb, res, sigmas, samples=10)["first_order"]["mse_increase"]
    assert expected_increase(pb, res.routing, sigmas) == pytest.approx(expected, rel=1e-9)
    # the stage blocks' value with the downstream sums where their recursion holds; the rows are met there
    pairing = pair_points(pb.target, pb.options.points_per_segment)
    solver = robust_solver(pb, pairing)
    x, p = _robust_start(pb, pairing, solver, res.routing, sigmas, 2.0)
    assert solver.terms(x, p)["robust"] * D**2 == pytest.approx(2.0 * expected, rel=1e-9)
    g = np.array(solver._g(x, p)).ravel()
    assert np.abs(g).max() < 1e-10


def test_no_lambda_error_without_an_actuator(designed):
    """The physical rule in analyze's tolerance and the robust term: a segment with lambda 1 has no actuator and no
    lambda error (first order and Monte Carlo); an actuated one never builds above 1."""
    import dataclasses

    from vine_nlp.methods.robust import expected_increase
    from vine_nlp.model.routing import Routing

    pb, res = designed
    r, lam_only = res.routing, Sigmas(0.0, 0.02, 0.0)
    part = Routing(theta=r.theta, lam=np.where(np.arange(r.segments) % 3 == 0, 1.0, r.lam), length=r.length, initial_pose=r.initial_pose)
    rep = tolerance_report(pb, dataclasses.replace(res, routing=part), lam_only, samples=200, seed=1)
    by = rep["per_segment"]["mse_by_param"]
    assert np.all(by[::3, 1] == 0.0) and np.all(by[1::3, 1] > 0.0)
    assert expected_increase(pb, part, lam_only) == pytest.approx(rep["first_order"]["mse_increase"], rel=1e-9)
    flat = dataclasses.replace(res, routing=Routing(theta=r.theta, lam=np.ones(r.segments), length=r.length, initial_pose=r.initial_pose))
    rep = tolerance_report(pb, flat, lam_only, samples=50, seed=1)
    assert rep["first_order"]["mse_increase"] == 0.0 and np.all(rep["monte_carlo"]["rmse"] == rep["nominal"]["rmse"])
    # lambda 0.999 everywhere: an error above 0.001 builds 1, so the errors are one-sided: about min(0, e), whose
    # standard deviation is 0.58 sigma (against lambdas drawn without the rule)
    near = Routing(theta=r.theta, lam=np.full(r.segments, 0.999), length=r.length, initial_pose=r.initial_pose)
    mc = tolerance_report(pb, dataclasses.replace(res, routing=near), lam_only, samples=400, seed=1)["monte_carlo"]
    drawn = batch_points(r.theta, 0.999 + 0.02 * np.random.default_rng(0).standard_normal((400, r.segments)), r.length, D,
                         [r.segments - 1], [1.0], r.initial_pose)
    assert 0.5 < mc["tip_std"] / float(np.sqrt(np.trace(np.cov(drawn[:, 0].T)))) < 0.7


@pytest.mark.slow
def test_robust_design_lowers_the_monte_carlo_error(designed):
    from vine_nlp.methods.robust import design_robust

    pb, res = designed
    sg = Sigmas.from_degrees(1.0, 0.02, 0.02)
    rob = design_robust(pb, sg, start=res, samples=1000, seed=1)
    assert rob.converged
    st = rob.stats
    assert st["robust_expected_mse_increase"] < st["robust_expected_mse_increase_start"]
    assert st["robust_expected_rmse"] < st["robust_expected_rmse_start"]
    # checked on the true (nonlinear) chain, the same seeded samples for both designs
    assert st["robust_mc_rms_rmse"] < 0.9 * st["robust_mc_rms_rmse_start"]
    assert st["robust_mc_mean_rmse"] < st["robust_mc_mean_rmse_start"]
    assert rob.metrics["rmse"] > res.metrics["rmse"]  # the price: a less exact nominal shape


def test_tolerance_figure(designed, tmp_path):
    from vine_nlp.front.analysis_plots import clearance_figure, tolerance_figure

    pb, res = designed
    rep = tolerance_report(pb, res, Sigmas.from_degrees(1.0, 0.02, 0.02), samples=200)
    tolerance_figure(rep, tmp_path / "tol.png")
    clearance_figure(res.routing, D, tmp_path / "clear.pdf", units="cm")
    assert (tmp_path / "tol.png").stat().st_size > 10_000 and (tmp_path / "clear.pdf").stat().st_size > 5_000


def test_robust_direct_term_equals_the_differentiated_points():
    """The segment's own points' term, with its dl part in closed form (|d rho / d dl| = u lambda_c), equals
    sum_i w_i |d rho_i / d q diag(sigma)|^2 differentiated through the helix in all three parameters."""
    import casadi as ca

    from vine_nlp.methods.robust import direct_term
    from vine_nlp.model.helix import center_rates
    from vine_nlp.model.segment import twist_parts

    n = 4
    q, u, w, sig = ca.SX.sym("q", 3), ca.SX.sym("u", n), ca.SX.sym("w", n), ca.SX.sym("sig", 3)
    kappa, tau, lc = center_rates(q[0], q[1], 1.0)
    brute = sum(w[i] * ca.sumsqr(ca.jacobian(ca.vertcat(*twist_parts(kappa, tau, u[i] * q[2] * lc)[1]), q) @ ca.diag(sig))
                for i in range(n))
    F = ca.Function("f", [q, u, w, sig], [direct_term(q[0], q[1], q[2], u, w, sig), brute])
    rng = np.random.default_rng(3)
    for qv in ([0.0, 1.0, 2.0], [0.3, 0.7, 1.5], [-0.9, 0.45, 4.0]):  # the straight tube, a helix, a tight one
        a, b = (float(v) for v in F(qv, rng.uniform(0, 1, n), rng.uniform(0, 1, n), [0.02, 0.03, 0.05]))
        assert b > 0 and a == pytest.approx(b, rel=1e-12)
