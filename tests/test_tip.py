"""Tip targets: least actuation for a tip position (and direction) from a fixed base, with a given tube length."""

import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import mutate

from vine_nlp.errors import InputError
from vine_nlp.front.reports import run_lines
from vine_nlp.io.archive import load_archive
from vine_nlp.io.formulations import write_tip_archive
from vine_nlp.io.problem_file import load_problem, parse_problem
from vine_nlp.methods.settings import MIN_LENGTH_FACTOR
from vine_nlp.methods.tip import actuation, design_tip
from vine_nlp.model.chain import chain_frames
from vine_nlp.problem import Actuator, DesignOptions, Routing, TipProblem

ROOT = Path(__file__).resolve().parents[1]
M, D, SEG = 8, 2.0, 3.0


def known_routing(seed):
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 1, M)
    theta = 0.4 * np.sin(2 * np.pi * (s + rng.uniform()))
    lam = 0.7 + 0.2 * np.sin(2 * np.pi * (s + rng.uniform()))
    length = np.full(M, SEG)
    end = chain_frames(theta, lam, length, D)[-1]
    return theta, lam, length, end[:3, 3], end[:3, 0]


def _problem(position, direction=None, objective="contraction", starts=2, length=M * SEG, actuator=Actuator("tendon", 0.4)):
    return TipProblem("tip", D, position, length, M, direction=direction, objective=objective, actuator=actuator,
                      options=DesignOptions(starts=starts))


def _check_bounds(r, pb):
    a = pb.actuator
    assert np.all(np.abs(r.routing.theta) <= a.theta_max + 1e-12)
    assert np.all((r.routing.lam >= a.lambda_min - 1e-12) & (r.routing.lam <= 1 + 1e-12))
    assert r.routing.length.sum() == pytest.approx(pb.length, abs=1e-9)
    assert np.all(r.routing.length >= MIN_LENGTH_FACTOR * pb.length / M - 1e-9)
    np.testing.assert_array_equal(r.routing.initial_pose, pb.initial_pose)  # the base does not move


@pytest.mark.parametrize("seed", [0, 1])
def test_reachable_tip_met_with_no_more_contraction_than_the_known_routing(seed):
    theta, lam, length, tip, _ = known_routing(seed)
    pb = _problem(tip)
    r = design_tip(pb)
    assert r.status == "optimal" and r.metrics["reachable"] == 1.0
    assert r.metrics["tip_error"] < 1e-6
    assert r.metrics["rmse"] == r.metrics["max_error"] == r.metrics["tip_error"]
    end = chain_frames(r.routing.theta, r.routing.lam, r.routing.length, D)[-1]  # independent check
    assert np.linalg.norm(end[:3, 3] - tip) < 1e-6
    assert np.allclose(r.shape.center[-1], end[:3, 3]) and np.allclose(r.shape.center[0], 0.0)
    known = np.sum((1 - lam) * length)
    assert r.metrics["actuation_contraction"] <= known
    _check_bounds(r, pb)


def test_starts_are_tried_until_one_is_optimal():
    _, _, _, tip, _ = known_routing(0)
    r = design_tip(_problem(tip, starts=4))
    status = r.stats["start_status"]
    assert status[-1] == "optimal" and "optimal" not in status[:-1]
    assert r.stats["starts"] == len(status) == len(r.stats["start_objectives"]) <= 4


def test_direction_constraint_holds_and_turns_objective():
    theta, lam, length, tip, tangent = known_routing(2)
    pb = _problem(tip, direction=tangent, objective="turns")
    r = design_tip(pb)
    assert r.converged and r.metrics["tip_error"] < 1e-6
    end = chain_frames(r.routing.theta, r.routing.lam, r.routing.length, D)[-1]
    assert np.dot(end[:3, 0], tangent) > 1 - 1e-10 and r.metrics["direction_error"] < 1e-6
    known = actuation(Routing(theta=theta, lam=lam, length=length), D)
    assert r.metrics["actuation_turning"] <= known["actuation_turning"]
    _check_bounds(r, pb)


def test_spam_actuator_keeps_one_lambda():
    _, _, _, tip, _ = known_routing(3)
    pb = _problem(tip, actuator=Actuator("spam", 0.5), starts=2)
    r = design_tip(pb)
    assert r.converged and r.metrics["tip_error"] < 1e-6
    assert np.ptp(r.routing.lam) == 0.0
    _check_bounds(r, pb)


def test_tip_farther_than_the_tube_is_infeasible():
    pb = _problem([M * SEG + 1.0, 0.0, 0.0])  # straight ahead, 1 cm beyond the tube's reach
    r = design_tip(pb)
    assert r.status == "infeasible" and not r.converged and r.metrics["reachable"] == 0.0
    assert "farther" in r.stats["infeasible_reason"]
    assert r.metrics["tip_error"] == pytest.approx(1.0, abs=1e-4)  # the nearest approach: the straight tube
    _check_bounds(r, pb)


