"""The timings the documentation shows (``about N s``, ``items/s``), against a run on this machine (issue 48).

The tests check every printed block's text and counts exactly (tests/printed.py) but not its timings: a test
that depends on the clock is a defect. This benchmark runs each block that shows a timing (its command, as the
tests do: interpreted NLP functions, a fresh cache) and checks each timing within ABOUT_FACTOR (2x) of what
was printed. Writes results/benchmarks/docs-timings.md; exits 1 where one is off (then refresh the block:
``python3 tests/printed.py --update PAGE`` on a machine neither idle nor busy).

Run: python3 benchmarks/bench_docs_timings.py [PATTERN]   (only the pages whose path contains PATTERN)
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, table, write_report

sys.path.insert(0, str(ROOT / "tests"))
import printed  # noqa: E402


def timed(block) -> bool:
    return any(n[1] and n[4] for line in block.lines for n in printed._skeleton(line)[1])


def main(pattern: str = "") -> int:
    rows, failed, load = [], 0, os.getloadavg()[0]
    for b in (b for b in printed.blocks() if timed(b) and pattern in str(b.file.relative_to(ROOT))):
        with tempfile.TemporaryDirectory() as tmp:
            cwd = Path(tmp)
            for name in ("problems", "examples"):
                (cwd / name).symlink_to(ROOT / name)
            (cwd / "results").mkdir()
            t = time.perf_counter()
            stdout, stderr = printed.run(b.command, cwd)
            wall = time.perf_counter() - t
        for line, got in printed._match(b, stdout, stderr):
            for shown, g in zip(printed._skeleton(line)[1], got or ()):
                if shown[1] and shown[4]:
                    why = printed.disagree(shown, g, b.tol, timings=True)
                    failed += why is not None
                    rows.append((f"{b.file.relative_to(ROOT)}:{b.line}", f"about {shown[3]}", g[3], f"{g[0] / shown[0]:.2f}" if shown[0] else "-",
                                 why or "ok", f"{wall:.0f}"))
        problems = printed.check(b, stdout, stderr, timings=True)
        failed += len([p for p in problems if "not printed" in p])
        rows += [(f"{b.file.relative_to(ROOT)}:{b.line}", "", "", "", p, "") for p in problems if "not printed" in p]
        print(f"{b.file.relative_to(ROOT)}:{b.line}: {b.command}: {wall:.1f} s", flush=True)
    write_report("docs-timings", "Timings shown in the documentation",
                 "`python3 benchmarks/bench_docs_timings.py`: every documentation block that shows a timing (`about N s`, "
                 "`items/s`), its command run as the tests run it (interpreted NLP functions, a fresh cache); each timing must be "
                 f"within {printed.ABOUT_FACTOR:g}x of the printed one (the tests compare the blocks' text and counts, not their timings). "
                 f"Load average (1 min) {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end ({os.cpu_count()} cores).",
                 table(["block", "shown", "printed", "printed / shown", "check", "command wall [s]"], rows),
                 f"{len(rows) - failed} of {len(rows)} within {printed.ABOUT_FACTOR:g}x.")
    print(f"{len(rows) - failed} of {len(rows)} timings within {printed.ABOUT_FACTOR:g}x -> results/benchmarks/docs-timings.md")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else ""))
