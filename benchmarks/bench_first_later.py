"""One file, one design (issue 46): a first run and a later run of every bundled problem and every obstacle scene.

A first run on a machine solves on the interpreted NLP functions while the compiler works in the background
(methods.compiled); later runs load the compiled ones. Each problem goes through ``vine_nlp.pipeline.run`` as
``vine-nlp design`` runs it, in two child processes, one per setting: ``VINE_NLP_CODEGEN=off`` (the first run's
functions) and ``VINE_NLP_CODEGEN=on`` (compiled, cached). Every run's routing (theta, lambda, lengths) is kept,
and the two are compared: the goal is 1e-6, the same exit status and the same runs.

Problems: problems/*.toml and the scene set's files (benchmarks/.cache/scenes/files, made by bench_scenes.py).
Records go to benchmarks/.cache/first-later/<setting>.pkl, and a run resumes from them; they are not tied to a
version of the code, so after a change start over with --fresh.
It takes about 10 minutes compiled and 17 interpreted on 2 cores.
Writes results/benchmarks/first-later.md.

Run: PYTHONPATH=src python3 benchmarks/bench_first_later.py [--fresh]
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from common import ROOT, table, write_report

CACHE = ROOT / "benchmarks" / ".cache" / "first-later"
SCENES = ROOT / "benchmarks" / ".cache" / "scenes" / "files"
SETTINGS = ("off", "on")
GOAL = 1e-6


def problems() -> list[Path]:
    return sorted((ROOT / "problems").glob("*.toml")) + sorted(SCENES.glob("*.toml"))


def child(setting: str, out: Path) -> None:
    """In a child process (VINE_NLP_CODEGEN already set): every problem's runs, their routings kept in ``out``."""
    from vine_nlp.io.problems import load_problem
    from vine_nlp.pipeline.runs import run

    recs = pickle.loads(out.read_bytes()) if out.exists() else {}
    files = problems()
    t0 = time.time()
    for i, path in enumerate(files):
        key = str(path.relative_to(ROOT))
        if key in recs:
            continue
        t1 = time.perf_counter()
        try:
            oc = run(load_problem(path))
            recs[key] = {"exit": oc.exit_code, "wall_s": time.perf_counter() - t1, "runs": {name: {k: np.asarray(getattr(r.routing, k), float) for k in ("theta", "lam", "length")}
                                                       for name, r in oc.runs.items() if getattr(r, "routing", None) is not None}}
        except Exception as exc:  # noqa: BLE001 - a failure is a record like any other (and must agree)
            recs[key] = {"error": f"{type(exc).__name__}: {exc}"}
        tmp = out.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(recs))
        os.replace(tmp, out)  # resumable: every finished problem kept
        print(f"{setting}: {i + 1}/{len(files)} {path.stem} ({time.time() - t0:.0f} s)", flush=True)


def compare(first: dict, later: dict) -> tuple[list, list]:
    """(max abs routing difference, name) of every problem whose two runs ended alike (the same error, or the same exit
    status and runs), and (name, first, later) of the problems whose outcome differs."""
    def outcome(r):
        return r.get("error"), r.get("exit"), sorted(r.get("runs", {}))

    diffs, unlike = [], []
    for key in sorted(set(first) & set(later)):
        a, b = first[key], later[key]
        if outcome(a) != outcome(b):
            unlike.append((key, a.get("error", a.get("exit")), b.get("error", b.get("exit"))))
            continue
        pairs = [(v, b["runs"][name][k]) for name, ra in a.get("runs", {}).items() for k, v in ra.items()]
        diffs.append((max((float(np.max(np.abs(v - w), initial=0.0)) if v.shape == w.shape else np.inf for v, w in pairs), default=0.0), key))
    return sorted(diffs, reverse=True), unlike


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fresh", action="store_true", help="ignore the records of an earlier run")
    ap.add_argument("--child", choices=SETTINGS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    CACHE.mkdir(parents=True, exist_ok=True)
    if args.child:
        child(args.child, CACHE / f"{args.child}.pkl")
        return
    for setting in SETTINGS:
        out = CACHE / f"{setting}.pkl"
        if args.fresh and out.exists():
            out.unlink()
        env = dict(os.environ, VINE_NLP_CODEGEN=setting, MPLBACKEND="Agg")
        subprocess.run([sys.executable, __file__, "--child", setting], env=env, check=True)
    first, later = (pickle.loads((CACHE / f"{s}.pkl").read_bytes()) for s in SETTINGS)
    walls = [sum(r.get("wall_s", np.nan) for r in recs.values()) for recs in (first, later)]
    diffs, unlike = compare(first, later)
    bundled = [d for d in diffs if d[1].startswith("problems/")]
    scenes = [d for d in diffs if not d[1].startswith("problems/")]
    rows = [(what, len(ds), sum(d[0] > GOAL for d in ds), f"{max((d[0] for d in ds), default=0.0):.3g}",
             sum(first[k].get("exit") == 0 for _, k in ds)) for what, ds in (("bundled problems", bundled), ("obstacle scenes", scenes))]
    lines = [f"- {k}: first {a}, later {b}" for k, a, b in unlike]
    write_report(
        "first-later", "One file, one design: a first run against a later run (issue 46)",
        "`python benchmarks/bench_first_later.py`: every bundled problem and every scene of the obstacle set through "
        "`vine_nlp.pipeline.run` (what `vine-nlp design` runs), once on the interpreted NLP functions (`VINE_NLP_CODEGEN=off`: "
        "a first run, while the compiler works) and once on the compiled ones (`on`: every later run), each in its own process; "
        "the largest difference of any run's theta, lambda or segment lengths between the two (goal: 1e-6), and the exit status "
        "of each." + (f" Wall time of the runs: interpreted {walls[0]:.0f} s, compiled {walls[1]:.0f} s." if np.all(np.isfinite(walls)) else ""),
        table(("problems", "compared", "over 1e-6", "largest difference", "exit 0 (both alike)"), rows),
        f"Problems whose exit, runs or error differ: {len(unlike)}" + (":\n\n" + "\n".join(lines) if lines else "."),
    )


if __name__ == "__main__":
    main()
