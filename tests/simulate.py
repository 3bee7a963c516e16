"""Simulated builds for tests and benchmarks: random deviations, and the points a robot built with them shows.

Builds obey the physical rule (spec "Physical builds", methods.correct.apply_deviations): no lambda error where the
nominal has no actuator (lambda 1), elsewhere the built lambda within [lambda_min, 1]."""

from __future__ import annotations

import numpy as np

from vine_nlp.methods.correct.deviations import Deviations, apply_deviations
from vine_nlp.methods.correct.pairing import LINE_SIDE, line_points
from vine_nlp.model.routing import Routing, Sigmas


def simulate_build(nominal: Routing, dev: Deviations, D: float, line: str = "outer", count: int = 300, noise: float = 0.0,
                   seed: int = 0) -> np.ndarray:
    """Measured points of the robot ``nominal`` with deviations ``dev`` (the physical rule): ``count`` points equally spaced in
    material coordinate along ``line``, Gaussian noise of standard deviation ``noise`` (problem units) per
    coordinate, shuffled (measurements come in any order)."""
    built = apply_deviations(nominal, dev)
    cum = np.concatenate([[0.0], np.cumsum(built.length)])
    l = np.linspace(0.0, cum[-1], count)
    j = np.clip(np.searchsorted(cum, l, side="right") - 1, 0, built.segments - 1)
    f = np.clip((l - cum[j]) / built.length[j], 0.0, 1.0)
    P, _ = line_points(built, D, j, f, LINE_SIDE[line])
    rng = np.random.default_rng(seed)
    P = P + noise * rng.standard_normal(P.shape)
    return P[rng.permutation(count)]


def draw_deviations(nominal: Routing, sigmas: Sigmas, systematic=(0.0, 0.0, 0.0), seed: int = 0, D: float = 1.0,
                    lambda_min: float = 0.4) -> Deviations:
    """Random deviations: independent per-segment errors at ``sigmas`` plus the ``systematic`` parts
    (theta offset rad, lambda offset, length scale factor); relative length errors multiply. ``lambda_min``: the
    actuator's (the built lambda's floor; the default of a tendon)."""
    rng = np.random.default_rng(seed)
    M = nominal.segments
    e = rng.standard_normal((M, 3))
    sl = sigmas.length if sigmas.relative_length else sigmas.length / nominal.length
    return Deviations(systematic[0] + sigmas.theta * e[:, 0], systematic[1] + sigmas.lam * e[:, 1],
                      systematic[2] * (1.0 + sl * e[:, 2]), lambda_min)


def simulate_state(nominal, devs, D: float, active, state: str = "", line: str = "outer", count: int = 300, noise: float = 0.0,
                   seed: int = 0) -> np.ndarray:
    """``simulate_build`` of a tube of several actuators (model.actuators.Lines ``nominal``, Deviations per actuator, the
    length ratio shared) in the state whose actuators ``active`` are pulled."""
    from vine_nlp.methods.correct.several import realized
    from vine_nlp.model.actuators import state_line

    built = realized(nominal, devs)
    cum = np.concatenate([[0.0], np.cumsum(built.length)])
    l = np.linspace(0.0, cum[-1], count)
    j = np.clip(np.searchsorted(cum, l, side="right") - 1, 0, built.segments - 1)
    P, _ = state_line(built, D, active, state)(j, np.clip((l - cum[j]) / built.length[j], 0.0, 1.0), LINE_SIDE[line])
    rng = np.random.default_rng(seed)
    return (P + noise * rng.standard_normal(P.shape))[rng.permutation(count)]


def draw_line_deviations(nominal, sigmas: Sigmas, systematic=(0.0, 0.0, 0.0), seed: int = 0, lambda_min=0.4) -> list:
    """``draw_deviations`` per actuator of ``nominal`` (Lines), one length ratio for the tube."""
    devs = [draw_deviations(nominal.routing(k), sigmas, systematic, seed + 7 * k, lambda_min=lambda_min) for k in range(nominal.count)]
    return [Deviations(d.theta, d.lam, devs[0].length_ratio, d.lambda_min) for d in devs]
