"""Buildable designs (issue 31): the formulation (methods.buildable) and what the doors make of it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import vine_nlp as vn
from vine_nlp.analysis.buildability import buildability, pieces, turning
from vine_nlp.api import ArgumentError
from vine_nlp.front.cli import main
from vine_nlp.io.problem_file import ProblemFile, load_problem
from vine_nlp.methods import buildable as B
from vine_nlp.methods import drive, settings
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.model import shape_lines
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import Routing
from vine_nlp.pipeline import Request
from vine_nlp.pipeline import run as run_pipeline
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, Result

HOOK = "problems/hook.toml"
STRAIGHT = 26  # the hook's segments on its first 60 cm (2.28 cm a segment)


def build(**kw) -> B.Build:
    return B.Build(**({"D": 2.0, "theta_max": math.radians(60), "kind": "tendon", "lambda_min": 0.4, "margin": 0.05,
                       "min_feature": 0.2} | kw))


def within_margins(lam, lo, hi):
    return np.all((lam == 1.0) | ((lam >= lo - 1e-9) & (lam <= hi + 1e-9)))


@pytest.fixture(scope="module")
def hook():
    return vn.solve(HOOK)


def test_hook_from_the_defaults_has_no_actuator_on_its_straight_part(hook):
    r, pb = hook.result.routing, load_problem(HOOK).problem
    assert hook.result.ok and hook.result.stats["buildable"]
    assert np.all(r.lam[:STRAIGHT] == 1.0)  # exactly: no pouch, stopper or pinch
    assert np.all(r.lam[STRAIGHT + 1:] < 1.0)  # the half circle bends everywhere
    assert np.all(r.theta[:STRAIGHT] == 0.0)  # the line held: its side set by the base roll
    rotation = math.degrees(math.acos(np.clip((np.trace(r.initial_pose[:3, :3]) - 1) / 2, -1, 1)))
    assert rotation < 0.5  # the target starts along +x at the origin: no roll
    b = B.Build.of(pb)
    rep = buildability(r, pb.diameter, "tendon", 0.4, b.margin, b.min_feature)
    assert rep.violations == [] and rep.below == [] and rep.turning_unactuated == 0.0
    assert hook.result.metrics["rmse"] <= B.accuracy_budget(pb, hook.result.stats["buildable_free_rmse"])


def test_every_segment_is_exactly_one_or_inside_the_margins(hook):
    pb, r = load_problem(HOOK).problem, hook.result.routing
    lo, hi = B.lambda_bounds(r.lam != 1.0, r.length, B.Build.of(pb))
    assert within_margins(r.lam, lo, hi) and np.all(r.lam[r.lam != 1.0] <= 0.95 + 1e-9)


def test_a_fixed_base_is_kept_exactly():
    pb = load_problem(HOOK).problem
    pose = np.eye(4)
    pose[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # rolled a quarter turn: the line must come round on the straight part
    d = vn.design(pb.target, pb.diameter, base=pose)
    r = d.result.routing
    np.testing.assert_array_equal(r.initial_pose, pose)
    assert np.all(r.lam[:STRAIGHT] == 1.0) and d.rmse < 0.01
    _, free, need = turning(r.theta, r.length, pb.diameter, r.lam != 1.0, base_free=False)
    assert need == pytest.approx(math.pi / 2, abs=0.05) and free == pytest.approx(need, rel=1e-6)  # the shortest way round


def test_a_free_design_inside_its_bounds_is_taken_without_a_solve_but_not_with_a_fixed_base():
    pb = load_problem("problems/trefoil-m4.toml").problem
    free = design_nlp(pb)
    res = B.design_buildable(pb, free)
    assert res.stats["buildable_rounds"] == 0 and res.stats["solves"] == 1 and np.all(res.routing.lam < 1.0)
    np.testing.assert_array_equal(res.routing.lam, free.routing.lam)
    pose = free.routing.initial_pose.copy()
    pose[:3, 3] += [0.0, 0.0, 0.1]  # 1 mm off the free design's: the free design is not this problem's
    fixed = dataclasses.replace(pb, options=dataclasses.replace(pb.options, base="fixed", base_pose=tuple(map(tuple, pose))))
    res = B.design_buildable(fixed, free)
    np.testing.assert_array_equal(res.routing.initial_pose, pose)
    assert res.stats["buildable_rounds"] >= 1 and res.metrics["rmse"] <= B.accuracy_budget(pb, free.metrics["rmse"]) + 0.1


def test_a_buildable_routing_is_recovered():
    """Known answer: a target the forward model makes from a buildable routing (straight runs, the line turned the
    shortest way, actuated segments inside the margins) gets that routing's classes and shape back."""
    M, n, D = 14, 6, 2.0
    lam = np.array([1, 1, 0.6, 0.7, 0.8, 1, 1, 1, 0.65, 0.7, 0.75, 0.7, 1, 1], float)
    theta = np.where(lam < 1, np.radians([0, 0, 10, 15, 5, 0, 0, 0, -10, -5, 0, 5, 0, 0]), 0.0)
    theta[5:8] = np.arctan(0.5 * D * 1.2 / 6.0)  # 1.2 rad of turning over the 6 cm run
    length = np.full(M, 2.0)
    seg, frac = segment_end_samples(length, n)
    center = shape_lines(theta, lam, length, D, seg, frac, np.eye(4))[0]
    pb = DesignProblem("known", D, center, Actuator(), DesignOptions(points_per_segment=n, min_feature=0.1))
    res = vn.solve(pb).result
    np.testing.assert_array_equal(res.routing.lam == 1.0, lam == 1.0)
    assert res.metrics["rmse"] < 5e-4 * D  # the build effort's pull on the actuated thetas: 0.003 mm here
    assert np.allclose(res.routing.lam, lam, atol=0.01) and np.allclose(res.routing.theta[5:8], theta[5:8], atol=math.radians(0.2))


