"""``vine-nlp correct`` and ``vine-nlp calibrate``: arguments -> ``pipeline.correct`` -> printed lines,
the correction archive, its figure."""

from __future__ import annotations

import math
import sys

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.front.files import check_figure, check_output, several_actuators, sigmas
from vine_nlp.front.plot import equal_view_3d, label_3d_axes, save_figure
from vine_nlp.io.archived import archived_problem
from vine_nlp.io.calibration import write_calibration
from vine_nlp.io.correction import write_correction_archive
from vine_nlp.pipeline.correct import calibrate, correct_files, shortfall

ROUTES = {"lambda": "stoppers or pouches on this robot", "lambda,theta": "the line drawn anew on a new tube"}


def report(result, units: str) -> list[str]:
    """The lines ``vine-nlp correct`` prints."""
    e, ab, c = result.estimate, result.as_built, result.corrected
    M = e.routing.segments
    dl, dt = c.routing.lam - result.built.lam, np.degrees(c.routing.theta - result.built.theta)
    route = ",".join(result.adjust)
    out = [
        f"estimate    {e.status}, {e.rounds} pair-and-solve rounds, {e.iterations} iterations, {e.solve_time_s:.2f} s; "
        f"{sum(m.points.shape[0] for m in result.measurements)} points of {len({m.build for m in result.measurements})} build(s)",
        f"  fit       measured points to the estimated line: RMSE {ab.metrics['rmse']:.4g} {units}, max {ab.metrics['max_error']:.4g} {units}",
        f"  built     error to the target as built: RMSE {ab.metrics['target_rmse']:.4g} {units}, max {ab.metrics['target_max_error']:.4g} {units}",
        _systematic(e),
        f"  per segment (median std): theta {math.degrees(float(np.median(e.std[:, 0]))):.3f} deg, lambda {float(np.median(e.std[:, 1])):.4f}, "
        f"length {float(np.median(e.std[:, 2])):.4g} {units}",
        *_routes(result, units),
    ]
    held = e.deviations.held if e.deviations.held is not None else np.zeros(M, bool)
    out.append(f"{_corrected(result)}: lambda changed in "
               f"{int(np.sum(np.abs(dl) > 1e-6))} of {M} segments (largest {float(np.max(np.abs(dl), initial=0)):.4f}; "
               f"{int(held.sum())} held: built against 1, their error beyond it unknown)"
               + (f", theta in {int(np.sum(np.abs(dt) > 1e-6))} (largest {float(np.max(np.abs(dt), initial=0)):.2f} deg)" if "theta" in route else ""))
    return out


def _systematic(e) -> str:
    s, sd = e.systematic, e.systematic_std
    return (f"  systematic theta offset {math.degrees(s[0]):+.3f} +- {math.degrees(sd[0]):.3f} deg, lambda offset {s[1]:+.4f} +- {sd[1]:.4f}, "
            f"length scale {s[2]:.4f} +- {sd[2]:.4f}")


def _routes(result, units: str) -> list[str]:
    out = []
    for k, (name, r) in enumerate(result.routes.items()):
        free = r.metrics.get("rmse_without_bounds")
        out.append(f"{'' if k else 'routes':12}{name:13} {ROUTES[name]}: predicted RMSE {r.metrics['rmse']:.4g} {units}, max "
                   f"{r.metrics['max_error']:.4g} {units}" + (f" ({free:.4g} {units} without the bounds)" if free is not None else ""))
    return out


def report_several(result, units: str) -> list[str]:
    """The lines ``vine-nlp correct`` prints for a tube of several actuators: per actuator what the estimate found (or
    that no measurement saw it), per state the error as built and the predicted one."""
    e, ab, c, built = result.estimate, result.as_built, result.corrected, result.built
    states = {m.state for m in result.measurements}
    out = [f"estimate    {e.status}, {e.rounds} pair-and-solve rounds, {e.iterations} iterations, {e.solve_time_s:.2f} s; "
           f"{sum(m.points.shape[0] for m in result.measurements)} points of {len(states)} state(s) ({', '.join(sorted(states))}), "
           f"{len({m.build for m in result.measurements})} build(s)",
           f"  fit       measured points to the estimated lines: RMSE {ab.metrics['rmse']:.4g} {units}, max {ab.metrics['max_error']:.4g} {units}",
           _systematic(e)]
    for k, name in enumerate(built.names):
        if name not in e.stats["measured"]:
            out.append(f"  actuator {name}: not measured, kept nominal")
            continue
        act, d = built.lam[k] < 1, e.deviations[k]
        dl, dt = c.lines.lam[k] - built.lam[k], np.degrees(c.lines.theta[k] - built.theta[k])
        out.append(f"  actuator {name}: lambda deviation median {float(np.median(d.lam[act])) if act.any() else 0:+.4f} (std "
                   f"{float(np.median(e.std[name][act, 1])) if act.any() else 0:.4f}), theta {math.degrees(float(np.median(d.theta))):+.3f} deg; "
                   f"corrected lambda in {int(np.sum(np.abs(dl) > 1e-6))} of {int(act.sum())} actuated segments (largest "
                   f"{float(np.max(np.abs(dl), initial=0)):.4f})" + (f", theta in {int(np.sum(np.abs(dt) > 1e-6))}" if "theta" in result.adjust else ""))
    for st in c.state_metrics:
        out.append(f"  state {st}{'' if st in states else ' (not measured)'}: RMSE to the target as built {ab.state_metrics[st]['rmse']:.4g} {units}, "
                   f"corrected (predicted) {c.state_metrics[st]['rmse']:.4g} {units}")
    out += _routes(result, units)
    out.append(_corrected(result))
    return out


