"""Figures, 1:1 fabrication templates and the archive summary."""

import csv
import math
import re
import warnings

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from matplotlib.text import Text

from vine_nlp.front import palette
from vine_nlp.front import template as tpl
from vine_nlp.front.figures import draw
from vine_nlp.front.plot import plot_archive, point_s, tube_surface
from vine_nlp.front.show import summarize
from vine_nlp.io.archive import Archive, load_archive, write_archive
from vine_nlp.methods.common import evaluate, pair_points, run_forward
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.model.shape import forward_shape
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, ForwardProblem, Routing

D = 2.43
N = 4  # points per segment
PAGE_PT = {"A4": (595.28, 841.89), "Letter": (612.0, 792.0)}
SOURCE = """name = "small"
units = "{units}"
[tube]
diameter = {D}
[target]
curve = "points"
file = "target.csv"
[actuator]
kind = "{kind}"
lambda_min = 0.4
theta_max_deg = 60.0
"""


def wave_routing(m=10, dl=4.0, scale=1.0):
    s = np.arange(m) * dl
    return Routing(theta=np.radians(20 * np.sin(0.15 * s / scale) + 5), lam=0.7 + 0.1 * np.cos(0.2 * s / scale), length=np.full(m, dl))


def _design(kind="tendon"):
    target = forward_shape(wave_routing(), D, per_segment=N).center
    problem = DesignProblem("small", D, target, Actuator(kind=kind), DesignOptions(points_per_segment=N))
    return problem, design_nlp(problem)


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
    """Paths of a forward archive, a design archive with runs nlp and greedy, and an sPAM design archive."""
    d = tmp_path_factory.mktemp("archives")
    fwd = run_forward(ForwardProblem("wave", D, wave_routing()))
    write_archive(d / "forward.h5", Archive("wave", "forward", "", D, runs={"forward": fwd}))
    problem, nlp = _design()
    # a second run: the nlp design with theta perturbed, evaluated like a design method would
    r = nlp.routing
    other = Routing(theta=r.theta + 0.02 * np.sin(np.arange(r.segments)), lam=r.lam, length=r.length, initial_pose=r.initial_pose)
    greedy = evaluate(problem, other, pair_points(problem.target, N), "greedy", status="acceptable", iterations=3)
    src = SOURCE.format(units="cm", D=D, kind="tendon")
    write_archive(d / "design.h5", Archive("small", "design", src, D, target=problem.target, runs={"nlp": nlp, "greedy": greedy}))
    sproblem, snlp = _design("spam")
    ssrc = SOURCE.format(units="cm", D=D, kind="spam")
    write_archive(d / "spam.h5", Archive("small-spam", "design", ssrc, D, target=sproblem.target, runs={"nlp": snlp}))
    return {"forward": d / "forward.h5", "design": d / "design.h5", "spam": d / "spam.h5"}


def long_archive(units="cm", m=30, dl=4.0):
    """A forward routing long enough for several strips and pages (lengths in ``units``)."""
    f = {"cm": 1.0, "mm": 10.0, "m": 0.01}[units]
    routing = wave_routing(m, dl * f, scale=f)
    result = run_forward(ForwardProblem("long", D * f, routing, units=units))
    return Archive("long", "forward", "", D * f, units=units, runs={"forward": result})


# ------------------------------------------------------------------ figures


@pytest.mark.parametrize("which", ["forward", "design"])
@pytest.mark.parametrize("suffix", ["png", "pdf"])
def test_figures_render_without_warnings(archives, tmp_path, which, suffix):
    out = tmp_path / f"fig.{suffix}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        draw(archives[which], out)
    data = out.read_bytes()
    assert data.startswith(b"\x89PNG" if suffix == "png" else b"%PDF")
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]  # no temporary file left


