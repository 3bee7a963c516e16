"""What a lab builds from a routing: where the actuator is, how far its line turns, the smallest feature, and
the parts to make per actuator kind (issue 31).

A segment with lambda exactly 1 has no actuator (no stopper, pouch or pinch); runs of segments with and
without one are the actuated and unactuated *pieces*. The line turns by dphi_j = (2/D) tan(theta_j) dl_j on
segment j; where lambda is 1 this only moves the line around a straight tube, and what the routing needs
there is the change of side from one actuated piece to the next, the shortest way round (and, with a
fixed base, from the base to the first piece).

Features follow the template's geometry (``gap_fractions``, drawn by front/template.py): an actuated segment's
path, dl / cos(theta) long, holds a centred gap (stopper gap, or pinch) of 1 - lambda of it; the stoppers
between gaps join across segment ends. Where a gap alone would be shorter than min_feature, the gaps of
partners (segments start + 2i and start + 2i + 1 of an actuated piece) merge into one at their common end
(each segment keeps its own contraction). Pouches (sPAM) follow the ideal pouch motor (Niiyama et al.,
2015): a flat pouch of length L0 inflates to arc faces of half angle a and contracts to L0 sin(a) / a, so
lambda >= 2 / pi; a piece's path is split into pouches about POUCH_LENGTH_D tube diameters long.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vine_nlp.model.chain import phi_from_theta
from vine_nlp.model.routing import actuated
from vine_nlp.model.units import MM_PER_UNIT, mm_per_unit  # noqa: F401  MM_PER_UNIT: for the importers from here

MIN_FEATURE_MM = 2.0  # the template's precision: a feature printed 1:1 and cut by hand, below 2 mm, is not built to 10 %
POUCH_LAMBDA_MIN = 2.0 / math.pi  # the ideal pouch motor's full contraction (a = pi / 2)
POUCH_LENGTH_D = 1.0
GAP_NAMES = {"tendon": ("stopper gap", "stopper"), "programmed": ("pinch", "unpinched part")}


def default_min_feature(units: str) -> float:
    """MIN_FEATURE_MM in ``units`` (0: no check, for units other than mm, cm, m, in)."""
    mm = mm_per_unit(units)
    return MIN_FEATURE_MM / mm if mm else 0.0


def wrap_angle(a):
    """Angles wrapped into [-pi, pi): the shortest way round."""
    return (np.asarray(a, float) + math.pi) % (2 * math.pi) - math.pi


def pouch_angle(lam: float) -> float:
    """The half angle a of an ideal pouch contracting to ``lam`` (sin(a) / a = lam; bisection), in [0, pi/2]."""
    lo, hi = 0.0, math.pi / 2
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if math.sin(mid) / mid > lam else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Piece:
    """Segments ``start`` to ``stop - 1``, all with an actuator or all without; s along the tube, path along the line."""

    start: int
    stop: int
    actuated: bool
    s0: float
    s1: float
    path: float


def pieces(actuated, length, path) -> list[Piece]:
    """Runs of segments with (``actuated``) and without an actuator."""
    act = np.asarray(actuated, bool)
    S, P = np.concatenate([[0.0], np.cumsum(length)]), np.concatenate([[0.0], np.cumsum(path)])
    cuts = [0, *(np.flatnonzero(np.diff(act)) + 1).tolist(), act.size]
    return [Piece(a, b, bool(act[a]), float(S[a]), float(S[b]), float(P[b] - P[a])) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def partners(actuated) -> np.ndarray:
    """Each segment's gap partner (start + 2i with start + 2i + 1 of an actuated piece), -1 where none."""
    act = np.asarray(actuated, bool)
    out = np.full(act.size, -1)
    for p in pieces(act, np.ones(act.size), np.ones(act.size)):
        if p.actuated:
            first = np.arange(p.start, p.stop - 1, 2)
            out[first], out[first + 1] = first + 1, first
    return out


def gap_fractions(lam, path, min_feature: float = 0.0) -> np.ndarray:
    """(M, 2): where each segment's gap lies along its path, fractions (t0, t1); NaN where there is no actuator.
    Centred, or at the common end of partners where either gap alone would be shorter than min_feature."""
    lam, path = np.asarray(lam, float), np.asarray(path, float)
    out = np.column_stack([0.5 * lam, 1 - 0.5 * lam])
    out[lam == 1.0] = np.nan
    mate = partners(lam != 1.0)
    for j in np.flatnonzero(mate > np.arange(lam.size)):
        if min((1 - lam[j]) * path[j], (1 - lam[j + 1]) * path[j + 1]) < min_feature:
            out[j], out[j + 1] = (lam[j], 1.0), (0.0, 1 - lam[j + 1])
    return out


