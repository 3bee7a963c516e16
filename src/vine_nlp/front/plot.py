"""Figures of result archives (``vine-nlp plot``).

One figure per archive, laid out like the paper's Figs. 9 and 11:

(a) 3-D view, one panel per run: the target (dashed black, drawn over the tube), the tube
    drawn at its true diameter D (a translucent surface of circles around the center line,
    built from the archived inner/outer lines), the actuator line, the opposite line
    (thin: diametrically opposite the actuator, it shows the twist), the segment ends
    (dots) and, for design runs, the center line inside the tube colored by its distance
    to the paired target point; obstacles (colours: front/palette.py, each in the legend);
(b) design archives: error against length along the unactuated tube, one line per run;
(c)-(e) theta(s) [deg] and lambda(s) (per segment, steps) and phi(s) [deg]
    against length along the unactuated tube, every run overlaid, legend with
    each run's RMSE.

Sized for a two-column paper (7.16 in wide; a single run fits one 3.5 in column),
fonts 7-8 pt, equal axis scaling in 3-D, units on every axis."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from vine_nlp.front import palette
from vine_nlp.front.files import figure_format
from vine_nlp.front.show import ordered_runs, source_table
from vine_nlp.front.view import obstacle_surface, tube_rings
from vine_nlp.io.archive import Archive, load_archive, write_atomic
from vine_nlp.model import chain_frames, chain_points
from vine_nlp.model.obstacles import Box, Capsule, Mesh, Plane, Sphere
from vine_nlp.model.pairing import pair_points

ERROR_CMAP = palette.ERROR_CMAP
RUN_COLORS = palette.RUNS
RUN_STYLES = ("-", "--", ":", "-.")
STYLE = {"font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "xtick.labelsize": 7, "ytick.labelsize": 7,
         "legend.fontsize": 7, "figure.titlesize": 9, "axes.linewidth": 0.6, "lines.linewidth": 1.0,
         "xtick.major.width": 0.6, "ytick.major.width": 0.6}
COLUMN_IN, PAGE_IN = 3.5, 7.16  # IEEE column and text widths


# ------------------------------------------------------------------ helpers


def segment_edges(routing) -> np.ndarray:
    """s_j, j = 0..M: length along the unactuated tube at the segment ends."""
    return np.concatenate([[0.0], np.cumsum(routing.length)])


def is_paired(archive: Archive, result) -> bool:
    """Design runs: shape row i pairs with target row i."""
    return archive.target is not None and result.shape.center.shape == np.shape(archive.target)


def error_along(archive: Archive, result) -> np.ndarray:
    """Distance of each modeled center point to its paired target point."""
    return np.linalg.norm(result.shape.center - archive.target, axis=1)


def point_s(archive: Archive, result) -> np.ndarray:
    """Length along the unactuated tube of each archived shape point.

    Design runs pair target point k with fraction frac_k of segment seg_k (model.pairing.pair_points); the pairing is
    rebuilt from the archived ``points_per_segment`` (or the n consistent with M and N) and accepted only if the model
    reproduces the archived center line there. Otherwise s is estimated from the target's chord length (proportional to
    the tube length)."""
    r, center = result.routing, result.shape.center
    N, M = center.shape[0], r.segments
    S = segment_edges(r)
    candidates = []
    n0 = result.stats.get("points_per_segment")
    if isinstance(n0, (int, float)) and n0 >= 1:
        candidates.append(int(n0))
    candidates += [n for n in range(max(1, (N - 1) // max(M, 1) - 1), N) if math.ceil((N - 1) / n) == M and n not in candidates]
    frames = chain_frames(r.theta, r.lam, r.length, archive.diameter, r.initial_pose)
    tol = 1e-6 * max(1.0, float(np.abs(center).max()))
    for n in candidates[:8]:
        try:
            p = pair_points(archive.target, n)
        except ValueError:
            continue
        if p.segments != M:
            continue
        pts, _ = chain_points(r.theta, r.lam, r.length, archive.diameter, p.seg, p.frac, frames=frames)
        if np.abs(pts - center).max() <= tol:
            return S[p.seg] + p.frac * r.length[p.seg]
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(archive.target, axis=0), axis=1))])
    return chord / max(chord[-1], 1e-300) * S[-1]


def tube_surface(shape, diameter: float, around: int = 24, max_rows: int = 500):
    """(X, Y, Z) grids of the tube wall: circles of diameter D around the center line (inner + outer) / 2
    (``vine_nlp.front.view.tube_rings``), at most ``max_rows`` of them."""
    inner, outer = np.asarray(shape.inner, float), np.asarray(shape.outer, float)
    rows = np.arange(inner.shape[0])
    if rows.size > max_rows:
        rows = np.unique(np.linspace(0, rows.size - 1, max_rows).round().astype(int))
    wall = tube_rings(0.5 * (inner[rows] + outer[rows]), inner[rows], diameter, around)
    return wall[..., 0], wall[..., 1], wall[..., 2]


def label_3d_axes(ax, units: str):
    """Units on every axis, five ticks each, tight label padding (readable at column width)."""
    ax.set_xlabel(f"x [{units}]", labelpad=-2)
    ax.set_ylabel(f"y [{units}]", labelpad=-2)
    ax.set_zlabel(f"z [{units}]", labelpad=-3)
    ax.tick_params(axis="both", pad=-1)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(5))


def set_equal_3d(ax, points, zoom: float = 1.0):
    """Equal scaling on all three axes (a helix must look round)."""
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in points if np.size(p)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid, half = 0.5 * (lo + hi), 0.5 * max(float((hi - lo).max()), 1e-9)
    for set_lim, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        set_lim(m - half, m + half)
    ax.set_box_aspect((1, 1, 1), zoom=zoom)


def equal_view_3d(ax, points, obstacles=(), pad: float = 0.0, zoom: float = 1.0):
    """Obstacles and equal axes around ``points`` (padded by ``pad``) and the obstacles: boxes and planes cut to the
    points' box (padded 10 % more: a wall or floor must not swamp the tube), spheres, capsules and meshes whole."""
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in points if np.size(p)])
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    margin = 0.1 * float((hi - lo).max())
    drawn = draw_obstacles(ax, obstacles, view=(lo - margin, hi + margin)) if obstacles else []
    set_equal_3d(ax, [lo, hi, *drawn], zoom)


