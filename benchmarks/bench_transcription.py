"""One transcription for every formulation: time per IPOPT iteration of each, against the plain NLP's.

Same target and structure for each pair, measured in the same run, solvers built before
timing (the build is reported apart), IPOPT's own iteration count:

- nlp (trefoil m = 4, 40 segments x 10 points; tendon and sPAM), exact and Gauss-Newton Hessian;
- multishape with K = 1 (the trefoil, sPAM) against the plain sPAM NLP;
- clearance (a helix whose turns are closer than D) against the plain NLP on the same helix;
- robust (trefoil and Bezier (b), sigmas 1 deg, 0.02, 2 %) against the plain NLP;
- tip (the trefoil's tip position and direction, 40 segments) against the plain NLP with 40 segments;
- obstacles (obstacle-pipe-bend, obstacle-mesh: the solves with rows, not the obstacle-free or pushed starts)
  against the plain NLP on the same target without its obstacles.

Also: command start to archive for trefoil, multishape-spam and tip-target (whole processes), with the
objective and RMSE of the archived design (the design quality the timing must not trade away). The
machine's load average is recorded before and after: the machine may be shared, so IPOPT's time is taken
as the CPU time of each solve by default (``--clock wall``: elapsed time, as IPOPT's stats report it), and
the commands' CPU time (user + system) is given beside their elapsed time. Each row also gives the share of
IPOPT's time spent in the NLP's functions (the rest is IPOPT's own, mostly the KKT factorization), and the report
says whether the NLP functions ran compiled (VINE_NLP_CODEGEN).
Writes results/benchmarks/transcription.md. Run: python benchmarks/bench_transcription.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import ROOT, table, write_report

from vine_nlp import targets
from vine_nlp.io.archive import load_archive
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import compiled, transcription
from vine_nlp.methods.clearance import design_with_clearance
from vine_nlp.methods.multishape import design_multishape
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.methods.obstacles import design_with_obstacles
from vine_nlp.methods.robust import design_robust
from vine_nlp.methods.tip import design_tip
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Sigmas
from vine_nlp.problem import Actuator, DesignProblem, MultiShapeProblem, TipProblem

SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)


# CPU seconds IPOPT spent in the NLP's functions (objective, rows, their derivatives), summed over solves;
# the rest of its time is its own: mostly factorizing the KKT matrix
FUNCTIONS = [0.0]
REGULARIZED = [0]  # iterations on which IPOPT corrected the KKT matrix's inertia (refactorizing) in the timed call
ONLY_TERM = [None]  # count only solvers with this term (the obstacle design's own start solves are not its rows')
LAST = [None]  # the solver of the last counted solve (its size: nlp_size, read where a row is reported)


def nlp_size(solver) -> tuple:
    """(variables, equality rows, inequality rows, nonzeros of the constraint Jacobian, of the Lagrangian Hessian's
    upper triangle): what IPOPT's KKT matrix is made of (its factor grows with them)."""
    f = solver.nlpsol
    jac = f.get_function("nlp_jac_g").sparsity_out("jac_g_x")
    hess = f.get_function("nlp_hess_l")
    rows, cols = hess.sparsity_out(hess.n_out() - 1).get_triplet()
    eq = int(np.sum(solver.lbg == solver.ubg))
    return f.size1_in(0), eq, solver.lbg.size - eq, jac.nnz(), sum(1 for r, c in zip(rows, cols) if r <= c)


def cpu_clock(cpu: bool) -> None:
    """IPOPT's time as the CPU time of each solve (``cpu``: on a shared machine, waiting for a core is not the
    solver's cost), and the time in the NLP's functions (CasADi's per-function CPU timers) added to FUNCTIONS."""
    solve = transcription.Solver.solve

    def timed(self, *a, **kw):
        t = time.process_time()
        sol = solve(self, *a, **kw)
        if cpu:
            sol.stats["ipopt_time_s"] = time.process_time() - t
        stats = self.nlpsol.stats()
        if ONLY_TERM[0] is None or ONLY_TERM[0] in self.term_names:
            FUNCTIONS[0] += sum(v for k, v in stats.items() if k.startswith("t_proc_nlp_"))
            REGULARIZED[0] += sum(1 for v in stats.get("iterations", {}).get("regularization_size", []) if v > 0)
            LAST[0] = self
        return sol

    transcription.Solver.solve = timed


