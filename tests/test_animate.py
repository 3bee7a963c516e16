"""`vine-nlp animate`: growth while actuated beside actuation after growth, self-contacts marked."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vine_nlp.analysis.collision import growth_contacts
from vine_nlp.front import animate, palette
from vine_nlp.front.cli import main
from vine_nlp.io.archive import Archive, write_archive
from vine_nlp.methods.common import run_forward
from vine_nlp.problem import ForwardProblem, Routing

D = 2.0


def loop_routing(lam=0.6, turns=1.1, M=24):
    """Straight lead-in 3 D long, then a planar circle of radius R = D (1 + lam) / (2 (1 - lam)) that
    closes on the lead-in: one self-contact, met when grown to 3 D + R phi* / lambda_c."""
    R = D * (1 + lam) / (2 * (1 - lam))
    lc = (1 + lam) / 2
    length = np.concatenate([np.full(4, 3 * D / 4), np.full(M, turns * 2 * math.pi * R / lc / M)])
    return Routing(theta=np.zeros(4 + M), lam=np.concatenate([np.ones(4), np.full(M, lam)]), length=length), R, lc


@pytest.fixture(scope="module")
def loop_file(tmp_path_factory):
    r, _, _ = loop_routing()
    path = tmp_path_factory.mktemp("animate") / "loop.h5"
    write_archive(path, Archive("loop", "forward", "", D, runs={"forward": run_forward(ForwardProblem("loop", D, r))}))
    return path


def test_contacts_appear_when_the_loop_closes():
    r, R, lc = loop_routing()
    g = growth_contacts(r, D, actuation_steps=0)
    assert len(g) == 1
    first = g[0]["growth_length"]
    phi = 2 * math.pi - math.acos(1 - D / R)  # where the circle comes within D of the lead-in line
    assert first == pytest.approx(3 * D + R * phi / lc, abs=0.25 * D)
    assert len(animate.frame_contacts(r, D, "grow", 0.95 * first, g)) == 0
    pts = animate.frame_contacts(r, D, "grow", r.length.sum(), g)
    assert pts.shape == (2, 3)
    assert np.linalg.norm(pts[0] - pts[1]) < D  # both sides of the contact
    # actuated after growth: the straight tube (t = 0) touches nothing, the final shape does
    assert len(animate.frame_contacts(r, D, "after", 0.0)) == 0
    after = animate.frame_contacts(r, D, "after", 1.0)
    assert len(after) >= 2 and np.linalg.norm(after[0] - after[1]) < D


def orange(frame) -> int:
    """Pixels of the contact marker's colour (palette.CONTACT, magenta #e7298a, after GIF quantization), below
    the legend's row (which shows the marker in every frame)."""
    a = np.asarray(frame.convert("RGB")).astype(int)[: int(0.88 * frame.size[1])]
    return int(((a[..., 0] > 190) & (a[..., 1] < 100) & (abs(a[..., 2] - 138) < 50)).sum())


def test_gif_grows_and_marks_the_contact(loop_file, tmp_path, capsys):
    out = tmp_path / "loop.gif"
    assert main(["animate", str(loop_file), "-o", str(out), "--frames", "6", "--mode", "both"]) == 0
    assert "self-contacts: 1 of the final shape" in capsys.readouterr().out
    im = Image.open(out)
    assert im.format == "GIF" and im.n_frames == 6
    frames = []
    for k in range(im.n_frames):
        im.seek(k)
        frames.append(im.copy())
    assert orange(frames[0]) == 0  # nothing grown, straight: no contact
    assert orange(frames[-1]) > 20  # grown and actuated: the contact is marked
    assert not np.array_equal(np.asarray(frames[0].convert("RGB")), np.asarray(frames[-1].convert("RGB")))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop.gif"]  # no temporary file left


def brown(frame) -> int:
    """Pixels of the obstacles' colour (#8c6d46, shaded, after GIF quantization)."""
    a = np.asarray(frame.convert("RGB")).astype(int)
    return int(((a[..., 0] - a[..., 2] > 30) & (a[..., 0] - a[..., 1] > 10) & (a[..., 0] < 200)).sum())


