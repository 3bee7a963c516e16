"""`vine-nlp view`: the HTML view of an archive or a sweep, checked in a real headless Chromium.

The browser tests drive Debian's chromium through its chromedriver with selenium
(the driver path is given, so Selenium Manager never runs and nothing is
downloaded). They are skipped, with the reason, only where those binaries are
missing (CI installs them: .ci/run).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from vine_nlp.front import palette, view
from vine_nlp.front.cli import main
from vine_nlp.io.archive import Archive, load_archive, write_archive
from vine_nlp.methods.common import run_forward
from vine_nlp.problem import ForwardProblem, Routing

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync", "--window-size=1100,800")
D = 2.0
ROOT = Path(__file__).resolve().parents[1]


def routing(m=12, dl=2.5, phase=0.0):
    s = np.arange(m) / m
    return Routing(theta=np.radians(15 * np.sin(2 * np.pi * s + phase) + 5), lam=0.6 + 0.2 * np.cos(2 * np.pi * s), length=np.full(m, dl))


def design_archive(obstacles=None) -> Archive:
    """A design archive with runs nlp and greedy (two routings) and the nlp shape as target."""
    nlp = run_forward(ForwardProblem("wave", D, routing()))
    greedy = run_forward(ForwardProblem("wave", D, routing(phase=0.3)))
    return Archive("wave", "design", "", D, target=nlp.shape.center, runs={"nlp": nlp, "greedy": greedy}, obstacles=list(obstacles or []))


@pytest.fixture(scope="module")
def archive_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("view") / "wave.h5"
    write_archive(path, design_archive())
    return path


@pytest.fixture(scope="module")
def trefoil(tmp_path_factory):
    """problems/trefoil-m4.toml designed by the command line (40 segments)."""
    out = tmp_path_factory.mktemp("trefoil") / "t.h5"
    proc = subprocess.run([sys.executable, "-m", "vine_nlp", "design", str(ROOT / "problems" / "trefoil-m4.toml"), "-o", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return out


# ------------------------------------------------------------------ the figure, no browser


def external_scripts(html: str) -> list[str]:
    """The src of every <script src=...> tag (scripts the page would fetch)."""
    return re.findall(r"<script[^>]*\ssrc=[\"']([^\"']+)", html)


def test_figure_traces_frames_and_sliders():
    from vine_nlp.model.obstacles import Box, Mesh, Sphere

    a = design_archive([Sphere((0.0, 0.0, -6.0), 2.0), Box((5.0, 5.0, 0.0), (1.0, 2.0, 3.0)),
                        Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])])
    fig = view.view_figure(a)
    names = [t.name for t in fig.data]
    per_run = ["tube (true D)", "actuator line", "opposite line (twist)", "center line"]
    assert names[:8] == [f"{run}: {thing}" for run in ("nlp", "greedy") for thing in per_run]
    assert names[8] == "target"
    assert names[9:] == ["obstacle 0 (sphere)", "obstacle 1 (box)", "obstacle 2 (mesh)"]
    assert [t.legendgroup for t in fig.data[:8]] == ["run nlp"] * 4 + ["run greedy"] * 4  # one legend click toggles a run
    assert all(t.showlegend for t in fig.data)  # every thing drawn is named in the legend
    # one colour per thing, the same as the figure's and the movie's (front/palette.py)
    colours = [fig.data[0].color, fig.data[1].line.color, fig.data[2].line.color, fig.data[8].line.color, fig.data[9].color]
    assert colours == [palette.TUBE, palette.ACTUATOR, palette.OPPOSITE, palette.TARGET, palette.OBSTACLE]
    assert fig.data[4].color == palette.TUBE and fig.data[5].line.color == palette.ACTUATOR
    assert fig.data[3].line.color not in colours and fig.data[7].line.color not in colours  # the runs' center lines
    assert fig.data[0].visible is True and fig.data[4].visible == "legendonly"
    assert len(fig.data[11].i) == 4  # the mesh's own faces
    sliders = fig.layout.sliders
    assert [s.name for s in sliders] == ["growth", "actuation"]
    assert len(sliders[0].steps) == view.GROWTH_STEPS + 1 and len(sliders[1].steps) == view.ACTUATION_STEPS + 1
    frames = {f.name: f for f in fig.frames}
    assert set(frames) == {f"grow-{k}" for k in range(view.GROWTH_STEPS + 1)} | {f"after-{k}" for k in range(view.ACTUATION_STEPS + 1)}
    assert list(frames["grow-3"].traces) == list(range(8))
    # the tube is at the true diameter: every ring point D/2 from its center point, and closed by caps
    c = np.column_stack([fig.data[3].x, fig.data[3].y, fig.data[3].z])
    V = np.column_stack([fig.data[0].x, fig.data[0].y, fig.data[0].z])
    rings = V[:-2].reshape(len(c), view.RING, 3)
    np.testing.assert_allclose(np.linalg.norm(rings - c[:, None, :], axis=2), D / 2, rtol=1e-5)
    np.testing.assert_allclose(V[-2:], c[[0, -1]], rtol=1e-6)
    F = np.column_stack([fig.data[0].i, fig.data[0].j, fig.data[0].k])
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    assert np.all(np.unique(edges, axis=0, return_counts=True)[1] == 2)  # closed: every edge in two triangles
    # every frame moves the same vertices (growth: the rings past the tip wait at the tip)
    assert {len(f.data[0].x) for f in fig.frames} == {len(V)}
    grow = next(f for f in fig.frames if f.name == "grow-0")
    g0 = np.column_stack([grow.data[0].x, grow.data[0].y, grow.data[0].z])[:-2].reshape(-1, view.RING, 3)
    np.testing.assert_allclose(np.linalg.norm(g0 - c[0], axis=2), D / 2, rtol=1e-5)  # nothing grown: every ring at the base
    np.testing.assert_allclose(g0, np.repeat(g0[:1], len(g0), axis=0))
    # the actuator line is on the surface
    inner = np.column_stack([fig.data[1].x, fig.data[1].y, fig.data[1].z])
    np.testing.assert_allclose(np.linalg.norm(inner - c, axis=1), D / 2, rtol=1e-5)
    outer = np.column_stack([fig.data[2].x, fig.data[2].y, fig.data[2].z])  # the opposite line: across the tube
    thin = np.unique(np.r_[np.arange(0, len(c), 2), len(c) - 1])  # every other point (half the page's bytes)
    np.testing.assert_allclose(outer, 2 * c[thin] - inner[thin], atol=1e-4 * D)


def test_obstacles_round_trip_through_the_archive(tmp_path):
    # /obstacles/<k> as the archive writes and reads them (attr shape, one dataset per parameter)
    from vine_nlp.model.obstacles import Box, Capsule, Mesh, Plane, Sphere

    a = design_archive()
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 degrees about z
    tetra = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    a.obstacles = [Sphere((0.0, 0.0, -6.0), 2.0, "ball"), Box((5.0, 5.0, 0.0), (1.0, 2.0, 3.0), R), Mesh(*tetra),
                   Capsule((0.0, 0.0, 0.0), (0.0, 10.0, 0.0), 1.0), Plane((0.0, 0.0, -10.0), (0.0, 0.0, 1.0))]
    write_archive(tmp_path / "obs.h5", a)
    fig = view.view_figure(load_archive(tmp_path / "obs.h5"))
    meshes = [t for t in fig.data if t.type == "mesh3d" and t.name.startswith("obstacle")]
    assert [t.name for t in meshes] == ["obstacle 0 ball (sphere)", "obstacle 1 (box)", "obstacle 2 (mesh)",
                                        "obstacle 3 (capsule)", "obstacle 4 (plane)"]

    def xyz(t):
        return np.column_stack([t.x, t.y, t.z])

    np.testing.assert_allclose(np.linalg.norm(xyz(meshes[0]) - [0, 0, -6], axis=1), 2.0, rtol=1e-6)
    np.testing.assert_allclose(np.ptp(xyz(meshes[1]), axis=0), [2.0, 1.0, 3.0], rtol=1e-6)  # size turned by R
    np.testing.assert_allclose(xyz(meshes[2]), tetra[0])
    assert np.column_stack([meshes[2].i, meshes[2].j, meshes[2].k]).tolist() == tetra[1].tolist()
    v = xyz(meshes[3])  # capsule: every point 1 from the segment p0-p1
    d = np.linalg.norm(v - np.column_stack([0 * v[:, 0], np.clip(v[:, 1], 0, 10), 0 * v[:, 0]]), axis=1)
    np.testing.assert_allclose(d, 1.0, rtol=1e-5)
    np.testing.assert_allclose(xyz(meshes[4])[:, 2], -10.0)


def test_growth_is_a_prefix_of_the_final_shape():
    r = routing()
    final = view.run_shape(r, D)
    total = float(r.length.sum())
    for lg in (0.0, 0.37 * total, 0.5 * total, total):
        grown = view.run_shape(r, D, upto=lg)
        n = len(grown["s"])
        assert grown["s"][-1] == pytest.approx(lg)
        assert np.all(np.diff(grown["s"]) >= 0)
        inside = final["s"] < lg
        np.testing.assert_allclose(grown["center"][: inside.sum()], final["center"][inside], atol=1e-12)
        # the grown tip lies on the final shape: the final line interpolated at lg
        tip = np.array([np.interp(lg, final["s"], final["center"][:, i]) for i in range(3)])
        assert np.linalg.norm(grown["center"][-1] - tip) < 0.02 * D  # chord vs arc between samples
        assert n >= 2


def test_actuation_after_growth_starts_straight_and_ends_designed():
    r = routing()
    straight = view.run_shape(r, D, lam=1.0 - 0.0 * (1.0 - r.lam))
    c = straight["center"] - straight["center"][0]
    # t = 0: lambda_t = 1, the unactuated tube is straight and as long as its material
    direction = c[-1] / np.linalg.norm(c[-1])
    assert np.linalg.norm(c - np.outer(c @ direction, direction), axis=1).max() < 1e-9
    assert np.linalg.norm(c[-1]) == pytest.approx(r.length.sum())
    full = view.run_shape(r, D, lam=1.0 - 1.0 * (1.0 - r.lam))
    np.testing.assert_allclose(full["center"], view.run_shape(r, D)["center"])


def test_hover_shows_s_theta_lambda_error():
    a = design_archive()
    fig = view.view_figure(a, run="greedy")
    assert [t.name for t in fig.data[:4]] == ["greedy: tube (true D)", "greedy: actuator line", "greedy: opposite line (twist)", "greedy: center line"]
    center = fig.data[3]
    for word in ("s = ", "theta = ", "lambda = ", "error = "):
        assert word in center.hovertemplate
    cd = np.asarray(center.customdata, float)
    r = a.runs["greedy"].routing
    assert cd[0, 0] == 0 and cd[-1, 0] == pytest.approx(r.length.sum(), rel=1e-6)
    assert set(np.round(cd[:, 2], 5)) <= set(np.round(r.lam, 5))
    # the error is the distance to the nearest target point (the nlp shape): nonzero for greedy
    assert 0 < np.nanmax(cd[:, 3]) < 10 * D
    nlp_cd = np.asarray(view.view_figure(a, run="nlp").data[3].customdata, float)
    assert np.nanmax(nlp_cd[:, 3]) < 0.6 * D  # nlp's own shape: within a sample spacing of the target


def test_unknown_run_is_refused():
    with pytest.raises(ValueError, match="no run 'zzz'"):
        view.view_figure(design_archive(), run="zzz")


def test_view_html_for_notebooks():
    a = design_archive()
    div = view.view_html(a, full_html=False, include_plotlyjs="cdn")
    assert "<html" not in div and "Plotly.newPlot" in div
    assert external_scripts(div) == ["https://cdn.plot.ly/plotly-" + div.split("https://cdn.plot.ly/plotly-")[1].split('"')[0]]
    page = view.view_html(a)
    assert "<html>" in page[:100] and page.rstrip().endswith("</html>")
    assert external_scripts(page) == []  # plotly.js is in the page: it opens with no network
    assert len(page) > 3_000_000


def test_trefoil_view_size(trefoil, tmp_path):
    out = tmp_path / "view.html"
    assert main(["view", str(trefoil), "-o", str(out)]) == 0
    size = out.stat().st_size
    assert size <= 6_000_000, f"{size / 1e6:.2f} MB"


# ------------------------------------------------------------------ sweep directories


def sweep_dir(root: Path, items=("wave-0", "wave-1", "wave-2"), run="nlp", name=None) -> Path:
    """A sweep directory: summary.csv and one archive per item (run ``run``, archive name ``name``)."""
    d = root / "sweep"
    d.mkdir()
    rows = []
    for i, item in enumerate(items):
        r = run_forward(ForwardProblem("wave", D, routing(phase=0.8 * i)))
        write_archive(d / f"{item}.h5" if "/" not in item else root / "outside.h5",
                      Archive(name or item, "design", "", D, target=r.shape.center, runs={run: r}))
        rows.append({"item": item, "method": "nlp", "status": "optimal", "rmse": 0.01 * (i + 1), "max_error": 0.02,
                     "solve_time_s": 0.5, "iterations": 3, "units": "cm", "error": ""})
    out = io.StringIO()
    w = csv.DictWriter(out, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    (d / "summary.csv").write_text(out.getvalue())
    return d


def test_sweep_view_has_every_item(tmp_path):
    d = sweep_dir(tmp_path)
    fig, shapes = view.sweep_figure(d)
    assert sorted(shapes) == ["wave-0", "wave-1", "wave-2"]
    scatter = [t for t in fig.data if t.type == "scatter"]
    assert [c[0] for c in scatter[0].customdata] == ["wave-0", "wave-1", "wave-2"]
    a = load_archive(d / "wave-2.h5")
    np.testing.assert_allclose(shapes["wave-2"]["runs"]["nlp"]["center"][-1], view.run_shape(a.runs["nlp"].routing, D)["center"][-1], atol=1e-4)
    out = tmp_path / "sweep.html"
    assert main(["view", str(d), "-o", str(out)]) == 0
    assert "vineShowItem" in out.read_text()


@pytest.mark.parametrize("item", ["../outside", "</script><svg onload=alert(1)>", "a%db", "x\u2028y"])
def test_sweep_view_refuses_what_is_no_item_name(tmp_path, capsys, item):
    d = sweep_dir(tmp_path, items=("wave-0", item))
    assert main(["view", str(d), "-o", str(tmp_path / "v.html")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {d / 'summary.csv'}: item: ") and err.count("\n") == 1 and "is not an item name" in err
    assert not (tmp_path / "v.html").exists()


HOSTILE_TEXT = st.one_of(st.text(st.characters(blacklist_categories=("Cs", "Cc", "Cf", "Zl", "Zp")), min_size=1, max_size=20),
                         st.sampled_from(["</script><script>window.pwned=1</script>", "<!--", "%d %s", "{plot_id}", "</SCRIPT >",
                                          "\\'\"];window.pwned=2;//", "<img src=x onerror=window.pwned=3>"])).filter(str.isprintable)


def _shapes_of(html: str) -> dict:
    return json.loads(re.search(r"var shapes = (.*?);\nvar nxy = ", html, re.S).group(1))


@settings(max_examples=12, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(run=HOSTILE_TEXT.filter(lambda t: "/" not in t and t not in (".", "..")), name=HOSTILE_TEXT)
@example(run="<!--<script>window.pwned=1;%d", name="<!--")  # no "/" in an HDF5 name: the double-escape trick instead
def test_fuzz_sweep_view_data_stays_data(tmp_path_factory, run, name):
    root = tmp_path_factory.mktemp("fuzzview")
    html = view.sweep_html(sweep_dir(root, items=("w-0",), run=run, name=name), include_plotlyjs=False)
    script = html[html.index("var shapes = "):]
    assert "<" not in script[:script.index(";\nvar nxy")]  # nothing in the data can close or comment out the script
    assert list(_shapes_of(html)["w-0"]["runs"]) == [run]  # and it reads back as given


# ------------------------------------------------------------------ command line: bad input


@pytest.mark.parametrize("args, prefix", [
    (["{a}", "-o", "{d}/v.htm5"], "error: {d}/v.htm5: -o: unknown view format '.htm5'"),
    (["{a}", "-o", "{d}/v.html", "--run", "zzz"], "error: {a}: --run: no run 'zzz' (runs: "),
    (["{bad}", "-o", "{d}/v.html"], "error: {bad}: "),
    (["{d}/missing.h5", "-o", "{d}/v.html"], "error: {d}/missing.h5: ARCHIVE: no such file"),
    (["{d}", "-o", "{d}/v.html"], "error: {d}: SWEEPDIR: no summary.csv"),
])
def test_view_bad_input(archive_file, tmp_path, capsys, args, prefix):
    bad = tmp_path / "not-an-archive.h5"
    bad.write_text("name = 'x'\n")
    fill = {"a": archive_file, "d": tmp_path, "bad": bad}
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["view", *(x.format(**fill) for x in args)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(prefix.format(**fill)) and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


# ------------------------------------------------------------------ in the browser


@pytest.fixture(scope="module")
def browser():
    if not (os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK)):
        pytest.skip(f"no Debian chromium and chromium-driver ({CHROMIUM}, {CHROMEDRIVER}): apt-get install chromium chromium-driver")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    profile = tempfile.TemporaryDirectory(prefix="vine-chromium-")
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={profile.name}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    records = []
    handler = logging.Handler()
    handler.emit = records.append
    logger = logging.getLogger("selenium.webdriver.common.driver_finder")
    logger.addHandler(handler)
    old_level = logger.level
    logger.setLevel(logging.DEBUG)
    try:
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
    # the driver path was given: Selenium Manager (which downloads browsers) did not run
    assert any("Skipping Selenium Manager" in r.getMessage() for r in records)
    driver.set_script_timeout(60)
    driver.set_page_load_timeout(120)
    yield driver
    driver.quit()
    profile.cleanup()


PLOT = "document.querySelector('.plotly-graph-div')"


def load(driver, path: Path):
    """Open ``path`` from disk; wait (bounded) until plotly has drawn it; return the browser log."""
    driver.get_log("browser")  # drop earlier pages' messages
    driver.get(Path(path).resolve().as_uri())
    drawn = driver.execute_async_script(f"""
        var done = arguments[arguments.length - 1], gd = {PLOT}, t0 = Date.now();
        (function poll() {{
            if (gd && gd._fullLayout && gd._fullData && gd.querySelector('.gl-container canvas')) {{ done(true); return; }}
            if (Date.now() - t0 > 50000) {{ done(false); return; }}
            setTimeout(poll, 50);
        }})();""")
    assert drawn, "plotly did not draw the page"
    return driver.get_log("browser")


def errors(log):
    return [m for m in log if m["level"] == "SEVERE"]


def screenshot(driver) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB"))


def trace_xyz(driver, index: int) -> np.ndarray:
    xyz = driver.execute_script(f"var t = {PLOT}._fullData[{index}]; return [Array.from(t.x), Array.from(t.y), Array.from(t.z)];")
    return np.array(xyz, float).T


def slide(driver, slider: int, step: int):
    """Move a slider as its own step does: Plotly.animate with the step's arguments."""
    ok = driver.execute_async_script(f"""
        var done = arguments[arguments.length - 1], gd = {PLOT};
        var st = gd.layout.sliders[{slider}].steps[{step}];
        Plotly.animate(gd, st.args[0], st.args[1]).then(function () {{ done(true); }}, function (e) {{ done(String(e)); }});""")
    assert ok is True, ok


