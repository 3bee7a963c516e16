"""Movies of a design (``vine-nlp animate``), as the paper's knot figure: growth while
actuated beside actuation after growth, self-contacts marked.

* grow: the tube grown while actuated to everted length l, 0 to full. The body is
  the prefix of the final shape; a contact of the final shape between material
  points l_early < l_late is marked once l >= l_late
  (:func:`vine_nlp.analysis.collision.growth_contacts`);
* after: the fully grown tube actuated by t, 0 to 1 (lambda_t = 1 - t (1 - lambda));
  the contacts of each intermediate shape are found again
  (:func:`vine_nlp.analysis.collision.routing_clearance`) and marked.

Both panels share one cube of equal axes (every shape of either panel inside) and draw the
archive's obstacles in every frame.

matplotlib.animation writes the movie: GIF through pillow, MP4 through ffmpeg
(where it is installed; an error otherwise). No pyplot: the figure is a plain
``matplotlib.figure.Figure``, the backend is never changed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from importlib.metadata import version
from pathlib import Path

import numpy as np

from vine_nlp.analysis.collision import growth_contacts, routing_clearance
from vine_nlp.analysis.obstacles import ModelLine, after_growth_routing
from vine_nlp.front.plot import equal_view_3d, label_3d_axes
from vine_nlp.front.view import tube_rings
from vine_nlp.io.archive import Archive, OutputError, write_atomic
from vine_nlp.model import shape_lines
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.problem import Routing

MODES = ("grow", "after", "both")
MOVIE_FORMATS = (".gif", ".mp4")
TUBE_COLOR = "#5b8fc7"
ACTUATOR_COLOR = "#d62728"
CONTACT_COLOR = "#ff7f0e"
# matplotlib >= 3.10 cuts 3-D artists at the axes' box (earlier ones draw the part beyond it over the margins)
CLIP = {"axlim_clip": True} if tuple(int(v) for v in version("matplotlib").split(".")[:2]) >= (3, 10) else {}


def movie_format(path) -> str:
    """The movie format of ``path`` by its extension (ValueError for an unknown one)."""
    ext = Path(path).suffix.lower()
    if ext not in MOVIE_FORMATS:
        raise ValueError(f"unknown movie format {ext or '(none)'!r}: use {', '.join(MOVIE_FORMATS)}")
    return ext


def ffmpeg_available() -> bool:
    from matplotlib import rcParams

    return shutil.which(rcParams["animation.ffmpeg_path"]) is not None


def _lines(routing: Routing, D: float, lam=None, upto=None):
    """Center and actuator lines (points at most D/4 apart), grown to material length ``upto``."""
    lam = routing.lam if lam is None else lam
    per = np.maximum(1, np.ceil(routing.length / (D / 4))).astype(int)
    seg, frac = segment_end_samples(routing.length, per)
    S = np.concatenate([[0.0], np.cumsum(routing.length)])
    if upto is not None and upto < S[-1]:
        l = S[seg] + frac * routing.length[seg]
        j = int(min(np.searchsorted(S, upto, side="right") - 1, routing.segments - 1))
        keep = l < upto
        seg = np.append(seg[keep], j)
        frac = np.append(frac[keep], (upto - S[j]) / routing.length[j])
    center, inner, _ = shape_lines(routing.theta, lam, routing.length, D, seg, frac, routing.initial_pose)
    return center, inner


def frame_contacts(routing: Routing, D: float, mode: str, value: float, growth=None) -> np.ndarray:
    """Contact points to mark: (K, 3), both sides of every contact region.

    mode "grow": ``value`` is the everted length, ``growth`` the list of
    :func:`growth_contacts`; mode "after": ``value`` is t.
    """
    if mode == "grow":
        ls = [(c["l_early"], c["l_late"]) for c in (growth or []) if not c["transient"] and c["growth_length"] <= value + 1e-12]
        if not ls:
            return np.zeros((0, 3))
        return ModelLine(routing, D).points(np.ravel(ls))
    res = routing_clearance(after_growth_routing(routing, value), D, refine=False, closest=False)
    if not res["regions"]:
        return np.zeros((0, 3))
    return np.array([p for r in res["regions"] for p in (r["point_i"], r["point_j"])])


def _draw(ax, center, inner, contacts, D, title):
    """One frame's tube, actuator line and contacts (the artists of the frame before are removed first)."""
    for artist in getattr(ax, "_vine_frame", []):
        artist.remove()
    frame = []
    if len(center) >= 2:
        rings = tube_rings(center, inner, D, ring=12)
        frame.append(ax.plot_surface(rings[..., 0], rings[..., 1], rings[..., 2], color=TUBE_COLOR, alpha=0.35, linewidth=0,
                                     shade=True, antialiased=False, **CLIP))
        frame += ax.plot(*inner.T, color=ACTUATOR_COLOR, lw=1.5, **CLIP)
    if len(contacts):
        frame.append(ax.scatter(*np.asarray(contacts).T, color=CONTACT_COLOR, s=40, marker="X", depthshade=False, label="self-contact"))
        frame.append(ax.legend(loc="upper right", fontsize=7))
    ax._vine_frame = frame
    ax.set_title(title, fontsize=9)


