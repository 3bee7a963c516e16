"""The first run of a new structure against the second (issue 35): problems/hook.toml with an empty code cache.

Writes results/benchmarks/first-run.md.
Run: python benchmarks/bench_first_run.py [--runs 3]

Per round, in a fresh cache directory: the command line's first run (interpreted functions, the C code
compiled by a detached compiler), then, once that compiler has finished (its lock released), a second run
(compiled functions loaded); then the API: the first vn.solve of a process with the empty cache (and its second
call right after, its third once the compiler has finished) against the first of a process with the compiled ones. Wall and CPU seconds of each command-line
run (its own process tree; the detached compiler is not part of it), medians over the rounds.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, machine, table, write_section

PROBLEM = ROOT / "problems" / "hook.toml"
API = """
import time, vine_nlp as vn
from vine_nlp.methods import compiled
t = time.perf_counter(); vn.solve({p!r}); a = time.perf_counter() - t
t = time.perf_counter(); vn.solve({p!r}); b = time.perf_counter() - t
assert compiled.wait(600)
t = time.perf_counter(); vn.solve({p!r}); c = time.perf_counter() - t
print(a, b, c)
"""


def _run(argv, env) -> tuple[float, float]:
    """(wall, CPU) seconds of one process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _wait_compilers(cache: Path) -> None:
    """Until every library's compiler in ``cache`` has released its lock (the library is written)."""
    for lock in sorted(cache.rglob("*.lock")):
        with open(lock) as f:
            fcntl.flock(f, fcntl.LOCK_EX)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    rows = {"cli first": [], "cli second": [], "api first call, empty cache": [], "api second call, at once": [],
            "api third call, after the compile": [], "api first call, compiled": []}
    nan = float("nan")
    loads = [os.getloadavg()[0]]
    for _ in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, VINE_NLP_CACHE_DIR=str(Path(tmp) / "cache"), VINE_NLP_CODEGEN="auto")
            cmd = [sys.executable, "-m", "vine_nlp", "design", str(PROBLEM), "-o", str(Path(tmp) / "h.h5"), "--force"]
            rows["cli first"].append(_run(cmd, env))
            _wait_compilers(Path(tmp) / "cache")
            rows["cli second"].append(_run(cmd, env))
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, VINE_NLP_CACHE_DIR=str(Path(tmp) / "cache"), VINE_NLP_CODEGEN="auto")
            calls = []
            for _ in range(2):  # a process with the empty cache, then one with the compiled functions
                out = subprocess.run([sys.executable, "-c", API.format(p=str(PROBLEM))], env=env, check=True, capture_output=True, text=True)
                calls.append(list(map(float, out.stdout.split())))
            rows["api first call, empty cache"].append((calls[0][0], nan))
            rows["api second call, at once"].append((calls[0][1], nan))
            rows["api third call, after the compile"].append((calls[0][2], nan))
            rows["api first call, compiled"].append((calls[1][0], nan))
        loads.append(os.getloadavg()[0])

    def med(key, i):
        return statistics.median(v[i] for v in rows[key])

    body = [[k, f"{med(k, 0):.2f}", "" if k.startswith("api") else f"{med(k, 1):.2f}",
             ", ".join(f"{v[0]:.2f}" for v in rows[k])] for k in rows]
    ratio_cli = med("cli first", 0) / med("cli second", 0)
    ratio_cpu = med("cli first", 1) / med("cli second", 1)
    ratio_api = med("api first call, empty cache", 0) / med("api first call, compiled", 0)
    text = "\n".join([
        "## First run of a new structure",
        "",
        f"Machine: {machine()}. Load average (1 min) {min(loads):.1f}-{max(loads):.1f} during the runs.",
        "",
        "`python benchmarks/bench_first_run.py`: problems/hook.toml (60 cm straight, a half circle of radius 10 cm, "
        "D = 2.5 cm, 400 points, 40 segments) with an empty code cache: the first run solves on the interpreted "
        "functions while a detached, niced compiler writes the compiled ones; the second, once it has finished, "
        f"loads them. Medians of {args.runs} rounds; the command line: whole process from start to exit.",
        "",
        table(["run", "wall [s]", "CPU [s]", "every round, wall [s]"], body),
        "",
        f"First against second, command line: {ratio_cli:.2f}x wall, {ratio_cpu:.2f}x CPU (goal 1.5x); "
        f"API, the first vn.solve of a process (imports included): {ratio_api:.2f}x. In the process with the empty cache "
        "the second call, right after the first, still runs interpreted (the compiler has not finished), later ones "
        "load the library.",
    ])
    path = write_section("first-run", text)
    print(text)
    print(f"-> {path}")


if __name__ == "__main__":
    main()
