"""Multi-shape sPAM design: one routing, K shapes at K contraction levels (known answers, archive, problem files)."""

import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import mutate
from scipy.spatial.transform import Rotation

from vine_nlp.errors import InputError
from vine_nlp.front.figures import draw
from vine_nlp.front.reports import run_lines
from vine_nlp.io.archive import load_archive
from vine_nlp.io.formulations import read_multishape_archive, write_multishape_archive
from vine_nlp.io.problem_file import load_problem, parse_problem
from vine_nlp.methods.multishape import MultiShapeResult, design_multishape
from vine_nlp.methods.transcription import get_solver
from vine_nlp.model import shape_lines
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.problem import Actuator, DesignOptions, MultiShapeProblem

ROOT = Path(__file__).resolve().parents[1]
M, N_PER, D = 10, 4, 2.0
NO_SMOOTH = dict(smooth_theta=0.0, smooth_lambda=0.0)


def family(levels, seed=0, M=M, n=N_PER):
    """Targets made by the forward model: ONE smooth random routing at several lambdas, one random base pose."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 1, M)
    theta = 0.5 * np.sin(2 * np.pi * (s * rng.uniform(0.5, 1.5) + rng.uniform()))
    length = np.full(M, 2.0)
    T0 = np.eye(4)
    T0[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T0[:3, 3] = rng.normal(size=3) * 5
    seg, frac = segment_end_samples(length, n)
    targets = [shape_lines(theta, lam, length, D, seg, frac, T0)[0] for lam in levels]
    return targets, theta, length, T0


def _problem(targets, levels=(), shared_pose=True, starts=1, **opts):
    return MultiShapeProblem(
        "ms",
        D,
        targets,
        levels=levels,
        actuator=Actuator("spam", 0.5),
        options=DesignOptions(points_per_segment=N_PER, starts=starts, **(NO_SMOOTH | opts)),
        shared_pose=shared_pose,
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_known_answer_free_levels_recovered(seed):
    # out of order on purpose: the most actuated target is not the first; inside the buildable band [2/pi + 0.05, 0.95]
    truth = (0.93, 0.7, 0.8)
    targets, theta, length, T0 = family(truth, seed)
    r = design_multishape(_problem(targets))
    assert isinstance(r, MultiShapeResult) and r.status == "optimal"
    for k in range(3):
        assert r.level_metrics[k]["rmse"] < 1e-6
    assert r.metrics["rmse"] < 1e-6
    np.testing.assert_allclose(r.levels, truth, atol=1e-4)
    np.testing.assert_allclose(r.routing.theta, theta, atol=1e-4)
    np.testing.assert_allclose(r.routing.length, length, atol=1e-4)
    for k in range(3):  # one shared base pose
        np.testing.assert_allclose(r.poses[k], T0, atol=1e-5)
    # the Result face is level 0: routing with lambda_0 repeated, shape paired with target 0
    np.testing.assert_allclose(r.routing.lam, np.full(M, r.levels[0]))
    assert r.shape.center.shape == targets[0].shape
    assert np.allclose(r.shapes[1].center, targets[1], atol=1e-5)


def test_fixed_levels_and_a_pose_per_level():
    truth = (0.55, 0.9)
    targets, theta, _, _ = family(truth, seed=3)
    # the same shapes drawn in two unrelated frames: only shared_pose = false can match both
    rot = Rotation.random(random_state=42).as_matrix()
    moved = [targets[0], targets[1] @ rot.T + np.array([10.0, -3.0, 2.0])]
    r = design_multishape(_problem(moved, levels=truth, shared_pose=False))
    assert r.converged and r.metrics["rmse"] < 1e-6
    assert tuple(r.levels) == truth and r.fixed == (True, True)
    assert not np.allclose(r.poses[0], r.poses[1], atol=1e-3)
    np.testing.assert_allclose(np.abs(r.routing.theta), np.abs(theta), atol=1e-4)
    # with one shared pose the same targets cannot both be met
    shared = design_multishape(_problem(moved, levels=truth, shared_pose=True))
    assert shared.metrics["rmse"] > 1e-2


def test_bounds_and_multistart_determinism():
    targets, _, _, _ = family((0.7, 0.9), seed=5)
    pb = MultiShapeProblem(
        "b", D, targets, actuator=Actuator("spam", 0.8, math.radians(20)),
        options=DesignOptions(points_per_segment=N_PER, starts=3, seed=2),
    )
    a, b = design_multishape(pb), design_multishape(pb)
    np.testing.assert_allclose(a.routing.theta, b.routing.theta, atol=1e-12)
    assert a.stats["starts"] == 3 and len(a.stats["start_objectives"]) == 3
    assert a.stats["objective"] <= min(a.stats["start_objectives"]) * (1 + 1e-9)
    assert np.all(np.abs(a.routing.theta) <= math.radians(20) + 1e-9)
    assert np.all((a.levels >= 0.8 - 1e-9) & (a.levels <= 1 + 1e-9))
    assert np.all(a.routing.length > 0)


def test_solver_is_built_once_per_structure():
    targets, _, _, _ = family((0.6, 0.9), seed=6)
    design_multishape(_problem(targets))
    hits = get_solver.cache_info().hits
    targets2, _, _, _ = family((0.7, 0.8), seed=7)
    design_multishape(_problem(targets2))
    assert get_solver.cache_info().hits == hits + 1


def test_archive_layout_round_trip_and_old_readers(tmp_path):
    truth = (0.6, 0.85)
    targets, _, _, _ = family(truth, seed=8)
    pb = _problem(targets)
    r = design_multishape(pb)

    class PF:  # what write_multishape_archive reads of a ProblemFile
        name, source, units, problem = "ms", "# source", "cm", pb

    path = tmp_path / "ms.h5"
    write_multishape_archive(path, PF, r)
    with h5py.File(path, "r") as h5:
        assert h5["problem"].attrs["kind"] == "multishape"
        np.testing.assert_allclose(h5["target/points"][()], targets[0])
        g = h5["runs/multishape"]
        np.testing.assert_allclose(g["design/lambda"][()], np.full(M, r.levels[0]))
        np.testing.assert_allclose(g["design/levels"][()], r.levels)
        for k in range(2):
            np.testing.assert_allclose(h5[f"targets/{k}/points"][()], targets[k])
            lv = g[f"levels/{k}"]
            assert set(lv["shape"]) == {"center", "inner", "outer"}
            assert lv["metrics"].attrs["rmse"] == pytest.approx(r.level_metrics[k]["rmse"])
            assert lv.attrs["lambda"] == pytest.approx(r.levels[k])
    old = load_archive(path)  # the generic reader sees a normal design archive
    assert old.runs["multishape"].metrics["rmse"] == pytest.approx(r.metrics["rmse"])
    np.testing.assert_allclose(old.target, targets[0])
    _, back, tg = read_multishape_archive(path)
    np.testing.assert_allclose(back.levels, r.levels)
    np.testing.assert_allclose(back.shapes[1].center, r.shapes[1].center)
    assert len(tg) == 2 and back.level_metrics[1]["rmse"] == pytest.approx(r.level_metrics[1]["rmse"])
    fig = draw(path, tmp_path / "ms.png")
    assert Path(fig).stat().st_size > 10_000
    lines = run_lines("multishape", back, None, "cm")
    assert len(lines) == 3 and "level 1: lambda" in lines[2]


# ------------------------------------------------------------------ problem files

MS = """
name = "ms"
[tube]
diameter = 2.0
[actuator]
kind = "spam"
[[targets]]
curve = "helix"
radius = 3.0
pitch = 1.0
length = 30.0
samples = 41
lambda = 0.7
[[targets]]
curve = "helix"
radius = 5.0
pitch = 2.0
length = 32.0
samples = 41
"""


def _parse(text, tmp_path):
    import tomllib

    return parse_problem(tomllib.loads(text), str(tmp_path / "p.toml"), text)


def test_problem_file_multishape(tmp_path):
    pf = _parse(MS + "[design]\npoints_per_segment = 4\nshared_pose = false\n", tmp_path)
    assert pf.kind == "multishape" and isinstance(pf.problem, MultiShapeProblem)
    p = pf.problem
    assert p.count == 2 and p.levels == (0.7, None) and not p.shared_pose
    assert p.actuator.kind == "spam" and p.actuator.lambda_min == 0.5
    assert p.options.starts == 4  # multishape default when [design] gives none
    assert _parse(MS.replace('kind = "spam"\n', ""), tmp_path).problem.actuator.kind == "spam"


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda t: t.replace('kind = "spam"', 'kind = "tendon"'), "actuator.kind: must be 'spam' in a multishape problem"),
        (lambda t: t.replace("lambda = 0.7", "lambda = 0.3"), "targets.0.lambda: must be in [actuator.lambda_min, 1] = [0.5, 1]"),
        (lambda t: t.replace("samples = 41\n\n", "samples = 41\n").replace("length = 32.0\nsamples = 41", "length = 32.0\nsamples = 40"),
         "targets.1.samples: has 40 points; every target needs as many as targets.0 (41)"),
        (lambda t: t.replace("radius = 5.0", "radius = -5.0"), "targets.1.radius: must be >= 0"),
        (lambda t: t.replace("pitch = 2.0", "pich = 2.0"), "targets.1.pich: unknown key"),
        (lambda t: t + "[target]\ncurve = 'trefoil'\n", "target: not used in a multishape problem"),
        (lambda t: t + "[design]\nshared_pose = 1\n", "design.shared_pose: must be true or false"),
        (lambda t: t + "[design]\nmethod = 'greedy'\n", "design.method: must be 'nlp' in a multishape problem"),
        (lambda t: t + "[design]\nhops = 3\n", "design.hops: unknown key"),
        (lambda t: t.replace("[[targets]]", "[[targetz]]"), "target: missing"),
    ],
)
def test_problem_file_multishape_errors(tmp_path, change, message):
    with pytest.raises(InputError) as info:
        _parse(change(MS), tmp_path)
    assert message in str(info.value)


def test_bundled_multishape_problem_parses():
    pf = load_problem(ROOT / "problems" / "multishape-spam.toml")
    assert pf.kind == "multishape" and pf.problem.count == 3
    assert pf.problem.levels[0] == 0.87 and pf.problem.levels[1] is None


# ------------------------------------------------------------------ fuzz: a problem or an InputError, nothing else

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_junk = st.one_of(st.booleans(), st.integers(-3, 10**6), st.floats(), st.text(max_size=6), st.lists(st.floats(-2, 2), max_size=4))
_helix = st.fixed_dictionaries(
    {"curve": st.just("helix"), "radius": st.floats(0.1, 5), "pitch": st.floats(-2, 2), "length": st.floats(1, 40)},
    optional={"samples": st.sampled_from([21, 41]), "lambda": st.floats(0.0, 1.2)},
)
_ms = st.fixed_dictionaries(
    {"tube": st.fixed_dictionaries({"diameter": st.floats(0.1, 5)}), "targets": st.lists(_helix, min_size=1, max_size=3)},
    optional={
        "actuator": st.fixed_dictionaries({}, optional={"kind": st.sampled_from(["spam", "tendon"]), "lambda_min": st.floats(0.1, 1)}),
        "design": st.fixed_dictionaries({}, optional={"points_per_segment": st.integers(1, 30), "shared_pose": st.booleans() | _junk}),
    },
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=_ms, key=st.integers(0, 100), junk=_junk)
def test_parse_multishape_fuzz(data, key, junk):
    mutate(data, key, ("replace", "delete", "misspell")[key % 3], junk)
    try:
        pf = parse_problem(data, "p.toml", "")
    except InputError as err:
        assert err.file and err.key and err.reason
        return
    assert pf.kind == "multishape"
    p = pf.problem
    assert len({t.shape[0] for t in p.targets}) == 1 and p.actuator.kind == "spam"
    assert all(v is None or p.actuator.lambda_min <= v <= 1 for v in p.levels)