def function_share(run):
    """(result of ``run()``, the share of its IPOPT time spent in the NLP's functions)."""
    FUNCTIONS[0] = 0.0
    REGULARIZED[0] = 0
    r = run()
    r.stats["regularized_iterations"] = REGULARIZED[0]
    return r, FUNCTIONS[0] / max(r.stats["ipopt_time_s"], 1e-12)


def per_iteration(run, repeat):
    """(median ms per IPOPT iteration, iterations, result, median share in the NLP's functions): the solvers built
    by a first call, then ``repeat`` timed calls; IPOPT's time and iterations summed over every solve of the call
    (clearance: its rounds)."""
    r = run()
    times, shares = [], []
    for _ in range(repeat):
        r, share = function_share(run)
        times.append(ms_per_iteration(r))
        shares.append(share)
    return statistics.median(times), iterations(r), r, statistics.median(shares)


def iterations(r) -> str:
    """IPOPT iterations of the last timed call, and (in parentheses) those with an inertia correction."""
    return f"{r.stats.get('ipopt_iterations', r.iterations)} ({r.stats['regularized_iterations']})"


def ms_per_iteration(r) -> float:
    return 1e3 * r.stats["ipopt_time_s"] / max(r.stats.get("ipopt_iterations", r.iterations), 1)


def paired(run, base, repeat):
    """(median ms per iteration of ``run``, iterations, result, median ratio to ``base``, median share in the NLP's
    functions): each timed call of ``run`` right after one of its plain NLP ``base``, so a shared machine's changing
    load hits both alike."""
    r = run()
    base()
    times, ratios, shares = [], [], []
    for _ in range(repeat):
        b = base()
        r, share = function_share(run)
        times.append(ms_per_iteration(r))
        ratios.append(times[-1] / ms_per_iteration(b))
        shares.append(share)
    return statistics.median(times), iterations(r), r, statistics.median(ratios), statistics.median(shares)


class Rows(list):
    """Rows of the table, printed as they come (a long run shows its progress)."""

    def append(self, row):
        print(" | ".join(map(str, row)), flush=True)
        super().append(row)


def exact(pb):
    return dataclasses.replace(pb, options=dataclasses.replace(pb.options, hessian="exact", starts=1, hops=0))


