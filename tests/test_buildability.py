"""Buildable designs (issue 31): the problem keys, the buildability report, and what show and the template say."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vine_nlp.analysis import buildability as B
from vine_nlp.errors import InputError
from vine_nlp.front.cli import main
from vine_nlp.io.problem_file import load_problem
from vine_nlp.model.routing import Routing

PROBLEM = "[tube]\ndiameter = 2.0\n[target]\ncurve = 'trefoil'\n"
POSE = "[[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]"


# ------------------------------------------------------------------ problem keys


def options(tmp_path, text):
    path = tmp_path / "p.toml"
    path.write_text(PROBLEM + text)
    return load_problem(path).problem.options


def test_build_keys_defaults_and_values(tmp_path):
    o = options(tmp_path, "")
    assert (o.correction_margin, o.min_feature, o.base, o.base_pose) == (0.05, None, "free", None)
    o = options(tmp_path, f"[design]\ncorrection_margin = 0.1\nmin_feature = 0.3\nbase = 'fixed'\n[routing]\ninitial_pose = {POSE}\n")
    assert (o.correction_margin, o.min_feature, o.base) == (0.1, 0.3, "fixed")
    np.testing.assert_array_equal(o.base_pose, [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    # the default margin leaves room whatever lambda_min is
    assert options(tmp_path, "[actuator]\nlambda_min = 0.96\n").correction_margin == pytest.approx(0.02)


BAD = [
    ("[actuator]\nlambda_min = 0.5\n[design]\ncorrection_margin = 0.3\n",
     "design.correction_margin: leaves no room: actuator.lambda_min + margin = 0.8 > 1 - margin = 0.7"),
    ("[design]\ncorrection_margin = -0.1\n", "design.correction_margin: must be >= 0"),
    ("[design]\nmin_feature = -0.2\n", "design.min_feature: must be >= 0"),
    ("[design]\nbase = 'fixed'\n", 'design.base: "fixed" needs a base pose: give [routing] initial_pose (4 x 4)'),
    ("[design]\nbase = 'loose'\n", "design.base: must be one of 'free', 'fixed'"),
    (f"[routing]\ninitial_pose = {POSE}\n", 'routing.initial_pose: a design problem\'s base pose needs [design] base = "fixed"'),
    ("[routing]\ntheta = 0.1\n", "routing.theta: unknown key"),
]


@pytest.mark.parametrize("text, expected", BAD)
def test_bad_build_keys_give_one_exact_line(tmp_path, capsys, text, expected):
    path, out = tmp_path / "bad.toml", tmp_path / "out.h5"
    path.write_text(PROBLEM + text)
    with pytest.raises(InputError, match=None) as info:
        load_problem(path)
    assert str(info.value) == f"{path}: {expected}"
    assert main(["design", str(path), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"error: {path}: {expected}"]
    assert not out.exists()


# ------------------------------------------------------------------ the report

D = 2.5


def routing(theta_deg, lam, dl=2.0):
    lam = np.asarray(lam, float)
    return Routing(theta=np.radians(np.asarray(theta_deg, float)), lam=lam, length=np.full(lam.size, dl))


def step(theta_deg, dl=2.0):
    """The line's turning over one segment, rad: (2 / D) tan(theta) dl."""
    return 2 / D * math.tan(math.radians(theta_deg)) * dl


def test_pieces_and_turning_known_answer():
    r = routing([10, 0, -5, 20, 20, 0], [1, 0.8, 0.7, 1, 1, 0.9])
    rep = B.buildability(r, D, "tendon", 0.4, 0.05, 0.2)
    assert [(p.start, p.stop, p.actuated) for p in rep.pieces] == [(0, 1, False), (1, 3, True), (3, 5, False), (5, 6, True)]
    assert rep.pieces[1].s0 == 2.0 and rep.pieces[1].s1 == 6.0
    assert rep.turning == pytest.approx(step(10) + step(5) + 2 * step(20))
    assert rep.turning_unactuated == pytest.approx(step(10) + 2 * step(20))
    # needed: the change of side between the two actuated pieces; the base's free roll takes segment 0's
    assert rep.turning_needed == pytest.approx(2 * step(20))
    fixed = B.buildability(r, D, base_free=False)
    assert fixed.turning_needed == pytest.approx(step(10) + 2 * step(20))


def test_needed_turning_is_the_shortest_way_round():
    # the unactuated run between the pieces winds 350 deg: the next piece needs the line only 10 deg away
    dl = 1.0
    t = math.degrees(math.atan(math.radians(350) / 4 * D / 2 / dl))  # 4 segments of 87.5 deg of line turning
    r = routing([0, t, t, t, t, 0], [0.8, 1, 1, 1, 1, 0.8], dl)
    rep = B.buildability(r, D)
    assert rep.turning_unactuated == pytest.approx(math.radians(350))
    assert rep.turning_needed == pytest.approx(math.radians(10))


