"""Interactive 3-D views (``vine-nlp view``): one self-contained HTML file made with plotly.

An archive's view shows every run (legend entries toggle a run's tube, actuator line, opposite line and
center line together; colours and words from front/palette.py), the target and any obstacles (``/obstacles/<k>``),
with two sliders:

* growth while actuated: everted length l from 0 to the full length. A robot grown
  while actuated lays every part down in its final shape, so the body is the prefix
  l' <= l of the final shape;
* actuation after growth: the fully grown tube actuated by t from 0 to 1,
  lambda_t = 1 - t (1 - lambda), theta and lengths as designed.

The sliders are two scenarios, not two axes: moving one draws its shape (the
other slider keeps showing its last position). Every frame moves the same tube
vertices (rings past the grown tip wait at the tip), so frames carry coordinates
only and the page of a 40-segment design stays under 6 MB.

Shapes come from the model (:func:`vine_nlp.model.shape_lines`). Hovering the
center line shows s (material coordinate: unactuated length from the base),
theta, lambda (lambda_t on the actuation slider) and the error (distance to the
nearest target point; archives with a target only).

A sweep directory's view shows summary.csv as a scatter (RMSE of every item and
method); clicking a point draws that item's tube center line and actuator line
in the 3-D panel beside it (the shapes are embedded in the page, no other file is
needed).

plotly is imported inside the functions that need it: the command line starts fast.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.front import palette
from vine_nlp.front.states import picked_states, state_lines, state_rates
from vine_nlp.front.sweep.summary import SUMMARY_CSV, read_summary
from vine_nlp.io import files, limits
from vine_nlp.io.archive import Archive, load_archive, write_atomic
from vine_nlp.model import shape_lines
from vine_nlp.model.actuators import owners
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.obstacles import Box, Mesh, Plane, Sphere
from vine_nlp.problem import Routing

GROWTH_STEPS = 20  # slider steps of growth (21 positions, 0 to full length)
ACTUATION_STEPS = 10  # slider steps of actuation after growth
RING = 8  # points around the tube (smooth-shaded; the page of a 40-segment design stays under 6 MB)
RUN_COLORS = palette.RUNS  # the center lines (hover); every other thing has its colour in front/palette.py
TRACES_PER_RUN = 4  # tube surface, actuator line, opposite line, center line (hover)


# ------------------------------------------------------------------ geometry


def _samples(routing: Routing, D: float, upto: float | None = None):
    """(segment, fraction, l) of points at most D/3 apart along the material, base to ``upto``
    (default: the tip); the last point is exactly at ``upto``."""
    per = np.maximum(1, np.ceil(routing.length / (D / 3.0))).astype(int)
    seg, frac = segment_end_samples(routing.length, per)
    S = np.concatenate([[0.0], np.cumsum(routing.length)])
    l = S[seg] + frac * routing.length[seg]
    if upto is None or upto >= S[-1]:
        return seg, frac, l
    keep = l < upto
    j = int(min(np.searchsorted(S, upto, side="right") - 1, routing.segments - 1))
    f = (upto - S[j]) / routing.length[j]
    seg = np.append(seg[keep], j)
    frac = np.append(frac[keep], f)
    l = np.append(l[keep], upto)
    if len(l) == 1:  # nothing grown yet: a zero-length tube at the base
        seg, frac, l = np.repeat(seg, 2), np.repeat(frac, 2), np.repeat(l, 2)
    return seg, frac, l


def tube_rings(center, inner, D: float, ring: int = RING) -> np.ndarray:
    """Points of the tube surface of diameter D: (P, ring + 1, 3), each ring closed.

    The ring at each point lies in the plane of the model's normal N (toward the
    actuator line, ``inner = center + (D/2) N``) and the binormal T x N.
    """
    center = np.asarray(center, float)
    N = (np.asarray(inner, float) - center) / (0.5 * D)
    if len(center) > 1 and np.ptp(center, axis=0).max() > 0:
        T = np.gradient(center, axis=0)
    else:
        T = np.tile([0.0, 0.0, 1.0], (len(center), 1))
    T = T - np.sum(T * N, axis=1, keepdims=True) * N
    norm = np.linalg.norm(T, axis=1, keepdims=True)
    T = np.where(norm > 1e-12, T / np.where(norm > 0, norm, 1), np.cross(N, [1.0, 0.0, 0.0]))
    B = np.cross(T, N)
    a = np.linspace(0.0, 2 * math.pi, ring + 1)
    return center[:, None, :] + 0.5 * D * (np.cos(a)[None, :, None] * N[:, None, :] + np.sin(a)[None, :, None] * B[:, None, :])


def run_shape(routing: Routing, D: float, lam=None, upto: float | None = None, target_tree=None) -> dict:
    """Center, actuator and opposite lines of ``routing`` (with ``lam`` instead of its lambda if given),
    grown to material length ``upto``; with per-point s, theta, lambda and error (nan without target)."""
    lam = routing.lam if lam is None else np.asarray(lam, float)
    seg, frac, l = _samples(routing, D, upto)
    center, inner, outer = shape_lines(routing.theta, lam, routing.length, D, seg, frac, routing.initial_pose)
    err = target_tree.query(center)[0] if target_tree is not None else np.full(len(l), np.nan)
    return {"center": center, "inner": inner, "outer": outer, "s": l, "theta": routing.theta[seg], "lam": lam[seg], "error": err}


def obstacle_surface(ob) -> np.ndarray:
    """A (rows, columns, 3) grid over the surface of a Sphere or Capsule (the figure's and the view's)."""
    w = np.linspace(0, 2 * np.pi, 25)
    if isinstance(ob, Sphere):
        W, P = np.meshgrid(w, np.linspace(0, np.pi, 13))
        return np.array(ob.center) + ob.radius * np.stack([np.cos(W) * np.sin(P), np.sin(W) * np.sin(P), np.cos(P)], -1)
    a, b, r = np.array(ob.p0), np.array(ob.p1), ob.radius
    axis, e1, e2 = ob.rounded_box()[1].T  # the capsule's frame: its axis first
    # one surface: hemisphere at p0, cylinder, hemisphere at p1 (polar angle 0..pi)
    pol = np.r_[np.linspace(0, 0.5 * np.pi, 7), np.linspace(0.5 * np.pi, np.pi, 7)]
    W, P = np.meshgrid(w, pol)
    base = np.where(np.arange(len(pol))[:, None] < 7, 0.0, 1.0)
    return (a + base[..., None] * (b - a) - r * np.cos(P)[..., None] * axis
            + r * np.sin(P)[..., None] * (np.cos(W)[..., None] * e1 + np.sin(W)[..., None] * e2))


def obstacle_mesh(ob, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (vertices, faces) drawing an obstacle (``vine_nlp.model.obstacles``); a plane as a square of side
    2 ``extent``."""
    if isinstance(ob, Mesh):
        return ob.vertices, ob.faces
    if isinstance(ob, Box):
        faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                 [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
        return ob.corners(), np.array(faces)
    if isinstance(ob, Plane):
        _, e1, e2 = ob.rounded_box()[1].T  # two directions in the plane
        V = np.array([np.array(ob.point) + extent * (a * e1 + b * e2) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        return V, np.array([[0, 1, 2], [0, 2, 3]])
    grid = obstacle_surface(ob)
    rows, cols = grid.shape[:2]
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    return grid.reshape(-1, 3), np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


# ------------------------------------------------------------------ archive view


def _f32(a):
    """Coordinates as float32: plotly embeds numpy arrays in binary (base64), half the size."""
    return np.asarray(a, dtype=np.float32)


def _xyz(p) -> dict:
    """The x, y, z arguments of a plotly 3-D trace through the points ``p`` (P, 3)."""
    return {"x": _f32(p[:, 0]), "y": _f32(p[:, 1]), "z": _f32(p[:, 2])}


def tube_vertices(shape: dict, D: float, count: int) -> np.ndarray:
    """Vertices of the drawn tube: ``count`` rings of RING points (the shape's rings, the last one
    repeated up to ``count``: every frame has the same vertices and faces, so frames carry
    coordinates only), then the base and tip centers (the caps)."""
    rings = tube_rings(shape["center"], shape["inner"], D)[:, :-1]
    if len(rings) < count:
        rings = np.concatenate([rings, np.repeat(rings[-1:], count - len(rings), axis=0)])
    return np.concatenate([rings.reshape(-1, 3), shape["center"][:1], shape["center"][-1:]])


def tube_faces(count: int, ring: int = RING) -> np.ndarray:
    """Triangles (i, j, k) over ``count`` rings of ``ring`` vertices, then the base and tip centers (:func:`tube_vertices`,
    ``front.export.tube_mesh``): the side between neighbouring rings and both caps."""
    i = np.arange(count - 1)[:, None] * ring
    k = np.arange(ring)[None, :]
    k1 = (k + 1) % ring
    side = np.concatenate([np.stack([i + k, i + ring + k, i + ring + k1], -1).reshape(-1, 3),
                           np.stack([i + k, i + ring + k1, i + k1], -1).reshape(-1, 3)])
    kk = np.arange(ring)
    base, tip = count * ring, count * ring + 1
    caps = np.concatenate([np.stack([np.full(ring, base), kk, (kk + 1) % ring], -1),
                           np.stack([np.full(ring, tip), (count - 1) * ring + (kk + 1) % ring, (count - 1) * ring + kk], -1)])
    return np.concatenate([side, caps]).astype(np.int32)


def _hover_data(shape):
    return _f32(np.column_stack([shape["s"], np.degrees(shape["theta"]), shape["lam"], shape["error"]]))


def _run_traces(go, name, shape, D, color, units, visible=True, lines=None):
    """Tube, lines on it (default: the actuator line and the opposite line; ``lines``: (label, points, colour, width)
    each), center line (hover) of one run or state."""
    if lines is None:
        lines = [(palette.LABELS["actuator"], shape["inner"], palette.ACTUATOR, 5), (palette.LABELS["opposite"], _thin(shape["outer"]), palette.OPPOSITE, 2)]
    count = len(shape["center"])
    V = tube_vertices(shape, D, count)
    F = tube_faces(count)
    group = name if name.startswith("state ") else f"run {name}"
    hover = (f"run {name}<br>s = %{{customdata[0]:.4g}} {units}<br>theta = %{{customdata[1]:.3g}} deg"
             f"<br>lambda = %{{customdata[2]:.3g}}<br>error = %{{customdata[3]:.3g}} {units}<extra></extra>")
    return [
        # a triangle mesh, not a Surface: plotly draws it faster, and fixed faces let frames send coordinates only
        go.Mesh3d(**_xyz(V), i=F[:, 0], j=F[:, 1], k=F[:, 2], name=f"{name}: {palette.LABELS['tube']}", legendgroup=group,
                  showlegend=True, color=palette.TUBE, opacity=0.4, hoverinfo="skip", visible=visible,
                  lighting={"ambient": 0.6, "diffuse": 0.6, "specular": 0.2}),
        *(go.Scatter3d(**_xyz(p), mode="lines", line={"color": c, "width": w}, name=f"{name}: {label}", legendgroup=group, showlegend=True,
                       hovertemplate=f"{label.split(' (')[0]}, {group}<extra></extra>", visible=visible) for label, p, c, w in lines),
        go.Scatter3d(**_xyz(shape["center"]), mode="lines", line={"color": color, "width": 2}, name=f"{name}: center line",
                     legendgroup=group, showlegend=True, customdata=_hover_data(shape), hovertemplate=hover, visible=visible),
    ]


def _thin(line):
    """Every other point of a thin line and its last (points 2D/3 apart: smooth at its width, half the bytes)."""
    return line[np.unique(np.r_[np.arange(0, len(line), 2), len(line) - 1])]


def _frame_data(go, shape, D, count):
    """The data of one run's four traces in a frame (same order as :func:`_run_traces`)."""
    V = tube_vertices(shape, D, count)
    return [go.Mesh3d(**_xyz(V)), go.Scatter3d(**_xyz(shape["inner"])), go.Scatter3d(**_xyz(_thin(shape["outer"]))),
            go.Scatter3d(**_xyz(shape["center"]), customdata=_hover_data(shape))]


def view_figure(archive: Archive, run: str | None = None):
    """The 3-D view of an archive as a plotly Figure (module docstring): only ``run`` if given, else every run,
    each toggled by its legend entry (the archive's default run first and shown, the others hidden until clicked).

    Traces: the runs (tube mesh, actuator line, opposite line, center line each), then the target and the obstacles. Frames
    ``grow-<k>`` and ``after-<k>`` drive the two sliders (growth first). ValueError (``Archive.pick_run``) for a
    run not in the archive or an archive without runs.
    """
    import plotly.graph_objects as go
    from scipy.spatial import cKDTree

    first = archive.pick_run(run)  # shown; without ``run`` the others start hidden (one legend click each)
    names = [first] + ([n for n in archive.runs if n != first] if run is None else [])
    D, u = archive.diameter, archive.units
    tree = cKDTree(np.asarray(archive.target, float)) if archive.target is not None and len(archive.target) else None
    fig = go.Figure()
    finals = {}
    for i, name in enumerate(names):
        r = archive.runs[name]
        finals[name] = run_shape(r.routing, D, target_tree=tree)
        color = RUN_COLORS[i % len(RUN_COLORS)]
        fig.add_traces(_run_traces(go, name, finals[name], D, color, u, visible=True if i == 0 else "legendonly"))
    pts = [f["center"] for f in finals.values()]
    if archive.target is not None:
        t = np.asarray(archive.target, float)
        pts.append(t)
        fig.add_trace(go.Scatter3d(**_xyz(t), mode="lines", line={"color": palette.TARGET, "width": 3, "dash": "dash"}, name=palette.LABELS["target"], showlegend=True,
                                   hovertemplate="target<extra></extra>"))
    allp = np.concatenate(pts)
    extent = float(np.ptp(allp, axis=0).max()) or 10 * D
    for k, o in enumerate(archive.obstacles):
        V, F = obstacle_mesh(o, 0.6 * extent)
        pts.append(V)
        fig.add_trace(go.Mesh3d(**_xyz(V), i=F[:, 0], j=F[:, 1], k=F[:, 2], color=palette.OBSTACLE, opacity=0.35, showlegend=True,
                                name=f"obstacle {k} {o.name} ({o.kind})" if o.name else f"obstacle {k} ({o.kind})",
                                hovertemplate=f"obstacle {k}: {o.kind}<extra></extra>"))
    run_traces = list(range(TRACES_PER_RUN * len(names)))
    total = max(float(np.sum(archive.runs[n].routing.length)) for n in names)
    frames, grow_steps, after_steps = [], [], []
    anim = {"mode": "immediate", "frame": {"duration": 0, "redraw": True}, "transition": {"duration": 0}}
    for k, lg in enumerate(np.linspace(0.0, total, GROWTH_STEPS + 1)):
        data = []
        for name in names:
            r = archive.runs[name].routing
            data += _frame_data(go, run_shape(r, D, upto=min(lg, float(np.sum(r.length))), target_tree=tree), D,
                                len(finals[name]["center"]))
        frames.append(go.Frame(name=f"grow-{k}", data=data, traces=run_traces))
        grow_steps.append({"label": f"{lg:.3g}", "method": "animate", "args": [[f"grow-{k}"], anim]})
    for k, t in enumerate(np.linspace(0.0, 1.0, ACTUATION_STEPS + 1)):
        data = []
        for name in names:
            r = archive.runs[name].routing
            shape = run_shape(r, D, lam=1.0 - t * (1.0 - r.lam), target_tree=tree) if t < 1 else finals[name]
            data += _frame_data(go, shape, D, len(finals[name]["center"]))
        frames.append(go.Frame(name=f"after-{k}", data=data, traces=run_traces))
        after_steps.append({"label": f"{t:.2g}", "method": "animate", "args": [[f"after-{k}"], anim]})
    fig.frames = frames
    title = f"{archive.name} ({archive.kind}), D = {D:.4g} {u}"
    fig.update_layout(
        title={"text": title, "x": 0.02},
        scene={"aspectmode": "data", "xaxis_title": f"x [{u}]", "yaxis_title": f"y [{u}]", "zaxis_title": f"z [{u}]",
               "camera": {"eye": camera_eye(np.concatenate(pts), D)}},
        legend={"title": {"text": "click to toggle"}, "itemclick": "toggle"},
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
        sliders=[
            {"active": len(grow_steps) - 1, "steps": grow_steps, "x": 0.02, "len": 0.46, "y": 0.0, "pad": {"t": 10},
             "currentvalue": {"prefix": f"grown while actuated: everted length [{u}] = "}, "name": "growth"},
            {"active": len(after_steps) - 1, "steps": after_steps, "x": 0.52, "len": 0.46, "y": 0.0, "pad": {"t": 10},
             "currentvalue": {"prefix": "actuated after growth: t = "}, "name": "actuation"},
        ],
        uirevision="keep",  # slider moves keep the camera
    )
    return fig


def camera_eye(points, D: float) -> dict:
    """plotly's default camera (1.25, 1.25, 1.25), moved back so a long shape fits: aspectmode "data" scales the
    axes to their ranges over the ranges' geometric mean, so the longest axis may reach beyond the default view."""
    r = np.maximum(np.ptp(np.asarray(points, float), axis=0), D)
    k = max(1.0, float(r.max() / np.exp(np.mean(np.log(r))))) ** 0.6  # (measured on the bundled problems: fits, not tiny)
    return {"x": 1.25 * k, "y": 1.25 * k, "z": 1.25 * k}


def states_figure(path, run: str | None = None):
    """The 3-D view of an archive of several actuators on one tube: one state at a time, chosen in the page's menu
    (its tube, center line (hover: s, theta and lambda of the line shaping the segment, error), every actuator's
    line in its palette colour (thick where pulled in that state) and the state's target)."""
    import plotly.graph_objects as go
    from scipy.spatial import cKDTree

    a, run, r, targets, states = picked_states(path, run)
    ls, D, u = r.lines, a.diameter, a.units
    fig, counts, pts = go.Figure(), [], []
    for i, (s, active) in enumerate(states.items()):
        seg, frac, shape, paths = state_lines(ls, D, active, s, spacing=D / 3)
        th, lam = state_rates(ls, owners(ls, active, s))
        err = cKDTree(targets[s]).query(shape.center)[0] if s in targets else np.full(len(seg), np.nan)
        d = {"center": shape.center, "inner": shape.inner, "s": np.r_[0.0, np.cumsum(ls.length)][seg] + frac * ls.length[seg],
             "theta": th[seg], "lam": lam[seg], "error": err}
        lines = [(f"line {n}" + " (pulled)" * (n in active), p, palette.LINES[k % len(palette.LINES)], 5 if n in active else 2)
                 for k, (n, p) in enumerate(paths.items())]
        traces = _run_traces(go, f"state {s}", d, D, palette.RUNS[1], u, visible=i == 0, lines=lines)  # gold: far from the lines
        traces += [go.Scatter3d(**_xyz(targets[s]), mode="lines", line={"color": palette.TARGET, "width": 3, "dash": "dash"}, visible=i == 0,
                                name=f"state {s}: {palette.LABELS['target']}", hovertemplate="target<extra></extra>")] if s in targets else []
        fig.add_traces(traces)
        counts.append(len(traces))
        pts += [shape.center] + ([targets[s]] if s in targets else [])
    first = np.r_[0, np.cumsum(counts)]
    titles = [f"{a.name}: state {s} ({', '.join(act)}), run {run}, D = {D:.4g} {u}" for s, act in states.items()]
    buttons = [{"label": f"{s} ({', '.join(act)})", "method": "update",
                "args": [{"visible": [bool(first[i] <= j < first[i + 1]) for j in range(first[-1])]}, {"title.text": titles[i]}]}
               for i, (s, act) in enumerate(states.items())]
    fig.update_layout(title={"text": titles[0], "x": 0.3}, margin={"l": 0, "r": 0, "t": 40, "b": 0}, uirevision="keep",
                      scene={"aspectmode": "data", "xaxis_title": f"x [{u}]", "yaxis_title": f"y [{u}]", "zaxis_title": f"z [{u}]",
                             "camera": {"eye": camera_eye(np.concatenate(pts), D)}},
                      updatemenus=[{"buttons": buttons, "direction": "down", "x": 0.0, "xanchor": "left", "y": 1.0, "yanchor": "top",
                                    "active": 0, "showactive": True, "name": "state"}])
    return fig


def view_html(archive, run: str | None = None, full_html: bool = True, include_plotlyjs=True) -> str:
    """The view of :func:`view_figure` (of :func:`states_figure` for the path of an archive of several actuators)
    as HTML: a whole page (``full_html``) or a ``<div>`` for notebooks; ``include_plotlyjs`` True embeds plotly.js
    (opens with no network), "cdn" links it (smaller)."""
    fig = view_figure(archive, run) if isinstance(archive, Archive) else states_figure(archive, run)
    return fig.to_html(full_html=full_html, include_plotlyjs=include_plotlyjs, auto_play=False,
                       config={"displaylogo": False, "responsive": True})


def write_html(path, html: str) -> None:
    """Write a page atomically (temporary file beside ``path``, then rename)."""
    write_atomic(path, lambda t: Path(t).write_text(html, encoding="utf-8"))


# ------------------------------------------------------------------ sweep view


def script_json(value) -> str:
    """JSON to paste into a <script> element: no text from the data can end the element ("</script>"),
    open a comment ("<!--") or be taken for plotly's "{plot_id}" placeholder."""
    text = json.dumps(value, ensure_ascii=True)  # U+2028 and U+2029 as escapes too
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026").replace("{plot_id}", "\\u007bplot_id}")


def is_sweep_dir(path) -> bool:
    return Path(path).is_dir() and (Path(path) / "summary.csv").is_file()


def sweep_figure(directory):
    """The view of a sweep directory: (figure, item shapes) with the shapes for the click handler; ValueError
    if the directory has no readable summary.csv or no item archive."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    d = Path(directory)
    files.open_input(d / SUMMARY_CSV, limit=SUMMARY_BYTES, limit_name="MAX_FILE_BYTES // 16").close()  # no pipe, no giant
    rows = read_summary(d / SUMMARY_CSV)
    shapes = {}
    units = ""
    for item in dict.fromkeys(r["item"] for r in rows):
        # an item is a plain file name in the sweep directory (sweep_file.py names them): no path from the data
        if not isinstance(item, str) or not ITEM_NAME.fullmatch(item):
            raise InputError(d / SUMMARY_CSV, "item", f"{str(item)[:80]!r} is not an item name (letters, digits, . _ + -)")
        path = d / f"{item}.h5"
        if not path.is_file() or path.resolve().parent != d.resolve():
            continue
        try:
            a = load_archive(path)
        except (OSError, ValueError, KeyError):
            continue
        units = a.units
        runs = {}
        for name, res in a.runs.items():
            s = run_shape(res.routing, a.diameter)
            runs[name] = {"center": np.round(s["center"], 5).tolist(), "inner": np.round(s["inner"], 5).tolist()}
        target = None if a.target is None else np.round(np.asarray(a.target, float), 5).tolist()
        shapes[item] = {"runs": runs, "target": target, "diameter": a.diameter}
    if not shapes:
        raise ValueError("no item archive (<item>.h5) next to summary.csv")
    fig = make_subplots(rows=1, cols=2, column_widths=[0.45, 0.55], specs=[[{"type": "xy"}, {"type": "scene"}]],
                        subplot_titles=("RMSE of every item (click one)", "shape of the item clicked"))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    items = list(dict.fromkeys(r["item"] for r in rows))
    for m_i, m in enumerate(methods):
        sel = [r for r in rows if r["method"] == m and r["rmse"] is not None]
        fig.add_trace(go.Scatter(
            x=[items.index(r["item"]) for r in sel], y=[r["rmse"] for r in sel], mode="markers", name=m,
            marker={"size": 9, "color": RUN_COLORS[m_i % len(RUN_COLORS)]},
            customdata=[[r["item"], m, r["status"], r["solve_time_s"]] for r in sel],
            hovertemplate="%{customdata[0]} (%{customdata[1]})<br>%{customdata[2]}<br>RMSE %{y:.4g}"
                          f" {units}<br>solve %{{customdata[3]:.3g}} s<extra></extra>"), row=1, col=1)
    first = next(iter(shapes))
    fr = shapes[first]
    first_run = next(iter(fr["runs"]))
    line = fr["runs"][first_run]
    for key, color, width in (("center", RUN_COLORS[0], 6), ("inner", palette.ACTUATOR, 3)):
        p = np.asarray(line[key])
        fig.add_trace(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", line={"color": color, "width": width},
                                   name=f"{'center line' if key == 'center' else 'actuator'} ({first} {first_run})",
                                   showlegend=True), row=1, col=2)
    t = np.asarray(fr["target"]) if fr["target"] is not None else np.zeros((0, 3))
    fig.add_trace(go.Scatter3d(x=t[:, 0], y=t[:, 1], z=t[:, 2], mode="lines", line={"color": palette.TARGET, "dash": "dash", "width": 2},
                               name=palette.LABELS["target"]), row=1, col=2)
    fig.update_xaxes(title_text="item", tickmode="array", tickvals=list(range(len(items))), ticktext=items, row=1, col=1)
    fig.update_yaxes(title_text=f"RMSE [{units}]", type="log", row=1, col=1)
    fig.update_layout(title={"text": f"sweep {d.name}: {len(items)} items, {len(rows)} runs", "x": 0.02},
                      scene={"aspectmode": "data"}, clickmode="event", margin={"l": 40, "r": 0, "t": 60, "b": 40},
                      legend={"orientation": "h", "y": -0.15})  # below: the 3-D panel keeps its width
    return fig, shapes


SUMMARY_BYTES = limits.MAX_FILE_BYTES // 16
ITEM_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
_SWEEP_JS = """
var gd = document.getElementById('{plot_id}');
function vineShowItem(item, run) {
  var it = shapes[item]; if (!it) { return false; }
  if (!(run in it.runs)) { run = Object.keys(it.runs)[0]; }
  var r = it.runs[run], t = it.target || [];
  function col(p, k) { return p.map(function (q) { return q[k]; }); }
  Plotly.restyle(gd, {x: [col(r.center, 0), col(r.inner, 0), col(t, 0)], y: [col(r.center, 1), col(r.inner, 1), col(t, 1)],
                      z: [col(r.center, 2), col(r.inner, 2), col(t, 2)],
                      name: ['center line (' + item + ' ' + run + ')', 'actuator (' + item + ' ' + run + ')', 'target']},
                 [nxy, nxy + 1, nxy + 2]);
  gd.vineItem = item + ' ' + run;
  return true;
}
window.vineShowItem = vineShowItem;
gd.on('plotly_click', function (ev) {
  var p = ev.points[0];
  if (p && p.customdata) { vineShowItem(p.customdata[0], p.customdata[1]); }
});
"""


def sweep_html(directory, include_plotlyjs=True) -> str:
    """The view of a sweep directory as one HTML page (:func:`sweep_figure`): clicking an item
    (or calling ``vineShowItem(item, run)`` in the page) draws its shape."""
    fig, shapes = sweep_figure(directory)
    n_xy = sum(1 for tr in fig.data if tr.type == "scatter")
    script = f"var shapes = {script_json(shapes)};\nvar nxy = {n_xy};" + _SWEEP_JS
    return fig.to_html(full_html=True, include_plotlyjs=include_plotlyjs, post_script=script,
                       config={"displaylogo": False, "responsive": True})
