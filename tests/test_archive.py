"""Result archives: round trip, the archived phi, the model reproduces archived shapes, atomic writes."""

import math

import h5py
import numpy as np
import pytest

from vine_nlp import __version__
from vine_nlp.design.common import evaluate, pair_points
from vine_nlp.design.nlp import design_nlp
from vine_nlp.design.problem import (
    Actuator,
    DesignOptions,
    DesignProblem,
    ForwardProblem,
    Routing,
)
from vine_nlp.design.result import forward_shape, run_forward
from vine_nlp.io import archive as archive_module
from vine_nlp.io.archive import Archive, load_archive, write_archive

D = 2.43
N_PER_SEGMENT = 4
FORWARD_SOURCE = """name = "wave"
units = "cm"
[tube]
diameter = 2.43
[routing]
length = 40.0
segment_length = 4.0
theta_deg = [5, 16, 24, 24, 19, 8, -4, -13, -15, -10]
lambda = 0.75
"""
DESIGN_SOURCE = """name = "small-design"
units = "cm"
[tube]
diameter = 2.43
[target]
curve = "points"
file = "target.csv"
[actuator]
kind = "tendon"
lambda_min = 0.4
theta_max_deg = 60.0
[design]
points_per_segment = 4
"""


def wave_routing(m=10, dl=4.0):
    s = np.arange(m) * dl
    return Routing(np.radians(20 * np.sin(0.15 * s) + 5), 0.7 + 0.1 * np.cos(0.2 * s), np.full(m, dl))


def forward_archive() -> Archive:
    result = run_forward(ForwardProblem("wave", D, wave_routing()))
    return Archive("wave", "forward", FORWARD_SOURCE, D, runs={"forward": result}, created="2024-05-06T07:08:09+00:00")


def design_problem(kind="tendon") -> DesignProblem:
    target = forward_shape(wave_routing(), D, per_segment=N_PER_SEGMENT).center  # 41 points, 10 segments
    return DesignProblem("small-design", D, target, Actuator(kind=kind), DesignOptions(points_per_segment=N_PER_SEGMENT))


@pytest.fixture(scope="module")
def design():
    problem = design_problem()
    return problem, design_nlp(problem)


def design_archive(problem, result) -> Archive:
    return Archive(
        "small-design", "design", DESIGN_SOURCE, D, target=problem.target, runs={"nlp": result},
        extra={"measured/points": problem.target[::3] + 0.01},
    )


def assert_archives_equal(a: Archive, b: Archive):
    for key in ("name", "kind", "source", "diameter", "units", "software_version", "format_version"):
        assert getattr(a, key) == getattr(b, key), key
    if a.target is None:
        assert b.target is None
    else:
        np.testing.assert_array_equal(a.target, b.target)
    assert a.extra.keys() == b.extra.keys()
    for key in a.extra:
        np.testing.assert_array_equal(a.extra[key], b.extra[key])
    assert set(a.runs) == set(b.runs)
    for name, r in a.runs.items():
        q = b.runs[name]
        for key in ("method", "status", "solve_time_s", "iterations", "metrics", "stats", "diameter"):
            assert getattr(r, key) == getattr(q, key), (name, key)
        for key in ("theta", "lam", "length", "initial_pose"):
            np.testing.assert_array_equal(getattr(r.routing, key), getattr(q.routing, key))
        for key in ("center", "inner", "outer"):
            np.testing.assert_array_equal(getattr(r.shape, key), getattr(q.shape, key))
        np.testing.assert_array_equal(r.phi, q.phi)


def test_forward_round_trip(tmp_path):
    a = forward_archive()
    path = tmp_path / "forward.h5"
    write_archive(path, a)
    b = load_archive(path)
    assert_archives_equal(a, b)
    assert b.created == a.created
    with h5py.File(path, "r") as h5:
        assert h5.attrs["format"] == "vine_nlp/result"
        assert h5.attrs["format_version"] == 1
        assert h5.attrs["software_version"] == __version__
        assert h5.attrs["units"] == "cm"
        assert h5["problem"].attrs["source"] == FORWARD_SOURCE
        assert h5["problem"].attrs["kind"] == "forward"
        assert h5["tube"].attrs["diameter"] == D
        assert set(h5["runs/forward/design"]) == {"theta", "lambda", "length", "phi", "initial_pose"}
        assert h5["runs/forward/design/initial_pose"].shape == (4, 4)
        assert h5["runs/forward/shape/center"].shape[1] == 3


def test_design_round_trip(tmp_path, design):
    problem, result = design
    a = design_archive(problem, result)
    path = tmp_path / "design.h5"
    write_archive(path, a)
    b = load_archive(path)
    assert_archives_equal(a, b)
    assert b.created  # stamped on write (ISO 8601)
    assert b.created[:4].isdigit() and "T" in b.created
    with h5py.File(path, "r") as h5:
        assert h5["target/points"].shape == problem.target.shape
        g = h5["runs/nlp"]
        assert g.attrs["method"] == "nlp" and g.attrs["status"] == result.status
        assert g.attrs["iterations"] == result.iterations
        assert set(g["metrics"].attrs) >= {"rmse", "max_error", "tv_theta", "tv_lambda"}
        # design runs: shape row i pairs with target row i
        assert g["shape/center"].shape == problem.target.shape


