"""The command line: exit codes, one-line errors, nothing written on bad input, bundled problems run."""

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from vine_nlp.front.cli import main
from vine_nlp.io.archive import load_archive
from vine_nlp.io.problem_file import load_problem
from vine_nlp.model import chain_frames

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"
FORWARD = sorted(p for p in PROBLEMS.glob("*.toml") if load_problem(p).kind == "forward")
DESIGN = sorted(p for p in PROBLEMS.glob("*.toml") if load_problem(p).kind == "design")


def test_bundled_problems_present():
    names = {p.stem for p in PROBLEMS.glob("*.toml")}
    assert {"static-helix", "three-section-helix", "polynomial-phi", "sinusoidal-spam"} <= names
    assert {"trefoil-m4", "bezier-a", "bezier-b", "bezier-c", "polyline-d", "spam-helix"} <= names


@pytest.mark.parametrize("path", FORWARD, ids=lambda p: p.stem)
def test_forward_bundled(path, tmp_path, capsys):
    out = tmp_path / "f.h5"
    assert main(["forward", str(path), "-o", str(out)]) == 0
    a = load_archive(out)
    assert a.kind == "forward" and list(a.runs) == ["forward"]
    r = a.runs["forward"]
    pf = load_problem(path)
    assert a.source == pf.source
    frames = chain_frames(r.routing.theta, r.routing.lam, r.routing.length, a.diameter, r.routing.initial_pose)
    # rows 0 and P-1 are the base and the tip
    np.testing.assert_allclose(r.shape.center[0], frames[0, :3, 3], atol=1e-12)
    np.testing.assert_allclose(r.shape.center[-1], frames[-1, :3, 3], atol=1e-10)
    with h5py.File(out) as h5:
        assert h5.attrs["format"] == "vine_nlp/result" and h5.attrs["format_version"] == 1
        assert h5["runs/forward/design/phi"].shape == (r.routing.segments + 1,)


def test_static_helix_matches_table_one(tmp_path):
    from vine_nlp.model import helix_forward

    out = tmp_path / "h.h5"
    assert main(["forward", str(PROBLEMS / "static-helix.toml"), "-o", str(out)]) == 0
    r = load_archive(out).runs["forward"]
    h = helix_forward(np.radians(10), 0.7, 2.62)
    # the inner line of the uniform chain has the actuator line's length: lambda x 30.5 cm actuated
    seg = np.linalg.norm(np.diff(r.shape.inner, axis=0), axis=1).sum()
    assert seg == pytest.approx(0.7 * 30.5, rel=2e-3)
    assert r.shape.center.shape[0] > 31
    assert h.R_c > 0


