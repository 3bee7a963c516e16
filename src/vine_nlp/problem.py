"""The problem and result types, in one place: what every door (command line, API, sweeps) hands to the
pipeline and what every method returns.

Plain, validated-elsewhere containers: ``vine_nlp.io.problems`` builds them from TOML files, the API from
its arguments, tests and scripts directly."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vine_nlp.model import phi_from_theta
from vine_nlp.model.calibration import Calibration
from vine_nlp.model.routing import Routing
from vine_nlp.model.shape import Shape

ACTUATOR_KINDS = ("tendon", "programmed", "spam")
METHODS = ("nlp", "greedy")
HESSIANS = ("auto", "exact", "gauss-newton")
SOLVERS = ("auto", "ipopt")
BASES = ("free", "fixed")


@dataclass(frozen=True)
class Actuator:
    """Actuator bounds (paper Sec. VI-A). ``kind == "spam"`` shares one lambda over all segments.

    Parameters
    ----------
    kind : str
        "tendon", "programmed" or "spam".
    lambda_min : float
        Smallest contraction ratio, in (0, 1).
    theta_max : float
        Largest drawn angle |theta|, rad (at most 60 deg by default; must stay below pi/2).
    """

    kind: str = "tendon"
    lambda_min: float = 0.4
    theta_max: float = math.radians(60.0)  # rad, must stay below pi/2

    @property
    def shared_lambda(self) -> bool:
        return self.kind == "spam"


@dataclass(frozen=True)
class DesignOptions:
    """Method settings; every method reads the fields it needs and ignores the rest.

    The smoothing weights multiply w (1/L) int (D theta')^2 ds (and the same for lambda) against the mean
    squared error / D^2 (they damp twisting that does not shape the tube); 4e-7 is the largest measured weight
    that costs about 3 % RMSE at most on the paper's smooth cases (results/BENCHMARKS.md, "Smoothing weight").

    Parameters
    ----------
    method : str
        "nlp" (one NLP) or "greedy" (the paper's Algorithm 1).
    points_per_segment : int
        n, target points per segment.
    lookahead : int
        k, segments per window (greedy only).
    smooth_theta, smooth_lambda : float
        Smoothing weights of theta and lambda.
    starts : int
        Multi-start: number of starts (1 = the geometric guess only).
    hops : int
        Rounds of basin hopping after the multi-start.
    greedy_starts : int
        Greedy: trial starts per window (stands in for MATLAB's GlobalSearch).
    seed : int
        Seed of every random choice (starts, hops).
    max_iter : int
        IPOPT's iteration limit.
    tol : float
        IPOPT's tolerance.
    hessian : str
        "auto" (Gauss-Newton, exact if it does not converge), "exact" or "gauss-newton".
    budget : float
        Seconds the nlp's corner search may take where the first solve shows a corner-like target
        (design.corners); 0 turns it off.
    solver : str
        "auto" or "ipopt": both IPOPT (the file key is kept; a Fatrop stage form was removed: no gain end to end).
    correction_margin : float
        Buildable designs: every lambda is exactly 1 (no actuator) or inside [lambda_min + margin,
        1 - margin], so the next round can correct an as-built error both ways.
    min_feature : float or None
        Smallest stopper gap, pinch, pouch or piece, in length units; None: 2 mm in the problem's units
        (``analysis.buildability.default_min_feature``).
    base : str
        "free" (the design chooses the base pose, with no arbitrary roll) or "fixed" (``base_pose``).
    base_pose : tuple or None
        The fixed base pose T^0_w (4 x 4, nested tuples).
    """

    method: str = "nlp"
    points_per_segment: int = 10  # n
    lookahead: int = 4  # k, greedy only
    smooth_theta: float = 4e-7
    smooth_lambda: float = 4e-7
    starts: int = 1  # nlp multi-start: number of starts (1 = the geometric guess only)
    hops: int = 0  # nlp basin hopping after the multi-start: re-solves from perturbed high-error windows
    greedy_starts: int = 4  # greedy: trial starts per window (stands in for GlobalSearch); 4 escapes the s-curve trap
    seed: int = 0
    max_iter: int = 3000
    tol: float = 1e-8
    hessian: str = "auto"  # nlp: "auto" (Gauss-Newton, exact if it does not converge), "exact" or "gauss-newton"
    budget: float = 20.0  # nlp: seconds for the corner search (design.corners; a safety stop, 0: off)
    solver: str = "auto"  # "auto" | "ipopt": both IPOPT
    correction_margin: float = 0.05
    min_feature: float | None = None
    base: str = "free"
    base_pose: tuple | None = None  # nested tuples: the options stay hashable and comparable


@dataclass(frozen=True)
class Load:
    """Self-weight and payload ([load]; SI units whatever the problem's length units; ``analysis.loads``).

    Parameters
    ----------
    pressure : float
        The tube's gauge pressure, kPa.
    mass_per_length : float
        kg per metre of grown tube (wall, actuators, everything grown).
    tip_mass : float
        kg, a payload at the tip.
    gravity : tuple
        m/s^2, in the problem's world frame.
    safety : float
        Every bending moment stays below capacity / safety.
    """

    pressure: float
    mass_per_length: float = 0.0
    tip_mass: float = 0.0
    gravity: tuple = (0.0, 0.0, -9.81)
    safety: float = 1.0


@dataclass(frozen=True)
class DesignProblem:
    """Inverse design: a routing whose center line follows a target curve.

    Parameters
    ----------
    name : str
        The problem's name (archives, figures).
    diameter : float
        Tube diameter D, in ``units``.
    target : ndarray, shape (N, 3)
        Target center line, as sampled.
    actuator : Actuator
        Actuator kind and bounds.
    options : DesignOptions
        Method settings.
    units : str
        Length unit of every length of the problem.
    obstacles : tuple
        Obstacle shapes (vine_nlp.analysis.obstacles), in ``units``.
    obstacle_margin : float
        Required gap between the tube surface and every obstacle.
    growth : str
        "while-actuated" or "after" (the intermediate shapes of actuation after growth must clear too).
    calibration : Calibration or None
        Systematic construction errors of the builder (vine_nlp.model.calibration): the design is made for
        the robot as built.
    load : Load or None
        Self-weight and payload: every section's bending moment stays below its capacity / safety.
    """

    name: str
    diameter: float
    target: np.ndarray  # (N, 3) target center line, as sampled
    actuator: Actuator = Actuator()
    options: DesignOptions = DesignOptions()
    units: str = "cm"
    obstacles: tuple = ()
    obstacle_margin: float = 0.0
    growth: str = "while-actuated"
    # the nominal to build has the calibration's systematic errors taken out (the pipeline)
    calibration: Calibration | None = None
    load: Load | None = None


@dataclass(frozen=True)
class ForwardProblem:
    """The shape of a given routing.

    Parameters
    ----------
    name : str
        The problem's name.
    diameter : float
        Tube diameter D.
    routing : Routing
        The routing to model.
    units : str
        Length unit.
    load : Load or None
        Self-weight and payload to judge the shape under.
    """

    name: str
    diameter: float
    routing: Routing
    units: str = "cm"
    load: Load | None = None


@dataclass(frozen=True)
class FitProblem:
    """Fit the model of a known routing to measured points (any order, any pose).

    Parameters
    ----------
    name : str
        The problem's name.
    diameter : float
        Tube diameter D.
    measured : ndarray, shape (K, 3)
        Measured points.
    line : str
        The measured line: "center", "inner" or "outer".
    routing : Routing
        The known routing; its lambda is the starting value where lambda is free.
    free : tuple
        What is estimated besides the rigid pose: () or ("lambda",).
    units : str
        Length unit.
    """

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
    """One sPAM routing, K target shapes at K contraction levels (``vine_nlp.methods.multishape``).

    All targets have the same number of points, so the pairing structure (segments, points per segment) is shared.

    Parameters
    ----------
    name : str
        The problem's name.
    diameter : float
        Tube diameter D.
    targets : tuple of ndarray
        K target curves, each (N, 3).
    levels : tuple
        K entries: a fixed lambda, or None where it is free (bounded by [actuator.lambda_min, 1]); () = all free.
    actuator : Actuator
        An sPAM actuator.
    options : DesignOptions
        Method settings.
    shared_pose : bool
        One base pose for every level (the same physical base); False: one per level.
    units : str
        Length unit.
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
    """Reach a tip position (and optionally a tip direction) with the least actuation (``vine_nlp.methods.tip``).

    Parameters
    ----------
    name : str
        The problem's name.
    diameter : float
        Tube diameter D.
    position : array_like, shape (3,)
        Tip position.
    length : float
        Total unactuated tube length L.
    segments : int
        M, the number of segments (each at least 0.2 L / M long).
    direction : array_like, shape (3,), optional
        Tip tangent (normalized), or None.
    objective : str
        "contraction" (sum (1 - lambda_j) dl_j) or "turns" (sum |tan theta_j| dl_j).
    initial_pose : array_like, shape (4, 4)
        The fixed base pose.
    actuator : Actuator
        Actuator kind and bounds.
    options : DesignOptions
        Method settings.
    units : str
        Length unit.
    obstacles : tuple
        Obstacle shapes, as DesignProblem's.
    obstacle_margin : float
        Required gap between the tube surface and every obstacle.
    growth : str
        "while-actuated" or "after".
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
    obstacles: tuple = ()  # as DesignProblem's
    obstacle_margin: float = 0.0
    growth: str = "while-actuated"

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


# ---------------------------------------------------------------- what every method returns

@dataclass(eq=False)
class Result:
    """What every method returns: one routing, its shape, its metrics and solver statistics.

    Parameters
    ----------
    method : str
        The run's name ("nlp", "greedy", "multishape", "tip", "nlp_robust", ...).
    routing : Routing
        The design (per segment theta, lambda, length) and its base pose.
    shape : Shape
        The modeled center, actuator and opposite lines; design runs: row i pairs with target row i.
    status : str
        "optimal", "acceptable", "max_iter", "failed", ... (IPOPT's return status, archived).
    solve_time_s : float
        Time of the method, in seconds.
    iterations : int
        IPOPT iterations (summed over starts, hops and rounds).
    metrics : dict
        rmse, max_error (problem units), tv_theta, tv_lambda and formulation-specific figures.
    stats : dict
        Solver statistics and options, archived as attributes of ``/runs/<run>/solver``.
    diameter : float
        Tube diameter D.
    shortfall : tuple of str
        Every hard requirement of the problem the design misses, one line each (the pipeline's judge:
        bounds, obstacle margin, clearance); empty when it meets them all.
    objective, hessian, met, buildable, runs
        What the methods decide on (``stats`` is for the archive only): the NLP's objective (None: no NLP, the
        greedy's), the Hessian its solve ended with, the formulation's own hard requirements as it judged them
        ({"clearance": bool}, {"obstacles": bool}), a buildable design, the results it was chosen from.
    """

    method: str
    routing: Routing
    shape: Shape
    status: str = "optimal"  # optimal | acceptable | max_iter | failed | ...
    solve_time_s: float = 0.0
    iterations: int = 0
    metrics: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)  # solver statistics and options, archived as attributes
    diameter: float = 1.0
    shortfall: tuple = ()
    objective: float | None = None
    hessian: str = ""
    met: dict = field(default_factory=dict)
    buildable: bool = False
    runs: tuple = field(default=(), repr=False)

    @property
    def phi(self) -> np.ndarray:
        return phi_from_theta(self.routing.theta, self.routing.length, self.diameter)

    @property
    def converged(self) -> bool:
        return self.status in ("optimal", "acceptable")

    @property
    def clear(self) -> bool:
        """Meets every hard requirement of its problem (no shortfall)."""
        return not self.shortfall

    @property
    def ok(self) -> bool:
        """Converged and clear: what exit status 0 means."""
        return self.converged and self.clear
