"""Obstacles around the tube: sampling rule, growth and a report (issue 15).

The shapes and their distances are ``vine_nlp.model.obstacles``. The tube of
diameter D clears an obstacle by ``gap = distance(center line, obstacle) - D/2``;
a design asks for gap >= margin everywhere along the tube (formats.md "Obstacles").

Sampling rule (:func:`sample_spacing`, :func:`dip`)
---------------------------------------------------
Center-line points at most h apart along the arc, each at distance >= r = D/2 + m from a convex obstacle K, bound the
whole center line: let y be the point of the chord between two samples nearest to K and k its nearest point on K; the
samples are >= r from k and y - k is normal to the chord, so the chord (length <= h) stays >= sqrt(r^2 - h^2/4) from K.
If K's surface has all radii of curvature >= R_K (sphere, capsule: their radius; plane: infinite; box, triangle: 0), the
same argument about the center of curvature gives sqrt((r + R_K)^2 - h^2/4) - R_K. The arc leaves its chord by at most
the sagitta (1 - cos(kappa h / 2)) / kappa (center-line curvature <= kappa), and the distance is 1-Lipschitz, so between
samples the gap drops at most

    dip(h) = (r + R_K) - sqrt((r + R_K)^2 - h^2 / 4) + (1 - cos(kappa h / 2)) / kappa.

No obstacle fits between samples (the chord never reaches K) when h < 2 r = D + 2 m. To hold gap >= margin - tol on the
continuous tube: sample at h with dip(h) <= tol, or ask the samples for margin + dip(h) (how the NLP rows should use
it). With kappa = 2/D (the limit lambda -> 0 at theta = 0; steeper theta bends more: :func:`curvature_bound` gives
2.21/D for theta <= 60 deg, lambda >= 0.4) and a sharp obstacle: dip ~ h^2 / (2 D), so tol = 1e-3 D needs h <= 0.045 D,
while h = D/4 costs an inflation of D/32. A mesh's unsigned distance is the minimum over its (convex) triangles, so the
bound holds for it with R_K = 0.

Growth (paper Sec. VI-D; as in ``vine_nlp.analysis.collision``): grown while actuated, every body is a prefix
of the final center line, so the final shape's gaps cover growth (:func:`grown_prefixes`); actuated after
growth, every intermediate shape (:func:`after_growth_shapes`) must clear the obstacles too.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from vine_nlp.model.chain import chain_frames, chain_points, segment_end_samples
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import Routing

GROWTH_MODES = ("while-actuated", "after")
DEFAULT_PER_SEGMENT = 20
DEFAULT_AFTER_STEPS = 20  # t grid of actuation after growth: 0, 1/20, ..., 1


# ------------------------------------------------------------------ gaps along a tube


def min_gap(center_points, diameter: float, obstacles) -> np.ndarray:
    """(P, K) gaps between the tube surface and every obstacle at every center point (P, 3): signed distance
    minus D/2 (negative: the tube cuts into the obstacle); meshes exact (trimesh)."""
    p = np.atleast_2d(np.asarray(center_points, float))
    out = np.empty((len(p), len(obstacles)))
    for k, ob in enumerate(obstacles):
        out[:, k] = np.asarray(ob.distance(p), float).reshape(-1) - 0.5 * float(diameter)
    return out


@lru_cache(maxsize=64)
def curvature_bound(diameter: float, theta_max: float = math.radians(60.0), lambda_min: float = 0.0) -> float:
    """Largest center-line curvature over |theta| <= theta_max, lambda_min <= lambda <= 1 (model.center_rates).
    Cached: a grid of 362 000 evaluations, asked again by every obstacle design of the same actuator."""
    lam = np.linspace(max(lambda_min, 0.0), 1.0, 2001)
    th = np.linspace(0.0, min(theta_max, math.radians(89.0)), 181)
    kc, _, _ = center_rates(th[:, None], lam[None, :], float(diameter))
    return float(np.max(np.abs(kc)))


def dip(h: float, diameter: float, margin: float = 0.0, kappa: float | None = None, sharpness: float = 0.0) -> float:
    """How far the gap can fall between center-line samples h apart (module docstring, "Sampling rule").

    kappa: largest center-line curvature (default 2/D); sharpness: the obstacle's smallest
    radius of curvature (0 for edges and corners). inf if h >= 2 (D/2 + margin + sharpness)."""
    r = 0.5 * float(diameter) + float(margin) + float(sharpness)
    kappa = 2.0 / float(diameter) if kappa is None else float(kappa)
    if math.isinf(sharpness):
        chord = 0.0
    elif h >= 2 * r:
        return math.inf
    else:
        chord = r - math.sqrt(r * r - 0.25 * h * h)
    sag = (1 - math.cos(0.5 * kappa * h)) / kappa if kappa > 0 else 0.0
    return chord + sag


def sample_spacing(diameter: float, margin: float = 0.0, tol: float | None = None, kappa: float | None = None,
                   sharpness: float = 0.0) -> float:
    """Largest spacing h of center-line samples (arc length) with dip(h) <= ``tol`` (default 1e-3 D), by bisection
    on :func:`dip`; ``kappa``: largest center-line curvature (default 2/D, :func:`curvature_bound`), ``sharpness``:
    the obstacle's smallest radius of curvature (:func:`sharpness_radius`)."""
    tol = 1e-3 * diameter if tol is None else float(tol)
    lo, hi = 0.0, 2 * (0.5 * diameter + margin + (0.0 if math.isinf(sharpness) else sharpness))
    if math.isinf(sharpness):
        hi = 4 * diameter
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if dip(mid, diameter, margin, kappa, sharpness) <= tol:
            lo = mid
        else:
            hi = mid
    return lo


