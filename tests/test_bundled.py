"""Every bundled problem, through every door: the command line, ``vn.solve`` and a one-item sweep give the same runs (routing to
1e-9, the same metrics and status, the same exit status), and the figure renders without warnings (do-mpc style)."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import vine_nlp as vn
from vine_nlp.front.cli import main
from vine_nlp.io.archive import load_archive
from vine_nlp.io.problems import load_problem

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = sorted((ROOT / "problems").glob("*.toml"))
COMMAND = {"forward": "forward", "design": "design", "multishape": "design", "tip": "design", "fit": "fit", "actuators": "design",
           "actuators-forward": "forward"}


def assert_same_runs(a, b):
    """Two archives of one problem hold the same runs: names, status, requirements, routing (1e-9), metrics."""
    assert set(a.runs) == set(b.runs)
    for name in a.runs:
        r, q = a.runs[name], b.runs[name]
        assert (r.method, r.status, r.shortfall) == (q.method, q.status, q.shortfall), name
        for key in ("theta", "lam", "length", "initial_pose"):
            np.testing.assert_allclose(getattr(r.routing, key), getattr(q.routing, key), rtol=0, atol=1e-9, err_msg=f"{name} {key}")
        assert r.metrics.keys() == q.metrics.keys(), name
        for key in r.metrics:
            assert r.metrics[key] == pytest.approx(q.metrics[key], rel=1e-9, abs=1e-12), (name, key)


def through_both_doors(path, tmp_path, cli_args=(), **api_options):
    """(command-line exit status, its archive, the API's Design, its archive) of one problem file."""
    kind = load_problem(path).kind
    cli_out, api_out = tmp_path / "cli.h5", tmp_path / "api.h5"
    status = main([COMMAND[kind], str(path), "-o", str(cli_out), *cli_args])
    d = vn.solve(path, **api_options)
    d.save(api_out)
    return status, load_archive(cli_out), d, load_archive(api_out)


@pytest.mark.slow
@pytest.mark.parametrize("path", PROBLEMS, ids=lambda p: p.stem)
def test_bundled_problem_through_every_door(path, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        status, cli, design, api = through_both_doors(path, tmp_path)
        assert main(["plot", str(tmp_path / "cli.h5"), "-o", str(tmp_path / "fig.png")]) == 0
    assert (tmp_path / "fig.png").stat().st_size > 10_000
    assert_same_runs(cli, api)
    assert status == (0 if design.ok else 1)
    assert status == 0  # every bundled problem is designed, converged and clear
    if load_problem(path).kind == "design":  # the third door: a one-item sweep (empty grid) of the same problem
        (tmp_path / "sweep.toml").write_text(f"name = \"one\"\nbase = {str(path)!r}\n")
        assert main(["sweep", str(tmp_path / "sweep.toml"), "-o", str(tmp_path / "sweep"), "--workers", "0"]) == status
        assert_same_runs(cli, load_archive(tmp_path / "sweep" / "one-0000.h5"))


@pytest.mark.slow
def test_a_calibrated_problem_with_robust_and_clearance_runs_through_both_doors(tmp_path):
    # the API and the command line start the robust and clearance designs from the same (realized) design and
    # give every run the calibration: the same archive
    src = (ROOT / "problems/bezier-c.toml").read_text()
    problem = tmp_path / "calibrated.toml"
    problem.write_text(src + "\n[calibration]\nlambda_offset = 0.02\ntheta_offset_deg = 0.5\nlength_scale = 1.01\n")
    status, cli, design, api = through_both_doors(problem, tmp_path, ("--robust", "--clearance", "--min-gap", "0.1"),
                                                  robust={"theta_deg": 1.0, "lambda": 0.02, "length": 0.02}, clearance=0.1)
    assert set(cli.runs) == {"nlp", "nlp_robust", "nlp_clearance"}
    assert_same_runs(cli, api)
    assert status == (0 if design.ok else 1)
    for r in cli.runs.values():  # every run is the nominal to build
        assert r.stats["calibration_lambda_offset"] == 0.02
