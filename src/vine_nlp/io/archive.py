"""HDF5 result archives (../shared/spec/formats.md, "Result archives"): written atomically, validated on load.

Writing. The HDF5 file is built in memory and its bytes written with ordinary file I/O to a temporary file beside the
target, then renamed onto it. A full disk, a read-only filesystem or a missing permission is one :class:`OutputError`
and leaves nothing behind; HDF5 itself never writes to the disk, so a failed write cannot leave it with a half-closed
file (which used to crash the interpreter at exit).

Reading. :func:`load_archive` opens the file through :mod:`vine_nlp.io.h5read` (no links, no external data, sizes
bounded before reading) and checks everything it returns against the spec: every dataset's dtype and shape and their
consistency (M segments, P shape rows, K levels), finite values (a metric other than rmse and max_error may be NaN:
"does not apply"), proper initial poses (4x4, orthonormal rotation with det +1, last row 0 0 0 1), attribute types and
the size limits of :mod:`vine_nlp.io.limits`. Anything else is an :class:`ArchiveError` ``(file, dataset path,
reason)``; no other exception leaves the loader. Groups the spec does not name are allowed; their datasets come back in
``Archive.extra`` and are validated too (numeric, at least 1-D, within the limits, finite except ``/frames``)."""

from __future__ import annotations

import datetime as _dt
import functools
import io
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from vine_nlp import __version__
from vine_nlp.errors import InputError
from vine_nlp.io import files, limits, outputs
from vine_nlp.io.h5read import ArchiveError, decode_attr, open_archive
from vine_nlp.io.obstacles import read_obstacles, write_obstacles
from vine_nlp.io.outputs import OutputError, output_error, temp_file
from vine_nlp.model.shape import Shape
from vine_nlp.problem import Result, Routing

FORMAT = "vine_nlp/result"
FORMAT_VERSION = 1
_COMPRESS = dict(compression="gzip", compression_opts=4, shuffle=True)
_COMPRESS_BYTES = 1 << 16  # datasets smaller than this are stored as they are
POSE_TOLERANCE = 1e-6  # |R^T R - I| and |det R - 1| of an archived initial pose


@dataclass
class Archive:
    name: str
    kind: str  # design | forward | fit
    source: str  # the problem file's text
    diameter: float
    units: str = "cm"
    target: np.ndarray | None = None
    runs: dict = field(default_factory=dict)  # run name -> Result
    extra: dict = field(default_factory=dict)  # further datasets: "/measured/points" -> array
    obstacles: list = field(default_factory=list)  # issue 15: /obstacles/<k> (vine_nlp.io.obstacles)
    software_version: str = __version__
    created: str = ""
    format_version: int = FORMAT_VERSION

    def default_run(self) -> str | None:
        """The run a command uses when none is named: the first of DEFAULT_RUNS present, else
        the first run (None for an archive without runs)."""
        return next((r for r in DEFAULT_RUNS if r in self.runs), next(iter(self.runs), None))

    def pick_run(self, run: str | None = None) -> str:
        """``run`` if given, else the default run; ValueError when there is no such run."""
        if run is None:
            run = self.default_run()
            if run is None:
                raise ValueError("the archive has no runs")
        elif run not in self.runs:
            raise ValueError(f"no run {run!r} in the archive (runs: {', '.join(self.runs) or 'none'})")
        return run


# the design a command reads from an archive by default (template, analyze, --warm), in this order
DEFAULT_RUNS = ("nlp", "nlp_robust", "nlp_clearance", "greedy", "forward", "fit", "tip", "multishape")


# ---------------------------------------------------------------- writing


def write_atomic(path, write):
    """Call ``write(tmp_path)`` then rename onto ``path``; on any failure nothing is left behind.
    An output the command line reserved (``vine_nlp.io.outputs``) is renamed when the command ends.
    An OSError while writing or renaming (disk full, permissions, read-only filesystem, a directory at
    ``path``) raises OutputError; other exceptions pass through unchanged."""
    path = Path(path)
    staged = outputs.staged(path, written=True)
    tmp = staged or temp_file(path)
    try:
        write(tmp)
        if staged is None:
            os.replace(tmp, path)
    except OutputError:
        tmp.unlink(missing_ok=True)
        raise
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        cause = _os_error(exc)
        if cause is None:
            raise
        raise output_error(path, cause) from None


