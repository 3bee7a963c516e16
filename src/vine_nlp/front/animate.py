"""Movies of a design (``vine-nlp animate``), as the paper's knot figure: growth while
actuated beside actuation after growth, self-contacts marked.

* grow: the tube grown while actuated to everted length l, 0 to full. The body is
  the prefix of the final shape; a contact of the final shape between material
  points l_early < l_late is marked once l >= l_late
  (:func:`vine_nlp.analysis.collision.growth_contacts`);
* after: the fully grown tube actuated by t, 0 to 1 (lambda_t = 1 - t (1 - lambda));
  the contacts of each intermediate shape are found again, as ``analyze`` finds them
  (:func:`vine_nlp.analysis.collision.routing_clearance`), and marked.

Each panel's equal axes hold its whole motion (every frame's tube: the straight tube of actuation after
growth too), so the robot is never cut; the obstacles are drawn in every frame. 1280 pixels wide; the
colours and legend words of ``plot`` and ``view`` (front/palette.py): tube, actuator line, opposite line
(across the tube from the actuator: the twist), self-contacts, obstacles. The default 41 frames put a
frame at every t where ``analyze`` looks for contacts after growth (0.05 apart), found by the same call.

An archive of several actuators on one tube (:func:`write_states_movie`): one panel going from state to state in
the archive's order, each actuator's line in its palette colour; between two states the lines pulled only in the
first are released (lambda_t = 1 - t (1 - lambda)), then the lines pulled only in the second are pulled, those
pulled in both stay: every frame is a shape of the model (never two active lines on one segment).

matplotlib.animation writes the movie: GIF through pillow, MP4 through ffmpeg
(where it is installed; an error otherwise). No pyplot: the figure is a plain
``matplotlib.figure.Figure``, the backend is never changed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from vine_nlp.analysis.collision import growth_contacts, routing_clearance
from vine_nlp.analysis.obstacles import ModelLine, after_growth_routing
from vine_nlp.front import palette
from vine_nlp.front.files import output_format
from vine_nlp.front.plot import equal_view_3d, label_3d_axes
from vine_nlp.front.states import picked_states, state_lines
from vine_nlp.front.view import run_shape, tube_rings
from vine_nlp.io.archive import Archive, OutputError, write_atomic
from vine_nlp.model.actuators import Lines
from vine_nlp.problem import Routing

MODES = ("grow", "after", "both")
MOVIE_FORMATS = (".gif", ".mp4")
movie_format = partial(output_format, formats=MOVIE_FORMATS, what="movie")  # an output's format by its extension (ValueError)
FRAMES = 41  # t = 0, 0.025, ..., 1: every step of analyze's actuation after growth (0.05) is a frame
WIDTH_PX, HEIGHT_PX, DPI = 1280, 680, 100  # legible at its own size: 10-15 pt text at 100 dpi


def ffmpeg_available() -> bool:
    from matplotlib import rcParams

    return shutil.which(rcParams["animation.ffmpeg_path"]) is not None


def frame_contacts(routing: Routing, D: float, mode: str, value: float, growth=None) -> np.ndarray:
    """Contact points to mark: (K, 3), both sides of every contact region.

    mode "grow": ``value`` is the everted length, ``growth`` the list of
    :func:`growth_contacts`; mode "after": ``value`` is t, the contacts found by the same call as ``analyze``'s
    (``growth_contacts`` at each of its steps): a frame at one of its t marks what ``analyze`` names there.
    """
    if mode == "grow":
        ls = [(c["l_early"], c["l_late"]) for c in (growth or []) if not c["transient"] and c["growth_length"] <= value + 1e-12]
        if not ls:
            return np.zeros((0, 3))
        return ModelLine(routing, D).points(np.ravel(ls))
    res = routing_clearance(routing if value == 1.0 else after_growth_routing(routing, value), D, closest=False)
    if not res["regions"]:
        return np.zeros((0, 3))
    return np.array([p for r in res["regions"] for p in (r["point_i"], r["point_j"])])


def panel_frames(routing: Routing, D: float, panel: str, frames: int, units: str, growth=None) -> list[dict]:
    """Every frame of one panel ("grow" or "after"): center, inner (actuator) and outer (opposite) lines, the
    contacts to mark and the title."""
    total = float(np.sum(routing.length))
    out = []
    for k in range(frames):
        x = k / (frames - 1)
        if panel == "grow":
            sh = run_shape(routing, D, upto=x * total)
            contacts = frame_contacts(routing, D, "grow", x * total, growth)
            title = f"grown while actuated: {x * total:.3g} of {total:.3g} {units}"
        else:
            sh = run_shape(routing, D, lam=1.0 - x * (1.0 - routing.lam))
            contacts = frame_contacts(routing, D, "after", x)
            title = f"actuated after growth: t = {x:.3g}"
        out.append({"center": sh["center"], "inner": sh["inner"], "outer": sh["outer"], "contacts": contacts, "title": title, "x": x})
    return out


def _draw(ax, frame, D):
    """One frame's tube, actuator and opposite lines and contacts (the artists of the frame before are removed first)."""
    for artist in getattr(ax, "_vine_frame", []):
        artist.remove()
    drawn = []
    center, inner = frame["center"], frame["inner"]
    if len(center) >= 2:
        drawn.append(_surface(ax, tube_rings(center, inner, D, ring=12)))
        for pts, color, lw in frame.get("lines") or [(inner, palette.ACTUATOR, 2.0), (frame["outer"], palette.OPPOSITE, 1.0)]:
            drawn += ax.plot(*pts.T, color=color, lw=lw, zorder=5 if lw > 1 else 4)
    if len(frame["contacts"]):
        drawn.append(ax.scatter(*np.asarray(frame["contacts"]).T, color=palette.CONTACT, s=110, marker="X", depthshade=False,
                               edgecolors="white", linewidths=0.8, zorder=10))
    ax._vine_frame = drawn
    ax.set_title(frame["title"], fontsize=13)