def _panel(ax, final, obstacles, D, units):
    """The fixed part of a panel: equal axes on one cube around the final shape and the obstacles, the obstacles,
    ticks and units: every panel gets the same ranges (the straight tube early in actuation after growth may reach
    beyond them: it is cut at the box)."""
    equal_view_3d(ax, [final], obstacles, pad=0.6 * D, zoom=0.9)
    label_3d_axes(ax, units)
    ax.tick_params(labelsize=7)


def movie_figure(archive: Archive, run: str, panels: int = 2, dpi: int = 80):
    """(Figure, 3-D axes) of a movie before its first frame: one cube of equal axes around the final shape for
    every panel (growing stays inside it), the obstacles drawn in each."""
    from matplotlib.figure import Figure

    D, u = archive.diameter, archive.units
    final = _lines(archive.runs[run].routing, D)[0]
    fig = Figure(figsize=(4.2 * panels, 4.4), dpi=dpi)
    fig.subplots_adjust(left=0.02, right=0.96, bottom=0.03, top=0.88, wspace=0.12)
    axes = [fig.add_subplot(1, panels, i + 1, projection="3d") for i in range(panels)]
    for ax in axes:
        _panel(ax, final, archive.obstacles, D, u)
    fig.suptitle(f"{archive.name}, run {run}: D = {D:.4g} {u}", fontsize=10)
    return fig, axes


def write_movie(archive: Archive, path, mode: str = "both", run: str | None = None, frames: int = 40, fps: int = 10,
                dpi: int = 80) -> dict:
    """Write the movie of ``run`` (default: the archive's default run) to ``path``, .gif (pillow) or .mp4 (ffmpeg):
    ``mode`` "grow" (growth while actuated), "after" (actuation after growth) or "both" side by side, ``frames``
    (>= 2) moving both panels together.

    Returns dict(run, mode, frames, contacts_grow (contacts of the final shape, marked while growing),
    contacts_after (largest number of contact regions in one frame after growth), format). ValueError for an
    unknown extension or mode, no such run, no runs, fewer than 2 frames; RuntimeError for an MP4 without
    ffmpeg installed (nothing is written).
    """
    from matplotlib import animation

    ext = movie_format(path)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
    if frames < 2:
        raise ValueError("a movie needs 2 frames or more")
    run = archive.pick_run(run)
    if ext == ".mp4" and not ffmpeg_available():
        raise RuntimeError("MP4 needs ffmpeg, which is not installed (apt-get install ffmpeg), or write a .gif")
    routing = archive.runs[run].routing
    D, u = archive.diameter, archive.units
    total = float(np.sum(routing.length))
    panels = ["grow", "after"] if mode == "both" else [mode]
    growth = growth_contacts(routing, D, actuation_steps=0) if "grow" in panels else []
    fig, axes = movie_figure(archive, run, len(panels), dpi)
    writer = animation.PillowWriter(fps=fps) if ext == ".gif" else animation.FFMpegWriter(fps=fps, codec="libx264",
                                                                                          extra_args=["-pix_fmt", "yuv420p"])
    after_max = 0

    def record(tmp):
        nonlocal after_max
        with writer.saving(fig, str(tmp), dpi):
            for k in range(frames):
                x = k / (frames - 1)
                for ax, panel in zip(axes, panels):
                    if panel == "grow":
                        lg = x * total
                        center, inner = _lines(routing, D, upto=lg)
                        contacts = frame_contacts(routing, D, "grow", lg, growth)
                        title = f"grown while actuated: {lg:.3g} of {total:.3g} {u}"
                    else:
                        center, inner = _lines(routing, D, lam=1.0 - x * (1.0 - routing.lam))
                        contacts = frame_contacts(routing, D, "after", x)
                        after_max = max(after_max, len(contacts) // 2)
                        title = f"actuated after growth: t = {x:.2f}"
                    _draw(ax, center, inner, contacts, D, title)
                writer.grab_frame()

    # the writer needs a real file name with the right extension: a temporary one beside the target
    target = Path(path)
    tmp_name = target.with_name(f".{target.name}.vine-nlp-{os.getpid()}-partial.tmp{ext}")  # swept if killed (io/outputs.py)
    def write(t):
        try:
            record(tmp_name)
        except subprocess.CalledProcessError as e:  # ffmpeg: a full disk ends its pipe, or it fails writing
            last = (e.stderr or b"").decode(errors="replace").strip().splitlines()[-1:] or [f"exit status {e.returncode}"]
            raise OutputError(target, "write", f"cannot write (ffmpeg: {last[0][:200]}); nothing was written") from None
        Path(t).write_bytes(tmp_name.read_bytes())

    try:
        write_atomic(target, write)
    finally:
        tmp_name.unlink(missing_ok=True)
    return {"run": run, "mode": mode, "frames": frames, "format": ext[1:],
            "contacts_grow": sum(1 for c in growth if not c["transient"]), "contacts_after": after_max}
