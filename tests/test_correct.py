"""As-built correction (design.correct, io.correction, ``vine-nlp correct`` / ``calibrate``): simulated builds
with known construction errors, measured through the forward model with noise."""

from __future__ import annotations

import dataclasses
import math
import tomllib

import h5py
import numpy as np
import pytest
from simulate import draw_deviations, simulate_build

from vine_nlp.analysis.buildability import buildability, correction_missed
from vine_nlp.front.cli import main
from vine_nlp.io.archive import Archive, write_archive
from vine_nlp.io.calibration import read_calibration
from vine_nlp.io.correction import read_correction
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import correct as C
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.correct.estimate import measure_block
from vine_nlp.methods.correct.laplace import line_jacobian
from vine_nlp.methods.correct.pairing import line_points
from vine_nlp.methods.settings import CAP_ROUND, SLIDE
from vine_nlp.methods.structure import frames12
from vine_nlp.model.calibration import Calibration, realized_of
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Routing, Sigmas
from vine_nlp.model.segment import so3_exp
from vine_nlp.model.shape import forward_shape
from vine_nlp.problem import DesignProblem

PROBLEM = """name = "small-trefoil"
units = "cm"
[tube]
diameter = 2.43
[target]
curve = "trefoil"
scale = [4.0, 4.0, 4.0]
t_range = [-0.6283185307179586, 1.5707963267948966]
samples = 121
[design]
points_per_segment = 10
"""
SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)
TRUTH = (math.radians(1.0), 0.02, 1.02)  # systematic parts: theta offset, lambda offset, length scale
NOISE = 0.05  # 0.5 mm, in cm


def built_error(problem, nominal, dev):
    """RMSE to the target of the robot with deviations ``dev`` built from ``nominal`` (the design's pairing)."""
    return evaluate(problem, C.apply_deviations(nominal, dev), pair_points(problem.target, 10), "x").metrics["rmse"]


def write_csv(path, pts, header=True):
    np.savetxt(path, pts, delimiter=",", header="x,y,z" if header else "", comments="")
    return path


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("correct")
    (d / "p.toml").write_text(PROBLEM)
    assert main(["design", str(d / "p.toml"), "-o", str(d / "design.h5")]) == 0
    problem = load_problem(d / "p.toml").problem
    from vine_nlp.io.archive import load_archive

    nominal = load_archive(d / "design.h5").runs["nlp"].routing
    dev = draw_deviations(nominal, SIGMAS, TRUTH, seed=3)
    pts = simulate_build(nominal, dev, problem.diameter, "outer", 150, NOISE, seed=4)
    write_csv(d / "m1.csv", pts)
    # lambda only (stoppers moved), and lambda and theta (the line redrawn) from the same measurement
    assert main(["correct", str(d / "design.h5"), str(d / "m1.csv"), "-o", str(d / "c1.h5"), "--adjust", "lambda"]) in (0, 1)
    assert main(["correct", str(d / "design.h5"), str(d / "m1.csv"), "-o", str(d / "c1t.h5"), "--adjust", "lambda,theta"]) in (0, 1)
    a1, s1 = read_correction(d / "c1t.h5")
    pts2 = simulate_build(a1.runs["corrected"].routing, dev, problem.diameter, "outer", 150, NOISE, seed=5)
    write_csv(d / "m2.csv", pts2)
    assert main(["correct", str(d / "c1t.h5"), str(d / "m2.csv"), "-o", str(d / "c2.h5"), "--adjust", "lambda,theta"]) in (0, 1)
    return {"dir": d, "problem": problem, "nominal": nominal, "dev": dev}


def test_physical_rule_and_round_trip():
    rng = np.random.default_rng(0)
    nom = Routing(theta=rng.uniform(-0.5, 0.5, 6), lam=[0.5, 0.7, 1.0, 0.98, 0.45, 0.9], length=rng.uniform(1, 2, 6))
    dev = C.Deviations(np.full(6, 0.01), np.array([0.02, -0.03, 0.05, 0.05, -0.1, -0.02]), np.full(6, 1.03), lambda_min=0.4)
    built = C.apply_deviations(nom, dev)
    # no actuator (lambda 1): exactly 1 whatever the error; elsewhere min(1, nominal + error), at least lambda_min
    np.testing.assert_allclose(built.lam, [0.52, 0.67, 1.0, 1.0, 0.4, 0.88], atol=1e-15)
    assert built.lam[2] == 1.0 and np.all(built.lam <= 1.0)
    np.testing.assert_allclose(built.theta, nom.theta + 0.01, atol=1e-15)  # theta and length: every segment
    np.testing.assert_allclose(built.length, nom.length * 1.03, rtol=1e-15)
    d = C.deviations_of(nom, built, 0.4)
    assert d.lam[2] == 0.0  # no lambda deviation without an actuator
    # a nominal inside the range comes back from what it realizes; no actuator stays none
    other = Routing(theta=rng.uniform(-0.5, 0.5, 6), lam=[0.6, 0.8, 1.0, 0.9, 0.7, 0.95], length=nom.length)
    back = C.remove_deviations(C.apply_deviations(other, d), d, other.lam < 1)
    np.testing.assert_allclose(back.theta, other.theta, atol=1e-15)
    np.testing.assert_allclose(back.lam, other.lam, atol=1e-15)
    np.testing.assert_allclose(back.length, other.length, rtol=1e-15)
    assert back.lam[2] == 1.0