def _os_error(exc: BaseException) -> OSError | None:
    """The OSError behind ``exc`` (a writer that failed on a full disk and then on its own broken state:
    matplotlib's PDF writer raises zlib.error or AttributeError), or None (a signal: None)."""
    for _ in range(8):
        if isinstance(exc, OSError) or not isinstance(exc, Exception):
            return exc if isinstance(exc, OSError) else None
        exc = exc.__cause__ or exc.__context__
    return None


def write_h5_atomic(path, fill) -> None:
    """Write an HDF5 file made by ``fill(h5)`` (an in-memory h5py.File) atomically to ``path``.

    HDF5 never touches the disk: the finished image is written with plain file I/O, so a
    failed write is one OutputError and nothing else (no HDF5 error at close or exit)."""
    buf = io.BytesIO()
    with h5py.File(buf, "w") as h5:
        fill(h5)
    _write_bytes(path, buf.getbuffer())


def _write_bytes(path, data) -> None:
    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())  # a full disk shows here at the latest, not after the rename

    write_atomic(path, write)


def _attr(value):
    if isinstance(value, (dict, list, tuple)):
        return json.dumps(value, default=float)
    if value is None:
        return "none"
    return value


# What h5py's high-level calls would make, made with its low-level ones at half the cost: scalar
# attributes, uncompressed datasets without modification times (h5py's default), parent groups on the way.
_SCALAR = h5py.h5s.create(h5py.h5s.SCALAR)
_TEXT = h5py.string_dtype()  # a str attribute: variable-length UTF-8
_DCPL = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
_DCPL.set_obj_track_times(False)
_LCPL = h5py.h5p.create(h5py.h5p.LINK_CREATE)
_LCPL.set_create_intermediate_group(True)
_type = functools.lru_cache(maxsize=None)(lambda dtype: h5py.h5t.py_create(dtype, logical=True))  # numpy -> HDF5


def _attrs(node, values: dict) -> None:
    """``node.attrs.update(values)``: text and numbers through the low-level calls, the rest through h5py."""
    for name, v in values.items():
        plain = isinstance(v, (str, int, float)) and not isinstance(v, bool) and name.isascii()
        if not plain:
            node.attrs[name] = v
            continue
        v = np.array(v, dtype=_TEXT) if isinstance(v, str) else np.asarray(v)
        h5py.h5a.create(node.id, name.encode(), _type(v.dtype), _SCALAR).write(v)


def _dataset(parent, name: str, data) -> None:
    # gzip only where it pays: on a shape of a few hundred points it saves ~10 % of the bytes and its
    # chunk index costs more than that; a reader cannot tell the storage apart (the spec is the layout)
    data = np.ascontiguousarray(data)
    if data.nbytes >= _COMPRESS_BYTES or not (data.ndim and data.size and data.dtype.kind in "fiu" and name.isascii()):
        parent.create_dataset(name, data=data, **(_COMPRESS if data.nbytes >= _COMPRESS_BYTES else {}))
        return
    space = h5py.h5s.create_simple(data.shape)
    h5py.h5d.create(parent.id, name.encode(), _type(data.dtype), space, dcpl=_DCPL, lcpl=_LCPL).write(h5py.h5s.ALL, h5py.h5s.ALL, data)


def _write(h5: h5py.File, a: Archive):
    created = a.created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    _attrs(h5, dict(format=FORMAT, format_version=FORMAT_VERSION, software_version=__version__, created=created, units=a.units))
    _attrs(h5.create_group("problem"), dict(name=a.name, kind=a.kind, source=a.source))
    _attrs(h5.create_group("tube"), {"diameter": float(a.diameter)})
    if a.target is not None:
        _dataset(h5, "target/points", np.asarray(a.target, float))
    for key, arr in a.extra.items():
        _dataset(h5, key.strip("/"), arr)
    if a.obstacles:
        write_obstacles(h5.create_group("obstacles"), a.obstacles)
    runs = h5.create_group("runs")
    for name, r in a.runs.items():
        g = runs.create_group(name)
        _attrs(g, dict(method=r.method, status=r.status, solve_time_s=float(r.solve_time_s), iterations=int(r.iterations),
                       shortfall="\n".join("; ".join(str(s).splitlines()) for s in r.shortfall)))  # one line each
        g.attrs["clear"] = bool(r.clear)
        d = g.create_group("design")
        for key, data in (("theta", r.routing.theta), ("lambda", r.routing.lam), ("length", r.routing.length),
                          ("phi", r.phi), ("initial_pose", r.routing.initial_pose)):
            _dataset(d, key, data)
        s = g.create_group("shape")
        for line in ("center", "inner", "outer"):
            _dataset(s, line, getattr(r.shape, line))
        _attrs(g.create_group("metrics"), {k: float(v) for k, v in r.metrics.items()})
        _attrs(g.create_group("solver"), {k: _attr(v) for k, v in r.stats.items()})


