"""Shared by the examples: where outputs go, running a vine-nlp command, the summary file.

Every example writes into one directory: ``--out DIR`` on its command line, else the
environment variable ``VINE_NLP_EXAMPLES_OUT``, else ``examples/out/``. Each subfolder is
named after the example, and each example ends by writing ``summary.json`` there: the
numbers it printed, which ``tests/test_examples.py`` checks against ``examples/expected/``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PROBLEMS = ROOT / "problems"
DATA = HERE / "data"


def arguments(name: str, description: str, extra=None) -> argparse.Namespace:
    """Parse ``--out DIR`` (and whatever ``extra(parser)`` adds); ``args.out`` is this example's folder."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--out", help="output folder (default: $VINE_NLP_EXAMPLES_OUT or examples/out)")
    if extra is not None:
        extra(p)
    args = p.parse_args()
    base = Path(args.out or os.environ.get("VINE_NLP_EXAMPLES_OUT") or HERE / "out")
    args.out = base / name
    args.out.mkdir(parents=True, exist_ok=True)
    return args


def vine_nlp(*argv, ok=(0,)) -> None:
    """Run one ``vine-nlp`` command in this process, as typed on a shell; stop on an exit status not in ``ok``."""
    from vine_nlp.front.cli import main

    argv = [str(a) for a in argv]
    print("$ vine-nlp " + " ".join(argv))
    rc = main(argv)
    if rc not in ok:
        raise SystemExit(f"vine-nlp {argv[0]} exited with {rc}")


def write_summary(out: Path, summary: dict) -> None:
    """Write the example's key numbers (and the files it made) to ``out/summary.json``."""
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    print(json.dumps(summary, indent=2, sort_keys=True))
