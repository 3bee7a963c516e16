"""Fatrop on the transcription's stage form: the same NLP as the plain chain, the same designs as IPOPT
where its functions are compiled, and IPOPT where they are not or where Fatrop fails."""

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from texts import TINY_TREFOIL

from vine_nlp.front.cli import main
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import compiled
from vine_nlp.methods.common import geometric_guess, pair_points
from vine_nlp.methods.nlp import design_bounds, design_nlp, get_fatrop, nlp_parameters, nlp_spec, start_x
from vine_nlp.methods.structure import Structure
from vine_nlp.methods.transcription import Smoothness, SoftTip, Solver, Spec, fatrop_safe
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("fatrop-cache")  # one compile per structure for the whole module


@pytest.fixture
def codegen(monkeypatch, cache):
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    monkeypatch.setenv("VINE_NLP_CACHE_DIR", str(cache))
    monkeypatch.setenv("VINE_NLP_CFLAGS", "-O0")
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(logging.getLogger("vine_nlp"), "propagate", True)
    if compiled.compiler() is None:
        pytest.skip("no C compiler on this machine")


def _problem(make_target, **options):
    target, truth = make_target(M=6, n=3, seed=4)
    opts = DesignOptions(points_per_segment=3, budget=0.0)
    return DesignProblem("fatrop", 2.0, target, options=dataclasses.replace(opts, **options)), truth


def test_stage_form_is_the_plain_nlp():
    """Same objective and terms at any x whose carried copies hold; rows: the plain ones negated, then zeros."""
    plain = Solver(nlp_spec(6, 3, False))
    stage = Solver(Spec(Structure(6, 3, stages=True), (Smoothness(), SoftTip())))
    rng = np.random.default_rng(7)
    values = {"cells": rng.uniform(0.1, 1.0, (15, 6)), "R0g": Rotation.random(random_state=2).as_matrix().ravel(order="F"),
              "smooth": [0.3, 0.2], "h": rng.uniform(0.5, 1.5, 5), "L": 4.0, "tip": rng.normal(size=3), "wtip": 0.5}
    x = rng.normal(size=plain.layout.size) * 0.5
    v = plain.unpack(x)
    xs = stage.pack_x(v["theta"], v["lam"], v["dl"], v["frames"], poses=v["poses"])
    pp, ps = plain.pack_params(values), stage.pack_params(values)
    assert stage.terms(xs, ps) == pytest.approx(plain.terms(x, pp), rel=1e-13)
    gp, gs = np.array(plain._g(x, pp)).ravel(), np.array(stage._g(xs, ps)).ravel()
    assert gs.size == gp.size + 2 * 6
    lay = stage.layout
    np.testing.assert_allclose(gs[:12], -gp[:12], atol=1e-14)  # the pose rows
    per_stage = gs[12:].reshape(6, 14)
    np.testing.assert_allclose(per_stage[:, :2], 0.0, atol=1e-15)  # the carried (theta_j, lam_j)
    np.testing.assert_allclose(per_stage[:, 2:].ravel(), -gp[12:], atol=1e-14)
    # variables in stage order: stage j+1's state (c_j, X_{j+1}) right after stage j's controls
    assert np.all(lay.carry[:, 0] == lay.dl + 1) and np.all(lay.X[1:, 0, 0] == lay.carry[:, 1] + 1)


def test_fatrop_designs_what_ipopt_designs(codegen, make_target):
    problem, truth = _problem(make_target)
    fat = design_nlp(problem)
    ipopt = design_nlp(dataclasses.replace(problem, options=dataclasses.replace(problem.options, solver="ipopt")))
    assert (fat.status, fat.stats["solver"], ipopt.stats["solver"]) == ("optimal", "fatrop", "ipopt")
    assert fat.stats["objective"] == pytest.approx(ipopt.stats["objective"], rel=1e-6)
    np.testing.assert_allclose(fat.routing.theta, ipopt.routing.theta, atol=1e-4)
    assert fat.metrics["rmse"] < 1e-3 * problem.diameter  # a target the model makes: followed closely
    # a built solver serves the next design
    assert design_nlp(problem).stats["build_time_s"] == 0.0


