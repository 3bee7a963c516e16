"""The one pipeline: truthful status (judge, exit codes), the same answer to bad input through every door,
and a stored routing re-run."""

from pathlib import Path

import numpy as np
import pytest

import vine_nlp as vn
from vine_nlp.analysis.buildability import buildability
from vine_nlp.front.cli import main
from vine_nlp.front.reports import comparison_table
from vine_nlp.io.archive import load_archive
from vine_nlp.io.problems import ProblemFile
from vine_nlp.methods.buildable import Build
from vine_nlp.model.obstacles import Sphere
from vine_nlp.model.shape import forward_shape
from vine_nlp.pipeline import Request, judge, run
from vine_nlp.pipeline.request import COMPARE
from vine_nlp.problem import DesignOptions, DesignProblem, Result

ROOT = Path(__file__).resolve().parents[1]
D = 2.0


def _straight(length=40.0, segments=10) -> vn.Routing:
    return vn.Routing(theta=np.zeros(segments), lam=np.ones(segments), length=np.full(segments, length / segments))


def test_judge_names_the_obstacle_margin_a_design_misses():
    # a straight tube along x; a sphere of radius 3 on the axis at x = 20 (the tube cuts through it), and the
    # same sphere 5 off the axis (gap 5 - 3 - D/2 = 1 > margin 0.5)
    r = _straight()
    target = forward_shape(r, D).center
    for center, clear in (((20.0, 0.0, 0.0), False), ((20.0, 5.0, 0.0), True)):
        problem = DesignProblem("p", D, target, obstacles=(Sphere(center, 3.0),), obstacle_margin=0.5)
        result = Result("nlp", r, forward_shape(r, D), diameter=D)
        judge(problem, result)
        assert result.clear is clear
        assert result.metrics["min_obstacle_gap"] == pytest.approx(-4.0 if not clear else 1.0, abs=1e-6)
        if not clear:
            assert result.shortfall == ("obstacle margin not kept: min gap -4 cm < margin 0.5",)


def test_judge_names_a_bound_a_design_breaks():
    r = vn.Routing(theta=np.full(3, 1.2), lam=np.array([0.3, 0.5, 1.0]), length=np.ones(3))  # 69 deg > 60 deg; lambda 0.3 < 0.4
    result = Result("nlp", r, forward_shape(r, D), diameter=D)
    judge(DesignProblem("p", D, np.zeros((4, 3))), result)
    assert result.shortfall[:2] == ("|theta| above its bound 60 deg", "lambda outside [0.4, 1]")
    assert result.shortfall[2:] and all(s.startswith("not buildable: ") for s in result.shortfall[2:])  # lambda 0.3: no margin


