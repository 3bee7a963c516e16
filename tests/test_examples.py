"""Every tutorial in examples/ runs end to end and its numbers meet examples/expected/<name>.json.

Each example writes its files and ``summary.json`` into ``<out>/<name>/``. The expectation
file names the files that must exist (and be what their suffix says) and bounds on the
summary's numbers: ``equal`` (exact), ``close`` ([value, absolute tolerance]), ``at_most``,
``at_least``, and ``same`` ([key, other key, tolerance]: two numbers the example computed
two ways). Scripts run in a subprocess; notebooks are executed by nbclient. Its tutorial's blocks
marked ``<!-- printed by: python3 examples/<script> -->`` must show what it printed (tests/printed.py).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import printed
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
EXPECTED = EXAMPLES / "expected"
TIMEOUT_S = 240

# the first bytes of each kind of output file
SIGNATURES = {".pdf": b"%PDF", ".png": b"\x89PNG", ".h5": b"\x89HDF", ".svg": b"<", ".html": b"<"}


def _expectations():
    params = []
    for path in sorted(EXPECTED.glob("*.json")):
        spec = json.loads(path.read_text())
        marks = [pytest.mark.slow] if spec.get("slow") else []
        params.append(pytest.param(path.stem, spec, id=path.stem, marks=marks))
    return params


def test_every_example_has_expectations():
    """No example goes untested, and no expectation names an example that is gone."""
    examples = {p.stem for p in EXAMPLES.glob("[0-9][0-9]_*.py")} | {p.stem for p in EXAMPLES.glob("[0-9][0-9]_*.ipynb")}
    expected = {p.stem for p in EXPECTED.glob("*.json")}
    assert examples == expected
    for name in expected:
        spec = json.loads((EXPECTED / f"{name}.json").read_text())
        script = spec.get("script") or spec.get("notebook")
        assert Path(script).stem == name and (EXAMPLES / script).is_file()


def _run_script(script: Path, out: Path) -> tuple[str, str]:
    """(stdout, stderr) of the example."""
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0")
    proc = subprocess.run(
        [sys.executable, str(script), "--out", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 0, f"{script.name} exited {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    assert "Traceback" not in proc.stderr
    return proc.stdout, proc.stderr


def _run_notebook(notebook: Path, out: Path, monkeypatch) -> tuple[str, str]:
    """(stdout, stderr) of the executed notebook's cells."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("VINE_NLP_EXAMPLES_OUT", str(out))  # the kernel inherits the environment
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(notebook, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=TIMEOUT_S, kernel_name="python3", resources={"metadata": {"path": str(EXAMPLES)}})
    client.execute()  # raises CellExecutionError, with the cell and its traceback, if a cell fails
    streams = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "stream"]
    return tuple("".join(o.text for o in streams if o.name == name) for name in ("stdout", "stderr"))


def _check(summary: dict, spec: dict) -> None:
    for key, want in spec.get("equal", {}).items():
        assert summary[key] == want, f"{key}: {summary[key]!r} != {want!r}"
    for key, (want, tol) in spec.get("close", {}).items():
        got = summary[key]
        got, want = (got, want) if isinstance(want, list) else ([got], [want])
        assert len(got) == len(want), key
        for g, w in zip(got, want):
            assert math.isfinite(g) and abs(g - w) <= tol, f"{key}: {g} not within {tol} of {w}"
    for key, most in spec.get("at_most", {}).items():
        assert math.isfinite(summary[key]) and summary[key] <= most, f"{key}: {summary[key]} > {most}"
    for key, least in spec.get("at_least", {}).items():
        assert math.isfinite(summary[key]) and summary[key] >= least, f"{key}: {summary[key]} < {least}"
    for a, b, tol in spec.get("same", []):
        assert abs(summary[a] - summary[b]) <= tol * max(1.0, abs(summary[b])), f"{a} {summary[a]} != {b} {summary[b]}"


@pytest.mark.parametrize(("name", "spec"), _expectations())
def test_example(name, spec, tmp_path, monkeypatch):
    if "notebook" in spec:
        stdout, stderr = _run_notebook(EXAMPLES / spec["notebook"], tmp_path, monkeypatch)
        command = f"examples/{spec['notebook']}"
    else:
        stdout, stderr = _run_script(EXAMPLES / spec["script"], tmp_path)
        command = f"python3 examples/{spec['script']}"
    out = tmp_path / name
    summary = json.loads((out / "summary.json").read_text())
    for rel in spec["files"]:
        path = out / rel
        assert path.is_file() and path.stat().st_size > 0, f"{rel} missing or empty"
        signature = SIGNATURES.get(path.suffix)
        if signature is not None:
            assert path.read_bytes()[: len(signature)] == signature, f"{rel} is not a {path.suffix} file"
    assert sorted(summary["files"]) == sorted(spec["files"])
    _check(summary, spec)
    # its tutorial shows what it printed (tests/printed.py): numbers within the stated tolerance, its warnings
    shown = [b for b in printed.blocks() if b.command == command]
    assert shown, f"no documentation block is marked <!-- printed by: {command} -->"
    problems = [p for b in shown for p in printed.check(b, stdout, stderr)]
    problems += [f"printed on stderr, not shown in the tutorial: {line!r}" for line in printed.unshown(stderr, shown)]
    assert not problems, "\n".join(problems)
