"""Figures of the design analyses: manufacturing tolerance and self-clearance.

* :func:`tolerance_figure`: (a) each segment's share of the tip position variance
  (first order, stacked by theta / lambda / length errors) against length along the
  unactuated tube: where construction errors matter most; (b) the Monte Carlo RMSE
  histogram with the nominal RMSE, the first-order prediction sqrt(E[MSE]) and the
  Monte Carlo mean and RMS.
* :func:`clearance_figure`: distance from each point of the center line to the
  nearest non-neighbouring part against length along the tube, the tube diameter D
  (contact below it) and where each contact appears when grown while actuated.

Same style and sizes as front.plot (IEEE column 3.5 in, fonts 7-8 pt)."""

from __future__ import annotations

import math

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from vine_nlp.analysis.collision import growth_contacts, routing_clearance
from vine_nlp.front.plot import COLUMN_IN, STYLE, save_figure

PARAM_COLORS = ("tab:blue", "tab:orange", "tab:green")
PARAM_LABELS = (r"$\theta$", r"$\lambda$", r"length")


def _save(fig: Figure, path) -> None:
    if path is not None:
        save_figure(fig, path)


def tolerance_figure(report: dict, path=None, title: str | None = None) -> Figure:
    """Per-segment tip-variance contribution vs length along the tube, and the MC RMSE histogram."""
    u = report.get("units", "")
    ps, fo, mc = report["per_segment"], report["first_order"], report["monte_carlo"]
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(COLUMN_IN, 4.2), layout="constrained")
        a, b = fig.subplots(2, 1)
        left, width = ps["l_start"], ps["l_end"] - ps["l_start"]
        total = max(float(ps["tip_var"].sum()), 1e-300)
        bottom = np.zeros_like(left)
        for k in range(3):
            share = 100 * ps["tip_var_by_param"][:, k] / total
            a.bar(left, share, width=width, bottom=bottom, align="edge", color=PARAM_COLORS[k], label=PARAM_LABELS[k],
                  edgecolor="white", linewidth=0.3)
            bottom = bottom + share
        a.set_xlabel(f"length along the unactuated tube [{u}]")
        a.set_ylabel("share of tip variance [%]")
        a.set_xlim(float(left[0]), float(ps["l_end"][-1]))
        a.set_ylim(0, 1.25 * a.get_ylim()[1])  # room for the legend
        a.legend(loc="upper right", frameon=False, ncol=3)
        a.set_title(f"(a) tip std {fo['tip_std']:.3g} {u} (first order), {mc['tip_std']:.3g} {u} (Monte Carlo)")
        r = mc["rmse"]
        b.hist(r, bins=min(60, max(10, int(math.sqrt(r.size)))), color="0.7", edgecolor="white", linewidth=0.3)
        lines = [(report["nominal"]["rmse"], "k", ":", "nominal"),
                 (fo["rmse"], "tab:red", "-", r"first order $\sqrt{E[\mathrm{MSE}]}$"),
                 (mc["rms_rmse"], "tab:blue", "--", r"MC $\sqrt{\mathrm{mean\ MSE}}$"),
                 (mc["mean_rmse"], "tab:green", "-.", "MC mean RMSE")]
        for v, c, ls, lab in lines:
            b.axvline(v, color=c, ls=ls, lw=1.0, label=f"{lab} {v:.3g}")
        b.set_xlabel(f"RMSE to the target [{u}]")
        b.set_ylabel("samples")
        sg = report["sigmas"]
        lu = "%" if sg["relative_length"] else u
        lv = 100 * sg["sigma_length"] if sg["relative_length"] else sg["sigma_length"]
        b.set_title(f"(b) {mc['samples']} samples, " + rf"$\sigma_\theta$ {sg['sigma_theta_deg']:.3g}$^\circ$, "
                    + rf"$\sigma_\lambda$ {sg['sigma_lambda']:.3g}, $\sigma_\ell$ {lv:.3g} {lu}")
        b.set_ylim(0, 1.7 * b.get_ylim()[1])  # room for the legend
        b.legend(loc="upper right", frameon=False, fontsize=6)
        if title:
            fig.suptitle(title)
    _save(fig, path)
    return fig


def nearest_distance_profile(points, s, exclude_arc, chunk: int = 512) -> np.ndarray:
    """For each point, the distance to the nearest point farther than ``exclude_arc`` along the line."""
    points, s = np.asarray(points, float), np.asarray(s, float)
    out = np.full(len(points), np.inf)
    for a in range(0, len(points), chunk):
        d = np.linalg.norm(points[a : a + chunk, None] - points[None], axis=2)
        d[np.abs(s[a : a + chunk, None] - s[None]) <= exclude_arc] = np.inf
        out[a : a + chunk] = d.min(axis=1)
    return out


def clearance_figure(routing, D: float, path=None, units: str = "", growth=None, title: str | None = None) -> Figure:
    """Nearest non-neighbour distance along the tube, the diameter D, and the growth order of contacts.

    ``growth``: the list from analysis.collision.growth_contacts (computed if None)."""
    res = routing_clearance(routing, D)
    line = res["line"]
    prof = nearest_distance_profile(line["points"], line["s"], res["exclude_arc"])
    growth = growth_contacts(routing, D) if growth is None else growth
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(COLUMN_IN, 2.2), layout="constrained")
        ax = fig.subplots()
        ax.plot(line["l"], prof, color="k", lw=1.0, label="nearest non-neighbour")
        ax.axhline(D, color="tab:red", ls="--", lw=0.8, label=f"D = {D:.3g} {units}")
        for c in growth:
            if c["transient"]:
                ax.axvspan(c["l_early"] - 0.02 * line["l"][-1], c["l_early"] + 0.02 * line["l"][-1], color="tab:orange", alpha=0.15, lw=0)
                ax.axvspan(c["l_late"] - 0.02 * line["l"][-1], c["l_late"] + 0.02 * line["l"][-1], color="tab:orange", alpha=0.15, lw=0)
            else:
                ax.axvline(c["growth_length"], color="tab:blue", lw=0.8, ls=":")
        if any(not c["transient"] for c in growth):
            ax.plot([], [], color="tab:blue", ls=":", label="contact appears (grown while actuated)")
        if any(c["transient"] for c in growth):
            ax.fill_between([], [], color="tab:orange", alpha=0.3, label="contact on the way (actuated after growth)")
        finite = prof[np.isfinite(prof)]
        top = 1.4 * max(2.0 * D, float(np.percentile(finite, 90)) if finite.size else 2.0 * D)
        ax.set_ylim(0, top)
        ax.set_xlim(float(line["l"][0]), float(line["l"][-1]))
        ax.set_xlabel(f"length along the unactuated tube [{units}]")
        ax.set_ylabel(f"distance [{units}]")
        ax.set_title(title or f"min clearance {res['clearance']:.3g} {units}, {len(res['regions'])} contact region(s)")
        ax.legend(loc="upper right", frameon=False, fontsize=6)
    _save(fig, path)
    return fig
