"""The doors of an archive of several actuators on one tube: export, analyze, template, view and animate per state
(spec "Several actuators on one tube"): what each draws or writes is the model's shape of each state."""

from __future__ import annotations

from types import SimpleNamespace

import h5py
import numpy as np
import pytest
import trimesh

from vine_nlp.analysis.collision import growth_contacts, routing_clearance
from vine_nlp.analysis.tolerance import tolerance_report
from vine_nlp.front import export
from vine_nlp.front.analyze import state_collision, state_tolerance
from vine_nlp.front.cli import main
from vine_nlp.front.states import state_lines
from vine_nlp.io.actuators import read_actuators_archive, write_actuators_archive
from vine_nlp.io.problems import ProblemFile
from vine_nlp.methods.actuators import ActuatorsProblem, Line, arc_pairing, evaluate, sample_states, state_arcs
from vine_nlp.model.actuators import Lines, state_shape
from vine_nlp.model.chain import shape_lines
from vine_nlp.model.pairing import pair_points
from vine_nlp.model.routing import Routing, Sigmas
from vine_nlp.problem import Actuator

D = 2.4
LAM_A = [0.6] * 10 + [1.0] * 10
LAM_B = [1.0] * 10 + [0.7] * 10
FORWARD = f"""name = "two"
[tube]
diameter = {D}
[routing]
length = 20.0
segment_length = 1.0
[[actuators]]
name = "A"
theta_deg = 5.0
lambda = {LAM_A}
[[actuators]]
name = "B"
theta_deg = -3.0
lambda = {LAM_B}
phi0_deg = 180
[[states]]
name = "a"
active = ["A"]
[[states]]
name = "ab"
active = ["A", "B"]
"""
STATES = {"a": ("A",), "b": ("B",), "ab": ("A", "B")}


def lines() -> Lines:
    return Lines(("A", "B"), np.radians([[5.0] * 20, [-3.0] * 20]), [LAM_A, LAM_B], [0.0, np.pi], np.ones(20))


@pytest.fixture(scope="module")
def forward(tmp_path_factory):
    d = tmp_path_factory.mktemp("fwd")
    (d / "p.toml").write_text(FORWARD)
    assert main(["forward", str(d / "p.toml"), "-o", str(d / "o.h5")]) == 0
    return d / "o.h5"


@pytest.fixture(scope="module")
def design(tmp_path_factory):
    """A design archive whose targets the lines meet exactly (three states: A, B, both)."""
    path = tmp_path_factory.mktemp("design") / "d.h5"
    ls = lines()
    problem = ActuatorsProblem("d", D, (Line("A"), Line("B")), STATES, targets=sample_states(ls, D, STATES, 41), units="cm")
    result = evaluate(problem, ls, status="optimal")
    write_actuators_archive(path, ProblemFile(str(path), "# made by the test\n", "actuators", "d", "cm", problem), {"nlp": result})
    return path


def segment_ends(ls, active, state):
    M = ls.segments
    return state_shape(ls, D, active, np.r_[np.arange(M), M - 1], np.r_[np.zeros(M), 1.0], state).center


# ---------------------------------------------------------------- export


def test_state_lines_are_the_model_shape_at_every_segment_end():
    ls = lines()
    for s, active in STATES.items():
        seg, frac, shape, paths = state_lines(ls, D, active, s)
        ends = np.flatnonzero(frac == 0)
        assert np.array_equal(seg[ends], np.arange(20)) and frac[-1] == 1.0
        np.testing.assert_allclose(shape.center[np.r_[ends, -1]], segment_ends(ls, active, s), atol=1e-12, rtol=0)
        np.testing.assert_allclose(np.linalg.norm(paths["A"] - shape.center, axis=1), D / 2, atol=1e-12)  # on the wall
        # where a line shapes the tube, it is the state's actuator line
        for name, part in (("A", seg < 10), ("B", seg >= 10)):
            if name in active:
                np.testing.assert_allclose(paths[name][part], shape.inner[part], atol=1e-12, rtol=0)