def test_archive_and_report(tmp_path):
    _, _, _, tip, tangent = known_routing(0)
    pb = _problem(tip, direction=tangent, starts=1)
    r = design_tip(pb)

    class PF:
        name, source, units, problem = "tip", "# source", "cm", pb

    path = tmp_path / "tip.h5"
    write_tip_archive(path, PF, r)
    with h5py.File(path, "r") as h5:
        assert h5["problem"].attrs["kind"] == "tip"
        np.testing.assert_allclose(h5["tip/position"][()], tip)
        np.testing.assert_allclose(h5["tip/direction"][()], tangent / np.linalg.norm(tangent))
        m = h5["runs/tip/metrics"].attrs
        assert m["tip_error"] == m["rmse"] == m["max_error"]
    a = load_archive(path)
    assert a.runs["tip"].status == r.status and a.target is None
    lines = run_lines("tip", r, pb, "cm")
    assert lines[0].startswith("tip: optimal, tip reachable") and "direction error" in lines[1]


# ------------------------------------------------------------------ problem files

TIP = """
name = "t"
[tube]
diameter = 2.0
[tip]
position = [10.0, 5.0, 3.0]
length = 30.0
"""


def _parse(text, tmp_path):
    import tomllib

    return parse_problem(tomllib.loads(text), str(tmp_path / "p.toml"), text)


def test_problem_file_tip(tmp_path):
    p = _parse(TIP, tmp_path).problem
    assert isinstance(p, TipProblem) and p.segments == 10 and p.objective == "contraction" and p.direction is None
    assert p.options.starts == 4 and np.array_equal(p.initial_pose, np.eye(4))
    text = TIP + "direction = [0, 0, 2]\nsegments = 6\nobjective = 'turns'\n[actuator]\nkind = 'spam'\n[design]\nstarts = 1\n"
    pf = _parse(text, tmp_path)
    assert pf.kind == "tip"
    p = pf.problem
    assert np.allclose(p.direction, [0, 0, 1]) and p.segments == 6 and p.objective == "turns"
    assert p.actuator.kind == "spam" and p.options.starts == 1


@pytest.mark.parametrize(
    "extra, message",
    [
        ("direction = [0, 0, 0]\n", "tip.direction: must be a nonzero vector"),
        ("segments = 0\n", "tip.segments: must be an integer >= 1"),
        ("objective = 'least'\n", "tip.objective: must be one of 'contraction', 'turns'"),
        ("initial_pose = [[1, 0, 0, 0]]\n", "tip.initial_pose: must be a 4 x 4 array"),
        ("postion = [1, 2, 3]\n", "tip.postion: unknown key; did you mean 'position'?"),
        ("[target]\ncurve = 'trefoil'\n", "target: not used in a tip problem"),
    ],
)
def test_problem_file_tip_errors(tmp_path, extra, message):
    with pytest.raises(InputError) as info:
        _parse(TIP + extra, tmp_path)
    assert message in str(info.value)


def test_problem_file_tip_required_keys(tmp_path):
    with pytest.raises(InputError, match="tip.length: missing"):
        _parse(TIP.replace("length = 30.0\n", ""), tmp_path)
    with pytest.raises(InputError, match="tip.position: must be a list of 3 numbers"):
        _parse(TIP.replace("[10.0, 5.0, 3.0]", "[10.0, 5.0]"), tmp_path)


def test_bundled_tip_problem_parses():
    pf = load_problem(ROOT / "problems" / "tip-target.toml")
    p = pf.problem
    assert pf.kind == "tip" and p.segments == 20 and np.allclose(p.direction, [0, 0, 1])
    assert np.linalg.norm(p.position) < p.length and math.isclose(p.length, 100.0)


# ------------------------------------------------------------------ fuzz: a problem or an InputError, nothing else

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_junk = st.one_of(st.booleans(), st.integers(-3, 10**6), st.floats(), st.text(max_size=6), st.lists(st.floats(), max_size=4))
_tip = st.fixed_dictionaries(
    {
        "tube": st.fixed_dictionaries({"diameter": st.floats(0.1, 5)}),
        "tip": st.fixed_dictionaries(
            {"position": st.lists(st.floats(-50, 50), min_size=3, max_size=3), "length": st.floats(0.1, 100)},
            optional={
                "direction": st.lists(st.floats(-1, 1), min_size=3, max_size=3),
                "segments": st.integers(1, 50),
                "objective": st.sampled_from(["contraction", "turns"]),
                "initial_pose": st.just(np.eye(4).tolist()),
            },
        ),
    },
    optional={"actuator": st.fixed_dictionaries({}, optional={"kind": st.sampled_from(["spam", "tendon"])})},
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=_tip, key=st.integers(0, 100), junk=_junk)
def test_parse_tip_fuzz(data, key, junk):
    mutate(data, key, ("replace", "delete", "misspell")[key % 3], junk)
    try:
        pf = parse_problem(data, "p.toml", "")
    except InputError as err:
        assert err.file and err.key and err.reason
        return
    p = pf.problem
    assert pf.kind == "tip" and p.length > 0 and p.segments >= 1 and np.all(np.isfinite(p.position))
    assert p.direction is None or abs(np.linalg.norm(p.direction) - 1) < 1e-12