def test_line_jacobian_matches_finite_differences_of_the_chain():
    # the Laplace step's Jacobian from the chain's twists equals differencing the whole chain
    rng = np.random.default_rng(1)
    M = 6
    r = Routing(theta=rng.uniform(-0.6, 0.6, M), lam=rng.uniform(0.4, 1.0, M), length=rng.uniform(1.0, 3.0, M), initial_pose=np.eye(4))
    seg = np.array([0, 1, 2, 3, 5, 5, 4])
    frac = np.array([0.3, 0.0, 1.0, 0.5, 0.9, 0.1, 0.7])
    P, J = line_jacobian(r, 2.0, seg, frac, C.LINE_SIDE["outer"])
    np.testing.assert_allclose(P, line_points(r, 2.0, seg, frac, C.LINE_SIDE["outer"])[0], atol=1e-12)
    for q, name in enumerate(("theta", "lam", "length")):
        for k in range(M):
            h = 1e-6
            up, dn = [np.array(getattr(r, n), float) for n in ("theta", "lam", "length")], [np.array(getattr(r, n), float) for n in ("theta", "lam", "length")]
            up[q][k] += h
            dn[q][k] -= h
            names = ("theta", "lam", "length")
            d = (line_points(Routing(**dict(zip(names, up)), initial_pose=np.eye(4)), 2.0, seg, frac, -0.5)[0]
                 - line_points(Routing(**dict(zip(names, dn)), initial_pose=np.eye(4)), 2.0, seg, frac, -0.5)[0]) / (2 * h)
            np.testing.assert_allclose(J[:, :, q * M + k].T, d, atol=1e-6, err_msg=f"{name} of segment {k}")


def test_estimate_recovers_systematic_parts_and_deviations(setup):
    _, s = read_correction(setup["dir"] / "c1t.h5")
    z = (s.systematic - np.array(TRUTH)) / s.systematic_std
    assert np.all(np.abs(z) < 3), z
    assert np.all(s.systematic_std > 0)
    dev = setup["dev"]
    # per-segment theta and lambda deviations follow the truth (lengths are weakly observable on a smooth curve)
    assert np.corrcoef(s.deviation["theta"], dev.theta)[0, 1] > 0.6
    assert np.corrcoef(s.deviation["lambda"], dev.lam)[0, 1] > 0.3
    assert s.uncertainty["theta"].shape == (setup["nominal"].segments,)


def test_correction_lowers_the_built_error(setup):
    problem, nominal, dev = setup["problem"], setup["nominal"], setup["dev"]
    a1, _ = read_correction(setup["dir"] / "c1t.h5")
    a2, _ = read_correction(setup["dir"] / "c2.h5")
    e0 = built_error(problem, nominal, dev)
    e1 = built_error(problem, a1.runs["corrected"].routing, dev)
    e2 = built_error(problem, a2.runs["corrected"].routing, dev)
    assert e1 < 0.15 * e0, (e0, e1)
    assert e2 < e1, (e1, e2)
    # the prediction stored with the corrected run is what the robot then realizes
    assert abs(a1.runs["corrected"].metrics["rmse"] - e1) < 0.5 * e1
    # lambda alone cannot undo theta errors: it still lowers the error, about as far as the true
    # deviations would let it (oracle)
    al, _ = read_correction(setup["dir"] / "c1.h5")
    el = built_error(problem, al.runs["corrected"].routing, dev)
    _, realized, _, _ = C.correct_routing(problem, C.apply_deviations(nominal, dev), dev, ("lambda",), nominal)
    oracle = evaluate(problem, realized, pair_points(problem.target, 10), "x").metrics["rmse"]
    assert el < 0.7 * e0 and el < 1.2 * oracle, (e0, el, oracle)


def test_contract_rule_holds_exactly(setup):
    a, s = read_correction(setup["dir"] / "c1.h5")
    built, ab, corr = a.runs["nlp"].routing, a.runs["as_built"].routing, a.runs["corrected"].routing
    # without --adjust theta, theta and length of the corrected nominal are the built nominal's
    np.testing.assert_array_equal(corr.theta, built.theta)
    np.testing.assert_array_equal(corr.length, built.length)
    np.testing.assert_allclose(s.deviation["theta"], ab.theta - built.theta, atol=1e-14)
    np.testing.assert_allclose(s.deviation["lambda"], ab.lam - built.lam, atol=1e-14)
    np.testing.assert_allclose(s.deviation["length_ratio"], ab.length / built.length, rtol=1e-14)
    # the corrected run's shape is what its nominal realizes with the deviations kept (the physical rule)
    dev = C.Deviations(s.deviation["theta"], s.deviation["lambda"], s.deviation["length_ratio"], 0.4)
    realized = C.apply_deviations(corr, dev)
    shape = evaluate(setup["problem"], realized, pair_points(setup["problem"].target, 10), "x").shape
    np.testing.assert_allclose(a.runs["corrected"].shape.center, shape.center, atol=1e-9)
    # the bounds act on what is built: the actuator's range, an actuator's nominal below 1
    assert np.all(realized.lam >= 0.4 - 1e-8) and np.all(realized.lam <= 1 + 1e-8) and np.all(corr.lam < 1)
    assert np.all(ab.lam <= 1.0)


