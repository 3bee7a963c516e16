"""Self-weight and payload (issue 45): the mechanics against closed forms and an independent sum, [load]
files, the judgement and the design with the load rows."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import vine_nlp
from vine_nlp.analysis.loads import METRES_PER_UNIT, _samples, load_report
from vine_nlp.front.cli import main
from vine_nlp.front.show import summarize
from vine_nlp.io.archive import load_archive, write_archive
from vine_nlp.methods.loads import BUDGET
from vine_nlp.model.routing import Routing
from vine_nlp.problem import Load


def _tilted(alpha_deg: float, L: float, M: int = 8) -> Routing:
    """A straight tube of length L along (cos a, 0, sin a)."""
    a = math.radians(alpha_deg)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]]
    return Routing(theta=np.zeros(M), lam=np.ones(M), length=np.full(M, L / M), initial_pose=T)


@pytest.mark.parametrize("alpha,w,m", [(0.0, 0.03, 0.0), (30.0, 0.05, 0.02), (-45.0, 0.0, 0.1), (70.0, 0.2, 0.05), (0.0, 0.04, 0.01)])
@pytest.mark.parametrize("units", ["cm", "m"])
def test_straight_cantilever_closed_form(alpha, w, m, units):
    """Margin and least pressure of a straight cantilever: w L^2 / 2 + m g L (times cos of the tilt) against pi P r^3."""
    k = METRES_PER_UNIT[units]
    L, D, P, safety = 1.2 / k, 0.05 / k, 4.0, 1.5
    load = Load(pressure=P, mass_per_length=w, tip_mass=m, safety=safety)
    rep = load_report(_tilted(alpha, L), D, units, load)
    g, Lm = 9.81, L * k
    moment = (w * g * Lm**2 / 2 + m * g * Lm) * math.cos(math.radians(alpha))
    capacity = math.pi * P * 1e3 * (D * k / 2) ** 3
    assert rep["margin"] == pytest.approx(capacity / moment, rel=1e-3)
    assert rep["min_pressure"] == pytest.approx(P * safety * moment / capacity, rel=1e-3)
    assert rep["collapse_at"] == pytest.approx(0.0, abs=1e-9)  # the base carries the most
    assert rep["holds"] == (capacity / moment >= safety)


def test_standing_straight_up_carries_no_moment():
    rep = load_report(_tilted(90.0, 100.0), 5.0, "cm", Load(pressure=1.0, mass_per_length=1.0, tip_mass=1.0, safety=2.0))
    assert rep["margin"] == math.inf and rep["min_pressure"] == 0.0 and math.isnan(rep["collapse_at"]) and rep["holds"]


def _curved() -> Routing:
    rng = np.random.default_rng(3)
    M = 6
    T = np.eye(4)
    T[:3, :3] = [[0.8, 0, -0.6], [0, 1, 0], [0.6, 0, 0.8]]
    return Routing(theta=rng.uniform(-0.6, 0.6, M), lam=np.array([1, 0.7, 0.9, 1, 0.5, 0.8]), length=rng.uniform(8, 15, M), initial_pose=T)


def test_moment_along_a_curved_shape_matches_an_independent_sum():
    """The report's moment (20 samples per segment, pieces at their chord middles) against a plain double sum
    over 400 points per segment (point masses by the trapezoid rule), at the segment ends, within 0.1 %."""
    r, D, units = _curved(), 3.0, "cm"
    load = Load(pressure=5.0, mass_per_length=0.08, tip_mass=0.03, gravity=(0.0, -2.0, -9.81), safety=1.0)
    rep = load_report(r, D, units, load, growth="after")  # the final shape's moment
    pts, t, s, l, _ = _samples(r, D, 400)
    pts, l = pts * 0.01, l * 0.01
    g = np.array(load.gravity)
    dm = load.mass_per_length * np.gradient(l) * 1.0
    dm[[0, -1]] = load.mass_per_length * np.diff(l)[[0, -1]] / 2  # trapezoid weights
    ends = np.arange(0, len(pts), 400)
    expect = []
    for k in ends:
        Mk = np.zeros(3)
        for i in range(k, len(pts)):
            Mk += np.cross(pts[i] - pts[k], dm[i] * g)
        Mk += np.cross(pts[-1] - pts[k], load.tip_mass * g)
        expect.append(np.linalg.norm(Mk - Mk.dot(t[k]) * t[k]))
    got = rep["moment"][np.arange(0, len(rep["s"]), 20)]
    assert got == pytest.approx(np.array(expect), rel=1e-3)
    assert np.all(got[:-1] > 0)


def test_growth_prefix_loads_more_than_the_final_shape():
    """A tube that reaches out and turns back up: grown part way, with the payload at its tip far out, the
    base carries more than at the end (the tip mass back over the base)."""
    M = 10
    theta = np.zeros(M)
    lam = np.r_[np.ones(5), np.full(5, 0.55)]
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # the actuator on top: the second half curls up and back
    r = Routing(theta=theta, lam=lam, length=np.full(M, 10.0), initial_pose=T)
    load = Load(pressure=3.0, mass_per_length=0.01, tip_mass=0.2, safety=1.0)
    rep = load_report(r, 4.0, "cm", load)
    after = load_report(r, 4.0, "cm", load, growth="after")
    assert np.all(rep["moment_growth"] >= rep["moment"] - 1e-12)
    assert rep["moment_growth"][0] > 1.05 * rep["moment"][0]
    # one of the base's prefixes: 50 cm of straight reach with the payload at its end
    assert rep["moment_growth"][0] >= 9.81 * (0.01 * 0.5**2 / 2 + 0.2 * 0.5) * (1 - 1e-9)
    # actuated after growth: the straight metre grown first, payload at its end
    assert after["moment_growth"][0] == pytest.approx(9.81 * (0.01 * 1.0**2 / 2 + 0.2 * 1.0), rel=1e-3)


# ---------------------------------------------------------------- [load] files and the judgement

BUNDLED = Path(__file__).resolve().parents[1] / "problems" / "load-reach.toml"

FORWARD = """name = "cantilever"
units = "cm"
[tube]
diameter = 5.0
[routing]
length = 100.0
segment_length = 10.0
theta = 0.0
lambda = 1.0
[load]
pressure = {pressure}
mass_per_length = 0.04
tip_mass = 0.02
safety = 1.5
"""


def _need() -> float:
    """The straight horizontal metre's least pressure, kPa: 1.5 (w g L^2 / 2 + m g L) / (pi r^3)."""
    return 1.5 * 9.81 * (0.04 / 2 + 0.02) / (math.pi * 0.025**3) / 1e3