# ------------------------------------------------------------------ sampling the model


def sample_chain(routing: Routing, diameter: float, per_segment=DEFAULT_PER_SEGMENT) -> dict:
    """Center line of ``routing`` at ``per_segment`` (int or (M,) ints; default 20, as the obstacle goals are
    checked) equal pieces of every segment, base to tip: dict(points (P, 3), s (actuated arc length), l (material
    coordinate), seg, frac, tangent (P, 3)), the segment ends included, P = sum(per_segment) + 1."""
    D = float(diameter)
    th, lam, ln = routing.theta, routing.lam, routing.length
    seg, frac = segment_end_samples(ln, per_segment)
    frames = chain_frames(th, lam, ln, D, routing.initial_pose)
    pts, rot = chain_points(th, lam, ln, D, seg, frac, routing.initial_pose, frames=frames)
    _, _, lc = center_rates(th, lam, D)
    arc = ln * lc
    s = np.concatenate([[0.0], np.cumsum(arc)])[seg] + frac * arc[seg]
    l = np.concatenate([[0.0], np.cumsum(ln)])[seg] + frac * ln[seg]
    return {"points": pts, "s": s, "l": l, "seg": seg, "frac": frac, "tangent": rot[:, :, 0]}


class ModelLine:
    """Exact center-line points of a routing at material coordinates l (for refinement)."""

    def __init__(self, routing, D):
        self.r, self.D = routing, D
        self.cum = np.concatenate([[0.0], np.cumsum(routing.length)])
        _, _, lc = center_rates(routing.theta, routing.lam, D)
        self.cum_s = np.concatenate([[0.0], np.cumsum(routing.length * lc)])
        self.frames = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)

    def locate(self, l):
        l = np.clip(np.asarray(l, float).reshape(-1), 0.0, self.cum[-1])
        seg = np.clip(np.searchsorted(self.cum, l, side="right") - 1, 0, self.r.segments - 1)
        return seg, (l - self.cum[seg]) / self.r.length[seg]

    def points(self, l):
        """(P, 3) center-line points at material lengths ``l`` (clipped to the tube), one chain evaluation."""
        seg, frac = self.locate(l)
        r = self.r
        return chain_points(r.theta, r.lam, r.length, self.D, seg, frac, r.initial_pose, frames=self.frames)[0]

    def arc(self, l):
        seg, frac = self.locate(l)
        return self.cum_s[seg] + frac * (self.cum_s[seg + 1] - self.cum_s[seg])


def grown_prefixes(routing: Routing, diameter: float, lengths, per_segment=DEFAULT_PER_SEGMENT) -> list[dict]:
    """Bodies grown while actuated to material lengths ``lengths``: prefixes of the final center line.

    Each: dict(length, points, s, l): the final shape's samples with l < length plus the exact point at l = length.
    Every prefix is a subset of the final line, so its gap to any obstacle is >= the final shape's (module docstring)."""
    D = float(diameter)
    full = sample_chain(routing, D, per_segment)
    model = ModelLine(routing, D)
    out = []
    for Lg in np.atleast_1d(np.asarray(lengths, float)):
        Lg = float(min(max(Lg, 0.0), model.cum[-1]))
        keep = full["l"] < Lg
        out.append({"length": Lg, "points": np.vstack([full["points"][keep], model.points([Lg])]),
                    "s": np.append(full["s"][keep], np.interp(Lg, model.cum, model.cum_s)), "l": np.append(full["l"][keep], Lg)})
    return out


