"""Time per IPOPT iteration of every formulation, this checkout against an earlier commit (issue 43: "within 5 %
of today's (bench_transcription), or better").

Checks the base commit out into a temporary git worktree and runs bench_transcription.py alternately there and here
(base, here, base, here, ...: ``--rounds`` pairs), each on its own package (PYTHONPATH), then joins the rows that both
report by formulation and target. The first round of a new checkout runs partly interpreted: its compiled
libraries (methods.compiled) are built by a niced background compiler while it runs; the report gives every round,
and the last ones are the warm ones to read. Writes results/benchmarks/transcription-ab.md.

    python benchmarks/transcription_ab.py --base c171e1e [--rounds 4] [--repeat 3]
    python benchmarks/transcription_ab.py --base c171e1e --tables BASE1.md NOW1.md [BASE2.md NOW2.md ...]
        (join reports bench_transcription.py wrote earlier, in that order, instead of running it)
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from common import ROOT, table, write_report

BENCH = "benchmarks/bench_transcription.py"
REPORT = ROOT / "results/benchmarks/transcription.md"


def rows(text: str) -> dict:
    """{(formulation, target): (ms per iteration, iterations)} of a bench_transcription report's first table."""
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) >= 7 and re.fullmatch(r"[\d.]+", cells[2]):
            out[(cells[0], cells[1])] = (float(cells[2]), cells[3])
    return out


def run(checkout: Path, repeat: int) -> str:
    """One bench_transcription run in ``checkout`` on its own package: its report."""
    env = dict(os.environ, PYTHONPATH=str(checkout / "src"))
    subprocess.run([sys.executable, BENCH, "--repeat", str(repeat)], cwd=checkout, env=env, check=True, capture_output=True)
    return (checkout / "results/benchmarks/transcription.md").read_text()


def block(k: int, n: int, base: str, now: str) -> str:
    """One round's table: the rows both reports have, with each report's commit and load average."""
    b, h = rows(base), rows(now)
    body = [(f, t, f"{b[f, t][0]:.2f}", f"{h[f, t][0]:.2f}", f"{h[f, t][0] / b[f, t][0]:.3f}", b[f, t][1], h[f, t][1])
            for f, t in b if (f, t) in h]
    said = lambda text: "; ".join(re.findall(r"commit \w+|Load average[^)]*\) at the start [\d., ]+at the end [\d., ]+", text))  # noqa: E731
    return (f"Round {k} of {n}. Base: {said(base)}. Now: {said(now)}.\n\n"
            + table(("formulation", "target", "base ms / it", "now ms / it", "ratio", "iterations base", "now"), body))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, help="the earlier commit")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--note", default="", help="a sentence for the report (what differs between the two)")
    ap.add_argument("--tables", nargs="+", type=Path, help="earlier reports: base, now, base, now, ...")
    args = ap.parse_args()
    if args.tables:
        texts = [p.read_text() for p in args.tables]
        pairs = list(zip(texts[0::2], texts[1::2]))
    else:
        mine = REPORT.read_text() if REPORT.exists() else None
        pairs = []
        with tempfile.TemporaryDirectory() as tmp:
            base = Path(tmp) / "base"
            subprocess.run(["git", "worktree", "add", "--detach", "-f", str(base), args.base], cwd=ROOT, check=True, capture_output=True)
            try:
                pairs = [(run(base, args.repeat), run(ROOT, args.repeat)) for _ in range(args.rounds)]
            finally:
                subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=ROOT, capture_output=True)
        if mine is not None:  # this checkout's own report stays the one bench_transcription wrote on its own
            REPORT.write_text(mine)
    blocks = [block(k, len(pairs), b, h) for k, (b, h) in enumerate(pairs, 1)]
    write_report("transcription-ab", f"Time per IPOPT iteration against {args.base}",
                 "benchmarks/transcription_ab.py: bench_transcription.py run alternately on the base commit and this "
                 "checkout (CPU time of each solve per IPOPT iteration, solvers built, the same starts); ratio: now / base "
                 "of the row's median. The first round of a new checkout compiles its libraries in the background while "
                 "it runs: read the later, warm rounds. " + args.note, *blocks)


if __name__ == "__main__":
    main()