def turning(theta, length, D: float, actuated, base_free: bool = True) -> tuple[float, float, float]:
    """(total, on unactuated segments, needed there) turning sum |dphi| of the actuator line, rad."""
    phi = phi_from_theta(theta, length, D)
    dphi, act = np.diff(phi), np.asarray(actuated, bool)
    on = [p for p in pieces(act, length, length) if p.actuated]
    ends = ([0] if on and not base_free else []) + [p.stop for p in on[:-1]]
    starts = ([on[0].start] if on and not base_free else []) + [p.start for p in on[1:]]
    needed = float(np.abs(wrap_angle(phi[starts] - phi[ends])).sum()) if starts else 0.0
    return float(np.abs(dphi).sum()), float(np.abs(dphi[~act]).sum()), needed


TURN_TOL = 1e-3  # rad: turning where lambda is 1 beyond what the routing needs there (rounding of the shortest way)


def digits(v: float, other: float) -> str:
    """``v`` to 6 digits, or to as many more as it takes to tell it from ``other`` (0.199999 is not 0.2)."""
    for p in range(6, 18):
        if v == other or f"{v:.{p}g}" != f"{other:.{p}g}":
            return f"{v:.{p}g}"
    return repr(v)


@dataclass
class Report:
    """A routing's buildability (lengths in the routing's units, angles in rad); see ``buildability``."""

    kind: str
    pieces: list
    turning: float  # the line's total turning, sum |dphi|
    turning_unactuated: float  # of it, on segments with lambda = 1
    turning_needed: float  # what the routing needs there
    violations: list  # segments with lambda neither 1 nor inside [lambda_min + margin, 1 - margin]
    features: list  # (length, name, segment or piece index)
    min_feature: float
    parts: dict = field(default_factory=dict)  # per actuator kind, see ``buildability``
    refused: list = field(default_factory=list)  # why a part cannot be made (pouches beyond 2 / pi)

    @property
    def smallest(self):
        """The shortest feature (length, name, index), or None."""
        return min(self.features, default=None)

    @property
    def below(self) -> list:
        """Features shorter than ``min_feature``."""
        return [f for f in self.features if f[0] < self.min_feature - 1e-12]

    def missed(self, lambda_lo: float, lambda_hi: float, units: str = "", band: str = "correction margin") -> list[str]:
        """The buildable rules this report misses, one line each: lambda exactly 1 or inside [lambda_lo, lambda_hi] (an
        actuator that barely contracts is not exactly 1; ``band`` names that range), the smallest feature at least
        min_feature (to the last digit), no turning of the line where lambda is 1 beyond what the routing needs there,
        pouches that can be made."""
        out, u = [], f" {units}" if units else ""
        if self.violations:
            v = self.violations
            out.append(f"{len(v)} segment(s) with lambda neither 1 nor in [{lambda_lo:.6g}, {lambda_hi:.6g}] ({band}; "
                       f"segments {', '.join(map(str, v[:8]))}{', ...' if len(v) > 8 else ''})")
        if self.below:
            length, name, _ = self.smallest
            out.append(f"{len(self.below)} feature(s) below min_feature {digits(self.min_feature, length)}{u} "
                       f"(smallest: {digits(length, self.min_feature)}{u} {name})")
        extra = self.turning_unactuated - self.turning_needed
        if extra > TURN_TOL:
            out.append(f"the actuator line turns {self.turning_unactuated / (2 * math.pi):.3g} turn(s) where lambda = 1, "
                       f"the routing needs {self.turning_needed / (2 * math.pi):.3g} there (pointless turning)")
        out += [f"pouch refused: {r}" for r in self.refused]
        return out


