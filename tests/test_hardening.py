"""Hardening: interruption leaves nothing partial, runs are deterministic, bad input never writes."""

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from holdpoint import finish, hold_env, release, spawn, wait_for_marker

from vine_nlp.front.cli import main
from vine_nlp.io.archive import load_archive

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_design_leaves_no_archive(tmp_path, sig):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "d.h5"
    # held after its first solve (event: the marker line), so the greedy is certainly mid-way
    env, fifo = hold_env(tmp_path / "hold", "solve")
    proc = spawn(["design", ROOT / "problems/trefoil-m4.toml", "-o", out, "--method", "greedy"], env)
    pid, before = wait_for_marker(proc, "solve")
    assert pid == proc.pid
    proc.send_signal(sig)
    rc, err = finish(proc, before)
    assert rc == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert list(out_dir.iterdir()) == []  # no archive, no temporary file


def test_held_design_released_finishes(tmp_path):
    # the hold point itself changes nothing: released, the run completes and writes its archive
    out = tmp_path / "d.h5"
    env, fifo = hold_env(tmp_path / "hold", "solve")
    proc = spawn(["design", ROOT / "problems/bezier-c.toml", "-o", out], env)
    wait_for_marker(proc, "solve")
    release(fifo)
    rc, err = finish(proc)
    assert rc == 0, err
    assert load_archive(out).runs["nlp"].status == "optimal"


def test_same_problem_same_design(tmp_path):
    src = (ROOT / "problems/bezier-c.toml").read_text().replace("lookahead = 4", "lookahead = 4\nstarts = 3\nseed = 11")
    p = tmp_path / "p.toml"
    p.write_text(src)
    runs = []
    for k in range(2):
        out = tmp_path / f"o{k}.h5"
        assert main(["design", str(p), "-o", str(out)]) == 0
        runs.append(load_archive(out).runs["nlp"])
    a, b = runs
    for field in ("theta", "lam", "length", "initial_pose"):
        np.testing.assert_allclose(getattr(a.routing, field), getattr(b.routing, field), atol=1e-9, rtol=0)
    assert a.stats["best_start"] == b.stats["best_start"]


BAD = [
    ("[tube]\ndiameter = 2\n[target]\ncurve = 'trefoil'\nsamples = 2\n", "target.samples"),
    ("[tube]\ndiameter = 2\n[target]\ncurve = 'spiral'\n", "target.curve"),
    ("[tube]\ndiametr = 2\n[target]\ncurve = 'trefoil'\n", "tube.diametr"),
    ("[tube]\ndiameter = 2\n[target]\ncurve = 'trefoil'\n[actuator]\nlambda_min = 0\n", "actuator.lambda_min"),
    ("[tube]\ndiameter = 2\n[target]\ncurve = 'trefoil'\n[actuator]\ntheta_max_deg = 90\n", "actuator.theta_max_deg"),
    ("[tube]\ndiameter = 2\n[routing]\nlength = 5\nsegment_length = 1\ntheta = 's.__class__'\nlambda = 0.5\n", "routing.theta"),
    ("[tube]\ndiameter = 2\n[routing]\nlength = 5\nsegment_length = 1\ntheta = '__import__(\"os\")'\nlambda = 0.5\n", "routing.theta"),
    ("[tube\ndiameter = 2\n", "line 1"),
]


@pytest.mark.parametrize("text,key", BAD)
def test_bad_problem_files_exit_2_with_one_line(tmp_path, capsys, text, key):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    out = tmp_path / "o.h5"
    cmd = "forward" if "[routing]" in text else "design"
    assert main([cmd, str(p), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {p}: {key}: ")
    assert not out.exists()


def _small_sweep(tmp_path, count=6):
    base = tmp_path / "base.toml"
    base.write_text((ROOT / "problems/trefoil-m4.toml").read_text().replace("samples = 400", "samples = 81").replace("points_per_segment = 10", "points_per_segment = 5"))
    sw = tmp_path / "s.toml"
    scales = ", ".join(str(2 + k) for k in range(count))
    sw.write_text(f'name = "s"\nbase = "base.toml"\nmethods = ["nlp"]\n[grid]\n"target.scale.2" = [{scales}]\n')
    return sw


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_sweep_keeps_finished_items_and_resumes(tmp_path, sig):
    import csv

    sw = _small_sweep(tmp_path, count=3)
    out = tmp_path / "out"
    # held once the first item's archive and the summary are on disk (event: the marker line)
    env, _ = hold_env(tmp_path / "hold", "sweep-item")
    proc = spawn(["sweep", sw, "-o", out, "--workers", "1"], env)
    wait_for_marker(proc, "sweep-item")
    proc.send_signal(sig)
    rc, err = finish(proc)
    assert rc == 130, err
    assert "interrupted" in err and "Traceback" not in err
    finished = sorted(p.stem for p in out.glob("*.h5"))
    assert finished == ["s-0000"]  # held right after the first item: exactly one is finished
    load_archive(out / "s-0000.h5")  # complete and valid
    assert not list(out.glob(".*.tmp"))
    with open(out / "summary.csv", newline="") as fh:
        assert sorted(row["item"] for row in csv.DictReader(fh)) == finished
    # the same command resumes and redoes nothing finished
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("*.h5")}
    done = subprocess.run([sys.executable, "-m", "vine_nlp", "sweep", str(sw), "-o", str(out), "--workers", "1"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "2 solved, 1 skipped" in done.stdout
    assert len(list(out.glob("*.h5"))) == 3
    assert all((out / name).stat().st_mtime_ns == t for name, t in mtimes.items())


DEEP = ".".join(["a"] * 30_000)
HOSTILE_SWEEPS = {  # issue 34: each hung, ran out of memory or ended in a traceback (leaving summary.csv and the lock)
    "fifo base": ('base = "fifo.toml"\n', "not a regular file"),
    "/dev/zero base": ('base = "/dev/zero"\n', "not a regular file"),
    "NUL in a grid value": ('base = "base.toml"\n[grid]\nunits = ["c\\u0000m"]\n', "printable"),
    "NUL in a grid key": ('base = "base.toml"\n[grid]\n"target.sc\\u0000ale.0" = [2, 3]\n', "printable"),
    "30 000-level dotted key": (f'base = "base.toml"\n[grid]\n{DEEP} = [1]\n', "more than 32"),
    "30 000-part quoted key": (f'base = "base.toml"\n[grid]\n"{DEEP}" = [1]\n', "more than 32|at most 255 characters"),
}


@pytest.mark.parametrize("case", list(HOSTILE_SWEEPS))
def test_hostile_sweep_files_are_one_error_line_and_leave_nothing(tmp_path, case):
    import os
    import re

    text, reason = HOSTILE_SWEEPS[case]
    _small_sweep(tmp_path)
    os.mkfifo(tmp_path / "fifo.toml")
    sweep = tmp_path / "hostile.toml"
    sweep.write_text('name = "h"\n' + text)
    out = tmp_path / "out"
    # the timeout only keeps a hang from hanging the suite
    r = subprocess.run([sys.executable, "-m", "vine_nlp", "sweep", str(sweep), "-o", str(out)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"error: {sweep}: ") and r.stderr.count("\n") == 1, r.stderr[:500]
    assert re.search(reason, r.stderr)
    assert r.stderr[:-1].isprintable()  # no NUL or other control character reaches the terminal
    assert not out.exists()  # no summary.csv, no lock