def _surface(ax, rings):
    """The tube's surface, as ``ax.plot_surface(*rings.T, color=TUBE, alpha=0.3, linewidth=0, shade=True,
    antialiased=False)`` draws it (its 50 rows of patches: the same polygons in the same order), with the patches cut
    at once instead of one by one (plot_surface's slow path when the rows do not divide evenly: most of a frame)."""
    from matplotlib.cbook import _array_patch_perimeters
    from matplotlib.colors import to_rgba
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection, _shade_colors

    rows = rings.shape[0]
    step = max(int(np.ceil(rows / 50)), 1)
    cut = (rows - 2) // step * step  # the whole steps; the last block the rest (as plot_surface's row_inds)
    blocks = [(rings[: cut + 1], step), (rings[cut:], rows - 1 - cut)] if cut else [(rings, rows - 1)]
    parts = [np.stack([_array_patch_perimeters(part[..., i], r, 1) for i in range(3)], axis=-1) for part, r in blocks]
    # plot_surface's shading (Poly3DCollection(shade=True)): each patch's normal from its vertices 0, n/3 and 2n/3
    normals = np.concatenate([np.cross(p[:, 0] - p[:, p.shape[1] // 3], p[:, p.shape[1] // 3] - p[:, 2 * p.shape[1] // 3]) for p in parts])
    surface = Poly3DCollection([p for part in parts for p in part], facecolors=_shade_colors(np.array(to_rgba(palette.TUBE)), normals),
                               alpha=0.3, linewidth=0, antialiased=False)
    ax.add_collection(surface, autolim="_datalim_only")
    return surface


def _legend(fig, obstacles: bool, contacts: bool, lines=None):
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    L = palette.LABELS
    lines = lines or [(L["actuator"], palette.ACTUATOR, 2.0), (L["opposite"], palette.OPPOSITE, 1.0)]
    handles = [Patch(color=palette.TUBE, alpha=0.6, label=L["tube"]), *(Line2D([], [], color=c, lw=w, label=t) for t, c, w in lines)]
    handles += [] if lines[0][0] != L["actuator"] else [Line2D([], [], color=palette.CONTACT, marker="X", ls="none", markersize=9,
                                                               label=L["contact"] + ("" if contacts else " (none in this movie)"))]
    if obstacles:
        handles.append(Patch(color=palette.OBSTACLE, alpha=0.5, label=L["obstacle"]))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=12, frameon=False)


def movie_figure(archive: Archive, run: str, panels: list, dpi: int = DPI, lines=None):
    """(Figure, 3-D axes) of a movie before its first frame: ``panels`` the frames of each panel
    (:func:`panel_frames`); each panel's equal axes hold every frame of its whole motion (the tube at its true
    diameter), and the obstacles, drawn in each; WIDTH_PX wide."""
    from matplotlib.figure import Figure

    D, u = archive.diameter, archive.units
    fig = Figure(figsize=(WIDTH_PX / dpi, (HEIGHT_PX if len(panels) > 1 else WIDTH_PX * 0.6) / dpi), dpi=dpi)
    fig.subplots_adjust(left=0.01, right=0.97, bottom=0.1, top=0.88, wspace=0.08)
    axes = [fig.add_subplot(1, len(panels), i + 1, projection="3d") for i in range(len(panels))]
    for ax, frames in zip(axes, panels):
        ax.computed_zorder = False  # drawn by zorder: the tube, then its lines, then the contacts on top (never hidden)
        motion = [f[key] for f in frames for key in ("center", "inner", "outer")]
        equal_view_3d(ax, motion, archive.obstacles, pad=0.5 * D, zoom=0.92)
        label_3d_axes(ax, u)
        ax.tick_params(labelsize=10)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.label.set_size(11)
    _legend(fig, bool(archive.obstacles), any(len(f["contacts"]) for frames in panels for f in frames), lines)
    fig.suptitle(f"{archive.name}, run {run}: D = {D:.4g} {u}", fontsize=15)
    return fig, axes


def write_movie(archive: Archive, path, mode: str = "both", run: str | None = None, frames: int = FRAMES, fps: int = 10,
                dpi: int = DPI) -> dict:
    """Write the movie of ``run`` (default: the archive's default run) to ``path``, .gif (pillow) or .mp4 (ffmpeg):
    ``mode`` "grow" (growth while actuated), "after" (actuation after growth) or "both" side by side, ``frames``
    (>= 2) moving both panels together (the default 41: every step of ``analyze``'s t is a frame).

    Returns dict(run, mode, frames, contacts_grow (contacts of the final shape, marked while growing),
    contacts_after (largest number of contact regions in one frame after growth), contacts_after_t (the t of the
    frames where they are marked), format). ValueError for an unknown extension or mode, no such run, no runs,
    fewer than 2 frames; RuntimeError for an MP4 without ffmpeg installed (nothing is written).
    """
    ext = movie_format(path)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
    if frames < 2:
        raise ValueError("a movie needs 2 frames or more")
    run = archive.pick_run(run)
    if ext == ".mp4" and not ffmpeg_available():
        raise RuntimeError("MP4 needs ffmpeg, which is not installed (apt-get install ffmpeg), or write a .gif")
    routing = archive.runs[run].routing
    D = archive.diameter
    names = ["grow", "after"] if mode == "both" else [mode]
    growth = growth_contacts(routing, D, actuation_steps=0) if "grow" in names else []
    panels = [panel_frames(routing, D, name, frames, archive.units, growth) for name in names]
    fig, axes = movie_figure(archive, run, panels, dpi)
    _record(fig, axes, panels, D, path, fps, dpi)
    after = panels[names.index("after")] if "after" in names else []
    return {"run": run, "mode": mode, "frames": frames, "format": ext[1:],
            "contacts_grow": sum(1 for c in growth if not c["transient"]),
            "contacts_after": max((len(f["contacts"]) // 2 for f in after), default=0),
            "contacts_after_t": [f["x"] for f in after if len(f["contacts"])]}


def _frames(fig, axes, panels, D: float):
    """Every frame's pixels (an RGBA array, reused): the figure without the frames' artists (axes, ticks, legend,
    obstacles: the same in every frame) is drawn once, and each frame draws only its own artists and titles on a
    copy of it (blitting: a frame costs its tube and lines, not the whole figure)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    for ax, frames in zip(axes, panels):  # the first frame laid out (the titles' places), its artists hidden
        _draw(ax, frames[0], D)
        for artist in [*ax._vine_frame, ax.title]:
            artist.set_alpha(0.0)
    canvas.draw()
    background, renderer = canvas.copy_from_bbox(fig.bbox), canvas.get_renderer()
    places = [ax.title.get_position() for ax in axes]  # where a draw puts them (a 3-D set_title moves its title)
    for ax in axes:
        ax.title.set_alpha(None)
    for k in range(len(panels[0])):
        canvas.restore_region(background)
        for ax, frames, place in zip(axes, panels, places):
            _draw(ax, frames[k], D)
            ax.title.set_position(place)
            for artist in sorted(ax._vine_frame, key=lambda a: a.get_zorder()):  # as the axes order them (computed_zorder off)
                if hasattr(artist, "do_3d_projection"):
                    artist.do_3d_projection()
                artist.draw(renderer)
            ax.title.draw(renderer)
        yield np.asarray(canvas.buffer_rgba())


def _gif_palette(first):
    """One 256-colour palette for every frame of a GIF: the first frame's colours and the palette's (front/palette.py:
    the tube, lines, contacts and obstacles, shaded and blended with the white background as they are drawn)."""
    from matplotlib.colors import to_rgb
    from PIL import Image

    named = np.array([to_rgb(getattr(palette, n)) for n in ("TUBE", "ACTUATOR", "OPPOSITE", "CONTACT", "OBSTACLE")]
                     + [to_rgb(c) for c in getattr(palette, "LINES", ())])
    mix = np.linspace(0.25, 1.0, 16)[:, None, None]  # alpha (or shade) from a quarter to whole, over white
    swatches = np.repeat(255 * (mix * named[None] + (1 - mix)), 8, axis=0).round().astype(np.uint8)  # (128, colours, 3)
    strip = Image.fromarray(np.repeat(swatches, 8, axis=1))
    both = Image.new("RGB", (max(first.width, strip.width), first.height + strip.height), "white")
    both.paste(first)
    both.paste(strip, (0, first.height))
    return both.quantize(method=Image.Quantize.FASTOCTREE)


def _record(fig, axes, panels, D: float, path, fps: int, dpi: int) -> None:
    """Draw every frame of ``panels`` (:func:`_frames`) into the movie at ``path``, atomically: a GIF through pillow (every
    frame in one palette, :func:`_gif_palette`, as it is drawn), an MP4 through matplotlib's ffmpeg pipe."""
    from matplotlib import animation
    from PIL import Image

    ext, target = movie_format(path), Path(path)
    fig.set_dpi(dpi)
    # the writer needs a real file name with the right extension: a temporary one beside the target
    tmp_name = target.with_name(f".{target.name}.vine-nlp-{os.getpid()}-partial.tmp{ext}")  # swept if killed (io/outputs.py)

    def record(tmp):
        if ext == ".gif":
            shots, colours = [], None
            for rgba in _frames(fig, axes, panels, D):
                rgb = Image.frombuffer("RGBA", (rgba.shape[1], rgba.shape[0]), rgba, "raw", "RGBA", 0, 1).convert("RGB")
                colours = _gif_palette(rgb) if colours is None else colours
                shots.append(rgb.quantize(palette=colours, dither=Image.Dither.NONE))
            shots[0].save(tmp, save_all=True, append_images=shots[1:], duration=int(1000 / fps), loop=0)
            return
        writer = animation.FFMpegWriter(fps=fps, codec="libx264", extra_args=["-pix_fmt", "yuv420p"])
        with writer.saving(fig, str(tmp), dpi):
            for rgba in _frames(fig, axes, panels, D):
                writer._proc.stdin.write(rgba.tobytes())  # the frame as grab_frame writes it (frame_format rgba), not drawn again

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


def state_frames(ls: Lines, D: float, states: dict, frames: int) -> list[dict]:
    """``frames`` frames from each state to the next (module docstring), as :func:`panel_frames` makes them, with
    every actuator's line ("lines": (points, colour, width), thick where pulled); "x": the frame's place in the
    movie, 0 to 1."""
    names, hops = list(states), max(1, len(states) - 1)
    out = []
    for k in range(frames):
        x = k / (frames - 1) * hops
        i = min(int(x), hops - 1) if len(names) > 1 else 0
        nxt = names[min(i + 1, len(names) - 1)]
        a, b = states[names[i]], states[nxt]
        off, on = [n for n in a if n not in b], [n for n in b if n not in a]
        split, u = (0.5 if on else 1.0) if off else 0.0, x - i  # release what only a pulls, then pull what only b pulls
        level = {n: 1.0 for n in set(a) & set(b)} | ({n: 1 - u / split for n in off} if u < split else {n: (u - split) / (1 - split) for n in on})
        active = [n for n in ls.names if level.get(n, 0.0) > 0] or [a[0]]
        lam = np.array([1.0 - level.get(n, 0.0) * (1.0 - ls.lam[j]) for j, n in enumerate(ls.names)])
        _, _, sh, paths = state_lines(replace(ls, lam=lam), D, active)
        lines = [(p, palette.LINES[j % len(palette.LINES)], 2.5 if level.get(n, 0.0) > 0 else 0.8) for j, (n, p) in enumerate(paths.items())]
        what = f"state {names[i]}" if u < 1e-9 else f"state {nxt}" if u > 1 - 1e-9 else f"{names[i]} \u2192 {nxt}"
        out.append({"center": sh.center, "inner": sh.inner, "outer": sh.outer, "lines": lines, "contacts": np.zeros((0, 3)),
                    "title": f"{what}: pulled " + (", ".join(f"{n} {level[n]:.0%}" for n in ls.names if level.get(n, 0) > 0) or "none"), "x": x / hops})
    return out


def write_states_movie(path, out, run: str | None = None, frames: int = FRAMES, fps: int = 10, dpi: int = DPI) -> dict:
    """The movie of an archive of several actuators on one tube, state to state (:func:`state_frames`), to ``out``
    (.gif or .mp4). Returns dict(run, states (in the movie's order), frames, format)."""
    a, run, r, _, states = picked_states(path, run)
    if movie_format(out) == ".mp4" and not ffmpeg_available():
        raise RuntimeError("MP4 needs ffmpeg, which is not installed (apt-get install ffmpeg), or write a .gif")
    panel = state_frames(r.lines, a.diameter, states, frames)
    fig, axes = movie_figure(a, run, [panel], dpi, [(f"line {n}", palette.LINES[j % len(palette.LINES)], 2.5) for j, n in enumerate(r.lines.names)])
    _record(fig, axes, [panel], a.diameter, out, fps, dpi)
    return {"run": run, "states": list(states), "frames": frames, "format": movie_format(out)[1:]}