def test_archive_round_trip(setup):
    a, s = read_correction(setup["dir"] / "c2.h5")
    assert set(a.runs) == {"nlp", "as_built", "corrected", "corrected_lambda", "corrected_lambda_theta"}
    # the chosen route is /runs/corrected, both predictions beside it; round 2 started from round 1's estimate
    np.testing.assert_array_equal(a.runs["corrected"].routing.theta, a.runs["corrected_lambda_theta"].routing.theta)
    assert s.attrs["adjust"] == "lambda,theta" and s.attrs["recommended"] in ("lambda", "lambda,theta")
    assert a.runs["corrected_lambda"].stats["route"] == "lambda"
    assert a.runs["as_built"].stats["warm_start"] is True
    assert read_correction(setup["dir"] / "c1.h5")[0].runs["as_built"].stats["warm_start"] is False
    assert len(s.builds) == 2 and [m.build for m in s.measurements] == [0, 1]
    a1, _ = read_correction(setup["dir"] / "c1t.h5")
    np.testing.assert_array_equal(s.builds[1].lam, a1.runs["corrected"].routing.lam)
    np.testing.assert_array_equal(s.builds[1].theta, a1.runs["corrected"].routing.theta)
    np.testing.assert_array_equal(s.builds[0].lam, a.runs["nlp"].routing.lam)
    pts = np.loadtxt(setup["dir"] / "m2.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(s.measurements[1].points, pts)
    assert s.measurements[1].file == "m2.csv" and s.measurements[1].line == "outer"
    with h5py.File(setup["dir"] / "c2.h5") as h5:
        assert h5["measured/points"].shape == (300, 3)
        assert h5["correction"].attrs["built_run"] == "corrected"


def test_changes_lists_what_changes(setup):
    from vine_nlp.front.changes import change_rows

    a, _ = read_correction(setup["dir"] / "c1.h5")
    rows = change_rows(a, "corrected")
    built, corr = a.runs["nlp"].routing, a.runs["corrected"].routing
    changed = np.flatnonzero(np.abs(corr.lam - built.lam) > 1e-9)
    assert [r["segment"] for r in rows] == changed.tolist()
    # a stopper keeps lambda of the actuator path (length / cos theta): longer when lambda grows
    for r in rows:
        j = r["segment"]
        want = 10 * (corr.lam[j] - built.lam[j]) * built.length[j] / np.cos(built.theta[j])  # cm -> mm
        assert r["stopper_change_mm"] == pytest.approx(want)
        assert r["action"] == ("longer" if want > 0 else "shorter")


def test_template_draws_the_changes(setup, tmp_path, capsys):
    import xml.etree.ElementTree as ET

    from vine_nlp.front.changes import change_rows
    from vine_nlp.front.template import change_text, write_template
    from vine_nlp.io.archive import load_archive

    d = setup["dir"]
    rows = change_rows(load_archive(d / "c1.h5"), "corrected")
    assert rows
    svg = tmp_path / "t.svg"
    assert main(["template", str(d / "c1.h5"), "-o", str(svg), "--changes"]) == 0
    out = capsys.readouterr().out
    ns = {"s": "http://www.w3.org/2000/svg"}
    layer = ET.parse(svg).getroot().find("s:g[@id='layer-changes']", ns)
    texts = [t.text for t in layer.findall("s:text", ns)]
    # every changing segment is labelled with its stopper change, once (on the strip holding its middle)
    want = sorted(change_text(r) for r in rows)
    assert sorted(texts) == want, (texts, want)
    legend = [t.text for t in ET.parse(svg).getroot().find("s:g[@id='layer-text']", ns).findall("s:text", ns)]
    assert f"[changes] framed: {len(rows)} segment(s) to change against the robot built last" in legend
    assert len(layer.findall("s:polyline", ns)) >= 4 * len(rows)  # a frame (4 sides) around each
    for r in rows:  # the words say which way and by how much, as the list printed
        assert f"{abs(r['stopper_change_mm']):5.1f} mm" in out
        assert change_text(r).endswith(f"{r['stopper_change_mm']:+.1f} mm {r['action']}")
    # without --changes nothing is marked; the PDF marks as many segments
    plain = tmp_path / "p.svg"
    assert main(["template", str(d / "c1.h5"), "-o", str(plain)]) == 0
    assert not ET.parse(plain).getroot().find("s:g[@id='layer-changes']", ns).findall("s:text", ns)
    info = write_template(d / "c1.h5", tmp_path / "t.pdf", run="corrected", changes=rows)
    assert info["changes"] == len(rows) and info["run"] == "corrected"


def test_correction_figure_has_equal_axes_and_the_obstacles(setup):
    """An out-of-plane error must look as large as it is: one scale on x, y and z (issue 35); obstacles drawn."""
    from vine_nlp.front.correct import correction_figure
    from vine_nlp.io.archived import archived_problem
    from vine_nlp.model.obstacles import Sphere
    from vine_nlp.pipeline.correct import correct_files

    result, archive, _, _ = correct_files(setup["dir"] / "design.h5", [setup["dir"] / "m1.csv"], sigmas=SIGMAS)
    problem = archived_problem(archive, setup["dir"] / "design.h5", "nlp")
    figures = [correction_figure(result, problem)]
    figures.append(correction_figure(result, dataclasses.replace(problem, obstacles=(Sphere(tuple(problem.target[0]), 1.0),))))
    (ax, ax_ob) = [[a for a in fig.axes if a.name == "3d"][0] for fig in figures]
    for a in (ax, ax_ob):
        spans = np.ptp([a.get_xlim(), a.get_ylim(), a.get_zlim()], axis=1)
        np.testing.assert_allclose(spans, spans[0], rtol=1e-12)
        np.testing.assert_allclose(a.get_box_aspect(), a.get_box_aspect()[0], rtol=1e-12)
    assert len(ax_ob.collections) == len(ax.collections) + 1
    # the points are shown on the line they were measured on, which is drawn too: not D/2 off the center line unexplained
    line = result.measurements[0].line
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert f"measured, {line} line" in legend
    assert (f"as built, {line} line" in legend) == (line != "center")


def _fails(capsys, argv, out, key):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and key in err[0], err
    assert not out.exists()


def test_bad_inputs_one_line_exit_2(setup, tmp_path, capsys):
    d = setup["dir"]
    out = tmp_path / "o.h5"
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z\n" + "1,2,3\n" * 12 + "1,oops,3\n")
    _fails(capsys, ["correct", str(d / "design.h5"), str(bad), "-o", str(out)], out, f"{bad}: line 14: 'oops' is not a number")
    few = write_csv(tmp_path / "few.csv", np.ones((4, 3)))
    _fails(capsys, ["correct", str(d / "design.h5"), str(few), "-o", str(out)], out, "needs at least 10 points")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    _fails(capsys, ["correct", str(junk), str(d / "m1.csv"), "-o", str(out)], out, "not an HDF5 file")
    _fails(capsys, ["correct", str(d / "design.h5"), str(d / "m1.csv"), "-o", str(out), "--run", "nope"], out, "--run: no run 'nope'")
    _fails(capsys, ["correct", str(d / "design.h5"), str(d / "m1.csv"), "-o", str(out), "--line", "side"], out, "--line")
    _fails(capsys, ["calibrate", str(d / "design.h5"), "-o", str(tmp_path / "c.toml")], tmp_path / "c.toml", "not a correction archive")


def test_measurement_that_cannot_be_this_robot(setup, tmp_path, capsys):
    d = setup["dir"]
    out = tmp_path / "o.h5"
    pts = np.loadtxt(d / "m1.csv", delimiter=",", skiprows=1)
    nan = pts.copy()
    nan[7, 1] = np.nan
    write_csv(tmp_path / "nan.csv", nan)
    _fails(capsys, ["correct", str(d / "design.h5"), str(tmp_path / "nan.csv"), "-o", str(out)], out, "nan.csv: line 9: 'nan' is not finite")
    t = np.linspace(0.0, 1.0, 100)[:, None]
    line = write_csv(tmp_path / "line.csv", np.hstack([100 * t, 0 * t + 50, 0 * t - 30]))  # another shape, somewhere else
    _fails(capsys, ["correct", str(d / "design.h5"), str(line), "-o", str(out)], out, "line.csv: points: cannot be this robot")


def test_unreachable_correction_says_so_once_writes_the_best_exit_1(setup, tmp_path, capsys):
    problem, nominal = setup["problem"], setup["nominal"]
    # a builder whose lambda comes out 0.2 too low: the design's lambdas (0.6 to 0.9) above 0.8 cannot be built
    # (their stoppers would need no gap at all)
    dev = draw_deviations(nominal, SIGMAS, (0.0, -0.2, 1.0), seed=3)
    m = write_csv(tmp_path / "far.csv", simulate_build(nominal, dev, problem.diameter, "outer", 150, NOISE, seed=4))
    out = tmp_path / "o.h5"
    assert main(["correct", str(setup["dir"] / "design.h5"), str(m), "-o", str(out), "--adjust", "lambda"]) == 1
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("correct: corrected (lambda): cannot reach the target within the bounds"), err
    assert "lambda at the actuator's least contraction (its nominal's gap at min_feature): segments" in err[0]
    (line,) = [x for x in cap.out.splitlines() if x.startswith("corrected ")]
    assert line.startswith("corrected   lambda (") and ", short of the target: " in line and "optimal" in line
    a, s = read_correction(out)
    assert a.runs["corrected"].shortfall and s.attrs["adjust"] == "lambda"
    # the best it found: still closer to the target than the robot as built
    assert built_error(problem, a.runs["corrected"].routing, dev) < built_error(problem, nominal, dev)


def test_one_summary_both_routes_exit_follows_the_chosen(setup, tmp_path, capsys):
    d = setup["dir"]
    out = tmp_path / "o.h5"
    code = main(["correct", str(d / "design.h5"), str(d / "m1.csv"), "-o", str(out)])
    cap = capsys.readouterr()
    a, s = read_correction(out)
    lines = cap.out.splitlines()
    assert [x[:12] for x in lines] == ["estimate    ", "  fit       ", "  built     ", "  systematic", "  per segmen", "routes      ",
                                       "            ", "corrected   ", "archive -> " + str(out)[:1]]
    assert lines[5].startswith("routes      lambda        stoppers or pouches on this robot: predicted RMSE ")
    assert lines[6].startswith("            lambda,theta  the line drawn anew on a new tube: predicted RMSE ")
    # without --adjust the recommended route is taken, and said so; the exit and stderr follow that route alone
    route = s.attrs["recommended"]
    assert s.attrs["adjust"] == route and lines[7].startswith(f"corrected   {route} (recommended), ")
    chosen = a.runs[f"corrected_{route.replace(',', '_')}"]
    np.testing.assert_array_equal(a.runs["corrected"].routing.lam, chosen.routing.lam)
    assert code == (1 if chosen.shortfall else 0) and bool(cap.err) == bool(chosen.shortfall)
    assert ("short of the target" in lines[7]) == bool(chosen.shortfall)


def test_estimate_and_correction_know_where_there_is_no_actuator(setup):
    problem, nominal = setup["problem"], setup["nominal"]
    # a design without an actuator on four segments (lambda 1), built with a lambda offset
    lam = nominal.lam.copy()
    lam[[3, 4, 8, 9]] = 1.0
    lam[6] = 0.99  # an actuator that the offset pushes against 1
    theta = nominal.theta.copy()
    theta[[3, 8]] = 0.8  # there the line winds around the straight tube (the shape does not see it, the outer line does)
    nom = Routing(theta=theta, lam=lam, length=nominal.length, initial_pose=nominal.initial_pose)
    dev = draw_deviations(nom, SIGMAS, TRUTH, seed=3)
    pts = simulate_build(nom, dev, problem.diameter, "outer", 150, NOISE, seed=4)
    res = C.correct(problem, [nom], [C.Measurement(pts, "outer")], sigmas=SIGMAS, measurement_sigma=NOISE)
    e = res.estimate
    assert res.as_built.metrics["rmse"] < 1.5 * math.sqrt(2) * NOISE  # the measured line fitted to its noise
    assert np.all(e.routing.lam[lam == 1.0] == 1.0) and np.all(e.deviations.lam[lam == 1.0] == 0.0)
    assert np.all(e.routing.lam <= 1.0)
    assert abs(e.systematic[1] - TRUTH[1]) < 3 * e.systematic_std[1]
    # the actuator built against 1 may have any error beyond it: held (its lambda kept) by both routes
    assert C.apply_deviations(nom, dev).lam[6] == 1.0 and e.deviations.held[6] and not np.any(e.deviations.held[lam == 1.0])
    for r in res.routes.values():  # no route adds an actuator; what they predict obeys the rule
        assert np.all(r.routing.lam[lam == 1.0] == 1.0) and np.all(r.routing.lam[lam < 1.0] < 1.0)
        assert r.routing.lam[6] == pytest.approx(0.99, abs=1e-12)
        assert built_error(problem, r.routing, dev) < (0.5 if r.stats["route"] == "lambda,theta" else 1.0) * built_error(problem, nom, dev)


def test_combine_systematic_known_answer():
    est = np.array([[0.01, 0.02, 1.02], [0.03, 0.02, 1.02]])
    sd = np.array([[0.01, 0.01, 0.01], [0.01, 0.01, 0.01]])
    mean, se, birge = C.combine_systematic(est, sd)
    assert mean[0] == pytest.approx(0.02) and mean[1] == pytest.approx(0.02) and mean[2] == pytest.approx(1.02)
    # scatter of theta: chi^2 = 2 (1^2) over 1 degree of freedom -> Birge ratio sqrt(2)
    assert birge == pytest.approx(math.sqrt(2))
    assert se[0] == pytest.approx(0.01 / math.sqrt(2) * math.sqrt(2))
    assert se[1] == pytest.approx(0.01 / math.sqrt(2))


def test_calibrate_and_design_with_it(setup, tmp_path):
    d = setup["dir"]
    cal_path = tmp_path / "cal.toml"
    assert main(["calibrate", str(d / "c1.h5"), str(d / "c2.h5"), "-o", str(cal_path)]) == 0
    cal = read_calibration(cal_path)
    assert cal.prototypes == 2 and cal.length_scale > 0
    assert tomllib.loads(cal_path.read_text())["calibration"]["lambda_offset"] == pytest.approx(cal.lambda_offset)
    # a problem naming the file: the design is for the robot as built
    (tmp_path / "p.toml").write_text(PROBLEM.replace('units = "cm"', 'units = "cm"\ncalibration = "cal.toml"'))
    pf = load_problem(tmp_path / "p.toml")
    assert pf.problem.calibration == cal
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "d.h5")]) == 0
    from vine_nlp.io.archive import load_archive

    r = load_archive(tmp_path / "d.h5").runs["nlp"]
    # the nominal, built by a robot with exactly the calibrated systematic errors, realizes the design
    realized = realized_of(r.routing, cal)
    fit = evaluate(pf.problem, realized, pair_points(pf.problem.target, 10), "x")
    np.testing.assert_allclose(fit.shape.center, r.shape.center, atol=1e-9)
    assert r.metrics["rmse"] < 0.05
    assert r.stats["calibration_clipped"] == 0


