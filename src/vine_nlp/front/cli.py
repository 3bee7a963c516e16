"""The ``vine-nlp`` command line (docs: "Command line"): arguments -> pipeline -> printed lines and files.

Exit status: 0 every run asked for converged and meets every hard requirement of its problem; 1 the
archive is written but a run did not (one line on stderr says what it misses); 2 bad input, reported
as one line ``error: <file>: <key>: <reason>``, nothing written; 130 interrupted.
"""

from __future__ import annotations

import argparse
import csv
import logging
import sys
from pathlib import Path

from vine_nlp import __version__
from vine_nlp.errors import InputError
from vine_nlp.front import files as ff
from vine_nlp.front.files import add_sigma_args, archive_run, check_figure, check_output, read_archive, several_actuators, sigmas
from vine_nlp.io import limits, outputs
from vine_nlp.methods import blas, compiled
from vine_nlp.model.units import mm_per_unit
from vine_nlp.pipeline.request import COMPARE
from vine_nlp.problem import METHODS

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT = 0, 1, 2
# the pipeline names what a problem cannot be asked for by the request's field; the command line by its flag
FLAGS = {"method": "--method", "warm": "--warm", "hops": "--hops", "budget": "--budget", "robust": "--robust",
         "clearance": "--clearance", "starts": "--starts"}
# what each solving command takes: the problem kinds, and the design runs (None: the problem's method)
SOLVES = {"design": (("design", "tip", "multishape", "actuators"), None), "compare": (("design",), COMPARE),
          "forward": (("forward", "actuators-forward"), None), "fit": (("fit",), None)}
KIND_KEY = {"design": "target", "forward": "routing", "fit": "measured"}


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in the project's one-line form and exits 2."""

    def error(self, message):
        raise InputError("command line", self.prog, message)


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


def _note(name):
    """A line of progress on stderr that does not break a progress bar."""

    def note(line):
        from tqdm import tqdm

        tqdm.write(f"{name}: {line}", file=sys.stderr)

    return note


# ---------------------------------------------------------------- the solving commands: one adapter


def _problem_file(args, kinds):
    """The problem the command names: a problem file of one of ``kinds``, or (forward) an archive's run."""
    from vine_nlp.io.problems import load_problem

    if args.command == "forward" and Path(args.problem).suffix.lower() in (".h5", ".hdf5"):
        return _stored_routing(args)
    pf = load_problem(args.problem)
    if pf.kind not in kinds:
        key = KIND_KEY[args.command if args.command != "compare" else "design"]
        raise InputError(args.problem, key, f"a {kinds[0]} problem needs [{key}] (this is a {pf.kind} problem)")
    return pf


def _stored_routing(args):
    """``forward ARCHIVE.h5 --run RUN``: the stored routing of a run as a forward problem."""
    from vine_nlp.io.problem_text import call_text, problem_source
    from vine_nlp.io.problems import ProblemFile
    from vine_nlp.problem import ForwardProblem

    archive = read_archive(args.problem, "PROBLEM")
    run = archive_run(archive, args.problem, args.run)
    if archive.kind.startswith("actuators"):  # several actuators: every line and state of the run (io.actuators)
        from vine_nlp.io.actuators import stored_forward

        problem, source = stored_forward(args.problem, run)
        return ProblemFile(str(args.problem), source, "actuators-forward", problem.name, archive.units, problem)
    problem = ForwardProblem(f"{archive.name}-{run}", archive.diameter, archive.runs[run].routing, units=archive.units)
    source = problem_source(problem, call_text("forward", archive=Path(args.problem).name, run=run))
    return ProblemFile(str(args.problem), source, "forward", problem.name, archive.units, problem)


