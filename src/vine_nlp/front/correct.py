"""``vine-nlp correct`` and ``vine-nlp calibrate``: close the loop on a built robot (spec/formats.md,
"As-built correction"). The estimate and the correction are ``vine_nlp.methods.correct``; the archive
layout is ``vine_nlp.io.correction``; this module reads files, reports and draws."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from vine_nlp.errors import InputError

# problem units per millimetre, for the default measurement sigma of 1 mm
UNITS_PER_MM = {"mm": 1.0, "cm": 0.1, "m": 0.001, "in": 1 / 25.4, "inch": 1 / 25.4}


def design_problem_of(archive, path):
    """The archive's design problem, parsed again from its stored source (the archived target kept)."""
    from vine_nlp.io.problem_file import parse_problem
    from vine_nlp.io.validate import parse_toml
    from vine_nlp.problem import DesignProblem

    try:
        pf = parse_problem(parse_toml(str(path), archive.source), str(path), archive.source)
        if pf.kind == "design":
            return replace(pf.problem, target=archive.target)
    except InputError:
        pass
    return DesignProblem(archive.name, archive.diameter, archive.target, units=archive.units)


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
    from vine_nlp.io.archive import Archive
    from vine_nlp.io.correction import MIN_MEASURED_POINTS, read_correction
    from vine_nlp.io.data_files import check_spread
    from vine_nlp.methods.correct import ADJUST, Measurement, correct
    from vine_nlp.model.routing import MEASURED_LINES, Sigmas

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
    for k, (p, f) in enumerate(zip(pts, measured)):
        check_spread(f if isinstance(f, (str, Path)) else f"measured[{k}]", p, archive.diameter, MIN_MEASURED_POINTS)
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
    from vine_nlp.io.correction import MAX_MEASURED_POINTS, MIN_MEASURED_POINTS, read_measured

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
    from vine_nlp.model.pairing import pair_points

    return pair_points(problem.target, problem.options.points_per_segment).segments


def correct_to_file(archive_path, measured, output, **kw):
    """``correct_files`` and write the correction archive to ``output`` (the API's file-level entry)."""
    from vine_nlp.io.correction import write_correction_archive

    result, archive, builds, settings = correct_files(archive_path, measured, **kw)
    write_correction_archive(output, archive, result, builds, settings)
    return result


def report(result, units: str) -> list[str]:
    """The lines ``vine-nlp correct`` prints."""
    e, ab, c = result.estimate, result.as_built, result.corrected
    s, sd = e.systematic, e.systematic_std
    M = e.routing.segments
    dl = result.corrected.routing.lam - result.built.lam
    out = [
        f"estimate    {e.status}, {e.rounds} pair-and-solve rounds, {e.iterations} iterations, {e.solve_time_s:.2f} s; "
        f"{sum(m.points.shape[0] for m in result.measurements)} points of {len({m.build for m in result.measurements})} build(s)",
        f"  fit       measured points to the estimated line: RMSE {ab.metrics['rmse']:.4g} {units}, max {ab.metrics['max_error']:.4g} {units}",
        f"  built     error to the target as built: RMSE {ab.metrics['target_rmse']:.4g} {units}, max {ab.metrics['target_max_error']:.4g} {units}",
        f"  systematic theta offset {math.degrees(s[0]):+.3f} +- {math.degrees(sd[0]):.3f} deg, lambda offset {s[1]:+.4f} +- {sd[1]:.4f}, "
        f"length scale {s[2]:.4f} +- {sd[2]:.4f}",
        f"  per segment (median std): theta {math.degrees(float(np.median(e.std[:, 0]))):.3f} deg, lambda {float(np.median(e.std[:, 1])):.4f}, "
        f"length {float(np.median(e.std[:, 2])):.4g} {units}",
        f"corrected   {c.status}, adjust {result.adjust and ','.join(result.adjust)}: predicted RMSE {c.metrics['rmse']:.4g} {units}, "
        f"max {c.metrics['max_error']:.4g} {units}; lambda changed in {int(np.sum(np.abs(dl) > 1e-6))} of {M} segments "
        f"(largest {float(np.max(np.abs(dl))) if M else 0:.4f})",
    ]
    return out


