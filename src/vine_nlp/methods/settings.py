"""How the NLPs are solved, apart from the problems and the formulations: the method, the solver's options
and every tuned constant of ``methods/``.

rockit keeps the solver and its options in the method, not in the problem: :class:`Method` holds what a
user may retune (starts, hops, max_iter, tol, hessian, budget, seed, rounds), one default each. A
formulation declares what its solves are like (:class:`Settings`: a start near the answer, rows that are
hard requirements, a Gauss-Newton solve from a guess, bounds that must hold exactly, ...) and the options
follow from the declaration. Every tuned constant of ``methods/`` is named here once, with one line on
why its value (grouped by the module that uses it); the figures that chose them are in results/BENCHMARKS.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from vine_nlp.problem import DesignOptions

# IPOPT's iteration limit and tolerance unless a problem or a method says otherwise: the problem file's [design]
# defaults (the file contract; converged designs end in tens to a few hundred iterations)
MAX_ITER = DesignOptions.max_iter
TOL = DesignOptions.tol


def quiet(max_iter: int, tol: float) -> dict:
    """IPOPT prints nothing inside library code (callers report progress themselves); its limit and tolerance."""
    return {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": int(max_iter), "ipopt.tol": float(tol)}


# every solve of the chain: a stop on objective plateaus (corners of polyline targets), adaptive barrier,
# results inside the original bounds (not IPOPT's relaxed ones)
CHAIN = {"ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_obj_change_tol": 1e-8, "ipopt.acceptable_iter": 10,
         "ipopt.mu_strategy": "adaptive", "ipopt.honor_original_bounds": "yes"}
# a start near the answer: not pushed back into the interior, a small first barrier
WARM = {"ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-6, "ipopt.warm_start_bound_push": 1e-9,
        "ipopt.warm_start_mult_bound_push": 1e-9, "ipopt.warm_start_slack_bound_push": 1e-9}
# the plain chain's Gauss-Newton solve from a guess ("Compiled NLP functions", "Sweep"): Mehrotra's probing
# barrier rule (Gauss-Newton converges on more targets), MUMPS's own scalings off (IPOPT scales already; on
# these small banded systems the pass is a large share of a factorization), constraint multipliers from
# zero (one factorization less; the continuity rows hold at a start on the target), no residual check of each
# step (fast_step_computation: 10 % of the 125-knot sweep's solver time, the same iterations and designs to 1e-10;
# results/benchmarks/buildable.md, "sixth session"). Exact-Hessian and warm solves keep CHAIN alone: the corner
# search's local minimum is sensitive to every bit of its start (with fast steps there the hook took 2051
# iterations instead of 260, polyline (d) another corner design).
GAUSS_NEWTON = {"ipopt.mu_oracle": "probing", "ipopt.mumps_permuting_scaling": 0, "ipopt.mumps_scaling": 0,
                "ipopt.constr_mult_init_max": 0.0, "ipopt.fast_step_computation": "yes"}
# rows that are hard requirements (clearance, obstacles, the robust recursion): held tightly, no early stop.
# 1e-8 (units of D: a quarter of a micrometre on these tubes): at 1e-10 IPOPT went on for hundreds of
# iterations at the optimum's objective, its infeasibility jumping between 1e-7 and 1e-1 on the nearly
# parallel rows of a flat wall (a slot beside the target: 682 iterations instead of 213, the same design)
HARD = {"ipopt.acceptable_tol": 1e-6, "ipopt.acceptable_iter": 15, "ipopt.constr_viol_tol": 1e-8,
        "ipopt.acceptable_constr_viol_tol": 1e-8}
# bounds that hold exactly (a tip): no bound relaxation, so the answer needs no projection that moves the tip
EXACT_BOUNDS = {"ipopt.bound_relax_factor": 0.0, "ipopt.acceptable_constr_viol_tol": 1e-10}
# IPOPT's monotone barrier from its default mu: fewer iterations and lower optima on the tip's degenerate objective
MONOTONE = {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": 0.1}
# one structure solved again and again (the as-built estimate's rounds): MUMPS's AMD ordering (its symbolic
# analysis is redone at every solve) and no multipliers of the parameters (unused: one derivative less)
REPEATED = {"ipopt.mumps_pivot_order": 0, "calc_lam_p": False}
# the greedy's and the corner search's window NLPs (a few variables, single shooting)
GREEDY_WINDOW = {"ipopt.acceptable_tol": 1e-6}
CORNER_WINDOW = {"ipopt.acceptable_tol": 1e-5, "ipopt.mu_strategy": "adaptive"}


@dataclass(frozen=True)
class Settings:
    """What a formulation declares about its solves; :meth:`options` turns it into the solver's options.

    ``max_iter``, ``tol``: the solver's limit and tolerance; ``warm``: the start is near the answer (WARM);
    ``guess``: a Gauss-Newton solve of the plain chain from a guess (GAUSS_NEWTON); ``exact_bounds``: the
    bounds hold exactly (EXACT_BOUNDS); ``monotone``: IPOPT's monotone barrier (MONOTONE); ``hard``: rows
    that are hard requirements (HARD); ``repeated``: one structure solved many times (REPEATED).
    """

    max_iter: int = MAX_ITER
    tol: float = TOL
    warm: bool = False
    guess: bool = False
    exact_bounds: bool = False
    monotone: bool = False
    hard: bool = False
    repeated: bool = False

    def options(self) -> dict:
        """The solver's options: in the order above, a later set overriding an earlier one's entries."""
        opts = quiet(self.max_iter, self.tol) | CHAIN
        for on, extra in ((self.warm, WARM), (self.guess, GAUSS_NEWTON), (self.exact_bounds, EXACT_BOUNDS),
                          (self.monotone, MONOTONE), (self.hard, HARD), (self.repeated, REPEATED)):
            if on:
                opts |= extra
        return opts


# ---------------------------------------------------------------- the design variables (methods.variables)

# segment lengths stay within this factor of the target's chord of the segment: a loose box that keeps IPOPT
# away from dl -> 0 without constraining real designs
LENGTH_FACTOR = (0.2, 5.0)
# a random start perturbs the geometric guess by normal draws of these standard deviations (theta in rad):
# the spread that decides more than solver options do ("Initialization and multi-start")
START_SPREAD = {"theta": 0.25, "lam": 0.1}

# ---------------------------------------------------------------- the method apart from the problem


@dataclass(frozen=True)
class Method:
    """How a design problem is solved, apart from what it asks (rockit's ``ocp.method``, ``ocp.solver``): one
    default each. ``Method.of(options)`` reads a problem file's ``[design]`` table (``DesignOptions``, the file
    contract); ``with_(...)`` retunes a solve without touching the problem (a basin hop's exact Hessian, the
    pushed target's loose tolerance).

    ``starts``: multi-start; ``hops``: basin-hopping rounds; ``max_iter``, ``tol``: IPOPT's; ``hessian``: "auto"
    (the drive's schedule), "exact" or "gauss-newton"; ``budget``: seconds of the corner search (0: none);
    ``seed``: every random choice; ``rounds``: active-set solves at most; ``band``: a lambda box (lo, hi) per segment
    every solve of the plain NLP keeps (the buildable design's one solve, ``methods.buildable.band``; None: the
    actuator's). The defaults of what a problem file may set are its ``[design]`` table's (``DesignOptions``): one
    default each."""

    starts: int = DesignOptions.starts
    hops: int = DesignOptions.hops
    max_iter: int = MAX_ITER
    tol: float = TOL
    hessian: str = DesignOptions.hessian
    budget: float = DesignOptions.budget  # a safety stop: the polyline (d)'s corner search ends well within it
    seed: int = DesignOptions.seed
    rounds: int = 6  # active sets (clearance pairs, obstacle rows): the bundled problems end in 1-3 ("Obstacles")
    band: tuple | None = field(default=None, compare=False)

    @classmethod
    def of(cls, options) -> "Method":
        """The method a problem's options (``DesignOptions``, read from its file) ask for."""
        return cls(**{k: getattr(options, k) for k in ("starts", "hops", "max_iter", "tol", "hessian", "budget", "seed")
                      if hasattr(options, k)})

    def with_(self, **changes) -> "Method":
        return replace(self, **changes)


ROUNDS = Method.rounds

# ---------------------------------------------------------------- the drive's loops

# Hessian "auto": Gauss-Newton gets this many iterations, then the exact Hessian solves the same start
# (a Gauss-Newton solve that needs more has large residuals: corners; "Initialization and multi-start")
AUTO_GN_MAX_ITER = 50
# the correction starts at the as-built routing, near its answer: the exact Hessian converges in a few tens
# of iterations where Gauss-Newton ran into its cap; Gauss-Newton only where the exact one fails
CORRECTION_SCHEDULE = (("exact", 300), ("gauss-newton", 300))
# the as-built estimate: the exact Hessian (Gauss-Newton crawls on the large residuals of the coarse stages),
# warm starts (re-pairing moves the answer little), this limit and tolerance per round ("As-built correction")
ESTIMATE = Settings(max_iter=200, tol=1e-8, warm=True, repeated=True)
ESTIMATE_HESSIAN = "exact"
# the estimate's ICP loop: pair-and-solve rounds of its last (finest) stage, of each coarser stage (whose
# pairs only need to be good enough for the next), the factor the fit's noise sigma shrinks by from stage to
# stage, and how close to the measurement's sigma a stage is merged into the last ("As-built correction")
ICP_ROUNDS = 6
COARSE_ROUNDS = 2
STAGE_FACTOR = 0.25
STAGE_MERGE = 1.5
# obstacles with a mesh: each solve moves the tube at most a trust radius and the active sets follow, so more rounds
MESH_ROUNDS = 12
# an active set's requirement rises by this times what the last round still misses where that is a dip between
# rows that hold: the loop then ends in one or two more solves (clearance, obstacles)
RAISE_FACTOR = 1.5
# clearance: pairs closer than D + min_gap + CLEARANCE_DETECT D get rows, about CLEARANCE_STEP D apart along each side
# of a contact; the loop ends at D + min_gap - CLEARANCE_TOL D (a design clear to round-off)
CLEARANCE_DETECT, CLEARANCE_STEP, CLEARANCE_TOL = 0.25, 0.5, 1e-7
# obstacles: a re-solve before the last round stops here and the next round goes on with fresh active sets (a
# warm re-solve after new slots could crawl to IPOPT's limit; "Obstacles")
ROUND_MAX_ITER = 400
# obstacles on a tip problem: a start whose solve needs more is left for the next start ("Obstacles")
TIP_MAX_ITER = 1200

# ---------------------------------------------------------------- corner-like targets (methods.corners)

# a first solve is corner-like when Gauss-Newton did not converge on it and its RMSE exceeds this share of D:
# the smooth paper cases end far below it, the polyline (d) far above ("Inverse design: the paper's cases")
CORNER_RMSE = 0.05
WINDOW = 3  # segments per window of the corner search and of a basin hop: a corner spans about three at 10 points each
WINDOW_STARTS = 4  # starts per window: the current values, theta mirrored, random draws
CORNER_WINDOW_MAX_ITER = 50  # a window has <= 3 W variables: a start that needs more is a bad start
WINDOW_TOL = 1e-6  # the polish that ends the round converges the design fully
WINDOW_SHARE = 0.5  # the share of the windows (those of largest error) a round visits ...
MIN_WINDOWS = 3  # ... but at least this many (short designs)
SEARCH_ROUNDS = 1  # rounds by default: a second gains little for much more time ("compare")
WINDOW_GAIN = 1e-4  # a window's new values must lower the design's error by this much (relative) to be taken

# ---------------------------------------------------------------- the formulations' and helpers' tuned constants
# drive
# objectives this close (relative) are the same optimum reached from different starts or rounds
TIE_RTOL = 1e-6
# compiled
# a block type is compiled on its own only up to this many SX instructions (its functions and derivatives): gcc
# -O1's time grows with them, and a larger block (an obstacle segment's samples against its primitives or
# triangles) would take longer than the solves it speeds up; such a block is a map of one sample's
# (blocks.Samples), whose block is compiled instead ("Active sets on compiled blocks")
BLOCK_BUDGET = 30_000
# a several-actuator segment block (one state's segment with one, two or three active lines: about 32k, 97k and 208k
# instructions with its derivatives) is compiled all the same: once per machine, in the background (gcc -O1 7, 12
# and 32 s), and its Hessian, most of an iteration, then runs 6.6x, 9.3x and 10.9x faster than interpreted
ACTUATORS_BLOCK_BUDGET = 250_000
# greedy
LAMBDA_START = 0.75  # paper: lambda_{1:k,0} = 0.75
GREEDY_SPREAD = 0.5  # random starts: half-width of the box around the carried-over values, x bound range
FIRST_WINDOW_FACTOR = 4  # the first window gets this many times the starts (paper: 2000 vs 300)
GREEDY_WINDOW_MAX_ITER = 200  # a window has <= 3k + 6 variables: a start that needs more is a bad start
SPAM_CANDIDATES = 11  # linspace(lambda_min, 1, 11)
SPAM_REFINE = 5  # second pass: 5 values within +-half a step of the best
FILTER_ORDER = 2  # the paper's low-pass filter: a second-order Butterworth, run forwards and backwards
# mirror
PLANAR = 1e-9  # |torsion sum| / sum |chord|^3 below this: a target planar to round-off (no handedness of its own)
# obstacles.design
BLOCKED_WEIGHT = 0.1  # weight of the target points closer than the margin to an obstacle (their fit cannot be exact)
MESH_BLOCKED_WEIGHT = 0.01  # the same where the scene has a mesh (module docstring, "Weights")
MESH_WEIGHT_RAMP = 1.0  # units of D: with a mesh, weights rise from MESH_BLOCKED_WEIGHT at the margin to 1 at margin + this
POLISH_RAMP = 3.0  # units of D: the buildable design's polish, weights from BLOCKED_WEIGHT at the margin to 1 at margin + this
NEAR_CLASSES = 1.0  # units of D beyond the margin: the buildable classes follow the pushed start's bends this near an obstacle
NEAR_DETOUR = 0.1  # units of D: ... and where the pushed start is this far off the target (its detour)
# obstacles.rows
MESH_K = 6  # nearest triangles per mesh sample (the plan's default)
TRI_EPS = 1e-9  # sqrt(d2 + eps^2) (units of D): finite gradients at distance 0
# obstacles.plan
SAMPLE_SPACING = 0.25  # target sample spacing h0, units of D: dip(D/4) ~ 0.03 D for a sharp obstacle
LENGTH_SLACK = 1.25  # segment lengths may grow this much during a solve before the rows' dip is too small
MAX_SAMPLES = 40  # samples per segment, at most (long segments: their rows' dip grows instead)
AFTER_SLOTS = 5  # growth "after": intermediate shapes with rows at a time (rows on all at once: a first solve of many minutes)
# units of D: a primitive gets rows on a segment when its slack is below ACTIVE_REACH plus REACH_DL times the
# segment's length (within reach of one solve)
ACTIVE_REACH = 1.0
REACH_DL = 0.5
MESH_TRUST = 1.5  # units of D: a frame moves at most this far per solve with a mesh (its nearest triangles stay valid)
# units of D: a column carries a mesh's rows when its slack is below this plus REACH_DL dl_j: far fewer rows than
# every column; a reach as short as the primitives' sent obstacle-mesh round a far wider detour ("Obstacles")
MESH_REACH = 8.0
# units of D: an outside sample closer than its requirement plus this also gets the tangent plane's row at its
# nearest point on the mesh (fewer rounds on obstacle-mesh and the torus scene: "Obstacles")
TANGENT_REACH = 0.5
# obstacles.push
# units of D: the pushed target clears by this much more than the rows ask; less with a mesh (its exact pushes
# already go the shortest way round, "Obstacles")
PUSH_EXTRA = 0.25
MESH_PUSH_EXTRA = 0.05
PUSH_PASSES = 8  # passes over the obstacles (a point pushed out of one may land in another)
REPUSH = 1  # primitives: times the designed chain of the pushed target is pushed and designed again where it does not clear
PUSH_DIRECTIONS = 16  # meshes: directions tried around a run's chord
PUSH_PROBES = 9  # meshes: points of a run that choose its direction
MARCH_STEPS = 80  # sphere-tracing steps of a push, at most
# IPOPT's tolerance for the designs of the pushed target: a start, which the rows' solve takes to the problem's
# own tolerance; at the problem's 1e-8 these designs crawled through their last digits on the pushed target's
# corners and took half of a typical scene's time ("Obstacle scenes")
PUSH_TOL = 1e-4
# fit.model_fit
FIT_SPACING = 0.1  # model lines are sampled at <= FIT_SPACING * D
LAMBDA_BOUNDS = (0.3, 1.0)  # the model fit's lambda range: below 0.3 no tube the fits have seen contracts
LAMBDA_GRID_STEP = 0.05  # the lambda grid that ranks starts: fine enough that the polish starts in the right basin
GRID_POLISH_ITER = 12  # the lambda grid only ranks values; the refinement polishes fully
GRID_POINTS = 1000  # measured points used while ranking the lambda grid
# fit.align
GLOBAL_POINTS = 300  # measured points used by the ICP of the global stage (all points are used for the polish)
ICP_GLOBAL_ITER = 60  # ICP rounds of the global stage: its pairs settle well within them
POLISH_TOP = 3  # the best poses of the global stage that are polished on all points
# buildable
# build-effort weights against the fit's mean squared error / D^2 (results/BENCHMARKS.md, "Buildable designs"):
# where the shape does not see the line (a first or last unactuated run) it holds it at theta 0 at no cost; where
# theta shapes the tube a tenth curbs the winding that cancels a bend the margin forces (bezier-b 807 -> 161 deg)
# at a few % RMSE (1e-3 cost polyline-d its budget); inner unactuated runs' turning the shape needs: nearly free
EFFORT, EFFORT_ACTUATED, EFFORT_INNER = 1e-3, 1e-4, 1e-6
ACCURACY_SLACK, ACCURACY_FLOOR_MM = 0.10, 0.05  # what the reclassification may give up: the budget
BUILDABLE_ROUNDS, BUILDABLE_REPAIRS = 8, 2  # solves at most; of them, re-solves while a gap is below min_feature (the lengths moved)
# the first solve from the free design: IPOPT's warm start where the classes' bounds move its lambda by at most this (trefoil-m4:
# 20 -> 3 iterations; the 125-knot sweep's 67 re-solved knots 950 -> 767 at 0.05 against 0.01; bezier-a's 0.12 took more warm than cold)
WARM_CLIP = 0.05
ROUND_ITER = 200  # a later round (other classes) that needs more is not taken: bezier-c's 6th round ran 1009 iterations for nothing
# the error diffusion's phases (share of the step, the pair's bend as the step): raced (PHASE_ITER), the best solved fully; the
# design's error on a gently bent target depends on where the isolated actuators fall (bezier-c: 0.27 mm at 0.5, 0.11 at 0.35)
DIFFUSION = ((0.5, False), (0.35, False), (0.7, False), (0.5, True))
# the phases race this many iterations each from the free design, the lowest RMSE's then solved fully (issue 46: bezier (a)-(c)
# and a known answer ranked as by their full solves at 6; at 4 the known answer not, nor by the objective at 6 (an iterate's
# objective ignores its continuity defects); 4 x 6 + 6-15 iterations where the full solves took 64-165)
PHASE_ITER = 6
BEND_TOL = 1e-6  # rad: a segment of the target bending less is straight
FEATURE_SLACK = 1.1  # a gap's lambda bound asks this much more than min_feature: a solve moves the lengths by up to ~10 %
# tip
MIN_LENGTH_FACTOR = 0.2  # dl_j >= 0.2 L / M
TURNS_EPS = 1e-6  # sqrt(tan^2 theta + eps): the "turns" measure smooth at theta 0
TIE_BREAK = 1e-2  # weight of the secondary measure (see module doc)
CLOSEST_ACTUATION = 1e-6  # weight of the actuation in the nearest-approach variant
CLOSE_ENOUGH = 1e-3  # nearest approach within this many D of the tip: re-solve the design from it
GUESS_POINTS = 4  # points per segment of the guide curve of the geometric guess
# actuators_design (several actuators on one tube)
ACTUATORS_PENALTY = 1e-4  # stage 1: weight of (1 - lambda_a)(1 - lambda_b) of exclusive pairs, against the mean squared error / D^2
ACTUATORS_ROUNDS = 3  # pairing rounds of the last stage at most (the others: one)
ACTUATORS_GAIN = 0.05  # ... and while a round lowers the objective by this fraction at least
ACTUATORS_REPAIR_TOL = 1e-5  # the linearized target holds where no paired fraction of a target's chord moved more than this
ACTUATORS_MIN_PIECE = 0.05  # a segment pairs with at least this fraction of 1/M of every target
ACTUATORS_KEPT = 2  # built solvers kept per process (a design's and a correction's; the process with both bundled designs peaks at 120 MB)
ACTUATORS_ON = 1e-3  # a line contracts on a segment (for the assignment) where 1 - lambda exceeds this
# loads (design under self-weight and payload)
LOAD_POINTS = 4  # points per segment carrying its weight in the moment recursion (the dense check tightens the rest)
LOAD_ROUNDS = 4  # solves at most: the first, then tightened by the dense check's shortfall
LOAD_TIGHTEN = 1.002  # past the shortfall, a tightened round asks this much more
LOAD_BUDGET = 0.1  # units of D: the RMSE a design may give up to stand; beyond it the design on the target is kept
# correct.pairing
SAMPLES_PER_SEGMENT = 24  # pieces per segment of the model lines the pairing projects onto
# the share of a pair's along-line difference kept in its residual: zero at a closest point, it damps sliding along the
# line between pairings (pure point-to-line let a hook's straight part slide: a shorter tube, a later bend)
SLIDE = 0.1
# correct.estimate
# weak priors on the systematic parts: wide against any construction method seen
DEFAULT_SYSTEMATIC_SIGMAS = (math.radians(10.0), 0.2, 0.2)
DEFAULT_MEASUREMENT_SIGMA_MM = 1.0  # a scanned or hand-measured point: about a millimetre
TRIM = 4.0  # pairs farther than this many sigmas of the stage are left out of it
SLOT_STEP = 8  # slots per segment are rounded up to a multiple of this (cached structures)
HELD_SIGMAS = 2.0  # an actuator estimated within this many standard deviations of lambda 1 may be clipped: held
CAP_ROUND = 1e-3  # lambda units: the cap's rounding (at most CAP_ROUND / 2 off min, at the kink)
# correct.correction
THETA_TRUST = 2.0  # with theta adjusted, the corrected theta stays within this many sigma_theta of the as-built one
ROUTE_GAIN = 2.0  # lambda and theta (a new tube) is recommended where it predicts this many times less error
REACH_TOL = 0.1  # the bounds cost accuracy where the unbounded prediction is this fraction (and 0.1 sigma_m) better
