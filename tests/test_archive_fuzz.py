"""Fuzzing the archive loader: real archives made by the project's own commands, mutated.

Property: ``load_archive`` on any mutation either raises ArchiveError (an InputError: one line,
exit 2 on the command line) or returns an Archive that holds only what the spec allows
(finite arrays of the right shapes, proper poses), which ``show`` then summarizes. It never
raises anything else.

Settings: ``FUZZ`` below, derandomized (the same examples on every run: CI never fails at
random). ``VINE_NLP_FUZZ_EXAMPLES=5000 VINE_NLP_FUZZ_RANDOM=1 pytest tests/test_archive_fuzz.py``
explores further.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vine_nlp.errors import InputError
from vine_nlp.front.cli import main
from vine_nlp.front.show import summarize
from vine_nlp.io.archive import ArchiveError, load_archive

# NumPy's RuntimeWarnings (overflow, invalid value, divide by zero) are errors: a mutated archive never makes one (issue 48)
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
ROOT = Path(__file__).resolve().parents[1]
FUZZ = settings(
    max_examples=int(os.environ.get("VINE_NLP_FUZZ_EXAMPLES", "80")),
    deadline=None,
    derandomize=not os.environ.get("VINE_NLP_FUZZ_RANDOM"),
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    database=None,
)


def _small(name: str, edits: dict, folder: Path) -> Path:
    text = (ROOT / "problems" / f"{name}.toml").read_text()
    for old, new in edits.items():
        assert old in text, old
        text = text.replace(old, new)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
    """One small archive of each layout, made by the commands: forward, design, fit (measured,
    frames), multi-shape (levels, targets), tip."""
    d = tmp_path_factory.mktemp("fuzz")
    made = {}
    runs = {
        "forward": ["forward", str(ROOT / "problems/three-section-helix.toml")],
        "design": ["design", str(_small("bezier-c", {}, d))],
        "fit": ["fit", str(ROOT / "problems/fit-sinusoidal.toml"), "--starts", "4",
                "--frames", *sorted(str(p) for p in (ROOT / "problems/data/sinusoidal-frames").glob("*.csv"))[:2]],
        "multishape": ["design", str(_small("multishape-spam", {"samples = 121": "samples = 31", "points_per_segment = 10": "points_per_segment = 5", "starts = 2": "starts = 1"}, d))],
        "tip": ["design", str(_small("tip-target", {"segments = 20": "segments = 6", "starts = 4": "starts = 1"}, d))],
    }
    for kind, args in runs.items():
        out = d / f"{kind}.h5"
        args = [*args[:2], "-o", str(out), *args[2:]]
        assert main(args) in (0, 1), kind  # 1: not converged is still an archive
        made[kind] = out
    return made


def _nodes(path: Path) -> list[tuple[str, str]]:
    """(kind, path) of every dataset, group and attribute of the file."""
    out = [("group", "/")]
    with h5py.File(path, "r") as h5:
        out += [("attr", f"/@{a}") for a in h5.attrs]

        def visit(name, obj):
            out.append(("dataset" if isinstance(obj, h5py.Dataset) else "group", f"/{name}"))
            out.extend(("attr", f"/{name}@{a}") for a in obj.attrs)

        h5.visititems(visit)
    return sorted(out)


JUNK = st.one_of(
    st.just(np.nan), st.just(np.inf), st.just(-np.inf), st.just(-1.0), st.just(0.0), st.just(1e300),
    st.just("text"), st.just(b"\xff\xfe"), st.just(np.arange(5.0)), st.just(np.array([], float)),
    st.just(np.array(["a", "b"], dtype=object)), st.just(np.array([1 + 2j])), st.just(True), st.just(2**62),
)
ACTIONS = ("delete", "poison", "reshape", "retype", "replace", "pose", "negate", "huge", "junk_group", "attr", "truncate", "link")


def _replace(parent, name, data):
    del parent[name]
    if isinstance(data, np.ndarray) and data.dtype == object:
        parent.create_dataset(name, data=data, dtype=h5py.string_dtype())
    else:
        parent.create_dataset(name, data=data)


def _mutate(path: Path, kind: str, node: str, action: str, junk, k: int) -> None:
    if action == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: (k * 7919) % max(1, len(data))])
        return
    with h5py.File(path, "a") as h5:
        if kind == "attr":
            owner, _, attr = node.partition("@")
            obj = h5[owner]
            if action == "delete":
                del obj.attrs[attr]
            else:
                obj.attrs[attr] = junk
            return
        if action == "junk_group":
            g = h5.require_group(f"zz{k % 3}/sub")
            g.create_dataset(f"d{k}", data=junk if not isinstance(junk, np.ndarray) or junk.dtype != object else [b"a"])
            return
        if node == "/":
            h5.attrs["format"] = junk if action == "attr" else "vine_nlp/other"
            return
        parent, name = h5[node.rsplit("/", 1)[0] or "/"], node.rsplit("/", 1)[1]
        if action == "delete":
            del parent[name]
        elif action == "link":
            del parent[name]
            parent[name] = h5py.SoftLink(f"/nowhere/{k}")
        elif kind == "group":
            if action == "huge":
                parent[f"{name}_big"] = h5py.SoftLink(node)
            del parent[name]
            parent.create_dataset(name, data=np.zeros(3))  # a dataset where a group belongs
        elif action == "poison":
            a = parent[name][()]
            if a.dtype.kind == "f" and a.size:
                a.reshape(-1)[k % a.size] = (np.nan, np.inf, -np.inf)[k % 3]
                parent[name][...] = a
        elif action == "reshape":
            a = np.asarray(parent[name][()])
            shapes = [a.reshape(-1), a[:-1] if a.ndim else a, np.concatenate([a, a[:1]]) if a.ndim else a, a.T, np.float64(1.0), np.zeros((0, 3))]
            _replace(parent, name, shapes[k % len(shapes)])
        elif action == "retype":
            a = np.asarray(parent[name][()])
            types = [a.astype("S8") if a.size else np.array([b"x"]), a.astype(complex), a.astype(bool), a.astype(np.int8)]
            _replace(parent, name, types[k % len(types)])
        elif action == "replace":
            _replace(parent, name, junk)
        elif action == "pose":
            a = parent[name][()].astype(float)
            if a.shape == (4, 4):
                a[(k % 4, (k // 4) % 4)] += 0.5 * (1 + k % 3)
                if k % 5 == 0:
                    a[:3, 0] *= -1  # a reflection
                parent[name][...] = a
        elif action == "negate":
            a = parent[name][()]
            if a.dtype.kind in "fi":
                parent[name][...] = -a
        elif action == "huge":
            del parent[name]
            # declared, never written: the loader must refuse it by its size, not read it
            parent.create_dataset(name, shape=(10**9, 3), dtype=float, chunks=(1024, 3), fillvalue=1.0)
        else:
            obj = parent[name]
            obj.attrs["x"] = junk


def _assert_valid(a) -> None:
    """What a successful load may return (the spec's layout, finite, proper poses)."""
    for r in a.runs.values():
        ro = r.routing
        M = ro.theta.size
        assert ro.lam.shape == ro.length.shape == (M,)
        for arr in (ro.theta, ro.lam, ro.length, ro.initial_pose, r.shape.center, r.shape.inner, r.shape.outer):
            assert np.all(np.isfinite(arr))
        assert np.all(ro.length > 0) and np.all(ro.lam > 0)
        R = ro.initial_pose[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-5) and np.linalg.det(R) > 0
        assert np.allclose(ro.initial_pose[3], [0, 0, 0, 1])
        assert r.shape.center.shape == r.shape.inner.shape == r.shape.outer.shape and r.shape.center.shape[1] == 3
        assert isinstance(r.status, str) and isinstance(r.method, str) and np.isfinite(r.solve_time_s)
    if a.target is not None:
        assert a.target.ndim == 2 and a.target.shape[1] == 3 and np.all(np.isfinite(a.target))
    assert a.diameter > 0 and np.isfinite(a.diameter)
    for key, value in a.extra.items():
        assert np.ndim(value) >= 1, key
    summarize(a)


def test_unmutated_archives_load(archives):
    for kind, path in archives.items():
        a = load_archive(path)
        _assert_valid(a)
        assert a.runs, kind


@FUZZ
@given(data=st.data(), action=st.sampled_from(ACTIONS), junk=JUNK, k=st.integers(0, 10**6))
def test_mutated_archives_load_or_raise_input_error(archives, tmp_path_factory, data, action, junk, k):
    kind = data.draw(st.sampled_from(sorted(archives)))
    nodes = _nodes(archives[kind])
    node_kind, node = data.draw(st.sampled_from(nodes))
    path = tmp_path_factory.mktemp("m") / "a.h5"
    shutil.copy(archives[kind], path)
    try:
        _mutate(path, node_kind, node, action, junk, k)
    except (TypeError, ValueError, OSError, KeyError):
        pass  # h5py would not store that mutation: the archive stays as far as it got
    try:
        a = load_archive(path)
    except ArchiveError as e:
        assert isinstance(e, InputError) and "\n" not in str(e)
        return
    _assert_valid(a)
