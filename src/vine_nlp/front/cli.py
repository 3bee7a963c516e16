"""The ``vine-nlp`` command line (../shared/spec/formats.md, "Command line").

Exit status: 0 done; 1 the solver did not reach its tolerance (archive still
written); 2 bad input, reported as one line ``error: <file>: <key>: <reason>``.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

from vine_nlp import __version__
from vine_nlp.errors import InputError
from vine_nlp.io import outputs
from vine_nlp.methods import blas, compiled

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in the project's one-line form and exits 2."""

    def error(self, message):
        raise InputError("command line", self.prog, message)


def _at_least(least: int):
    """argparse type: an integer >= ``least`` (a usage error otherwise)."""

    def convert(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid integer: {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be >= {least}, got {value}")
        return value

    return convert


def _seconds(text):
    """argparse type: a finite number of seconds >= 0 (a usage error otherwise)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not (value >= 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def _check_output(path: str, force: bool, arg: str = "-o") -> Path:
    return outputs.reserve(path, force, arg)  # checked now, written when the command ends (io/outputs.py)


def _check_figure(path, force, key="--plot"):
    if not path:
        return None
    from vine_nlp.front.plot import figure_format

    out = _check_output(path, force, key)
    try:
        figure_format(out)
    except ValueError as e:
        raise InputError(path, key, str(e)) from None
    return out


def _read_archive(path, key="ARCHIVE"):
    """The archive at ``path``, validated; any problem is one InputError ``(path, dataset, reason)``
    (``key``: the command-line argument that named it, for a path that is no file at all)."""
    from vine_nlp.io.archive import load_archive

    if not Path(path).exists():
        raise InputError(path, key, "no such file")
    return load_archive(path)  # raises only ArchiveError, an InputError naming the dataset


def _archive_from(pf, runs, target=None):
    from vine_nlp.io.archive import Archive

    return Archive(
        name=pf.name, kind=pf.kind, source=pf.source, diameter=pf.problem.diameter, units=pf.units, target=target, runs=runs,
        obstacles=list(getattr(pf.problem, "obstacles", ())),
    )


def cmd_forward(args) -> int:
    from vine_nlp.io.archive import write_archive
    from vine_nlp.io.problem_file import load_problem
    from vine_nlp.methods.common import run_forward

    pf = load_problem(args.problem)
    if pf.kind != "forward":
        raise InputError(args.problem, "routing", f"a forward problem needs [routing] (this is a {pf.kind} problem)")
    out = _check_output(args.output, args.force)
    fig = _check_figure(args.plot, args.force)
    result = run_forward(pf.problem)
    write_archive(out, _archive_from(pf, {"forward": result}))
    r = pf.problem.routing
    print(
        f"{pf.name}: {r.segments} segments, tube length {r.length.sum():.4g} {pf.units}, "
        f"tip at ({', '.join(f'{v:.4g}' for v in result.shape.center[-1])}) {pf.units} -> {out}"
    )
    if fig:
        from vine_nlp.front.plot import plot_archive_file

        plot_archive_file(out, fig)
        print(f"figure -> {fig}")
    return EXIT_OK


def _load(path, kind):
    from vine_nlp.io.problem_file import load_problem

    pf = load_problem(path)
    if pf.kind != kind:
        key = {"design": "target", "forward": "routing", "fit": "measured"}[kind]
        raise InputError(path, key, f"a {kind} problem needs [{key}] (this is a {pf.kind} problem)")
    return pf


def _progress_bar(desc, unit):
    """A tqdm bar on stderr for long work; returns (callback(done, total), close()).
    Not a terminal (logs, pipes): no bar, and tqdm is not even imported."""
    if not sys.stderr.isatty():
        return (lambda done, total: None), (lambda: None)
    from tqdm import tqdm

    bar = None

    def update(done, total):
        nonlocal bar
        if total <= 1:
            return
        if bar is None:
            bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False, dynamic_ncols=True)
        bar.n = done
        bar.refresh()

    def close():
        if bar is not None:
            bar.close()

    return update, close


def _fmt_len(v, units):
    return f"{v:.4g} {units}"


def _report(name, r, units):
    m = r.metrics
    return (
        f"{name}: {r.status}, RMSE {_fmt_len(m['rmse'], units)}, max error {_fmt_len(m['max_error'], units)}, "
        f"solve time {r.solve_time_s:.3f} s, {r.iterations} iterations"
    )


def _run_method(pf, method, args):
    from vine_nlp.methods.methods import run_design

    kw = {}
    if method == "nlp":
        kw["workers"] = args.workers
        if args.starts is not None:
            kw["starts"] = args.starts
        if args.hops is not None:
            kw["hops"] = args.hops
        if args.budget is not None:
            kw["budget"] = args.budget
        kw["note"] = _note(pf.name)
        if getattr(args, "warm", None):
            kw["warm"] = _warm_routing(args.warm)
    update, close = _progress_bar(f"{pf.name} {method}", "solves" if method == "nlp" else "windows")
    try:
        return run_design(pf.problem, method, progress=update, **kw)
    finally:
        close()


def _note(name):
    """A line of progress on stderr that does not break a progress bar."""

    def note(line):
        from tqdm import tqdm

        tqdm.write(f"{name}: {line}", file=sys.stderr)

    return note


def _warm_routing(path):
    a = _read_archive(path, "--warm")
    if not a.runs:
        raise InputError(path, "--warm", "the archive has no design run")
    return a.runs[a.default_run()].routing


def cmd_design(args) -> int:
    from vine_nlp.io.archive import write_archive
    from vine_nlp.io.problem_file import load_problem

    pf = load_problem(args.problem)
    if pf.kind == "multishape":
        return _design_other(pf, args)
    if pf.kind == "tip":
        return _design_other(pf, args)
    if pf.kind != "design":
        raise InputError(args.problem, "target", f"a design problem needs [target] (this is a {pf.kind} problem)")
    out = _check_output(args.output, args.force)
    fig = _check_figure(args.plot, args.force)
    method = args.method or pf.problem.options.method
    if pf.problem.obstacles and method != "nlp":
        raise InputError(args.problem, "--method", "obstacles are designed by the nlp formulation only")
    result = _run_method(pf, method, args)
    runs = {method: result}
    if pf.problem.obstacles:
        from vine_nlp.methods.obstacles import FREE_RUN, design_with_obstacles

        # run "nlp" is the design among the obstacles; the obstacle-free design it started from is kept beside it
        runs = {method: design_with_obstacles(pf.problem, start=result), FREE_RUN: result}
        result = runs[method]
    if args.robust:
        from vine_nlp.methods.robust import design_robust

        runs["nlp_robust"] = design_robust(pf.problem, _sigmas(args), start=result, weight=args.robust_weight)
    if args.clearance:
        from vine_nlp.methods.clearance import design_with_clearance

        runs["nlp_clearance"] = design_with_clearance(pf.problem, min_gap=args.min_gap, start=result)
    _obstacle_metrics(pf.problem, runs)
    write_archive(out, _archive_from(pf, runs, target=pf.problem.target))
    for name, r in runs.items():
        print(_report(name, r, pf.units))
        if "min_obstacle_gap" in r.metrics:
            print(f"  min obstacle gap {_fmt_len(r.metrics['min_obstacle_gap'], pf.units)} (margin {pf.problem.obstacle_margin:g})"
                  + (f", {_fmt_len(r.metrics['min_obstacle_gap_after'], pf.units)} actuated after growth"
                     if "min_obstacle_gap_after" in r.metrics else ""))
    result = runs[list(runs)[-1]]
    print(f"archive -> {out}")
    if fig:
        from vine_nlp.front.plot import plot_archive_file

        plot_archive_file(out, fig)
        print(f"figure -> {fig}")
    return EXIT_OK if result.converged else EXIT_NOT_CONVERGED


def _obstacle_metrics(problem, runs):
    """min_obstacle_gap (and min_obstacle_gap_after) on every run of a problem with obstacles."""
    if getattr(problem, "obstacles", ()):
        from vine_nlp.analysis.obstacles import obstacle_metrics

        for r in runs.values():
            r.metrics.update(obstacle_metrics(r.routing, problem.diameter, problem.obstacles, problem.growth, problem.obstacle_margin))


def _only_nlp(pf, args):
    if args.method not in (None, "nlp"):
        raise InputError(args.problem, "--method", f"{pf.kind} problems are solved by the nlp formulation only")
    if getattr(args, "warm", None):
        raise InputError(args.problem, "--warm", f"not available for {pf.kind} problems")
    if getattr(args, "hops", None):
        raise InputError(args.problem, "--hops", f"not available for {pf.kind} problems")
    if getattr(args, "budget", None) is not None:
        raise InputError(args.problem, "--budget", f"not available for {pf.kind} problems")


def _design_other(pf, args) -> int:
    """Problems beyond the paper's (multi-shape, tip): their formulation's solve, archive writer, report and
    figure, from the registry (front.registry)."""
    from vine_nlp.front.registry import for_problem

    f = for_problem(pf.problem)
    _only_nlp(pf, args)
    out = _check_output(args.output, args.force)
    fig = _check_figure(args.plot, args.force)
    update, close = _progress_bar(f"{pf.name} {pf.kind}", "starts")
    try:
        result, _ = f.solve(pf.problem, starts=args.starts, progress=update)
    finally:
        close()
    f.write_archive(out, pf, {f.run: result})
    for line in f.report(f.run, result, pf.problem, pf.units):
        print(line)
    print(f"archive -> {out}")
    if fig:
        from vine_nlp.front.plot import save_figure  # matplotlib only when a figure is asked for

        save_figure(f.figure(out), fig)
        print(f"figure -> {fig}")
    return EXIT_OK if result.converged else EXIT_NOT_CONVERGED


def cmd_compare(args) -> int:
    from vine_nlp.io.archive import write_archive
    from vine_nlp.methods.greedy import lowpass

    pf = _load(args.problem, "design")
    out = _check_output(args.output, args.force)
    fig = _check_figure(args.plot, args.force)
    runs = {}
    for method in ("nlp", "greedy"):
        runs[method] = _run_method(pf, method, args)
    runs["greedy_filtered"] = lowpass(runs["greedy"], pf.problem)
    write_archive(out, _archive_from(pf, runs, target=pf.problem.target))
    print(comparison_table(runs, pf.units))
    print(f"archive -> {out}")
    if fig:
        from vine_nlp.front.plot import plot_archive_file

        plot_archive_file(out, fig)
        print(f"figure -> {fig}")
    return EXIT_OK if all(r.converged for r in runs.values()) else EXIT_NOT_CONVERGED


def _design_problem_of(archive, path):
    """The design problem of an archive: parsed again from its stored source; the archived
    target stands in for target files that are not where the source says."""
    import dataclasses

    from vine_nlp.io.problem_file import parse_problem
    from vine_nlp.io.validate import parse_toml  # the checks of a problem file's text (no tracebacks from it)
    from vine_nlp.problem import DesignProblem

    try:
        pf = parse_problem(parse_toml(str(path), archive.source), str(path), archive.source)
        if pf.kind == "design":
            return dataclasses.replace(pf.problem, target=archive.target)
    except InputError:
        pass
    return DesignProblem(archive.name, archive.diameter, archive.target, units=archive.units)


def _sigmas(args):
    from vine_nlp.analysis.tolerance import Sigmas

    if args.sigma_length_abs is not None:
        return Sigmas.from_degrees(args.sigma_theta_deg, args.sigma_lambda, args.sigma_length_abs, relative_length=False)
    return Sigmas.from_degrees(args.sigma_theta_deg, args.sigma_lambda, args.sigma_length, relative_length=True)


def cmd_analyze(args) -> int:
    """Self-collision, growth order and manufacturing tolerance of an archived design."""
    from vine_nlp.analysis.collision import (
        collision_metrics,
        growth_contacts,
        helix_collisions,
        routing_clearance,
    )
    from vine_nlp.analysis.tolerance import tolerance_metrics, tolerance_report

    archive = _read_archive(args.archive)
    run = args.run or archive.default_run()
    if run not in archive.runs:
        raise InputError(args.archive, "--run", f"no run {run!r} (runs: {', '.join(archive.runs)})")
    for flag in ("tolerance_figure", "clearance_figure"):
        _check_figure(getattr(args, flag), True)
    r = archive.runs[run]
    D, u = archive.diameter, archive.units
    cl = routing_clearance(r.routing, D, margin=args.margin)
    where = f" at {cl['l_i']:.4g} / {cl['l_j']:.4g} {u} of tube" if "l_i" in cl and cl.get("clearance", float("inf")) < float("inf") else ""
    print(f"clearance   min {cl['clearance']:.4g} {u} ({cl['clearance'] / D:.2f} D){where}; {len(cl['regions'])} contact region(s)")
    growth = growth_contacts(r.routing, D, margin=args.margin)
    final = [g for g in growth if not g.get("transient")]
    on_way = [g for g in growth if g.get("transient")]
    print(f"growth      grown while actuated: {len(final)} contact(s)"
          + "".join(f"; first at {g['growth_length']:.4g} {u} grown" for g in final[:1])
          + f"; actuated after growth: {len(final) + len(on_way)} contact(s) on the way"
          + ("" if not growth else f" (from t = {min(g['actuation_fraction'] for g in growth):.2f})"))
    print(f"helices     uniform sections of >= 1 turn self-colliding (paper condition): {len(helix_collisions(r.routing, D))}")
    metrics = collision_metrics(r, D, margin=args.margin)
    if archive.obstacles:
        metrics |= _analyze_obstacles(archive, r, u)
    figures = []
    if archive.kind == "design" and archive.target is not None:
        problem = _design_problem_of(archive, args.archive)
        sig = _sigmas(args)
        rep = tolerance_report(problem, r, sig, samples=args.samples, seed=args.seed)
        fo, mc, nom = rep["first_order"], rep["monte_carlo"], rep["nominal"]
        length = f"{100 * args.sigma_length:g} %" if args.sigma_length_abs is None else f"{args.sigma_length_abs:g} {u}"
        print(f"tolerance   sigma theta {args.sigma_theta_deg:g} deg, lambda {args.sigma_lambda:g}, length {length} (per segment, independent)")
        print(f"  rmse      nominal {nom['rmse']:.4g} {u}; first order {fo['rmse']:.4g} {u}; Monte Carlo mean {mc['mean_rmse']:.4g} / rms {mc['rms_rmse']:.4g} {u} ({mc['samples']} samples, seed {mc['seed']})")
        print(f"  tip       std {fo['tip_std']:.4g} {u} (first order) / {mc['tip_std']:.4g} {u} (Monte Carlo)")
        ps = rep["per_segment"]
        share = ps["tip_var"] / max(float(ps["tip_var"].sum()), 1e-300)
        j = int(share.argmax())
        print(f"  worst     segment {j} at {ps['l_mid'][j]:.4g} {u} of tube: {100 * share[j]:.0f} % of the tip variance")
        metrics |= tolerance_metrics(rep)
        if args.tolerance_figure:
            from vine_nlp.front.analysis_plots import tolerance_figure

            tolerance_figure(rep, args.tolerance_figure, title=f"{archive.name}: {run}")
            figures.append(args.tolerance_figure)
    if args.clearance_figure:
        from vine_nlp.front.analysis_plots import clearance_figure

        clearance_figure(r.routing, D, args.clearance_figure, units=u, growth=growth, title=f"{archive.name}: {run}")
        figures.append(args.clearance_figure)
    for f in figures:
        print(f"figure -> {f}")
    if args.write_metrics:
        from vine_nlp.io.archive import write_archive

        # archived metrics are finite (archives are validated on read): one that does not apply is left
        # out (first_contact_growth_length of a tube that never touches itself)
        r.metrics.update({k: float(v) for k, v in metrics.items() if math.isfinite(float(v))})
        write_archive(args.archive, archive)
        print(f"metrics -> {args.archive} (/runs/{run}/metrics)")
    return EXIT_OK


def _analyze_obstacles(archive, r, u) -> dict:
    """Print the distance to every obstacle along the tube and the contacts, final and intermediate shapes
    (margin and growth from the archived problem's [design]); the run metrics."""
    from vine_nlp.analysis.obstacles import obstacle_report, report_rows
    from vine_nlp.io.obstacles import DEFAULT_GROWTH, parse_obstacle_design
    from vine_nlp.io.validate import parse_toml

    try:
        design = parse_toml("archive", archive.source).get("design", {})
        margin, growth = parse_obstacle_design(design if isinstance(design, dict) else {}, "archive")
    except InputError:
        margin, growth = 0.0, DEFAULT_GROWTH
    rep = obstacle_report(r.routing, archive.diameter, archive.obstacles, growth, margin)
    print(f"obstacles   {len(archive.obstacles)}; margin {margin:.4g} {u}; growth {growth}; "
          f"min gap {rep['min_gap']:.4g} {u} (final), {rep['min_gap_intermediate']:.4g} {u} (intermediate shapes); "
          + ("clear" if rep["clear"] else "NOT clear"))
    for row in report_rows(rep):
        name = f" '{row['name']}'" if row["name"] else ""
        line = (f"  obstacle {row['index']} {row['kind']}{name}: min gap {row['min_gap']:.4g} {u} at s = {row['s']:.4g} {u}; "
                f"{row['contacts']} contact(s)")
        if growth == "after":
            line += f"; actuated after growth: min gap {row['min_gap_after']:.4g} {u} at t = {row['t_worst']:.2f}"
        elif row["first_contact_length"] is not None:
            line += f"; first contact at {row['first_contact_length']:.4g} {u} grown"
        print(line)
    out = {"min_obstacle_gap": float(rep["min_gap"])}
    if growth == "after":
        out["min_obstacle_gap_after"] = float(rep["min_gap_intermediate"])
    return out


def _add_sigma_args(p):
    p.add_argument("--sigma-theta-deg", type=float, default=1.0, metavar="DEG", help="construction error of theta (default 1)")
    p.add_argument("--sigma-lambda", type=float, default=0.02, metavar="S", help="construction error of lambda (default 0.02)")
    p.add_argument("--sigma-length", type=float, default=0.02, metavar="F", help="relative error of segment lengths (default 0.02)")
    p.add_argument("--sigma-length-abs", type=float, metavar="L", help="absolute error of segment lengths instead, in units")


def cmd_sweep(args) -> int:
    from vine_nlp.front.sweep import format_report, run_sweep
    from vine_nlp.io.problem_file import load_sweep

    sweep = load_sweep(args.sweep)  # every item is validated before any work starts
    try:
        report = run_sweep(sweep, args.output, workers=args.workers, scheduler=args.scheduler, force=args.force)
    except KeyboardInterrupt as e:
        partial = getattr(e, "sweep_report", None)
        if partial is not None:
            print(format_report(partial))
            print("interrupted: every finished item is archived; run the same command again to resume", file=sys.stderr)
            return 130
        raise
    print(format_report(report))
    return EXIT_OK if not (report.failed or report.not_converged) else EXIT_NOT_CONVERGED


def cmd_fit(args) -> int:
    from vine_nlp.io.archive import write_archive
    from vine_nlp.methods.fit import describe_fit, fit_problem

    pf = _load(args.problem, "fit")
    out = _check_output(args.output, args.force)
    fig = _check_figure(args.plot, args.force)
    frames_fig = _check_figure(args.frames_plot, args.force) if args.frames else None
    if args.frames:
        from vine_nlp.io.problem_file import read_points

        measured_frames = [read_points(f) for f in args.frames]  # bad data files fail before any work
    try:
        result, extras = fit_problem(pf.problem, starts=args.starts, seed=args.seed)
    except ValueError as e:  # too few usable points after the parser's checks
        raise InputError(args.problem, "measured.file", str(e)) from None
    archive = _archive_from(pf, {"fit": result})
    archive.extra.update(extras)
    frames = _fit_frames(pf, args, measured_frames) if args.frames else None
    if frames is not None:
        archive.extra.update({f"frames/{k}": v for k, v in frames.items() if k != "fits"})
    write_archive(out, archive)
    print(f"{pf.name}: {describe_fit(result, pf.units)} -> {out}")
    if frames is not None:
        for k, (name, lam, rmse) in enumerate(zip(args.frames, frames["lambda"], frames["rmse"])):
            print(f"  frame {k} {name}: lambda {lam:.4f}, RMSE {rmse:.4g} {pf.units}")
    if fig:
        from vine_nlp.front.fit_plots import plot_fit

        plot_fit(out, fig)
        print(f"figure -> {fig}")
    if frames_fig:
        from vine_nlp.front.fit_plots import plot_frames

        plot_frames(frames["fits"], frames_fig, units=pf.units, title=f"{pf.name}: lambda over frames")
        print(f"frames figure -> {frames_fig}")
    return EXIT_OK if result.converged else EXIT_NOT_CONVERGED


def _fit_frames(pf, args, measured) -> dict:
    """Batch of frames of one actuator (paper Fig. 9(d)): lambda and RMSE per frame."""
    import numpy as np

    from vine_nlp.methods.fit import fit_frames

    update, close = _progress_bar(f"{pf.name} frames", "frames")
    try:
        fits = fit_frames(pf.problem, measured, starts=args.starts, seed=args.seed)
        update(len(fits), len(fits))
    finally:
        close()
    return {
        "fits": fits,
        "lambda": np.array([f.lam for f in fits]),
        "rmse": np.array([f.rmse for f in fits]),
        "r2": np.array([getattr(f, "r2", np.nan) for f in fits]),
    }


def cmd_plot(args) -> int:
    archive = _read_archive(args.archive)
    out = _check_figure(args.output, args.force, "-o")
    if archive.kind == "fit":
        from vine_nlp.front.fit_plots import plot_fit

        plot_fit(archive, out)
    elif archive.kind == "multishape":
        from vine_nlp.front.multishape_plot import plot_multishape_file

        plot_multishape_file(args.archive, out)  # reads the per-level groups itself
    else:
        from vine_nlp.front.plot import plot_archive, save_figure

        save_figure(plot_archive(archive, obstacles=archive.obstacles), out)
    print(f"figure -> {out}")
    return EXIT_OK


def cmd_template(args) -> int:
    from vine_nlp.front.template import write_template

    out = _check_output(args.output, args.force)
    fmt = _output_format(out, "template", "template_format")
    if fmt == ".dxf":
        _need_extra("template", "ezdxf")
    archive = _read_archive(args.archive)
    csv = _check_output(args.csv, args.force, "--csv") if args.csv else None
    rows = None
    if getattr(args, "changes", False):
        from vine_nlp.front.changes import change_rows, changes_text

        try:
            rows = change_rows(archive, args.run or "corrected")
        except (ValueError, KeyError) as e:
            raise InputError(args.archive, "--changes", str(e).strip("'")) from None
        print(changes_text(rows, archive.units))
    try:
        info = write_template(archive, out, csv_path=csv, paper=args.paper, run=args.run or ("corrected" if rows is not None else None),
                              changes=rows)
    except ValueError as e:
        raise InputError(args.archive, "--run" if args.run and args.run in str(e) else "template", str(e)) from None
    if fmt == ".pdf":
        print(
            f"{info['pages']} page(s), {info['strips']} strip(s), {info['paper']} {info['orientation']}, run {info['run']}, "
            f"{info['segments']} segments, tube {info['tube_length']:.4g} {archive.units} -> {out}"
        )
    else:  # SVG, DXF: one sheet, strips cut as for the paper
        w, h = info["paper_mm"]
        print(
            f"one {w:.0f} x {h:.0f} mm sheet ({fmt[1:].upper()}, millimetres), {info['strips']} strip(s) cut for {info['paper']}, "
            f"run {info['run']}, {info['segments']} segments, tube {info['tube_length']:.4g} {archive.units} -> {out}"
        )
    if csv:
        print(f"cuts -> {csv}")
    print("print at 100 % (no 'fit to page') and check the 10 cm scale bar" if fmt == ".pdf"
          else "the 10 cm scale bar is 100 mm in the file: check it after import")
    return EXIT_OK


def _front(name):
    """The module vine_nlp.front.<name> by dotted name, imported when a command first needs it
    (as the registry does: the command line starts fast)."""
    import importlib

    return importlib.import_module(f"vine_nlp.front.{name}")


def _output_format(out, module, function):
    """The format of an output file by its extension (``vine_nlp.front.<module>.<function>(path)``);
    a bad one is bad input."""
    try:
        return getattr(_front(module), function)(out)
    except ValueError as e:
        raise InputError(out, "-o", str(e)) from None


def _need_extra(command, *modules):
    """The optional packages a command needs (the ``view`` extra): a one-line error when one is missing."""
    import importlib.util

    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise InputError("command line", command, f"needs {', '.join(missing)}: python3 -m pip install 'vine_nlp[view]'")


def _archive_run(archive, path, run):
    """``run`` (default: the archive's default run), which must be in the archive."""
    if run is None:
        run = archive.default_run()
        if run is None:
            raise InputError(path, "runs", "the archive has no runs")
    if run not in archive.runs:
        raise InputError(path, "--run", f"no run {run!r} (runs: {', '.join(archive.runs) or 'none'})")
    return run


def cmd_view(args) -> int:
    """One self-contained HTML view of an archive or of a sweep directory."""
    view = _front("view")
    _need_extra("view", "plotly")
    out = _check_output(args.output, args.force)
    if out.suffix.lower() not in (".html", ".htm"):
        raise InputError(out, "-o", f"unknown view format {out.suffix or '(none)'!r}: use .html")
    src = Path(args.source)
    if src.is_dir():
        if args.run:
            raise InputError(src, "--run", "a sweep view shows every run")
        if not view.is_sweep_dir(src):
            raise InputError(src, "SWEEPDIR", "no summary.csv: not a sweep directory")
        try:
            html = view.sweep_html(src)
        except (ValueError, OSError, KeyError) as e:
            raise InputError(src, "SWEEPDIR", str(e)) from None
        what = "sweep"
    else:
        archive = _read_archive(src)
        if args.run is not None:
            _archive_run(archive, src, args.run)
        elif not archive.runs:
            raise InputError(src, "runs", "the archive has no runs")
        html = view.view_html(archive, run=args.run)
        what = ", ".join([args.run] if args.run else archive.runs)
    view.write_html(out, html)
    print(f"view of {what} ({len(html) / 1e6:.2f} MB, opens offline) -> {out}")
    return EXIT_OK


def cmd_animate(args) -> int:
    """The knot figure as a movie: growth while actuated beside actuation after growth."""
    animate = _front("animate")
    out = _check_output(args.output, args.force)
    fmt = _output_format(out, "animate", "movie_format")
    if fmt == ".gif":
        _need_extra("animate", "PIL")
    if fmt == ".mp4" and not animate.ffmpeg_available():
        raise InputError(out, "-o", "MP4 needs ffmpeg, which is not installed (apt-get install ffmpeg); write a .gif instead")
    archive = _read_archive(args.archive)
    run = _archive_run(archive, args.archive, args.run)
    info = animate.write_movie(archive, out, mode=args.mode, run=run, frames=args.frames, fps=args.fps)
    print(f"{info['frames']} frames ({info['mode']}), run {run}, self-contacts: {info['contacts_grow']} of the final shape, "
          f"up to {info['contacts_after']} at once when actuated after growth -> {out}")
    return EXIT_OK


def cmd_export(args) -> int:
    """The tube as a closed triangle mesh (STL, OBJ, PLY, glTF binary)."""
    export = _front("export")
    out = _check_output(args.output, args.force)
    _need_extra("export", "trimesh")
    fmt = _output_format(out, "export", "mesh_format")
    if fmt in (".stl", ".ply"):
        _check_output(out.with_name(f"{out.stem}.actuator{out.suffix}"), args.force)
    archive = _read_archive(args.archive)
    run = _archive_run(archive, args.archive, args.run)
    try:
        info = export.write_mesh(archive, out, run=run)
    except ValueError as e:
        raise InputError(args.archive, "units" if "units" in str(e) else "--run", str(e)) from None
    closed = "closed" if info["watertight"] else "NOT closed"
    print(f"run {run}: {info['faces']} faces, {closed}, volume {info['volume']:.4g} {archive.units}^3, "
          f"coordinates in {info['units']} -> {', '.join(str(f) for f in info['files'])}")
    return EXIT_OK


def cmd_show(args) -> int:
    from vine_nlp.front.show import summarize

    print(summarize(_read_archive(args.archive)))
    return EXIT_OK


def comparison_table(runs, units) -> str:
    head = f"{'run':<16}{'status':<12}{'RMSE [' + units + ']':>14}{'max [' + units + ']':>14}{'time [s]':>10}{'iter/solves':>13}{'TV theta':>10}{'TV lambda':>11}"
    lines = [head, "-" * len(head)]
    for name, r in runs.items():
        m = r.metrics
        count = r.stats.get("window_solves", r.iterations)
        lines.append(
            f"{name:<16}{r.status:<12}{m['rmse']:>14.5g}{m['max_error']:>14.5g}{r.solve_time_s:>10.3f}{count:>13}"
            f"{m['tv_theta']:>10.4g}{m['tv_lambda']:>11.4g}"
        )
    if "nlp" in runs and "greedy" in runs and runs["nlp"].solve_time_s > 0:
        lines.append(f"nlp is {runs['greedy'].solve_time_s / runs['nlp'].solve_time_s:.1f}x faster than greedy")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="vine-nlp",
        description="Design actuator routings for vine robots (Blumenschein et al., IEEE T-RO 2021).",
    )
    p.add_argument("--version", action="version", version=f"vine-nlp {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    f = sub.add_parser("forward", help="shape of a given routing -> result archive")
    f.add_argument("problem", metavar="PROBLEM.toml")
    f.add_argument("-o", "--output", required=True, metavar="OUT.h5")
    f.add_argument("--plot", metavar="FIG.png", help="also draw the shape (png or pdf)")
    f.add_argument("--force", action="store_true", help="overwrite existing output files")
    f.set_defaults(func=cmd_forward)

    for name, func, text in (
        ("design", cmd_design, "inverse design of a routing for a target curve -> result archive"),
        ("compare", cmd_compare, "run nlp and greedy on one problem: one archive, a table on stdout"),
    ):
        d = sub.add_parser(name, help=text)
        d.add_argument("problem", metavar="PROBLEM.toml")
        d.add_argument("-o", "--output", required=True, metavar="OUT.h5")
        if name == "design":
            d.add_argument("--method", choices=("nlp", "greedy"), help="default: the problem's [design] method (nlp)")
            d.add_argument("--warm", metavar="ARCHIVE.h5", help="nlp: start from the design in an earlier archive")
            d.add_argument("--robust", action="store_true", help="also a design minimizing the expected error under construction errors (run nlp_robust)")
            d.add_argument("--robust-weight", type=float, default=1.0, metavar="W", help="weight of the expected error increase")
            _add_sigma_args(d)
            d.add_argument("--clearance", action="store_true", help="also a design keeping the tube clear of itself (run nlp_clearance)")
            d.add_argument("--min-gap", type=float, default=0.0, metavar="G", help="clearance beyond D, in units")
        d.add_argument("--starts", type=_at_least(1), metavar="N", help="nlp: number of starts of the multi-start (default: the problem's)")
        d.add_argument("--hops", type=_at_least(0), metavar="N", help="nlp: rounds of basin hopping after the starts, for targets with corners (default: the problem's)")
        d.add_argument("--budget", type=_seconds, metavar="S", help="nlp: seconds for the corner search where the first solve shows a corner-like target (default: the problem's [design] budget, 20; 0: off)")
        d.add_argument("--workers", type=_at_least(1), default=1, metavar="N", help="nlp: run the starts in N processes")
        d.add_argument("--plot", metavar="FIG.png", help="also draw the result (png or pdf)")
        d.add_argument("--force", action="store_true", help="overwrite existing output files")
        d.set_defaults(func=func)

    an = sub.add_parser("analyze", help="self-collision, growth order and manufacturing tolerance of a design")
    an.add_argument("archive", metavar="OUT.h5")
    an.add_argument("--run", help="which run (default: nlp, greedy, forward, ...)")
    _add_sigma_args(an)
    an.add_argument("--samples", type=int, default=2000, help="Monte Carlo samples (default 2000)")
    an.add_argument("--seed", type=int, default=0)
    an.add_argument("--margin", type=float, default=0.0, metavar="G", help="count approaches closer than D + G as contacts")
    an.add_argument("--tolerance-figure", metavar="FIG.png", help="where along the tube errors matter most")
    an.add_argument("--clearance-figure", metavar="FIG.png", help="clearance along the tube")
    an.add_argument("--write-metrics", action="store_true", help="store the figures as metrics of the run in the archive")
    an.set_defaults(func=cmd_analyze)

    sw = sub.add_parser("sweep", help="many design problems: one archive per item, summary.csv and a summary figure")
    sw.add_argument("sweep", metavar="SWEEP.toml")
    sw.add_argument("-o", "--output", required=True, metavar="DIR")
    sw.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: all cores)")
    sw.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask distributed cluster (e.g. tcp://host:8786)")
    sw.add_argument("--force", action="store_true", help="redo items whose archives exist")
    sw.set_defaults(func=cmd_sweep)

    ft = sub.add_parser("fit", help="fit the model of a known routing to measured points (pose, optionally lambda)")
    ft.add_argument("problem", metavar="PROBLEM.toml")
    ft.add_argument("-o", "--output", required=True, metavar="OUT.h5")
    ft.add_argument("--starts", type=int, default=24, metavar="N", help="starting orientations of the global pose search")
    ft.add_argument("--seed", type=int, default=0)
    ft.add_argument("--plot", metavar="FIG.png", help="measured points against the fitted model, error against length")
    ft.add_argument("--frames", nargs="+", metavar="FRAME.csv", help="also fit these frames of the same actuator in order")
    ft.add_argument("--frames-plot", metavar="FIG.png", help="with --frames: lambda over frames and error against length")
    ft.add_argument("--force", action="store_true", help="overwrite existing output files")
    ft.set_defaults(func=cmd_fit)

    pl = sub.add_parser("plot", help="figures of an archive (png or pdf)")
    pl.add_argument("archive", metavar="OUT.h5")
    pl.add_argument("-o", "--output", required=True, metavar="FIG.png")
    pl.add_argument("--force", action="store_true", help="overwrite an existing figure")
    pl.set_defaults(func=cmd_plot)

    t = sub.add_parser("template", help="1:1 fabrication template (PDF, or SVG/DXF in mm) and cut list (CSV) of a design")
    t.add_argument("archive", metavar="OUT.h5")
    t.add_argument("-o", "--output", required=True, metavar="TEMPLATE.pdf|.svg|.dxf")
    t.add_argument("--csv", metavar="CUTS.csv", help="also write one row per segment")
    t.add_argument("--paper", choices=("A4", "Letter"), default="A4")
    t.add_argument("--run", help="which run of the archive (default: nlp, greedy or forward)")
    t.add_argument("--changes", action="store_true", help="correction archives: also list, and frame on the template, the segments whose stoppers change against the robot built last")
    t.add_argument("--force", action="store_true", help="overwrite existing output files")
    t.set_defaults(func=cmd_template)

    vw = sub.add_parser("view", help="interactive 3-D view (one HTML file, offline) of an archive or a sweep directory")
    vw.add_argument("source", metavar="ARCHIVE.h5|SWEEPDIR")
    vw.add_argument("-o", "--output", required=True, metavar="VIEW.html")
    vw.add_argument("--run", help="show only this run (default: every run, toggled in the legend)")
    vw.add_argument("--force", action="store_true", help="overwrite an existing file")
    vw.set_defaults(func=cmd_view)

    am = sub.add_parser("animate", help="movie: growth while actuated beside actuation after growth (GIF or MP4)")
    am.add_argument("archive", metavar="ARCHIVE.h5")
    am.add_argument("-o", "--output", required=True, metavar="MOVIE.gif|MOVIE.mp4")
    am.add_argument("--mode", choices=("grow", "after", "both"), default="both")
    am.add_argument("--run", help="which run (default: nlp, greedy, forward, ...)")
    am.add_argument("--frames", type=_at_least(2), default=40, metavar="N", help="frames (default 40)")
    am.add_argument("--fps", type=_at_least(1), default=10, metavar="N", help="frames per second (default 10)")
    am.add_argument("--force", action="store_true", help="overwrite an existing file")
    am.set_defaults(func=cmd_animate)

    ex = sub.add_parser("export", help="the tube as a closed triangle mesh (STL, OBJ, PLY, glTF .glb)")
    ex.add_argument("archive", metavar="ARCHIVE.h5")
    ex.add_argument("-o", "--output", required=True, metavar="TUBE.stl|.obj|.ply|.glb")
    ex.add_argument("--run", help="which run (default: nlp, greedy, forward, ...)")
    ex.add_argument("--force", action="store_true", help="overwrite existing files")
    ex.set_defaults(func=cmd_export)

    co = sub.add_parser("correct", help="estimate a built robot from measured points and correct it -> correction archive")
    from vine_nlp.front import correct as correct_cmd  # argument tables and commands; the solvers load when run

    correct_cmd.add_correct_arguments(co, _add_sigma_args)
    co.set_defaults(func=lambda a: correct_cmd.cmd_correct(a, _check_output, _check_figure))
    cb = sub.add_parser("calibrate", help="systematic construction errors over several correction archives -> CAL.toml")
    correct_cmd.add_calibrate_arguments(cb)
    cb.set_defaults(func=lambda a: correct_cmd.cmd_calibrate(a, _check_output))

    sh = sub.add_parser("show", help="readable summary of an archive")
    sh.add_argument("archive", metavar="OUT.h5")
    sh.set_defaults(func=cmd_show)
    return p


class _NoteHandler(logging.Handler):
    """The library's notes (compiling, falling back to interpreted functions) as ``note:`` lines."""

    def emit(self, record: logging.LogRecord) -> None:
        print(f"note: {record.getMessage()}", file=sys.stderr)


def _show_notes() -> None:
    log = logging.getLogger("vine_nlp")
    if not any(isinstance(h, _NoteHandler) for h in log.handlers):
        log.addHandler(_NoteHandler(logging.INFO))
        log.setLevel(logging.INFO)
        log.propagate = False


def main(argv=None) -> int:
    from vine_nlp import interrupt

    _show_notes()
    blas.own_process()  # the command line's process is ours: one BLAS thread (design.blas)
    parser = build_parser()
    # SIGTERM unwinds like Ctrl-C: atomic writers remove their temporary files on the way out
    restore = interrupt.install()
    try:
        compiled.mode()  # a bad VINE_NLP_CODEGEN is one error line before any work
        args = parser.parse_args(argv)
        with outputs.run():  # the outputs _check_output reserved: all written when the command ends, or none
            return args.func(args)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted: nothing partial was written", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        return EXIT_OK
    except OSError as e:
        # a file error no reader or atomic writer turned into an InputError: still one line, exit 2
        print(f"error: {e.filename or '-'}: file: {e.strerror or e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        restore()


if __name__ == "__main__":
    raise SystemExit(main())