OFFSET = 0.05  # a known lambda offset of the builder


def _shifted(plain_lam, offset=OFFSET, lambda_min=0.4):
    """The nominal lambda a calibrated design builds: the realized design's lambda minus the offset, within the bounds."""
    return np.clip(plain_lam - offset, lambda_min, 1.0)


@pytest.fixture(scope="module")
def plain_design(tmp_path_factory):
    """The small trefoil designed without a calibration (the reference of the calibrated designs)."""
    import vine_nlp as vn

    d = tmp_path_factory.mktemp("plain")
    (d / "p.toml").write_text(PROBLEM)
    return vn.solve(load_problem(d / "p.toml").problem).lam


def test_python_api_applies_the_calibration(plain_design, tmp_path):
    import vine_nlp as vn
    from vine_nlp.io.calibration import write_calibration

    p = tmp_path / "p.toml"
    p.write_text(PROBLEM + f"[calibration]\nlambda_offset = {OFFSET}\n")
    problem = load_problem(p).problem
    d = vn.solve(problem)
    np.testing.assert_allclose(d.lam, _shifted(plain_design), atol=1e-9)
    assert d.stats["calibration_lambda_offset"] == OFFSET
    # the archived source carries the table: the saved design reads back as calibrated
    d.save(tmp_path / "d.h5")
    assert tomllib.loads(vn.load(tmp_path / "d.h5").source)["calibration"]["lambda_offset"] == OFFSET
    # vn.design(points, ...) with a calibration file
    write_calibration(tmp_path / "cal.toml", Calibration(lambda_offset=OFFSET))
    d2 = vn.design(problem.target, problem.diameter, calibration=tmp_path / "cal.toml")
    np.testing.assert_allclose(d2.lam, _shifted(plain_design), atol=1e-9)
    with pytest.raises(vn.ArgumentError, match="calibration"):
        vn.design(problem.target, problem.diameter, calibration=tmp_path / "missing.toml")


