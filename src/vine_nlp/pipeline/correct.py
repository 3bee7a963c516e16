"""Close the loop on a built robot (docs: "As-built correction"): an archive and measured points ->
the estimate of what was built and the nominal to build next; several prototypes -> a calibration.
The estimate and the correction are ``vine_nlp.methods.correct``; the archive layout ``vine_nlp.io.correction``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io.actuators import read_actuators_archive
from vine_nlp.io.archive import Archive
from vine_nlp.io.archived import archived_actuators, archived_problem
from vine_nlp.io.calibration import Calibration
from vine_nlp.io.correction import MAX_MEASURED_POINTS, MIN_MEASURED_POINTS, read_correction, read_measured, write_correction_archive
from vine_nlp.io.data_files import check_spread
from vine_nlp.methods import settings
from vine_nlp.methods.correct import ADJUST, Deviations, Measurement, combine_systematic, correct
from vine_nlp.methods.correct.several import correct_several
from vine_nlp.model.pairing import pair_points
from vine_nlp.model.routing import MEASURED_LINES, Sigmas, actuated
from vine_nlp.model.units import mm_per_unit
from vine_nlp.pipeline.runs import judge_load

PLAUSIBLE_MEDIAN = 5.0  # median distance of the measured points to the estimated line, in noise sigmas, beyond which it is not this robot


def correct_files(archive_path, measured, *, run=None, lines=("outer",), adjust=None, free_pose=False, sigmas=None,
                  measurement_sigma=None, states=None):
    """Read an archive (a design archive, or the path of a correction archive: its earlier measurements are used
    too, its estimate is the warm start) and the points measured on the robot built from run ``run`` (CSV files or
    (K, 3) arrays; ``lines``: one for all or one per file), estimate and correct (``adjust``: the route taken, None:
    the recommended one); no file written. Returns (CorrectionResult, base Archive, builds (Routing, oldest first),
    the /correction attributes). Raises InputError: a bad archive or CSV, an unknown run, mismatched lines.
    An archive of several actuators: ``states`` names the state of each file (or one for all): :func:`_correct_several`."""
    archive_path, archive, state, run = _built_run(archive_path, run)
    lines = tuple(lines)
    if len(lines) not in (1, len(measured)):
        raise InputError("command line", "--line", f"one line for all files or one per file ({len(measured)}), got {len(lines)}")
    for ln in lines:
        if ln not in MEASURED_LINES:
            raise InputError("command line", "--line", f"must be one of {', '.join(MEASURED_LINES)}, got {ln!r}")
    adjust = None if adjust is None else tuple(adjust)
    if adjust is not None and adjust not in ADJUST:
        raise InputError("command line", "--adjust", "must be lambda or lambda,theta")
    pts = [_points(p, k) for k, p in enumerate(measured)]
    for k, (p, f) in enumerate(zip(pts, measured)):
        check_spread(f if isinstance(f, (str, Path)) else f"measured[{k}]", p, archive.diameter, MIN_MEASURED_POINTS)
    mm = mm_per_unit(archive.units)  # for the default measurement sigma of 1 mm
    if measurement_sigma is None and mm is None:
        raise InputError("command line", "--sigma-measurement", f"archive units {archive.units!r}: give the measurement sigma in them")
    if measurement_sigma is not None and not measurement_sigma > 0:
        raise InputError("command line", "--sigma-measurement", f"must be > 0, got {measurement_sigma}")
    sigmas = sigmas or Sigmas.from_degrees(1.0, 0.02, 0.02)
    measurement_sigma = measurement_sigma or settings.DEFAULT_MEASUREMENT_SIGMA_MM / (mm or 10.0)
    if archive.kind.startswith("actuators"):
        if free_pose:
            raise InputError("command line", "--free-pose", "not for an archive of several actuators yet (measure in its frame)")
        return _correct_several(archive_path, archive, state, run, measured, pts, lines, adjust, sigmas, measurement_sigma, states)
    if states:
        raise InputError(archive_path, "--state", "an archive of one actuator has no states (--state is for archives of several actuators)")
    problem = archived_problem(archive, archive_path, run)
    built = archive.runs[run].routing
    builds = (list(state.builds) if state else []) + [built]
    if any(b.segments != built.segments for b in builds):
        raise InputError(archive_path, f"/runs/{run}/design/theta", "the builds of one robot need the same segments")
    M = pair_points(problem.target, problem.options.points_per_segment).segments
    if built.segments != M:
        raise InputError(archive_path, f"/runs/{run}/design/theta", f"{built.segments} segments, the problem's pairing has {M}")
    new = [Measurement(p, lines[0] if len(lines) == 1 else lines[k], len(builds) - 1, "free" if free_pose else "archive",
                       Path(f).name if isinstance(f, (str, Path)) else f"measured[{k}]")
           for k, (p, f) in enumerate(zip(pts, measured))]
    ms = (list(state.measurements) if state else []) + new
    # round 2 and later start from the last round's estimate (its deviations and systematic parts)
    dev = state.deviation if state is not None and len(state.deviation) == 3 else None
    start = Deviations(dev["theta"], dev["lambda"], dev["length_ratio"]) if dev else None
    result = correct(problem, builds, ms, adjust=adjust, sigmas=sigmas, measurement_sigma=measurement_sigma,
                     units_per_mm=1 / (mm or 10.0), start=start, start_systematic=state.systematic if start else None)
    _check_plausible(result, new, problem.diameter, archive.units)
    if problem.load is not None:  # the robot as built and the correction to build, under the problem's [load]
        judge_load(problem, result.as_built)
        result.corrected.shortfall = tuple(result.corrected.shortfall) + tuple(judge_load(problem, result.corrected))
    return result, archive, builds, _settings(run, result, free_pose, sigmas)


def _settings(run, result, free_pose, sigmas) -> dict:
    """The /correction attributes."""
    return {"built_run": run, "adjust": ",".join(result.adjust), "recommended": result.recommended, "free_pose": bool(free_pose), "sigma_theta_rad": sigmas.theta,
            "sigma_lambda": sigmas.lam, "sigma_length": sigmas.length, "relative_length": bool(sigmas.relative_length),
            "sigma_measurement": result.estimate.stats["measurement_sigma"]}


def _correct_several(path, archive, state, run, measured, pts, lines, adjust, sigmas, sigma_m, names):
    """``correct_files`` of an archive of several actuators (spec "As-built correction"): each measurement names its
    state (``names``: one per file, or one for all; none where the archive has one state); the runs returned in the
    archive are ActuatorsResults, the builds Lines."""
    runs = {r: read_actuators_archive(path, r)[1] for r in archive.runs}
    problem = archived_actuators(archive, path, runs[run])
    names = list(names or ())
    if not names and len(problem.states) == 1:
        names = list(problem.states)
    if len(names) not in (1, len(measured)):
        raise InputError("command line", "--state", f"one state for all files or one per file ({len(measured)}), got {len(names)}"
                         + ("" if names else f"; the archive's states: {', '.join(problem.states)}"))
    built = runs[run].lines
    for s in names:
        if s not in problem.states:
            raise InputError(path, "--state", f"no state {s!r} (states: {', '.join(problem.states)})")
        if not actuated(built.lam[built.index(problem.states[s])]).any():
            raise InputError(path, "--state", f"state {s!r}: its actuators ({', '.join(problem.states[s])}) have no actuator on any "
                             f"segment of run {run}: its shape is straight and shows no deviation")
    builds = (list(state.builds) if state else []) + [built]
    if any(b.segments != built.segments or b.names != built.names for b in builds):
        raise InputError(path, f"/runs/{run}/actuators", "the builds of one robot need the same actuators and segments")
    new = [Measurement(p, lines[0] if len(lines) == 1 else lines[k], len(builds) - 1, "archive",
                       Path(f).name if isinstance(f, (str, Path)) else f"measured[{k}]", names[0] if len(names) == 1 else names[k])
           for k, (p, f) in enumerate(zip(pts, measured))]
    old = list(state.measurements) if state else []
    if unknown := [m.state for m in old if m.state not in problem.states]:
        raise InputError(path, f"/measured/{unknown[0]}", "a measurement of a state the archive does not have")
    start = state.deviation if state is not None and state.deviation else None
    result = correct_several(problem, builds, old + new, adjust=adjust, sigmas=sigmas, measurement_sigma=sigma_m, start=start,
                             start_systematic=state.systematic if start else None)
    _check_plausible(result, new, problem.diameter, archive.units)
    archive.runs = runs
    return result, archive, builds, _settings(run, result, False, sigmas)


def _built_run(archive_path, run):
    """(path, design Archive, correction state or None, the run that was built) of ``correct_files``'s archive."""
    if isinstance(archive_path, Archive):
        archive, state = archive_path, None
        if any(k.startswith("correction/") for k in archive.extra):
            raise InputError(archive.name, "ARCHIVE", "a correction archive: pass its path (its measurements are read from the file)")
        archive_path = Path(f"{archive.name}.h5")
    else:
        archive_path = Path(archive_path)
        if not archive_path.exists():
            raise InputError(archive_path, "ARCHIVE", "no such file")
        archive, state = read_correction(archive_path)
    if archive.kind not in ("design", "actuators") or archive.target is None:
        raise InputError(archive_path, "/problem@kind", f"correct needs a design archive with a target (this is {archive.kind!r})")
    if run is None:
        run = "corrected" if state is not None and "corrected" in archive.runs else archive.default_run()
    if run is None or run not in archive.runs:
        raise InputError(archive_path, "--run", f"no run {run!r} (runs: {', '.join(archive.runs) or 'none'})")
    if run == "as_built":
        raise InputError(archive_path, "--run", "as_built is an estimate, not a nominal that was built")
    return archive_path, archive, state, run