def command_time(problem):
    """(elapsed seconds, CPU seconds (user + system), the archived design's objective and RMSE) of one command."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "o.h5"
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "vine_nlp", "design", str(problem), "-o", str(path), "--force"],
                       check=True, capture_output=True)
        elapsed = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        run = next(iter(load_archive(path).runs.values()))
    return elapsed, r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime, run.stats["objective"], run.metrics["rmse"]


def size_cols(base=None) -> tuple:
    """The last counted solve's NLP size (nlp_size) and its KKT nonzeros (Jacobian + Hessian triangle + one per
    variable and row: IPOPT's diagonal) as a ratio to ``base``'s (the plain NLP's size)."""
    size = nlp_size(LAST[0])
    nx, eq, ineq, nj, nh = size
    kkt = lambda s: s[3] + s[4] + s[0] + s[1] + 2 * s[2]  # noqa: E731 (an inequality row also brings its slack)
    return f"{nx}, {eq} / {ineq}, {nj} + {nh}", f"{kkt(size) / kkt(base or size):.2f}"


def quality(r):
    return f"{r.stats['objective']:.6g}"


def pct(share: float) -> str:
    return f"{100 * share:.0f} %"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu", help="IPOPT's time: CPU time of each solve, or elapsed")
    args = ap.parse_args()
    cpu_clock(args.clock == "cpu")
    rep = args.repeat
    rows = Rows()
    load0 = os.getloadavg()

    tre = exact(load_problem(ROOT / "problems/trefoil-m4.toml").problem)
    base_ms, base_it, base, sh = per_iteration(lambda: design_nlp(tre), rep)
    tre_size = nlp_size(LAST[0])
    rows.append(("nlp (exact Hessian)", "trefoil, M = 40, n = 10", f"{base_ms:.2f}", base_it, quality(base), pct(sh), "1.00", *size_cols()))
    gn = dataclasses.replace(tre, options=dataclasses.replace(tre.options, hessian="gauss-newton"))
    plain = lambda: design_nlp(tre)  # noqa: E731
    ms, it, r, ratio, sh = paired(lambda: design_nlp(gn), plain, rep)
    rows.append(("nlp (Gauss-Newton)", "trefoil", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f}", *size_cols(tre_size)))

    spam = dataclasses.replace(tre, actuator=Actuator("spam", tre.actuator.lambda_min, tre.actuator.theta_max))
    spam_ms, it, r, sh = per_iteration(lambda: design_nlp(spam), rep)
    spam_size = nlp_size(LAST[0])
    rows.append(("nlp, sPAM", "trefoil", f"{spam_ms:.2f}", it, quality(r), pct(sh), "1.00", *size_cols()))
    ms1 = MultiShapeProblem(tre.name, tre.diameter, [tre.target], [None], spam.actuator, spam.options)
    ms, it, r, ratio, sh = paired(lambda: design_multishape(ms1, starts=1), lambda: design_nlp(spam), rep)
    rows.append(("multishape, K = 1", "trefoil, sPAM", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f} (vs sPAM nlp)", *size_cols(spam_size)))

    # clearance: a helix whose turns are closer than D (the tube following it would collide)
    coil = DesignProblem("tight-helix", 2.0, targets.helix(radius=3.0, pitch=0.25, length=50.0, samples=101),
                         actuator=Actuator("tendon", 0.4), options=dataclasses.replace(tre.options, points_per_segment=5))
    coil_ms, it, free, sh = per_iteration(lambda: design_nlp(coil), rep)
    coil_size = nlp_size(LAST[0])
    rows.append(("nlp (exact Hessian)", "tight helix, M = 20, n = 5", f"{coil_ms:.2f}", it, quality(free), pct(sh), "1.00", *size_cols()))
    ms, it, r, ratio, sh = paired(lambda: design_with_clearance(coil, start=free), lambda: design_nlp(coil), rep)
    rows.append(("clearance", f"tight helix ({r.stats['clearance_pairs']} pairs, {r.stats['clearance_rounds']} solves, "
                 f"min clearance {r.stats['min_clearance'] / coil.diameter:.5f} D)", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f}",
                 *size_cols(coil_size)))

    ms, it, r, ratio, sh = paired(lambda: design_robust(tre, SIGMAS, start=base), plain, rep)
    rows.append(("robust", "trefoil", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f}", *size_cols(tre_size)))
    bez = exact(load_problem(ROOT / "problems/bezier-b.toml").problem)
    bez_ms, bez_it, bez_base, sh = per_iteration(lambda: design_nlp(bez), rep)
    bez_size = nlp_size(LAST[0])
    rows.append(("nlp (exact Hessian)", "Bezier (b)", f"{bez_ms:.2f}", bez_it, quality(bez_base), pct(sh), "1.00", *size_cols()))
    ms, it, r, ratio, sh = paired(lambda: design_robust(bez, SIGMAS, start=bez_base), lambda: design_nlp(bez), rep)
    rows.append(("robust", "Bezier (b)", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f}", *size_cols(bez_size)))

    # obstacles: the rows' solves (like clearance, an active set: interpreted structure, small blocks compiled)
    for name, label in (("obstacle-pipe-bend", "pipe bend, 5 capsules"), ("obstacle-mesh", "mesh, 360 triangles")):
        # the rows' solves use the exact Hessian: the plain NLP to compare with does too; the obstacle design starts
        # from design_nlp(problem), as `vine-nlp design` does (a mesh's active-set loop is sensitive to its start:
        # from the design of the problem without obstacles, 1e-6 away, obstacle-mesh ends on the block's far side)
        pb = load_problem(ROOT / f"problems/{name}.toml").problem
        nb = exact(dataclasses.replace(pb, obstacles=()))
        ob_ms, ob_it, ob_base, sh = per_iteration(lambda: design_nlp(nb), rep)  # noqa: B023
        ob_size = nlp_size(LAST[0])
        rows.append(("nlp (exact Hessian)", f"{name} without its obstacles", f"{ob_ms:.2f}", ob_it, quality(ob_base), pct(sh), "1.00",
                     *size_cols()))
        ob_free = design_nlp(pb)
        ONLY_TERM[0] = "obstacles"  # like ipopt_iterations: the solves with rows
        ms, it, r, ratio, sh = paired(lambda: design_with_obstacles(pb, start=ob_free), lambda: design_nlp(nb), rep)  # noqa: B023
        ONLY_TERM[0] = None
        rows.append(("obstacles", f"{label} ({r.stats['obstacle_rounds']} solves with rows, min gap "
                     f"{r.metrics['min_obstacle_gap']:.4g} for margin {pb.obstacle_margin:g})", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f}",
                     *size_cols(ob_size)))

    end = chain_frames(base.routing.theta, base.routing.lam, base.routing.length, tre.diameter, base.routing.initial_pose)
    T0 = end[0]
    tip = TipProblem("tip", tre.diameter, end[-1][:3, 3], float(base.routing.length.sum()), base.routing.segments,
                     direction=end[-1][:3, 0], initial_pose=T0, actuator=tre.actuator, options=tre.options)
    ms, it, r, ratio, sh = paired(lambda: design_tip(tip, starts=1), plain, rep)
    rows.append(("tip", f"trefoil's tip, M = 40 ({r.status})", f"{ms:.2f}", it, quality(r), pct(sh), f"{ratio:.2f}", *size_cols(tre_size)))

    names = ("trefoil-m4", "multishape-spam", "tip-target")
    runs = [[command_time(ROOT / f"problems/{p}.toml") for p in names] for _ in range(rep)]  # the three in turn, each round
    cmd_rows = []
    for k, p in enumerate(names):
        t, c = (statistics.median(x[k][i] for x in runs) for i in (0, 1))
        rt, rc = (statistics.median(x[k][i] / x[0][i] for x in runs) for i in (0, 1))
        cmd_rows.append((p, f"{t:.2f}", f"{rt:.2f}", f"{c:.2f}", f"{rc:.2f}", f"{runs[-1][k][2]:.6g}", f"{runs[-1][k][3]:.3g}"))
    load = f"Load average (1, 5, 15 min) at the start {', '.join(f'{v:.1f}' for v in load0)}, at the end " + \
        ", ".join(f"{v:.1f}" for v in os.getloadavg()) + " (2 cores)."
    write_report(
        "transcription",
        "One transcription: time per iteration of every formulation",
        "Each formulation is terms, rows and blocks on design.transcription; per-stage blocks carry their own SX "
        "derivatives. Median over the timed calls of (IPOPT time / IPOPT iterations), the solvers already built, same "
        f"start (clearance: summed over its active-set solves; IPOPT's time: {args.clock} clock); ratio: the median over the "
        "timed calls of the ratio to the plain NLP on the same target and structure, timed right before each call. Goals: "
        "<= 1.5x (robust <= 4x). Objective: the design's (units of D^2; the tip's: actuation and tie-break). In functions: "
        "the share of IPOPT's time spent in the NLP's functions (objective, rows, their derivatives; CasADi's CPU timers), "
        "the rest is IPOPT's own, mostly factorizing the KKT matrix (clearance pairs couple segments a turn apart: "
        "a much denser factor than the banded chain's). Iterations: of the last timed call, in parentheses those on "
        "which IPOPT corrected the KKT matrix's inertia (a nonconvex step: the matrix is factorized again, at least "
        "twice per such iteration; the tip's path to its few sharp bends and the obstacle rows' curvature). NLP: the "
        "last counted solve's variables, equality / inequality rows, and nonzeros of the constraint Jacobian and of the "
        "Lagrangian Hessian's upper triangle; KKT nonzeros ratio: J + H + one per variable, equality row and (with its "
        "slack) two per inequality row, against the plain NLP's on the same target: the matrix IPOPT factorizes at "
        "least once per iteration. Clearance pairs also fill the factor beyond these nonzeros (they couple segments a "
        "turn apart). One BLAS thread (design.blas).",
        f"NLP functions: VINE_NLP_CODEGEN={compiled.mode()}. Clearance and obstacles, whose active sets change the "
        "structure, run it interpreted with each block type under design.compiled.BLOCK_BUDGET compiled on its own "
        "(the segment, the pose, the clearance pairs; an obstacle block, over it, as a map of its one-sample block). " + load,
        table(("formulation", "target", "ms / iteration", "iterations (inertia corrected)", "objective", "in functions", "ratio",
               "NLP: variables, rows = / >=, nonzeros J + H", "KKT nonzeros ratio"), rows),
        "Command start to archive (`vine-nlp design P.toml`, whole process; the three commands in turn, "
        f"{rep} rounds, medians of the times and of the per-round ratios; goal: multishape and tip <= 2x the trefoil), "
        "with the archived design's objective and RMSE "
        "(problem units; the tip's: its tip error):",
        table(("problem", "elapsed s", "ratio to trefoil", "CPU s", "CPU ratio", "objective", "rmse"), cmd_rows),
    )
    print("\n".join(" | ".join(map(str, r)) for r in cmd_rows))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
