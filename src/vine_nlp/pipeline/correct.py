"""Close the loop on a built robot (docs: "As-built correction"): an archive and measured points ->
the estimate of what was built and the nominal to build next; several prototypes -> a calibration.
The estimate and the correction are ``vine_nlp.methods.correct``; the archive layout ``vine_nlp.io.correction``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io.archive import Archive
from vine_nlp.io.calibration import Calibration
from vine_nlp.io.correction import MAX_MEASURED_POINTS, MIN_MEASURED_POINTS, read_correction, read_measured, write_correction_archive
from vine_nlp.io.problems import design_problem_of
from vine_nlp.methods.correct import ADJUST, Measurement, combine_systematic, correct
from vine_nlp.model.pairing import pair_points
from vine_nlp.model.routing import MEASURED_LINES, Sigmas

# problem units per millimetre, for the default measurement sigma of 1 mm
UNITS_PER_MM = {"mm": 1.0, "cm": 0.1, "m": 0.001, "in": 1 / 25.4, "inch": 1 / 25.4}
PLAUSIBLE_MEDIAN = 5.0  # median distance of the measured points to the estimated line, in noise sigmas, beyond which it is not this robot


def correct_files(archive_path, measured, *, run=None, lines=("outer",), adjust=("lambda",), free_pose=False, sigmas=None,
                  measurement_sigma=None):
    """Read an archive and measured CSV files, estimate and correct (no file written).

    Parameters
    ----------
    archive_path : path-like or Archive
        A design archive or the path of a correction archive (then its earlier measurements are used too).
    measured : list of path-like or (K, 3) arrays
        CSV files (or arrays) of points measured on the robot built from run ``run``.
    lines : tuple of str
        One line for all files, or one per file.

    Returns
    -------
    (CorrectionResult, base Archive, builds (list of Routing), settings dict)

    Raises
    ------
    InputError
        Bad archive, bad CSV, unknown run, mismatched lines.
    """
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
    if archive.kind != "design" or archive.target is None:
        raise InputError(archive_path, "/problem@kind", f"correct needs a design archive with a target (this is {archive.kind!r})")
    if run is None:
        run = "corrected" if state is not None and "corrected" in archive.runs else archive.default_run()
    if run is None or run not in archive.runs:
        raise InputError(archive_path, "--run", f"no run {run!r} (runs: {', '.join(archive.runs) or 'none'})")
    if run == "as_built":
        raise InputError(archive_path, "--run", "as_built is an estimate, not a nominal that was built")
    lines = tuple(lines)
    if len(lines) not in (1, len(measured)):
        raise InputError("command line", "--line", f"one line for all files or one per file ({len(measured)}), got {len(lines)}")
    for ln in lines:
        if ln not in MEASURED_LINES:
            raise InputError("command line", "--line", f"must be one of {', '.join(MEASURED_LINES)}, got {ln!r}")
    adjust = tuple(adjust)
    if adjust not in ADJUST:
        raise InputError("command line", "--adjust", "must be lambda or lambda,theta")
    pts = [_points(p, k) for k, p in enumerate(measured)]
    problem = design_problem_of(archive, archive_path)
    units_per_mm = UNITS_PER_MM.get(archive.units.lower())
    if measurement_sigma is None and units_per_mm is None:
        raise InputError("command line", "--sigma-measurement", f"archive units {archive.units!r}: give the measurement sigma in them")
    if measurement_sigma is not None and not measurement_sigma > 0:
        raise InputError("command line", "--sigma-measurement", f"must be > 0, got {measurement_sigma}")
    built = archive.runs[run].routing
    builds = (list(state.builds) if state else []) + [built]
    if any(b.segments != built.segments for b in builds):
        raise InputError(archive_path, f"/runs/{run}/design/theta", "the builds of one robot need the same segments")
    if built.segments != _segments(problem):
        raise InputError(archive_path, f"/runs/{run}/design/theta", f"{built.segments} segments, the problem's pairing has {_segments(problem)}")
    new = [Measurement(p, lines[0] if len(lines) == 1 else lines[k], len(builds) - 1, "free" if free_pose else "archive",
                       Path(f).name if isinstance(f, (str, Path)) else f"measured[{k}]")
           for k, (p, f) in enumerate(zip(pts, measured))]
    ms = (list(state.measurements) if state else []) + new
    sigmas = sigmas or Sigmas.from_degrees(1.0, 0.02, 0.02)
    result = correct(problem, builds, ms, adjust=adjust, sigmas=sigmas, measurement_sigma=measurement_sigma,
                     units_per_mm=units_per_mm or 0.1)
    _check_plausible(result, new, problem.diameter, archive.units)
    settings = {"built_run": run, "adjust": ",".join(adjust), "free_pose": bool(free_pose), "sigma_theta_rad": sigmas.theta,
                "sigma_lambda": sigmas.lam, "sigma_length": sigmas.length, "relative_length": bool(sigmas.relative_length),
                "sigma_measurement": result.estimate.stats["measurement_sigma"]}
    return result, archive, builds, settings


def _check_plausible(result, new, D, units):
    """A measurement that cannot be this robot (another shape, another frame, the wrong archive): the
    estimated robot passes far from most of its points, farther than noise explains. InputError naming it.

    Under Gaussian noise sigma per coordinate the median point-to-line distance is about 1.2 sigma; more
    than PLAUSIBLE_MEDIAN sigma (and a quarter of the diameter) is not noise."""
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


def _segments(problem):
    return pair_points(problem.target, problem.options.points_per_segment).segments


def correct_to_file(archive_path, measured, output, **kw):
    """``correct_files`` and write the correction archive to ``output`` (the API's file-level entry)."""
    result, archive, builds, settings = correct_files(archive_path, measured, **kw)
    write_correction_archive(output, archive, result, builds, settings)
    return result


def unreachable_text(result, problem) -> str:
    """Why the correction cannot reach the target ("" when it can): a solver that did not converge, or the
    values to build pinned at the builder's bounds (lambda in [lambda_min, 1], theta within theta_max when
    adjusted): the target needs values beyond them."""
    if not result.as_built.converged:
        return f"the estimate did not converge ({result.as_built.status})"
    if not result.corrected.converged:
        return f"the correction did not converge ({result.corrected.status})"
    a, r, eps = problem.actuator, result.corrected.routing, 1e-6
    changed = np.abs(r.lam - result.built.lam) > eps
    pinned = changed & ((r.lam <= a.lambda_min + eps) | (r.lam >= 1.0 - eps))
    if "theta" in result.adjust:
        pinned |= (np.abs(r.theta - result.built.theta) > eps) & (np.abs(r.theta) >= a.theta_max - eps)
    if pinned.any():
        seg = ", ".join(str(j) for j in np.flatnonzero(pinned)[:10]) + (" ..." if pinned.sum() > 10 else "")
        return (f"the target cannot be reached within the bounds: {int(pinned.sum())} segment(s) at a bound "
                f"(lambda in [{a.lambda_min:g}, 1]{', |theta| <= theta_max' if 'theta' in result.adjust else ''}; segments {seg})")
    return ""


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