def _check_plausible(result, new, D, units):
    """InputError for a measurement that cannot be this robot: the estimate passes farther from most of its points
    than noise explains (the median distance is about 1.2 sigma under Gaussian noise; more than PLAUSIBLE_MEDIAN
    sigma and a quarter of the diameter is not noise): another shape, another frame, the wrong archive."""
    sig = float(result.estimate.stats["measurement_sigma"])
    limit = max(PLAUSIBLE_MEDIAN * sig, 0.25 * D)
    dists = result.estimate.residuals[len(result.estimate.residuals) - len(new):]
    for m, d in zip(new, dists):
        med = float(np.median(d))
        if med > limit:
            raise InputError(m.file, "points", f"cannot be this robot: the best estimate passes {med:.3g} {units} (median) from "
                             f"the points, more than {limit:.3g} {units} (noise sigma {sig:.3g}); another shape, another frame "
                             "(--free-pose) or another archive?")


def _points(p, k):
    """Measured points from a CSV path or an (K, 3) array (checked like a file)."""
    if isinstance(p, (str, Path)):
        return read_measured(p)
    a = np.asarray(p, float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"measured[{k}]", "values", f"must be an (n, 3) array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"measured[{k}]", f"row {int(np.argmin(np.all(np.isfinite(a), axis=1)))}", "not finite")
    if not MIN_MEASURED_POINTS <= a.shape[0] <= MAX_MEASURED_POINTS:
        raise InputError(f"measured[{k}]", "values", f"needs {MIN_MEASURED_POINTS} to {MAX_MEASURED_POINTS} points, got {a.shape[0]}")
    return a


def correct_to_file(archive_path, measured, output, **kw):
    """``correct_files`` and write the correction archive to ``output`` (the API's file-level entry)."""
    result, archive, builds, settings = correct_files(archive_path, measured, **kw)
    write_correction_archive(output, archive, result, builds, settings)
    return result


def shortfall(result) -> list[str]:
    """Why the chosen route does not reach the target, one line each ([] when it does: exit 0): an estimate that did
    not converge, or the route's own shortfall (methods.correct: bounds that cost accuracy, a correction that did not
    converge, each buildable rule its nominal misses)."""
    if not result.as_built.converged:
        return [f"the estimate did not converge ({result.as_built.status})"]
    return list(result.corrected.shortfall)


def calibrate(paths) -> tuple[Calibration, float]:
    """The systematic construction errors over several correction archives (prototypes of one method):
    (Calibration, the scatter of the estimates in units of their standard errors, Birge's ratio)."""
    est, sd = [], []
    for path in paths:
        if not Path(path).exists():
            raise InputError(path, "ARCHIVE", "no such file")
        _, state = read_correction(path)
        if state is None:
            raise InputError(path, "/correction", "not a correction archive (made by vine-nlp correct)")
        est.append(state.systematic)
        sd.append(state.systematic_std)
    mean, se, birge = combine_systematic(est, sd)
    cal = Calibration(lambda_offset=float(mean[1]), theta_offset_deg=math.degrees(mean[0]), length_scale=float(mean[2]),
                      lambda_offset_se=float(se[1]), theta_offset_deg_se=math.degrees(se[0]), length_scale_se=float(se[2]),
                      prototypes=len(est))
    return cal, birge