def fmt_len(value: float, units: str) -> str:
    return f"{value:.3g} {units}"


# ------------------------------------------------------------------ panels


def _halfspace_polytope(A, b):
    """Vertices and hull triangles of {x: A x <= b} (bounded), or None when it is empty or flat."""
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError
    norms = np.linalg.norm(A, axis=1)
    # Chebyshev center: an interior point for qhull, and the test for emptiness
    res = linprog(np.r_[np.zeros(3), -1.0], A_ub=np.column_stack([A, norms]), b_ub=b, bounds=[(None, None)] * 3 + [(0, None)])
    if not res.success or res.x[3] <= 1e-9 * max(1.0, float(np.abs(b).max())):
        return None
    try:
        hs = HalfspaceIntersection(np.column_stack([A, -b]), res.x[:3])
        hull = ConvexHull(hs.intersections)
    except QhullError:
        return None
    return hull.points, hull.simplices


def draw_obstacles(ax, obstacles, view=None, color=palette.OBSTACLE, alpha: float = 0.3):
    """Draw obstacles (``vine_nlp.analysis.obstacles`` shapes) into a 3-D axis.

    Spheres, capsules and meshes are drawn whole; boxes and planes (the solid half-space
    behind the plane) are cut to ``view`` = (lo, hi) corners (default: the axis limits), so a
    large wall or floor does not swamp the tube. Returns the points drawn (for extents)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    if view is None:
        view = (np.array([ax.get_xlim()[0], ax.get_ylim()[0], ax.get_zlim()[0]]),
                np.array([ax.get_xlim()[1], ax.get_ylim()[1], ax.get_zlim()[1]]))
    lo, hi = (np.asarray(v, float) for v in view)
    A_view = np.vstack([np.eye(3), -np.eye(3)])
    b_view = np.r_[hi, -lo]
    drawn = []
    style = dict(color=color, alpha=alpha, linewidth=0, edgecolor="none", antialiased=False, shade=True)
    for ob in obstacles:
        tris = None
        if isinstance(ob, (Sphere, Capsule)):
            pts = obstacle_surface(ob)
            ax.plot_surface(pts[..., 0], pts[..., 1], pts[..., 2], **style).set_rasterized(True)
            drawn.append(pts.reshape(-1, 3))
        elif isinstance(ob, Mesh):
            tris = ob.triangles
        elif isinstance(ob, (Box, Plane)):
            if isinstance(ob, Box):
                R, c, h = np.array(ob.rotation), np.array(ob.center), 0.5 * np.array(ob.size)
                A = np.vstack([R.T, -R.T])
                bb = np.r_[R.T @ c + h, -(R.T @ c) + h]
            else:
                n = np.array(ob.normal)
                A, bb = n[None, :], np.array([n @ np.array(ob.point)])
            poly = _halfspace_polytope(np.vstack([A, A_view]), np.r_[bb, b_view])
            if poly is not None:
                tris = poly[0][poly[1]]
        if tris is not None:
            coll = Poly3DCollection(tris, facecolors=color, edgecolors="none", alpha=alpha)
            coll.set_rasterized(True)
            ax.add_collection3d(coll)
            drawn.append(tris.reshape(-1, 3))
    return drawn


def plot_shape_3d(ax, archive: Archive, name: str, norm=None, cmap=ERROR_CMAP, legend: bool = True, zoom: float = 1.0,
                  obstacles=None):
    """One run in 3-D: target, tube wall at true diameter, actuator/opposite lines, error-colored center line."""
    u, D = archive.units, archive.diameter
    r = archive.runs[name]
    everything = [r.shape.inner, r.shape.outer]
    handles = []
    if archive.target is not None:
        # mplot3d sorts collections (the wall, obstacles) by depth and gives them zorders from about 2 up, one each;
        # lines keep their own: above every collection, the target is never hidden under the wall (dashes with
        # gaps: the coloured center line shows between them)
        handles += ax.plot(*archive.target.T, color=palette.TARGET, ls=(0, (3, 3)), lw=0.8, label=palette.LABELS["target"], zorder=100)
        everything.append(archive.target)
    measured = archive.extra.get("measured/points")
    if measured is not None:
        handles.append(ax.scatter(*np.asarray(measured).T, s=2, color="0.35", depthshade=False, label="measured"))
        everything.append(measured)
    X, Y, Z = tube_surface(r.shape, D)
    wall = ax.plot_surface(X, Y, Z, color=palette.TUBE, alpha=0.22, linewidth=0, edgecolor="none", antialiased=False,
                           shade=True, rstride=1, cstride=1)
    wall.set_rasterized(True)  # thousands of facets: an image inside vector (pdf) output
    handles.append(Patch(color=palette.TUBE, alpha=0.5, label=palette.LABELS["tube"]))
    handles += ax.plot(*r.shape.inner.T, color=palette.ACTUATOR, lw=1.1, label=palette.LABELS["actuator"])
    handles += ax.plot(*r.shape.outer.T, color=palette.OPPOSITE, lw=0.6, label=palette.LABELS["opposite"])
    center = r.shape.center
    if norm is not None and is_paired(archive, r):
        err = error_along(archive, r)
        segs = np.stack([center[:-1], center[1:]], axis=1)
        lc = Line3DCollection(segs, cmap=cmap, norm=norm, linewidths=1.6, label=palette.LABELS["center"])
        lc.set_array(0.5 * (err[:-1] + err[1:]))
        ax.add_collection3d(lc)
        handles.append(Line2D([], [], color=matplotlib.colormaps[cmap](0.6), lw=1.6, label=palette.LABELS["center"]))
    else:
        handles += ax.plot(*center.T, color="0.25", lw=0.8, label="center line")
    ends = chain_frames(r.routing.theta, r.routing.lam, r.routing.length, D, r.routing.initial_pose)[:, :3, 3]
    handles.append(ax.scatter(*ends.T, s=3, color="k", depthshade=False, label="segment ends"))
    ax.scatter(*center[0], s=14, color="k", marker="s", depthshade=False)
    if obstacles:
        handles.append(Patch(color=palette.OBSTACLE, alpha=0.5, label=palette.LABELS["obstacle"]))
    label_3d_axes(ax, u)
    equal_view_3d(ax, everything, obstacles, zoom=zoom)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.pane.set_alpha(0.0)
        axis._axinfo["grid"]["linewidth"] = 0.3
    if legend:
        ax.legend(handles=handles, loc="upper left", fontsize=7, frameon=False, handlelength=1.2, borderaxespad=0.0, labelspacing=0.25,
                  bbox_to_anchor=(-0.1, 1.0))  # into the margin left of the 3-D box: off the tube
    return ax


def run_label(archive: Archive, name: str) -> str:
    r = archive.runs[name]
    if "rmse" in r.metrics:
        return f"{name} (RMSE {fmt_len(r.metrics['rmse'], archive.units)})"
    return name


def _bound_lines(ax, values, bounds):
    """Dotted bound lines that do not stretch the axis: shown where the data come near them."""
    lo, hi = float(np.min(values)), float(np.max(values))
    pad = 0.08 * max(hi - lo, 1e-3 * max(abs(hi), 1.0), 1e-9)
    lo, hi = lo - pad, hi + pad
    for b in bounds:
        if lo - 3 * pad <= b <= hi + 3 * pad:
            ax.axhline(b, color="0.45", lw=0.7, ls=":")
            lo, hi = min(lo, b - 0.5 * pad), max(hi, b + 0.5 * pad)
    ax.set_ylim(lo, hi)


def plot_parameters(axes, archive: Archive, names, colors, styles=None, legend: bool = True):
    """theta(s), lambda(s) as per-segment steps and phi(s) (piecewise linear) for every run,
    against length along the unactuated tube; dotted lines: the problem's bounds."""
    ax_t, ax_l, ax_p = axes
    styles = styles or {}
    u = archive.units
    thetas, lams = [], []
    for name in names:
        r = archive.runs[name]
        S = segment_edges(r.routing)
        kw = dict(color=colors[name], ls=styles.get(name, "-"), lw=1.0)
        ax_t.stairs(np.degrees(r.routing.theta), S, baseline=None, label=run_label(archive, name), **kw)
        ax_l.stairs(r.routing.lam, S, baseline=None, label=run_label(archive, name), **kw)
        ax_p.plot(S, np.degrees(r.phi), label=run_label(archive, name), **kw)
        thetas.append(np.degrees(r.routing.theta))
        lams.append(r.routing.lam)
    act = source_table(archive, "actuator")
    th_max, lam_min = act.get("theta_max_deg"), act.get("lambda_min")
    ax_t.axhline(0.0, color="0.6", lw=0.4)
    if thetas:
        _bound_lines(ax_t, np.concatenate(thetas), [s * float(th_max) for s in (-1, 1)] if _number(th_max) else [])
        _bound_lines(ax_l, np.concatenate(lams + [[1.0]]), [float(lam_min)] if _number(lam_min) else [])
    ax_l.axhline(1.0, color="0.6", lw=0.4)
    ax_t.set_ylabel(r"$\theta$ [deg]")
    ax_l.set_ylabel(r"$\lambda$ [-]")
    ax_p.set_ylabel(r"$\phi$ [deg]")
    for ax in axes:
        ax.set_xlabel(f"s along unactuated tube [{u}]")
        ax.set_xlim(left=0.0)
        ax.grid(True, lw=0.3, color="0.85")
    if legend:
        ax_t.legend(loc="best", frameon=False, handlelength=1.8)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def plot_error(ax, archive: Archive, names, colors, styles=None):
    """Distance to the target against length along the unactuated tube (paper Fig. 12(d))."""
    styles = styles or {}
    u = archive.units
    for name in names:
        r = archive.runs[name]
        if not is_paired(archive, r):
            continue
        ax.plot(point_s(archive, r), error_along(archive, r), color=colors[name], ls=styles.get(name, "-"), lw=1.0,
                label=run_label(archive, name))
    ax.set_xlabel(f"s along unactuated tube [{u}]")
    ax.set_ylabel(f"error to target [{u}]")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.3, color="0.85")
    ax.legend(loc="best", frameon=False, handlelength=1.8)