def correction_figure(result, problem, units: str = "cm"):
    """Target, measured points, estimated as-built line and predicted corrected shape; deviations per segment."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 5.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.plot(*problem.target.T, "k-", lw=1, label="target")
    ax.plot(*result.as_built.shape.center.T, "C1-", lw=1.2, label="as built (estimate)")
    ax.plot(*result.corrected.shape.center.T, "C2-", lw=1.2, label="corrected (predicted)")
    for k, m in enumerate(result.measurements):
        ax.scatter(*m.points.T, s=2, color="C0", label="measured" if k == 0 else None)
    ax.set_xlabel(f"x [{units}]")
    ax.set_ylabel(f"y [{units}]")
    ax.set_zlabel(f"z [{units}]")
    ax.legend(loc="upper left", fontsize=8)
    e = result.estimate
    j = np.arange(e.routing.segments)
    for row, (vals, sd, label) in enumerate((
        (np.degrees(e.deviations.theta), np.degrees(e.std[:, 0]), "theta deviation [deg]"),
        (e.deviations.lam, e.std[:, 1], "lambda deviation"),
        (100 * (e.deviations.length_ratio - 1), 100 * e.std[:, 2] / result.built.length, "length deviation [%]"),
    )):
        a = fig.add_subplot(3, 2, 2 * row + 2)
        a.errorbar(j, vals, yerr=sd, fmt="o", ms=2, lw=0.8)
        a.axhline(0, color="k", lw=0.5)
        a.set_ylabel(label, fontsize=8)
    a.set_xlabel("segment")
    fig.subplots_adjust(left=0.02, right=0.97, wspace=0.25, hspace=0.35)
    fig.suptitle(f"as built: RMSE to target {result.as_built.metrics['target_rmse']:.3g} {units}; "
                 f"corrected (predicted) {result.corrected.metrics['rmse']:.3g} {units}")
    return fig


def cmd_correct(args, check_output, check_figure) -> int:
    """The command: read, estimate, correct, write, report (``check_output``/``check_figure``: the CLI's checks)."""
    from vine_nlp.io.correction import write_correction_archive
    from vine_nlp.model.routing import Sigmas

    out = check_output(args.output, args.force)
    fig = check_figure(args.plot, args.force)
    if args.sigma_length_abs is not None:
        sig = Sigmas.from_degrees(args.sigma_theta_deg, args.sigma_lambda, args.sigma_length_abs, relative_length=False)
    else:
        sig = Sigmas.from_degrees(args.sigma_theta_deg, args.sigma_lambda, args.sigma_length, relative_length=True)
    if not (sig.theta > 0 and sig.lam > 0 and sig.length > 0):
        raise InputError("command line", "--sigma-*", "the construction-error sigmas must be > 0")
    lines = tuple(x.strip() for x in args.line.split(","))
    adjust = tuple(x.strip() for x in args.adjust.split(","))
    result, archive, builds, settings = correct_files(args.archive, args.measured, run=args.run, lines=lines, adjust=adjust,
                                                      free_pose=args.free_pose, sigmas=sig, measurement_sigma=args.sigma_measurement)
    write_correction_archive(out, archive, result, builds, settings)
    for line in report(result, archive.units):
        print(line)
    print(f"archive -> {out}")
    problem = design_problem_of(archive, args.archive)
    unreachable = unreachable_text(result, problem)
    if unreachable:
        print(f"correct: {unreachable}; the best correction found is written", file=sys.stderr)
    if fig:
        from vine_nlp.front.plot import save_figure

        save_figure(correction_figure(result, problem, archive.units), fig)
        print(f"figure -> {fig}")
    return 0 if result.corrected.converged and result.as_built.converged and not unreachable else 1


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


def add_correct_arguments(p, add_sigma_args) -> None:
    p.add_argument("archive", metavar="ARCHIVE.h5")
    p.add_argument("measured", nargs="+", metavar="MEASURED.csv", help="points measured on the built robot (rows x y z, any order)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.h5")
    p.add_argument("--run", help="the nominal that was built (default: corrected in a correction archive, else the design run)")
    p.add_argument("--line", default="outer", metavar="LINE[,LINE...]", help="measured line: center, inner or outer; one per file or one for all (default outer)")
    p.add_argument("--adjust", default="lambda", choices=("lambda", "lambda,theta"), metavar="lambda|lambda,theta", help="what the builder changes (default lambda: stopper or pinch lengths)")
    p.add_argument("--free-pose", action="store_true", help="the measurement is in an unknown frame: estimate its rigid pose")
    add_sigma_args(p)
    p.add_argument("--sigma-measurement", type=float, metavar="S", help="measurement noise, in units (default 1 mm)")
    p.add_argument("--plot", metavar="FIG.png", help="measured, estimated and corrected shapes; deviations per segment")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")


# ---------------------------------------------------------------- calibrate


def cmd_calibrate(args, check_output) -> int:
    """Systematic parts over several built prototypes -> a [calibration] table (TOML)."""
    from vine_nlp.io.calibration import Calibration, write_calibration
    from vine_nlp.io.correction import read_correction
    from vine_nlp.methods.correct import combine_systematic

    out = check_output(args.output, args.force)
    if out.suffix.lower() != ".toml":
        raise InputError(out, "-o", "the calibration is a TOML file (.toml)")
    est, sd = [], []
    for path in args.archives:
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
    write_calibration(out, cal)
    print(f"{len(est)} prototype(s): theta offset {cal.theta_offset_deg:+.3f} +- {cal.theta_offset_deg_se:.3f} deg, "
          f"lambda offset {cal.lambda_offset:+.4f} +- {cal.lambda_offset_se:.4f}, length scale {cal.length_scale:.4f} +- "
          f"{cal.length_scale_se:.4f}" + (f" (scatter {birge:.2f}x the standard errors)" if len(est) > 1 else ""))
    print(f"calibration -> {out}")
    return 0


def add_calibrate_arguments(p) -> None:
    p.add_argument("archives", nargs="+", metavar="ARCHIVE.h5", help="correction archives of prototypes of one construction method")
    p.add_argument("-o", "--output", required=True, metavar="CAL.toml")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
