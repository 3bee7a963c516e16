"""As-built correction of a tube of several actuators (spec "As-built correction", "Several actuators on one tube"):
the bundled base/tip problem built from its known routing with known per-actuator deviations, measured through the
model in one state and in two, corrected by ``vine-nlp correct --state``."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from simulate import draw_line_deviations, simulate_state

from vine_nlp.front.cli import main
from vine_nlp.io.actuators import read_actuators_archive, write_actuators_archive
from vine_nlp.io.calibration import read_calibration
from vine_nlp.io.correction import read_correction
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods.actuators import evaluate
from vine_nlp.methods.correct.pairing import LINE_SIDE, Measurement
from vine_nlp.methods.correct.several import _Model, _pairs, _point, realized
from vine_nlp.model.actuators import Lines
from vine_nlp.model.routing import Sigmas

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "actuators-base-tip.toml"
SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)
TRUTH = (math.radians(1.0), 0.02, 1.02)  # systematic parts: theta offset, lambda offset, length scale
NOISE = 0.05  # 0.5 mm, in cm


def truth() -> Lines:
    """The known routing the bundled problem's targets were made from (problems/data/make_actuators_base_tip.py)."""
    spec = importlib.util.spec_from_file_location("make_bt", ROOT / "problems" / "data" / "make_actuators_base_tip.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.truth()


def design_archive(path, lines: Lines):
    pf = load_problem(PROBLEM)
    write_actuators_archive(path, pf, {"nlp": evaluate(pf.problem, lines, status="optimal")})
    return pf.problem


def measure(path, lines, devs, problem, state, seed):
    pts = simulate_state(lines, devs, problem.diameter, problem.states[state], state, "outer", 150, NOISE, seed)
    np.savetxt(path, pts, delimiter=",", header="x,y,z", comments="")
    return str(path)


def run(argv) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(argv)
    return code, out.getvalue()


def built_rmse(problem, lines, devs) -> dict:
    return {s: m["rmse"] for s, m in evaluate(problem, realized(lines, devs)).state_metrics.items()}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("correct-actuators")
    nominal = truth()
    problem = design_archive(d / "design.h5", nominal)
    devs = draw_line_deviations(nominal, SIGMAS, TRUTH, seed=3)
    base, tip = measure(d / "base.csv", nominal, devs, problem, "base", 4), measure(d / "tip.csv", nominal, devs, problem, "tip", 5)
    out = {"dir": d, "problem": problem, "nominal": nominal, "devs": devs}
    # one state (A alone: B unmeasured), lambda only; two states, lambda and theta
    out["one"] = run(["correct", str(d / "design.h5"), base, "--state", "base", "--adjust", "lambda", "-o", str(d / "one.h5")])
    out["two"] = run(["correct", str(d / "design.h5"), base, tip, "--state", "base", "--state", "tip", "--adjust", "lambda,theta",
                      "-o", str(d / "two.h5")])
    # round 2: the corrected nominal built with the same deviations, measured in the state of both actuators
    corrected = read_actuators_archive(d / "two.h5", "corrected")[1].lines
    both = measure(d / "both.csv", corrected, devs, problem, "both", 6)
    out["chain"] = run(["correct", str(d / "two.h5"), both, "--state", "both", "--adjust", "lambda,theta", "-o", str(d / "three.h5")])
    return out


def _lines(path, run_name):
    return read_actuators_archive(path, run_name)[1].lines


def _deviation(path, name):
    import h5py

    with h5py.File(path, "r") as h5:
        g = h5[f"runs/as_built/actuators/{name}"]
        return {k: g[k][()] for k in ("deviation/theta", "deviation/lambda", "uncertainty/theta", "uncertainty/lambda")}


@pytest.mark.slow
def test_one_state_estimates_the_measured_actuator_and_keeps_the_other_nominal(setup):
    """Estimated within its own uncertainty (the Laplace standard deviations: z-scores of RMS about 1 when the
    estimate is calibrated; 2 allows for the prior's pull on a 20-segment sample); B, never active in a measured
    state, keeps its nominal exactly, as built and corrected."""
    code, text = setup["one"]
    d, nominal, devs = setup["dir"], setup["nominal"], setup["devs"]
    assert code in (0, 1)
    assert "  actuator B: not measured, kept nominal" in text.splitlines()
    act = nominal.lam[0] < 1
    dv = _deviation(d / "one.h5", "A")
    z_lam = (dv["deviation/lambda"] - devs[0].lam)[act] / dv["uncertainty/lambda"][act]
    z_th = (dv["deviation/theta"] - devs[0].theta) / dv["uncertainty/theta"]
    assert np.sqrt(np.mean(z_lam**2)) < 2 and np.sqrt(np.mean(z_th**2)) < 2
    assert np.all(dv["uncertainty/lambda"][act] < SIGMAS.lam)  # the measurement taught something beyond the prior
    b = _deviation(d / "one.h5", "B")
    assert np.all(b["deviation/theta"] == 0) and np.all(b["deviation/lambda"] == 0)
    for run_name in ("as_built", "corrected"):
        got = _lines(d / "one.h5", run_name)
        assert np.array_equal(got.theta[1], nominal.theta[1]) and np.array_equal(got.lam[1], nominal.lam[1])
    corrected = _lines(d / "one.h5", "corrected")
    assert np.array_equal(corrected.theta, nominal.theta)  # lambda alone: theta and the lengths as built
    assert np.array_equal(corrected.length, nominal.length)
    # both routes predicted and written, the one asked for taken
    routes = [ln for ln in text.splitlines() if "predicted RMSE" in ln]
    assert len(routes) == 2 and "corrected   lambda (" in text
    theta_route = _lines(d / "one.h5", "corrected_lambda_theta")
    assert np.array_equal(_lines(d / "one.h5", "corrected_lambda").lam, corrected.lam) and not np.array_equal(theta_route.theta, nominal.theta)


@pytest.mark.slow
def test_corrections_land_the_measured_states_near_their_targets(setup):
    """Built with the same deviations, the corrected nominal lands every measured state nearer its target than the
    robot as built; with lambda and theta from two states, each within 30 % of its error as built (one round from
    0.5 mm noise: the rest is the estimate's error); the prediction stored in the archive is what the build realizes
    within a tenth of the error as built."""
    problem, nominal, devs, d = setup["problem"], setup["nominal"], setup["devs"], setup["dir"]
    before = built_rmse(problem, nominal, devs)
    one = built_rmse(problem, _lines(d / "one.h5", "corrected"), devs)
    assert one["base"] < 0.8 * before["base"]
    two = built_rmse(problem, _lines(d / "two.h5", "corrected"), devs)
    for s in ("base", "tip"):
        assert two[s] < 0.3 * before[s], (s, two[s], before[s])
    _, r, _ = read_actuators_archive(d / "two.h5", "corrected")
    for s in ("base", "tip"):  # predicted with the estimated deviations: close to what the true ones realize
        assert abs(r.state_metrics[s]["rmse"] - two[s]) < 0.1 * before[s]


@pytest.mark.slow
def test_bounds_of_the_physical_rule_hold(setup):
    """lambda <= 1 everywhere, exactly 1 where the nominal has no actuator, in the estimate and the corrections."""
    d, nominal = setup["dir"], setup["nominal"]
    none = nominal.lam >= 1
    for name in ("one.h5", "two.h5", "three.h5"):
        for run_name in ("as_built", "corrected", "corrected_lambda", "corrected_lambda_theta"):
            lam = _lines(d / name, run_name).lam
            assert np.all(lam <= 1.0) and np.all(lam[none] == 1.0), (name, run_name)
            assert np.all(lam[~none] >= 0.4)


@pytest.mark.slow
def test_a_correction_archive_chains_and_every_door_reads_it(setup, tmp_path):
    d = setup["dir"]
    code, text = setup["chain"]
    assert code in (0, 1), text
    a, state = read_correction(d / "three.h5")
    assert a.kind == "actuators" and state.attrs["built_run"] == "corrected" and len(state.builds) == 2
    assert sorted({(m.state, m.build) for m in state.measurements}) == [("base", 0), ("both", 1), ("tip", 0)]
    assert a.extra["measured/base/points"].shape == (150, 3) and a.extra["measured/both/points"].shape == (150, 3)
    assert np.array_equal(state.builds[1].lam, _lines(d / "two.h5", "corrected").lam)
    assert {"nlp", "as_built", "corrected"} <= set(a.runs)
    code, shown = run(["show", str(d / "three.h5")])
    assert code == 0 and "run corrected" in shown and "state both (A, B)" in shown
    for ext in ("svg", "dxf"):
        assert run(["template", str(d / "three.h5"), "--run", "corrected", "-o", str(tmp_path / f"t.{ext}")])[0] == 0
    assert run(["export", str(d / "three.h5"), "--run", "corrected", "--state", "both", "-o", str(tmp_path / "t.stl")])[0] == 0
    assert main(["template", str(d / "three.h5"), "--changes", "-o", str(tmp_path / "c.svg")]) == 2  # --changes: one actuator's
    assert not (tmp_path / "c.svg").exists()
    # calibrate pools the systematic parts of correction archives of several actuators (one method, every line)
    assert run(["calibrate", str(d / "two.h5"), str(d / "one.h5"), "-o", str(tmp_path / "cal.toml")])[0] == 0
    cal = read_calibration(tmp_path / "cal.toml")
    assert cal.prototypes == 2 and abs(cal.lambda_offset - TRUTH[1]) < 3 * cal.lambda_offset_se + 0.005


# ------------------------------------------------------------------ bad input: one line, exit 2, nothing written


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    d = tmp_path_factory.mktemp("plain")
    nominal = truth()
    problem = design_archive(d / "design.h5", nominal)
    measure(d / "m.csv", nominal, draw_line_deviations(nominal, SIGMAS, TRUTH, seed=1), problem, "base", 2)
    straight = Lines(nominal.names, nominal.theta, np.vstack([nominal.lam[0], np.ones(nominal.segments)]), nominal.phi0, nominal.length)
    design_archive(d / "straight.h5", straight)
    return d


@pytest.mark.parametrize("extra, key, reason", [
    (["--state", "nope"], "{design}: --state", "no state 'nope' (states: base, tip, both)"),
    (["--state", "base", "--state", "tip"], "command line: --state", "one state for all files or one per file (1), got 2"),
    ([], "command line: --state", "one state for all files or one per file (1), got 0; the archive's states: base, tip, both"),
    (["--state", "base", "--free-pose"], "command line: --free-pose", "not for an archive of several actuators yet (measure in its frame)"),
    (["--state", "base", "--plot", "f.png"], "f.png: --plot", "not for an archive of several actuators yet (`vine-nlp show OUT.h5` prints "
     "each state's error as built and corrected)"),
], ids=["unknown", "count", "missing", "free-pose", "plot"])
def test_bad_states_are_one_line(plain, capsys, extra, key, reason):
    out = plain / "out.h5"
    assert main(["correct", str(plain / "design.h5"), str(plain / "m.csv"), "-o", str(out), *extra]) == 2
    assert capsys.readouterr().err == f"error: {key.format(design=plain / 'design.h5')}: {reason}\n"
    assert not out.exists()


def test_a_state_whose_actuators_have_none_is_refused(plain, capsys):
    out = plain / "out.h5"
    assert main(["correct", str(plain / "straight.h5"), str(plain / "m.csv"), "--state", "tip", "-o", str(out)]) == 2
    assert capsys.readouterr().err == (f"error: {plain / 'straight.h5'}: --state: state 'tip': its actuators (B) have no actuator on any "
                                       "segment of run nlp: its shape is straight and shows no deviation\n")
    assert not out.exists()


def test_state_on_an_archive_of_one_actuator_is_refused(tmp_path, capsys):
    from vine_nlp.io.archive import Archive, write_archive
    from vine_nlp.methods.common import evaluate as evaluate_one
    from vine_nlp.methods.common import pair_points
    from vine_nlp.model.routing import Routing
    from vine_nlp.problem import DesignProblem

    target = np.arange(9)[:, None] * [1.0, 0.0, 0.0]
    problem = DesignProblem("one", 2.0, target)
    run_ = evaluate_one(problem, Routing(theta=np.zeros(4), lam=np.full(4, 0.8), length=np.full(4, 2.0)), pair_points(target, 2), "nlp")
    path = tmp_path / "one.h5"
    write_archive(path, Archive("one", "design", "", 2.0, target=target, runs={"nlp": run_}))
    np.savetxt(tmp_path / "m.csv", np.arange(36.0).reshape(12, 3) * 0.1, delimiter=",")
    assert main(["correct", str(path), str(tmp_path / "m.csv"), "--state", "a", "-o", str(tmp_path / "o.h5")]) == 2
    assert capsys.readouterr().err == (f"error: {path}: --state: an archive of one actuator has no states (--state is for archives "
                                       "of several actuators)\n")
    assert not (tmp_path / "o.h5").exists()


def test_the_residuals_jacobian_by_the_chain_rule_is_casadis_own():
    """The estimate's residuals and their Jacobian (each point's residual in its segment's frame, times that frame's
    derivative in the parameters) equal CasADi's automatic Jacobian of the same residuals written whole, at a random
    point: two measurements (states base and tip), the point-major order, the weight."""
    problem, nominal = load_problem(PROBLEM).problem, truth()
    devs = draw_line_deviations(nominal, SIGMAS, TRUTH, seed=2)
    D = problem.diameter
    ms = [Measurement(simulate_state(nominal, devs, D, problem.states[s], s, "outer", 40, NOISE, seed), state=s)
          for s, seed in (("base", 7), ("tip", 8))]
    model = _Model([nominal], problem.states, [0, 1], D, [a.actuator.lambda_min for a in problem.actuators])
    pairs = _pairs([nominal], [d for d in devs], problem.states, ms, D)
    z = np.random.default_rng(5).normal(0.0, 0.02, model.n)
    for m, pr in zip(ms, pairs):
        chain = model.chain(m.state, 0)
        whole = ca.vertcat(*[_point(D)(ca.vertcat(ca.vec(chain[j][0]), chain[j][1], *chain[j][2:]), f, LINE_SIDE[m.line] * D, m.points[i], pr.tangent[i])
                             for i, (j, f) in enumerate(zip(pr.seg, pr.frac))]) * 2.0
        fn = ca.Function("whole", [model.z], [whole, ca.jacobian(whole, model.z)])
        r, J = (np.asarray(ca.densify(v)) for v in fn(z))
        np.testing.assert_allclose(model.residuals(z, m, pr, 2.0), r.ravel(), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(model.residuals(z, m, pr, 2.0, jacobian=True), J, rtol=1e-9, atol=1e-10)