def test_violations_features_and_stoppers():
    lam = [0.98, 0.6, 0.42, 1.0, 0.5]
    r = routing([0, 30, 0, 0, 0], lam)
    rep = B.buildability(r, D, "tendon", lambda_min=0.4, margin=0.05)
    assert rep.violations == [0, 2]  # 0.98 > 1 - margin, 0.42 < lambda_min + margin
    path = r.length / np.cos(r.theta)
    # the template's geometry: centred gaps of (1 - lambda) of a segment's path; stoppers and gaps cover each actuated piece
    stoppers = rep.parts["stoppers"]
    gaps = [f for f in rep.features if f[1] == "stopper gap"]
    assert [g[2] for g in gaps] == [0, 1, 2, 4]
    np.testing.assert_allclose([g[0] for g in gaps], [(1 - lam[j]) * path[j] for j in (0, 1, 2, 4)])
    assert sum(b - a for a, b in stoppers) + sum(g[0] for g in gaps) == pytest.approx(path[[0, 1, 2, 4]].sum())
    assert stoppers[0] == (0.0, pytest.approx(0.98)) and stoppers[1][0] == pytest.approx(1.02)  # lambda / 2 of a 2-long path, then the gap
    assert rep.parts["tendons"] == [pytest.approx(path[:3].sum()), pytest.approx(path[4])]
    assert rep.smallest == (pytest.approx(0.04), "stopper gap", 0) and rep.below == []
    pinches = B.buildability(r, D, "programmed").parts["pinches"]
    assert len(pinches) == 4 and pinches[0] == pytest.approx((0.98, 1.02))


def test_short_gaps_merge_with_their_partners():
    lam = [0.98, 0.6, 0.42, 1.0, 0.5]
    r = routing([0, 30, 0, 0, 0], lam)
    path = r.length / np.cos(r.theta)
    assert B.partners(np.array(lam) != 1).tolist() == [1, 0, -1, -1, -1]
    f = B.gap_fractions(lam, path, 0.2)
    np.testing.assert_allclose(f[:2], [[0.98, 1.0], [0.0, 0.4]])  # at the partners' common end
    assert np.isnan(f[3]).all()
    rep = B.buildability(r, D, "tendon", min_feature=0.2)
    gaps = [g for g in rep.features if g[1] == "stopper gap"]
    assert gaps[0] == (pytest.approx(0.04 + 0.4 * path[1]), "stopper gap", 0) and [g[2] for g in gaps] == [0, 2, 4]
    assert rep.below == []
    # each segment keeps its contraction: stoppers are still lambda of each path in all
    assert sum(b - a for a, b in rep.parts["stoppers"]) == pytest.approx(np.dot(lam, path) - path[3])


def test_pouches_of_the_ideal_pouch_motor():
    assert B.pouch_angle(B.POUCH_LAMBDA_MIN) == pytest.approx(math.pi / 2)
    a = B.pouch_angle(0.8)
    assert math.sin(a) / a == pytest.approx(0.8, abs=1e-12)
    rep = B.buildability(routing([0] * 5, [1, 0.8, 0.8, 0.8, 1]), D, "spam", 0.5)
    assert rep.parts["pouches"] == [(2, pytest.approx(3.0), pytest.approx(a))]  # a 6-long piece: pouches about D = 2.5 long
    rep = B.buildability(routing([0] * 3, [0.6] * 3), D, "spam", 0.5)
    assert rep.parts["pouches"] == [None]
    assert rep.refused == ["piece 0 (segments 0-2): lambda 0.6 is below the ideal pouch motor's 2/pi = 0.637: no pouch contracts that far"]


def test_default_min_feature_is_two_millimetres():
    assert B.default_min_feature("cm") == pytest.approx(0.2) and B.default_min_feature("mm") == 2.0
    assert B.default_min_feature("furlong") == 0.0


# ------------------------------------------------------------------ show and the template


def archive(lam, kind="tendon", theta_deg=10.0, dl=4.0, extra=""):
    from vine_nlp.io.archive import Archive
    from vine_nlp.methods.common import run_forward
    from vine_nlp.problem import ForwardProblem

    lam = np.asarray(lam, float)
    r = Routing(theta=np.full(lam.size, math.radians(theta_deg)), lam=lam, length=np.full(lam.size, dl))
    source = f"[actuator]\nkind = '{kind}'\nlambda_min = 0.4\n[design]\nmin_feature = 0.2\n{extra}"
    return Archive("b", "forward", source, D, runs={"forward": run_forward(ForwardProblem("b", D, r))})


def read_csv(path):
    import csv

    with open(path, newline="") as f:
        return [{k: float(v) if v != "" else math.nan for k, v in row.items()} for row in csv.DictReader(f)]


