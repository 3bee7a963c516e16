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

import json
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io import limits
from vine_nlp.io.actuators import write_actuators_archive
from vine_nlp.io.archive import Archive, ArchiveError, load_archive, write_archive
from vine_nlp.io.calibration import check_calibration
from vine_nlp.io.data_files import check_spread, read_csv
from vine_nlp.io.h5read import decode_attr, open_archive
from vine_nlp.io.validate import SourceFile
from vine_nlp.methods.actuators import ActuatorsResult
from vine_nlp.methods.correct import CorrectionResult, Deviations, Measurement
from vine_nlp.model.actuators import Lines
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
    deviation: dict | list | None = field(default_factory=dict)  # several actuators: Deviations per actuator, or None


def write_correction_archive(path, base: Archive, result: CorrectionResult, builds: list, settings: dict) -> None:
    """Write the correction archive (module docstring) atomically.

    ``base``: the archive that was corrected (its target, problem and runs other than as_built and
    corrected are kept); ``builds``: the nominal of every build so far, oldest first (the last is
    ``result.built``); ``settings``: attributes of /correction (adjust, free_pose, sigmas, built_run). A tube of
    several actuators: :func:`_write_several`."""
    if isinstance(result.corrected, ActuatorsResult):
        return _write_several(path, base, result, builds, settings)
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


def _write_several(path, base: Archive, result: CorrectionResult, builds: list, settings: dict) -> None:
    """The correction archive of a tube of several actuators (spec "As-built correction"): ``base``'s runs (each an
    ActuatorsResult) but a correction's, ``as_built``, ``corrected`` and both routes' in the several-actuator layout, the
    deviations and uncertainties per actuator under /runs/as_built/actuators/<name>/ and the length's under
    /runs/as_built/; /measured/<state>/points (every point of the state so far) and /measured/<state>/<k>/points;
    /correction/builds/<b>/{theta, lambda (K, M), phi0 (K,), length (M,), initial_pose}."""
    runs = {k: v for k, v in base.runs.items() if k not in RUNS} | {"as_built": result.as_built, "corrected": result.corrected}
    runs |= {f"corrected_{name.replace(',', '_')}": r for name, r in result.routes.items()}
    extra = {k: v for k, v in base.extra.items() if k.split("/")[0] not in ("measured", "correction", "targets")}
    by_state = {}
    for m in result.measurements:
        by_state.setdefault(m.state, []).append(m)
    for st, ms in by_state.items():
        extra[f"measured/{st}/points"] = np.concatenate([m.points for m in ms])
        extra |= {f"measured/{st}/{k}/points": m.points for k, m in enumerate(ms)}
    for b, r in enumerate(builds):
        for name, v in (("theta", r.theta), ("lambda", r.lam), ("phi0", r.phi0), ("length", r.length), ("initial_pose", r.initial_pose)):
            extra[f"correction/builds/{b}/{name}"] = v
    est = result.estimate
    extra |= {"correction/systematic": est.systematic, "correction/systematic_std": est.systematic_std}
    states = result.corrected.stats["states"]
    problem = SimpleNamespace(diameter=base.diameter, states=states, targets={st: base.extra[f"targets/{st}/points"] for st in states})

    def extend(h5):
        h5["correction"].attrs.update(format=FORMAT, builds=len(builds), systematic_names="theta_offset_rad,lambda_offset,length_scale", **settings)
        for st, ms in by_state.items():
            for k, m in enumerate(ms):
                h5[f"measured/{st}/{k}"].attrs.update(line=m.line, file=m.file, build=int(m.build))
        ab, names = h5["runs/as_built"], est.routing.names
        for k, name in enumerate(names):
            for key, v in (("deviation/theta", est.deviations[k].theta), ("deviation/lambda", est.deviations[k].lam),
                           ("uncertainty/theta", est.std[name][:, 0]), ("uncertainty/lambda", est.std[name][:, 1])):
                ab.create_dataset(f"actuators/{name}/{key}", data=v)
        ab.create_dataset("deviation/length_ratio", data=est.deviations[0].length_ratio)
        ab.create_dataset("uncertainty/length", data=est.std[names[0]][:, 2])

    write_actuators_archive(path, SimpleNamespace(problem=problem, name=base.name, kind=base.kind, source=base.source, units=base.units),
                            runs, extra, extend)


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
    several = a.kind.startswith("actuators")
    builds = _builds_several(file, h5, a, B) if several else _builds(file, a, B)
    ms = _measurements(file, h5, a, B, several)
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
    unc, dev = _deviations_several(file, h5, builds[-1]) if several else _as_built_spread(file, h5, builds[0].theta.size)
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


