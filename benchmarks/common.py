"""Shared helpers of the benchmark scripts: machine description and section files.

Each benchmark writes its own section to results/benchmarks/<name>.md; collect.py
joins the sections into results/BENCHMARKS.md. Absolute times on a shared 2-core
machine are noisy: compare ratios measured in the same run.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
from pathlib import Path

from vine_nlp.methods import blas

# the benchmarks run as the command line does: one BLAS thread (design.blas)
blas.own_process()

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ROOT / "results" / "benchmarks"
FIGURES = ROOT / "results" / "figures"


def commit() -> str:
    """The checkout's short commit ("?" without git)."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip() or "?"
    except OSError:
        return "?"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import casadi
    import numpy

    mem = ""
    try:
        kb = int(next(l for l in Path("/proc/meminfo").read_text().splitlines() if l.startswith("MemTotal")).split()[1])
        mem = f", {kb / 2**20:.0f} GiB"
    except (OSError, StopIteration, ValueError):
        pass
    return (
        f"{cpu}, {os.cpu_count()} cores{mem}; Python {platform.python_version()}, casadi {casadi.__version__}, "
        f"numpy {numpy.__version__}; BLAS threads {os.environ.get('OPENBLAS_NUM_THREADS', 'default')}; commit {commit()}; {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='minutes')}"
    )


def write_atomic(path: Path, text: str) -> Path:
    """``text`` to ``path`` whole or not at all: an interrupted benchmark leaves no half-written file to trip the next run."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def write_section(name: str, text: str) -> Path:
    SECTIONS.mkdir(parents=True, exist_ok=True)
    return write_atomic(SECTIONS / f"{name}.md", text.rstrip() + "\n")


def write_report(name: str, title: str, description: str, *blocks: str) -> Path:
    """A section: its title, the machine it ran on, what was measured, then tables and notes."""
    return write_section(name, "\n\n".join([f"## {title}", f"Machine: {machine()}", description, *blocks]))


def table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)
