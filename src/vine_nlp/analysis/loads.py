"""Self-weight and payload (issue 45): the bending moment along the tube and what its sections carry.

Mechanics (SI units throughout; lengths converted from the problem's units, :data:`METRES_PER_UNIT`):

- The tube is a cantilever clamped at its base. The moment at a section s is that of the weight beyond s
  and of the tip mass, about the section: M(s) = sum_i (c_i - r(s)) x m_i g + (r_tip - r(s)) x m_tip g. The
  weight is ``mass_per_length`` per unit of *grown* (material, unactuated) length: a contracted section is
  shorter along its center line but carries the material it grew. Each piece between two samples is a
  point mass at its chord's middle (exact for a straight piece; the pieces are 1/20 of a segment).
- Only the component of M perpendicular to the tangent bends the section; the axial component is a torsion,
  which an inflated tube carries by its hoop and axial tension and which is taken to lower no capacity
  here (assumed, not modelled). The moment of a shape is static: the shape is the model's, not deflected
  by the load (a stiff, pressurized tube; collapse is a local fold, not a large deflection).
- Capacity: an unactuated section folds at the collapse moment of an inflated beam, pi P r^3 (Comer and
  Levy 1963; r = D/2). McFarland and Coad 2023 extend the inflated-beam models to straight vine robots under
  their own weight at any launch angle; the trends their abstract reports (collapse length growing with the
  square root of P and linearly with D) are what w L^2 / 2 = pi P r^3 gives for a wall mass w proportional
  to D (their full model was not available here; it is not reproduced). A section whose actuator is contracted (lambda < 1) is already wrinkled on its actuator side; it
  is given the wrinkling-onset moment pi P r^3 / 2 (Comer and Levy: the moment at which the axial membrane
  stress P r / 2 t first vanishes on one side), whatever the direction of the load against the actuator
  and ignoring the actuator's own tension: a conservative choice (McFarland and McGuinness 2025 model
  steered robots with the measured shape and the tail tension; that model is not reproduced here).
- Growth while actuated: every grown prefix of the final shape stands too, with the tip mass riding at the
  growing tip (a payload carried while growing). Actuated after growth: the straight tube grown along the
  base tangent, then the final shape (the intermediate shapes of the actuation are not checked).

Capacity is linear in P, so the least pressure at which every section holds with the safety factor is
P * safety / margin."""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.analysis.obstacles import sample_chain
from vine_nlp.model.routing import Routing
from vine_nlp.model.units import METRES_PER_UNIT

WRINKLED = 0.5  # an actuated section's capacity, as a fraction of pi P r^3 (module docstring)
PER_SEGMENT = 20  # samples per segment of the report (as the obstacle report's)
ZERO = 1e-6  # a bending moment below this fraction of the largest possible one is none (round-off)
CHUNK = 512  # sections per block of the prefix search (memory: a few CHUNK x N arrays)


def collapse_moment(pressure_kpa: float, radius_m: float, actuated=False):
    """The moment a section carries before it folds, N m: pi P r^3, half of it where ``actuated``."""
    return math.pi * pressure_kpa * 1e3 * radius_m**3 * np.where(actuated, WRINKLED, 1.0)


def _levers(points: np.ndarray, l: np.ndarray, w: float, tip_mass: float):
    """Suffix sums of the pieces' masses and first moments: S0 (N,), S1 (N, 3) over the pieces beyond each point."""
    dm = w * np.diff(l)
    c = 0.5 * (points[1:] + points[:-1])
    S0 = np.r_[np.cumsum(dm[::-1])[::-1], 0.0]
    S1 = np.vstack([np.cumsum((dm[:, None] * c)[::-1], axis=0)[::-1], np.zeros((1, 3))])
    return S0, S1


def moments(points, l, mass_per_length: float, tip_mass: float, gravity) -> np.ndarray:
    """Moment vectors (N, 3), N m, at every point of a center line (metres) with grown lengths ``l`` (metres):
    the weight beyond each point (``mass_per_length`` kg/m) and ``tip_mass`` (kg) at the last point, gravity
    (m/s^2) in the points' frame."""
    p, l, g = np.asarray(points, float), np.asarray(l, float), np.asarray(gravity, float)
    S0, S1 = _levers(p, l, mass_per_length, tip_mass)
    return np.cross(S1 - p * S0[:, None] + tip_mass * (p[-1] - p), g)


def bending(M, tangents) -> np.ndarray:
    """|M - (M . t) t|: the part of each moment that bends its section (the rest is torsion)."""
    M, t = np.asarray(M, float), np.asarray(tangents, float)
    return np.linalg.norm(M - np.sum(M * t, axis=-1, keepdims=True) * t, axis=-1)