def _request(args, pf, methods):
    from vine_nlp.pipeline import Request

    get = lambda name, default=None: getattr(args, name, default)  # noqa: E731 (each command has some of the options)
    warm = None
    if get("warm"):
        a = read_archive(args.warm, "--warm")
        if not a.runs:
            raise InputError(args.warm, "--warm", "the archive has no design run")
        warm = a.runs[a.default_run()].routing
    if pf.kind == "design":
        from vine_nlp.io.obstacles import check_start

        check_start(pf.problem, args.problem)
    if get("clearance") and getattr(pf.problem, "target", None) is not None:
        import numpy as np

        span = float(np.linalg.norm(np.ptp(pf.problem.target, axis=0)))
        if args.min_gap > span:
            raise InputError("command line", "--min-gap", f"{args.min_gap:g} is wider than the target, which spans {span:.4g} {pf.units}: "
                             "a tube that keeps that far from itself cannot follow it")
    frames = ()
    if get("frames"):
        from vine_nlp.io.data_files import read_points

        frames = tuple(read_points(f) for f in args.frames)  # bad data files fail before any work
    return Request(methods=methods or ((args.method,) if get("method") else ()), robust=sigmas(args) if get("robust") else None,
                   robust_weight=get("robust_weight", 1.0), clearance=args.min_gap if get("clearance") else None,
                   starts=get("starts"), hops=get("hops"), budget=get("budget"), workers=get("workers", 1), warm=warm,
                   fit_starts=get("fit_starts", 24), seed=get("seed", 0), frames=frames, note=_note(pf.name))


def cmd_solve(args) -> int:
    """forward, design, compare, fit: problem -> pipeline -> archive, lines, figure; the exit status of the outcome."""
    from vine_nlp.front.reports import comparison_table, outcome_lines
    from vine_nlp.pipeline import run  # CasADi loads when a command solves

    kinds, methods = SOLVES[args.command]
    pf = _problem_file(args, kinds)
    out = check_output(args.output, args.force)
    figures = [f for f in (check_figure(getattr(args, "plot", None), args.force),
                           check_figure(getattr(args, "frames_plot", None), args.force) if getattr(args, "frames", None) else None) if f]
    request = _request(args, pf, methods)
    update, close = _progress_bar(f"{pf.name} {pf.kind}", "solves")
    try:
        outcome = run(pf, _with_progress(request, update))
    except InputError as e:
        raise InputError(e.file, FLAGS.get(e.key, e.key), e.reason) from None
    except ValueError as e:  # a fit with too few usable points after the reader's checks
        if pf.kind != "fit":
            raise
        raise InputError(args.problem, "measured.file", str(e)) from None
    finally:
        close()
    outcome.write(out)
    print(comparison_table(outcome.runs, pf.units, pf.problem) if methods else "\n".join(outcome_lines(outcome)))
    print(f"archive -> {out}")
    for line in outcome.shortfalls():
        print(f"{pf.name}: {line}", file=sys.stderr)
    if figures:
        from vine_nlp.front.figures import draw  # matplotlib loads only for a figure (half a second)

        draw(out, figures[0])
        print(f"figure -> {figures[0]}")
    if len(figures) > 1:
        from vine_nlp.front.fit_plots import plot_frames

        plot_frames(outcome.details["frames"], figures[1], units=pf.units, title=f"{pf.name}: lambda over frames")
        print(f"frames figure -> {figures[1]}")
    return outcome.exit_code


def _with_progress(request, update):
    import dataclasses

    return dataclasses.replace(request, progress=update)


# ---------------------------------------------------------------- the other commands


def cmd_sweep(args) -> int:
    from vine_nlp.front.sweep import format_report, run_sweep
    from vine_nlp.io.sweep_file import load_sweep

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
    return EXIT_OK if not (report.failed or report.not_converged or report.short) else EXIT_NOT_CONVERGED


def cmd_analyze(args) -> int:
    from vine_nlp.front import analyze  # matplotlib and SciPy load when the command runs

    return analyze.cmd_analyze_states(args) if several_actuators(args.archive) else analyze.cmd_analyze(args)


def cmd_correct(args) -> int:
    from vine_nlp.front import correct  # the solvers load when the command runs

    return correct.cmd_correct(args)


def cmd_calibrate(args) -> int:
    from vine_nlp.front import correct

    return correct.cmd_calibrate(args)


