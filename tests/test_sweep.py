"""Design sweeps: one archive per item, the summary, resume, failures, Ctrl-C, dask, crashes."""

from __future__ import annotations

import csv
import dataclasses
import os

import numpy as np
import pytest
from texts import TINY_TREFOIL

from vine_nlp.errors import InputError
from vine_nlp.front import sweep as sw
from vine_nlp.front.sweep import executors
from vine_nlp.io.archive import load_archive
from vine_nlp.io.problem_file import ProblemFile, load_sweep

BASE = TINY_TREFOIL + 'hessian = "exact"  # one solver variant per worker: the build count below is exact\n'

COLUMNS = ["item", "target.scale.0", "target.scale.1", "method", "status", "rmse", "max_error", "solve_time_s"]


def _write_sweep(folder, methods=("nlp",), base=BASE, name="tiny"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.toml").write_text(base)
    listed = ", ".join(f'"{m}"' for m in methods)
    (folder / "sweep.toml").write_text(
        f'name = "{name}"\nbase = "base.toml"\nmethods = [{listed}]\n'
        '[grid]\n"target.scale.0" = [3, 4]\n"target.scale.1" = [3, 5]\n'
    )
    return folder / "sweep.toml"


def _read_csv(path):
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        return header, [dict(zip(header, row)) for row in reader]


def _h5_files(folder):
    return sorted(p.name for p in folder.glob("*.h5"))


def _mtimes(folder):
    return {p.name: p.stat().st_mtime_ns for p in folder.glob("*.h5")}


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """The tiny sweep (4 items) solved once by 2 local worker processes."""
    root = tmp_path_factory.mktemp("local")
    path = _write_sweep(root / "in")
    out = root / "out" / "nested"  # does not exist: run_sweep creates it
    report = sw.run_sweep(load_sweep(path), out, workers=2, progress=False)
    return path, out, report


def test_local_run_writes_one_archive_per_item_and_the_summary(local_run):
    path, out, report = local_run
    items = [item for item, _, _ in load_sweep(path).items()]
    assert (report.done, report.skipped, report.failed, report.total) == (4, 0, 0, 4)
    assert report.created_dir and report.executor == "2 local worker processes"
    assert _h5_files(out) == sorted(f"{i}.h5" for i in items)
    header, rows = _read_csv(out / "summary.csv")
    assert header[: len(COLUMNS)] == COLUMNS  # the spec's columns, in order; extras after them
    assert header[len(COLUMNS):] == ["iterations", "units", "error"]
    assert [(r["item"], r["method"]) for r in rows] == [(i, "nlp") for i in items]
    assert [(r["target.scale.0"], r["target.scale.1"]) for r in rows] == [("3", "3"), ("3", "5"), ("4", "3"), ("4", "5")]
    for row in rows:
        a = load_archive(out / f"{row['item']}.h5")
        run = a.runs["nlp"]
        assert a.name == row["item"] and list(a.runs) == ["nlp"]
        assert float(row["rmse"]) == run.metrics["rmse"]  # full precision, not rounded
        assert float(row["max_error"]) == run.metrics["max_error"]
        assert float(row["solve_time_s"]) == run.solve_time_s
        assert row["status"] == run.status == "optimal"
        assert int(row["iterations"]) == run.iterations and row["units"] == "cm" and row["error"] == ""
        assert "item tiny-0" in a.source  # the archive says which grid point it is
    assert (out / "summary.png").stat().st_size > 0
    text = sw.format_report(report)
    assert "4 solved, 0 skipped" in text and "(created)" in text and "nlp: RMSE mean" in text


_TIMES = ("solve_time_s", "build_time_s", "ipopt_time_s", "search_time_s")  # what differs between two solves of one problem


def test_a_workers_archive_is_what_vine_nlp_design_writes_for_the_item(local_run, tmp_path):
    from vine_nlp.front.cli import main

    _, out, _ = local_run
    item = "tiny-0003"  # target.scale.0 = 4, target.scale.1 = 5
    problem = tmp_path / "item.toml"
    problem.write_text(BASE.replace('name = "tiny-trefoil"', f'name = "{item}"').replace("[4.0, 4.0, 4.0]", "[4, 5, 4.0]"))
    assert main(["design", str(problem), "-o", str(tmp_path / "one.h5")]) == 0
    swept, one = load_archive(out / f"{item}.h5"), load_archive(tmp_path / "one.h5")
    assert (swept.name, swept.kind, swept.units, swept.diameter) == (one.name, one.kind, one.units, one.diameter)
    assert swept.source == BASE + f"\n# sweep 'tiny' item {item}: target.scale.0 = 4, target.scale.1 = 5\n"
    assert list(swept.runs) == list(one.runs) == ["nlp"]
    a, b = swept.runs["nlp"], one.runs["nlp"]
    assert (a.status, a.iterations, a.metrics) == (b.status, b.iterations, b.metrics)
    assert {k: v for k, v in a.stats.items() if k not in _TIMES} == {k: v for k, v in b.stats.items() if k not in _TIMES}
    for x, y in ((swept.target, one.target), (a.routing.theta, b.routing.theta), (a.routing.lam, b.routing.lam),
                 (a.routing.length, b.routing.length), (a.routing.initial_pose, b.routing.initial_pose),
                 (a.phi, b.phi), (a.shape.center, b.shape.center), (a.shape.outer, b.shape.outer)):
        assert np.array_equal(x, y)


def test_long_lived_workers_build_each_solver_once(local_run):
    _, out, _ = local_run
    builds = [load_archive(p).runs["nlp"].stats["build_time_s"] for p in out.glob("*.h5")]
    # two worker processes, one structure: at most one build in each, the other items reuse it
    assert 1 <= sum(b > 0 for b in builds) <= 2


def test_rerun_skips_finished_items_and_keeps_their_archives(local_run):
    path, out, first = local_run
    before = _mtimes(out)
    _, rows_before = _read_csv(out / "summary.csv")
    report = sw.run_sweep(load_sweep(path), out, workers=2, progress=False)
    assert (report.done, report.skipped, report.failed) == (0, 4, 0)
    assert report.executor == ""  # nothing to solve: no pool started
    assert _mtimes(out) == before
    _, rows = _read_csv(out / "summary.csv")
    assert rows == rows_before  # rows rebuilt from the archives
    assert "0 solved, 4 skipped" in sw.format_report(report)


@pytest.mark.slow
def test_dask_cluster_gives_the_same_summary(local_run, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    path, out_local, _ = local_run
    out = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        report = sw.run_sweep(load_sweep(path), out, scheduler=cluster.scheduler_address, progress=False)
    assert (report.done, report.failed) == (4, 0)
    assert report.executor.startswith("dask scheduler")
    assert report.archived_here == 0  # the workers see the directory (the lock's token): they wrote the archives
    _, local = _read_csv(out_local / "summary.csv")
    _, remote = _read_csv(out / "summary.csv")
    drop = ("solve_time_s",)  # timing differs, everything else is the same solve
    assert [{k: v for k, v in r.items() if k not in drop} for r in remote] == [
        {k: v for k, v in r.items() if k not in drop} for r in local
    ]
    assert _h5_files(out) == _h5_files(out_local)


@pytest.mark.slow
def test_dask_workers_that_do_not_see_the_directory_send_results_back(local_run, tmp_path, monkeypatch):
    from vine_nlp.front.sweep import executors

    distributed = pytest.importorskip("dask.distributed")
    path, out_local, _ = local_run
    monkeypatch.setattr(executors, "_reaches", lambda out_dir, token: False)  # as on another machine
    # two threads in one worker process: its items run one at a time all the same (two at once crashed in CasADi)
    with distributed.LocalCluster(n_workers=1, processes=False, threads_per_worker=2, dashboard_address=None) as cluster:
        report = sw.run_sweep(load_sweep(path), tmp_path / "out", scheduler=cluster.scheduler_address, progress=False)
    assert (report.done, report.failed, report.archived_here) == (4, 0, 4)
    assert "4 archives were written by this process: the workers could not reach" in sw.format_report(report)
    assert _h5_files(tmp_path / "out") == _h5_files(out_local)


def test_a_failing_item_is_reported_and_the_others_finish(tmp_path, monkeypatch):
    path = _write_sweep(tmp_path / "in")
    out = tmp_path / "out"
    real = executors.design_item

    def flaky(pf, method):
        if pf.name == "tiny-0002":
            raise RuntimeError("boom\nsecond line")
        return real(pf, method)

    monkeypatch.setattr(executors, "design_item", flaky)
    report = sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    assert (report.done, report.failed) == (3, 1)
    assert report.executor == "in this process"
    assert _h5_files(out) == ["tiny-0000.h5", "tiny-0001.h5", "tiny-0003.h5"]  # no archive for the failure
    _, rows = _read_csv(out / "summary.csv")
    assert [r["status"] for r in rows] == ["optimal", "optimal", "failed", "optimal"]
    failed = rows[2]
    assert failed["error"] == "RuntimeError: boom second line"  # one line
    assert failed["rmse"] == failed["max_error"] == failed["solve_time_s"] == ""
    assert report.failures == [("tiny-0002", "nlp", "RuntimeError: boom second line")]
    assert "failed: tiny-0002 nlp: RuntimeError: boom" in sw.format_report(report)

    # the next run retries only the failed item
    monkeypatch.setattr(executors, "design_item", real)
    before = _mtimes(out)
    again = sw.run_sweep(load_sweep(path), out, workers=0, progress=False)
    assert (again.done, again.skipped, again.failed) == (1, 3, 0)
    assert {k: v for k, v in _mtimes(out).items() if k in before} == before
    _, rows = _read_csv(out / "summary.csv")
    assert [r["status"] for r in rows] == ["optimal"] * 4


def test_an_archive_hdf5_refuses_fails_its_item_alone(tmp_path, monkeypatch):
    from vine_nlp.pipeline import runs as pipeline_runs  # where every door's archive is written (Outcome.write)

    path = _write_sweep(tmp_path / "in")
    real = pipeline_runs.write_archive

    def refuses(where, archive):
        if archive.name == "tiny-0001":  # as h5py refuses a text with NUL
            raise ValueError("VLEN strings do not support embedded NULLs")
        real(where, archive)

    monkeypatch.setattr(pipeline_runs, "write_archive", refuses)
    report = sw.run_sweep(load_sweep(path), tmp_path / "out", workers=1, progress=False)
    assert (report.done, report.failed) == (3, 1)
    assert report.failures == [("tiny-0001", "nlp", "cannot archive the result (ValueError: VLEN strings do not support "
                                                    "embedded NULLs)")]
    assert _h5_files(tmp_path / "out") == ["tiny-0000.h5", "tiny-0002.h5", "tiny-0003.h5"]


def test_a_failing_method_keeps_the_other_methods_of_its_item(tmp_path, monkeypatch):
    path = _write_sweep(tmp_path / "in", methods=("nlp", "greedy"))
    out = tmp_path / "out"
    real = executors.design_item
    calls = []
    broken = {"tiny-0001"}

    def fake_greedy(pf, method):
        calls.append((pf.name, method))
        if method == "greedy":  # stands in for the (slow) greedy method: the nlp design, relabelled
            if pf.name in broken:
                raise ValueError("greedy went wrong")
            r = real(pf, "nlp")["nlp"]
            return {"greedy": dataclasses.replace(r, method="greedy", solve_time_s=2 * r.solve_time_s,
                                                  metrics={**r.metrics, "rmse": 1.5 * r.metrics["rmse"]})}
        return real(pf, method)

    monkeypatch.setattr(executors, "design_item", fake_greedy)
    report = sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    assert (report.done, report.failed) == (3, 1)
    assert list(load_archive(out / "tiny-0001.h5").runs) == ["nlp"]  # the finished run is kept
    assert sorted(load_archive(out / "tiny-0000.h5").runs) == ["greedy", "nlp"]
    _, rows = _read_csv(out / "summary.csv")
    assert [(r["item"], r["method"], r["status"]) for r in rows[2:4]] == [
        ("tiny-0001", "nlp", "optimal"), ("tiny-0001", "greedy", "failed")]
    assert (out / "summary.png").exists()  # with the NLP-against-greedy panel

    calls.clear()
    broken.clear()
    again = sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    assert calls == [("tiny-0001", "greedy")]  # only the missing run is solved
    assert (again.done, again.skipped, again.failed) == (1, 3, 0)
    assert sorted(load_archive(out / "tiny-0001.h5").runs) == ["greedy", "nlp"]


def test_an_interrupt_inside_a_worker_fails_the_run_not_the_sweep(tmp_path, monkeypatch):
    # CasADi turns an exception inside IPOPT into a status that vine_nlp.interrupt raises as
    # KeyboardInterrupt; workers ignore Ctrl-C, so there it is the run's failure.
    path = _write_sweep(tmp_path / "in")
    _, _, pf = load_sweep(path).items()[0]

    def interrupted(pf, method):
        raise KeyboardInterrupt

    monkeypatch.setattr(executors, "design_item", interrupted)
    runs, timings = sw.solve_item(pf, ["nlp"], remote=True)
    assert runs == {} and "KeyboardInterrupt" in timings["errors"]["nlp"]
    with pytest.raises(KeyboardInterrupt):  # in this process it is the user's Ctrl-C
        sw.solve_item(pf, ["nlp"])


def test_ctrl_c_keeps_finished_archives_and_a_valid_summary(tmp_path):
    path = _write_sweep(tmp_path / "in")
    out = tmp_path / "out"
    seen = []

    def interrupt(item, rows):
        seen.append(item)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt) as info:
        sw.run_sweep(load_sweep(path), out, workers=2, progress=False, callback=interrupt)
    report = info.value.sweep_report
    # the callback of the first finished item interrupts; the other worker's item may have
    # finished in the same wait (both archives written before the callbacks): both are kept
    assert report.interrupted and len(seen) == 1 and 1 <= report.done < 4
    kept = _h5_files(out)
    assert f"{seen[0]}.h5" in kept and len(kept) == report.done
    for p in out.glob("*.h5"):
        load_archive(p)
    assert not list(out.glob(".*.tmp"))  # no half-written files
    _, rows = _read_csv(out / "summary.csv")
    assert [f"{r['item']}.h5" for r in rows] == kept
    assert "not run (interrupted)" in sw.format_report(report)

    again = sw.run_sweep(load_sweep(path), out, workers=2, progress=False)
    assert (again.done, again.skipped, again.failed) == (4 - report.done, report.done, 0)
    _, rows = _read_csv(out / "summary.csv")
    assert [r["item"] for r in rows] == [f"tiny-000{k}" for k in range(4)]


def test_archives_of_another_version_of_the_sweep_are_redone(tmp_path):
    path = _write_sweep(tmp_path / "in")
    out = tmp_path / "out"
    sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    (out / "tiny-0003.h5").write_bytes(b"not an archive")  # e.g. cut short by a power failure
    _write_sweep(tmp_path / "in", base=BASE.replace("diameter = 2.43", "diameter = 2.5"))
    report = sw.run_sweep(load_sweep(path), out, workers=1, progress=False)
    assert (report.done, report.skipped, report.replaced) == (4, 0, 4)
    assert all(load_archive(p).diameter == 2.5 for p in out.glob("*.h5"))
    assert "were replaced" in sw.format_report(report)
    forced = sw.run_sweep(load_sweep(path), out, workers=1, progress=False, force=True)
    assert (forced.done, forced.skipped, forced.replaced) == (4, 0, 0)


class _Crashes(ProblemFile):
    """A problem that kills the worker process that receives it (as a native crash would)."""

    def __reduce__(self):
        return (os._exit, (3,))


@pytest.mark.slow
def test_an_item_that_kills_its_worker_fails_alone(tmp_path):
    path = _write_sweep(tmp_path / "in")
    sweep = load_sweep(path)
    items = sweep.items()
    item, overrides, pf = items[1]
    sweep._items[1] = (item, overrides, _Crashes(**{f.name: getattr(pf, f.name) for f in dataclasses.fields(pf)}))
    out = tmp_path / "out"
    report = sw.run_sweep(sweep, out, workers=2, progress=False)
    assert (report.done, report.failed) == (3, 1)
    assert [f[0] for f in report.failures] == ["tiny-0001"]
    assert "worker process died" in report.failures[0][2]
    assert _h5_files(out) == ["tiny-0000.h5", "tiny-0002.h5", "tiny-0003.h5"]


def test_bad_arguments_are_input_errors_and_create_nothing(tmp_path):
    path = _write_sweep(tmp_path / "in")
    with pytest.raises(InputError, match="--workers"):
        sw.run_sweep(load_sweep(path), tmp_path / "a", workers=-1, progress=False)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a directory"):
        sw.run_sweep(load_sweep(path), tmp_path / "file", workers=1, progress=False)
    with pytest.raises(InputError, match="--scheduler"):
        sw.run_sweep(load_sweep(path), tmp_path / "a", scheduler="no-port-here", progress=False)
    assert not (tmp_path / "a").exists()


def test_a_scheduler_without_dask_names_the_extra_and_creates_nothing(tmp_path, monkeypatch):
    import sys

    path = _write_sweep(tmp_path / "in")
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as where the [cluster] extra is not installed
    with pytest.raises(InputError) as e:
        sw.run_sweep(load_sweep(path), tmp_path / "a", scheduler="tcp://127.0.0.1:8786", progress=False)
    assert str(e.value) == "command line: --scheduler: needs dask.distributed: python3 -m pip install 'vine_nlp[cluster]'"
    assert not (tmp_path / "a").exists()


def test_plot_summary_draws_both_methods_and_skips_failures(tmp_path):
    rows = []
    for k in range(6):
        for method, rmse in (("nlp", 0.01 * (k + 1)), ("greedy", 0.03 * (k + 1))):
            rows.append({"item": f"s-{k}", "method": method, "status": "optimal", "rmse": rmse, "max_error": 2 * rmse,
                         "solve_time_s": 0.1 * (k + 1), "units": "cm"})
    rows.append({"item": "s-6", "method": "nlp", "status": "failed", "rmse": None, "max_error": None,
                 "solve_time_s": None, "units": "cm"})
    png = sw.plot_summary(rows, tmp_path / "f.png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    stats = sw.method_stats(rows)
    assert stats["nlp"]["count"] == 6 and stats["nlp"]["failed"] == 1
    assert stats["nlp"]["rmse_max"] == pytest.approx(0.6) and stats["nlp"]["units"] == "mm"
    assert stats["greedy"]["worst_item"] == "s-5"


def test_the_package_imports_dask_only_for_a_scheduler():
    import subprocess
    import sys

    code = ("import sys, vine_nlp.front.sweep as s; "
            "from vine_nlp.front.sweep import run_sweep, format_report, method_stats, plot_summary, solve_item; "
            "print(sorted(m for m in ('dask', 'distributed', 'matplotlib') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_a_chunk_archives_each_item_in_order_and_keeps_failures_apart(tmp_path, monkeypatch):
    path = _write_sweep(tmp_path / "in")
    items = load_sweep(path).items()[:2]
    real = executors.design_item

    def second_fails(pf, method):
        if pf.name == items[1][0]:
            raise RuntimeError("second item")
        return real(pf, method)

    monkeypatch.setattr(executors, "design_item", second_fails)
    chunk = [(item, pf, ["nlp"], {}) for item, _, pf in items]
    out = tmp_path / "out"
    out.mkdir()
    first, second = sw.solve_chunk(chunk, out, remote=True)
    # the worker wrote the archive; only the summary's numbers come back
    assert "runs" not in first and first["errors"] == {}
    assert first["cells"] == {"nlp": sw.cells(load_archive(out / f"{items[0][0]}.h5").runs["nlp"])}
    assert second["cells"] == {} and second["errors"] == {"nlp": "RuntimeError: second item"}
    assert _h5_files(out) == [f"{items[0][0]}.h5"]
    # a worker that does not see the sweep's directory (another machine: not the lock's token) sends the runs back
    lock = sw.DirectoryLock(out)
    lock.acquire()
    try:
        (here,) = sw.solve_chunk(chunk[:1], out, token=lock.token, remote=True)
        (away,) = sw.solve_chunk(chunk[:1], out, token="another-sweep", remote=True)
    finally:
        lock.release()
    assert "cells" in here and "runs" not in here
    assert "cells" not in away and away["runs"]["nlp"].status == "optimal"


def test_local_chunks_are_small_and_end_as_single_items():
    pool = sw.LocalPool.__new__(sw.LocalPool)  # the chunk policy only, no processes
    pool.workers = 2
    sizes = [pool.chunk_size(n) for n in range(1, 500)]
    assert max(sizes) == sw.MAX_CHUNK and min(sizes) == 1
    assert all(s == 1 for s in sizes[: 4 * 2 * 2 - 1])  # the last items travel alone: no worker waits for a long chunk
    assert all(1 <= s <= max(1, n // 8) for n, s in enumerate(sizes, start=1))


@pytest.mark.slow
def test_an_item_that_kills_its_worker_inside_a_chunk_fails_alone(tmp_path, monkeypatch):
    path = _write_sweep(tmp_path / "in")
    sweep = load_sweep(path)
    item, overrides, pf = sweep.items()[1]
    sweep._items[1] = (item, overrides, _Crashes(**{f.name: getattr(pf, f.name) for f in dataclasses.fields(pf)}))
    monkeypatch.setattr(sw.LocalPool, "chunk_size", lambda self, pending: 2)  # items 0 and 1 share a task
    report = sw.run_sweep(sweep, tmp_path / "out", workers=2, progress=False)
    assert (report.done, report.failed) == (3, 1)  # item 0, lost with the chunk, ran again alone
    assert [f[0] for f in report.failures] == ["tiny-0001"] and "worker process died" in report.failures[0][2]
    assert _h5_files(tmp_path / "out") == ["tiny-0000.h5", "tiny-0002.h5", "tiny-0003.h5"]


@pytest.mark.slow
def test_a_fresh_process_forks_its_workers_and_never_loads_the_solver(tmp_path):
    import subprocess
    import sys

    path = _write_sweep(tmp_path / "in")
    code = (
        "import sys\n"
        "from vine_nlp.front.sweep import executors, run_sweep\n"
        "from vine_nlp.io.problem_file import load_sweep\n"
        "pools = []\n"
        "make = executors.make_pool\n"
        "def spy(*a, **k):\n"
        "    pools.append(make(*a, **k))\n"
        "    return pools[-1]\n"
        "import vine_nlp.front.sweep.engine as engine\n"
        "engine.make_pool = spy\n"
        f"r = run_sweep(load_sweep({str(path)!r}), {str(tmp_path / 'out')!r}, workers=2, progress=False)\n"
        "print(r.done, r.failed, pools[0].start_method, 'vine_nlp.methods.transcription' in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    # forked workers start with everything imported; the parent only writes files, so it stays safe to fork
    assert r.stdout.split() == ["4", "0", "fork", "False"]
    assert _h5_files(tmp_path / "out") == [f"tiny-000{k}.h5" for k in range(4)]


def test_what_design_refuses_a_sweep_refuses_before_anything_is_written(tmp_path):
    # one pipeline (issue 30): obstacle problems are swept as `vine-nlp design` designs them, and what it
    # refuses for them (the greedy method) a sweep refuses with the same reason, before any work
    base = BASE + '\n[[obstacles]]\nshape = "sphere"\ncenter = [50.0, 0.0, 0.0]\nradius = 1.0\n'
    path = _write_sweep(tmp_path / "in", base=base, methods=("nlp", "greedy"))
    with pytest.raises(InputError, match="obstacles are designed by the nlp formulation only") as info:
        sw.run_sweep(load_sweep(path), tmp_path / "out", workers=2, progress=False)
    assert info.value.key == "method"
    assert not (tmp_path / "out").exists()


def test_a_sweep_of_several_actuators_writes_their_archives_and_resumes(tmp_path):
    """A several-actuator base: one archive per item in the spec's layout (every state's shape), the same design as
    `vine-nlp design` of the item; the summary's rmse is the run's, over every state's points; a rerun skips."""
    from test_actuators_io import DESIGN

    from vine_nlp.pipeline import run

    (tmp_path / "base.toml").write_text(DESIGN)
    path = tmp_path / "sweep.toml"
    path.write_text('name = "two"\nbase = "base.toml"\n[grid]\n"tube.diameter" = [2.4, 3.0]\n')
    out = tmp_path / "out"
    report = sw.run_sweep(load_sweep(path), out, workers=0, progress=False)
    assert (report.done, report.failed) == (2, 0)
    assert _h5_files(out) == ["two-0000.h5", "two-0001.h5"]
    _, rows = _read_csv(out / "summary.csv")
    item = load_sweep(path).items()[1][2]
    alone = run(item).runs["nlp"]
    archive = load_archive(out / "two-0001.h5")
    assert archive.kind == "actuators" and float(rows[1]["rmse"]) == pytest.approx(alone.metrics["rmse"], rel=1e-9)
    assert np.allclose(archive.runs["nlp"].routing.theta, alone.routing.theta, atol=1e-12)
    second = sw.run_sweep(load_sweep(path), out, workers=0, progress=False)
    assert (second.done, second.skipped) == (0, 2)


def test_a_sweep_of_several_actuators_is_made_by_the_nlp_alone(tmp_path):
    from test_actuators_io import DESIGN

    (tmp_path / "base.toml").write_text(DESIGN)
    path = tmp_path / "sweep.toml"
    path.write_text('base = "base.toml"\nmethods = ["nlp", "greedy"]\n')
    with pytest.raises(InputError) as info:
        load_sweep(path)
    assert str(info.value) == f'{path}: methods: a design of several actuators is made by the nlp alone: ["nlp"]'