def test_sweep_applies_the_calibration(plain_design, tmp_path):
    from vine_nlp.front import sweep as sw
    from vine_nlp.io.archive import load_archive
    from vine_nlp.io.problem_file import load_sweep

    (tmp_path / "base.toml").write_text(PROBLEM + f"[calibration]\nlambda_offset = {OFFSET}\n")
    (tmp_path / "sweep.toml").write_text('name = "cal"\nbase = "base.toml"\nmethods = ["nlp"]\n[grid]\n"target.scale.0" = [4.0]\n')
    report = sw.run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", workers=1, progress=False)
    (h5,) = sorted((tmp_path / "out").glob("*.h5"))
    run = load_archive(h5).runs["nlp"]
    np.testing.assert_allclose(run.routing.lam, _shifted(plain_design), atol=1e-9)
    assert run.stats["calibration_lambda_offset"] == OFFSET
    assert report is not None


def test_calibration_table_errors(tmp_path, capsys):
    p = tmp_path / "p.toml"
    p.write_text(PROBLEM + "[calibration]\nlength_scale = -1.0\n")
    assert main(["design", str(p), "-o", str(tmp_path / "o.h5")]) == 2
    assert "calibration.length_scale: must be > 0" in capsys.readouterr().err
    p.write_text(PROBLEM + "[calibration]\nlambda_offset = 0.01\ncolour = 1\n")
    assert main(["design", str(p), "-o", str(tmp_path / "o.h5")]) == 2
    assert "calibration.colour: unknown key" in capsys.readouterr().err
    p.write_text(PROBLEM.replace('units = "cm"', 'units = "cm"\ncalibration = "missing.toml"'))
    assert main(["design", str(p), "-o", str(tmp_path / "o.h5")]) == 2
    assert "calibration: no such file" in capsys.readouterr().err
    assert Calibration().length_scale == 1.0


