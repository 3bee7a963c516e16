"""``vine-nlp analyze`` under a problem's [load] (issue 45): the lines it prints and its figure, the bending
moment and the capacity along the tube, the final shape's and the largest over growth (analysis.loads)."""

from __future__ import annotations

import math

import matplotlib

from vine_nlp.analysis.loads import fold_line, growth_curve, load_metrics, load_report
from vine_nlp.errors import InputError
from vine_nlp.front.plot import COLUMN_IN, STYLE, save_figure
from vine_nlp.io.problems import parse_problem
from vine_nlp.io.validate import parse_toml


def archived_load(archive, path):
    """(Load, growth) of the archive's problem, or (None, None) where its source has no valid [load]."""
    try:
        pf = parse_problem(parse_toml(str(path), archive.source), str(path), archive.source)
    except InputError:
        return None, None
    load = getattr(pf.problem, "load", None)
    return load, getattr(pf.problem, "growth", "while-actuated")


def analyze_load(archive, path, routing, figure=None, title: str = "") -> dict:
    """Print the load lines of one run, draw ``figure`` if asked; the run's load metrics ({} without [load])."""
    load, growth = archived_load(archive, path)
    if load is None:
        if figure:
            raise InputError(path, "--load-figure", "the archived problem has no [load]")
        return {}
    u = archive.units
    rep = load_report(routing, archive.diameter, u, load, growth)
    if growth == "while-actuated" and math.isfinite(rep["margin"]):
        rep["growth_curve"] = growth_curve(routing, archive.diameter, u, load, rep["weakest"])
    m = load_metrics(rep)
    where = f" at s = {rep['collapse_at']:.4g} {u}" if math.isfinite(rep["margin"]) else ""
    print(f"load        {load.pressure:g} kPa, {load.mass_per_length:g} kg/m, tip {load.tip_mass:g} kg, safety {load.safety:g}, "
          f"growth {growth}: " + (f"holds, margin {rep['margin']:.3g}{where}; it needs {rep['min_pressure']:.4g} kPa" if rep["holds"]
                                  else fold_line(rep, load, u)))
    if figure:
        load_figure(rep, figure, u, title)
        print(f"figure -> {figure}")
    return m


def load_figure(rep: dict, path=None, units: str = "", title: str = ""):
    """Bending moment (final shape; the largest over growth) and capacity along the tube, N m; with
    ``rep["growth_curve"]`` a second panel: the weakest section's moment as the tube grows."""
    from matplotlib.figure import Figure
    curve = rep.get("growth_curve")
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(COLUMN_IN, 4.2 if curve else 2.4), layout="constrained")
        ax, *more = fig.subplots(2 if curve else 1, 1) if curve else [fig.subplots()]
        s = rep["s"]
        ax.plot(s, rep["capacity"], color="k", lw=1.0, label="capacity (it folds)")
        ax.plot(s, rep["capacity"] / rep["safety"], color="k", lw=0.8, ls=":", label=f"capacity / safety {rep['safety']:g}")
        ax.plot(s, rep["moment"], color="tab:blue", lw=1.0, label="moment, final shape")
        ax.plot(s, rep["moment_growth"], color="tab:red", lw=1.0, ls="--", label="moment, largest while growing")
        if math.isfinite(rep["margin"]):
            ax.axvline(rep["collapse_at"], color="0.5", lw=0.6, ls=":")
        ax.set_xlabel(f"arc length along the tube [{units}]")
        ax.set_ylabel("bending moment [N m]")
        ax.set_ylim(0, 1.45 * max(float(rep["capacity"].max()), float(rep["moment_growth"].max())))
        ax.legend(frameon=False, loc="upper center", ncol=2, fontsize=6)
        ax.set_title(("(a) " if curve else "") + f"{title}: margin {rep['margin']:.3g}, needs {rep['min_pressure']:.3g} kPa".lstrip(": "))
        if curve:
            b, i = more[0], rep["weakest"]
            b.plot(curve[0], curve[1], color="tab:red", lw=1.0, label=f"moment at s = {rep['collapse_at']:.3g} {units}")
            b.axhline(rep["capacity"][i] / rep["safety"], color="k", lw=0.8, ls=":", label="its capacity / safety")
            b.set_xlabel(f"grown length [{units}]")
            b.set_ylabel("bending moment [N m]")
            b.set_ylim(0, 1.3 * max(float(curve[1].max()), float(rep["capacity"][i] / rep["safety"])))
            b.legend(frameon=False, loc="upper left", fontsize=6)
            b.set_title("(b) the weakest section as the tube grows")
    if path is not None:
        save_figure(fig, path)
    return fig
