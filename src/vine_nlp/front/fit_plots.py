"""Figures of model fits (paper Sec. V): measured points against the fitted model, and frame sequences.

* :func:`plot_fit`: 3-D view of the measured points with the model moved onto them
  (equal axes) and the position error against length along the model line
  (paper Figs. 5, 7(d)-(e), 9(c)).
* :func:`plot_frames`: lambda over the frames of an actuated sequence and the error
  against length of a few frames (paper Figs. 9(d) and 11(c)-(d))."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from vine_nlp.front.plot import save_figure, set_equal_3d
from vine_nlp.io.archive import Archive, load_archive
from vine_nlp.model.routing import MEASURED_LINES

LINE_COLORS = {"center": "tab:gray", "inner": "tab:blue", "outer": "tab:red"}


def _fit_inputs(source, extras):
    """(result, extras, units, name) from an Archive, an archive path, (Result, extras) or a Result."""
    units, name = "cm", ""
    if isinstance(source, (str, Path)):
        source = load_archive(source)
    if isinstance(source, Archive):
        units, name = source.units, source.name
        runs = source.runs
        result = runs.get("fit") or next((r for r in runs.values() if r.method == "fit"), None)
        if result is None:
            raise ValueError("the archive has no fit run")
        extras = dict(source.extra) | dict(extras or {})
    elif isinstance(source, tuple):
        result, extras = source[0], dict(source[1]) | dict(extras or {})
    else:
        result = source
    extras = {k.strip("/"): np.asarray(v) for k, v in (extras or {}).items()}
    if "measured/points" not in extras:
        raise ValueError("plot_fit needs the measured points (extras 'measured/points')")
    return result, extras, units, name


def plot_fit(source, path=None, extras=None, title=None):
    """Measured points against the fitted model, and the error against length.

    ``source``: an archive written by ``vine-nlp fit`` (an :class:`Archive` or its
    path), a ``(Result, extras)`` pair from :func:`vine_nlp.methods.fit.fit_problem`, or a
    Result with ``extras`` given separately. Returns the Figure, also written to ``path`` (png or pdf) if given."""
    result, ex, units, name = _fit_inputs(source, extras)
    pts = ex["measured/points"].reshape(-1, 3)
    err, s = ex.get("measured/error"), ex.get("measured/s")
    closest = ex.get("measured/closest")
    code = ex.get("measured/line", np.full(pts.shape[0], -1)).astype(int)
    measured_lines = sorted(set(code.tolist()))

    fig = Figure(figsize=(11, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    for k, line in enumerate(MEASURED_LINES):
        xyz = getattr(result.shape, line)
        on = k in measured_lines
        ax.plot(*xyz.T, color=LINE_COLORS[line], lw=1.6 if on else 0.6, alpha=1.0 if on else 0.5,
                label=f"model {line} line" + (" (fitted)" if on else ""))
    for k in measured_lines:
        sel = code == k
        label = f"measured {MEASURED_LINES[k]}" if 0 <= k < len(MEASURED_LINES) else "measured"
        color = LINE_COLORS.get(MEASURED_LINES[k], "k") if 0 <= k < len(MEASURED_LINES) else "k"
        ax.scatter(*pts[sel].T, s=10, color=color, edgecolors="k", linewidths=0.3, label=label, depthshade=False)
    if closest is not None and pts.shape[0] <= 2000:
        for p, c in zip(pts, closest.reshape(-1, 3)):
            ax.plot(*np.stack([p, c]).T, color="k", lw=0.4, alpha=0.6)
    ax.set_xlabel(f"x [{units}]")
    ax.set_ylabel(f"y [{units}]")
    ax.set_zlabel(f"z [{units}]")
    set_equal_3d(ax, [pts, result.shape.center, result.shape.inner, result.shape.outer])
    ax.legend(loc="upper left", fontsize=7)

    ax2 = fig.add_subplot(1, 2, 2)
    if err is not None and s is not None:
        for k in measured_lines:
            sel = code == k
            order = np.argsort(s[sel])
            line = MEASURED_LINES[k] if 0 <= k < len(MEASURED_LINES) else "measured"
            ax2.plot(s[sel][order], err[sel][order], "o-", ms=3, lw=0.8, color=LINE_COLORS.get(line, "k"), label=f"{line} line")
        ax2.legend(fontsize=8)
    ax2.set_xlabel(f"length along the model line [{units}]")
    ax2.set_ylabel(f"position error [{units}]")
    ax2.set_ylim(bottom=0)
    ax2.grid(alpha=0.3)
    m = result.metrics
    bits = [f"RMSE {m['rmse']:.3g} {units}" if "rmse" in m else "", f"max {m['max_error']:.3g} {units}" if "max_error" in m else "",
            f"$R^2$ {m['r2']:.4f}" if "r2" in m else "", f"$\\lambda$ = {m['lambda']:.4f}" if "lambda" in m else ""]
    ax2.set_title(", ".join(b for b in bits if b), fontsize=9)
    fig.suptitle(title or (f"{name}: model fit" if name else "model fit"), fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=150)
    return fig


def plot_frames(results, path, units: str = "cm", title=None, show: int = 5):
    """Lambda over the frames of a sequence and the error against length of ``show`` frames (evenly spread,
    labelled with their lambda). ``results``: the list from :func:`vine_nlp.methods.fit.fit_frames` (frames that
    could not be fitted are gaps)."""
    lam, rmse = np.array([r[0] for r in results], float), np.array([r[1] for r in results], float)
    x = np.arange(lam.size)
    fig = Figure(figsize=(11, 4.2))
    a1, a2 = fig.subplots(1, 2)
    a1.plot(x, lam, "o-", ms=3, lw=1.0, color="tab:blue")
    a1.set_xlabel("frame")
    a1.set_ylabel(r"fitted $\lambda$", color="tab:blue")
    a1.grid(alpha=0.3)
    a1b = a1.twinx()
    a1b.plot(x, rmse, ".", ms=3, color="tab:red")
    a1b.set_ylabel(f"RMSE [{units}]", color="tab:red")
    a1b.set_ylim(bottom=0)
    ok = [k for k, r in enumerate(results) if np.isfinite(r[0]) and getattr(r, "s", None) is not None and np.size(r.s)]
    if ok:
        picks = sorted(set(np.array(ok)[np.round(np.linspace(0, len(ok) - 1, min(show, len(ok)))).astype(int)].tolist()),
                       key=lambda k: -lam[k])
        for k in picks:
            r = results[k]
            order = np.argsort(r.s)
            a2.plot(np.asarray(r.s)[order], np.asarray(r.error)[order], "o-", ms=3, lw=0.8,
                    label=f"frame {k}: $\\lambda$ = {lam[k]:.3f}, RMSE {rmse[k]:.3g}")
        a2.legend(fontsize=7)
    a2.set_xlabel(f"length along the model line [{units}]")
    a2.set_ylabel(f"position error [{units}]")
    a2.set_ylim(bottom=0)
    a2.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=150)
    return fig