@pytest.mark.slow
def test_free_pose_recovers_the_measurement_frame(setup, tmp_path):
    from vine_nlp.front.correct import correct_files
    from vine_nlp.model.segment import so3_exp

    d = setup["dir"]
    pts = np.loadtxt(d / "m1.csv", delimiter=",", skiprows=1)
    R = so3_exp(np.array([0.1, -0.2, 0.5]))
    moved = pts @ R.T + np.array([30.0, -4.0, 7.0])  # the scanner's own frame
    res, *_ = correct_files(d / "design.h5", [moved], free_pose=True, adjust=("lambda", "theta"))
    # the estimated transform takes the points back near the archive frame: what a rigid motion of the
    # whole robot explains (errors of the first segments) is not separable from the frame, so not exactly
    frame_error = np.sqrt(np.mean(np.sum((res.measurements[0].points - pts) ** 2, axis=1)))
    assert frame_error < 2.0, frame_error
    z = (res.estimate.systematic - np.array(TRUTH)) / res.estimate.systematic_std
    assert np.all(np.abs(z) < 3), z
    problem, dev = setup["problem"], setup["dev"]
    assert built_error(problem, res.corrected.routing, dev) < 0.5 * built_error(problem, setup["nominal"], dev)


@pytest.mark.slow
def test_spam_one_shared_lambda(tmp_path):
    p = tmp_path / "spam.toml"
    p.write_text(PROBLEM.replace("[design]", '[actuator]\nkind = "spam"\nlambda_min = 0.5\n[design]'))
    assert main(["design", str(p), "-o", str(tmp_path / "d.h5")]) in (0, 1)
    from vine_nlp.io.archive import load_archive

    problem = load_problem(p).problem
    nominal = load_archive(tmp_path / "d.h5").runs["nlp"].routing
    dev = draw_deviations(nominal, Sigmas.from_degrees(0.5, 0.0, 0.01), (0.0, -0.03, 1.0), seed=1)
    pts = simulate_build(nominal, dev, problem.diameter, "outer", 150, NOISE, seed=2)
    res = C.correct(problem, [nominal], [C.Measurement(pts, "outer")], sigmas=Sigmas.from_degrees(0.5, 0.01, 0.01))
    lam = res.corrected.routing.lam
    assert np.ptp(lam) == 0.0  # one pressure
    assert abs(res.estimate.systematic[1] + 0.03) < 3 * res.estimate.systematic_std[1]
    assert built_error(problem, res.corrected.routing, dev) < built_error(problem, nominal, dev)