def write_archive(path, archive: Archive, extend=None) -> None:
    """Write ``archive`` (the spec's layout, ``extra`` as further datasets) to ``path`` atomically:
    built in memory, temporary file, fsync, rename. ``extend(h5)`` adds further groups (multi-shape
    levels, ...) to the in-memory file. OutputError when it cannot be written: nothing is left."""

    def fill(h5):
        _write(h5, archive)
        if extend is not None:
            extend(h5)

    write_h5_atomic(path, fill)


def add_metrics(path, run: str, metrics: dict) -> None:
    """Set the attributes ``metrics`` of ``/runs/<run>/metrics`` of the archive at ``path`` (``analyze
    --write-metrics``): the archive's bytes copied and changed there, every group, dataset and attribute
    this does not name kept as it was (a correction's, a multi-shape run's levels, groups of later
    versions); written atomically like every archive."""
    data = files.read_text(path, limit=limits.MAX_FILE_BYTES, limit_name="MAX_FILE_BYTES", binary=True)
    buf = io.BytesIO(data)
    with h5py.File(buf, "r+") as h5:
        g = h5[f"runs/{run}"].require_group("metrics")
        for k, v in metrics.items():
            g.attrs[k] = float(v)
    _write_bytes(path, buf.getbuffer())


# ---------------------------------------------------------------- reading and validation


_LINE_BREAKS = {ord(c): " " for c in "\n\r\t"}
_CORE_GROUPS = ("problem", "tube", "target", "runs", "obstacles")
_LINES = ("center", "inner", "outer")
_FINITE_METRICS = ("rmse", "max_error")
_NAN_ALLOWED = ("frames",)  # per-frame fits archive NaN for a frame that could not be fitted


