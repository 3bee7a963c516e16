"""The ``vine-nlp`` command line (../shared/spec/formats.md, "Command line").

Exit status: 0 done; 1 the solver did not reach its tolerance (archive still
written); 2 bad input, reported as one line ``error: <file>: <key>: <reason>``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vine_nlp import __version__
from vine_nlp.errors import InputError

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in the project's one-line form and exits 2."""

    def error(self, message):
        raise InputError("command line", self.prog, message)


def _check_output(path: str, force: bool, arg: str = "-o") -> Path:
    out = Path(path)
    if out.exists() and not force:
        raise InputError(path, arg, "exists; pass --force to overwrite it")
    if not out.parent.exists():
        raise InputError(path, arg, f"directory {str(out.parent)!r} does not exist")
    return out


def _archive_from(pf, runs, target=None):
    from vine_nlp.io.archive import Archive

    return Archive(
        name=pf.name, kind=pf.kind, source=pf.source, diameter=pf.problem.diameter, units=pf.units, target=target, runs=runs
    )


def cmd_forward(args) -> int:
    from vine_nlp.design.result import run_forward
    from vine_nlp.io.archive import write_archive
    from vine_nlp.io.problem_file import load_problem

    pf = load_problem(args.problem)
    if pf.kind != "forward":
        raise InputError(args.problem, "routing", f"a forward problem needs [routing] (this is a {pf.kind} problem)")
    out = _check_output(args.output, args.force)
    fig = _check_output(args.plot, args.force, "--plot") if args.plot else None
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
    return p


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return args.func(args)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