def _measurements(file, h5, a: Archive, B: int, several: bool = False) -> list:
    """Every measurement kept (/measured/k; several actuators: /measured/<state>/k), each of one of the B builds;
    at least one."""
    ms, top = [], h5.get("measured")
    groups = [(st, f"measured/{st}") for st in (top if top is not None else ())] if several else [("", "measured")]
    for state, key in groups:
        mg, k = h5.get(key), 0
        while isinstance(mg, h5py.Group) and str(k) in mg:
            node, at = mg[str(k)], f"{key}/{k}"
            pts = a.extra.get(f"{at}/points")
            if pts is None:
                raise ArchiveError(file, f"/{at}/points", "missing")
            line = _attr(file, node, "line", (str,))
            if line not in MEASURED_LINES:
                raise ArchiveError(file, f"/{at}@line", f"must be one of {', '.join(MEASURED_LINES)}, got {line!r}")
            build = _attr(file, node, "build", (int,))
            if not 0 <= build < B:
                raise ArchiveError(file, f"/{at}@build", f"must be 0..{B - 1}, got {build}")
            try:  # the rule of a measurement read from a file: archived, it was one
                check_spread(file, pts.astype(float), a.diameter, MIN_MEASURED_POINTS)
            except InputError as e:
                raise ArchiveError(file, f"/{at}/points", e.reason) from None
            ms.append(Measurement(pts.astype(float), line, build, "archive", _attr(file, node, "file", (str,), False, ""), state))
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


def _builds_several(file, h5, a: Archive, B: int) -> list:
    """The B nominal Lines built so far (/correction/builds/b: theta and lambda (K, M), phi0 (K,), length (M,))."""
    try:
        names = tuple(json.loads(decode_attr(h5["runs/as_built"].attrs["actuators"])))
    except (KeyError, ValueError, TypeError):
        raise ArchiveError(file, "/runs/as_built@actuators", "missing or not the JSON list of the actuators") from None
    builds = []
    for b in range(B):
        key = f"correction/builds/{b}"
        try:
            theta, lam, phi0, length, pose = (a.extra[f"{key}/{n}"].astype(float) for n in ("theta", "lambda", "phi0", "length", "initial_pose"))
        except KeyError as exc:
            raise ArchiveError(file, f"/{key}", f"missing {exc.args[0].rsplit('/', 1)[-1]}") from None
        M = builds[0].segments if builds else length.size
        if theta.shape != (len(names), M) or lam.shape != theta.shape or phi0.shape != (len(names),) or length.shape != (M,) or pose.shape != (4, 4):
            raise ArchiveError(file, f"/{key}", f"theta and lambda need ({len(names)}, {M}) values, phi0 one per actuator, length one per segment (the same in every build), initial_pose 4 x 4")
        if np.any(length <= 0) or np.any(lam <= 0) or np.any(lam > 1):
            raise ArchiveError(file, f"/{key}", "lengths must be > 0 and lambdas in (0, 1]")
        builds.append(Lines(names, theta, lam, phi0, length, pose))
    return builds


def _deviations_several(file, h5, latest: Lines) -> tuple[dict, list | None]:
    """The as-built estimate's deviations per actuator (Deviations, the length ratio shared), None where not stored."""
    ab, M = h5.get("runs/as_built"), latest.segments
    at = [f"actuators/{n}/deviation/{q}" for n in latest.names for q in ("theta", "lambda")] + ["deviation/length_ratio"]
    if ab is None or any(k not in ab for k in at):
        return {}, None
    v = {}
    for k in at:
        v[k] = np.asarray(ab[k][()], float)
        if v[k].shape != (M,) or not np.all(np.isfinite(v[k])):
            raise ArchiveError(file, f"/runs/as_built/{k}", f"must be {M} finite values")
    ratio = v["deviation/length_ratio"]
    return {}, [Deviations(v[f"actuators/{n}/deviation/theta"], v[f"actuators/{n}/deviation/lambda"], ratio) for n in latest.names]
