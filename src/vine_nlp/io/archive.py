"""HDF5 result archives (../shared/spec/formats.md, "Result archives"), written atomically."""

from __future__ import annotations

import datetime as _dt
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from vine_nlp import __version__
from vine_nlp.design.problem import Routing
from vine_nlp.design.result import Result, Shape

FORMAT = "vine_nlp/result"
FORMAT_VERSION = 1
_COMPRESS = dict(compression="gzip", compression_opts=4, shuffle=True)


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
    software_version: str = __version__
    created: str = ""
    format_version: int = FORMAT_VERSION

    def default_run(self) -> str | None:
        """The run a command uses when none is named: the first of DEFAULT_RUNS present, else
        the first run (None for an archive without runs)."""
        return next((r for r in DEFAULT_RUNS if r in self.runs), next(iter(self.runs), None))


# the design a command reads from an archive by default (template, analyze, --warm), in this order
DEFAULT_RUNS = ("nlp", "nlp_robust", "nlp_clearance", "greedy", "forward", "fit", "tip", "multishape")


def atomic_path(path: Path):
    """A temporary file beside ``path``: same directory, so the final os.replace is atomic."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    # mkstemp makes the file private (0600): give the result the permissions a plain open() would
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return Path(tmp)


def write_atomic(path, write):
    """Call ``write(tmp_path)`` then rename onto ``path``; on any failure nothing is left behind."""
    path = Path(path)
    tmp = atomic_path(path)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _attr(value):
    if isinstance(value, (dict, list, tuple)):
        return json.dumps(value, default=float)
    if value is None:
        return "none"
    return value


def _write(h5: h5py.File, a: Archive):
    h5.attrs.update(
        format=FORMAT,
        format_version=FORMAT_VERSION,
        software_version=__version__,
        created=a.created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        units=a.units,
    )
    g = h5.create_group("problem")
    g.attrs.update(name=a.name, kind=a.kind, source=a.source)
    h5.create_group("tube").attrs["diameter"] = float(a.diameter)
    if a.target is not None:
        h5.create_dataset("target/points", data=np.asarray(a.target, float), **_COMPRESS)
    for key, arr in a.extra.items():
        h5.create_dataset(key.strip("/"), data=np.asarray(arr), **_COMPRESS)
    runs = h5.create_group("runs")
    for name, r in a.runs.items():
        g = runs.create_group(name)
        g.attrs.update(method=r.method, status=r.status, solve_time_s=float(r.solve_time_s), iterations=int(r.iterations))
        d = g.create_group("design")
        d.create_dataset("theta", data=r.routing.theta, **_COMPRESS)
        d.create_dataset("lambda", data=r.routing.lam, **_COMPRESS)
        d.create_dataset("length", data=r.routing.length, **_COMPRESS)
        d.create_dataset("phi", data=r.phi, **_COMPRESS)
        d.create_dataset("initial_pose", data=r.routing.initial_pose)
        s = g.create_group("shape")
        for line in ("center", "inner", "outer"):
            s.create_dataset(line, data=getattr(r.shape, line), **_COMPRESS)
        m = g.create_group("metrics")
        m.attrs.update({k: float(v) for k, v in r.metrics.items()})
        st = g.create_group("solver")
        st.attrs.update({k: _attr(v) for k, v in r.stats.items()})


def write_archive(path, archive: Archive) -> None:
    """Write ``archive`` to ``path`` atomically (temporary file in the same directory, then rename)."""

    def write(tmp):
        with h5py.File(tmp, "w") as h5:
            _write(h5, archive)

    write_atomic(path, write)


def _decode(v):
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v


_CORE_GROUPS = ("problem", "tube", "target", "runs")


def _collect(extra, key, obj):
    if isinstance(obj, h5py.Dataset):
        extra[key] = obj[()]


def load_archive(path) -> Archive:
    """Read an archive back into typed objects."""
    with h5py.File(path, "r") as h5:
        if _decode(h5.attrs.get("format")) != FORMAT:
            raise ValueError(f"{path}: not a vine_nlp result archive")
        p = h5["problem"].attrs
        a = Archive(
            name=_decode(p["name"]),
            kind=_decode(p["kind"]),
            source=_decode(p["source"]),
            diameter=float(h5["tube"].attrs["diameter"]),
            units=_decode(h5.attrs["units"]),
            target=h5["target/points"][()] if "target/points" in h5 else None,
            software_version=_decode(h5.attrs["software_version"]),
            created=_decode(h5.attrs["created"]),
            format_version=int(h5.attrs["format_version"]),
        )
        # everything outside the core layout comes back as it was written (measured points, frames, ...)
        for top in h5:
            if top not in _CORE_GROUPS:
                h5[top].visititems(lambda name, obj, top=top: _collect(a.extra, f"{top}/{name}", obj))
        for name, g in h5["runs"].items():
            d = g["design"]
            routing = Routing(d["theta"][()], d["lambda"][()], d["length"][()], d["initial_pose"][()])
            shape = Shape(*(g["shape"][k][()] for k in ("center", "inner", "outer")))
            stats = {k: _decode(v) for k, v in g["solver"].attrs.items()} if "solver" in g else {}
            a.runs[name] = Result(
                method=_decode(g.attrs["method"]),
                routing=routing,
                shape=shape,
                status=_decode(g.attrs["status"]),
                solve_time_s=float(g.attrs["solve_time_s"]),
                iterations=int(g.attrs["iterations"]),
                metrics={k: float(v) for k, v in g["metrics"].attrs.items()},
                stats=stats,
                diameter=a.diameter,
            )
    return a
