"""How the NLPs are solved: the solver's options and the drive's tuned constants, apart from the formulations.

rockit keeps the solver and its options in the method, not in the problem. Here a formulation
declares what its solves are like (:class:`Settings`: a start near the answer, rows that are hard
requirements, a Gauss-Newton solve from a guess, bounds that must hold exactly, ...) and the
options follow from the declaration, the same for every formulation that declares the same.
The loops of ``methods.drive`` take their caps and rules from the constants below: each is named
here once, with one line on why its value; the figures that chose it are in results/BENCHMARKS.md.
"""

from __future__ import annotations

from dataclasses import dataclass


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
# zero (one factorization less; the continuity rows hold at a start on the target). Exact-Hessian and warm
# solves keep CHAIN alone: the corner search's local minimum is sensitive to every bit of its start.
GAUSS_NEWTON = {"ipopt.mu_oracle": "probing", "ipopt.mumps_permuting_scaling": 0, "ipopt.mumps_scaling": 0,
                "ipopt.constr_mult_init_max": 0.0}
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

    max_iter: int = 3000
    tol: float = 1e-8
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
# active sets (clearance pairs, obstacle rows): solves at most; the bundled problems end in 1-3 ("Obstacles")
ROUNDS = 6
# obstacles with a mesh: each solve moves the tube at most a trust radius and the active sets follow, so more rounds
MESH_ROUNDS = 12
# an active set's requirement rises by this times what the last round still misses where that is a dip between
# rows that hold: the loop then ends in one or two more solves (clearance, obstacles)
RAISE_FACTOR = 1.5
# obstacles: a re-solve before the last round stops here and the next round goes on with fresh active sets (a
# warm re-solve after new slots could crawl to IPOPT's limit; "Obstacles")
ROUND_MAX_ITER = 400
# obstacles on a tip problem: a start whose solve needs more is left for the next start ("Obstacles")
TIP_MAX_ITER = 1200

# ---------------------------------------------------------------- corner-like targets (methods.corners)

# a first solve is corner-like when Gauss-Newton did not converge on it and its RMSE exceeds this share of D:
# the smooth paper cases end far below it, the polyline (d) far above ("Inverse design: the paper's cases")
CORNER_RMSE = 0.05
DEFAULT_BUDGET = 20.0  # seconds of the corner search: a safety stop, the polyline (d)'s search ends well within it
WINDOW = 3  # segments per window of the corner search and of a basin hop: a corner spans about three at 10 points each
WINDOW_STARTS = 4  # starts per window: the current values, theta mirrored, random draws
WINDOW_MAX_ITER = 50  # a window has <= 3 W variables: a start that needs more is a bad start
WINDOW_TOL = 1e-6  # the polish that ends the round converges the design fully
WINDOW_SHARE = 0.5  # the share of the windows (those of largest error) a round visits ...
MIN_WINDOWS = 3  # ... but at least this many (short designs)
SEARCH_ROUNDS = 1  # rounds by default: a second gains little for much more time ("compare")
WINDOW_GAIN = 1e-4  # a window's new values must lower the design's error by this much (relative) to be taken