def _bent_everywhere(M=16, n=6, D=2.0, **options):
    """A target the forward model makes from a routing actuated on every segment, inside the margins."""
    lam = np.linspace(0.6, 0.85, M)
    theta = np.radians(np.linspace(-20.0, 25.0, M))
    length = np.full(M, 2.0)
    seg, frac = segment_end_samples(length, n)
    center = shape_lines(theta, lam, length, D, seg, frac, np.eye(4))[0]
    return DesignProblem("bent", D, center, Actuator(), DesignOptions(points_per_segment=n, **options)), theta, lam


def test_a_target_bent_everywhere_is_designed_in_one_solve():
    """Issue 46: where the target's bends actuate every segment in every phase, the buildable problem is solved
    once, inside the band (no free design, no round), and the known routing comes back."""
    pb, theta, lam = _bent_everywhere()
    lo, hi = B.band(pb)
    b = B.Build.of(pb)
    assert np.all(lo == b.lo) and np.all(hi <= 1 - b.margin) and np.all(hi > lam.max())
    res = vn.solve(pb).result
    assert res.ok and res.stats["buildable_one_solve"] and res.stats["lambda_band"] and res.stats["buildable_rounds"] == 0
    assert "buildable_free_rmse" not in res.stats  # no free design was made
    assert res.stats["solves"] == 1 and res.metrics["rmse"] < 1e-4 * pb.diameter
    np.testing.assert_allclose(res.routing.lam, lam, atol=1e-3)
    np.testing.assert_allclose(res.routing.theta, theta, atol=math.radians(0.1))
    assert B.missed(pb, res) == []


def test_the_band_only_where_nothing_is_left_to_decide():
    pb, _, _ = _bent_everywhere()
    assert B.band(load_problem(HOOK).problem) is None  # a straight run: the free design decides the classes
    assert B.band(dataclasses.replace(pb, actuator=Actuator(kind="spam"))) is None  # one lambda: its own band
    fixed = dataclasses.replace(pb, options=dataclasses.replace(pb.options, base="fixed", base_pose=np.eye(4)))
    assert B.band(fixed) is None  # a fixed base: the rounds place the line


def test_compare_shows_the_free_design_beside_the_one_solve():
    """compare's nlp_free is a free design (lambda up to 1, no band) where the nlp run was solved inside the band."""
    pb, _, _ = _bent_everywhere(M=10)
    found = run_pipeline(ProblemFile(kind="design", name="bent", path=None, problem=pb, source="", units="cm"), Request(methods=("nlp_free", "nlp")))
    assert found.runs["nlp"].stats["buildable_one_solve"] and "lambda_band" not in found.runs["nlp_free"].stats