def cmd_plot(args) -> int:
    from vine_nlp.front.figures import draw

    archive = read_archive(args.archive)
    ff.within_limits("plot", archive, args.archive, list(archive.runs))
    out = check_figure(args.output, args.force, "-o")
    draw(args.archive, out)
    print(f"figure -> {out}")
    return EXIT_OK


def cmd_template(args) -> int:
    from vine_nlp.front.template import write_actuators_template, write_template

    out = check_output(args.output, args.force)
    fmt = _output_format(out, "template", "template_format")
    archive = read_archive(args.archive)
    csv = check_output(args.csv, args.force, "--csv") if args.csv else None
    _template_limits(archive, args, fmt)
    rows = None
    if getattr(args, "changes", False):
        from vine_nlp.front.changes import change_rows, changes_text

        try:
            rows = change_rows(archive, args.run or "corrected")
        except (ValueError, KeyError) as e:
            raise InputError(args.archive, "--changes", str(e).strip("'")) from None
        print(changes_text(rows, archive.units))
    several = several_actuators(args.archive)
    try:
        info = write_actuators_template(args.archive, out, csv, args.paper, args.run) if several else \
            write_template(archive, out, csv_path=csv, paper=args.paper, run=args.run or ("corrected" if rows is not None else None), changes=rows)
    except InputError:
        raise
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
    from vine_nlp.front.show import build_warnings

    for line in [] if several else build_warnings(archive, info["run"]):  # judged as show and the design judge it
        print(f"warning: {args.archive}: {line}", file=sys.stderr)
    print("print at 100 % (no 'fit to page') and check the 10 cm scale bar" if fmt == ".pdf"
          else "the 10 cm scale bar is 100 mm in the file: check it after import")
    return EXIT_OK


def _template_limits(archive, args, fmt) -> None:
    """A template's run within the command's limits; at most MAX_TEMPLATE_MM of tube (1:1)."""
    run = args.run or ("corrected" if getattr(args, "changes", False) else None)
    if run is not None and run not in archive.runs:
        return  # the template names the missing run itself
    run = run or archive.default_run()
    if run is None:
        return
    ff.within_limits("template", archive, args.archive, [run])
    length = float(archive.runs[run].routing.length.sum()) * (mm_per_unit(archive.units) or 0.0)
    if length > limits.MAX_TEMPLATE_MM:  # PDF pages, and SVG/DXF's A4 cut lines and ruler ticks (50 m: a minute, 5 GB)
        raise InputError(args.archive, "runs", f"run {run}: {length / 1000:.4g} m of tube; a 1:1 template takes at most "
                         f"{limits.MAX_TEMPLATE_MM / 1000:g} m (vine_nlp.io.limits.MAX_TEMPLATE_MM)")


def _sweep_view_limits(src) -> None:
    """A sweep view loads every item's archive: at most limits.MAX_VIEW_ITEMS rows of summary.csv (counted first)."""
    from vine_nlp.io.files import text_lines

    summary = Path(src) / "summary.csv"
    for number, _ in text_lines(summary):  # a line over MAX_LINE_CHARS is one line too (the csv module's limit is 131072)
        if number > limits.MAX_VIEW_ITEMS + 1:
            raise InputError(summary, "rows", f"more than {limits.MAX_VIEW_ITEMS} items: a view shows at most that many "
                             "(vine_nlp.io.limits.MAX_VIEW_ITEMS); view the items' archives one by one")


def cmd_view(args) -> int:
    """One self-contained HTML view of an archive or of a sweep directory."""
    view = _front("view")
    out = check_output(args.output, args.force)
    if out.suffix.lower() not in (".html", ".htm"):
        raise InputError(out, "-o", f"unknown view format {out.suffix or '(none)'!r}: use .html")
    src = Path(args.source)
    if src.is_dir():
        if args.run:
            raise InputError(src, "--run", "a sweep view shows every run")
        if not view.is_sweep_dir(src):
            raise InputError(src, "SWEEPDIR", "no summary.csv: not a sweep directory")
        _sweep_view_limits(src)
        try:
            html = view.sweep_html(src)
        except (ValueError, OSError, KeyError, csv.Error) as e:  # csv.Error: a field over the csv module's limit
            raise InputError(src, "SWEEPDIR", str(e)) from None
        what = "sweep"
    else:
        archive = read_archive(src)
        if args.run is not None:
            archive_run(archive, src, args.run)
        elif not archive.runs:
            raise InputError(src, "runs", "the archive has no runs")
        several = several_actuators(src)  # one page, a menu of its states (of the run named, or the default run)
        ff.within_limits("view", archive, src, [archive.pick_run(args.run)] if args.run or several else list(archive.runs))
        html = view.view_html(src if several else archive, run=args.run)
        what = ", ".join([args.run] if args.run else archive.runs) if not several else f"every state of run {archive.pick_run(args.run)}"
    view.write_html(out, html)
    print(f"view of {what} ({len(html) / 1e6:.2f} MB, opens offline) -> {out}")
    return EXIT_OK


