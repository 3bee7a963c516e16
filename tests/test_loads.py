"""Self-weight and payload (issue 45): the mechanics against closed forms and an independent sum, [load]
files, the judgement and the design with the load rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vine_nlp.analysis.loads import METRES_PER_UNIT, _samples, load_report
from vine_nlp.model.routing import Routing
from vine_nlp.problem import Load


def _tilted(alpha_deg: float, L: float, M: int = 8) -> Routing:
    """A straight tube of length L along (cos a, 0, sin a)."""
    a = math.radians(alpha_deg)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]]
    return Routing(np.zeros(M), np.ones(M), np.full(M, L / M), T)


@pytest.mark.parametrize("alpha,w,m", [(0.0, 0.03, 0.0), (30.0, 0.05, 0.02), (-45.0, 0.0, 0.1), (70.0, 0.2, 0.05), (0.0, 0.04, 0.01)])
@pytest.mark.parametrize("units", ["cm", "m"])
def test_straight_cantilever_closed_form(alpha, w, m, units):
    """Margin and least pressure of a straight cantilever: w L^2 / 2 + m g L (times cos of the tilt) against pi P r^3."""
    k = METRES_PER_UNIT[units]
    L, D, P, safety = 1.2 / k, 0.05 / k, 4.0, 1.5
    load = Load(pressure=P, mass_per_length=w, tip_mass=m, safety=safety)
    rep = load_report(_tilted(alpha, L), D, units, load)
    g, Lm = 9.81, L * k
    moment = (w * g * Lm**2 / 2 + m * g * Lm) * math.cos(math.radians(alpha))
    capacity = math.pi * P * 1e3 * (D * k / 2) ** 3
    assert rep["margin"] == pytest.approx(capacity / moment, rel=1e-3)
    assert rep["min_pressure"] == pytest.approx(P * safety * moment / capacity, rel=1e-3)
    assert rep["collapse_at"] == pytest.approx(0.0, abs=1e-9)  # the base carries the most
    assert rep["holds"] == (capacity / moment >= safety)


def test_standing_straight_up_carries_no_moment():
    rep = load_report(_tilted(90.0, 100.0), 5.0, "cm", Load(pressure=1.0, mass_per_length=1.0, tip_mass=1.0, safety=2.0))
    assert rep["margin"] == math.inf and rep["min_pressure"] == 0.0 and math.isnan(rep["collapse_at"]) and rep["holds"]


def _curved() -> Routing:
    rng = np.random.default_rng(3)
    M = 6
    T = np.eye(4)
    T[:3, :3] = [[0.8, 0, -0.6], [0, 1, 0], [0.6, 0, 0.8]]
    return Routing(rng.uniform(-0.6, 0.6, M), np.array([1, 0.7, 0.9, 1, 0.5, 0.8]), rng.uniform(8, 15, M), T)


def test_moment_along_a_curved_shape_matches_an_independent_sum():
    """The report's moment (20 samples per segment, pieces at their chord middles) against a plain double sum
    over 400 points per segment (point masses by the trapezoid rule), at the segment ends, within 0.1 %."""
    r, D, units = _curved(), 3.0, "cm"
    load = Load(pressure=5.0, mass_per_length=0.08, tip_mass=0.03, gravity=(0.0, -2.0, -9.81), safety=1.0)
    rep = load_report(r, D, units, load, growth="after")  # the final shape's moment
    pts, t, s, l, _ = _samples(r, D, 400)
    pts, l = pts * 0.01, l * 0.01
    g = np.array(load.gravity)
    dm = load.mass_per_length * np.gradient(l) * 1.0
    dm[[0, -1]] = load.mass_per_length * np.diff(l)[[0, -1]] / 2  # trapezoid weights
    ends = np.arange(0, len(pts), 400)
    expect = []
    for k in ends:
        Mk = np.zeros(3)
        for i in range(k, len(pts)):
            Mk += np.cross(pts[i] - pts[k], dm[i] * g)
        Mk += np.cross(pts[-1] - pts[k], load.tip_mass * g)
        expect.append(np.linalg.norm(Mk - Mk.dot(t[k]) * t[k]))
    got = rep["moment"][np.arange(0, len(rep["s"]), 20)]
    assert got == pytest.approx(np.array(expect), rel=1e-3)
    assert np.all(got[:-1] > 0)


def test_growth_prefix_loads_more_than_the_final_shape():
    """A tube that reaches out and turns back up: grown part way, with the payload at its tip far out, the
    base carries more than at the end (the tip mass back over the base)."""
    M = 10
    theta = np.zeros(M)
    lam = np.r_[np.ones(5), np.full(5, 0.55)]
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # the actuator on top: the second half curls up and back
    r = Routing(theta, lam, np.full(M, 10.0), T)
    load = Load(pressure=3.0, mass_per_length=0.01, tip_mass=0.2, safety=1.0)
    rep = load_report(r, 4.0, "cm", load)
    after = load_report(r, 4.0, "cm", load, growth="after")
    assert np.all(rep["moment_growth"] >= rep["moment"] - 1e-12)
    assert rep["moment_growth"][0] > 1.05 * rep["moment"][0]
    # one of the base's prefixes: 50 cm of straight reach with the payload at its end
    assert rep["moment_growth"][0] >= 9.81 * (0.01 * 0.5**2 / 2 + 0.2 * 0.5) * (1 - 1e-9)
    # actuated after growth: the straight metre grown first, payload at its end
    assert after["moment_growth"][0] == pytest.approx(9.81 * (0.01 * 1.0**2 / 2 + 0.2 * 1.0), rel=1e-3)