@pytest.mark.slow
def test_a_design_that_does_not_converge_is_written_and_exits_1_through_every_door(tmp_path, capsys):
    problem = tmp_path / "p.toml"
    problem.write_text((ROOT / "problems/trefoil-m4.toml").read_text().replace("[design]", "[design]\nmax_iter = 2\nhessian = \"exact\""))
    out = tmp_path / "out.h5"
    assert main(["design", str(problem), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "trefoil-m4: nlp: max_iter, did not converge"
    assert load_archive(out).runs["nlp"].status == "max_iter"  # the best design found is written
    d = vn.solve(problem)
    assert (d.status, d.converged, d.ok) == ("max_iter", False, False)


def test_bad_input_gets_the_same_answer_through_every_door(tmp_path, capsys):
    problem = tmp_path / "bad.toml"
    problem.write_text((ROOT / "problems/trefoil-m4.toml").read_text().replace("diameter = 2.43", "diameter = -1.0"))
    out = tmp_path / "out.h5"
    assert main(["design", str(problem), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {problem}: tube.diameter: must be > 0"
    assert not out.exists()
    with pytest.raises(vn.ArgumentError) as e:
        vn.solve(problem)
    assert str(e.value) == f"problem: {problem}: tube.diameter: must be > 0"
    # a request the problem cannot take: the command line names its flag, the API its argument
    assert main(["forward", str(ROOT / "problems/static-helix.toml"), "-o", str(out)]) == 0
    assert main(["design", str(ROOT / "problems/tip-target.toml"), "-o", str(tmp_path / "t.h5"), "--warm", str(out)]) == 2
    assert capsys.readouterr().err.strip().endswith("tip-target.toml: --warm: not available for tip problems")
    with pytest.raises(vn.ArgumentError, match=r"^problem: .*tip-target.toml: hops: not available for tip problems$"):
        vn.solve(ROOT / "problems/tip-target.toml", hops=2)


def test_forward_reruns_a_stored_routing(tmp_path, capsys):
    design, again = tmp_path / "d.h5", tmp_path / "f.h5"
    assert main(["design", str(ROOT / "problems/bezier-c.toml"), "-o", str(design)]) == 0
    assert main(["forward", str(design), "--run", "nlp", "-o", str(again)]) == 0
    a, b = load_archive(design), load_archive(again)
    r, f = a.runs["nlp"], b.runs["forward"]
    for key in ("theta", "lam", "length", "initial_pose"):
        np.testing.assert_array_equal(getattr(r.routing, key), getattr(f.routing, key))
    # the forward shape runs base to tip along the same chain: it ends where the design's center line ends
    np.testing.assert_allclose(f.shape.center[-1], r.shape.center[-1], atol=1e-9)
    assert b.kind == "forward" and b.name == "bezier-c-nlp"
    assert main(["forward", str(design), "--run", "greedy", "-o", str(tmp_path / "g.h5")]) == 2
    assert "--run: no run 'greedy' (runs: nlp)" in capsys.readouterr().err


@pytest.mark.slow
def test_compare_shows_buildable_and_free_figures_for_both_methods():
    # a target the model makes from a routing with lambda 0.97 on segments 2-5 and 8-9: within the correction margin
    # of 1, so the free designs, which recover the routing, are not buildable; the buildable ones are
    M = 10
    lam = np.where(np.isin(np.arange(M), [0, 1, 6, 7]), 0.7, 0.97)
    r = vn.Routing(theta=0.3 * np.cos(np.arange(M)), lam=lam, length=np.full(M, 3.0))
    options = DesignOptions(points_per_segment=5, greedy_starts=2)
    problem = DesignProblem("p", D, forward_shape(r, D, per_segment=5).center, options=options)
    out = run(ProblemFile("p.toml", "", "design", "p", "cm", problem), Request(methods=COMPARE))
    assert tuple(out.runs) == ("nlp_free", "nlp", "greedy", "greedy_buildable", "greedy_filtered")
    assert out.decisive == ("nlp", "greedy", "greedy_buildable", "greedy_filtered") and out.ok  # nlp_free: a figure only
    for name in ("nlp_free", "greedy"):  # the known answer, lambda 0.97 where the routing has it
        assert out.runs[name].metrics["rmse"] < 1e-3 * D
        np.testing.assert_allclose(out.runs[name].routing.lam, lam, atol=1e-3)
    b = Build.of(problem)
    for name in ("nlp", "greedy_buildable"):
        rb = out.runs[name]
        assert rb.buildable and rb.shortfall == ()
        rep = buildability(rb.routing, D, "tendon", 0.4, b.margin, b.min_feature)
        assert rep.missed(b.lo, 1 - b.margin) == []
    table = comparison_table(out.runs, "cm", problem).splitlines()
    assert {row.split()[0]: row.split()[-1] for row in table[2:7]} == {
        "nlp": "yes", "nlp_free": "no", "greedy_buildable": "yes", "greedy": "no", "greedy_filtered": "no"}
    assert "nlp_free misses: 6 segment(s) with lambda neither 1 nor in [0.45, 0.95] (correction margin; segments 2, 3, 4, 5, 8, 9)" in table
    assert table[-2].startswith("buildable: nlp is ") and " faster than greedy_buildable, RMSE " in table[-2]
    assert table[-1].startswith("free: nlp_free is ") and " faster than greedy, RMSE " in table[-1]