def _corrected(result) -> str:
    """The closing line's start, both reports': the route taken, why, the corrected design's status."""
    route, c = ",".join(result.adjust), result.corrected
    why = "recommended" if route == result.recommended else f"as asked; recommended {result.recommended}"
    return f"corrected   {route} ({why}), {c.status}{', short of the target' if c.shortfall else ''}"


def correction_figure(result, problem, units: str = "cm"):
    """Target, measured points, estimated as-built line and predicted corrected shape (equal axes: an out-of-plane
    error looks as large as it is), the problem's obstacles; deviations per segment."""
    from matplotlib.figure import Figure  # matplotlib loads when a figure is asked for
    fig = Figure(figsize=(12, 5.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    lines = [problem.target, result.as_built.shape.center, result.corrected.shape.center]
    for line, style, label in zip(lines, ("k-", "C1-", "C2-"), ("target", "as built (estimate)", "corrected (predicted)")):
        ax.plot(*line.T, style, lw=1.2, label=label)
    # the points sit on the line they were measured on (outer: D/2 off the center line), so that line is drawn too
    for name in dict.fromkeys(m.line for m in result.measurements):
        if name != "center":
            ax.plot(*getattr(result.as_built.shape, name).T, "C1:", lw=0.8, label=f"as built, {name} line")
        pts = [m.points for m in result.measurements if m.line == name]
        ax.scatter(*np.vstack(pts).T, s=2, color="C0", label=f"measured, {name} line")
        lines.extend(pts)
    label_3d_axes(ax, units)
    equal_view_3d(ax, lines, problem.obstacles)
    ax.legend(loc="upper left", fontsize=8)
    e = result.estimate
    j = np.arange(e.routing.segments)
    for row, (vals, sd, label) in enumerate((
        (np.degrees(e.deviations.theta), np.degrees(e.std[:, 0]), "theta deviation [deg]"),
        (e.deviations.lam, e.std[:, 1], "lambda deviation"),
        (100 * (e.deviations.length_ratio - 1), 100 * e.std[:, 2] / result.built.length, "length deviation [%]"),
    )):
        a = fig.add_subplot(3, 2, 2 * row + 2)
        a.errorbar(j, vals, yerr=sd, fmt="o", ms=2, lw=0.8), a.axhline(0, color="k", lw=0.5), a.set_ylabel(label, fontsize=8)
    a.set_xlabel("segment")
    fig.subplots_adjust(left=0.02, right=0.97, wspace=0.25, hspace=0.35)
    fig.suptitle(f"as built: RMSE to target {result.as_built.metrics['target_rmse']:.3g} {units}; "
                 f"corrected (predicted) {result.corrected.metrics['rmse']:.3g} {units}")
    return fig


def cmd_correct(args) -> int:
    """The command: read, estimate, correct, write, report."""
    out = check_output(args.output, args.force)
    fig = check_figure(args.plot, args.force)
    sig = sigmas(args)
    if not (sig.theta > 0 and sig.lam > 0 and sig.length > 0):
        raise InputError("command line", "--sigma-*", "the construction-error sigmas must be > 0")
    lines = tuple(x.strip() for x in args.line.split(","))
    adjust = tuple(x.strip() for x in args.adjust.split(",")) if args.adjust else None

    several = several_actuators(args.archive)
    if fig and several:
        raise InputError(args.plot, "--plot", "not for an archive of several actuators yet (`vine-nlp show OUT.h5` prints each state's error as built and corrected)")
    result, archive, builds, settings = correct_files(args.archive, args.measured, run=args.run, lines=lines, adjust=adjust,
                                                      free_pose=args.free_pose, sigmas=sig, measurement_sigma=args.sigma_measurement,
                                                      states=args.state)
    write_correction_archive(out, archive, result, builds, settings)
    for line in (report_several if several else report)(result, archive.units):
        print(line)
    print(f"archive -> {out}")
    short = shortfall(result)
    for k, line in enumerate(short):  # one line each, the first saying what is written
        print(f"correct: corrected ({','.join(result.adjust)}): {line}" + ("" if k else "; the best correction found is written"), file=sys.stderr)
    if fig:
        save_figure(correction_figure(result, archived_problem(archive, args.archive, settings["built_run"]), archive.units), fig)
        print(f"figure -> {fig}")
    return 1 if short else 0


def cmd_calibrate(args) -> int:
    """Systematic parts over several built prototypes -> a [calibration] table (TOML)."""
    out = check_output(args.output, args.force)
    if out.suffix.lower() != ".toml":
        raise InputError(out, "-o", "the calibration is a TOML file (.toml)")
    cal, birge = calibrate(args.archives)
    write_calibration(out, cal)
    print(f"{cal.prototypes} prototype(s): theta offset {cal.theta_offset_deg:+.3f} +- {cal.theta_offset_deg_se:.3f} deg, "
          f"lambda offset {cal.lambda_offset:+.4f} +- {cal.lambda_offset_se:.4f}, length scale {cal.length_scale:.4f} +- "
          f"{cal.length_scale_se:.4f}" + (f" (scatter {birge:.2f}x the standard errors)" if cal.prototypes > 1 else ""))
    print(f"calibration -> {out}")
    return 0