def test_unwinding_keeps_the_shape_and_takes_the_shortest_way():
    rng = np.random.default_rng(3)
    M, D = 12, 2.0
    act = np.array([0, 0, 1, 1, 0, 0, 0, 1, 1, 1, 0, 0], bool)
    theta = rng.uniform(-1.0, 1.0, M)
    lam = np.where(act, rng.uniform(0.5, 0.9, M), 1.0)
    r = Routing(theta=theta, lam=lam, length=np.full(M, 2.0), initial_pose=np.eye(4))
    u = B.unwind(r, act, build(D=D))
    seg, frac = segment_end_samples(r.length, 5)
    a, b = (shape_lines(x.theta, x.lam, x.length, D, seg, frac, x.initial_pose)[0] for x in (r, u))
    np.testing.assert_allclose(a, b, atol=1e-9)
    assert np.all(u.theta[:2] == 0.0) and np.all(u.theta[10:] == 0.0)  # into the base roll; nothing downstream
    assert np.ptp(u.theta[4:7]) < 1e-12  # the inner run at one slope
    _, free, need = turning(u.theta, u.length, D, act)
    assert free == pytest.approx(need) and need <= math.pi


def test_classes_known_answers():
    b = build()
    length = np.full(30, 2.0)
    kappa, _, lc = (np.asarray(v) for v in center_rates(0.0, B.upper(length, np.zeros(30, bool), b), b.D))
    alone = kappa * lc * length
    assert not B.classify(np.zeros(30), length, b).any()  # straight: no actuator
    assert B.classify(np.full(30, 0.3), length, b).all()  # bent beyond the least bend: everywhere
    act = B.classify(np.full(30, 0.25 * alone[0]), length, b)  # a quarter of the least bend: about every fourth
    assert 6 <= act.sum() <= 8 and np.all(np.diff(np.flatnonzero(act)) >= 3)
    assert B.classify(np.zeros(5), np.full(5, 2.0), build(kind="spam")).all()  # an sPAM's pouches run the whole tube


def test_lambda_bounds_mask_partners_and_spam():
    b = build(min_feature=0.3)
    act = np.array([0, 1, 1, 1, 0], bool)
    lo, hi = B.lambda_bounds(act, np.full(5, 2.0), b)
    np.testing.assert_array_equal(lo, [1, 0.45, 0.45, 0.45, 1])
    # segments 1, 2 are partners (their joined gap 0.3 of 4 cm); segment 3 alone needs 0.3 of 2 cm; with the slack
    k = settings.FEATURE_SLACK
    np.testing.assert_allclose(hi, [1, 1 - k * 0.3 / 4, 1 - k * 0.3 / 4, 1 - k * 0.3 / 2, 1])
    lo, hi = B.lambda_bounds(np.ones(3, bool), np.full(3, 2.0), build(kind="spam", lambda_min=0.5))
    np.testing.assert_allclose([lo[0], hi[0]], [2 / math.pi + 0.05, 0.95])


def test_spam_keeps_one_lambda_inside_the_pouch_range():
    d = vn.solve("problems/spam-helix.toml").result
    lam = d.routing.lam
    assert np.ptp(lam) == 0.0 and 2 / math.pi + 0.05 - 1e-9 <= lam[0] <= 0.95 + 1e-9


class _Fake:
    """A solve whose RMSE is 1 + how many classes differ from ``want``; its multipliers ask for ``want`` (and, lying,
    for no actuator at ``lie``)."""

    def __init__(self, want, lie=()):
        self.want, self.lie = np.asarray(want, bool), list(lie)

    def __call__(self, act, start, round=0):
        miss = int(np.sum(act != self.want))
        res = Result("nlp", Routing(theta=start.theta, lam=np.where(act, 0.95, 1.0), length=start.length, initial_pose=start.initial_pose), None, status="optimal",
                     metrics={"rmse": 1.0 + miss})
        mult = np.where(self.want & ~act, -1.0, np.where(~self.want & act, 1.0, 0.0))
        mult[self.lie] = 1.0
        return res, mult


WANT = np.array([1, 1, 0, 1, 0, 0, 1, 0], bool)
START = Routing(theta=np.zeros(8), lam=np.full(8, 0.9), length=np.full(8, 2.0), initial_pose=np.eye(4))


