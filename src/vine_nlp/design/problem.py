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
HESSIANS = ("auto", "exact", "gauss-newton")
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
    # weights of w (1/L) int (D theta')^2 ds etc. against the mean squared error / D^2: damps
    # twisting that does not shape the tube. 4e-7: the largest of the weights measured that costs
    # about 3 % RMSE at most on the paper's smooth cases (Bezier a: -16 % TV theta for +1.8 % RMSE,
    # Bezier c +3.1 %; 1e-6 costs Bezier c 11 %); results/BENCHMARKS.md, "Smoothing weight"
    smooth_theta: float = 4e-7
    smooth_lambda: float = 4e-7
    starts: int = 1  # nlp multi-start: number of starts (1 = the geometric guess only)
    hops: int = 0  # nlp basin hopping after the multi-start: re-solves from perturbed high-error windows
    greedy_starts: int = 4  # greedy: trial starts per window (stands in for GlobalSearch); 4 escapes the s-curve trap
    seed: int = 0
    max_iter: int = 3000
    tol: float = 1e-8
    hessian: str = "auto"  # nlp: "auto" (Gauss-Newton, exact if it does not converge), "exact" or "gauss-newton"


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


# ---------------------------------------------------------------- further formulations (paper, Conclusion)

TIP_OBJECTIVES = ("contraction", "turns")


@dataclass(frozen=True)
class MultiShapeProblem:
    """One sPAM routing, K target shapes at K contraction levels (``vine_nlp.design.multishape``).

    ``levels[k]`` is the fixed lambda of target k, or None where it is free (bounded
    by [actuator.lambda_min, 1]). All targets have the same number of points, so the
    pairing structure (segments, points per segment) is shared. ``shared_pose``: one
    base pose for every level (the same physical base); False gives each level its
    own pose (targets measured in different frames).
    """

    name: str
    diameter: float
    targets: tuple  # K arrays (N, 3)
    levels: tuple = ()  # K entries: float (fixed lambda) or None (free); () = all free
    actuator: Actuator = Actuator(kind="spam", lambda_min=0.5)
    options: DesignOptions = DesignOptions()
    shared_pose: bool = True
    units: str = "cm"

    def __post_init__(self):
        tg = tuple(np.asarray(t, dtype=float).reshape(-1, 3) for t in self.targets)
        object.__setattr__(self, "targets", tg)
        levels = tuple(self.levels) if self.levels else (None,) * len(tg)
        levels = tuple(None if v is None else float(v) for v in levels)
        object.__setattr__(self, "levels", levels)
        if not tg:
            raise ValueError("a multishape problem needs at least one target")
        if len(levels) != len(tg):
            raise ValueError("levels needs one entry (a lambda or None) per target")
        if len({t.shape[0] for t in tg}) != 1:
            raise ValueError("all targets need the same number of points")

    @property
    def count(self) -> int:
        """K, the number of levels."""
        return len(self.targets)

    def level_problem(self, k: int) -> DesignProblem:
        """Target k as a single-shape sPAM problem (pairing, geometric guess, evaluation)."""
        return DesignProblem(self.name, self.diameter, self.targets[k], self.actuator, self.options, self.units)


@dataclass(frozen=True)
class TipProblem:
    """Reach a tip position (and optionally a tip direction) with the least actuation (``vine_nlp.design.tip``).

    The base pose is fixed (the robot grows from a fixed base); the tube length and
    the number of segments are design inputs. ``objective``: "contraction" minimizes
    sum_j (1 - lambda_j) dl_j, "turns" the actuator's turning sum_j |tan theta_j| dl_j.
    """

    name: str
    diameter: float
    position: np.ndarray  # (3,)
    length: float  # total unactuated tube length L
    segments: int = 10  # M
    direction: np.ndarray | None = None  # (3,) unit tangent at the tip, or None
    objective: str = "contraction"
    initial_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    actuator: Actuator = Actuator()
    options: DesignOptions = DesignOptions()
    units: str = "cm"

    def __post_init__(self):
        object.__setattr__(self, "position", np.asarray(self.position, dtype=float).reshape(3))
        if self.direction is not None:
            d = np.asarray(self.direction, dtype=float).reshape(3)
            n = float(np.linalg.norm(d))
            if not n > 0:
                raise ValueError("direction must be a nonzero vector")
            object.__setattr__(self, "direction", d / n)
        object.__setattr__(self, "initial_pose", np.asarray(self.initial_pose, dtype=float).reshape(4, 4))
        if self.objective not in TIP_OBJECTIVES:
            raise ValueError(f"objective must be one of {TIP_OBJECTIVES}")
        if not (self.length > 0 and int(self.segments) >= 1):
            raise ValueError("length must be > 0 and segments >= 1")
