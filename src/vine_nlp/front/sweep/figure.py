"""summary.png: RMSE and solve-time distributions per method, NLP against greedy item by item."""

from __future__ import annotations

from pathlib import Path

from vine_nlp.front.sweep.summary import FAILED, _mm


def preload_matplotlib() -> None:
    """Import what :func:`plot_summary` needs (run in a thread while a sweep waits for its workers)."""
    try:
        import matplotlib.backends.backend_agg  # noqa: F401
        import matplotlib.figure  # noqa: F401
        import matplotlib.ticker  # noqa: F401
    except Exception:  # noqa: BLE001 - plot_summary imports them again and reports what is wrong
        pass


def plot_summary(rows, path, title: str | None = None) -> Path:
    """Summary figure of a sweep: RMSE and solve-time distributions per method, NLP against greedy.

    ``rows`` as in summary.csv (dicts with item, method, status, rmse, solve_time_s, units). RMSE is shown in mm when
    the units are a length unit (cm, mm, m, in). ``title`` goes before the item count at the top. The file is written
    atomically; its format follows the suffix."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter

    from vine_nlp.io.archive import write_atomic
    path = Path(path)
    ok = [r for r in rows if r.get("rmse") is not None and r.get("status") != FAILED]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    units = next((r.get("units") for r in ok if r.get("units")), "cm")
    factor, unit = _mm(units)
    by_method = {m: [r for r in ok if r["method"] == m] for m in methods}
    paired = {}
    if "nlp" in by_method and "greedy" in by_method:
        greedy = {r["item"]: r["rmse"] for r in by_method["greedy"]}
        paired = {r["item"]: (greedy[r["item"]], r["rmse"]) for r in by_method["nlp"] if r["item"] in greedy}

    panels = 3 if paired else 2
    # fixed margins, no layout engine: constrained layout measured every text twice and drew the figure
    # twice (more than half the time of the figure, which is drawn when everything else is done)
    fig = Figure(figsize=(4.6 * panels, 4.0))
    fig.subplots_adjust(left=0.2 / panels, right=1 - 0.05 / panels, bottom=0.13, top=0.85, wspace=0.32)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, panels)
    colors = {m: f"C{k}" for k, m in enumerate(methods)}

    def hist(ax, key, scale, label, unit):
        values = {m: np.array([r[key] * scale for r in by_method[m]]) for m in methods if by_method[m]}
        finite = [v[np.isfinite(v) & (v > 0)] for v in values.values()]
        allv = np.concatenate(finite) if finite else np.array([])
        if allv.size == 0:
            ax.text(0.5, 0.5, "no finished runs", ha="center", va="center", transform=ax.transAxes)
            ax.set_xlabel(label)
            return
        lo, hi = allv.min(), allv.max()
        if hi > 20 * lo:
            bins = np.geomspace(lo, hi, 25)
            ax.set_xscale("log")
        else:
            bins = np.linspace(lo, hi if hi > lo else lo + 1e-12, 25)
        for m, v in values.items():
            v = v[np.isfinite(v) & (v > 0)]
            ax.hist(v, bins=bins, alpha=0.6, color=colors[m], label=f"{m} (n = {v.size}, mean {v.mean():.3g} {unit})")
        ax.set_xlabel(label)
        ax.set_ylabel("runs")
        # few, unclipped tick labels: minor log labels and long decimals collide at this width
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.xaxis.set_major_locator(MaxNLocator(5) if ax.get_xscale() == "linear" else LogLocator())
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend(fontsize="small")

    hist(axes[0], "rmse", factor, f"RMSE [{unit}]", unit)
    axes[0].set_title("Error")
    hist(axes[1], "solve_time_s", 1.0, "solve time [s]", "s")
    axes[1].set_title("Solve time")
    if paired:
        ax = axes[2]
        g = np.array([v[0] for v in paired.values()]) * factor
        n = np.array([v[1] for v in paired.values()]) * factor
        ax.scatter(g, n, s=14, color="C0")
        lo, hi = min(g.min(), n.min()), max(g.max(), n.max())
        ax.plot([lo, hi], [lo, hi], "k--", lw=1, label="y = x")
        if hi > 20 * lo > 0:
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.set_xlabel(f"greedy RMSE [{unit}]")
        ax.set_ylabel(f"NLP RMSE [{unit}]")
        better = int(np.sum(n < g))
        ax.set_title(f"Item by item: NLP better on {better}/{len(g)}")
        ax.legend(fontsize="small")
        ax.set_aspect("equal", adjustable="datalim")
    failed = sum(1 for r in rows if r.get("status") == FAILED)
    head = f"{len(dict.fromkeys(r['item'] for r in rows))} items"
    if failed:
        head += f", {failed} failed run" + ("s" if failed != 1 else "")
    fig.suptitle(f"{title}: {head}" if title else head)
    fmt = path.suffix.lstrip(".").lower() or "png"
    write_atomic(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=120))
    return path