def test_tampered_correction_archive_is_one_line(setup, tmp_path, capsys):
    import shutil

    bad = tmp_path / "bad.h5"
    shutil.copy(setup["dir"] / "c1.h5", bad)
    with h5py.File(bad, "a") as h5:
        h5["measured/0"].attrs["line"] = "side"
    out = tmp_path / "o.h5"
    _fails(capsys, ["correct", str(bad), str(setup["dir"] / "m1.csv"), "-o", str(out)], out, "/measured/0@line: must be one of")
    shutil.copy(setup["dir"] / "c1.h5", bad)
    with h5py.File(bad, "a") as h5:
        del h5["correction/builds/0/lambda"]
    _fails(capsys, ["correct", str(bad), str(setup["dir"] / "m1.csv"), "-o", str(out)], out, "/correction/builds/0: missing lambda")
    _fails(capsys, ["calibrate", str(setup["dir"] / "c1.h5"), "-o", str(tmp_path / "cal.txt")], tmp_path / "cal.txt", ".toml")


@pytest.mark.parametrize("free", [False, True])
def test_measure_slot_is_the_point_to_line_residual_of_the_model(free):
    # one slot of the estimate's NLP: the numpy model's line point at (segment, fraction), minus the measured
    # point (moved by the rigid transform when free), with the tangent projected out, times the weight
    rng = np.random.default_rng(4)
    M = 5
    r = Routing(theta=rng.uniform(-0.6, 0.6, M), lam=np.r_[rng.uniform(0.4, 0.9, M - 1), 0.99], length=rng.uniform(1.0, 3.0, M), initial_pose=np.eye(4))
    bt = measure_block(free)
    shift = np.array([0.03, 0.05, 1.05])  # an earlier build: its theta and lambda shifted, its lengths scaled
    # the physical rule: its lambda at most 1 (the cap of an earlier build, rounded over CAP_ROUND)
    x = r.lam + shift[1]
    built = Routing(theta=r.theta + shift[0], lam=0.5 * (1 + x - np.sqrt((1 - x) ** 2 + CAP_ROUND**2)), length=r.length * shift[2], initial_pose=np.eye(4))
    assert abs(built.lam[-1] - 1.0) < CAP_ROUND and np.all(np.abs(built.lam[:-1] - x[:-1]) < 1e-5)
    w_rot, t_move, c = np.array([0.1, -0.2, 0.05]), np.array([0.3, 0.1, -0.2]), np.array([1.0, 2.0, 0.5])
    for j, u, side in ((0, 0.0, -0.5), (2, 0.4, 0.5), (4, 1.0, 0.0), (4, 0.6, -0.5)):
        m, t = rng.normal(size=3), rng.normal(size=3)
        t /= np.linalg.norm(t)
        P, _ = line_points(built, 1.0, [j], [u], side)
        X = frames12(chain_frames(built.theta, built.lam, built.length, 1.0))[:, j]
        v = np.r_[X, r.theta[j], r.lam[j], r.length[j]]
        d = np.r_[shift, u, m, t, 0.7, side]
        mm = m
        if free:
            v = np.r_[v, w_rot, t_move]
            d = np.r_[d, c, 1.0]
            mm = so3_exp(w_rot) @ (m - c) + c + t_move
        d = np.r_[d, 1.0]
        e = P[0] - mm
        want = 0.7 * (e - (1 - SLIDE) * t * np.dot(t, e))
        np.testing.assert_allclose(np.array(bt.residual(v, d)).ravel(), want, atol=1e-12)
        assert float(bt.fn(v, d)[0]) == pytest.approx(np.sum(want**2), rel=1e-12)


