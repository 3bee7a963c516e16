"""Typed problem descriptions shared by every design method, the forward model runner and the fit.

These are plain, validated-elsewhere containers: ``vine_nlp.io.problem_file`` builds
them from TOML files, tests and scripts build them directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

ACTUATOR_KINDS = ("tendon", "programmed", "spam")
METHODS = ("nlp", "greedy")
MEASURED_LINES = ("center", "inner", "outer")


@dataclass(frozen=True)
class Actuator:
    """Actuator bounds (paper Sec. VI-A). ``kind == "spam"`` shares one lambda over all segments."""

    kind: str = "tendon"
    lambda_min: float = 0.4
    theta_max: float = math.radians(60.0)  # rad, must stay below pi/2

    @property
    def shared_lambda(self) -> bool:
        return self.kind == "spam"


@dataclass(frozen=True)
class DesignOptions:
    """Method settings; every method reads the fields it needs and ignores the rest."""

    method: str = "nlp"
    points_per_segment: int = 10  # n
    lookahead: int = 4  # k, greedy only
    smooth_theta: float = 1e-3
    smooth_lambda: float = 1e-3
    starts: int = 1  # nlp multi-start: number of starts (1 = the geometric guess only)
    greedy_starts: int = 8  # greedy: trial starts per window (stands in for GlobalSearch)
    seed: int = 0
    max_iter: int = 3000
    tol: float = 1e-8


@dataclass(frozen=True)
class Routing:
    """A discretized actuator routing: one entry per segment (paper eq. phi(s_j))."""

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


@dataclass(frozen=True)
class DesignProblem:
    name: str
    diameter: float
    target: np.ndarray  # (N, 3) target center line, as sampled
    actuator: Actuator = Actuator()
    options: DesignOptions = DesignOptions()
    units: str = "cm"


@dataclass(frozen=True)
class ForwardProblem:
    name: str
    diameter: float
    routing: Routing
    units: str = "cm"


@dataclass(frozen=True)
class FitProblem:
    name: str
    diameter: float
    measured: np.ndarray  # (K, 3) measured points, any order, any pose
    line: str  # center | inner | outer
    routing: Routing  # known routing; its lambda is the starting value where lambda is free
    free: tuple = ()  # () or ("lambda",)
    units: str = "cm"