@pytest.mark.parametrize("act, limit, lie, rounds", [
    (np.zeros(8, bool), 0.5, (), 2),  # over the budget: actuators where the multipliers ask for contraction, all at once
    (WANT | (np.arange(8) == 2), 0.5, (), 2),  # an actuator at its top that asks for less goes
    (WANT, 0.5, (0,), 2),  # a removal that leaves the RMSE higher is not kept
    (WANT, 1.5, (0,), 1),  # within the budget: done
])
def test_reclassify_rule_flips_what_the_multipliers_ask_for(act, limit, lie, rounds):
    rule = B.Reclassify(_Fake(WANT, lie), act, build(min_feature=0.0), limit=limit)
    found = drive.refine(rule, settings.BUILDABLE_ROUNDS, START)
    np.testing.assert_array_equal(rule.act, WANT)
    np.testing.assert_array_equal(found.best.routing.lam == 1.0, ~WANT)
    assert found.best.metrics["rmse"] == 1.0 and found.rounds == rounds


def test_the_race_keeps_the_lowest_rmse_and_the_lowest_objective_after_a_few_iterations_and_no_flips_follow():
    """Every phase solved settings.PHASE_ITER iterations from the same start (counted); the classes and iterates (unwound)
    of the lowest RMSE and of the lowest objective, once where they agree; the full solve from one takes no flips."""
    seen = []

    def capped(act, start, cap, objective=None):
        seen.append((start.lam[0], cap))
        res, _ = _Fake(WANT)(act, start)
        res.objective = res.metrics["rmse"] if objective is None else objective[len(seen) - 1]
        res.routing.theta[:] = 0.1 * len(seen)  # which solve's iterate
        return res

    far, near = ~WANT, WANT ^ (np.arange(8) == 0)  # RMSE 9 and 2
    stats = drive.Stats()
    (act, start), = B.race(capped, [far, near, WANT], START, build(min_feature=0.0), stats)
    np.testing.assert_array_equal(act, WANT)
    assert seen == [(0.9, settings.PHASE_ITER)] * 3 and stats.solves == 3
    np.testing.assert_array_equal(start.lam == 1.0, ~WANT)  # the winner's iterate, unwound: theta 0 on the last run
    assert start.theta[0] == pytest.approx(0.3)
    seen.clear()
    found = B.race(lambda a, r, cap: capped(a, r, cap, [3.0, 0.5, 1.0]), [far, near, WANT], START, build(min_feature=0.0), stats)
    assert [a.tolist() for a, _ in found] == [WANT.tolist(), near.tolist()] and found[1][1].theta[1] == pytest.approx(0.2)
    rule = B.Reclassify(_Fake(WANT), near, build(min_feature=0.0), limit=0.5, flips=False)
    assert drive.refine(rule, settings.BUILDABLE_ROUNDS, START).rounds == 1 and np.array_equal(rule.act, near)


def test_phases_are_distinct_and_the_default_comes_first():
    b, length = build(), np.full(30, 2.0)
    kappa, _, lc = (np.asarray(v) for v in center_rates(0.0, B.upper(length, np.zeros(30, bool), b), b.D))
    bends = np.full(30, 0.3 * kappa[0] * lc[0] * 2.0)  # 0.3 of the isolated actuator's least bend per segment
    found = B.phases(bends, length, b)
    np.testing.assert_array_equal(found[0], B.classify(bends, length, b))
    assert len(found) == len({a.tobytes() for a in found}) >= 3
    assert all(abs(a.sum() - 0.3 * 30) <= 3 for a in found[:3])  # as many actuators, elsewhere
    assert len(B.phases(np.zeros(30), length, b)) == 1 and len(B.phases(np.full(30, 0.3), length, b)) == 1  # one answer: once


BAD_API = [
    ({"correction_margin": 0.4}, "correction_margin: leaves no room: actuator.lambda_min + margin = 0.8 > 1 - margin = 0.6"),
    ({"correction_margin": -0.1}, "correction_margin: must be >= 0"),
    ({"min_feature": -1}, "min_feature: must be >= 0"),
    ({"base": "fixed"}, 'base: "fixed" needs a base pose: pass the pose (4 x 4) as base'),
    ({"base": "loose"}, "base: must be one of 'free', 'fixed'"),
    ({"base": np.ones((4, 4))}, "base: last row must be [0, 0, 0, 1]"),
    ({"base": 3}, "base: must be a 4 x 4 array (4 rows of 4 numbers)"),
]


@pytest.mark.parametrize("kw, expected", BAD_API)
def test_bad_build_arguments_name_the_argument(kw, expected):
    with pytest.raises(ArgumentError) as info:
        vn.design(np.c_[np.linspace(0, 10, 21), np.zeros(21), np.zeros(21)], 1.0, **kw)
    assert str(info.value) == expected


