"""Faults: a full disk, a read-only filesystem, no permission, a directory in the way, a worker
process killed mid-item (local pool and dask), two sweeps into one directory.

Small filesystems are tmpfs mounts (needs root and mount permission; skipped with the reason
otherwise). Every wait is for an event (a hold marker, a claim file, a process exit), bounded
only so that a broken program fails instead of hanging: nothing assumes how long a solve takes.
"""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from holdpoint import finish, hold_env, release, spawn, wait_for_claim, wait_for_marker
from texts import TINY_TREFOIL

from vine_nlp.errors import InputError
from vine_nlp.front import sweep as sw
from vine_nlp.io.archive import OutputError, load_archive, write_archive
from vine_nlp.io.problem_file import load_sweep

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems/bezier-c.toml"

BASE = TINY_TREFOIL


def _sweep_file(folder: Path, count: int = 4) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.toml").write_text(BASE)
    scales = ", ".join(str(3 + 0.5 * k) for k in range(count))
    (folder / "sweep.toml").write_text(f'name = "t"\nbase = "base.toml"\nmethods = ["nlp"]\n[grid]\n"target.scale.2" = [{scales}]\n')
    return folder / "sweep.toml"


def _run(*args, env=None):
    return subprocess.run([sys.executable, "-m", "vine_nlp", *map(str, args)], capture_output=True, text=True, env=env)


def _one_error_line(stderr: str, start: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(start), stderr
    assert "Traceback" not in stderr
    return lines[0]


def _rows(path: Path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# ---------------------------------------------------------------- small filesystems


@pytest.fixture
def tmpfs(tmp_path):
    """mount(size, ro=False) -> a fresh tmpfs directory; unmounted at the end."""
    mounted = []

    def mount(size: str, ro: bool = False) -> Path:
        if sys.platform != "linux" or os.geteuid() != 0:
            pytest.skip("mounting a tmpfs needs root on Linux")
        where = tmp_path / f"fs{len(mounted)}"
        where.mkdir()
        opts = f"size={size}" + (",ro" if ro else "")
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], capture_output=True, text=True)
        if r.returncode != 0:
            pytest.skip(f"mount -t tmpfs not allowed here: {r.stderr.strip()}")
        mounted.append(where)
        return where

    yield mount
    for where in reversed(mounted):
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def _fill(where: Path, leave: int) -> Path:
    """A file that takes all of ``where``'s free space but ``leave`` bytes."""
    st = os.statvfs(where)
    free = st.f_bavail * st.f_frsize
    filler = where / "filler"
    with open(filler, "wb") as fh:
        fh.write(b"\0" * max(0, free - leave))
    return filler


def test_design_on_a_full_disk_is_one_line_and_leaves_nothing(tmpfs):
    fs = tmpfs("32k")  # smaller than the archive (58 kB)
    out = fs / "d.h5"
    r = _run("design", PROBLEM, "-o", out)
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {out}: write: cannot write (No space left on device)")
    assert list(fs.iterdir()) == []  # no archive, no temporary file


def test_plot_on_a_filling_disk_is_one_line(tmpfs, capsys):
    from vine_nlp.front.cli import main

    fs = tmpfs("256k")
    _fill(fs, 100_000)  # the archive fits, the figure does not
    out, fig = fs / "f.h5", fs / "f.png"
    assert main(["forward", str(ROOT / "problems/three-section-helix.toml"), "-o", str(out), "--plot", str(fig)]) == 2
    err = capsys.readouterr().err
    _one_error_line(err, f"error: {fig}: write: cannot write (No space left on device)")
    assert sorted(p.name for p in fs.iterdir()) == ["filler"]  # a run's outputs: all or none


def test_read_only_filesystem_is_one_line(tmpfs):
    fs = tmpfs("1m", ro=True)
    r = _run("design", PROBLEM, "-o", fs / "d.h5")
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {fs / 'd.h5'}: write: cannot write (Read-only file system)")


