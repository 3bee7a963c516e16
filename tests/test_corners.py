"""The corner search of the design NLP (design.corners): the window's rigid tail is exact, the detector
tells corners from smooth targets, the search lowers the objective, deterministically, and stops cleanly."""

import dataclasses
import threading

import numpy as np
import pytest

from vine_nlp import targets
from vine_nlp.front.cli import main
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import corners, settings
from vine_nlp.methods.common import pair_points
from vine_nlp.methods.drive import TIE_RTOL
from vine_nlp.methods.nlp import _solve, design_nlp, guess_from_routing, solve_from
from vine_nlp.model.chain import chain_points
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem

D = 2.43
# one sharp corner: the first solve ends at 0.587 cm RMSE (0.24 D), the search lower (measured: objective
# 0.0583 -> 0.0504)
CORNER = np.array([[0, 0, 0], [25, 0, 0], [27, -22, 8.0]])


def _corner_problem(**opts):
    return DesignProblem("corner", D, targets.polyline(CORNER, samples=61), actuator=Actuator("tendon", 0.4),
                         options=DesignOptions(points_per_segment=10, **opts))


@pytest.fixture(scope="module")
def first():
    pb = _corner_problem()
    pairing = pair_points(pb.target, 10)
    return pb, pairing, solve_from(pb, pairing=pairing)


def _error_from(pb, pairing, routing, a):
    """(1/N) sum |r_i - t_i|^2 / D^2 over the points of segments a.. (what a window from a sees)."""
    pts, _ = chain_points(routing.theta, routing.lam, routing.length, D, pairing.seg, pairing.frac, routing.initial_pose)
    keep = pairing.seg >= a
    return float(np.sum((pts[keep] - pb.target[keep]) ** 2) / D**2 / pb.target.shape[0])


@pytest.mark.parametrize("a, W", [(0, 3), (1, 3), (1, 2), (0, 4)])
def test_window_objective_is_the_whole_error_from_the_window_on(first, a, W):
    # the tail after the window moves rigidly with the window's end frame: its quadratic form in that
    # frame is exact, for the current values and for any new ones
    pb, pairing, r = first
    win = corners._Window(pb, pairing, r.routing, a, W)
    assert win.objective(win.x) == pytest.approx(_error_from(pb, pairing, r.routing, a), rel=1e-10, abs=1e-14)
    rng = np.random.default_rng(3)
    for x in win.starts(rng, 4)[1:]:  # theta mirrored, then random values inside the bounds
        assert np.all((x >= win.lbx) & (x <= win.ubx))
        moved = win.apply(r.routing, x, D)
        np.testing.assert_array_equal(moved.theta[:a], r.routing.theta[:a])
        np.testing.assert_array_equal(moved.length[a + W :], r.routing.length[a + W :])
        assert win.objective(x) == pytest.approx(_error_from(pb, pairing, moved, a), rel=1e-10, abs=1e-14)


def test_the_detector_fires_on_corners_only(first, make_target):
    pb, _, r = first
    assert r.hessian.startswith("exact") and r.metrics["rmse"] > settings.CORNER_RMSE * D
    assert corners.corner_like(pb, r)
    # a target the model follows exactly: Gauss-Newton converges, the residuals vanish
    tgt, _ = make_target(seed=0)
    smooth = DesignProblem("t", 2.0, tgt, actuator=Actuator("tendon", 0.4), options=DesignOptions(points_per_segment=5))
    s = solve_from(smooth)
    assert not corners.corner_like(smooth, s)
    # large residuals alone, with Gauss-Newton converged, are not a corner either
    assert not corners.corner_like(pb, dataclasses.replace(r, hessian="gauss-newton", status="optimal"))


