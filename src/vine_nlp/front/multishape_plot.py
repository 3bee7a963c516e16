"""Figure of a multi-shape archive: the family of shapes of ONE sPAM routing at its K levels.

(a) 3-D: every level's modeled center line (solid, one colour per level, as the runs of
    ``vine_nlp.front.plot``: lambda in panel (c)'s legend), its actuator line (the actuator
    line's colour of every figure, thin) and its target (dashed black), the base marked;
    equal axis scaling, units on every axis (colours: front/palette.py).
(b) the shared routing theta(s) [deg] against length along the unactuated tube;
(c) each level's error to its target against that length.

Sized like ``vine_nlp.front.plot`` (7.16 in wide, 7-8 pt fonts); png, pdf or svg by suffix."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from vine_nlp.front import palette
from vine_nlp.front.plot import PAGE_IN, STYLE, label_3d_axes, set_equal_3d
from vine_nlp.io.formulations import read_multishape_archive
from vine_nlp.model.pairing import pair_points


def _level_s(result, k, target):
    """Length along the unactuated tube of each paired point of level k (model.pairing)."""
    n = result.stats.get("points_per_segment")
    r = result.routing
    edges = np.concatenate([[0.0], np.cumsum(r.length)])
    if isinstance(n, (int, float)) and n >= 1:
        try:
            p = pair_points(target, int(n))
            if p.segments == r.segments:
                return edges[p.seg] + p.frac * r.length[p.seg]
        except ValueError:
            pass
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(target, axis=0), axis=1))])
    return chord / max(chord[-1], 1e-300) * edges[-1]


def plot_multishape_figure(source) -> Figure:
    """The figure of a multi-shape archive: ``source`` is its path, or the
    ``(archive, result, targets)`` that ``io.formulations.read_multishape_archive`` returns."""
    if isinstance(source, (str, Path)):
        source = read_multishape_archive(source)
    return multishape_figure(*source)


def multishape_figure(a, r, targets) -> Figure:
    """Draw a multi-shape result: ``a`` the archive (name, units, diameter), ``r`` the MultiShapeResult (shared routing,
    K levels, shapes and per-level metrics), ``targets`` the K target point arrays (N, 3). Reads nothing."""
    u, K = a.units, r.count
    colors = [palette.RUNS[k % len(palette.RUNS)] for k in range(K)]
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(PAGE_IN, 3.6), layout="constrained")
        gs = fig.add_gridspec(2, 2, width_ratios=[1.25, 1.0])
        ax = fig.add_subplot(gs[:, 0], projection="3d")
        everything = []
        for k in range(K):
            sh, tg = r.shapes[k], targets[k]
            ax.plot(*sh.center.T, color=colors[k], lw=1.3)
            ax.plot(*sh.inner.T, color=palette.ACTUATOR, lw=0.6)
            ax.plot(*tg.T, "--", color=palette.TARGET, lw=0.7, dashes=(3, 3))
            ax.scatter(*sh.center[0], s=10, color=colors[k], marker="s", depthshade=False)
            everything += [sh.center, sh.inner, tg]
        ax.plot([], [], "-", color=colors[0], lw=1.3, label="center lines (colour: level)")
        ax.plot([], [], "-", color=palette.ACTUATOR, lw=0.6, label="actuator lines")
        ax.plot([], [], "--", color=palette.TARGET, lw=0.7, dashes=(3, 3), label="targets")
        label_3d_axes(ax, u)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.pane.set_alpha(0.0)
        set_equal_3d(ax, everything)
        ax.legend(loc="upper left", frameon=False, fontsize=6, ncols=3, bbox_to_anchor=(0.0, 1.02))
        pose = "one shared base pose" if r.shared_pose else "a base pose per level"
        ax.set_title(f"(a) {K} shapes of one routing, {pose}", pad=0)

        edges = np.concatenate([[0.0], np.cumsum(r.routing.length)])
        ax_t = fig.add_subplot(gs[0, 1])
        ax_t.stairs(np.degrees(r.routing.theta), edges, color="k", lw=1.0, baseline=None)
        ax_t.set_ylabel(r"$\theta$ [deg]")
        ax_t.ticklabel_format(axis="y", useOffset=False)
        th = np.degrees(r.routing.theta)
        if np.ptp(th) < 1.0:  # a (nearly) uniform routing: show its value, not round-off
            ax_t.set_ylim(th.mean() - 1.0, th.mean() + 1.0)
        ax_t.set_title("(b) shared routing", loc="left", pad=2)
        ax_e = fig.add_subplot(gs[1, 1], sharex=ax_t)
        for k in range(K):
            err = np.linalg.norm(r.shapes[k].center - targets[k], axis=1)
            tag = "fixed" if r.fixed and r.fixed[k] else "free"
            ax_e.plot(_level_s(r, k, targets[k]), err, color=colors[k], lw=1.0,
                      label=f"$\\lambda$ = {r.levels[k]:.4g} ({tag}): RMSE {r.level_metrics[k]['rmse']:.3g} {u}")
        ax_e.legend(frameon=False, fontsize=6)
        ax_e.set_xlabel(f"s, length along the unactuated tube [{u}]")
        ax_e.set_ylabel(f"error [{u}]")
        ax_e.set_title("(c) center-line error to each target", loc="left", pad=2)
        m = r.metrics
        fig.suptitle(f"{a.name} (multishape), D = {a.diameter:.3g} {u}: RMSE {m['rmse']:.3g} {u}, max {m['max_error']:.3g} {u}, {r.status}")
    return fig