def test_bad_margin_on_the_command_line(tmp_path, capsys):
    path, out = tmp_path / "p.toml", tmp_path / "o.h5"
    path.write_text("[tube]\ndiameter = 2.0\n[target]\ncurve = 'trefoil'\n[design]\ncorrection_margin = 0.35\n")
    assert main(["design", str(path), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"error: {path}: design.correction_margin: leaves no room: actuator.lambda_min + margin = 0.75 > 1 - margin = 0.65"]
    assert not out.exists()


@pytest.mark.slow
def test_robust_and_clearance_keep_the_classes(hook):
    pb = load_problem(HOOK).problem
    d = vn.design(pb.target, pb.diameter, robust={"theta_deg": 1.0, "lambda": 0.02, "length": 0.02}, clearance=0.0)
    act = d.runs["nlp"].result.routing.lam != 1.0
    lo, hi = B.lambda_bounds(act, d.runs["nlp"].result.routing.length, B.Build.of(pb))
    for run in ("nlp_robust", "nlp_clearance"):
        lam = d.runs[run].result.routing.lam
        np.testing.assert_array_equal(lam == 1.0, ~act)
        assert within_margins(lam, lo, hi)
    assert [p.actuated for p in pieces(act, np.ones(act.size), np.ones(act.size))] == [False, True]


# ---------------------------------------------------------------- the rules every design is judged by (issue 46)


def _rules(theta, lam, length, **kw):
    b = build(**kw)
    r = Routing(theta=np.asarray(theta, float), lam=np.asarray(lam, float), length=np.asarray(length, float), initial_pose=np.eye(4))
    return buildability(r, b.D, b.kind, b.lambda_min, b.margin, b.min_feature).missed(b.lo, 1 - b.margin, "cm")


def test_a_buildable_routing_misses_no_rule():
    assert _rules(np.zeros(6), [1, 1, 0.7, 0.7, 1, 1], np.full(6, 2.0)) == []


def test_an_actuator_that_barely_contracts_is_not_lambda_one():
    lines = _rules(np.zeros(4), [1, 1 - 1e-8, 0.7, 1], np.full(4, 2.0))
    assert lines == ["1 segment(s) with lambda neither 1 nor in [0.45, 0.95] (correction margin; segments 1)"]


def test_min_feature_is_met_to_the_last_digit():
    # one actuated segment of 2 cm whose gap is 1e-7 cm short of 0.2 cm: missed, and said to the digit that shows it
    lines = _rules(np.zeros(3), [1, 1 - (0.2 - 1e-7) / 2.0, 1], np.full(3, 2.0), margin=0.01)
    assert lines == ["1 feature(s) below min_feature 0.2 cm (smallest: 0.1999999 cm stopper gap)"]
    assert _rules(np.zeros(3), [1, 0.9, 1], np.full(3, 2.0), margin=0.01) == []  # exactly 0.2: met


def test_turning_where_lambda_is_one_beyond_the_need_is_pointless():
    D, L = 2.0, 2.0
    turn = math.atan(0.5 * D * math.pi / (3 * L))  # half a turn over segments 2-4 between the two pieces
    theta = [0.0, 0.0, turn, turn, turn, 0.0]
    assert _rules(theta, [0.7, 0.7, 1, 1, 1, 0.7], np.full(6, L)) == []  # the shortest way (half a turn both ways)
    wound = np.arctan(3 * np.tan(theta))  # 1.5 turns: the line winds once for nothing
    assert _rules(wound, [0.7, 0.7, 1, 1, 1, 0.7], np.full(6, L)) == [
        "the actuator line turns 1.5 turn(s) where lambda = 1, the routing needs 0.5 there (pointless turning)"]


def test_bundled_tip_target_is_buildable_and_exits_zero(tmp_path, capsys):
    assert main(["design", "problems/tip-target.toml", "-o", str(tmp_path / "t.h5")]) == 0
    d = vn.solve("problems/tip-target.toml")
    r, pb = d.result, load_problem("problems/tip-target.toml").problem
    assert d.result.status == "optimal" and d.result.metrics["tip_error"] < 1e-6
    assert (r.routing.lam == 1.0).sum() >= 5 and within_margins(r.routing.lam, 0.45, 0.95)
    assert B.missed(pb, r) == [] and r.buildable


def test_multishape_levels_stay_in_the_band_and_a_fixed_one_outside_is_a_shortfall(tmp_path, capsys):
    text = open("problems/multishape-spam.toml").read().replace("correction_margin = 0.025", "correction_margin = 0.05")
    (tmp_path / "ms.toml").write_text(text)
    d = vn.solve(tmp_path / "ms.toml")  # the target at 0.97: its free level held at 1 - margin
    lo = 2 / math.pi + 0.05
    assert np.all((d.result.levels >= lo - 1e-9) & (d.result.levels <= 0.95 + 1e-9)) and d.result.shortfall == ()
    assert d.result.levels[2] == pytest.approx(0.95, abs=1e-6)
    (tmp_path / "ms.toml").write_text(text.replace("lambda = 0.87", "lambda = 0.97"))  # a fixed level above the band
    assert main(["design", str(tmp_path / "ms.toml"), "-o", str(tmp_path / "ms.h5")]) == 1
    assert f"not buildable: level 0: lambda 0.97 outside [{lo:.6g}, 0.95] (correction margin)" in capsys.readouterr().err


POLE = """name = "pole"
units = "cm"
[tube]
diameter = 2.5
[target]
curve = "bezier"
control_points = [[0, 0, 0], [20, 0, 0], [40, 25, 0], [60, 25, 0]]
samples = 401
[design]
points_per_segment = 10
obstacle_margin = 0.5
[[obstacles]]
shape = "capsule"
p0 = [30, 12.5, -10]
p1 = [30, 12.5, 10]
radius = 3.0
"""


@pytest.mark.slow
def test_the_pole_design_is_buildable_and_clear(tmp_path):
    (tmp_path / "pole.toml").write_text(POLE)
    d = vn.solve(tmp_path / "pole.toml")
    pb = load_problem(tmp_path / "pole.toml").problem
    r = d.runs["nlp"].result
    assert d.ok and r.metrics["min_obstacle_gap"] >= 0.5 - 1e-6 and B.missed(pb, r) == []
    assert (r.routing.lam == 1.0).sum() >= 5
    assert set(d.runs) == {"nlp", "nlp_no_obstacles"} and d.runs["nlp_no_obstacles"].result.metrics["min_obstacle_gap"] < 0


# one of each kind, and the obstacle problem whose two runs took different steps before the sampled blocks agreed bitwise
SAME_DESIGN = ("trefoil-m4", "spam-helix", "tip-target", "multishape-spam", "obstacle-gap", "obstacle-pipe-bend", "obstacle-tip-wall",
               "obstacle-wrap-cylinder")


def _runs(name: str) -> dict:
    from vine_nlp.io.problems import load_problem as load
    from vine_nlp.methods.transcription import clear_caches
    from vine_nlp.pipeline.runs import run

    clear_caches()  # the built solvers are kept per structure, whatever the setting they were built under
    return {n: r.routing for n, r in run(load(f"problems/{name}.toml")).runs.items()}


@pytest.mark.slow
@pytest.mark.parametrize("name", SAME_DESIGN)
def test_a_first_run_and_a_later_run_give_one_design(name, monkeypatch, tmp_path):
    # the first run solves on the interpreted functions (the compiler works in the background), later runs on the
    # compiled ones: the same design (issue 46)
    from vine_nlp.methods import compiled

    if compiled.compiler() is None:
        pytest.skip("no C compiler on this machine")
    monkeypatch.setenv("VINE_NLP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("VINE_NLP_CFLAGS", "-O0")  # quicker to compile; neither flag reorders arithmetic
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    first = _runs(name)
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    later = _runs(name)
    assert first.keys() == later.keys()
    for run, r in first.items():
        for key in ("theta", "lam", "length"):
            np.testing.assert_allclose(getattr(later[run], key), getattr(r, key), rtol=0, atol=1e-6, err_msg=f"{run} {key}")


def test_a_tip_problem_takes_its_own_margin(tmp_path):
    # the default design's actuated segments sit near 0.53-0.57 (lambda_min 0.4): a margin of 0.2 moves them into [0.6, 0.8]
    text = open("problems/tip-target.toml").read().replace("[design]\n", "[design]\ncorrection_margin = 0.2\n")
    (tmp_path / "tip.toml").write_text(text)
    d = vn.solve(tmp_path / "tip.toml")
    assert d.ok and within_margins(d.result.routing.lam, 0.6, 0.8) and np.any(d.result.routing.lam < 1.0)