def test_the_search_lowers_the_objective_and_is_deterministic_in_any_number_of_threads(first):
    pb, pairing, r = first
    off = design_nlp(pb, budget=0)
    assert "search_rounds" not in off.stats
    assert off.stats["objective"] == pytest.approx(r.stats["objective"], rel=1e-12)
    found = design_nlp(pb)  # default: the corner search runs
    st = found.stats
    assert found.converged and st["search_rounds"] >= 1 and st["search_accepted"] >= 1 and not st["search_budget_hit"]
    assert found.stats["objective"] < off.stats["objective"] * 0.9  # measured: 0.0504 vs 0.0583
    assert found.metrics["rmse"] < off.metrics["rmse"]
    assert found.stats["objective"] == pytest.approx(st["search_objectives"][-1], rel=TIE_RTOL)
    assert found.iterations > off.iterations
    # the same seed, one thread or two: the same design
    one = corners.search(pb, solve_from(pb, pairing=pairing), pairing, _polish(pb, pairing), workers=1)
    assert one.stats["search_workers"] == 1 and found.stats["search_workers"] == 2
    np.testing.assert_array_equal(one.routing.theta, found.routing.theta)
    np.testing.assert_array_equal(one.routing.lam, found.routing.lam)
    np.testing.assert_array_equal(one.routing.length, found.routing.length)


def _polish(pb, pairing):
    return lambda routing: _solve(pb, guess_from_routing(pb, pairing, routing), pairing, "chain", False, "exact", 3000)


def test_rounds_end_when_nothing_changes_with_progress_and_a_line_per_round(first):
    pb, pairing, r = first
    calls, lines = [], []
    res = corners.search(pb, dataclasses.replace(r, stats=dict(r.stats)), pairing, _polish(pb, pairing),
                         progress=lambda d, t: calls.append((d, t)), note=lines.append, rounds=3)
    assert calls and calls[-1][0] == calls[-1][1] and all(d <= t for d, t in calls)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)
    st = res.stats
    # measured: round 1 changes a window (0.0583 -> 0.0504), round 2 finds nothing better and ends the search
    assert st["search_rounds"] == len(lines) == 2 and len(st["search_objectives"]) == 1
    assert lines[0].startswith("corner search round 1: 1 windows changed, objective 0.0582831 -> ")
    assert lines[1].startswith("corner search round 2: no window changed")
    assert res.stats["objective"] == st["search_objectives"][0] < r.stats["objective"] * 0.9


def test_a_spent_budget_starts_no_window_and_keeps_the_design(first):
    pb, pairing, r = first
    polished = []
    res = corners.search(pb, dataclasses.replace(r, stats=dict(r.stats)), pairing, lambda x: polished.append(x), budget=0.0)
    assert res.stats["search_windows"] == 0 and res.stats["search_budget_hit"]
    assert res.routing is r.routing and polished == []


def test_an_interrupt_stops_the_search_and_leaves_no_thread(first):
    pb, pairing, r = first

    def interrupted(routing):
        raise KeyboardInterrupt

    before = {t.ident for t in threading.enumerate()}
    with pytest.raises(KeyboardInterrupt):
        corners.search(pb, dataclasses.replace(r, stats=dict(r.stats)), pairing, interrupted, workers=2)
    left = [t for t in threading.enumerate() if t.ident not in before and t.name.startswith("vine-nlp-window")]
    assert left == []


def test_budget_in_problem_files_and_on_the_command_line(tmp_path, capsys):
    text = 'name = "c"\n[tube]\ndiameter = 2.43\n[target]\ncurve = "polyline"\ncontrol_points = [[0, 0, 0], [25, 0, 0], [27, -22, 8]]\nsamples = 61\n'
    path = tmp_path / "c.toml"
    path.write_text(text + "[design]\nbudget = 1.5\n")
    assert load_problem(path).problem.options.budget == 1.5
    path.write_text(text)
    assert load_problem(path).problem.options.budget == DesignOptions().budget == settings.Method().budget
    path.write_text(text + "[design]\nbudget = -1\n")
    out = tmp_path / "o.h5"
    assert main(["design", str(path), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {path}: design.budget: must be >= 0"
    path.write_text(text)
    assert main(["design", str(path), "-o", str(out), "--budget", "-2"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: command line: vine-nlp design: argument --budget: must be a finite number >= 0 and <= 604800, got -2"]
    assert not out.exists()
    # --budget 0: no search, the first solve's design is archived; the budget bounds the whole design (issue 48):
    # the second start is cut, and the status says so (exit 1)
    assert main(["design", str(path), "-o", str(out), "--budget", "0", "--starts", "2"]) == 1
    assert out.exists()
    err = capsys.readouterr().err
    assert "corner search" not in err and err.splitlines()[-1] == "c: nlp: max_time, the budget cut 1 of 2 starts"
