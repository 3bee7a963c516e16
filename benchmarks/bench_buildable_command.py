"""The buildable design's cost as a user meets it: `vine-nlp design P.toml`, whole process, against the same
command on the free design (issue 46: "a buildable design at most 1.3x the free design's time").

The free design is the same problem with ``correction_margin = 0`` and ``min_feature = 0`` in ``[design]`` (no
buildable rule left to enforce: the buildable pass returns the free design). The two commands run in turn (free,
buildable, free, ...) after one unmeasured run each (``VINE_NLP_CODEGEN=on``: the compiled functions built, so every measured run loads them), each
run's CPU time (user + system of the child) and wall time taken; ratio: the median over the pairs of buildable /
free. Writes results/benchmarks/buildable-command.md.

    python benchmarks/bench_buildable_command.py [--runs 7] [--only bezier-a ...]
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, table, write_report

PROBLEMS = ("trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "hook", "polyline-d")


def free_copy(problem: Path, folder: Path) -> Path:
    """The problem with no buildable rule: correction_margin and min_feature 0 in its [design] table."""
    text = problem.read_text()
    text = re.sub(r"^(correction_margin|min_feature)\s*=.*$", "", text, flags=re.M)
    if re.search(r"^\[design\]", text, flags=re.M):
        text = re.sub(r"^\[design\]", "[design]\ncorrection_margin = 0.0\nmin_feature = 0.0", text, count=1, flags=re.M)
    else:
        text += "\n[design]\ncorrection_margin = 0.0\nmin_feature = 0.0\n"
    out = folder / problem.name
    out.write_text(text.replace('file = "', f'file = "{problem.parent}/'))  # a points target's CSV beside the original
    return out


def timed(problem: Path, out: Path, codegen: str = "auto") -> tuple[float, float, str]:
    """(CPU s, wall s, the design's line) of one whole `vine-nlp design` process."""
    env = dict(os.environ, VINE_NLP_CODEGEN=codegen)
    before = os.times()
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "vine_nlp", "design", str(problem), "-o", str(out), "--force"], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = os.times()
    line = next((ln for ln in r.stdout.splitlines() if ln.startswith("nlp:")), f"exit {r.returncode}")
    return (after.children_user - before.children_user) + (after.children_system - before.children_system), wall, line


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--only", nargs="*", default=None)
    args = ap.parse_args()
    rows, load0 = [], os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in args.only or PROBLEMS:
            built = ROOT / "problems" / f"{name}.toml"
            free = free_copy(built, tmp)
            for p in (free, built):  # warm-up: compiles every structure it meets before it solves, so the runs load them
                timed(p, tmp / "w.h5", codegen="on")
            cf, wf, cb, wb = [], [], [], []
            for _ in range(args.runs):
                c, w, free_line = timed(free, tmp / "f.h5")
                cf.append(c), wf.append(w)
                c, w, built_line = timed(built, tmp / "b.h5")
                cb.append(c), wb.append(w)
            med = statistics.median
            rows.append((name, f"{med(wf):.3f} ({med(cf):.3f})", f"{med(wb):.3f} ({med(cb):.3f})",
                         f"{med(b / f for b, f in zip(wb, wf)):.2f}", f"{med(b / f for b, f in zip(cb, cf)):.2f}",
                         free_line.split(", solve time")[0], built_line.split(", solve time")[0]))
    load1 = os.getloadavg()
    write_report("buildable-command", "The buildable design as a user meets it: the whole command",
                 __doc__.split("\n\n")[1].replace("\n", " ") + f" {args.runs} pairs per problem. Load average (1 min) "
                 f"{load0[0]:.2f} before, {load1[0]:.2f} after.",
                 table(("problem", "free: wall s (CPU s)", "buildable: wall s (CPU s)", "ratio wall", "ratio CPU",
                        "free design", "buildable design"), rows))


if __name__ == "__main__":
    main()