@pytest.mark.slow
def test_view_draws_offline_and_sliders_move_the_shape(browser, archive_file, tmp_path):
    out = tmp_path / "view.html"
    assert main(["view", str(archive_file), "-o", str(out)]) == 0
    assert external_scripts(out.read_text()) == []  # nothing to fetch: plotly.js is in the page
    log = load(browser, out)
    assert errors(log) == []
    assert browser.execute_script(f"return {PLOT}.querySelectorAll('.gl-container canvas').length") >= 1
    before = screenshot(browser)
    # not blank: many colours, and the actuator line's blue among them
    assert len(np.unique(before.reshape(-1, 3), axis=0)) > 50
    blue = (before[..., 2].astype(int) - before[..., 0] > 40).sum()
    assert blue > 500
    a = load_archive(archive_file)
    r = a.runs["nlp"].routing
    final = trace_xyz(browser, 3)
    np.testing.assert_allclose(final, view.run_shape(r, D)["center"], atol=1e-4)
    # growth slider, step 5 of 20: the grown prefix, up to a quarter of the length
    slide(browser, 0, 5)
    grown = trace_xyz(browser, 3)
    want = view.run_shape(r, D, upto=0.25 * r.length.sum())["center"]
    assert len(grown) == len(want) < len(final)
    np.testing.assert_allclose(grown, want, atol=1e-4)
    assert not np.array_equal(screenshot(browser), before)
    # actuation slider at t = 0: the straight tube
    slide(browser, 1, 0)
    straight = trace_xyz(browser, 3)
    np.testing.assert_allclose(straight, view.run_shape(r, D, lam=np.ones_like(r.lam))["center"], atol=1e-4)
    slide(browser, 1, view.ACTUATION_STEPS)
    np.testing.assert_allclose(trace_xyz(browser, 3), final, atol=1e-4)
    assert errors(browser.get_log("browser")) == []


