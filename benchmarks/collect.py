"""Join the benchmark sections (results/benchmarks/*.md) into results/BENCHMARKS.md."""

from __future__ import annotations

import os

from common import ROOT, SECTIONS

ORDER = ["design", "scaling", "derivatives", "compare", "smoothing", "init", "sweep", "fit"]


def main():
    parts = ["# Benchmarks\n", "Written by the scripts in benchmarks/ (`python benchmarks/<script>.py`, then "
             "`python benchmarks/collect.py`). Each section names the machine and the commit it ran on; "
             "compare ratios measured in the same run, absolute times on a shared 2-core machine are noisy.\n"]
    files = sorted(SECTIONS.glob("*.md"), key=lambda p: (ORDER.index(p.stem) if p.stem in ORDER else 99, p.stem))
    for f in files:
        parts.append(f.read_text())
    out = ROOT / "results" / "BENCHMARKS.md"
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(parts))
    os.replace(tmp, out)
    print(f"-> {out}")


if __name__ == "__main__":
    main()
