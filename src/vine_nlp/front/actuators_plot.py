"""Figure of an archive of several actuators on one tube: one 3-D panel per state (the center line, every
actuator's line in its own colour, solid where it is pulled in that state, thin where not; the target dashed),
then every actuator's lambda along the tube. Sized like ``vine_nlp.front.plot``; png, pdf or svg by suffix."""

from __future__ import annotations

import math

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from vine_nlp.front import palette
from vine_nlp.front.plot import PAGE_IN, STYLE, label_3d_axes, set_equal_3d
from vine_nlp.io.actuators import read_actuators_archive
from vine_nlp.model.actuators import actuator_lines
from vine_nlp.model.chain import segment_end_samples


def plot_actuators_figure(path) -> Figure:
    a, r, targets = read_actuators_archive(path)
    ls, u, D = r.lines, a.units, a.diameter
    states = r.stats["states"]
    colors = {name: palette.LINES[k % len(palette.LINES)] for k, name in enumerate(ls.names)}
    seg, frac = segment_end_samples(ls.length, np.maximum(1, np.ceil(ls.length / (0.25 * D))).astype(int))
    cols = min(3, len(states))
    rows = math.ceil(len(states) / cols)
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(PAGE_IN, 2.6 * rows + 1.6), layout="constrained")
        gs = fig.add_gridspec(rows + 1, cols, height_ratios=[2.6] * rows + [1.3])
        for i, (s, active) in enumerate(states.items()):
            ax = fig.add_subplot(gs[i // cols, i % cols], projection="3d")
            drawn = [r.shapes[s].center]
            ax.plot(*r.shapes[s].center.T, color="k", lw=1.0)
            for name, pts in actuator_lines(ls, D, active, seg, frac, s).items():
                on = name in active
                ax.plot(*pts.T, color=colors[name], lw=1.2 if on else 0.4, alpha=1.0 if on else 0.5)
                drawn.append(pts)
            if s in targets:
                ax.plot(*targets[s].T, "--", color="0.4", lw=0.8, dashes=(3, 2))
                drawn.append(targets[s])
            label_3d_axes(ax, u)
            set_equal_3d(ax, drawn)
            m = r.state_metrics.get(s)
            ax.set_title(f"{s} ({', '.join(active)})" + (f": RMSE {m['rmse']:.3g} {u}" if "rmse" in (m or {}) else ""), pad=0)
        ax_l = fig.add_subplot(gs[rows, :])
        edges = np.r_[0.0, np.cumsum(ls.length)]
        for k, name in enumerate(ls.names):
            ax_l.stairs(ls.lam[k], edges, color=colors[name], lw=1.0, baseline=None, label=name)
        ax_l.set_xlabel(f"s, length along the unactuated tube [{u}]")
        ax_l.set_ylabel(r"$\lambda$")
        ax_l.legend(frameon=False, fontsize=6, ncols=min(ls.count, 6))
        fig.suptitle(f"{a.name}: {ls.count} actuators, {len(states)} states, D = {D:.3g} {u}, {r.status}")
    return fig