def cmd_animate(args) -> int:
    """The knot figure as a movie: growth while actuated beside actuation after growth."""
    animate = _front("animate")
    out = check_output(args.output, args.force)
    fmt = _output_format(out, "animate", "movie_format")
    if fmt == ".mp4" and not animate.ffmpeg_available():
        raise InputError(out, "-o", "MP4 needs ffmpeg, which is not installed (apt-get install ffmpeg); write a .gif instead")
    archive = read_archive(args.archive)
    run = archive_run(archive, args.archive, args.run)
    ff.within_limits("animate", archive, args.archive, [run])
    if several_actuators(args.archive):  # state to state (--mode is for one actuator)
        info = animate.write_states_movie(args.archive, out, run=run, frames=args.frames, fps=args.fps)
        print(f"{info['frames']} frames, run {run}, state to state: {' -> '.join(info['states'])} -> {out}")
        return EXIT_OK
    info = animate.write_movie(archive, out, mode=args.mode, run=run, frames=args.frames, fps=args.fps)
    print(f"{info['frames']} frames ({info['mode']}), run {run}, self-contacts: {info['contacts_grow']} of the final shape, "
          f"up to {info['contacts_after']} at once when actuated after growth"
          + (f" (t = {min(info['contacts_after_t']):.3g} to {max(info['contacts_after_t']):.3g})" if info.get("contacts_after_t") else "")
          + f" -> {out}")
    return EXIT_OK


def cmd_export(args) -> int:
    """The tube as a closed triangle mesh (STL, OBJ, PLY, glTF binary)."""
    export = _front("export")
    if several_actuators(args.archive):
        return export.cmd_export_states(args)
    out = check_output(args.output, args.force)
    fmt = _output_format(out, "export", "mesh_format")
    if fmt in (".stl", ".ply"):
        check_output(out.with_name(f"{out.stem}.actuator{out.suffix}"), args.force)
    archive = read_archive(args.archive)
    run = archive_run(archive, args.archive, args.run)
    ff.within_limits("export", archive, args.archive, [run])
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

    print(summarize(read_archive(args.archive), path=args.archive))
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


def _add_correct_arguments(p) -> None:
    p.add_argument("measured", nargs="+", metavar="MEASURED.csv", help="points measured on the built robot (rows x y z, any order)")
    p.add_argument("--run", type=ff.run_name, help="the nominal that was built (default: corrected in a correction archive, else the design run)")
    p.add_argument("--line", default="outer", metavar="LINE[,LINE...]", help="measured line: center, inner or outer; one per file or one for all (default outer)")
    p.add_argument("--adjust", choices=("lambda", "lambda,theta"), metavar="lambda|lambda,theta", help="the route taken as /runs/corrected: lambda (stoppers or pouches on this robot) or lambda,theta (the line drawn anew on a new tube); default: the recommended one (both are predicted)")
    p.add_argument("--free-pose", action="store_true", help="the measurement is in an unknown frame: estimate its rigid pose")
    p.add_argument("--state", action="append", type=ff.run_name, metavar="NAME", help="several actuators: the state a MEASURED file was measured in; once per file, in order, or once for all (optional where the archive has one state)")
    add_sigma_args(p)
    p.add_argument("--sigma-measurement", type=ff.bounded(0, limits.MAX_COORDINATE, above=True), metavar="S", help="measurement noise, in units (default 1 mm)")
    p.add_argument("--plot", metavar="FIG.png", help="measured, estimated and corrected shapes; deviations per segment")