class _Checker:
    """Reads datasets and attributes of one open archive, each checked, errors named by path."""

    def __init__(self, file):
        self.file = str(file)

    def fail(self, key, reason):
        raise ArchiveError(self.file, key, reason)

    # -- attributes
    def text(self, node, name, required=True, default="", lines=False):
        """A text attribute: one printable line (``lines``: newlines and tabs allowed too)."""
        key = f"{_path(node)}@{name}"
        if name not in node.attrs:
            if required:
                self.fail(key, "missing attribute")
            return default
        v = decode_attr(node.attrs[name])
        if not isinstance(v, str):
            self.fail(key, f"must be text, got {type(v).__name__}")
        if len(v) > limits.MAX_TEXT_CHARS:
            self.fail(key, f"longer than {limits.MAX_TEXT_CHARS} characters (vine_nlp.io.limits.MAX_TEXT_CHARS)")
        if not (v.translate(_LINE_BREAKS) if lines else v).isprintable():
            self.fail(key, "must be printable text (no control characters)")
        return v

    def number(self, node, name, integer=False, minimum=None, required=True, default=None, finite=True, nan_ok=False):
        key = f"{_path(node)}@{name}"
        if name not in node.attrs:
            if required:
                self.fail(key, "missing attribute")
            return default
        v = decode_attr(node.attrs[name])
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"must be a number, got {type(v).__name__}")
        if integer and not (isinstance(v, int) or float(v).is_integer()):
            self.fail(key, f"must be an integer, got {v!r}")
        if (math.isnan(v) and not nan_ok) or (finite and math.isinf(v)):
            self.fail(key, f"must be finite, got {v!r}")
        if minimum is not None and v < minimum:
            self.fail(key, f"must be >= {minimum}, got {v!r}")
        return int(v) if integer else float(v)

    # -- datasets
    def group(self, parent, name, required=True):
        key = f"{_path(parent).rstrip('/')}/{name}"
        if name not in parent:
            if required:
                self.fail(key, "missing")
            return None
        g = parent[name]
        if not isinstance(g, h5py.Group):
            self.fail(key, "must be a group")
        return g

    def array(self, parent, name, shape, limit, finite=True, limit_name="MAX_DATASET_ELEMENTS"):
        """Dataset ``name``: float (ints accepted), ``shape`` a tuple of int or None (any), size <= limit."""
        key = f"{_path(parent).rstrip('/')}/{name}"
        if name not in parent:
            self.fail(key, "missing")
        ds = parent[name]
        if not isinstance(ds, h5py.Dataset):
            self.fail(key, "must be a dataset")
        return self.values(ds, key, shape, limit, finite, limit_name=limit_name)

    def values(self, ds, key, shape, limit, finite=True, raw=False, limit_name="MAX_DATASET_ELEMENTS"):
        # the dtype (real numbers) was checked when the archive was opened (io/h5read.py)
        if ds.shape is None:
            self.fail(key, "empty dataset (no shape)")
        if shape is not None:
            if len(ds.shape) != len(shape) or any(want is not None and got != want for got, want in zip(ds.shape, shape)):
                want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ("," if len(shape) == 1 else "") + ")"
                self.fail(key, f"shape {ds.shape}, expected {want}")
        size = int(np.prod(ds.shape, dtype=np.int64))
        if size > limit:
            self.fail(key, f"{size} values, more than the limit of {limit} (vine_nlp.io.limits.{limit_name})")
        stored = np.asarray(ds[()])
        data = stored.astype(float)
        if finite and not np.all(np.isfinite(data)):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(data))[0])
            where = ", ".join(map(str, bad))
            self.fail(key, f"non-finite value {float(data[bad])} at [{where}]" if bad else f"non-finite value {float(data)}")
        return stored if raw else data

    def pose(self, parent, name):
        key = f"{_path(parent).rstrip('/')}/{name}"
        T = self.array(parent, name, (4, 4), 16)
        R = T[:3, :3]
        if not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0), atol=POSE_TOLERANCE, rtol=0):
            self.fail(key, f"last row must be 0 0 0 1, got {T[3].tolist()}")
        with np.errstate(all="ignore"):  # 1e300: an overflow is a refusal below, not a warning
            err = float(np.abs(R.T @ R - np.eye(3)).max())
        if err > POSE_TOLERANCE:
            self.fail(key, f"rotation part is not orthonormal (|R^T R - I| = {err:.3g})")
        if np.linalg.det(R) < 0:
            self.fail(key, "rotation part has det -1 (a reflection, not a rotation)")
        return self.coordinates(key, T)

    def coordinates(self, key, data):
        """``data`` (points, a pose) with no coordinate beyond MAX_COORDINATE: the problem files' rule."""
        big = float(np.abs(data).max(initial=0.0))
        if big > limits.MAX_COORDINATE:
            self.fail(key, f"coordinates up to {big:.4g}: at most {limits.MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE)")
        return data

    def shape_lines(self, parent, key_prefix, rows=None):
        g = self.group(parent, "shape")
        lines = []
        for line in _LINES:
            arr = self.array(g, line, (rows, 3), 3 * limits.MAX_SHAPE_POINTS, limit_name="MAX_SHAPE_POINTS")
            if arr.shape[0] < 1:
                self.fail(f"{_path(g)}/{line}", "no rows")
            self.coordinates(f"{_path(g)}/{line}", arr)
            rows = arr.shape[0]
            lines.append(arr)
        return Shape(*lines)

    def metrics(self, parent):
        if "metrics" not in parent:
            return {}
        g = self.group(parent, "metrics")
        out = {}
        for k in g.attrs:
            # NaN is how a metric says "does not apply" (analyze: no first contact); rmse and max_error always apply
            v = self.number(g, k, finite=False, nan_ok=k not in _FINITE_METRICS)
            if k in _FINITE_METRICS and not (math.isfinite(v) and v >= 0):
                self.fail(f"{_path(g)}@{k}", f"must be finite and >= 0, got {v!r}")
            out[k] = v
        return out


def _path(node) -> str:
    return node.name or "/"


