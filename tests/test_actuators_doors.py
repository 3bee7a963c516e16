"""The doors of an archive of several actuators on one tube: export, analyze, template, view and animate per state
(spec "Several actuators on one tube"): what each draws or writes is the model's shape of each state."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from vine_nlp.front import export
from vine_nlp.front.cli import main
from vine_nlp.front.states import state_lines
from vine_nlp.io.actuators import read_actuators_archive, write_actuators_archive
from vine_nlp.io.problems import ProblemFile
from vine_nlp.methods.actuators import ActuatorsProblem, Line, evaluate, sample_states
from vine_nlp.model.actuators import Lines, state_shape

D = 2.4
LAM_A = [0.6] * 10 + [1.0] * 10
LAM_B = [1.0] * 10 + [0.7] * 10
FORWARD = f"""name = "two"
[tube]
diameter = {D}
[routing]
length = 20.0
segment_length = 1.0
[[actuators]]
name = "A"
theta_deg = 5.0
lambda = {LAM_A}
[[actuators]]
name = "B"
theta_deg = -3.0
lambda = {LAM_B}
phi0_deg = 180
[[states]]
name = "a"
active = ["A"]
[[states]]
name = "ab"
active = ["A", "B"]
"""
STATES = {"a": ("A",), "b": ("B",), "ab": ("A", "B")}


def lines() -> Lines:
    return Lines(("A", "B"), np.radians([[5.0] * 20, [-3.0] * 20]), [LAM_A, LAM_B], [0.0, np.pi], np.ones(20))


@pytest.fixture(scope="module")
def forward(tmp_path_factory):
    d = tmp_path_factory.mktemp("fwd")
    (d / "p.toml").write_text(FORWARD)
    assert main(["forward", str(d / "p.toml"), "-o", str(d / "o.h5")]) == 0
    return d / "o.h5"


@pytest.fixture(scope="module")
def design(tmp_path_factory):
    """A design archive whose targets the lines meet exactly (three states: A, B, both)."""
    path = tmp_path_factory.mktemp("design") / "d.h5"
    ls = lines()
    problem = ActuatorsProblem("d", D, (Line("A"), Line("B")), STATES, targets=sample_states(ls, D, STATES, 41), units="cm")
    result = evaluate(problem, ls, status="optimal")
    write_actuators_archive(path, ProblemFile(str(path), "# made by the test\n", "actuators", "d", "cm", problem), "nlp", result)
    return path


def segment_ends(ls, active, state):
    M = ls.segments
    return state_shape(ls, D, active, np.r_[np.arange(M), M - 1], np.r_[np.zeros(M), 1.0], state).center


# ---------------------------------------------------------------- export


def test_state_lines_are_the_model_shape_at_every_segment_end():
    ls = lines()
    for s, active in STATES.items():
        seg, frac, shape, paths = state_lines(ls, D, active, s)
        ends = np.flatnonzero(frac == 0)
        assert np.array_equal(seg[ends], np.arange(20)) and frac[-1] == 1.0
        np.testing.assert_allclose(shape.center[np.r_[ends, -1]], segment_ends(ls, active, s), atol=1e-12, rtol=0)
        np.testing.assert_allclose(np.linalg.norm(paths["A"] - shape.center, axis=1), D / 2, atol=1e-12)  # on the wall
        # where a line shapes the tube, it is the state's actuator line
        for name, part in (("A", seg < 10), ("B", seg >= 10)):
            if name in active:
                np.testing.assert_allclose(paths[name][part], shape.inner[part], atol=1e-12, rtol=0)


@pytest.mark.parametrize("ext", [".stl", ".glb"])
def test_export_every_state(forward, tmp_path, capsys, ext):
    out = tmp_path / f"t{ext}"
    assert main(["export", str(forward), "-o", str(out)]) == 0
    _, r, _ = read_actuators_archive(forward)
    for s in ("a", "ab"):
        f = tmp_path / f"t.{s}{ext}"
        scale = 0.01 if ext == ".glb" else 1.0  # cm -> m
        scene = trimesh.load(f, force="scene")
        tube = scene.geometry["tube"] if ext == ".glb" else next(iter(scene.geometry.values()))
        assert tube.is_watertight
        # every ring's center is the state's model shape there (glb keeps the vertices in order)
        ring = export.RING
        _, _, shape, _ = state_lines(r.lines, D, r.stats["states"][s], s)
        centers = np.asarray(tube.vertices[: len(shape.center) * ring]).reshape(-1, ring, 3).mean(axis=1) if ext == ".glb" else None
        if centers is not None:
            np.testing.assert_allclose(centers, shape.center * scale, atol=1e-9)
            assert sorted(scene.geometry) == ["actuator-A", "actuator-B", "tube"]
        else:
            for name in ("A", "B"):
                assert trimesh.load(tmp_path / f"t.{s}.actuator-{name}{ext}").is_watertight
    assert not out.exists()
    assert "run forward state ab (A, B): " in capsys.readouterr().out


def test_export_one_state_into_the_file_named(forward, tmp_path):
    out = tmp_path / "ab.obj"
    assert main(["export", str(forward), "-o", str(out), "--state", "ab"]) == 0
    text = out.read_text()
    assert text.startswith("# vine_nlp tube of two run forward state ab, units cm")
    assert [x for x in text.splitlines() if x.startswith("o ")] == ["o tube", "o actuator-A", "o actuator-B"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ab.obj"]


@pytest.mark.parametrize("argv, message", [
    (["--state", "zz"], "{a}: --state: no state 'zz' (states: a, ab)"),
    (["--run", "nlp"], "{a}: --run: no run 'nlp' in the archive (runs: forward)"),
])
def test_export_bad_state_or_run(forward, tmp_path, capsys, argv, message):
    assert main(["export", str(forward), "-o", str(tmp_path / "t.stl"), *argv]) == 2
    assert capsys.readouterr().err == f"error: {message.format(a=forward)}\n"
    assert list(tmp_path.iterdir()) == []


def test_state_of_a_one_actuator_archive_is_refused(tmp_path, capsys):
    from vine_nlp.io.archive import Archive, write_archive
    from vine_nlp.methods.common import run_forward
    from vine_nlp.problem import ForwardProblem, Routing

    r = Routing(theta=np.zeros(3), lam=np.full(3, 0.7), length=np.ones(3))
    write_archive(tmp_path / "one.h5", Archive("one", "forward", "", D, runs={"forward": run_forward(ForwardProblem("one", D, r))}))
    assert main(["export", str(tmp_path / "one.h5"), "-o", str(tmp_path / "t.stl"), "--state", "a"]) == 2
    assert capsys.readouterr().err == (f"error: {tmp_path / 'one.h5'}: --state: an archive of one actuator has no states "
                                       "(--state is for archives of several actuators)\n")