def _command(sub, name: str, text: str, output: str | None, *source, **how):
    """A command's parser: its help line ``text``, its positional argument ``source`` (``how``: as add_argument
    takes it) and, where it writes one, ``-o OUTPUT`` (its metavar)."""
    p = sub.add_parser(name, help=text)
    p.add_argument(*source, **how)
    if output:
        p.add_argument("-o", "--output", required=True, metavar=output)
    return p


def _done(p, func, force: str | None = None) -> None:
    """The command's ``--force`` (its help; none for a command that writes nothing) and the function it runs."""
    if force:
        p.add_argument("--force", action="store_true", help=force)
    p.set_defaults(func=func)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="vine-nlp",
        description="Design actuator routings for vine robots (Blumenschein et al., IEEE T-RO 2021).",
    )
    p.add_argument("--version", action="version", version=f"vine-nlp {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    f = _command(sub, "forward", "shape of a given routing -> result archive", "OUT.h5", "problem", metavar="PROBLEM.toml|ARCHIVE.h5",
                 help="a forward problem, or an archive whose stored routing is re-run")
    f.add_argument("--run", type=ff.run_name, help="with an archive: which run's routing (default: its default run)")
    f.add_argument("--plot", metavar="FIG.png", help="also draw the shape (png or pdf)")
    _done(f, cmd_solve, "overwrite existing output files")

    for name, text in (
        ("design", "inverse design of a routing for a target curve -> result archive"),
        ("compare", "nlp and the greedy, each free and buildable, on one problem: one archive, a table on stdout"),
    ):
        d = _command(sub, name, text, "OUT.h5", "problem", metavar="PROBLEM.toml")
        if name == "design":
            d.add_argument("--method", choices=METHODS, help="default: the problem's [design] method (nlp)")
            d.add_argument("--warm", metavar="ARCHIVE.h5", help="nlp: start from the design in an earlier archive")
            d.add_argument("--robust", action="store_true", help="also a design minimizing the expected error under construction errors (run nlp_robust)")
            d.add_argument("--robust-weight", type=ff.bounded(0, 1e6), default=1.0, metavar="W", help="weight of the expected error increase")
            add_sigma_args(d)
            d.add_argument("--clearance", action="store_true", help="also a design keeping the tube clear of itself (run nlp_clearance)")
            d.add_argument("--min-gap", type=ff.bounded(0, limits.MAX_COORDINATE), default=0.0, metavar="G", help="clearance beyond D, in units")
        d.add_argument("--starts", type=ff.bounded(1, limits.MAX_STARTS, True), metavar="N", help="nlp: number of starts of the multi-start (default: the problem's)")
        d.add_argument("--hops", type=ff.bounded(0, limits.MAX_HOPS, True), metavar="N", help="nlp: rounds of basin hopping after the starts, for targets with corners (default: the problem's)")
        d.add_argument("--budget", type=ff.bounded(0, limits.MAX_SECONDS), metavar="S", help="seconds for the whole design: no start, hop or round begins after it (the first start always runs; a design it cut is status max_time, exit 1) and the corner search ends within it (default: no bound, the corner search the problem's [design] budget, 20 s; 0: the first start alone, no search)")
        d.add_argument("--workers", type=ff.bounded(1, limits.MAX_WORKERS, True), default=1, metavar="N", help="nlp: run the starts in N processes")
        d.add_argument("--plot", metavar="FIG.png", help="also draw the result (png or pdf)")
        _done(d, cmd_solve, "overwrite existing output files")

    an = _command(sub, "analyze", "self-collision, growth order and manufacturing tolerance of a design", None, "archive", metavar="OUT.h5")
    an.add_argument("--run", type=ff.run_name, help="which run (default: nlp, greedy, forward, ...)")
    an.add_argument("--state", type=ff.run_name, help="several actuators: this state alone (default: every state)")
    add_sigma_args(an)
    an.add_argument("--samples", type=ff.bounded(1, limits.MAX_SAMPLES, True), default=2000, help="Monte Carlo samples (default 2000)")
    an.add_argument("--seed", type=ff.bounded(0, limits.MAX_SEED, True), default=0)
    an.add_argument("--margin", type=ff.bounded(0, limits.MAX_COORDINATE), default=0.0, metavar="G", help="count approaches closer than D + G as contacts")
    an.add_argument("--tolerance-figure", metavar="FIG.png", help="where along the tube errors matter most")
    an.add_argument("--clearance-figure", metavar="FIG.png", help="clearance along the tube")
    an.add_argument("--load-figure", metavar="FIG.png", help="[load]: bending moment and capacity along the tube and over growth")
    an.add_argument("--write-metrics", action="store_true", help="store the figures as metrics of the run in the archive")
    _done(an, cmd_analyze)

    sw = _command(sub, "sweep", "many design problems: one archive per item, summary.csv and a summary figure", "DIR", "sweep",
                  metavar="SWEEP.toml")
    sw.add_argument("--workers", type=ff.bounded(0, limits.MAX_WORKERS, True), metavar="N", help="local worker processes (default: all cores)")
    sw.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask distributed cluster (e.g. tcp://host:8786)")
    _done(sw, cmd_sweep, "redo items whose archives exist")

    ft = _command(sub, "fit", "fit the model of a known routing to measured points (pose, optionally lambda)", "OUT.h5", "problem",
                  metavar="PROBLEM.toml")
    ft.add_argument("--starts", dest="fit_starts", type=ff.bounded(1, limits.MAX_STARTS, True), default=24, metavar="N", help="starting orientations of the global pose search")
    ft.add_argument("--seed", type=ff.bounded(0, limits.MAX_SEED, True), default=0)
    ft.add_argument("--plot", metavar="FIG.png", help="measured points against the fitted model, error against length")
    ft.add_argument("--frames", nargs="+", metavar="FRAME.csv", help="also fit these frames of the same actuator in order")
    ft.add_argument("--frames-plot", metavar="FIG.png", help="with --frames: lambda over frames and error against length")
    _done(ft, cmd_solve, "overwrite existing output files")

    pl = _command(sub, "plot", "figures of an archive (png or pdf)", "FIG.png", "archive", metavar="OUT.h5")
    _done(pl, cmd_plot, "overwrite an existing figure")

    t = _command(sub, "template", "1:1 fabrication template (PDF, or SVG/DXF in mm) and cut list (CSV) of a design",
                 "TEMPLATE.pdf|.svg|.dxf", "archive", metavar="OUT.h5")
    t.add_argument("--csv", metavar="CUTS.csv", help="also write one row per segment")
    t.add_argument("--paper", choices=("A4", "Letter"), default="A4")
    t.add_argument("--run", type=ff.run_name, help="which run of the archive (default: nlp, greedy or forward)")
    t.add_argument("--changes", action="store_true", help="correction archives: also list, and frame on the template, the segments whose stoppers change against the robot built last")
    _done(t, cmd_template, "overwrite existing output files")

    vw = _command(sub, "view", "interactive 3-D view (one HTML file, offline) of an archive or a sweep directory", "VIEW.html", "source",
                  metavar="ARCHIVE.h5|SWEEPDIR")
    vw.add_argument("--run", type=ff.run_name, help="show only this run (default: every run, toggled in the legend)")
    _done(vw, cmd_view, "overwrite an existing file")

    am = _command(sub, "animate", "movie: growth while actuated beside actuation after growth (GIF or MP4)", "MOVIE.gif|MOVIE.mp4",
                  "archive", metavar="ARCHIVE.h5")
    am.add_argument("--mode", choices=("grow", "after", "both"), default="both", help="one actuator (several: state to state)")
    am.add_argument("--run", type=ff.run_name, help="which run (default: nlp, greedy, forward, ...)")
    am.add_argument("--frames", type=ff.bounded(2, limits.MAX_FRAMES, True), default=41, metavar="N",
                    help="frames (default 41: a frame at every t analyze looks at)")
    am.add_argument("--fps", type=ff.bounded(1, limits.MAX_FPS, True), default=10, metavar="N", help="frames per second (default 10)")
    _done(am, cmd_animate, "overwrite an existing file")

    ex = _command(sub, "export", "the tube as a closed triangle mesh (STL, OBJ, PLY, glTF .glb)", "TUBE.stl|.obj|.ply|.glb", "archive",
                  metavar="ARCHIVE.h5")
    ex.add_argument("--run", type=ff.run_name, help="which run (default: nlp, greedy, forward, ...)")
    ex.add_argument("--state", type=ff.run_name, help="several actuators: this state alone, in OUT (default: every state, OUT.<state>.ext each)")
    _done(ex, cmd_export, "overwrite existing files")

    co = _command(sub, "correct", "estimate a built robot from measured points and correct it -> correction archive", "OUT.h5", "archive",
                  metavar="ARCHIVE.h5")
    _add_correct_arguments(co)
    _done(co, cmd_correct, "overwrite existing output files")
    cb = _command(sub, "calibrate", "systematic construction errors over several correction archives -> CAL.toml", "CAL.toml", "archives",
                  nargs="+", metavar="ARCHIVE.h5", help="correction archives of prototypes of one construction method")
    _done(cb, cmd_calibrate, "overwrite an existing file")

    _done(_command(sub, "show", "readable summary of an archive", None, "archive", metavar="OUT.h5"), cmd_show)
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


def _commands(parser) -> str:
    """The list of commands with their one-line help, for ``vine-nlp`` run alone."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rows = [f"  {c.dest:<10s} {c.help}" for c in sub._choices_actions]
    return "\n".join(["usage: vine-nlp COMMAND [options]   (vine-nlp --help; vine-nlp COMMAND --help: its options)", "commands:", *rows])


def _one_actuator_only(args) -> None:
    """One error line, before any work, for --state on an archive of one actuator."""
    path = getattr(args, "archive", None) or getattr(args, "source", None)
    if getattr(args, "state", None) is not None and Path(path).is_file() and not several_actuators(path):
        raise InputError(path, "--state", "an archive of one actuator has no states (--state is for archives of several actuators)")


def main(argv=None) -> int:
    from vine_nlp import interrupt

    _show_notes()
    blas.own_process()  # the command line's process is ours: one BLAS thread (design.blas)
    parser = build_parser()
    # SIGTERM unwinds like Ctrl-C: atomic writers remove their temporary files on the way out
    restore = interrupt.install()
    try:
        compiled.mode()  # a bad VINE_NLP_CODEGEN is one error line before any work
        if not (sys.argv[1:] if argv is None else argv):  # no command: what the commands are, and where to read more
            print(_commands(parser))
            return EXIT_BAD_INPUT
        args = parser.parse_args(argv)
        _one_actuator_only(args)
        with outputs.run():  # the outputs check_output reserved: all written when the command ends, or none
            code = args.func(args)
            if interrupt.requested() and code != 130:  # a signal whose KeyboardInterrupt a library swallowed: nothing is committed
                raise KeyboardInterrupt
            return code
    except BaseException as e:  # noqa: BLE001  each kind is one line and an exit code, or raised again
        return _ending(e)
    finally:
        restore()


def _ending(e: BaseException) -> int:
    """The exit code (and the one line) of a command that raised ``e``; ``e`` again when it is a bug."""
    from vine_nlp import interrupt

    # whatever a signal became on its way out of a library (h5py's lock: a SystemError) is the interrupt
    if isinstance(e, KeyboardInterrupt) or (interrupt.requested() and not isinstance(e, SystemExit)):
        print("interrupted: nothing partial was written", file=sys.stderr)
        return 130
    if isinstance(e, InputError):
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if isinstance(e, BrokenPipeError):  # output piped into head & co.
        sys.stderr.close()
        return EXIT_OK
    if isinstance(e, OSError):
        # a file error no reader or atomic writer turned into an InputError: still one line, exit 2
        print(f"error: {e.filename or '-'}: file: {e.strerror or e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    raise e


if __name__ == "__main__":
    raise SystemExit(main())