def test_directory_in_the_way_is_one_line(tmp_path):
    (tmp_path / "d.h5").mkdir()
    r = _run("design", PROBLEM, "-o", tmp_path / "d.h5", "--force")
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {tmp_path / 'd.h5'}: write: cannot write (is a directory)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.h5"]


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores file permissions: no EACCES to provoke")
def test_no_permission_is_one_line(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        r = _run("design", PROBLEM, "-o", locked / "d.h5")
    finally:
        locked.chmod(0o700)
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {locked / 'd.h5'}: write: cannot write (Permission denied)")


def test_write_errors_are_output_errors_and_leave_nothing(tmp_path, tmpfs):
    made = tmp_path / "f.h5"
    assert _run("forward", ROOT / "problems/three-section-helix.toml", "-o", made).returncode == 0
    archive = load_archive(made)
    (tmp_path / "dir.h5").mkdir()
    with pytest.raises(OutputError) as info:
        write_archive(tmp_path / "dir.h5", archive)
    assert isinstance(info.value, InputError) and isinstance(info.value, OSError)
    assert str(info.value) == f"{tmp_path / 'dir.h5'}: write: cannot write (is a directory); nothing was written"
    fs = tmpfs("16k")
    with pytest.raises(OutputError, match="No space left on device") as info:
        write_archive(fs / "a.h5", archive)
    assert info.value.errno == 28
    assert list(fs.iterdir()) == []


@pytest.mark.slow
def test_sweep_on_a_full_disk_keeps_finished_items_and_resumes(tmpfs, tmp_path):
    fs = tmpfs("512k")
    path = _sweep_file(tmp_path / "in", count=4)
    out = fs / "out"
    out.mkdir()
    filler = _fill(fs, 100_000)  # room for about two archives of ~41 kB, not four
    r = _run("sweep", path, "-o", out, "--workers", "1")
    assert r.returncode == 2, r.stderr
    line = _one_error_line(r.stderr, f"error: {out}{os.sep}")  # an archive or the summary
    assert "No space left on device" in line and "run the same command again to resume" in line
    kept = sorted(p.name for p in out.glob("*.h5"))
    assert 1 <= len(kept) < 4
    for p in out.glob("*.h5"):
        load_archive(p)  # whole archives only
    assert not list(out.glob(".*.tmp"))
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("*.h5")}

    filler.unlink()  # space is back: the same command finishes the rest
    again = _run("sweep", path, "-o", out, "--workers", "1")
    assert again.returncode == 0, again.stderr
    assert f"{4 - len(kept)} solved, {len(kept)} skipped" in again.stdout
    assert len(list(out.glob("*.h5"))) == 4
    assert {n: (out / n).stat().st_mtime_ns for n in mtimes} == mtimes
    assert sorted(row["item"] for row in _rows(out / "summary.csv")) == [f"t-000{k}" for k in range(4)]


def test_sweep_stops_at_an_unwritable_archive_and_resumes(tmp_path):
    path = _sweep_file(tmp_path / "in", count=3)
    out = tmp_path / "out"
    (out / "t-0001.h5").mkdir(parents=True)  # a directory where item 1's archive should go
    with pytest.raises(OutputError) as info:
        sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    assert info.value.file == str(out / "t-0001.h5") and info.value.key == "write"
    assert info.value.reason == ("cannot write (is a directory); the sweep stopped, finished items kept: 1; "
                                 "run the same command again to resume")
    assert sorted(p.name for p in out.glob("*.h5")) == ["t-0000.h5", "t-0001.h5"]  # item 0 and the directory
    assert [row["item"] for row in _rows(out / "summary.csv")] == ["t-0000"]
    assert not list(out.glob(".*.tmp"))
    (out / "t-0001.h5").rmdir()
    again = sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    assert (again.done, again.skipped, again.failed) == (2, 1, 0)


# ---------------------------------------------------------------- workers killed mid-item


@pytest.mark.slow
def test_local_worker_killed_mid_item_is_run_again(tmp_path):
    path = _sweep_file(tmp_path / "in", count=2)
    out = tmp_path / "out"
    env, fifo = hold_env(tmp_path / "hold", "solve")
    proc = spawn(["sweep", path, "-o", out, "--workers", "2"], env)
    worker = wait_for_claim(fifo)  # a worker process is inside an item
    assert worker != proc.pid
    os.kill(worker, signal.SIGKILL)
    rc, err = finish(proc)
    assert rc == 0, err
    assert "Traceback" not in err
    assert len(list(out.glob("*.h5"))) == 2  # the killed item ran again in a fresh pool
    assert [row["status"] for row in _rows(out / "summary.csv")] == ["optimal"] * 2