@pytest.mark.parametrize("ext", [".stl", ".glb"])
def test_export_every_state(forward, tmp_path, capsys, ext):
    out = tmp_path / f"t{ext}"
    assert main(["export", str(forward), "-o", str(out)]) == 0
    _, r, _ = read_actuators_archive(forward)
    for s in ("a", "ab"):
        f = tmp_path / f"t.{s}{ext}"
        scale = 0.01 if ext == ".glb" else 1.0  # cm -> m
        scene = trimesh.load(f, force="scene")
        tube = scene.geometry["tube"] if ext == ".glb" else next(iter(scene.geometry.values()))
        assert tube.is_watertight
        # every ring's center is the state's model shape there (glb keeps the vertices in order)
        ring = export.RING
        _, _, shape, _ = state_lines(r.lines, D, r.stats["states"][s], s)
        centers = np.asarray(tube.vertices[: len(shape.center) * ring]).reshape(-1, ring, 3).mean(axis=1) if ext == ".glb" else None
        if centers is not None:
            np.testing.assert_allclose(centers, shape.center * scale, atol=1e-9)
            assert sorted(scene.geometry) == ["actuator-A", "actuator-B", "tube"]
        else:  # closed, pi (D/2)^2 times the state's center line long (up to the 64-gon's area and the sampling)
            length = np.linalg.norm(np.diff(shape.center, axis=0), axis=1).sum()
            assert tube.volume / (np.pi * (D / 2) ** 2 * length) == pytest.approx(1, abs=3e-3)
            for name in ("A", "B"):
                assert trimesh.load(tmp_path / f"t.{s}.actuator-{name}{ext}").is_watertight
    assert not out.exists()
    assert "run forward state ab (A, B): " in capsys.readouterr().out