def buildability(routing, D: float, kind: str = "tendon", lambda_min: float = 0.4, margin: float = 0.05,
                 min_feature: float = 0.0, base_free: bool = True) -> Report:
    """The buildability report of ``routing`` (per-segment theta, lam, length) on a tube of diameter D.

    ``parts``: "stoppers" (tendon: (start, end) along the line from the base, one per stopper, joined across
    segments), "tendons" (tendon: each actuated piece's line length), "pinches" (programmed: (start, end)),
    "pouches" (spam: per actuated piece (count, length L0, half angle a), or None where refused).
    """
    theta, lam, length = (np.asarray(v, float) for v in (routing.theta, routing.lam, routing.length))
    path = length / np.cos(theta)
    act = lam != 1.0
    ps = pieces(act, length, path)
    total, free, needed = turning(theta, length, D, act, base_free)
    ok = ~act | ((lam >= lambda_min + margin - 1e-9) & (lam <= 1 - margin + 1e-9))
    features = [(p.s1 - p.s0, "actuated piece" if p.actuated else "unactuated piece", k) for k, p in enumerate(ps)]
    report = Report(kind, ps, total, free, needed, np.flatnonzero(~ok).tolist(), features, min_feature)
    P = np.concatenate([[0.0], np.cumsum(path)])
    if kind == "spam":
        _pouches(report, lam, path, D)
        return report
    gap_name, stopper_name = GAP_NAMES.get(kind, GAP_NAMES["tendon"])
    f = gap_fractions(lam, path, min_feature)
    gaps = []  # (start, end, first segment) along the line; partners' touching gaps are one
    for j in np.flatnonzero(act):
        a, b = P[j] + f[j, 0] * path[j], P[j] + f[j, 1] * path[j]
        if gaps and abs(gaps[-1][1] - a) < 1e-12:
            a, j = gaps.pop()[::2]
        gaps.append((float(a), float(b), int(j)))
    features += [(b - a, gap_name, j) for a, b, j in gaps]
    stoppers = []
    for p in (p for p in ps if p.actuated):
        edges = [P[p.start]] + [v for a, b, j in gaps if p.start <= j < p.stop for v in (a, b)] + [P[p.stop]]
        stoppers += [(float(a), float(b)) for a, b in zip(edges[::2], edges[1::2]) if b - a > 1e-12]
    starts = np.searchsorted(P, [a for a, _ in stoppers], side="right") - 1  # the segment each stopper starts in
    features += [(b - a, stopper_name, int(j)) for (a, b), j in zip(stoppers, starts)]
    if kind == "programmed":
        report.parts["pinches"] = [(float(a), float(b)) for a, b, _ in gaps]
    else:
        report.parts["stoppers"] = stoppers
        report.parts["tendons"] = [p.path for p in ps if p.actuated]
    return report


def correction_missed(nominal, built_lam, D: float, kind: str = "tendon", lambda_min: float = 0.4, min_feature: float = 0.0,
                      units: str = "") -> list[str]:
    """The buildable rules for a correction's new ``nominal`` of a robot built from a nominal with lambda ``built_lam``,
    one line each. A correction spends the correction margin (that is what it is for), and no actuator can be added
    to a built robot: lambda exactly 1 where the robot has none (model.routing.actuated), within [lambda_min, 1]
    elsewhere; min_feature and no pointless turning as for every design (the robot's base stays where it was built:
    the line's turning from it to the first actuated piece is needed)."""
    out = buildability(nominal, D, kind, lambda_min, 0.0, min_feature, base_free=False).missed(lambda_min, 1.0, units, "the actuator's range")
    added = np.flatnonzero(~actuated(built_lam) & (np.asarray(nominal.lam, float) != 1.0))
    if added.size:
        out.insert(0, f"{added.size} segment(s) with an actuator where the robot has none (lambda exactly 1 there; segments "
                      f"{', '.join(map(str, added[:8]))}{', ...' if added.size > 8 else ''})")
    return out


def _pouches(report: Report, lam, path, D: float) -> None:
    """Pouches of each actuated piece (ideal pouch motor); lambda beyond its range is refused with the reason."""
    out = []
    for k, p in enumerate(report.pieces):
        if not p.actuated:
            continue
        piece_lam = float(np.dot(lam[p.start:p.stop], path[p.start:p.stop]) / p.path)
        if piece_lam < POUCH_LAMBDA_MIN - 1e-12:
            report.refused.append(f"piece {k} (segments {p.start}-{p.stop - 1}): lambda {piece_lam:.3g} is below the ideal pouch "
                                  f"motor's 2/pi = {POUCH_LAMBDA_MIN:.3f}: no pouch contracts that far")
            out.append(None)
            continue
        count = max(1, round(p.path / (POUCH_LENGTH_D * D)))
        out.append((count, p.path / count, pouch_angle(piece_lam)))
        report.features.append((p.path / count, "pouch", k))
    report.parts["pouches"] = out