def test_each_panel_holds_its_whole_motion_in_equal_axes_with_the_legend_and_the_obstacles(tmp_path):
    from vine_nlp.model.obstacles import Sphere

    r, R, _ = loop_routing()
    ball = Sphere((3 * D, 3 * R, 0.0), D)  # beside the loop, in its plane
    archive = Archive("loop", "forward", "", D, runs={"forward": run_forward(ForwardProblem("loop", D, r))}, obstacles=[ball])
    panels = [animate.panel_frames(r, D, name, 5, "cm", growth_contacts(r, D, actuation_steps=0)) for name in ("grow", "after")]
    fig, axes = animate.movie_figure(archive, "forward", panels)
    assert fig.get_size_inches()[0] * fig.dpi >= 1280  # legible at its own size
    for ax, frames in zip(axes, panels):
        lim = np.array([ax.get_xlim(), ax.get_ylim(), ax.get_zlim()])
        np.testing.assert_allclose(np.ptp(lim, axis=1), np.ptp(lim[0]), rtol=1e-12)  # equal axes
        np.testing.assert_allclose(ax.get_box_aspect(), ax.get_box_aspect()[0], rtol=1e-12)
        assert len(ax.collections) == 1  # the sphere, before any frame
        for f in frames:  # the whole tube (its surface D/2 around the center line) at every frame, never cut
            assert (f["center"].min(0) - D / 2 >= lim[:, 0]).all() and (f["center"].max(0) + D / 2 <= lim[:, 1]).all()
        assert (np.r_[3 * D, 3 * R, 0] + D <= lim[:, 1]).all()
    # after growth the straight tube at t = 0 (as long as the whole robot) is inside too
    assert np.ptp(panels[1][0]["center"][:, 0]) == pytest.approx(r.length.sum())
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["tube (true D)", "actuator line", "opposite line (twist)", "self-contact", "obstacle"]
    colours = [h.get_facecolor()[:3] if hasattr(h, "get_facecolor") and not hasattr(h, "get_xdata") else h.get_color()
               for h in fig.legends[0].legend_handles]
    from matplotlib.colors import to_rgb
    assert [to_rgb(c) for c in colours] == [to_rgb(c) for c in (palette.TUBE, palette.ACTUATOR, palette.OPPOSITE, palette.CONTACT, palette.OBSTACLE)]
    out = tmp_path / "ball.gif"
    write_archive(tmp_path / "ball.h5", archive)
    assert main(["animate", str(tmp_path / "ball.h5"), "-o", str(out), "--frames", "3"]) == 0
    im = Image.open(out)
    for k in range(im.n_frames):  # the obstacle in every frame, not only in the first
        im.seek(k)
        assert brown(im) > 200, k


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is not installed (apt-get install ffmpeg)")
def test_mp4_through_ffmpeg(loop_file, tmp_path):
    out = tmp_path / "loop.mp4"
    assert main(["animate", str(loop_file), "-o", str(out), "--frames", "4", "--mode", "grow"]) == 0
    assert out.read_bytes()[4:8] == b"ftyp"
    if shutil.which("ffprobe"):
        n = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                            "stream=nb_read_frames", "-of", "csv=p=0", str(out)], capture_output=True, text=True, check=True)
        assert int(n.stdout.strip()) == 4