def _run(c: _Checker, name: str, g, a: Archive) -> Result:
    if not isinstance(g, h5py.Group):
        c.fail(f"/runs/{name}", "must be a group")
    d = c.group(g, "design")
    theta = c.array(d, "theta", (None,), limits.MAX_SEGMENTS, limit_name="MAX_SEGMENTS")
    M = theta.size
    lam = c.array(d, "lambda", (M,), limits.MAX_SEGMENTS, limit_name="MAX_SEGMENTS")
    length = c.array(d, "length", (M,), limits.MAX_SEGMENTS, limit_name="MAX_SEGMENTS")
    c.array(d, "phi", (M + 1,), limits.MAX_SEGMENTS + 1, limit_name="MAX_SEGMENTS")  # derived from theta: checked, not kept
    broken = limits.routing_rule(theta, lam, length, a.diameter)
    if broken:
        c.fail(f"{_path(d)}/{broken[0]}", broken[1])
    pose = c.pose(d, "initial_pose")
    # design runs pair shape row i with target row i (the spec), so P = N
    rows = a.target.shape[0] if a.target is not None and a.kind in ("design", "multishape") else None
    shape = c.shape_lines(g, _path(g), rows)
    stats = {}
    if "solver" in g:
        st = c.group(g, "solver")
        for k, v in st.attrs.items():
            v = decode_attr(v)
            if isinstance(v, str):
                v = c.text(st, k, lines=True)
            elif isinstance(v, np.ndarray):
                if v.size > limits.MAX_DATASET_ELEMENTS or v.dtype.kind not in "fiub":
                    c.fail(f"{_path(st)}@{k}", f"unsupported attribute value (dtype {v.dtype}, {v.size} values)")
            elif not isinstance(v, (int, float, bool)):
                c.fail(f"{_path(st)}@{k}", f"unsupported attribute type {type(v).__name__}")
            stats[k] = v
    if "levels" in g:
        _levels(c, g, d, M, a)
    return Result(method=c.text(g, "method"), routing=Routing(theta=theta, lam=lam, length=length, initial_pose=pose), shape=shape, status=c.text(g, "status"),
                  solve_time_s=c.number(g, "solve_time_s", minimum=0), iterations=c.number(g, "iterations", integer=True, minimum=0),
                  metrics=c.metrics(g), stats=stats, diameter=a.diameter, objective=stats.get("objective"),
                  buildable=bool(stats.get("buildable", False)), hessian=str(stats.get("hessian", "")),
                  shortfall=tuple(s for s in c.text(g, "shortfall", required=False, lines=True).split("\n") if s))


def _levels(c: _Checker, g, d, M, a: Archive) -> None:
    """Multi-shape extension: design/levels (K,), levels/<k>/{initial_pose, shape/*, metrics}, /targets/<k>."""
    levels = c.array(d, "levels", (None,), limits.MAX_LEVELS, limit_name="MAX_LEVELS")
    K = levels.size
    if K < 1 or not np.all((levels > 0) & (levels <= 1)):
        c.fail(f"{_path(d)}/levels", "contraction levels must be in (0, 1], at least one")
    lv = c.group(g, "levels")
    for k in range(K):
        one = c.group(lv, str(k))
        c.number(one, "lambda", required=False)
        c.pose(one, "initial_pose")
        target = a.extra.get(f"targets/{k}/points")
        if target is None:
            c.fail(f"/targets/{k}/points", f"missing: level {k} of {_path(g)} has no target")
        c.shape_lines(one, _path(one), target.shape[0])
        c.metrics(one)
    extra = sorted(set(lv) - {str(k) for k in range(K)})
    if extra:
        c.fail(f"{_path(lv)}/{extra[0]}", f"no such level: design/levels has {K}")


