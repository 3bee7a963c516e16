"""Correction archives (spec/formats.md, "As-built correction") and measured-point files.

A correction archive is a result archive (every command reads it) with:

``/runs/<design run>``       the nominal that was first built (kept from the input archive)
``/runs/as_built``           the estimated effective routing of the robot measured last; metrics ``rmse``,
                             ``max_error`` against the measurements (distances of the measured points to the
                             estimated line), ``target_rmse``, ``target_max_error`` against the target;
                             ``uncertainty/{theta,lambda,length}`` (M,) standard deviations of the estimate;
                             ``deviation/{theta,lambda,length_ratio}`` (M,) the deviations kept build to build
``/runs/corrected``          the nominal to build next on the chosen route (``/correction@adjust``); shape and
                             metrics: what it is predicted to realize; ``shortfall``: why it cannot reach the target
``/runs/corrected_lambda``, ``/runs/corrected_lambda_theta``  both routes' corrections (stats ``route``,
                             ``recommended``; metric ``rmse_without_bounds`` where a bound is reached)
``/measured/points``         every measured point so far (archive frame), all files stacked
``/measured/<k>/points``     measurement k, attrs ``line``, ``file``, ``build``
``/correction``              attrs ``format`` ("vine_nlp/correction"), ``builds``, ``built_run``, ``adjust`` (the
                             route taken), ``recommended``, ``free_pose``, the sigmas; ``systematic`` (3,) = (theta
                             offset rad, lambda offset, length scale) and ``systematic_std`` (3,);
                             ``builds/<b>/{theta,lambda,length,initial_pose}`` the nominal of build b (oldest first)

Bad files raise :class:`vine_nlp.errors.InputError` (archives: ``ArchiveError``) naming the file and the key."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io import limits
from vine_nlp.io.archive import Archive, ArchiveError, load_archive, write_archive
from vine_nlp.io.calibration import check_calibration
from vine_nlp.io.data_files import check_spread, read_csv
from vine_nlp.io.h5read import decode_attr, open_archive
from vine_nlp.io.validate import SourceFile
from vine_nlp.methods.correct import CorrectionResult, Measurement
from vine_nlp.model.routing import MEASURED_LINES, Routing

FORMAT = "vine_nlp/correction"
MIN_MEASURED_POINTS = 10
MAX_MEASURED_POINTS = limits.MAX_TARGET_POINTS
RUNS = ("as_built", "corrected", "corrected_lambda", "corrected_lambda_theta")


def read_measured(path) -> np.ndarray:
    """Measured points of a CSV file: rows x y z (a header line and # comments allowed), any order. InputError
    ``(file, "line N" | "values" | "file", reason)``: a missing file, a bad row, too few or too many points."""
    path = Path(path)
    pts = read_csv(SourceFile(str(path)))
    if pts.shape[1] != 3:
        raise InputError(path, "line 1", f"expected 3 values (x y z), got {pts.shape[1]}")
    if pts.shape[0] < MIN_MEASURED_POINTS:
        raise InputError(path, "values", f"needs at least {MIN_MEASURED_POINTS} points, got {pts.shape[0]}")
    return pts


@dataclass
class CorrectionState:
    """What a correction archive adds: the builds' nominals (oldest first), the measurements and the settings."""

    builds: list
    measurements: list
    attrs: dict = field(default_factory=dict)
    systematic: np.ndarray | None = None
    systematic_std: np.ndarray | None = None
    uncertainty: dict = field(default_factory=dict)
    deviation: dict = field(default_factory=dict)


def write_correction_archive(path, base: Archive, result: CorrectionResult, builds: list, settings: dict) -> None:
    """Write the correction archive (module docstring) atomically.

    ``base``: the archive that was corrected (its target, problem and runs other than as_built and
    corrected are kept); ``builds``: the nominal of every build so far, oldest first (the last is
    ``result.built``); ``settings``: attributes of /correction (adjust, free_pose, sigmas, built_run)."""
    runs = {k: v for k, v in base.runs.items() if k not in RUNS}
    runs["as_built"], runs["corrected"] = result.as_built, result.corrected
    for name, r in result.routes.items():
        runs[f"corrected_{name.replace(',', '_')}"] = r
    extra = {k: v for k, v in base.extra.items() if not (k.startswith("measured/") or k.startswith("correction/"))}
    ms = result.measurements
    extra["measured/points"] = np.concatenate([m.points for m in ms])
    for k, m in enumerate(ms):
        extra[f"measured/{k}/points"] = m.points
    for b, r in enumerate(builds):
        for name, v in (("theta", r.theta), ("lambda", r.lam), ("length", r.length), ("initial_pose", r.initial_pose)):
            extra[f"correction/builds/{b}/{name}"] = v
    est = result.estimate
    extra |= {"correction/systematic": est.systematic, "correction/systematic_std": est.systematic_std}
    archive = Archive(name=base.name, kind=base.kind, source=base.source, diameter=base.diameter, units=base.units,
                      target=base.target, runs=runs, extra=extra)

    def extend(h5):
        g = h5["correction"]
        g.attrs.update(format=FORMAT, builds=len(builds), systematic_names="theta_offset_rad,lambda_offset,length_scale",
                       **{k: v for k, v in settings.items()})
        for k, m in enumerate(ms):
            h5[f"measured/{k}"].attrs.update(line=m.line, file=m.file, build=int(m.build))
        ab = h5["runs/as_built"]
        for name, col in (("theta", 0), ("lambda", 1), ("length", 2)):
            ab.create_dataset(f"uncertainty/{name}", data=est.std[:, col])
        dev = est.deviations
        for name, v in (("theta", dev.theta), ("lambda", dev.lam), ("length_ratio", dev.length_ratio)):
            ab.create_dataset(f"deviation/{name}", data=v)

    write_archive(path, archive, extend=extend)


def read_correction(path) -> tuple[Archive, CorrectionState | None]:
    """The archive (validated by ``load_archive``) and its correction state (None for a plain design archive).
    ArchiveError: a malformed correction part, naming the dataset or attribute."""
    a = load_archive(path)
    try:
        with open_archive(path) as h5:
            if "correction" not in h5:
                return a, None
            return a, _state(str(path), h5, a)
    except ArchiveError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ArchiveError(path, "/correction", f"cannot read ({' '.join(str(exc).split())[:200]})") from None


def _attr(file, node, name, kinds, required=True, default=None):
    if name not in node.attrs:
        if required:
            raise ArchiveError(file, f"{node.name}@{name}", "missing attribute")
        return default
    v = decode_attr(node.attrs[name])
    if not isinstance(v, kinds) or isinstance(v, bool) and bool not in kinds:
        raise ArchiveError(file, f"{node.name}@{name}", f"unexpected type {type(v).__name__}")
    return v


def _state(file, h5, a: Archive) -> CorrectionState:
    g = h5["correction"]
    if not isinstance(g, h5py.Group):
        raise ArchiveError(file, "/correction", "must be a group")
    if _attr(file, g, "format", (str,)) != FORMAT:
        raise ArchiveError(file, "/correction@format", f"not {FORMAT!r}")
    B = _attr(file, g, "builds", (int,))
    if not 1 <= B <= limits.MAX_RUNS:
        raise ArchiveError(file, "/correction@builds", f"must be 1..{limits.MAX_RUNS}, got {B}")
    builds = _builds(file, a, B)
    ms = _measurements(file, h5, a, B)
    attrs = {name: _attr(file, g, name, (str, int, float, bool)) for name in g.attrs}
    sysv, sys_sd = a.extra.get("correction/systematic"), a.extra.get("correction/systematic_std")
    for key, v in (("systematic", sysv), ("systematic_std", sys_sd)):
        if v is None or np.shape(v) != (3,):
            raise ArchiveError(file, f"/correction/{key}", "missing or not 3 values")
    if not sysv[2] > 0 or np.any(sys_sd < 0):
        raise ArchiveError(file, "/correction/systematic", "length scale must be > 0 and standard deviations >= 0")
    for key, table in (("systematic", dict(theta_offset_deg=np.degrees(sysv[0]), lambda_offset=sysv[1], length_scale=sysv[2])),
                       ("systematic_std", dict(theta_offset_deg_se=np.degrees(sys_sd[0]), lambda_offset_se=sys_sd[1], length_scale_se=sys_sd[2]))):
        try:  # the calibration table's rules: what calibrate makes of these, a design reads
            check_calibration(table, "")
        except InputError as e:
            raise ArchiveError(file, f"/correction/{key}", e.reason.replace("must", f"{e.key.split('.')[-1]} must", 1)) from None
    unc, dev = _as_built_spread(file, h5, builds[0].theta.size)
    return CorrectionState(builds, ms, attrs, np.asarray(sysv, float), np.asarray(sys_sd, float), unc, dev)


def _builds(file, a: Archive, B: int) -> list:
    """The B routings built so far (/correction/builds/b), one segment count in all."""
    builds, M = [], None
    for b in range(B):
        key = f"correction/builds/{b}"
        try:
            theta, lam, length, pose = (a.extra[f"{key}/{n}"].astype(float) for n in ("theta", "lambda", "length", "initial_pose"))
        except KeyError as exc:
            raise ArchiveError(file, f"/{key}", f"missing {exc.args[0].rsplit('/', 1)[-1]}") from None
        M = theta.size if M is None else M
        if theta.ndim != 1 or lam.shape != theta.shape or length.shape != theta.shape or theta.size != M:
            raise ArchiveError(file, f"/{key}", "theta, lambda and length need one entry per segment, the same in every build")
        if np.any(length <= 0) or np.any(lam <= 0):
            raise ArchiveError(file, f"/{key}", "lengths and lambdas must be > 0")
        if pose.shape != (4, 4):
            raise ArchiveError(file, f"/{key}/initial_pose", f"shape {pose.shape}, expected (4, 4)")
        builds.append(Routing(theta=theta, lam=lam, length=length, initial_pose=pose))
    return builds


def _measurements(file, h5, a: Archive, B: int) -> list:
    """Every measurement kept (/measured/k), each of one of the B builds; at least one."""
    ms, mg, k = [], h5.get("measured"), 0
    while mg is not None and str(k) in mg:
        node = mg[str(k)]
        pts = a.extra.get(f"measured/{k}/points")
        if pts is None:
            raise ArchiveError(file, f"/measured/{k}/points", "missing")
        line = _attr(file, node, "line", (str,))
        if line not in MEASURED_LINES:
            raise ArchiveError(file, f"/measured/{k}@line", f"must be one of {', '.join(MEASURED_LINES)}, got {line!r}")
        build = _attr(file, node, "build", (int,))
        if not 0 <= build < B:
            raise ArchiveError(file, f"/measured/{k}@build", f"must be 0..{B - 1}, got {build}")
        try:  # the rule of a measurement read from a file: archived, it was one
            check_spread(file, pts.astype(float), a.diameter, MIN_MEASURED_POINTS)
        except InputError as e:
            raise ArchiveError(file, f"/measured/{k}/points", e.reason) from None
        ms.append(Measurement(pts.astype(float), line, build, "archive", _attr(file, node, "file", (str,), False, "")))
        k += 1
    if sum(len(m.points) for m in ms) > MAX_MEASURED_POINTS:
        raise ArchiveError(file, "/measured", f"{sum(len(m.points) for m in ms)} measured points in all: at most {MAX_MEASURED_POINTS}")
    if not ms:
        raise ArchiveError(file, "/measured/0/points", "missing: a correction archive holds its measurements")
    return ms


def _as_built_spread(file, h5, M: int) -> tuple[dict, dict]:
    """The as-built estimate's uncertainty and deviation per segment (/runs/as_built/...), where stored."""
    unc, dev = {}, {}
    ab = h5.get("runs/as_built")
    if ab is not None:
        for grp, out, names in (("uncertainty", unc, ("theta", "lambda", "length")), ("deviation", dev, ("theta", "lambda", "length_ratio"))):
            for n in names:
                ds = ab.get(f"{grp}/{n}")
                if ds is None:
                    continue
                v = np.asarray(ds[()], float)
                if v.shape != (M,) or not np.all(np.isfinite(v)):
                    raise ArchiveError(file, f"/runs/as_built/{grp}/{n}", f"must be {M} finite values")
                out[n] = v
    return unc, dev