def test_figure_is_readable_and_labelled(archives):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = plot_archive(archives["design"])
        fig.canvas.draw()
    sizes = [t.get_fontsize() for t in fig.findobj(Text) if t.get_text().strip() and t.get_visible()]
    assert min(sizes) >= 7
    axes3d = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(axes3d) == 2  # one 3-D view per run
    for ax in axes3d:
        for label in (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()):
            assert "[cm]" in label
        lo, hi = zip(ax.get_xlim(), ax.get_ylim(), ax.get_zlim())
        assert np.ptp(np.subtract(hi, lo)) < 1e-9  # equal scaling
    panels = [ax for ax in fig.axes if ax.name == "rectilinear" and ax.get_xlabel()]
    assert len(panels) == 4  # error, theta, lambda, phi
    for ax in panels:
        assert "[cm]" in ax.get_xlabel() and "[" in ax.get_ylabel()
    assert any("colorbar" in ax.get_label() or "error" in ax.get_ylabel() for ax in fig.axes if ax.name == "rectilinear")
    legends = " ".join(t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts())
    assert "nlp (RMSE" in legends and "greedy (RMSE" in legends


def test_the_design_figure_shows_what_it_says(archives):
    """Angles in one unit, every line in the legend, the target over the tube, obstacles in every 3-D view."""
    from vine_nlp.model.obstacles import Sphere

    a = load_archive(archives["design"])
    a.obstacles = [Sphere(tuple(a.target[len(a.target) // 2] + [0.0, 0.0, 3 * D]), D)]
    fig, bare = plot_archive(a, obstacles=a.obstacles), plot_archive(a)
    fig.canvas.draw()  # mplot3d gives the collections their depth-sorted zorders when drawn
    phi = [ax for ax in fig.axes if ax.get_ylabel().startswith(r"$\phi$")][0]
    assert phi.get_ylabel() == r"$\phi$ [deg]"
    np.testing.assert_allclose(phi.get_lines()[0].get_ydata(), np.degrees(a.runs["nlp"].phi))
    views = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(views) == 2
    for ax, without in zip(views, [ax for ax in bare.axes if ax.name == "3d"]):
        (target,) = [line for line in ax.get_lines() if line.get_label() == "target"]
        assert target.get_zorder() > max(c.get_zorder() for c in ax.collections)  # drawn last: never under the wall
        assert len(ax.collections) == len(without.collections) + 1  # the sphere, in every view
    legend = views[0].get_legend()
    assert [t.get_text() for t in legend.get_texts()] == ["target", "tube (true D)", "actuator line", "opposite line (twist)",
                                                           "center line (colour: error)", "segment ends", "obstacle"]
    # one colour per thing, the same in view, animate and the template (front/palette.py)
    handles = dict(zip([t.get_text() for t in legend.get_texts()], legend.legend_handles))
    for label, colour in (("target", palette.TARGET), ("tube (true D)", palette.TUBE), ("actuator line", palette.ACTUATOR),
                          ("opposite line (twist)", palette.OPPOSITE), ("obstacle", palette.OBSTACLE)):
        h = handles[label]
        assert to_rgb(h.get_color() if hasattr(h, "get_xdata") else h.get_facecolor()[:3]) == to_rgb(colour), label
    assert (tpl.STOPPER_COLOR, tpl.GAP_COLOR) == (palette.ACTUATOR, palette.REMOVED)
    assert len({palette.ACTUATOR, palette.OPPOSITE, palette.TARGET, palette.TUBE, palette.OBSTACLE, palette.CONTACT,
                palette.REMOVED, palette.CHANGE, *palette.RUNS}) == 8 + len(palette.RUNS)  # no colour for two things


def test_forward_figure_has_no_error_panel(archives):
    fig = plot_archive(archives["forward"])
    labels = [ax.get_ylabel() for ax in fig.axes if ax.name == "rectilinear"]
    assert not any("error" in label for label in labels)
    assert len([ax for ax in fig.axes if ax.name == "3d"]) == 1


def test_tube_surface_has_true_diameter(archives):
    a = load_archive(archives["design"])
    shape = a.runs["nlp"].shape
    X, Y, Z = tube_surface(shape, a.diameter)
    wall = np.stack([X, Y, Z], axis=-1)
    center = 0.5 * (shape.inner + shape.outer)
    r = np.linalg.norm(wall - center[:, None, :], axis=-1)
    np.testing.assert_allclose(r, a.diameter / 2, rtol=1e-12)


def test_error_is_plotted_against_tube_length(archives):
    a = load_archive(archives["design"])
    r = a.runs["nlp"]
    s = point_s(a, r)
    p = pair_points(a.target, N)
    edges = np.concatenate([[0.0], np.cumsum(r.routing.length)])
    np.testing.assert_allclose(s, edges[p.seg] + p.frac * r.routing.length[p.seg], atol=1e-12)
    assert s[0] == 0.0 and s[-1] == pytest.approx(edges[-1])


def test_unknown_figure_format_is_refused(archives, tmp_path):
    with pytest.raises(ValueError, match="png"):
        draw(archives["forward"], tmp_path / "fig.jpg")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ templates


def pdf_pages(path):
    data = path.read_bytes()
    pages = len(re.findall(rb"/Type\s*/Page(?![a-zA-Z])", data))
    boxes = [tuple(float(v) for v in m.split()) for m in re.findall(rb"/MediaBox\s*\[\s*([-\d.\s]+?)\s*\]", data)]
    return pages, boxes


def read_cuts(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return [{k: float(v) if v != "" else math.nan for k, v in row.items()} for row in rows]  # "": does not apply


@pytest.mark.parametrize("paper", ["A4", "Letter"])
def test_template_pages_and_paper_size(tmp_path, paper):
    a = long_archive()
    pdf = tmp_path / "template.pdf"
    info = tpl.write_template(a, pdf, paper=paper)
    pages, boxes = pdf_pages(pdf)
    assert info["pages"] == pages > 1
    assert info["strips"] > info["pages"] or info["strips"] >= pages
    assert len(boxes) == pages
    w, h = PAGE_PT[paper]
    for box in boxes:
        assert box[:2] == (0.0, 0.0)
        assert sorted(box[2:]) == pytest.approx(sorted((w, h)), abs=0.01)
    pw, ph = info["paper_mm"]
    assert sorted((pw, ph)) == pytest.approx(sorted(v / 72 * 25.4 for v in (w, h)), abs=0.01)


def test_template_csv(archives, tmp_path):
    pdf, cuts = tmp_path / "t.pdf", tmp_path / "CUTS.csv"
    info = tpl.write_template(archives["design"], pdf, cuts)
    a = load_archive(archives["design"])
    r = a.runs["nlp"]
    assert info["run"] == "nlp"  # the default: nlp before greedy
    rows = read_cuts(cuts)
    with open(cuts) as f:
        assert f.readline().strip().split(",") == list(tpl.CSV_COLUMNS)
    assert len(rows) == r.routing.segments == info["segments"]
    C = math.pi * a.diameter
    for j, row in enumerate(rows):
        assert row["segment"] == j
        assert row["stopper_length"] + row["gap_length"] == pytest.approx(row["actuator_length"], rel=1e-9)
        dl = row["s_end"] - row["s_start"]
        assert row["actuator_length"] == pytest.approx(dl / math.cos(math.radians(row["theta_deg"])), rel=1e-8)
        assert row["stopper_length"] == pytest.approx(row["lambda"] * row["actuator_length"], rel=1e-8)
        assert 0.0 <= row["c_start"] < C and 0.0 <= row["c_end"] < C
        for key, phi in (("c_start", "phi_start_rad"), ("c_end", "phi_end_rad")):
            assert (row[key] - 0.5 * a.diameter * row[phi]) / C == pytest.approx(round((row[key] - 0.5 * a.diameter * row[phi]) / C), abs=1e-8)
        if j:
            assert row["s_start"] == pytest.approx(rows[j - 1]["s_end"], rel=1e-9)
            assert row["phi_start_rad"] == pytest.approx(rows[j - 1]["phi_end_rad"], rel=1e-9)
    assert rows[0]["s_start"] == 0.0 and rows[0]["phi_start_rad"] == 0.0
    assert sum(row["s_end"] - row["s_start"] for row in rows) == pytest.approx(r.routing.length.sum(), rel=1e-9)
    np.testing.assert_allclose([row["phi_end_rad"] for row in rows], r.phi[1:], rtol=1e-9)
    assert info["stoppers"] == info["gaps"] == r.routing.segments  # every segment split (lambda < 1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["CUTS.csv", "t.pdf"]


def test_template_run_choice(archives, tmp_path):
    info = tpl.write_template(archives["design"], tmp_path / "g.pdf", tmp_path / "g.csv", run="greedy")
    assert info["run"] == "greedy"
    rows = read_cuts(tmp_path / "g.csv")
    theta = load_archive(archives["design"]).runs["greedy"].routing.theta
    np.testing.assert_allclose([row["theta_deg"] for row in rows], np.degrees(theta), rtol=1e-9)
    with pytest.raises(ValueError, match="no run"):
        tpl.write_template(archives["design"], tmp_path / "x.pdf", run="fit")
    assert not (tmp_path / "x.pdf").exists()
    assert tpl.write_template(archives["forward"], tmp_path / "f.pdf")["run"] == "forward"


def test_spam_template_has_no_stoppers(archives, tmp_path):
    info = tpl.write_template(archives["spam"], tmp_path / "s.pdf", tmp_path / "s.csv")
    assert info["spam"] is True
    assert info["stoppers"] == 0 and info["gaps"] == 0
    rows = read_cuts(tmp_path / "s.csv")
    assert np.ptp([row["lambda"] for row in rows]) < 1e-12  # one lambda for the whole muscle
    # the flag overrides the problem file
    assert tpl.write_template(archives["design"], tmp_path / "d.pdf", spam=True)["stoppers"] == 0
    assert tpl.write_template(archives["spam"], tmp_path / "d.pdf", spam=False)["stoppers"] > 0


@pytest.mark.parametrize("units", ["cm", "mm"])
def test_template_is_one_to_one(units):
    """1 cm of tube is 1 cm on the page, whatever the problem's units; strips share 1 cm."""
    a = long_archive(units)
    table = tpl.cut_table(a, "forward")
    cm = tpl.CM_PER_UNIT[units]
    lay = tpl.layout(table["s_end"][-1] * cm, math.pi * a.diameter * cm, "A4", unit_per_cm=1 / cm)
    fig = tpl._page(a, "forward", [table | {"spam": False, "style": tpl.STYLE}], lay, 0)
    W_mm, H_mm = lay.width_mm, lay.height_mm
    assert tuple(fig.get_size_inches() * 25.4) == pytest.approx((W_mm, H_mm))
    strips = [ax for ax in fig.axes]
    assert 1 <= len(strips) <= lay.per_page
    for ax in strips:
        box = ax.get_position()
        (s0, s1), (c0, c1) = ax.get_xlim(), ax.get_ylim()
        assert box.width * W_mm / ((s1 - s0) * cm) == pytest.approx(10.0)  # mm per cm of tube
        assert box.height * H_mm / ((c1 - c0) * cm) == pytest.approx(10.0)
        assert box.x0 >= 0 and box.x1 <= 1 and box.y0 >= 0 and box.y1 <= 1
    tiles = lay.tiles
    assert tiles[0].s0 == 0 and tiles[-1].s_end == pytest.approx(table["s_end"][-1])
    for t, nxt in zip(tiles[:-1], tiles[1:]):
        assert nxt.s0 == pytest.approx(t.s1)
        assert (t.s_end - nxt.s0) * cm == pytest.approx(1.0)  # the shared centimetre
        assert t.label.startswith(f"strip {t.index + 1}/{len(tiles)}")


def test_template_refuses_other_units(tmp_path):
    a = long_archive("m")
    with pytest.raises(ValueError, match="cm or mm"):
        tpl.write_template(a, tmp_path / "t.pdf", tmp_path / "c.csv")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="paper"):
        tpl.write_template(long_archive(), tmp_path / "t.pdf", paper="A3")
    assert list(tmp_path.iterdir()) == []


def test_template_keeps_existing_files_on_failure(archives, tmp_path, monkeypatch):
    pdf = tmp_path / "t.pdf"
    pdf.write_bytes(b"old")

    def boom(*args, **kwargs):
        raise RuntimeError("renderer failed")

    monkeypatch.setattr(tpl, "_page", boom)
    with pytest.raises(RuntimeError):
        tpl.write_template(archives["design"], pdf, tmp_path / "c.csv")
    assert pdf.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.pdf"]


# ------------------------------------------------------------------ show


def test_summary(archives):
    text = summarize(archives["design"])
    for piece in ("small (design)", "D = 2.43 cm", "actuator tendon", "vine_nlp", "target    41 points",
                  "run nlp", "run greedy", "status      acceptable", "segments    10", "rmse", "max_error", "tv_theta"):
        assert piece in text, piece
    assert text.index("run nlp") < text.index("run greedy")
    fwd = summarize(load_archive(archives["forward"]))
    assert "wave (forward)" in fwd and "run forward" in fwd and "rmse" not in fwd


def test_show_judges_as_the_design_does_and_rounds_to_what_numbers_mean():
    """Issue 46/47: a gap a hair below min_feature is printed to the digit that tells them apart, and counted below;
    lambda just below 1 is an actuator (only exactly 1 is none), said with the line's turning there; theta 1e-7 deg is 0."""
    from vine_nlp.analysis.buildability import digits

    assert digits(0.199107, 0.2) == "0.199107" and digits(0.2 - 1e-9, 0.2) == "0.199999999" and digits(0.2, 0.2) == "0.2"
    lam = np.array([1.0, 1.0 - 1e-8, 1.0 - 4e-7, 0.8, 0.8, 1.0])
    theta = np.array([1e-9, np.radians(60), np.radians(-60), 0.1, 0.1, -2e-9])
    r = run_forward(ForwardProblem("n", D, Routing(theta=theta, lam=lam, length=np.full(6, 5.0))))
    text = summarize(Archive("n", "forward", SOURCE.format(units="cm", D=D, kind="tendon"), D, runs={"forward": r}))
    assert "  actuated    1 piece(s) (segments 1-4), 2 segment(s) without an actuator (lambda = 1)" in text
    turn = 2 * (2 / D) * math.tan(math.radians(60)) * 5.0 / (2 * math.pi)
    assert f"  near 1      2 segment(s) with lambda in (1 - margin, 1), not 1: an actuator that barely contracts; the line turns {turn:.3g} there" in text
    gap = re.search(r"smallest    (\S+) cm stopper gap \((\d+) below min_feature 0.2 cm\)", text)
    assert float(gap[1]) < 0.2 and int(gap[2]) >= 1
    zero = run_forward(ForwardProblem("z", D, Routing(theta=np.array([1.3e-9, -2.3e-9]), lam=np.array([1.0, 1.0]), length=np.full(2, 5.0))))
    text = summarize(Archive("z", "forward", "", D, runs={"forward": zero}))
    assert "  theta       0 to 0 deg" in text and "-0" not in text.split("theta")[1].splitlines()[0]


def test_template_warns_where_the_design_rules_refuse_what_it_draws(tmp_path, capsys):
    from vine_nlp.front.cli import main

    src = SOURCE.format(units="cm", D=D, kind="tendon")
    for name, lam in (("near", [1.0, 1.0 - 1e-8, 1.0, 0.8, 0.8]), ("fine", [1.0, 0.8, 0.8, 0.8, 1.0])):
        r = run_forward(ForwardProblem(name, D, Routing(theta=np.full(5, 0.05), lam=np.array(lam), length=np.full(5, 5.0))))
        write_archive(tmp_path / f"{name}.h5", Archive(name, "forward", src, D, runs={"forward": r}))
        assert main(["template", str(tmp_path / f"{name}.h5"), "-o", str(tmp_path / f"{name}.pdf")]) == 0
        err = capsys.readouterr().err
        if name == "fine":
            assert err == ""
        else:
            assert err.startswith(f"warning: {tmp_path / 'near.h5'}: run forward: not buildable as drawn: 1 feature(s) below min_feature 0.2 cm")
            assert err.rstrip().endswith("; 1 segment(s) with lambda neither 1 nor in [0.45, 0.95]") and err.count("\n") == 1


def test_show_lists_every_level_of_a_multishape_archive(tmp_path):
    from vine_nlp.io.formulations import write_multishape_archive
    from vine_nlp.methods.multishape import MultiShapeResult

    r = run_forward(ForwardProblem("m", D, Routing(theta=np.full(4, 0.05), lam=np.full(4, 0.87), length=np.full(4, 5.0))))
    ms = MultiShapeResult(method="multishape", routing=r.routing, shape=r.shape, status="optimal", solve_time_s=0.1, iterations=5,
                          metrics={"rmse": 0.0}, stats={}, diameter=D, levels=np.array([0.87, 0.92, 0.97]), fixed=(True, False, False),
                          poses=np.array([np.eye(4)] * 3), shapes=[r.shape] * 3, level_metrics=[{"rmse": 0.0, "max_error": 0.0}] * 3,
                          shared_pose=True)

    class PF:  # what write_multishape_archive reads of a ProblemFile
        name, units = "m", "cm"
        source = SOURCE.format(units="cm", D=D, kind="spam")
        problem = type("P", (), {"targets": [r.shape.center] * 3, "diameter": D})()

    path = tmp_path / "m.h5"
    write_multishape_archive(path, PF, ms)
    text = summarize(path)
    assert "  level 0     lambda 0.87 (fixed), rmse 0 cm" in text and "  level 1     lambda 0.92 (free), rmse 0 cm" in text
    assert "  level 2     lambda 0.97 (free), rmse 0 cm; outside [" in text and "0.95]: no room to correct" in text


# ------------------------------------------------------------------ SVG and DXF templates


def _dxf_lines(doc, layer):
    """(start, end) of every straight piece on ``layer``: LINEs and LWPOLYLINE edges, in drawing units."""
    out = []
    for e in doc.modelspace().query(f'LINE[layer=="{layer}"]'):
        out.append((np.array(e.dxf.start)[:2], np.array(e.dxf.end)[:2]))
    for e in doc.modelspace().query(f'LWPOLYLINE[layer=="{layer}"]'):
        pts = np.array(e.get_points("xy"))
        if e.closed:
            pts = np.vstack([pts, pts[:1]])
        out += list(zip(pts[:-1], pts[1:]))
    return out


def _length(lines):
    return float(sum(np.linalg.norm(b - a) for a, b in lines))


@pytest.mark.parametrize("units", ["cm", "mm"])
def test_dxf_template_is_one_to_one_in_mm(tmp_path, units):
    ezdxf = pytest.importorskip("ezdxf")
    a = long_archive(units, m=5)  # 20 cm of tube: one strip
    out = tmp_path / "t.dxf"
    info = tpl.write_template(a, out, tmp_path / "c.csv")
    assert info["format"] == "dxf" and info["pages"] == 1 and info["strips"] == 1
    doc = ezdxf.readfile(out)
    assert doc.header["$INSUNITS"] == 4  # millimetres
    assert {layer.dxf.name for layer in doc.layers} >= set(tpl.LAYERS)
    # the 10 cm scale bar measures 100 in the file's units
    bar = max(_dxf_lines(doc, "scale"), key=lambda ab: np.linalg.norm(ab[1] - ab[0]))
    assert np.linalg.norm(bar[1] - bar[0]) == pytest.approx(100.0, abs=1e-9)
    assert bar[0][1] == pytest.approx(bar[1][1])  # horizontal
    table = tpl.cut_table(a, "forward")
    mm = 10 * tpl.CM_PER_UNIT[units]
    # the path drawn is the actuator, unrolled: every segment dl / cos(theta) long, split lambda : 1 - lambda
    assert _length(_dxf_lines(doc, "actuator_path")) == pytest.approx(table["actuator_length"].sum() * mm, rel=1e-9)
    assert _length(_dxf_lines(doc, "stoppers")) == pytest.approx(table["stopper_length"].sum() * mm, rel=1e-9)
    assert _length(_dxf_lines(doc, "removed")) == pytest.approx(table["gap_length"].sum() * mm, rel=1e-9)
    # the strip's outline: the tube's length by its circumference, at 1:1
    (outline,) = doc.modelspace().query('LWPOLYLINE[layer=="outline"]')
    pts = np.array(outline.get_points("xy"))
    assert np.ptp(pts[:, 0]) == pytest.approx(table["s_end"][-1] * mm, rel=1e-9)
    assert np.ptp(pts[:, 1]) == pytest.approx(math.pi * a.diameter * mm, rel=1e-9)
    assert len(doc.modelspace().query('TEXT[layer=="text"]')) > 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.csv", "t.dxf"]


def test_svg_and_dxf_draw_the_strips_of_the_pdf(tmp_path):
    import xml.etree.ElementTree as ET

    ezdxf = pytest.importorskip("ezdxf")
    a = long_archive()  # 120 cm: several strips
    pdf = tpl.write_template(a, tmp_path / "t.pdf")
    svg = tpl.write_template(a, tmp_path / "t.svg")
    dxf = tpl.write_template(a, tmp_path / "t.dxf")
    assert pdf["strips"] == svg["strips"] == dxf["strips"] > 2
    table = tpl.cut_table(a, "forward")
    lay = tpl.layout(table["s_end"][-1], math.pi * a.diameter, "A4")
    widths = sorted(round((t.s_end - t.s0) * 10, 6) for t in lay.tiles)  # mm
    doc = ezdxf.readfile(tmp_path / "t.dxf")
    outlines = doc.modelspace().query('LWPOLYLINE[layer=="outline"]')
    assert sorted(round(float(np.ptp(np.array(o.get_points("xy"))[:, 0])), 6) for o in outlines) == widths
    ns = {"svg": "http://www.w3.org/2000/svg", "ink": "http://www.inkscape.org/namespaces/inkscape"}
    root = ET.parse(tmp_path / "t.svg").getroot()
    w, h = svg["paper_mm"]
    assert root.get("width") == f"{w:.3f}mm" and root.get("viewBox") == f"0 0 {w:.3f} {h:.3f}"  # user unit = 1 mm
    layers = {g.get(f"{{{ns['ink']}}}label"): g for g in root.findall("svg:g", ns)}
    assert set(layers) == set(tpl.LAYERS)
    polys = layers["outline"].findall("svg:polygon", ns)
    svg_widths = sorted(round(float(np.ptp([float(p.split(",")[0]) for p in g.get("points").split()])), 3) for g in polys)
    assert svg_widths == pytest.approx([round(v, 3) for v in widths], abs=1e-3)
    bar = [[tuple(map(float, p.split(","))) for p in pl.get("points").split()] for pl in layers["scale"].findall("svg:polyline", ns)]
    longest = max(bar, key=lambda pts: abs(pts[-1][0] - pts[0][0]))
    assert longest[-1][0] - longest[0][0] == pytest.approx(100.0)
    # the path on both sheets: the same total length (the shared centimetres are drawn on both strips they join)
    svg_path = sum(np.linalg.norm(np.diff(np.array([tuple(map(float, p.split(","))) for p in pl.get("points").split()]), axis=0), axis=1).sum()
                   for pl in layers["actuator_path"].findall("svg:polyline", ns))
    assert svg_path == pytest.approx(_length(_dxf_lines(doc, "actuator_path")), rel=1e-6)
    assert svg_path > table["actuator_length"].sum() * 10


def test_template_format_errors(archives, tmp_path, capsys):
    from vine_nlp.front.cli import main

    for name, message in (("t.svgz", "unknown template format '.svgz': use .pdf, .svg, .dxf"),
                          ("t", "unknown template format '(none)'")):
        assert main(["template", str(archives["design"]), "-o", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {tmp_path / name}: -o: {message}") and err.count("\n") == 1
    assert main(["template", str(archives["design"]), "-o", str(tmp_path / "t.dxf"), "--run", "zzz"]) == 2
    assert capsys.readouterr().err.startswith(f"error: {archives['design']}: --run: no run 'zzz'")
    assert list(tmp_path.iterdir()) == []
    assert main(["template", str(archives["design"]), "-o", str(tmp_path / "t.svg")]) == 0
    assert "the 10 cm scale bar is 100 mm in the file" in capsys.readouterr().out