def prefix_bending(points, l, tangents, mass_per_length: float, tip_mass: float, gravity, section: int | None = None):
    """Growth while actuated: for every section k, the largest bending moment over the grown prefixes ending at
    a point q >= k, the tip mass at q; (moment (N,), the prefix's end q (N,)). With ``section``: that section's
    bending moment under every prefix (N,), 0 for those that end before it.

    The lever of prefix q about section k is a_k + b_q + S0_q p_k (a_k = S1_k - (S0_k + m) p_k, b_q = m p_q -
    S1_q), so |L x g|^2 - ((L x g) . t_k)^2 = |L|^2 |g|^2 - (L . g)^2 - (L . (g x t_k))^2 is a few matrix
    products: O(N^2) numbers, no N x N x 3 array."""
    p, l, g, t = (np.asarray(v, float) for v in (points, l, gravity, tangents))
    S0, S1 = _levers(p, l, mass_per_length, tip_mass)
    a, b, h = S1 - (S0 + tip_mass)[:, None] * p, tip_mass * p - S1, np.cross(g, t)
    N = p.shape[0]

    def squared(k: np.ndarray) -> np.ndarray:  # (len(k), N): sections k, every prefix end; 0 where it ends before
        ak, pk, hk = a[k], p[k], h[k]
        LL = (np.sum(ak * ak, 1)[:, None] + np.sum(b * b, 1)[None] + np.sum(pk * pk, 1)[:, None] * S0**2 + 2 * ak @ b.T
              + 2 * S0 * (np.sum(ak * pk, 1)[:, None] + pk @ b.T))
        Lg = (ak @ g)[:, None] + (b @ g)[None] + (pk @ g)[:, None] * S0
        Lh = np.sum(ak * hk, 1)[:, None] + hk @ b.T + np.sum(pk * hk, 1)[:, None] * S0
        return np.where(np.arange(N)[None] < k[:, None], 0.0, np.maximum(LL * (g @ g) - Lg**2 - Lh**2, 0.0))

    if section is not None:
        return np.sqrt(squared(np.array([section]))[0])
    best, where = np.zeros(N), np.arange(N)
    for lo in range(0, N, CHUNK):
        k = np.arange(lo, min(N, lo + CHUNK))
        b2 = squared(k)
        where[k] = np.argmax(b2, axis=1)
        best[k] = np.sqrt(b2[np.arange(k.size), where[k]])
    return best, where


def _samples(routing: Routing, D: float, per_segment: int):
    smp = sample_chain(routing, D, per_segment)
    seg, frac, act = smp["seg"], smp["frac"], routing.lam < 1.0 - 1e-9
    # a segment end belongs to both segments: the weaker one counts
    actuated = act[seg] | ((frac == 0) & act[np.maximum(seg - 1, 0)])
    return smp["points"], smp["tangent"], smp["s"], smp["l"], actuated


def load_report(routing: Routing, D: float, units: str, load, growth: str = "while-actuated", per_segment: int = PER_SEGMENT) -> dict:
    """The moments and capacities along ``routing``'s tube under ``load`` (``problem.Load``) and its figures.

    Returns dict: s (arc length, problem units), moment (the final shape's bending moment, N m), moment_growth
    (the largest over growth: prefixes while actuated, the straight tube after), capacity (N m), margin (min
    capacity / moment, inf where nothing bends), collapse_at (s of that minimum, problem units; NaN where
    inf), min_pressure (kPa: every section holds with the safety factor), holds (margin >= safety),
    growth_length (the grown length, problem units, of the prefix that loads the weakest section most), l (the
    samples' grown lengths), prefix_end (per sample, the grown length of the prefix that loads it most)."""
    k = METRES_PER_UNIT[units]
    pts, t, s, l, actuated = _samples(routing, D, per_segment)
    pts, l_m = pts * k, l * k
    w, m, g = load.mass_per_length, load.tip_mass, np.asarray(load.gravity, float)
    final = bending(moments(pts, l_m, w, m, g), t)
    if growth == "while-actuated":
        worst, end = prefix_bending(pts, l_m, t, w, m, g)
    else:  # grown straight along the base tangent, then actuated: the straight tube's moments count too
        straight = Routing(theta=np.zeros(routing.segments), lam=np.ones(routing.segments), length=routing.length, initial_pose=routing.initial_pose)
        sp, st, _, _, _ = _samples(straight, D, per_segment)
        worst, end = np.maximum(final, bending(moments(sp * k, l_m, w, m, g), st)), np.full(s.size, s.size - 1)
    cap = collapse_moment(load.pressure, 0.5 * D * k, actuated)
    scale = float(np.linalg.norm(g)) * (w * l_m[-1] + m) * max(l_m[-1], 1e-300)
    with np.errstate(divide="ignore"):
        ratio = np.where(worst > ZERO * scale, cap / np.maximum(worst, 1e-300), np.inf)
    i = int(np.argmin(ratio))
    margin = float(ratio[i])
    return {"s": s, "moment": final, "moment_growth": worst, "capacity": cap, "margin": margin,
            "collapse_at": float(s[i]) if math.isfinite(margin) else math.nan,
            "min_pressure": load.pressure * load.safety / margin, "holds": margin >= load.safety, "safety": load.safety,
            "growth_length": float(l[end[i]]), "l": l, "prefix_end": l[end], "weakest": i}


def growth_curve(routing: Routing, D: float, units: str, load, section: int, per_segment: int = PER_SEGMENT):
    """Grown while actuated: the bending moment (N m) at sample ``section`` of :func:`load_report` as the tube
    grows, (grown length (problem units), moment), from the section on."""
    k = METRES_PER_UNIT[units]
    pts, t, _, l, _ = _samples(routing, D, per_segment)
    curve = prefix_bending(pts * k, l * k, t, load.mass_per_length, load.tip_mass, np.asarray(load.gravity, float), section=section)
    return l[section:], curve[section:]


def load_metrics(rep: dict) -> dict:
    """The run metrics of a load report: load_margin, collapse_at, min_pressure."""
    return {"load_margin": rep["margin"], "collapse_at": rep["collapse_at"], "min_pressure": rep["min_pressure"]}


def fold_line(rep: dict, load, units: str) -> str:
    """The judgement's line where a tube does not hold: where it folds and the pressure it would need."""
    return (f"folds under its weight at s = {rep['collapse_at']:.4g} {units} (load margin {rep['margin']:.3g} < safety "
            f"{load.safety:g} at {load.pressure:g} kPa); it needs at least {rep['min_pressure']:.4g} kPa")