def test_estimate_compiles_once_and_takes_the_interpreted_steps(setup, monkeypatch, tmp_path):
    # the ICP pairing is data: one structure serves every round, so the estimate compiles once, and its
    # compiled functions give the interpreted estimate
    from vine_nlp.methods import compiled
    from vine_nlp.methods.transcription import get_solver

    get_solver.cache_clear()  # built solvers are cached per structure, whatever the mode they were built in
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    monkeypatch.setenv("VINE_NLP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("VINE_NLP_CFLAGS", "-O0")
    if compiled.compiler() is None:
        pytest.skip("no C compiler on this machine")
    problem, nominal = setup["problem"], setup["nominal"]
    pts = simulate_build(nominal, setup["dev"], problem.diameter, "outer", 60, NOISE, seed=9)
    run = dict(nominals=[nominal], measurements=[C.Measurement(pts, "outer")], D=problem.diameter, sigmas=SIGMAS,
               measurement_sigma=NOISE)
    before = dict(compiled.stats)
    fast = C.estimate_as_built(**run)
    assert fast.rounds > 1
    assert compiled.stats["compiled"] == before["compiled"] + 1
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    get_solver.cache_clear()  # the interpreted solver of the same structure
    slow = C.estimate_as_built(**run)
    assert (fast.iterations, fast.rounds) == (slow.iterations, slow.rounds)
    for a, b in ((fast.routing.theta, slow.routing.theta), (fast.routing.lam, slow.routing.lam), (fast.std, slow.std)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-8)


def test_correction_rule_known_answers():
    # the buildable rules' variant for a correction: the margin is spent, no actuator added (analysis.buildability)
    built = Routing(theta=np.zeros(6), lam=np.array([0.8, 0.8, 1.0, 1.0, 0.7, 0.7]), length=np.full(6, 4.0))

    def rule(lam):
        return correction_missed(dataclasses.replace(built, lam=np.array(lam)), built.lam, 2.43, "tendon", 0.4, 0.2, "cm")

    assert rule([0.97, 0.97, 1.0, 1.0, 0.7, 0.7]) == []  # inside the correction margin: what a correction is for
    assert rule([0.8, 0.8, 0.9, 1.0, 0.7, 0.7]) == [
        "1 segment(s) with an actuator where the robot has none (lambda exactly 1 there; segments 2)"]
    assert rule([0.35, 0.8, 1.0, 1.0, 0.7, 0.7]) == [
        "1 segment(s) with lambda neither 1 nor in [0.4, 1] (the actuator's range; segments 0)"]
    # partners' gaps join: 2 x 4 x 0.02 = 0.16 cm < 0.2 cm
    assert rule([0.98, 0.98, 1.0, 1.0, 0.7, 0.7]) == ["1 feature(s) below min_feature 0.2 cm (smallest: 0.16 cm stopper gap)"]


def _straight_run_robot(tmp_path, wound: bool):
    """A design archive of a known buildable routing (actuated 0-3 and 7-9, straight 4-6 at one slope; ``wound``: one full
    turn more there, the same shape) and the points of the robot built from it whose actuators all contract 0.04 more."""
    M, D = 10, 2.43
    lam = np.where(np.arange(M) < 4, 0.92, np.where(np.arange(M) > 6, 0.8, 1.0))
    theta = np.array([0.3, 0.25, 0.2, 0.15, 0.1, 0.1, 0.1, -0.2, -0.25, -0.3])
    if wound:
        theta[4:7] = np.arctan(np.tan(theta[4:7]) + math.pi * D / 12.0)  # the line turns 2 pi more over the 12 cm run
    nominal = Routing(theta=theta, lam=lam, length=np.full(M, 4.0))
    problem = DesignProblem("run", D, forward_shape(nominal, D, per_segment=10).center)
    run = evaluate(problem, nominal, pair_points(problem.target, 10), "nlp")
    write_archive(tmp_path / "d.h5", Archive("run", "design", "", D, "cm", problem.target, {"nlp": run}))
    dev = C.Deviations(np.zeros(M), np.where(lam < 1, -0.04, 0.0), np.ones(M), 0.4)
    return write_csv(tmp_path / "m.csv", simulate_build(nominal, dev, D, "outer", 150, 0.01, seed=4)), nominal


@pytest.mark.parametrize("wound", [False, True])
def test_a_correction_spends_the_margin_and_is_judged(tmp_path, capsys, wound):
    m, nominal = _straight_run_robot(tmp_path, wound)
    code = main(["correct", str(tmp_path / "d.h5"), str(m), "-o", str(tmp_path / "c.h5"), "--adjust", "lambda"])
    err = capsys.readouterr().err.strip().splitlines()
    corr = read_correction(tmp_path / "c.h5")[0].runs["corrected"]
    # known answer: the actuators contract 0.04 more, so their nominal goes up by 0.04; 0.96 is inside the correction
    # margin (a design could not have it) and its gaps meet min_feature with their partners'
    np.testing.assert_allclose(corr.routing.lam, np.where(nominal.lam < 1, nominal.lam + 0.04, 1.0), atol=0.01)
    assert np.all(corr.routing.lam[nominal.lam == 1.0] == 1.0)
    if not wound:
        assert code == 0 and err == [] and corr.shortfall == ()
        assert correction_missed(corr.routing, nominal.lam, 2.43, "tendon", 0.4, 0.2) == []
        assert buildability(corr.routing, 2.43, "tendon", 0.4, 0.05, 0.2).missed(0.45, 0.95)  # a design's rule: the margin
        return
    # the line kept as built winds a full turn where no actuator needs it: one line, exit 1
    assert code == 1 and len(err) == 1, err
    assert err[0].startswith("correct: corrected (lambda): not buildable: the actuator line turns ")
    need = 2 * math.tan(0.1) * 12.0 / 2.43 / (2 * math.pi)  # turns: (2 / D) tan(theta) l over the run, one full turn more
    assert err[0].endswith(f"turns {need + 1:.3g} turn(s) where lambda = 1, the routing needs {need:.3g} there (pointless turning); "
                           "the best correction found is written")
    assert corr.shortfall == (err[0].split(": ", 2)[2].removesuffix("; the best correction found is written"),)