def test_fatrop_keeps_active_bounds(codegen, make_target):
    """theta_max below the true routing's largest |theta|: bounds active, the answer inside them, as IPOPT's."""
    problem, truth = _problem(make_target)
    cap = 0.6 * float(np.max(np.abs(truth.theta)))
    problem = dataclasses.replace(problem, actuator=Actuator(theta_max=cap))
    fat = design_nlp(problem)
    ipopt = design_nlp(dataclasses.replace(problem, options=dataclasses.replace(problem.options, solver="ipopt")))
    assert (fat.status, fat.stats["solver"]) == ("optimal", "fatrop")
    assert np.max(np.abs(fat.routing.theta)) <= cap
    assert np.sum(np.abs(fat.routing.theta) > cap - 1e-6) >= 1
    assert fat.stats["objective"] == pytest.approx(ipopt.stats["objective"], rel=1e-5)


def test_ipopt_takes_over_where_fatrop_fails(codegen, make_target):
    problem, _ = _problem(make_target, hessian="gauss-newton", max_iter=2)
    r = design_nlp(problem)
    assert (r.stats["solver"], r.stats["fatrop_status"]) == ("ipopt", "max_iter")
    assert r.iterations == r.stats["fatrop_iterations"] + 2


def test_ipopt_where_nothing_is_compiled_or_fatrop_cannot_take_the_chain(monkeypatch, make_target):
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    assert get_fatrop(6, 3) is None
    problem, _ = _problem(make_target)
    assert design_nlp(problem).stats["solver"] == "ipopt"


def test_solver_key_in_problem_files(tmp_path, capsys):
    path = tmp_path / "p.toml"
    path.write_text(TINY_TREFOIL + 'solver = "ipot"\n')
    out = tmp_path / "out.h5"
    assert main(["design", str(path), "-o", str(out)]) == 2
    assert capsys.readouterr().err == f"error: {path}: design.solver: must be one of 'auto', 'ipopt'; did you mean 'ipopt'?\n"
    assert not out.exists()


def test_fatrop_gets_only_what_it_can_take(codegen, make_target):
    """Fatrop loops without end on a non-finite evaluation: such data never reach it; where it raises
    (inconsistent bounds), the solve is a failed one, not an exception."""
    x, p, lo, hi = np.zeros(3), np.ones(4), -np.ones(3), np.ones(3)
    assert fatrop_safe(x, p, lo, hi)
    assert not fatrop_safe(x, np.r_[p[:3], np.nan], lo, hi)
    assert not fatrop_safe(np.r_[x[:2], np.inf], p, lo, hi)
    assert not fatrop_safe(x, p, lo, np.r_[hi[:2], -2.0])
    problem, _ = _problem(make_target)
    solver = get_fatrop(6, 3, 50)
    pairing = pair_points(problem.target, 3)
    guess = geometric_guess(problem, pairing)
    lbx, ubx = solver.bounds(*design_bounds(problem, pairing))
    x0 = start_x(solver, guess, problem.diameter)
    j = solver.layout.theta[2]
    lbx[j] = ubx[j] + 0.1
    x, status, st = solver.solve(x0, solver.pack_params(nlp_parameters(problem, pairing, guess.initial_pose[:3, :3])), lbx, ubx)
    assert (status, st["solver"], st["iterations"]) == ("failed", "fatrop", 0)


@pytest.mark.parametrize("name", ["trefoil-m4", "bezier-a", "bezier-b", "bezier-c"])
def test_fatrop_on_the_paper_cases_ends_where_ipopt_does(codegen, name):
    problem = load_problem(PROBLEMS / f"{name}.toml").problem
    fat = design_nlp(problem)
    ipopt = design_nlp(dataclasses.replace(problem, options=dataclasses.replace(problem.options, solver="ipopt")))
    assert (fat.status, fat.stats["solver"]) == ("optimal", "fatrop")
    assert fat.stats["objective"] == pytest.approx(ipopt.stats["objective"], rel=1e-6)
    assert fat.metrics["rmse"] == pytest.approx(ipopt.metrics["rmse"], rel=1e-4)
