"""A discretized actuator routing and the construction errors of building one (pure value types)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# The three lines of the tube a measurement can follow (center line, actuator line, opposite line).
MEASURED_LINES = ("center", "inner", "outer")


@dataclass(frozen=True, kw_only=True)
class Routing:
    """A discretized actuator routing: one entry per segment (paper eq. phi(s_j)). Built by name only
    (``Routing(theta=..., lam=..., length=...)``): the design variables are declared in ``vine_nlp.methods.variables``.

    Parameters
    ----------
    theta : array_like, shape (M,)
        Drawn angle of the actuator per segment, rad.
    lam : array_like, shape (M,) or scalar
        Contraction ratio per segment (a scalar is repeated: an sPAM).
    length : array_like, shape (M,)
        Unactuated center-line length of each segment.
    initial_pose : array_like, shape (4, 4)
        Base pose T^0_w (default identity).
    """

    theta: np.ndarray  # (M,) rad
    lam: np.ndarray  # (M,)
    length: np.ndarray  # (M,) unactuated center-line length of each segment
    initial_pose: np.ndarray = field(default_factory=lambda: np.eye(4))  # T^0_w

    def __post_init__(self):
        object.__setattr__(self, "theta", np.asarray(self.theta, dtype=float).reshape(-1))
        m = self.theta.size
        lam = np.asarray(self.lam, dtype=float).reshape(-1)
        if lam.size == 1 and m != 1:
            lam = np.full(m, lam[0])
        object.__setattr__(self, "lam", lam)
        object.__setattr__(self, "length", np.asarray(self.length, dtype=float).reshape(-1))
        object.__setattr__(self, "initial_pose", np.asarray(self.initial_pose, dtype=float).reshape(4, 4))
        if not (self.lam.size == m and self.length.size == m):
            raise ValueError("theta, lam and length need one entry per segment")

    @property
    def segments(self) -> int:
        return self.theta.size


# A nominal lambda this close to 1 has no actuator (a stopper gap of a millionth of the segment: none is built);
# TOP: the largest nominal lambda that keeps one
NO_ACTUATOR_TOL = 1e-6
TOP = 1.0 - 2 * NO_ACTUATOR_TOL


def actuated(lam) -> np.ndarray:
    """Where a nominal routing has an actuator: lambda below 1 (spec "Physical builds")."""
    return np.asarray(lam, float) < 1.0 - NO_ACTUATOR_TOL


def built_lambda(lam, d_lam, lambda_min: float):
    """The physical rule (spec "Physical builds"): the lambda a robot realizes when built from the nominal ``lam``
    with lambda errors ``d_lam``. Without an actuator exactly 1; with one, nominal + error within the actuator's
    range [lambda_min, 1] (it cannot lengthen the tube, nor contract beyond its range)."""
    lam = np.asarray(lam, float)
    return np.where(actuated(lam), np.clip(lam + d_lam, lambda_min, 1.0), 1.0)


@dataclass(frozen=True)
class Sigmas:
    """Standard deviations of the construction errors of a built routing (independent, zero-mean Gaussian).

    Parameters
    ----------
    theta : float
        Drawn angle, rad.
    lam : float
        Contraction ratio, absolute (lambda 0.70 +- 0.02).
    length : float
        Segment length: relative (0.02 = 2 %) if ``relative_length``, else in problem units.
    relative_length : bool
        Whether ``length`` is relative to each segment's length.
    """

    theta: float = 0.0  # rad
    lam: float = 0.0  # absolute
    length: float = 0.0  # relative (fraction) if relative_length, else problem length units
    relative_length: bool = True

    @classmethod
    def from_degrees(cls, theta_deg: float = 0.0, lam: float = 0.0, length: float = 0.0, relative_length: bool = True) -> "Sigmas":
        return cls(math.radians(theta_deg), lam, length, relative_length)

    def per_segment(self, length) -> np.ndarray:
        """(M, 3) standard deviations of (theta, lambda, dl) per segment, in problem units."""
        length = np.asarray(length, float)
        sl = self.length * length if self.relative_length else np.full(length.shape, self.length)
        return np.column_stack([np.full(length.shape, self.theta), np.full(length.shape, self.lam), sl])

    def as_dict(self) -> dict:
        return {"sigma_theta_rad": self.theta, "sigma_theta_deg": math.degrees(self.theta), "sigma_lambda": self.lam,
                "sigma_length": self.length, "relative_length": self.relative_length}