def test_mp4_without_ffmpeg_is_refused(loop_file, tmp_path):
    # a PATH without ffmpeg on it: the command refuses before any work and writes nothing
    env = {**os.environ, "PATH": str(tmp_path / "empty-bin")}
    out = tmp_path / "loop.mp4"
    proc = subprocess.run([sys.executable, "-m", "vine_nlp", "animate", str(loop_file), "-o", str(out)],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"error: {out}: -o: MP4 needs ffmpeg, which is not installed") and proc.stderr.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, prefix", [
    (["{a}", "-o", "{d}/m.avi"], "error: {d}/m.avi: -o: unknown movie format '.avi': use .gif, .mp4"),
    (["{a}", "-o", "{d}/m.gif", "--run", "nlp"], "error: {a}: --run: no run 'nlp' (runs: forward)"),
    (["{a}", "-o", "{d}/m.gif", "--mode", "sideways"], "error: command line: vine-nlp animate: argument --mode: invalid choice"),
    (["{a}", "-o", "{d}/m.gif", "--frames", "1"], "error: command line: vine-nlp animate: argument --frames: must be an integer >= 2 and <= 150"),
    (["{bad}", "-o", "{d}/m.gif"], "error: {bad}: "),
])
def test_animate_bad_input(loop_file, tmp_path, capsys, args, prefix):
    bad = tmp_path / "bad.h5"
    bad.write_text("not hdf5")
    fill = {"a": loop_file, "d": tmp_path, "bad": bad}
    assert main(["animate", *(x.format(**fill) for x in args)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(prefix.format(**fill)) and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.h5"]


def test_movie_format():
    assert animate.movie_format(Path("a.GIF")) == ".gif"
    with pytest.raises(ValueError, match="unknown movie format '.webm'"):
        animate.movie_format("a.webm")


def test_after_growth_contacts_are_marked_on_the_frames_analyze_names():
    # analyze looks at t = 0.05, 0.10, ..., 1 (growth_contacts' 20 steps); the default 41 frames include each of them
    # and mark what the same call finds there: the first of them with a mark is analyze's "from t = ..."
    r, _, _ = loop_routing()
    first = growth_contacts(r, D)[0]["actuation_fraction"]
    frames = animate.panel_frames(r, D, "after", animate.FRAMES, "cm")
    marked = [f["x"] for f in frames if len(f["contacts"])]
    on_grid = [x for x in marked if abs(20 * x - round(20 * x)) < 1e-9]
    assert on_grid and on_grid[0] == pytest.approx(first) and 0 < first < 1
    assert all(x >= first - 0.05 + 1e-9 for x in marked)  # nothing marked a step of analyze's before it


@pytest.mark.parametrize("rows", [2, 13, 50, 51, 101, 237])
def test_the_tube_surface_is_plot_surfaces_polygons_and_shading(rows):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    s = np.linspace(0, 3, rows)
    center = np.column_stack([5 * np.cos(s), 5 * np.sin(s), s])
    rings = animate.tube_rings(center, center + [0, 0, D / 2], D, ring=12)
    figures = Figure(), Figure()
    axes = [f.add_subplot(projection="3d") for f in figures]
    ours = animate._surface(axes[0], rings)
    theirs = axes[1].plot_surface(*np.moveaxis(rings, -1, 0), color=palette.TUBE, alpha=0.3, linewidth=0, shade=True, antialiased=False)
    for f, ax in zip(figures, axes):  # the same view: each projected and depth-sorted as it is drawn
        ax.set(xlim=(-8, 8), ylim=(-8, 8), zlim=(-1, 5))
        FigureCanvasAgg(f).draw()
    assert len(ours.get_paths()) == len(theirs.get_paths()) >= 1
    for a, b in zip(ours.get_paths(), theirs.get_paths()):  # the same polygons, in order
        np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(ours.get_facecolor(), theirs.get_facecolor())  # the same shading


def test_blitted_frames_are_the_full_figure_drawn_again(tmp_path):
    """Each frame drawn on the figure's still part (animate._frames) is, pixel for pixel, the whole figure drawn for it."""
    import io

    from vine_nlp.model.obstacles import Sphere

    r, R, _ = loop_routing()
    archive = Archive("loop", "forward", "", D, runs={"forward": run_forward(ForwardProblem("loop", D, r))}, obstacles=[Sphere((3 * D, 3 * R, 0.0), D)])
    panels = [animate.panel_frames(r, D, name, 4, "cm", growth_contacts(r, D, actuation_steps=0)) for name in ("grow", "after")]
    fig, axes = animate.movie_figure(archive, "forward", panels)
    blitted = [f.copy() for f in animate._frames(fig, axes, panels, D)]
    fig, axes = animate.movie_figure(archive, "forward", panels)
    assert any(len(f["contacts"]) for f in panels[0])  # a contact marker is among what is compared
    for k in range(4):
        for ax, frames in zip(axes, panels):
            animate._draw(ax, frames[k], D)
        whole = io.BytesIO()
        fig.savefig(whole, format="rgba", dpi=fig.dpi)
        assert np.array_equal(np.frombuffer(whole.getvalue(), np.uint8).reshape(blitted[k].shape), blitted[k]), k