@pytest.mark.slow
def test_sweep_view_click_shows_the_item(browser, tmp_path):
    d = sweep_dir(tmp_path)
    out = tmp_path / "sweep.html"
    assert main(["view", str(d), "-o", str(out)]) == 0
    assert errors(load(browser, out)) == []
    n_xy = browser.execute_script(f"return {PLOT}._fullData.filter(function (t) {{ return t.type === 'scatter'; }}).length")
    first = trace_xyz(browser, n_xy)
    # a click on the point of wave-2 (plotly's own click event, as a mouse click emits it)
    browser.execute_script(f"var gd = {PLOT}; gd.emit('plotly_click', {{points: [{{customdata: ['wave-2', 'nlp']}}]}});")
    shown = trace_xyz(browser, n_xy)
    a = load_archive(d / "wave-2.h5")
    np.testing.assert_allclose(shown, view.run_shape(a.runs["nlp"].routing, D)["center"], atol=1e-4)
    assert not np.allclose(shown, first)
    assert browser.execute_script(f"return {PLOT}.vineItem") == "wave-2 nlp"
    assert errors(browser.get_log("browser")) == []


@pytest.mark.slow
@settings(max_examples=2, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(run=HOSTILE_TEXT.filter(lambda t: "/" not in t and t not in (".", "..")), name=HOSTILE_TEXT)
@example(run="<!--<script>window.pwned=1;%d", name="<img src=x onerror=window.pwned=3>")
def test_no_script_from_the_data_runs_in_the_browser(browser, tmp_path_factory, run, name):
    root = tmp_path_factory.mktemp("hostileview")
    d = sweep_dir(root, items=("w-0", "w-1"), run=run, name=name)
    out = root / "v.html"
    assert main(["view", str(d), "-o", str(out)]) == 0
    assert errors(load(browser, out)) == []
    assert browser.execute_script("return window.pwned === undefined && document.querySelectorAll('img[src=x], svg[onload]').length === 0")
    assert browser.execute_script("return window.vineShowItem('w-1', arguments[0])", run) is True  # the click handler works
    assert browser.execute_script(f"return {PLOT}.vineItem") == f"w-1 {run}"


def test_math_of_tube_rings():
    # a straight line along x: rings are circles of radius D/2 in the y-z plane
    center = np.column_stack([np.linspace(0, 5, 6), np.zeros(6), np.zeros(6)])
    inner = center + [0, D / 2, 0]
    rings = view.tube_rings(center, inner, D, ring=8)
    assert rings.shape == (6, 9, 3)
    np.testing.assert_allclose(rings[..., 0], center[:, None, 0] + 0 * rings[..., 0], atol=1e-12)
    np.testing.assert_allclose(np.hypot(rings[..., 1], rings[..., 2]), D / 2)
    np.testing.assert_allclose(rings[:, 0], rings[:, -1], atol=1e-12)  # closed
    assert math.isclose(rings[0, 2, 1], D / 2 * math.cos(2 * math.pi * 2 / 8), abs_tol=1e-12)


@pytest.mark.slow
def test_view_of_several_actuators_switches_state_in_the_menu(browser, tmp_path):
    """An archive of several actuators: the menu shows one state at a time, its center line the model's."""
    lam_a, lam_b = [0.6] * 6 + [1.0] * 6, [1.0] * 6 + [0.7] * 6
    (tmp_path / "p.toml").write_text(f'name = "two"\n[tube]\ndiameter = {D}\n[routing]\nlength = 24.0\nsegment_length = 2.0\n'
                                     f'[[actuators]]\nname = "A"\ntheta_deg = 5.0\nlambda = {lam_a}\n'
                                     f'[[actuators]]\nname = "B"\ntheta_deg = -3.0\nlambda = {lam_b}\nphi0_deg = 180\n'
                                     '[[states]]\nname = "a"\nactive = ["A"]\n[[states]]\nname = "ab"\nactive = ["A", "B"]\n')
    assert main(["forward", str(tmp_path / "p.toml"), "-o", str(tmp_path / "f.h5")]) == 0
    out = tmp_path / "v.html"
    assert main(["view", str(tmp_path / "f.h5"), "-o", str(out)]) == 0
    assert external_scripts(out.read_text()) == []
    assert errors(load(browser, out)) == []
    fig = view.states_figure(tmp_path / "f.h5")
    centers = [k for k, t in enumerate(fig.data) if t.name.endswith("center line")]
    before = screenshot(browser)
    shown = browser.execute_script(f"return {PLOT}._fullData.map(t => t.visible)")
    assert [shown[k] for k in centers] == [True, False]
    ok = browser.execute_async_script(f"""
        var done = arguments[arguments.length - 1], gd = {PLOT}, b = gd.layout.updatemenus[0].buttons[1];
        Plotly.update(gd, b.args[0], b.args[1]).then(function () {{ done(true); }}, function (e) {{ done(String(e)); }});""")
    assert ok is True, ok
    shown = browser.execute_script(f"return {PLOT}._fullData.map(t => t.visible)")
    assert [shown[k] for k in centers] == [False, True]
    want = np.column_stack([fig.data[centers[1]].x, fig.data[centers[1]].y, fig.data[centers[1]].z])
    np.testing.assert_allclose(trace_xyz(browser, centers[1]), want, atol=1e-4)
    assert browser.execute_script(f"return {PLOT}._fullLayout.title.text").startswith("two: state ab (A, B)")
    assert not np.array_equal(screenshot(browser), before)
    assert errors(browser.get_log("browser")) == []
