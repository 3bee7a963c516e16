"""Result archives: round trip, the archived phi, the model reproduces archived shapes, atomic writes."""

import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from vine_nlp import __version__
from vine_nlp.errors import InputError
from vine_nlp.io import archive as archive_module
from vine_nlp.io import limits
from vine_nlp.io.archive import Archive, load_archive, write_archive
from vine_nlp.methods.common import evaluate, pair_points, run_forward
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.model.shape import forward_shape
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, ForwardProblem, Routing

ROOT = Path(__file__).resolve().parents[1]
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
    return Routing(theta=np.radians(20 * np.sin(0.15 * s) + 5), lam=0.7 + 0.1 * np.cos(0.2 * s), length=np.full(m, dl))


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


# ---------------------------------------------------------------- validation on load


@pytest.fixture
def written(tmp_path, design):
    """A fresh copy of a valid design archive (nlp run, target, measured points) for each test."""
    path = tmp_path / "a.h5"
    write_archive(path, design_archive(*design))
    return path


def _edit(path, fn):
    with h5py.File(path, "a") as h5:
        fn(h5)


def _set(name, index, value):
    def fn(h5):
        a = h5[name][()]
        a[index] = value
        h5[name][...] = a

    return fn


def _replace(name, data):
    def fn(h5):
        del h5[name]
        h5.create_dataset(name, data=data)

    return fn