def test_judgement_exits_1_with_its_line_below_the_needed_pressure(tmp_path, capsys):
    need = _need()
    for factor, code in ((0.5, 1), (1.01, 0)):
        p = tmp_path / f"c{factor}.toml"
        p.write_text(FORWARD.format(pressure=repr(need * factor)))
        out = tmp_path / f"c{factor}.h5"
        assert main(["forward", str(p), "-o", str(out)]) == code
        err = capsys.readouterr().err.strip().splitlines()
        if code:
            assert err == [f"cantilever: forward: optimal; folds under its weight at s = 0 cm (load margin {1.5 * factor:.3g} < safety 1.5 "
                           f"at {need * factor:g} kPa); it needs at least {need:.4g} kPa"]
        else:
            assert err == []
        m = load_archive(out).runs["forward"].metrics
        assert m["load_margin"] == pytest.approx(1.5 * factor, rel=1e-3) and m["min_pressure"] == pytest.approx(need, rel=1e-3)


@pytest.mark.parametrize("change,line", [
    ("pressure = -1.0", "load.pressure: must be > 0, got -1"),
    ("pressure = 0", "load.pressure: must be > 0, got 0"),
    ("mass_per_length = -0.1", "load.mass_per_length: must be >= 0, got -0.1"),
    ("tip_mass = -2", "load.tip_mass: must be >= 0, got -2"),
    ("safety = 0.5", "load.safety: must be >= 1, got 0.5"),
    ("gravity = [0.0, 0.0, 0.0]", "load.safety: asks for a safety factor under zero gravity: nothing weighs (give gravity)"),
    ("gravity = [0.0, -9.81]", "load.gravity: must be a list of 3 numbers"),
    ("tip_mas = 0.1", "load.tip_mas: unknown key; did you mean 'tip_mass'?"),
    ("units_ = 1", "load.units_: unknown key"),
])
def test_bad_load_keys_give_one_error_line(tmp_path, capsys, change, line):
    text = BUNDLED.read_text()
    key = change.split(" = ")[0]
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith(f"{key} =")) + "\n" + change + "\n"
    p, out = tmp_path / "bad.toml", tmp_path / "bad.h5"
    p.write_text(text)
    assert main(["design", str(p), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"error: {p}: {line}"]
    assert not out.exists()


def test_load_needs_units_that_convert_to_metres(tmp_path, capsys):
    p, out = tmp_path / "ft.toml", tmp_path / "ft.h5"
    p.write_text(FORWARD.format(pressure=5.0).replace('units = "cm"', 'units = "ft"'))
    assert main(["forward", str(p), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {p}: units: must be one of mm, cm, m, in, inch with [load] (its SI values need metres)"
    assert not out.exists()


def test_load_is_refused_in_a_tip_problem(tmp_path, capsys):
    p = tmp_path / "tip.toml"
    p.write_text((BUNDLED.parents[0] / "tip-target.toml").read_text() + "\n[load]\npressure = 5.0\nmass_per_length = 0.1\n")
    assert main(["design", str(p), "-o", str(tmp_path / "t.h5")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {p}: load: not used in a tip problem"


# ---------------------------------------------------------------- the design


def test_design_with_load_meets_its_rows_and_the_judge(tmp_path):
    """The bundled reach at 8 kPa: on the target it would need 8.25 kPa; the design stands (margin >= safety
    everywhere, every grown prefix) a few millimetres off the target, and is ok; Design.ok agrees."""
    d = vine_nlp.solve(BUNDLED)
    r = d.result
    assert d.ok and r.ok and r.method == "nlp_load" and r.stats["load_rounds"] >= 1
    assert r.stats["start_load_margin"] < 1.5 <= r.metrics["load_margin"]
    assert r.metrics["min_pressure"] <= 8.0 * (1 + 1e-9)
    assert r.stats["start_rmse"] < r.metrics["rmse"] < r.stats["start_rmse"] + BUDGET * 8.0
    rep = load_report(r.routing, 8.0, "cm", d.problem.load)
    assert rep["holds"] and rep["margin"] == pytest.approx(r.metrics["load_margin"])


def test_design_at_half_the_pressure_keeps_the_target_and_folds(tmp_path):
    """At 4 kPa the design that stands curls far off the target: the design on the target stays run nlp, judged
    to fold (not ok), the one that stands beside it (run nlp_load)."""
    p = tmp_path / "half.toml"
    p.write_text(BUNDLED.read_text().replace("pressure = 8.0", "pressure = 4.0"))
    d = vine_nlp.solve(p)
    runs = d.runs
    nlp = runs["nlp"].result
    assert not d.ok and d.run == "nlp" and "nlp_load" in runs
    assert nlp.shortfall == (f"folds under its weight at s = 0 cm (load margin {nlp.metrics['load_margin']:.3g} < safety 1.5 at 4 kPa); "
                             f"it needs at least {nlp.metrics['min_pressure']:.4g} kPa",)
    # the design on the target, judged: as design_with_load found it before its rows; it needs about 8.25 kPa
    assert nlp.metrics["load_margin"] == pytest.approx(runs["nlp_load"].result.stats["start_load_margin"], rel=1e-12)
    assert 8.0 < nlp.metrics["min_pressure"] < 8.5
    assert runs["nlp_load"].result.metrics["rmse"] > nlp.metrics["rmse"] + BUDGET * 8.0


def test_analyze_prints_draws_and_writes_the_load_metrics(tmp_path, capsys):
    p, out, fig = tmp_path / "c.toml", tmp_path / "c.h5", tmp_path / "load.png"
    need = _need()
    p.write_text(FORWARD.format(pressure=repr(2 * need)))
    assert main(["forward", str(p), "-o", str(out)]) == 0
    a = load_archive(out)
    a.runs["forward"].metrics.clear()  # as an archive written before [load] was judged
    write_archive(out, a)
    capsys.readouterr()
    assert main(["analyze", str(out), "--write-metrics", "--load-figure", str(fig), "--samples", "10"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln for ln in lines if ln.startswith("load ")] == [
        f"load        {2 * need:g} kPa, 0.04 kg/m, tip 0.02 kg, safety 1.5, growth while-actuated: holds, margin 3 at s = 0 cm; "
        f"it needs {need:.4g} kPa"]
    assert fig.stat().st_size > 1000 and f"figure -> {fig}" in lines
    m = load_archive(out).runs["forward"].metrics
    assert m["load_margin"] == pytest.approx(3.0, rel=1e-3) and m["collapse_at"] == 0.0 and m["min_pressure"] == pytest.approx(need, rel=1e-3)
    assert "  min_pressure " + f"{m['min_pressure']:.6g} kPa" in summarize(out).splitlines()


@pytest.mark.slow
def test_sweep_error_column_agrees_with_the_judgement(tmp_path):
    """Sweep items over the pressure: the error column says where an item folds, as the design's exit line does."""
    import csv

    sweep = tmp_path / "s.toml"
    sweep.write_text(f'name = "press"\nbase = "{BUNDLED.as_posix()}"\nmethods = ["nlp"]\n[grid]\n"load.pressure" = [4.0, 12.0]\n')
    main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--workers", "1"])
    rows = list(csv.DictReader(open(tmp_path / "out" / "summary.csv", encoding="utf-8")))
    assert [r["error"].startswith("misses: folds under its weight at s = 0 cm") for r in rows] == [True, False]
    assert "it needs at least 8.2" in rows[0]["error"] and rows[1]["error"] == ""


def test_the_design_rows_recursion_matches_the_analysis():
    """methods.loads' recursion (4 weight points per segment) and its prefix rows against analysis.loads on the
    full shape and on the shape grown to segment k (payload there), at the segment starts, within 0.5 %."""
    from vine_nlp.methods.loads import load_extra, scales
    from vine_nlp.model.chain import chain_frames
    from vine_nlp.problem import DesignProblem

    r, D = _curved(), 3.0
    load = Load(pressure=5.0, mass_per_length=0.08, tip_mass=0.03, gravity=(0.0, -2.0, -9.81), safety=1.2)
    problem = DesignProblem("c", D, np.zeros((12, 3)), load=load)
    E = load_extra(problem, r)
    a, _, g = scales(problem)
    SM = math.pi * 5e3 * (0.015**3) / 1.2
    F = chain_frames(r.theta, r.lam, r.length, D, r.initial_pose)
    t, p = F[:, :3, 0], F[:, :3, 3] / D

    def bend(mu, j):
        return SM * np.linalg.norm(mu - mu.dot(t[j]) * t[j])

    full = load_report(r, D, "cm", load, growth="after")["moment"][::20]
    assert [bend(E[:3, j], j) for j in range(r.segments)] == pytest.approx(full[:-1], rel=5e-3)
    for k in (2, 4):
        grown = Routing(theta=r.theta[:k], lam=r.lam[:k], length=r.length[:k], initial_pose=r.initial_pose)
        want = load_report(grown, D, "cm", load, growth="after")["moment"][::20][:k]
        got = [bend(E[:3, j] - E[:3, k] - np.cross(p[k] - p[j], g) * a * E[3, k], j) for j in range(k)]
        assert got == pytest.approx(want, rel=5e-3)


HOOK = """name = "hook"
units = "cm"
[tube]
diameter = 8.0
[target]
curve = "bezier"
control_points = [[0, 0, 0], [60, 0, 0], [110, 0, 0], [110, 0, 50], [60, 0, 50]]
samples = 121
[actuator]
kind = "tendon"
[design]
base = "fixed"
[routing]
initial_pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
[load]
pressure = 12.0
mass_per_length = 0.03
tip_mass = 0.1
safety = 1.5
"""


def test_a_hook_stands_while_it_grows(tmp_path):
    """A reach that turns back over itself: grown part way, its payload is farther out than at the end, so a
    grown prefix loads the base most. The design adds rows for those prefixes and stands all the way."""
    p = tmp_path / "hook.toml"
    p.write_text(HOOK)
    d = vine_nlp.solve(p)
    r = d.result
    assert d.ok and r.method == "nlp_load" and r.stats["load_prefix_rows"] >= 1
    rep = load_report(r.routing, 8.0, "cm", d.problem.load)
    assert rep["holds"] and rep["margin"] >= 1.5
    assert np.any(rep["moment_growth"] > 1.05 * rep["moment"])  # growth matters here


@pytest.mark.slow
def test_correct_judges_the_correction_under_the_load(tmp_path, capsys):
    """``vine-nlp correct`` of a design with [load]: the corrected run gets the load metrics, and at a pressure it
    folds at, the correction is not ok (exit 1, the fold line in its line)."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from simulate import draw_deviations, simulate_build

    from vine_nlp.io.correction import read_correction
    from vine_nlp.model.routing import Sigmas

    problem = ('name = "t"\nunits = "cm"\n[tube]\ndiameter = 2.43\n[target]\ncurve = "trefoil"\nscale = [4.0, 4.0, 4.0]\n'
               't_range = [-0.6283185307179586, 1.5707963267948966]\nsamples = 121\n'
               '[load]\npressure = 1000.0\nmass_per_length = 0.02\ntip_mass = 0.01\nsafety = 1.5\n')
    (tmp_path / "p.toml").write_text(problem)
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "d.h5")]) == 0
    a = load_archive(tmp_path / "d.h5")
    nominal = a.runs["nlp"].routing
    dev = draw_deviations(nominal, Sigmas.from_degrees(1.0, 0.02, 0.02), (0.01, 0.02, 1.02), seed=3)
    np.savetxt(tmp_path / "m.csv", simulate_build(nominal, dev, 2.43, "outer", 150, 0.05, seed=4), delimiter=",", header="x,y,z", comments="")
    a.source = a.source.replace("pressure = 1000.0", "pressure = 0.01")  # the robot as it is run: 10 Pa
    write_archive(tmp_path / "low.h5", a)
    capsys.readouterr()
    for name, folds in (("d.h5", False), ("low.h5", True)):
        code = main(["correct", str(tmp_path / name), str(tmp_path / "m.csv"), "-o", str(tmp_path / f"c-{name}"), "--adjust", "lambda,theta"])
        err = capsys.readouterr().err
        corrected = read_correction(tmp_path / f"c-{name}")[0].runs["corrected"]
        assert {"load_margin", "collapse_at", "min_pressure"} <= corrected.metrics.keys()
        assert ("folds under its weight" in err) == folds and (code == 1 if folds else True)


def test_growth_curve_of_a_straight_reach_is_the_closed_form():
    """The base's moment as a horizontal tube grows to L', its payload at the tip: w g L'^2 / 2 + m g L'."""
    from vine_nlp.analysis.loads import growth_curve

    load = Load(pressure=4.0, mass_per_length=0.05, tip_mass=0.02)
    l, moment = growth_curve(_tilted(0.0, 120.0), 5.0, "cm", load, 0)
    Lm = l * 0.01
    assert moment == pytest.approx(9.81 * (0.05 * Lm**2 / 2 + 0.02 * Lm), rel=1e-9, abs=1e-12)