def test_export_one_state_into_the_file_named(forward, tmp_path):
    out = tmp_path / "ab.obj"
    assert main(["export", str(forward), "-o", str(out), "--state", "ab"]) == 0
    text = out.read_text()
    assert text.startswith("# vine_nlp tube of two run forward state ab, units cm")
    assert [x for x in text.splitlines() if x.startswith("o ")] == ["o tube", "o actuator-A", "o actuator-B"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ab.obj"]


@pytest.mark.parametrize("argv, message", [
    (["--state", "zz"], "{a}: --state: no state 'zz' (states: a, ab)"),
    (["--run", "nlp"], "{a}: --run: no run 'nlp' in the archive (runs: forward)"),
])
def test_export_bad_state_or_run(forward, tmp_path, capsys, argv, message):
    assert main(["export", str(forward), "-o", str(tmp_path / "t.stl"), *argv]) == 2
    assert capsys.readouterr().err == f"error: {message.format(a=forward)}\n"
    assert list(tmp_path.iterdir()) == []


def test_state_of_a_one_actuator_archive_is_refused(tmp_path, capsys):
    from vine_nlp.io.archive import Archive, write_archive
    from vine_nlp.methods.common import run_forward
    from vine_nlp.problem import ForwardProblem, Routing

    r = Routing(theta=np.zeros(3), lam=np.full(3, 0.7), length=np.ones(3))
    write_archive(tmp_path / "one.h5", Archive("one", "forward", "", D, runs={"forward": run_forward(ForwardProblem("one", D, r))}))
    assert main(["export", str(tmp_path / "one.h5"), "-o", str(tmp_path / "t.stl"), "--state", "a"]) == 2
    assert capsys.readouterr().err == (f"error: {tmp_path / 'one.h5'}: --state: an archive of one actuator has no states "
                                       "(--state is for archives of several actuators)\n")


# ---------------------------------------------------------------- analyze


def contents(path) -> dict:
    """Every attribute and dataset of an archive: path -> bytes or repr."""
    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = obj[()].tobytes()
        out.update({f"{name}@{k}": repr(v) for k, v in obj.attrs.items()})

    with h5py.File(path, "r") as h5:
        visit("", h5)
        h5.visititems(visit)
    return out


def test_state_tolerance_of_one_line_is_the_one_actuator_report():
    """One line: the state's tolerance (central differences, the same draws) is tolerance_report's."""
    M, pps = 8, 3
    r = Routing(theta=np.radians(np.linspace(-20, 30, M)), lam=[0.6, 0.7, 1.0, 0.5, 0.8, 1.0, 0.9, 0.55], length=np.linspace(1.0, 2.0, M))
    pairing = pair_points(np.column_stack([np.linspace(0, 12, M * pps + 1), np.zeros(M * pps + 1), np.zeros(M * pps + 1)]), pps)
    target = shape_lines(r.theta, r.lam, r.length, D, pairing.seg, pairing.frac)[0] + 0.05
    sig = Sigmas.from_degrees(1.0, 0.02, 0.02)
    problem = SimpleNamespace(diameter=D, target=target, options=SimpleNamespace(points_per_segment=pps), actuator=Actuator(lambda_min=0.4))
    want = tolerance_report(problem, SimpleNamespace(routing=r), sig, samples=50, seed=3)
    ls = Lines(("A",), [r.theta], [r.lam], [0.0], r.length)
    got = state_tolerance(ls, D, ("A",), "s", target, pairing.seg, pairing.frac, sig, [0.4], samples=50, seed=3)
    assert got["nominal"]["rmse"] == pytest.approx(want["nominal"]["rmse"], abs=1e-12)
    np.testing.assert_allclose(got["monte_carlo"]["rmse"], want["monte_carlo"]["rmse"], rtol=1e-10)
    for key in ("rmse", "tip_std"):
        assert got["first_order"][key] == pytest.approx(want["first_order"][key], rel=1e-6)
    np.testing.assert_allclose(got["per_segment"]["tip_var_by_param"], want["per_segment"]["tip_var_by_param"], rtol=1e-5, atol=1e-12)


def test_state_collision_of_a_coil_is_the_routing_clearance():
    """A state whose one line shapes every segment: its contacts are those of the one-actuator routing."""
    ls = Lines(("A", "B"), np.zeros((2, 40)), [[0.4] * 40, [1.0] * 40], [0.0, 2.0], np.ones(40))
    got = state_collision(ls, D, ("A",), "coil", u="cm")
    want = routing_clearance(ls.routing(0), D)
    assert got["contacts"] == len(want["regions"]) >= 1
    assert got["min_clearance"] == pytest.approx(want["clearance"], rel=2e-3)
    first = min(g["growth_length"] for g in growth_contacts(ls.routing(0), D, actuation_steps=0))
    assert abs(got["first_contact_growth_length"] - first) <= D / 8


def test_analyze_every_state_and_write_metrics_keeping_the_archive(design, tmp_path, capsys):
    path = tmp_path / "d.h5"
    path.write_bytes(design.read_bytes())
    before = contents(path)
    assert main(["analyze", str(path), "--samples", "20", "--write-metrics"]) == 0
    out = capsys.readouterr().out
    assert [x for x in out.splitlines() if x.startswith("state ")] == ["state a (A)", "state b (B)", "state ab (A, B)"]
    assert out.count("  tolerance   sigma theta 1 deg, lambda 0.02, length 2 % (per segment, independent)") == 3
    assert out.endswith(f"metrics -> {path} (/runs/nlp/states/<state>/metrics)\n")
    after = contents(path)
    assert {k: v for k, v in after.items() if k in before} == before  # nothing lost, nothing changed
    added = set(after) - set(before)
    assert {k.split("@")[0] for k in added} == {f"runs/nlp/states/{s}/metrics" for s in STATES}
    _, r, _ = read_actuators_archive(path)
    assert r.state_metrics["ab"]["contacts"] == 0 and r.state_metrics["ab"]["tolerance_rmse_mc_mean"] > 0
    assert main(["show", str(path)]) == 0


def test_analyze_one_state_of_a_forward_archive(forward, tmp_path, capsys):
    path = tmp_path / "f.h5"
    path.write_bytes(forward.read_bytes())
    assert main(["analyze", str(path), "--state", "ab", "--write-metrics"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("state ab (A, B)\n  clearance   ") and "tolerance" not in out
    _, r, _ = read_actuators_archive(path)
    assert set(r.state_metrics) == {"ab"} and r.state_metrics["ab"]["contacts"] == 0
    assert main(["show", str(path)]) == 0 and main(["plot", str(path), "-o", str(tmp_path / "f.png")]) == 0
    assert main(["analyze", str(path), "--tolerance-figure", str(tmp_path / "t.png")]) == 2
    assert capsys.readouterr().err.endswith("error: command line: --tolerance-figure: not drawn for an archive of several actuators\n")


# ---------------------------------------------------------------- template


def _dxf_lines(doc, layer):
    return [np.array([tuple(e.dxf.start)[:2], tuple(e.dxf.end)[:2]]) for e in doc.modelspace().query(f'LINE[layer=="{layer}"]')]


def test_template_dxf_draws_every_line_from_its_start_in_its_own_layers(forward, tmp_path, capsys):
    import ezdxf

    from vine_nlp.front import palette
    from vine_nlp.front import template as tpl

    out = tmp_path / "t.dxf"
    assert main(["template", str(forward), "-o", str(out), "--csv", str(tmp_path / "c.csv")]) == 0
    assert "1 strip(s) cut for A4, run forward, 20 segments, tube 20 cm" in capsys.readouterr().out
    doc = ezdxf.readfile(out)
    ls, mm, C = lines(), 10.0, np.pi * D
    (outline,) = doc.modelspace().query('LWPOLYLINE[layer=="outline"]')
    origin = np.array(outline.get_points("xy"))[:, :2].min(axis=0)  # (s, c) = (0, 0)
    phi = ls.phi(D)
    for k, name in enumerate(("A", "B")):
        layer = doc.layers.get(f"stoppers-{name}")
        assert layer.rgb == tuple(int(palette.LINES[k][i:i + 2], 16) for i in (1, 3, 5))
        path = _dxf_lines(doc, f"actuator_path-{name}")
        # the line drawn: every segment dl / cos(theta) long, each point where phi_k puts it around the tube
        assert sum(np.linalg.norm(p[1] - p[0]) for p in path) == pytest.approx((ls.length / np.cos(ls.theta[k])).sum() * mm, rel=1e-9)
        sc = (np.concatenate(path) - origin) / mm
        want = 0.5 * D * np.interp(sc[:, 0], np.r_[0.0, np.cumsum(ls.length)], phi[k])
        gap = np.abs(np.mod(sc[:, 1] - want + C / 2, C) - C / 2)
        assert gap.max() < 1e-9
        on = ls.lam[k] < 1
        stoppers = sum(np.linalg.norm(p[1] - p[0]) for p in _dxf_lines(doc, f"stoppers-{name}"))
        assert stoppers == pytest.approx((ls.lam[k] * ls.length / np.cos(ls.theta[k]))[on].sum() * mm, rel=1e-9)
        # where it starts around the tube: a triangle at the base, at c = (D/2) phi_k[0], and its angle
        (start,) = doc.modelspace().query(f'LWPOLYLINE[layer=="actuator_path-{name}"]')
        tip = np.array(start.get_points("xy"))[:, :2]
        assert ((tip - origin) / mm)[:, 1].mean() == pytest.approx(0.5 * D * ls.phi0[k], abs=1e-9)
        texts = [t.dxf.text for t in doc.modelspace().query(f'TEXT[layer=="actuator_path-{name}"]')]
        assert texts == [f"{name}: \u03c6 = {np.degrees(ls.phi0[k]):.4g}\u00b0"]
    assert set(tpl.LAYERS) <= {layer.dxf.name for layer in doc.layers}
    rows = (tmp_path / "c.csv").read_text().splitlines()
    assert rows[0].startswith("actuator,segment,s_start") and len(rows) == 41
    assert rows[21].startswith("B,0,0,1,-3,1,3.14159265") and rows[1].startswith("A,0,0,1,5,0.6,0,")


def test_template_pdf_and_svg_of_several_lines(design, tmp_path):
    import xml.etree.ElementTree as ET

    from vine_nlp.front import palette
    from vine_nlp.front.template import write_actuators_template

    info = write_actuators_template(design, tmp_path / "t.pdf")
    assert (info["pages"], info["strips"], info["run"]) == (1, 1, "nlp") and (tmp_path / "t.pdf").read_bytes()[:5] == b"%PDF-"
    assert info["actuators"]["A"]["unactuated"] == 10 and info["actuators"]["B"]["stoppers"] == 10
    write_actuators_template(design, tmp_path / "t.svg")
    ink = "{http://www.inkscape.org/namespaces/inkscape}label"
    layers = {g.get(ink): g for g in ET.parse(tmp_path / "t.svg").getroot() if g.get(ink)}
    assert {"stoppers-A", "removed-B", "actuator_path-B"} <= set(layers)
    assert layers["stoppers-B"].get("stroke") == palette.LINES[1] and layers["removed-B"].get("stroke") == palette.REMOVED


# ---------------------------------------------------------------- view


def test_view_has_a_menu_of_states_each_drawing_its_shape(design, tmp_path, capsys):
    from vine_nlp.front.view import states_figure

    fig = states_figure(design)
    ls, K = lines(), 2
    per_state = 1 + K + 1 + 1  # tube, every line, center line, target
    assert len(fig.data) == 3 * per_state
    (menu,) = fig.layout.updatemenus
    assert [b.label for b in menu.buttons] == ["a (A)", "b (B)", "ab (A, B)"]
    for i, (s, active) in enumerate(STATES.items()):
        shown = menu.buttons[i].args[0]["visible"]
        assert shown == [i * per_state <= j < (i + 1) * per_state for j in range(len(fig.data))]
        center = fig.data[i * per_state + 1 + K]
        assert center.name == f"state {s}: center line"
        xyz = np.column_stack([center.x, center.y, center.z])
        seg, frac, shape, _ = state_lines(ls, D, active, s, spacing=D / 3)
        np.testing.assert_allclose(xyz, shape.center, atol=1e-5)  # the page's float32 of the model's state shape
        ends = np.flatnonzero(frac == 0)
        np.testing.assert_allclose(xyz[np.r_[ends, -1]], segment_ends(ls, active, s), atol=1e-5)
        widths = [fig.data[i * per_state + 1 + k].line.width for k in range(K)]
        assert widths == [5 if n in active else 2 for n in ("A", "B")]
        assert fig.data[i * per_state].visible == (i == 0)
    out = tmp_path / "v.html"
    assert main(["view", str(design), "-o", str(out)]) == 0
    assert "view of every state of run nlp" in capsys.readouterr().out and out.read_text().count("ab (A, B)") >= 1


# ---------------------------------------------------------------- animate


def test_state_to_state_frames_pass_through_every_state_and_release_before_pulling():
    from vine_nlp.front.animate import state_frames

    ls = lines()
    frames = state_frames(ls, D, STATES, 9)  # a -> b -> ab: a frame at every state and halfway between
    assert [f["title"] for f in frames[::4]] == ["state a: pulled A 100%", "state b: pulled B 100%", "state ab: pulled A 100%, B 100%"]
    for f, (s, active) in zip(frames[::4], STATES.items()):
        seg, frac, shape, paths = state_lines(ls, D, active, s)
        np.testing.assert_allclose(f["center"], shape.center, atol=1e-12, rtol=0)
        assert [w for _, _, w in f["lines"]] == [2.5 if n in active else 0.8 for n in ("A", "B")]
    # halfway from a to b: A released, B not yet pulled: the straight tube along the base's x axis
    assert frames[2]["title"] == "a \u2192 b: pulled none"
    np.testing.assert_allclose(frames[2]["center"][:, 1:], 0.0, atol=1e-12)
    assert frames[2]["center"][-1, 0] == pytest.approx(ls.length.sum(), abs=1e-12)
    # from b to ab: B stays pulled throughout, A is pulled up to its full lambda
    assert frames[6]["title"] == "b \u2192 ab: pulled A 50%, B 100%"
    assert [f["x"] for f in frames] == pytest.approx(np.linspace(0, 1, 9))


def test_animate_state_to_state(forward, tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "m.gif"
    assert main(["animate", str(forward), "-o", str(out), "--frames", "5"]) == 0
    assert capsys.readouterr().out == f"5 frames, run forward, state to state: a -> ab -> {out}\n"
    with Image.open(out) as im:
        assert im.n_frames == 5 and im.size == (1280, 768)


def test_template_draws_an_spam_line_as_one_muscle(tmp_path):
    from vine_nlp.front.template import write_actuators_template

    (tmp_path / "p.toml").write_text(FORWARD.replace('name = "B"\n', 'name = "B"\nkind = "spam"\nlambda_min = 0.5\n'))
    assert main(["forward", str(tmp_path / "p.toml"), "-o", str(tmp_path / "f.h5")]) == 0
    drawn = write_actuators_template(tmp_path / "f.h5", tmp_path / "t.pdf")["actuators"]
    assert drawn["B"]["spam"] and drawn["B"]["stoppers"] == 0 and not drawn["A"]["spam"] and drawn["A"]["stoppers"] == 10


def test_a_state_name_that_is_no_plain_name_is_refused(forward, tmp_path, capsys):
    """State names go into file names: an archive whose states are no plain names is refused, nothing written."""
    import json

    path = tmp_path / "bad.h5"
    path.write_bytes(forward.read_bytes())
    with h5py.File(path, "r+") as h5:
        g = h5["runs/forward"]
        g.attrs["states"] = json.dumps({"a": ["A"], "x/y": ["A", "B"]})
        g.create_group("states/x")
        g.move("states/ab", "states/x/y")  # the reader finds the state's group at states/x/y
    out = tmp_path / "t.stl"
    assert main(["export", str(path), "-o", str(out)]) == 2
    assert capsys.readouterr().err == f"error: {path}: /runs/forward@states: state name 'x/y' is not plain: letters, digits, '-', '_' or '.'\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.h5"]


def test_state_tolerance_first_order_is_the_monte_carlo_of_small_errors():
    """Two lines, state ab: for small errors the first-order expected MSE increase and the tip covariance are the
    Monte Carlo ones (each line's theta and lambda and the lengths mapped to the same columns in both)."""
    ls = lines()
    target = sample_states(ls, D, {"ab": ("A", "B")}, 41)["ab"] + 0.01
    seg, frac = arc_pairing(target, state_arcs(ls, D, ("A", "B")))
    rep = state_tolerance(ls, D, ("A", "B"), "ab", target, seg, frac, Sigmas.from_degrees(0.05, 0.002, 0.002), [0.4, 0.4], samples=1500, seed=1)
    fo, mc = rep["first_order"], rep["monte_carlo"]
    assert mc["mse_increase"] == pytest.approx(fo["mse_increase"], rel=0.1)
    assert mc["tip_std"] == pytest.approx(fo["tip_std"], rel=0.05)
    by = rep["per_segment"]["tip_var_by_param"]
    assert by.shape == (20, 3) and by[:, 1][np.r_[0:10]].min() > 0  # lambda errors where A has an actuator
    assert by.sum() == pytest.approx(fo["tip_std"] ** 2, rel=1e-9)
