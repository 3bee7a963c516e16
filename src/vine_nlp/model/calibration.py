"""The systematic construction errors of one construction method (``vine-nlp calibrate``), as a value type.

A design problem may carry one (``[calibration]`` or ``calibration = "CAL.toml"``): the design is then made for the
robot as it actually gets built. The design method designs as usual (what the robot should realize); the nominal to
build is that design with the systematic parts taken out (:func:`nominal_of`, applied by the pipeline)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vine_nlp.model.routing import TOP, Routing, actuated, built_lambda


@dataclass(frozen=True)
class Calibration:
    """Built = nominal + offsets, lengths times the scale (the contract's deviation rule, shared by all segments;
    lambda by the physical rule).

    Attributes
    ----------
    lambda_offset, theta_offset_deg
        Built minus nominal (theta in degrees).
    length_scale
        Built over nominal length (> 0).
    lambda_offset_se, theta_offset_deg_se, length_scale_se
        Their standard errors.
    prototypes
        How many builds they come from.
    """

    lambda_offset: float = 0.0
    theta_offset_deg: float = 0.0
    length_scale: float = 1.0
    lambda_offset_se: float = 0.0
    theta_offset_deg_se: float = 0.0
    length_scale_se: float = 0.0
    prototypes: int = 0

    def __post_init__(self):
        vals = (self.lambda_offset, self.theta_offset_deg, self.length_scale, self.lambda_offset_se, self.theta_offset_deg_se,
                self.length_scale_se)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("calibration values must be finite")
        if not self.length_scale > 0:
            raise ValueError("length_scale must be > 0")

    @property
    def theta_offset(self) -> float:
        return math.radians(self.theta_offset_deg)


def nominal_of(realized: Routing, cal: Calibration, theta_max: float, lambda_min: float) -> tuple[Routing, int]:
    """The nominal that realizes ``realized`` under ``cal`` (the physical rule: no actuator where lambda is 1, an
    actuator's nominal below 1), theta clipped to the builder's bounds; (nominal, clipped count)."""
    theta = realized.theta - cal.theta_offset
    t2 = np.clip(theta, -theta_max, theta_max)
    act, lam = actuated(realized.lam), realized.lam - cal.lambda_offset
    l2 = np.where(act, np.minimum(lam, TOP), 1.0)
    clipped = int(np.sum(t2 != theta) + np.sum(act & (l2 != lam)))
    return Routing(theta=t2, lam=l2, length=realized.length / cal.length_scale, initial_pose=realized.initial_pose), clipped


def realized_of(nominal: Routing, cal: Calibration, lambda_min: float = 0.0) -> Routing:
    """What a nominal realizes under ``cal`` (the physical rule, model.routing.built_lambda)."""
    return Routing(theta=nominal.theta + cal.theta_offset, lam=built_lambda(nominal.lam, cal.lambda_offset, lambda_min),
                   length=nominal.length * cal.length_scale, initial_pose=nominal.initial_pose)