def test_design_command_writes_archive_and_reports(tmp_path, capsys):
    out = tmp_path / "d.h5"
    code = main(["design", str(PROBLEMS / "spam-helix.toml"), "-o", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "RMSE" in text and "iterations" in text and "optimal" in text
    a = load_archive(out)
    r = a.runs["nlp"]
    assert r.shape.center.shape == a.target.shape
    assert np.ptp(r.routing.lam) == 0


def test_exit_1_when_not_converged(tmp_path):
    src = (PROBLEMS / "trefoil-m4.toml").read_text().replace("lookahead = 4", "lookahead = 4\nmax_iter = 1")
    p = tmp_path / "p.toml"
    p.write_text(src)
    out = tmp_path / "d.h5"
    assert main(["design", str(p), "-o", str(out)]) == 1
    assert load_archive(out).runs["nlp"].status == "max_iter"  # the best point is still archived


def _run(*args):
    return subprocess.run([sys.executable, "-m", "vine_nlp", *map(str, args)], capture_output=True, text=True)


def test_bad_input_one_line_exit_2_nothing_written(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('name = "x"\n[tube]\ndiameter = -1\n[routing]\nlength = 5\nsegment_length = 1\ntheta = 0\nlambda = 0.5\n')
    out = tmp_path / "o.h5"
    r = _run("forward", p, "-o", out)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"error: {p}: tube.diameter: must be > 0"]
    assert not out.exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--hops", "-1"], "error: command line: vine-nlp design: argument --hops: must be an integer >= 0 and <= 1000, got -1"),
        (["--starts", "0"], "error: command line: vine-nlp design: argument --starts: must be an integer >= 1 and <= 1000, got 0"),
        (["--workers", "two"], "error: command line: vine-nlp design: argument --workers: invalid integer: 'two'"),
    ],
)
def test_counts_on_the_command_line_are_checked(tmp_path, capsys, args, message):
    out = tmp_path / "o.h5"
    assert main(["design", str(PROBLEMS / "bezier-c.toml"), "-o", str(out), *args]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [message]
    assert not out.exists()


def test_hops_are_refused_for_multishape_problems(tmp_path, capsys):
    out = tmp_path / "o.h5"
    problem = PROBLEMS / "multishape-spam.toml"
    assert main(["design", str(problem), "-o", str(out), "--hops", "2"]) == 2
    assert capsys.readouterr().err.strip() == f"error: {problem}: --hops: not available for multishape problems"
    assert not out.exists()


def test_refuses_to_overwrite_without_force(tmp_path):
    out = tmp_path / "o.h5"
    out.write_bytes(b"keep me")
    r = _run("forward", PROBLEMS / "static-helix.toml", "-o", out)
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {out}: -o: exists; pass --force to overwrite it"
    assert out.read_bytes() == b"keep me"
    assert _run("forward", PROBLEMS / "static-helix.toml", "-o", out, "--force").returncode == 0
    assert load_archive(out).kind == "forward"


def test_missing_output_directory(tmp_path):
    out = tmp_path / "nope" / "o.h5"
    r = _run("forward", PROBLEMS / "static-helix.toml", "-o", out)
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {out}: -o: directory {str(out.parent)!r} does not exist"


def test_wrong_problem_kind(tmp_path):
    r = _run("forward", PROBLEMS / "trefoil-m4.toml", "-o", tmp_path / "o.h5")
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {PROBLEMS / 'trefoil-m4.toml'}: routing: a forward problem needs [routing] (this is a design problem)"


def test_usage_errors_exit_2():
    r = _run("frobnicate")
    assert r.returncode == 2 and r.stderr.startswith("error: command line:") and len(r.stderr.strip().splitlines()) == 1
    r = _run("design")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_help_lists_only_real_commands():
    r = _run("--help")
    assert r.returncode == 0
    for cmd in ("forward", "design", "compare"):
        assert cmd in r.stdout


def test_fit_command_recovers_the_synthetic_lambda(tmp_path, capsys):
    # problems/data/make_synthetic.py made these markers with lambda 0.85 and 1.4 mm noise
    out = tmp_path / "fit.h5"
    assert main(["fit", str(PROBLEMS / "fit-sinusoidal.toml"), "-o", str(out)]) == 0
    a = load_archive(out)
    r = a.runs["fit"]
    assert a.kind == "fit"
    assert r.routing.lam[0] == pytest.approx(0.85, abs=0.02)
    assert r.metrics["rmse"] < 0.2 and r.metrics["r2"] > 0.99
    assert a.extra["measured/points"].shape == (15, 3)
    assert "lambda 0.8" in capsys.readouterr().out


def test_fit_frames_recover_lambda_over_frames(tmp_path, capsys):
    # make_synthetic.frames(): lambda 0.98, 0.93, 0.87, 0.81, 0.76 (the paper's Fig. 9 range)
    frames = sorted((PROBLEMS / "data" / "sinusoidal-frames").glob("frame-*.csv"))
    out, fig = tmp_path / "f.h5", tmp_path / "frames.png"
    args = ["fit", str(PROBLEMS / "fit-sinusoidal.toml"), "-o", str(out), "--frames", *map(str, frames), "--frames-plot", str(fig)]
    assert main(args) == 0
    lam = load_archive(out).extra["frames/lambda"]
    np.testing.assert_allclose(lam, [0.98, 0.93, 0.87, 0.81, 0.76], atol=0.02)
    assert fig.stat().st_size > 0


def test_fit_frames_bad_file_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "frame.csv"
    bad.write_text("x,y,z\n1,2,nan\n")
    out = tmp_path / "f.h5"
    assert main(["fit", str(PROBLEMS / "fit-sinusoidal.toml"), "-o", str(out), "--frames", str(bad)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {bad}: line 2: 'nan' is not finite"
    assert not out.exists()


def test_sweep_command_runs_and_resumes(tmp_path, capsys):
    base = tmp_path / "base.toml"
    base.write_text((PROBLEMS / "trefoil-m4.toml").read_text().replace("samples = 400", "samples = 41").replace("points_per_segment = 10", "points_per_segment = 5"))
    sw = tmp_path / "s.toml"
    sw.write_text('name = "s"\nbase = "base.toml"\nmethods = ["nlp"]\n[grid]\n"target.scale.2" = [3, 5]\n')
    out = tmp_path / "out"
    assert main(["sweep", str(sw), "-o", str(out), "--workers", "1"]) == 0
    assert sorted(p.name for p in out.glob("*.h5")) == ["s-0000.h5", "s-0001.h5"]
    capsys.readouterr()
    assert main(["sweep", str(sw), "-o", str(out), "--workers", "1"]) == 0
    assert "2 skipped" in capsys.readouterr().out


def test_sweep_bad_grid_key_exit_2(tmp_path, capsys):
    sw = tmp_path / "s.toml"
    sw.write_text(f'name = "s"\nbase = "{PROBLEMS / "trefoil-m4.toml"}"\n[grid]\n"tube.diameter" = [-1]\n')
    assert main(["sweep", str(sw), "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.startswith(f"error: {sw}: tube.diameter: must be > 0")
    assert not (tmp_path / "out").exists()


def _small_trefoil(tmp_path):
    p = tmp_path / "small.toml"
    p.write_text((PROBLEMS / "trefoil-m4.toml").read_text().replace("samples = 400", "samples = 41").replace("points_per_segment = 10", "points_per_segment = 5"))
    return p


def test_analyze_reports_clearance_and_tolerance(tmp_path, capsys):
    out = tmp_path / "d.h5"
    assert main(["design", str(_small_trefoil(tmp_path)), "-o", str(out)]) == 0
    capsys.readouterr()
    fig = tmp_path / "tol.png"
    assert main(["analyze", str(out), "--samples", "200", "--tolerance-figure", str(fig), "--write-metrics"]) == 0
    text = capsys.readouterr().out
    for word in ("clearance", "growth", "tolerance", "Monte Carlo", "tip"):
        assert word in text
    m = load_archive(out).runs["nlp"].metrics
    assert m["min_clearance"] > 0
    assert m["tolerance_tip_std_mc"] == pytest.approx(m["tolerance_tip_std_first_order"], rel=0.15)
    assert fig.stat().st_size > 0


def test_analyze_of_a_tube_that_never_turns_back_says_so(tmp_path, capsys):
    arc = tmp_path / "arc.toml"  # theta 0: a plane arc turning by less than half a turn
    arc.write_text('name = "arc"\n[tube]\ndiameter = 2.0\n[routing]\nlength = 20.0\nsegment_length = 1.0\ntheta = 0.0\nlambda = 0.97\n')
    out = tmp_path / "arc.h5"
    assert main(["forward", str(arc), "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["analyze", str(out)]) == 0
    (line,) = [t for t in capsys.readouterr().out.splitlines() if t.startswith("clearance")]
    assert line == "clearance   none to report: the tube never comes back toward itself; 0 contact region(s)"


def test_design_robust_run_is_archived_beside_nlp(tmp_path, capsys):
    out = tmp_path / "d.h5"
    assert main(["design", str(_small_trefoil(tmp_path)), "-o", str(out), "--robust"]) == 0
    runs = load_archive(out).runs
    assert set(runs) == {"nlp", "nlp_robust"}
    assert runs["nlp_robust"].metrics["rmse"] >= runs["nlp"].metrics["rmse"] - 1e-9  # robustness costs nominal accuracy