@pytest.mark.parametrize("which", ["forward", "design"])
def test_archived_phi_is_the_papers_sum(tmp_path, design, which):
    a = forward_archive() if which == "forward" else design_archive(*design)
    path = tmp_path / "a.h5"
    write_archive(path, a)
    with h5py.File(path, "r") as h5:
        (run,) = h5["runs"]
        d = h5["runs"][run]["design"]
        theta, length, phi = d["theta"][()], d["length"][()], d["phi"][()]
        diameter = h5["tube"].attrs["diameter"]
    assert phi.shape == (theta.size + 1,)
    assert phi[0] == 0.0
    # paper eq. phi(s_j): (2/D) sum_k tan(theta_k) dl_k
    expected = np.concatenate([[0.0], 2.0 / diameter * np.cumsum(np.tan(theta) * length)])
    np.testing.assert_allclose(phi, expected, rtol=1e-12, atol=1e-12)


def test_model_reproduces_archived_forward_shape(tmp_path):
    path = tmp_path / "forward.h5"
    write_archive(path, forward_archive())
    b = load_archive(path)
    r = b.runs["forward"]
    shape = forward_shape(r.routing, b.diameter)
    for key in ("center", "inner", "outer"):
        np.testing.assert_allclose(getattr(shape, key), getattr(r.shape, key), rtol=0, atol=1e-10)
    # rows 0 and P-1 are the base and the tip
    np.testing.assert_allclose(r.shape.center[0], r.routing.initial_pose[:3, 3], atol=1e-12)


def test_model_reproduces_archived_design_shape(tmp_path, design):
    problem, result = design
    path = tmp_path / "design.h5"
    write_archive(path, design_archive(problem, result))
    b = load_archive(path)
    r = b.runs["nlp"]
    rerun_problem = DesignProblem(b.name, b.diameter, b.target, problem.actuator, problem.options)
    again = evaluate(rerun_problem, r.routing, pair_points(b.target, N_PER_SEGMENT), "nlp")
    for key in ("center", "inner", "outer"):
        np.testing.assert_allclose(getattr(again.shape, key), getattr(r.shape, key), rtol=0, atol=1e-10)
    assert again.metrics["rmse"] == pytest.approx(r.metrics["rmse"], abs=1e-10)
    assert again.metrics["max_error"] == pytest.approx(r.metrics["max_error"], abs=1e-10)
    # the inner/outer lines are D apart everywhere
    np.testing.assert_allclose(np.linalg.norm(r.shape.inner - r.shape.outer, axis=1), b.diameter, rtol=1e-12)


def _failing_write(h5, a):
    h5.create_group("problem").attrs["name"] = a.name  # a partial file, then the failure
    raise RuntimeError("disk full")


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_failed_write_leaves_no_file(tmp_path, monkeypatch, error):
    def fail(h5, a):
        h5.create_group("problem")
        raise error("stop")

    monkeypatch.setattr(archive_module, "_write", fail)
    path = tmp_path / "out.h5"
    with pytest.raises(error):
        write_archive(path, forward_archive())
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary file left behind


def test_failed_write_keeps_existing_archive(tmp_path, monkeypatch):
    path = tmp_path / "out.h5"
    good = forward_archive()
    write_archive(path, good)
    before = path.read_bytes()
    monkeypatch.setattr(archive_module, "_write", _failing_write)
    with pytest.raises(RuntimeError, match="disk full"):
        write_archive(path, forward_archive())
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5"]
    monkeypatch.undo()
    assert_archives_equal(good, load_archive(path))


def test_load_rejects_other_hdf5(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as h5:
        h5.attrs["format"] = "something/else"
    with pytest.raises(ValueError, match="not a vine_nlp result archive"):
        load_archive(path)


def test_spam_design_round_trip_keeps_repeated_lambda(tmp_path):
    problem = design_problem(kind="spam")
    result = design_nlp(problem)
    a = Archive("spam", "design", DESIGN_SOURCE.replace('"tendon"', '"spam"'), D, target=problem.target, runs={"nlp": result})
    path = tmp_path / "spam.h5"
    write_archive(path, a)
    b = load_archive(path)
    lam = b.runs["nlp"].routing.lam
    assert lam.shape == (result.routing.segments,)  # repeated for spam
    assert np.ptp(lam) <= 1e-12
    assert math.isfinite(b.runs["nlp"].metrics["rmse"])


@pytest.mark.parametrize(
    "runs, expected",
    [
        (["greedy", "greedy_filtered", "nlp"], "nlp"),
        (["greedy_filtered", "greedy"], "greedy"),
        (["nlp_clearance", "nlp_robust"], "nlp_robust"),
        (["fit", "forward"], "forward"),
        (["custom", "other"], "custom"),
        ([], None),
    ],
)
def test_default_run_is_the_same_for_every_command(runs, expected):
    a = Archive(name="a", kind="design", source="", diameter=D, runs={r: None for r in runs})
    assert a.default_run() == expected
