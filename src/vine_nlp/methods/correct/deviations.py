"""Deviations, the contract's rule (spec/formats.md, "As-built correction"): what stays with a robot from build to build.

A robot built from the nominal (theta, lam, length) realizes (theta_ab, lam_ab, length_ab). The deviations
d_theta = theta_ab - theta, d_lam = lam_ab - lam and the length ratio r = length_ab / length stay with the
robot: built from nominal (theta', lam', length') it realizes (theta' + d_theta, lam' + d_lam, length' r).
The estimate and the correction use them only through these functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vine_nlp.model.routing import Routing


@dataclass(frozen=True)
class Deviations:
    """What stays with the robot from build to build: theta and lambda differences, length ratios (M,)."""

    theta: np.ndarray
    lam: np.ndarray
    length_ratio: np.ndarray


def deviations_of(nominal: Routing, as_built: Routing) -> Deviations:
    """The deviations of ``as_built`` from the ``nominal`` it was built from."""
    return Deviations(as_built.theta - nominal.theta, as_built.lam - nominal.lam, as_built.length / nominal.length)


def apply_deviations(nominal: Routing, dev: Deviations) -> Routing:
    """What a robot with deviations ``dev`` realizes when built from ``nominal`` (contract's rule)."""
    return Routing(nominal.theta + dev.theta, nominal.lam + dev.lam, nominal.length * dev.length_ratio, nominal.initial_pose)


def remove_deviations(as_built: Routing, dev: Deviations) -> Routing:
    """The nominal that realizes ``as_built`` on a robot with deviations ``dev``."""
    return Routing(as_built.theta - dev.theta, as_built.lam - dev.lam, as_built.length / dev.length_ratio, as_built.initial_pose)