@pytest.mark.slow
def test_dask_worker_killed_mid_item_is_run_again(tmp_path, monkeypatch):
    distributed = pytest.importorskip("dask.distributed")
    path = _sweep_file(tmp_path / "in", count=2)
    out = tmp_path / "out"
    env, fifo = hold_env(tmp_path / "hold", "solve")
    monkeypatch.setenv("VINE_NLP_TEST_HOLD", env["VINE_NLP_TEST_HOLD"])  # the nannies start workers with it
    killed = []

    def kill_when_held():
        pid = wait_for_claim(fifo)
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        killer = threading.Thread(target=kill_when_held, daemon=True)
        killer.start()
        report = sw.run_sweep(load_sweep(path), out, scheduler=cluster.scheduler_address, progress=False)
        killer.join(timeout=60)
    assert killed and killed[0] != os.getpid()
    # the scheduler gives the lost task to a fresh worker: nothing lost, nothing failed
    assert (report.done, report.failed) == (2, 0), report.failures
    assert len(list(out.glob("*.h5"))) == 2


def _children(pid: int) -> list[int]:
    """Pids of the live child processes of ``pid`` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # ended meanwhile
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _wait_gone(pidfds: dict, deadline_s: float = 60.0) -> list[int]:
    """Wait (on the event, bounded) until each process of ``pidfds`` ended; the pids still alive."""
    import select

    end = time.monotonic() + deadline_s
    alive = dict(pidfds)
    while alive and time.monotonic() < end:
        ready, _, _ = select.select(list(alive.values()), [], [], max(0.0, end - time.monotonic()))
        for pid in [p for p, fd in alive.items() if fd in ready]:
            os.close(alive.pop(pid))
    return list(alive)


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "pidfd_open"), reason="waits on pidfds (Linux)")
def test_workers_die_with_a_killed_sweep(tmp_path):
    # issue 34: after kill -9 of the sweep its pool workers lived on for good, blocked on a pipe
    path = _sweep_file(tmp_path / "in", count=4)
    env, fifo = hold_env(tmp_path / "hold", "solve")
    proc = spawn(["sweep", path, "-o", tmp_path / "out", "--workers", "2"], env)
    held = wait_for_claim(fifo)  # a worker is inside an item, the other one alive too
    workers = _children(proc.pid)
    assert held in workers and len(workers) == 2
    pidfds = {pid: os.pidfd_open(pid) for pid in workers}
    proc.kill()
    proc.wait()
    assert _wait_gone(pidfds) == []
    # nothing finished is lost: the same command skips every archive the killed sweep left and does the rest
    out = tmp_path / "out"
    kept = {p.name: p.stat().st_mtime_ns for p in out.glob("*.h5")}
    again = _run("sweep", path, "-o", out, "--workers", "2")
    assert again.returncode == 0, again.stderr
    assert f"{4 - len(kept)} solved, {len(kept)} skipped" in again.stdout
    assert {n: (out / n).stat().st_mtime_ns for n in kept} == kept and len(list(out.glob("*.h5"))) == 4
    assert not list(out.glob(".*.tmp"))


def test_a_worker_ends_when_the_parents_pipe_closes():
    # the second way a worker notices its parent is gone (where there is no parent-death signal)
    import multiprocessing as mp

    from vine_nlp.front.sweep import executors

    r, w = os.pipe()

    def worker():
        executors._worker_init(close_fds=(w,), watch_fd=r)  # as a forked pool worker starts
        threading.Event().wait()

    child = mp.get_context("fork").Process(target=worker)
    child.start()
    os.close(r)
    assert child.is_alive()
    os.close(w)  # as when the parent dies: the last write end is gone
    child.join(timeout=60)
    assert child.exitcode == 1


# ---------------------------------------------------------------- one sweep per directory


def test_second_sweep_into_a_locked_directory_is_refused(tmp_path):
    path = _sweep_file(tmp_path / "in")
    out = tmp_path / "out"
    out.mkdir()
    lock = sw.DirectoryLock(out)
    lock.acquire()  # stands for a running sweep (flock: another open file, even in this process)
    try:
        with pytest.raises(InputError, match=f"another sweep \\(pid {os.getpid()}\\) is writing into this directory"):
            sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
        assert not list(out.glob("*.h5")) and not (out / "summary.csv").exists()
    finally:
        lock.release()
    report = sw.run_sweep(load_sweep(path), out, workers=1, progress=False)  # free again
    assert report.done == 4


@pytest.mark.slow
def test_two_sweep_commands_into_one_directory(tmp_path):
    path = _sweep_file(tmp_path / "in")
    out = tmp_path / "out"
    env, fifo = hold_env(tmp_path / "hold", "sweep-item")
    first = spawn(["sweep", path, "-o", out, "--workers", "1"], env)
    pid, before = wait_for_marker(first, "sweep-item")  # running, holding the lock
    second = _run("sweep", path, "-o", out, "--workers", "1")
    assert second.returncode == 2
    _one_error_line(second.stderr, f"error: {out}: -o: another sweep (pid {first.pid}) is writing into this directory")
    release(fifo)
    rc, err = finish(first, before)
    assert rc == 0, err
    assert len(list(out.glob("*.h5"))) == 4


# ---------------------------------------------------------------- huge inputs

FORWARD_1E5 = """\
name = "long"
units = "cm"
[tube]
diameter = 2.43
[routing]
length = {length}
segment_length = 1.0
theta_deg = 5
lambda = 0.7
"""
MEMORY_LIMIT = 1 << 30  # the README's figure for a forward run of MAX_SEGMENTS segments


def _limited(limit_bytes):
    def preexec():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    return preexec


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS is how the memory limit is held here")
def test_routing_of_1e5_segments_runs_within_1_gb(tmp_path):
    from vine_nlp.io import limits

    problem = tmp_path / "long.toml"
    problem.write_text(FORWARD_1E5.format(length=float(limits.MAX_SEGMENTS)))
    out = tmp_path / "long.h5"
    # one BLAS thread: thread pools reserve address space per core, which says nothing about the run
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-m", "vine_nlp", "forward", str(problem), "-o", str(out)],
                       capture_output=True, text=True, preexec_fn=_limited(MEMORY_LIMIT), env=env)
    assert r.returncode == 0, r.stderr
    assert load_archive(out).runs["forward"].routing.segments == limits.MAX_SEGMENTS  # and it loads again
    shown = subprocess.run([sys.executable, "-m", "vine_nlp", "show", str(out)], capture_output=True, text=True,
                           preexec_fn=_limited(MEMORY_LIMIT), env=env)
    assert shown.returncode == 0 and f"segments    {limits.MAX_SEGMENTS}" in shown.stdout


def test_routing_beyond_the_segment_limit_is_refused_in_one_line(tmp_path):
    problem = tmp_path / "longer.toml"
    problem.write_text(FORWARD_1E5.format(length=1e6))
    r = _run("forward", problem, "-o", tmp_path / "x.h5")
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {problem}: routing.segment_length: gives more than 100000 segments")


def test_target_of_1e6_samples_is_refused_in_one_line(tmp_path):
    problem = tmp_path / "big.toml"
    problem.write_text((ROOT / "problems/trefoil-m4.toml").read_text().replace("samples = 400", "samples = 1000000"))
    r = _run("design", problem, "-o", tmp_path / "x.h5")
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {problem}: target.samples: must be an integer <= 100000")


def test_archive_with_a_1e6_point_target_is_refused_in_one_line(tmp_path):
    import h5py

    from vine_nlp.io import limits

    path = tmp_path / "big.h5"
    assert _run("forward", ROOT / "problems/three-section-helix.toml", "-o", path).returncode == 0
    with h5py.File(path, "a") as h5:
        h5.create_dataset("target/points", shape=(10**6, 3), dtype=float, chunks=(4096, 3), fillvalue=0.5)
    r = _run("show", path)
    assert r.returncode == 2
    _one_error_line(r.stderr, f"error: {path}: /target/points: 3000000 values, more than the limit of "
                              f"{3 * limits.MAX_TARGET_POINTS} (vine_nlp.io.limits.MAX_TARGET_POINTS)")


def test_a_csv_target_beyond_the_point_limit_is_refused_in_one_line(tmp_path, capsys):
    from vine_nlp.front.cli import main
    from vine_nlp.io import limits

    n = limits.MAX_TARGET_POINTS + 1
    t = np.linspace(0.0, 1.0, n)
    np.savetxt(tmp_path / "big.csv", np.column_stack([t, np.sin(t), np.zeros(n)]), delimiter=",", fmt="%.6f")
    (tmp_path / "p.toml").write_text('[tube]\ndiameter = 2\n[target]\ncurve = "points"\nfile = "big.csv"\n')
    out = tmp_path / "o.h5"
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {tmp_path / 'big.csv'}: values: ") and "MAX_TARGET_POINTS" in err[0]
    assert not out.exists()
