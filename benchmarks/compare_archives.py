"""Every bundled problem's archive against a reference made the same way from another commit (behaviour unchanged).

    python3 benchmarks/compare_archives.py REF_DIR [--only NAME ...] [--out DIR]

REF_DIR holds ``<problem>.h5`` made by ``vine-nlp design|fit|forward problems/<problem>.toml -o REF_DIR/<problem>.h5``
run from /tmp with ``VINE_NLP_CODEGEN=off``. Each problem is run again the same way with this checkout's
package, and the two archives are compared: the same groups, datasets and attributes; every dataset and
number to ``--tol`` (default 1e-9; relative to the larger of 1 and the value); texts equal. Timings
(``*_time_s``) are left out. One line per problem; exit 1 where any differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
COMMAND = {"forward": "forward", "fit": "fit"}  # any other kind: design


def _flat(f: h5py.File) -> dict:
    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = obj[()]
        for k, v in obj.attrs.items():
            if not k.endswith("_time_s"):
                out[f"{name}@{k}"] = v

    f.visititems(visit)
    return out


def differences(ref: Path, new: Path, tol: float) -> list[str]:
    """What differs between two archives (empty: the same)."""
    with h5py.File(ref) as a, h5py.File(new) as b:
        fa, fb = _flat(a), _flat(b)
    out = [f"only in reference: {k}" for k in sorted(fa.keys() - fb.keys())]
    out += [f"only in new: {k}" for k in sorted(fb.keys() - fa.keys())]
    for k in sorted(fa.keys() & fb.keys()):
        x, y = fa[k], fb[k]
        if isinstance(x, (bytes, str)) or isinstance(y, (bytes, str)):
            if x != y and not k.endswith("@source"):
                out.append(f"{k}: {x!r} != {y!r}")
            continue
        x, y = np.asarray(x), np.asarray(y)
        if x.shape != y.shape:
            out.append(f"{k}: shape {x.shape} != {y.shape}")
        elif x.dtype.kind in "fiub" and y.dtype.kind in "fiub":
            xf, yf = x.astype(float), y.astype(float)
            both = np.isnan(xf) & np.isnan(yf)
            err = np.where(both, 0.0, np.abs(xf - yf) / np.maximum(1.0, np.abs(xf)))
            if err.size and not np.nanmax(err) <= tol:
                out.append(f"{k}: differs by {np.nanmax(err):.3g}")
        elif not np.array_equal(x, y):
            out.append(f"{k}: {x!r} != {y!r}")
    return out


def run(name: str, kind: str, out: Path) -> int:
    env = dict(os.environ, VINE_NLP_CODEGEN="off", PYTHONPATH=str(ROOT / "src"))
    env.setdefault("VINE_NLP_CACHE_DIR", tempfile.mkdtemp(prefix="vine-compare-"))
    cmd = [sys.executable, "-m", "vine_nlp", COMMAND.get(kind, "design"), str(ROOT / "problems" / f"{name}.toml"), "-o", str(out)]
    return subprocess.run(cmd, cwd="/tmp", env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ref", type=Path)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--tol", type=float, default=1e-9)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "src"))
    from vine_nlp.io.problems import load_problem

    out_dir = args.out or Path(tempfile.mkdtemp(prefix="vine-compare-"))
    out_dir.mkdir(parents=True, exist_ok=True)
    bad = 0
    for ref in sorted(args.ref.glob("*.h5")):
        name = ref.stem
        if args.only and name not in args.only:
            continue
        kind = load_problem(ROOT / "problems" / f"{name}.toml").kind
        new = out_dir / f"{name}.h5"
        code = run(name, kind, new)
        diff = [f"exit {code}"] if code or not new.exists() else differences(ref, new, args.tol)
        bad += bool(diff)
        print(f"{name}: {'same' if not diff else 'DIFFERS'}" + "".join(f"\n    {d}" for d in diff[:12]), flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