def _extras(c: _Checker, h5, a: Archive) -> None:
    """Every dataset outside the core layout, checked and kept in ``a.extra`` (their number and sizes
    were bounded when the archive was opened: io/h5read.py)."""
    found = []
    for top in h5:
        if top in _CORE_GROUPS:
            continue
        obj = h5[top]
        if isinstance(obj, h5py.Dataset):
            found.append((top, obj))
        else:
            obj.visititems(lambda name, o, top=top: found.append((f"{top}/{name}", o)) if isinstance(o, h5py.Dataset) else None)
    for name, ds in found:
        key = f"/{name}"
        if ds.ndim < 1:
            c.fail(key, "must be an array (at least 1-D), got a scalar")
        data = c.values(ds, key, None, limits.MAX_DATASET_ELEMENTS, finite=name.split("/")[0] not in _NAN_ALLOWED, raw=True)
        parts = name.split("/")
        if parts[0] in ("targets", "measured") and parts[-1] in ("points", "closest"):
            if data.ndim != 2 or data.shape[1] != 3 or data.shape[0] > limits.MAX_TARGET_POINTS:
                c.fail(key, f"shape {data.shape}, expected (n, 3) with n <= {limits.MAX_TARGET_POINTS} (vine_nlp.io.limits.MAX_TARGET_POINTS)")
        if parts[0] == "tip" and data.shape != (3,):
            c.fail(key, f"shape {data.shape}, expected (3,)")
        if parts[0] in ("targets", "measured", "tip") and parts[-1] in ("points", "closest", "position"):
            c.coordinates(key, data.astype(float))
        if name == "tip/direction" and not np.linalg.norm(data.astype(float)) > 0:
            c.fail(key, "direction must not be zero")
        a.extra[name] = data


def _load(c: _Checker, h5) -> Archive:
    fmt = decode_attr(h5.attrs.get("format"))
    if fmt != FORMAT:
        c.fail("/@format", "not a vine_nlp result archive")
    version = c.number(h5, "format_version", integer=True, minimum=1)
    if version > FORMAT_VERSION:
        c.fail("/@format_version", f"format version {version} is newer than this vine_nlp reads ({FORMAT_VERSION})")
    p, tube = c.group(h5, "problem"), c.group(h5, "tube")
    units = c.text(h5, "units")
    if not units or len(units) > limits.MAX_UNITS_CHARS:
        c.fail("/@units", f"must be a unit name, got {units[:40]!r}")
    diameter = c.number(tube, "diameter")
    if not 0 < diameter <= limits.MAX_COORDINATE:
        c.fail("/tube@diameter", f"must be > 0 and <= {limits.MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE), got {diameter!r}")
    target = None
    if "target" in h5:
        tg = c.group(h5, "target")
        target = c.array(tg, "points", (None, 3), 3 * limits.MAX_TARGET_POINTS, limit_name="MAX_TARGET_POINTS")
        if target.shape[0] < 2:
            c.fail("/target/points", f"needs at least 2 points, got {target.shape[0]}")
        c.coordinates("/target/points", target)
    a = Archive(name=c.text(p, "name"), kind=c.text(p, "kind"), source=c.text(p, "source", lines=True), diameter=diameter,
                units=units, target=target, software_version=c.text(h5, "software_version"),
                created=c.text(h5, "created", required=False), format_version=version)
    # everything outside the core layout comes back as it was written (measured points, frames, ...)
    _extras(c, h5, a)
    if "obstacles" in h5:
        if not isinstance(h5["obstacles"], h5py.Group):
            c.fail("/obstacles", "must be a group of obstacles /obstacles/<k>")
        try:
            a.obstacles = read_obstacles(h5["obstacles"], c.file)
        except ArchiveError:
            raise
        except InputError as exc:
            raise ArchiveError(exc.file, exc.key, exc.reason) from None
    runs = c.group(h5, "runs")
    if len(runs) > limits.MAX_RUNS:
        c.fail("/runs", f"{len(runs)} runs, more than the limit of {limits.MAX_RUNS} (vine_nlp.io.limits.MAX_RUNS)")
    for name in runs:
        a.runs[name] = _run(c, name, runs[name], a)
    return a


def load_archive(path) -> Archive:
    """Read the archive at ``path`` back into an Archive, every part checked (see the module docstring).
    Raises ArchiveError (an InputError and a ValueError) for a missing, unreadable, malformed or oversized
    archive, naming the dataset and the reason; nothing else."""
    c = _Checker(path)
    try:
        with open_archive(path) as h5:
            return _load(c, h5)
    except ArchiveError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, IndexError, AttributeError, UnicodeError,
            OverflowError, MemoryError, json.JSONDecodeError) as exc:
        # h5py reports damaged files in many ways; the part being read is not always known here
        text = " ".join(str(exc).split())[:300] or type(exc).__name__
        raise ArchiveError(path, "file", f"cannot read the archive ({text})") from None