# ------------------------------------------------------------------ figure


def plot_archive(archive, obstacles=None) -> Figure:
    """The figure of an archive (an Archive or a path to one).

    Layouts: one run without target (forward): a 3.5 in column, 3-D view over the theta, lambda, phi panels. One design
    run: 7.16 in, 3-D view and error in the first row, theta, lambda, phi in the second. Several runs (``compare``): one
    3-D view per run (at most three) over error, theta, lambda, phi in a 2 x 2 grid. ``obstacles``
    (``vine_nlp.io.obstacles.read_obstacles`` of the archive's /obstacles) are drawn in every 3-D view."""
    if not isinstance(archive, Archive):
        archive = load_archive(archive)
    names = ordered_runs(archive)
    colors = {n: RUN_COLORS[i % len(RUN_COLORS)] for i, n in enumerate(names)}
    styles = {n: RUN_STYLES[i % len(RUN_STYLES)] for i, n in enumerate(names)}
    paired = [n for n in names if is_paired(archive, archive.runs[n])]
    shown3d = names[:3]
    k = len(shown3d)
    err_max = max((float(error_along(archive, archive.runs[n]).max()) for n in paired), default=0.0)
    norm = Normalize(0.0, err_max if err_max > 0 else 1.0) if paired else None
    with matplotlib.rc_context(STYLE):
        if k <= 1 and not paired:
            fig = Figure(figsize=(COLUMN_IN, 2.9 + 3 * 1.45), layout="constrained")
            gs = fig.add_gridspec(4, 1, height_ratios=[2.9, 1.45, 1.45, 1.45])
            cells3d = [gs[0]]
            ax_e = None
            cells = [gs[1], gs[2], gs[3]]
        elif k <= 1:
            fig = Figure(figsize=(PAGE_IN, 3.2 + 1.75), layout="constrained")
            gs = fig.add_gridspec(2, 1, height_ratios=[3.2, 1.75])
            row = gs[0].subgridspec(1, 2, width_ratios=[1.25, 1.0])
            cells3d = [row[0]]
            ax_e = fig.add_subplot(row[1])
            low = gs[1].subgridspec(1, 3)
            cells = [low[0], low[1], low[2]]
        else:
            h3d = 3.2 if k == 2 else 2.5
            fig = Figure(figsize=(PAGE_IN, h3d + 2 * 1.55), layout="constrained")
            gs = fig.add_gridspec(2, 1, height_ratios=[h3d, 2 * 1.55])
            row = gs[0].subgridspec(1, k)
            cells3d = [row[i] for i in range(k)]
            low = gs[1].subgridspec(2, 2)
            ax_e = fig.add_subplot(low[0, 0]) if paired else None
            cells = [low[0, 1], low[1, 0], low[1, 1]] if paired else [low[0, 0], low[0, 1], low[1, 0]]
        fig.get_layout_engine().set(h_pad=0.02, w_pad=0.02, hspace=0.04, wspace=0.04)
        axes3d = []
        for i, name in enumerate(shown3d):
            ax = fig.add_subplot(cells3d[i], projection="3d")
            plot_shape_3d(ax, archive, name, norm=norm, legend=(i == 0), zoom=0.95 if k < 3 else 0.82, obstacles=obstacles)
            r = archive.runs[name]
            title = f"({chr(ord('a') + i)}) {name}"
            if "rmse" in r.metrics and "max_error" in r.metrics:
                title += f"\nRMSE {fmt_len(r.metrics['rmse'], archive.units)}, max {fmt_len(r.metrics['max_error'], archive.units)}"
            ax.set_title(title, pad=0)
            axes3d.append(ax)
        if norm is not None:
            cb = fig.colorbar(ScalarMappable(norm=norm, cmap=ERROR_CMAP), ax=axes3d, shrink=0.7, pad=0.1 if k == 1 else 0.06, aspect=25)
            cb.set_label(f"center-line error to target [{archive.units}]")
        ax_t = fig.add_subplot(cells[0], sharex=ax_e)
        ax_l = fig.add_subplot(cells[1], sharex=ax_t)
        ax_p = fig.add_subplot(cells[2], sharex=ax_t)
        panels = [ax_t, ax_l, ax_p]
        if ax_e is not None:
            plot_error(ax_e, archive, names, colors, styles)
            panels.insert(0, ax_e)
        plot_parameters((ax_t, ax_l, ax_p), archive, names, colors, styles, legend=ax_e is None)
        for i, ax in enumerate(panels):
            ax.set_title(f"({chr(ord('a') + k + i)})", loc="left", pad=2)
        fig.suptitle(f"{archive.name} ({archive.kind}), D = {fmt_len(archive.diameter, archive.units)}")
    return fig


def save_figure(fig, figure_path, dpi: int = 300) -> Path:
    """Write a figure (format by suffix: png, pdf, svg) atomically, in the house style, and close it."""
    fmt = figure_format(figure_path)
    try:
        with matplotlib.rc_context(STYLE):
            write_atomic(figure_path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=fmt))
    finally:
        if getattr(fig.canvas, "manager", None) is not None:
            # a figure made with pyplot (by the caller): release it from pyplot's registry;
            # the figures made here are plain Figures, never registered there
            import matplotlib.pyplot as plt

            plt.close(fig)
    return Path(figure_path)