def _rotation(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


BAD_ARCHIVES = [
    (_set("runs/nlp/design/theta", 3, np.nan), "/runs/nlp/design/theta", "non-finite value nan at [3]"),
    (_set("runs/nlp/shape/inner", (5, 1), np.inf), "/runs/nlp/shape/inner", "non-finite value inf at [5, 1]"),
    (_set("target/points", (0, 0), -np.inf), "/target/points", "non-finite value -inf at [0, 0]"),
    (_set("runs/nlp/design/length", 0, 0.0), "/runs/nlp/design/length", "must be > 0 (segment 1: 0)"),
    (_set("runs/nlp/design/lambda", 1, -0.5), "/runs/nlp/design/lambda", "must be in (0, 1] (segment 2: -0.5)"),
    (_replace("runs/nlp/design/lambda", np.full(9, 0.7)), "/runs/nlp/design/lambda", "shape (9,), expected (10,)"),
    (_replace("runs/nlp/design/phi", np.zeros(10)), "/runs/nlp/design/phi", "shape (10,), expected (11,)"),
    (_replace("runs/nlp/shape/outer", np.zeros((40, 3))), "/runs/nlp/shape/outer", "shape (40, 3), expected (41, 3)"),
    (_replace("runs/nlp/shape/center", np.zeros((40, 3))), "/runs/nlp/shape/center", "shape (40, 3), expected (41, 3)"),
    (_replace("runs/nlp/design/theta", np.array([b"a", b"b"])), "/runs/nlp/design/theta", "must hold real numbers, got dtype |S1"),
    (_replace("runs/nlp/design/theta", np.zeros(10, complex)), "/runs/nlp/design/theta", "must hold real numbers, got dtype complex128"),
    (_replace("runs/nlp/design/initial_pose", 2 * np.eye(4)), "/runs/nlp/design/initial_pose", "last row must be 0 0 0 1, got [0.0, 0.0, 0.0, 2.0]"),
    (_replace("runs/nlp/design/initial_pose", np.diag([1.0, 1.0, 1.1, 1.0])), "/runs/nlp/design/initial_pose", "rotation part is not orthonormal (|R^T R - I| = 0.21)"),
    (_replace("runs/nlp/design/initial_pose", np.diag([1.0, 1.0, -1.0, 1.0])), "/runs/nlp/design/initial_pose", "rotation part has det -1 (a reflection, not a rotation)"),
    (_replace("runs/nlp/design/initial_pose", np.eye(3)), "/runs/nlp/design/initial_pose", "shape (3, 3), expected (4, 4)"),
    (lambda h5: h5["runs/nlp/design"].pop("theta"), "/runs/nlp/design/theta", "missing"),
    (lambda h5: h5["runs/nlp"].attrs.__setitem__("iterations", 2.5), "/runs/nlp@iterations", "must be an integer, got 2.5"),
    (lambda h5: h5["runs/nlp"].attrs.__setitem__("solve_time_s", "fast"), "/runs/nlp@solve_time_s", "must be a number, got str"),
    (lambda h5: h5["runs/nlp"].attrs.__setitem__("status", 3), "/runs/nlp@status", "must be text, got int"),
    (lambda h5: h5["runs/nlp/metrics"].attrs.__setitem__("rmse", np.nan), "/runs/nlp/metrics@rmse", "must be finite, got nan"),
    (lambda h5: h5["tube"].attrs.__setitem__("diameter", -2.0), "/tube@diameter", "must be > 0 and <= 1e+09 (vine_nlp.io.limits.MAX_COORDINATE), got -2.0"),
    (lambda h5: h5.attrs.__setitem__("format_version", 2), "/@format_version", "format version 2 is newer than this vine_nlp reads (1)"),
    (lambda h5: h5["problem"].attrs.__delitem__("source"), "/problem@source", "missing attribute"),
    (lambda h5: h5.create_dataset("measured/extra", data=[1.0, np.nan]), "/measured/extra", "non-finite value nan at [1]"),
    (lambda h5: h5.create_dataset("notes", data=3.0), "/notes", "must be an array (at least 1-D), got a scalar"),
    (lambda h5: h5.create_dataset("future/0/radius", data=np.array([b"x"])), "/future/0/radius", "must hold real numbers, got dtype |S1"),
]


@pytest.mark.parametrize("edit, key, reason", BAD_ARCHIVES)
def test_invalid_archives_are_one_input_error(written, edit, key, reason):
    _edit(written, edit)
    with pytest.raises(InputError) as info:
        load_archive(written)
    assert (info.value.file, info.value.key, info.value.reason) == (str(written), key, reason)


def test_rotated_poses_and_unknown_groups_are_accepted(written):
    def edit(h5):
        h5["runs/nlp/design/initial_pose"][...] = _rotation(33) @ h5["runs/nlp/design/initial_pose"][()]
        h5.create_dataset("future/0/center", data=[1.0, 2.0, 3.0])  # a group the spec does not name: kept and checked
        h5.create_dataset("frames/lambda", data=[0.8, np.nan])  # a frame that could not be fitted

    _edit(written, edit)
    a = load_archive(written)
    np.testing.assert_allclose(a.extra["future/0/center"], [1.0, 2.0, 3.0])
    assert np.isnan(a.extra["frames/lambda"][1])


def test_size_limits_are_checked_before_reading(written, monkeypatch):
    # a dataset declared with 10^9 rows and never written: refused by its size, not read
    def edit(h5):
        del h5["target/points"]
        h5.create_dataset("target/points", shape=(10**9, 3), dtype=float, chunks=(1024, 3), fillvalue=1.0)

    _edit(written, edit)
    with pytest.raises(InputError) as info:
        load_archive(written)
    assert info.value.key == "/target/points"
    assert info.value.reason == (
        f"3000000000 values, more than the limit of {limits.MAX_DATASET_ELEMENTS} (vine_nlp.io.limits.MAX_DATASET_ELEMENTS)")


@pytest.mark.parametrize("content, reason", [
    (b"", "not an HDF5 file"),
    (b"\x89HDF\r\n\x1a\n" + b"\0" * 40, "cannot read the archive"),
    (b"hello", "not an HDF5 file"),
])
def test_damaged_files_are_one_input_error(tmp_path, content, reason):
    path = tmp_path / "bad.h5"
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        load_archive(path)
    assert info.value.key == "file" and info.value.reason.startswith(reason)


def test_truncated_archive_is_one_input_error(written):
    data = written.read_bytes()
    written.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as info:
        load_archive(written)
    assert info.value.key == "file" and info.value.reason.startswith("cannot read the archive (")


def test_write_archive_extend_adds_groups_in_the_same_atomic_write(tmp_path):
    path = tmp_path / "x.h5"
    write_archive(path, forward_archive(), extend=lambda h5: h5.create_dataset("frames/rmse", data=[0.1, 0.2]))
    np.testing.assert_array_equal(load_archive(path).extra["frames/rmse"], [0.1, 0.2])
    assert [p.name for p in tmp_path.iterdir()] == ["x.h5"]


READERS = [
    ["show", "{a}"],
    ["plot", "{a}", "-o", "{d}/f.png"],
    ["analyze", "{a}", "--samples", "10"],
    ["template", "{a}", "-o", "{d}/t.pdf"],
    ["design", str(ROOT / "problems/bezier-c.toml"), "-o", "{d}/w.h5", "--warm", "{a}"],
]


@pytest.mark.parametrize("args", READERS, ids=lambda a: a[0] + (" --warm" if "--warm" in a else ""))
def test_every_command_refuses_an_invalid_archive_in_one_line(tmp_path, capsys, args):
    from vine_nlp.front.cli import main

    path = tmp_path / "in.h5"
    write_archive(path, forward_archive())
    _edit(path, _set("runs/forward/design/theta", 2, np.nan))
    out = tmp_path / "out"
    out.mkdir()
    assert main([a.format(a=path, d=out) for a in args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {path}: /runs/forward/design/theta: non-finite value nan at [2]"]
    assert list(out.iterdir()) == []


def _stored(obj):
    """How HDF5 holds an attribute or dataset: type class, size, string kind and charset, shape, value."""
    oid = obj if isinstance(obj, h5py.h5a.AttrID) else obj.id
    t = oid.get_type()
    string = (t.is_variable_str(), t.get_cset()) if isinstance(t, h5py.h5t.TypeStringID) else None
    value = obj[()] if isinstance(obj, h5py.Dataset) else None
    return t.get_class(), t.get_size(), string, oid.shape, None if value is None else value.tobytes()


def test_the_writer_stores_what_h5pys_own_calls_store(tmp_path):
    # write_archive makes attributes and small datasets with h5py's low-level calls (issue 36: half the
    # cost); readers must find exactly what h5py's high-level calls make (the format did not change)
    values = {"text": "ipopt", "unicode": "θ λ", "int": 7, "big": 2**40, "float": 0.1, "nan": math.nan,
              "numpy": np.float64(2.5), "flag": True, "list": [1, 2], "non-ascii ä": 1.0}
    arrays = {"a": np.arange(5.0), "b": np.arange(12).reshape(4, 3), "c/d": np.ones((3, 3)), "big": np.zeros((9000, 3))}
    with h5py.File(tmp_path / "a.h5", "w") as h5:
        fast, ref = h5.create_group("fast"), h5.create_group("ref")
        archive_module._attrs(fast, values)
        ref.attrs.update(values)
        for name, data in arrays.items():
            archive_module._dataset(fast, name, data)
            ref.create_dataset(name, data=data)
    with h5py.File(tmp_path / "a.h5", "r") as h5:
        fast, ref = h5["fast"], h5["ref"]
        assert sorted(fast.attrs) == sorted(ref.attrs)
        for name in ref.attrs:
            assert _stored(fast.attrs.get_id(name)) == _stored(ref.attrs.get_id(name)), name
            assert repr(fast.attrs[name]) == repr(ref.attrs[name]), name
        for name in arrays:
            assert _stored(fast[name]) == _stored(ref[name]), name
        assert fast["big"].compression == "gzip" and fast["a"].chunks is None  # gzip only where it pays
