"""Deviations, the contract's rule (spec/formats.md, "As-built correction" and "Physical builds"): what stays with a
robot from build to build.

A robot built from the nominal (theta, lam, length) realizes (theta_ab, lam_ab, length_ab). The deviations
d_theta = theta_ab - theta, d_lam = lam_ab - lam and the length ratio r = length_ab / length stay with the
robot: built from nominal (theta', lam', length') it realizes theta' + d_theta, length' r and the physical rule's
lambda (model.routing.built_lambda: 1 where lam' = 1, no actuator; min(1, lam' + d_lam), at least lambda_min,
elsewhere). The estimate, the correction and the simulated builds use them only through these functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vine_nlp.model.routing import TOP, Routing, actuated, built_lambda


@dataclass(frozen=True)
class Deviations:
    """What stays with the robot from build to build: theta and lambda differences, length ratios (M,), and the
    actuator's range floor ``lambda_min`` (no built lambda below it). ``held`` (M,) bool or None: actuators built
    at lambda 1 or indistinguishably near it, whose error beyond the clip is unknown (a lower nominal would
    realize nominal + an error no measurement has shown): a correction keeps their lambda."""

    theta: np.ndarray
    lam: np.ndarray
    length_ratio: np.ndarray
    lambda_min: float = 0.0
    held: np.ndarray | None = None


def deviations_of(nominal: Routing, as_built: Routing, lambda_min: float = 0.0) -> Deviations:
    """The deviations of ``as_built`` from the ``nominal`` it was built from (no lambda deviation without an actuator)."""
    d_lam = np.where(actuated(nominal.lam), as_built.lam - nominal.lam, 0.0)
    return Deviations(as_built.theta - nominal.theta, d_lam, as_built.length / nominal.length, lambda_min)


def apply_deviations(nominal: Routing, dev: Deviations) -> Routing:
    """What a robot with deviations ``dev`` realizes when built from ``nominal`` (the physical rule)."""
    return Routing(theta=nominal.theta + dev.theta, lam=built_lambda(nominal.lam, dev.lam, dev.lambda_min), length=nominal.length * dev.length_ratio,
                   initial_pose=nominal.initial_pose)


def remove_deviations(as_built: Routing, dev: Deviations, act) -> Routing:
    """The nominal that realizes ``as_built`` on a robot with deviations ``dev``: an actuator where ``act`` (its
    nominal at most TOP), lambda 1 (none) elsewhere."""
    lam = np.where(act, np.minimum(as_built.lam - dev.lam, TOP), 1.0)
    return Routing(theta=as_built.theta - dev.theta, lam=lam, length=as_built.length / dev.length_ratio, initial_pose=as_built.initial_pose)