def test_template_draws_no_actuator_as_removed_and_lists_the_parts(tmp_path):
    ezdxf = pytest.importorskip("ezdxf")
    from vine_nlp.front import template as tpl

    a = archive([0.8, 0.7, 0.9, 1.0, 1.0, 0.6, 0.6], dl=2.5)
    info = tpl.write_template(a, tmp_path / "t.dxf", tmp_path / "c.csv")
    assert info["unactuated"] == 2 and info["refused"] == [] and info["strips"] == 1
    rows = read_csv(tmp_path / "c.csv")
    path = 2.5 / math.cos(math.radians(10))
    assert [r["actuated"] for r in rows] == [1, 1, 1, 0, 0, 1, 1]
    assert [r["piece"] for r in rows][:3] == [0, 0, 0] and math.isnan(rows[3]["piece"]) and rows[6]["piece"] == 1
    assert rows[3]["stopper_length"] == rows[3]["gap_length"] == 0 and math.isnan(rows[3]["gap_start"])
    assert rows[0]["tendon_length"] == pytest.approx(3 * path) and rows[5]["tendon_length"] == pytest.approx(2 * path)
    assert rows[1]["gap_end"] - rows[1]["gap_start"] == pytest.approx(0.3 * path)  # 0.76 cm: centred, alone
    assert rows[1]["gap_start"] == pytest.approx(path + 0.35 * path)
    assert math.isnan(rows[0]["pouches"]) and math.isnan(rows[0]["pinch_length"])
    doc = ezdxf.readfile(tmp_path / "t.dxf")

    def length(layer):
        return sum(math.dist(tuple(e.dxf.start)[:2], tuple(e.dxf.end)[:2]) for e in doc.modelspace().query(f'LINE[layer=="{layer}"]'))

    # 1:1 in mm: stoppers, gaps, and the unactuated segments' path on the layer "removed"
    assert length("stoppers") == pytest.approx(10 * sum(r["stopper_length"] for r in rows), rel=1e-9)
    assert length("removed") == pytest.approx(10 * (sum(r["gap_length"] for r in rows) + 2 * path), rel=1e-9)
    pdf = tpl.write_template(a, tmp_path / "t.pdf")
    assert pdf["unactuated"] == 2 and pdf["gaps"] == 5


def test_template_parts_per_actuator_kind(tmp_path):
    from vine_nlp.front import template as tpl

    tpl.write_template(archive([0.9, 0.95, 1.0], "programmed"), tmp_path / "p.pdf", tmp_path / "p.csv")
    rows = read_csv(tmp_path / "p.csv")
    assert [r["pinch_length"] for r in rows[:2]] == [pytest.approx(r["gap_length"]) for r in rows[:2]] and math.isnan(rows[2]["pinch_length"])
    info = tpl.write_template(archive([0.8] * 4 + [1.0], "spam", dl=2.5), tmp_path / "s.pdf", tmp_path / "s.csv")
    rows = read_csv(tmp_path / "s.csv")
    assert info["spam"] and info["refused"] == []
    path = 2.5 / math.cos(math.radians(10))
    assert rows[0]["pouches"] == 4 and rows[0]["pouch_length"] == pytest.approx(path) and math.isnan(rows[4]["pouches"])
    info = tpl.write_template(archive([0.6] * 3, "spam"), tmp_path / "r.pdf", tmp_path / "r.csv")
    assert info["refused"] == ["piece 0 (segments 0-2): lambda 0.6 is below the ideal pouch motor's 2/pi = 0.637: no pouch contracts that far"]
    assert math.isnan(read_csv(tmp_path / "r.csv")[0]["pouches"])


def test_show_reports_buildability():
    from vine_nlp.front.show import summarize

    text = summarize(archive([0.8, 0.7, 0.9, 1.0, 1.0, 0.6, 0.6], extra="correction_margin = 0.15\n"))
    assert "actuated    2 piece(s) (segments 0-2, 5-6), 2 segment(s) without an actuator (lambda = 1)" in text
    assert "stoppers    7, tendon(s) 12.1851, 8.12341 cm" in text  # a stopper at each end of a piece and between its gaps
    turns = [t / (2 * math.pi) for t in (7 * step(10, 4.0), 2 * step(10, 4.0), 2 * step(10, 4.0))]
    assert f"line turns  {turns[0]:.3g} in all, {turns[1]:.3g} where lambda = 1 (the routing needs {turns[2]:.3g} there)" in text
    assert "smallest    0.406171 cm stopper gap (0 below min_feature 0.2 cm)" in text
    assert "margin      1 segment(s) with lambda neither 1 nor in [0.55, 0.85]" in text
    text = summarize(archive([0.6] * 3, "spam"))
    assert "pouches     - (ideal pouch motor); refused: piece 0" in text