def after_growth_routing(routing: Routing, t: float) -> Routing:
    """The intermediate routing of actuation after growth: lambda_t = 1 - t (1 - lambda), theta fixed."""
    return Routing(theta=routing.theta, lam=1.0 - float(t) * (1.0 - routing.lam), length=routing.length, initial_pose=routing.initial_pose)


def after_growth_shapes(routing: Routing, diameter: float, ts=None, per_segment=DEFAULT_PER_SEGMENT) -> list[dict]:
    """Center lines of the intermediate shapes of actuation after full growth, one dict(t, routing (lambda_t =
    1 - t (1 - lambda)), points, s, l) per actuation fraction t of ``ts`` (default 0, 1/20, ..., 1; t = 0 is the
    unactuated straight tube, t = 1 the final shape)."""
    ts = np.linspace(0.0, 1.0, DEFAULT_AFTER_STEPS + 1) if ts is None else np.atleast_1d(np.asarray(ts, float))
    out = []
    for t in ts:
        rt = after_growth_routing(routing, t)
        smp = sample_chain(rt, diameter, per_segment)
        out.append({"t": float(t), "routing": rt, **{k: smp[k] for k in ("points", "s", "l")}})
    return out


# ------------------------------------------------------------------ report


def _runs(mask) -> list[tuple[int, int]]:
    """Runs of True in a boolean array as (first, last) index pairs."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


REFINE_GRID = 17  # points per bracket and round of the refined minima
REFINE_ROUNDS = 8  # each round shrinks every bracket 8-fold: 8 rounds leave ~1e-7 of two sample spacings


def _refined_minima(model: ModelLine, obstacles, l, gaps) -> list[tuple[float, float]]:
    """Per obstacle, (gap, material length) of the minimum of the gap over the material interval around its
    smallest sample: a grid search whose bracket shrinks round by round to the best point's neighbours, every
    obstacle's grid in one chain evaluation per round (a search per obstacle, point by point, paid the chain's
    evaluation for every point). Never above the smallest sample."""
    n = len(l)
    idx = np.argmin(gaps, axis=0)
    best = [(float(gaps[i, k]), float(l[i])) for k, i in enumerate(idx)]
    lo = np.array([l[max(i - 1, 0)] for i in idx], float)
    hi = np.array([l[min(i + 1, n - 1)] for i in idx], float)
    live = np.flatnonzero(hi > lo)
    u = np.linspace(0.0, 1.0, REFINE_GRID)
    for _ in range(REFINE_ROUNDS):
        if live.size == 0:
            break
        x = lo[live, None] + (hi - lo)[live, None] * u  # (K, G)
        pts = model.points(x).reshape(live.size, REFINE_GRID, 3)
        for m, k in enumerate(live):
            f = np.asarray(obstacles[k].distance(pts[m]), float).reshape(-1) - 0.5 * model.D
            b = int(np.argmin(f))
            if f[b] < best[k][0]:
                best[k] = (float(f[b]), float(x[m, b]))
            lo[k], hi[k] = x[m, max(b - 1, 0)], x[m, min(b + 1, REFINE_GRID - 1)]
    return best


def _shape_gaps(routing, D, obstacles, margin, smp, refine) -> list[dict]:
    gaps = min_gap(smp["points"], D, obstacles)
    model = ModelLine(routing, D)
    cum_l, cum_s = model.cum, model.cum_s
    out = []
    refined = _refined_minima(model, obstacles, smp["l"], gaps) if refine and len(obstacles) else None
    for k, ob in enumerate(obstacles):
        g = gaps[:, k]
        i = int(np.argmin(g))
        gmin, lmin = refined[k] if refine else (float(g[i]), float(smp["l"][i]))
        contacts = []
        for a, b in _runs(g < margin):
            j = a + int(np.argmin(g[a:b + 1]))
            contacts.append({"s": (float(smp["s"][a]), float(smp["s"][b])), "l": (float(smp["l"][a]), float(smp["l"][b])),
                             "min_gap": float(g[j]), "at_s": float(smp["s"][j])})
        s_min = float(np.interp(lmin, cum_l, cum_s))
        if refine and contacts == [] and gmin < margin:  # the refined minimum dips below the margin between two samples
            contacts.append({"s": (s_min, s_min), "l": (lmin, lmin), "min_gap": gmin, "at_s": s_min})
        out.append({"index": k, "kind": ob.kind, "name": ob.name, "min_gap": gmin, "l": lmin, "s": s_min, "gaps": g, "contacts": contacts})
    return out


def obstacle_report(routing: Routing, diameter: float, obstacles, growth: str = "while-actuated", margin: float = 0.0,
                    per_segment=DEFAULT_PER_SEGMENT, ts=None, refine: bool = True) -> dict:
    """Distance from the tube to every obstacle along the tube, and the contacts (runs of samples with gap < ``margin``).

    Final shape: sampled at ``per_segment`` points per segment, each obstacle's minimum refined on the continuous model
    (``refine``: a bounded 1-D search around the smallest sample). Intermediate shapes: grown while actuated they are
    prefixes (covered by the final shape; each obstacle's ``first_contact_length`` is the material length grown when its
    first contact appears); with ``growth`` "after", the shapes lambda_t on the grid ``ts`` (default 21 values of t) are
    checked at the samples.

    Returns
    -------
    dict
        growth, margin, final: list per obstacle of dict(index, kind, name, min_gap, s, l (where), gaps (P,) per sample,
        contacts: list of dict(s (from, to), l (from, to), min_gap, at_s))), s (P,), l (P,) the final samples, min_gap
        (over all obstacles, final shape; inf without obstacles), intermediate: while-actuated: list per obstacle of
        dict(index, min_gap, first_contact_length); after: dict(t (T,), gaps (T, K) per-shape minima, worst: list per
        obstacle of dict(index, min_gap, t, s, l), contacts: list per t of the per-obstacle contact lists),
        min_gap_intermediate, clear (every gap >= margin - 1e-3 D, final and intermediate).

    Raises
    ------
    ValueError
        ``growth`` is not one of GROWTH_MODES.
    """
    if growth not in GROWTH_MODES:
        raise ValueError(f"growth must be one of {GROWTH_MODES}, not {growth!r}")
    D = float(diameter)
    smp = sample_chain(routing, D, per_segment)
    final = _shape_gaps(routing, D, obstacles, margin, smp, refine)
    gmin = min((f["min_gap"] for f in final), default=math.inf)
    out = {"growth": growth, "margin": float(margin), "final": final, "s": smp["s"], "l": smp["l"], "min_gap": gmin}
    if growth == "while-actuated":
        out["intermediate"] = [{"index": f["index"], "min_gap": f["min_gap"],
                                "first_contact_length": (f["contacts"][0]["l"][0] if f["contacts"] else None)} for f in final]
        out["min_gap_intermediate"] = gmin
    else:
        shapes = after_growth_shapes(routing, D, ts, per_segment)
        T, K = len(shapes), len(obstacles)
        gaps = np.empty((T, K))
        worst = [{"index": k, "min_gap": math.inf, "t": None, "s": None, "l": None} for k in range(K)]
        contacts = []
        for a, sh in enumerate(shapes):
            per = final if sh["t"] == 1.0 else _shape_gaps(sh["routing"], D, obstacles, margin, sh, False)
            contacts.append([p["contacts"] for p in per])
            for k, p in enumerate(per):
                gaps[a, k] = p["min_gap"]
                if p["min_gap"] < worst[k]["min_gap"]:
                    worst[k].update(min_gap=p["min_gap"], t=sh["t"], s=p["s"], l=p["l"])
        out["intermediate"] = {"t": np.array([sh["t"] for sh in shapes]), "gaps": gaps, "worst": worst, "contacts": contacts}
        out["min_gap_intermediate"] = float(gaps.min()) if gaps.size else math.inf
    out["clear"] = bool(min(gmin, out["min_gap_intermediate"]) >= margin - 1e-3 * D)
    return out


def obstacle_metrics(report: dict) -> dict:
    """The run's metrics attributes of an :func:`obstacle_report`: ``min_obstacle_gap`` (final shape,
    formats.md), and with growth "after" also ``min_obstacle_gap_after`` (smallest over the intermediate shapes)."""
    out = {"min_obstacle_gap": float(report["min_gap"])}
    if report["growth"] == "after":
        out["min_obstacle_gap_after"] = float(report["min_gap_intermediate"])
    return out


def report_rows(report: dict) -> list[dict]:
    """One flat row per obstacle (index, kind, name, min_gap, s, contacts, and for growth "after"
    min_gap_after, t_worst): for tables (``vine-nlp analyze``)."""
    rows = []
    for f in report["final"]:
        row = {"index": f["index"], "kind": f["kind"], "name": f["name"], "min_gap": f["min_gap"], "s": f["s"],
               "contacts": len(f["contacts"])}
        inter = report["intermediate"]
        if report["growth"] == "after":
            w = inter["worst"][f["index"]]
            row.update(min_gap_after=w["min_gap"], t_worst=w["t"])
        else:
            row.update(first_contact_length=inter[f["index"]]["first_contact_length"])
        rows.append(row)
    return rows
