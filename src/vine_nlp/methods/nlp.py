"""Inverse design as ONE nonlinear program, solved with IPOPT (the plain formulation).

The chain's multiple-shooting transcription (methods.transcription) with the point fit, the tip paired
with the chain's end, and the smoothness penalties:

  J = (1/N) sum_k |r_c(k) - r_cd(k)|^2 / D^2
      + w_theta (1/L) int (D dtheta/ds)^2 ds + w_lambda (1/L) int (D dlambda/ds)^2 ds,

the derivative integrals on the target's arc length so the penalties mean the same at any discretization
(they replace the paper's low-pass filter); one lambda for an sPAM. Bounds |theta| <= theta_max,
lambda_min <= lambda <= 1, segment lengths within LENGTH_FACTOR of the target's chord of the segment
(the declarations of methods.variables).
The solver is built once per structure and cached; targets, weights and guesses are data. On the drive:
the starts (``drive.multistart``), the Hessian schedule (``solve_from``), basin hops; where the first
solve shows a corner-like target the windowed search of ``methods.corners`` follows.
"""

from __future__ import annotations

import os
import time

import numpy as np

from vine_nlp.methods import common, corners, drive, variables
from vine_nlp.methods.common import Guess, evaluate, geometric_guess, pair_points
from vine_nlp.methods.drive import TIE_RTOL
from vine_nlp.methods.settings import AUTO_GN_MAX_ITER, MAX_ITER, SEARCH_ROUNDS, TOL, WINDOW, Method, Settings
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Smoothness, SoftTip, Solution, Spec, cell_data, smoothing_steps
from vine_nlp.methods.transcription import get_solver as _get
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.pairing import Pairing
from vine_nlp.problem import DesignProblem, Result, Routing

__all__ = ["design_nlp", "solve_from", "start_guesses", "guess_from_routing", "basin_hops", "get_solver", "nlp_parameters", "TIE_RTOL"]


def nlp_spec(M: int, n: int, shared_lambda: bool, max_iter: int = MAX_ITER, tol: float = TOL, warm: bool = False,
             hessian: str = "exact", terms: tuple = (), hard: bool = False, extra: int = 0) -> Spec:
    """The plain NLP's structure and terms; more ``terms`` (with ``extra`` stage variables and ``hard`` rows): a
    formulation built on it. A Gauss-Newton solve of the plain chain from a guess declares itself so."""
    guess = hessian == "gauss-newton" and not warm and not terms
    return Spec(Structure(M, n, 1, "shared" if shared_lambda else "segment", "free", extra=extra), (Smoothness(), SoftTip()) + tuple(terms),
                hessian, Settings(max_iter, tol, warm=warm, guess=guess, hard=hard))


def extended_solver(problem: DesignProblem, pairing: Pairing, terms: tuple, extra: int = 0, max_iter: int | None = None,
                    warm: bool = False):
    """The plain NLP of ``problem`` plus ``terms`` with hard rows and ``extra`` variables per stage, exact Hessian
    (clearance, robust, obstacles); ``max_iter``: a cap below ``options.max_iter``; ``warm``: a start near the answer."""
    o = problem.options
    max_iter = o.max_iter if max_iter is None else min(o.max_iter, max_iter)
    return _get(nlp_spec(pairing.segments, pairing.n, problem.actuator.shared_lambda, max_iter, o.tol, warm=warm, terms=terms, hard=True,
                         extra=extra))


def get_solver(M: int, n: int, shared_lambda: bool, max_iter: int = MAX_ITER, tol: float = TOL, warm: bool = False, hessian: str = "exact"):
    """The plain NLP's solver, cached per structure (building costs more than one solve)."""
    return _get(nlp_spec(M, n, shared_lambda, max_iter, tol, warm, hessian))


def nlp_parameters(problem: DesignProblem, pairing: Pairing, R0g: np.ndarray) -> dict:
    """The plain NLP's data for ``problem`` (scaled by D): cells (fractions, paired targets, weights 1/N),
    the tip and its weight, the guess rotation, smoothing weights, arc steps between segment middles, total arc length."""
    o, D = problem.options, problem.diameter
    N = problem.target.shape[0]
    tgt = problem.target / D
    h, L = smoothing_steps(pairing.chord / D, pairing.bounds)
    return {"cells": cell_data(pairing, tgt, 1.0 / N), "R0g": R0g.ravel(order="F"), "smooth": [o.smooth_theta, o.smooth_lambda],
            "h": h, "L": L, "tip": tgt[-1], "wtip": 1.0 / N}


def design_bounds(problem: DesignProblem, pairing: Pairing) -> dict:
    """``common.design_bounds`` in units of D (the NLP's)."""
    return common.design_bounds(problem, pairing, problem.diameter)


def start_x(solver, guess: Guess, D: float, frames: str = "target") -> np.ndarray:
    """x of a guess: frames on the target (multiple shooting's advantage: the error does not accumulate
    along the chain in the first iterate) or on the chain of the guessed design."""
    if frames == "target":
        fr = guess.frames.copy()
        fr[0] = guess.initial_pose
    else:
        fr = chain_frames(guess.theta, guess.lam, guess.length, D, guess.initial_pose)
    fr[:, :3, 3] /= D
    pose = np.r_[np.zeros(3), guess.initial_pose[:3, 3] / D]
    return solver.pack_x(frames12(fr)[None], poses=pose[None], theta=guess.theta, lam=guess.lam, length=guess.length / D)


def solve_from(
    problem: DesignProblem, guess: Guess | None = None, pairing: Pairing | None = None, frames: str = "target", warm: bool = False,
    method: Method | None = None,
) -> Result:
    """One solve of the inverse-design NLP for ``problem`` from ``guess`` (default: the geometric guess).

    ``frames``: "target" starts the shooting frames on the target, "chain" on the guessed design's chain;
    ``warm``: IPOPT's warm-start options; ``method``: how (default ``Method.of(problem.options)``). Its
    ``hessian`` "auto" (default) is the drive's Hessian
    schedule: Gauss-Newton (several times cheaper per iteration, and a true KKT point where it converges)
    for settings.AUTO_GN_MAX_ITER iterations, then the exact Hessian from the same start, or from
    Gauss-Newton's "acceptable" point (a polish).
    """
    m = method or Method.of(problem.options)
    pairing = pairing or pair_points(problem.target, problem.options.points_per_segment)
    guess = guess or geometric_guess(problem, pairing)
    if m.hessian != "auto":
        return _solve(problem, guess, pairing, frames, warm, m.hessian, m.max_iter, m)

    def step(hessian, max_iter, previous):
        if previous is None:
            r = _solve(problem, guess, pairing, frames, warm, hessian, max_iter, m)
            r.hessian = hessian
        elif previous.status == "acceptable":  # the exact Hessian polishes Gauss-Newton's acceptable point
            r = _solve(problem, guess_from_routing(problem, pairing, previous.routing), pairing, "chain", True, hessian, max_iter, m)
            r.hessian = "exact, polishing gauss-newton's acceptable point"
        else:
            r = _solve(problem, guess, pairing, frames, warm, hessian, max_iter, m)
            r.hessian = "exact (after gauss-newton did not converge)"
        r.stats["hessian"] = r.hessian  # archived
        return r

    return drive.schedule(step, (("gauss-newton", min(m.max_iter, AUTO_GN_MAX_ITER)), ("exact", m.max_iter)))


def _solve(problem, guess, pairing, frames, warm, hessian, max_iter, method: Method | None = None) -> Result:
    D, method = problem.diameter, method or Method.of(problem.options)
    M, n = pairing.segments, pairing.n
    R0g = guess.initial_pose[:3, :3]
    data = nlp_parameters(problem, pairing, R0g)
    bounds = design_bounds(problem, pairing) | ({} if method.band is None else {"lam": method.band})
    solver = get_solver(M, n, problem.actuator.shared_lambda, max_iter, method.tol, warm, hessian)
    lbx, ubx = solver.bounds(**bounds)
    sol = solver.solve(start_x(solver, guess, D, frames), solver.pack_params(data), lbx, ubx)
    band = {} if method.band is None else {"lambda_band": True}
    return result_of(problem, pairing, sol, R0g, "nlp", method=method, max_iter=max_iter, hessian=hessian, **band)


def result_of(problem, pairing, sol: Solution, R0g, run, method: Method | None = None, **extra) -> Result:
    """A Result (run ``run``) of a solution of the plain NLP or a formulation built on it, solved by ``method``
    (default the problem's options'); ``extra``: more stats (archived)."""
    o, m, st = problem.options, method or Method.of(problem.options), dict(sol.stats)
    stats = st | {"segments": pairing.segments, "points_per_segment": pairing.n, "smooth_theta": o.smooth_theta,
                  "smooth_lambda": o.smooth_lambda, "tol": m.tol, "max_iter": m.max_iter} | extra
    return evaluate(problem, sol.routing(problem.diameter, R0g), pairing, run, status=sol.status, solve_time_s=stats.pop("solve_time_s"),
                    iterations=stats.pop("iterations"), stats=stats, objective=sol.objective, hessian=str(stats["hessian"]))


def start_guesses(problem: DesignProblem, pairing: Pairing, starts: int) -> list[Guess]:
    """The starts of a multi-start, deterministic for a given ``options.seed``.

    Start 0 is the geometric guess; start 1 the same guess with the other choice of
    side at bending reversals (its mirror for planar targets); further starts perturb
    theta and lambda of start 0 or 1 randomly inside the bounds (the symmetry
    breaking and the spread that decide more than solver options do).
    """
    guesses = [geometric_guess(problem, pairing, +1.0)]
    if starts > 1:
        guesses.append(geometric_guess(problem, pairing, -1.0))
    rng = np.random.default_rng(problem.options.seed)
    a = problem.actuator
    for k in range(2, starts):
        base = guesses[k % 2]
        theta = variables.perturb(variables.THETA, base.theta, rng, a)
        lam = variables.perturb(variables.LAM, base.lam, rng, a)
        if a.shared_lambda:
            lam = np.full_like(lam, variables.draw(variables.LAM, rng, a))
        guesses.append(Guess(theta, lam, base.length, base.initial_pose, base.frames))
    return guesses


def _solve_start(args):
    problem, guess, frames, warm, method = args
    return solve_from(problem, guess, frames=frames, warm=warm, method=method)


def chain_guess(problem: DesignProblem, routing: Routing) -> Guess:
    """A start on a routing's own chain (frames where the routing puts them)."""
    return Guess(routing.theta, routing.lam, routing.length, routing.initial_pose,
                 chain_frames(routing.theta, routing.lam, routing.length, problem.diameter, routing.initial_pose))


def guess_from_routing(problem: DesignProblem, pairing: Pairing, routing: Routing) -> Guess:
    """A warm start from an earlier design: resampled onto this problem's segments if their count differs."""
    M = pairing.segments
    if routing.segments == M:
        theta, lam, length = routing.theta, routing.lam, routing.length
    else:
        s_old = (np.arange(routing.segments) + 0.5) / routing.segments
        s_new = (np.arange(M) + 0.5) / M
        theta = np.interp(s_new, s_old, routing.theta)
        lam = np.interp(s_new, s_old, routing.lam)
        length = np.full(M, routing.length.sum() / M)
    theta, lam = variables.clip({"theta": theta, "lam": lam}, variables.box(problem.actuator, np.zeros(M), only=("theta", "lam"))).values()
    if problem.actuator.shared_lambda:
        lam = np.full(M, float(np.mean(lam)))
    frames = chain_frames(theta, lam, length, problem.diameter, routing.initial_pose)
    return Guess(theta, lam, length, routing.initial_pose.copy(), frames)


def design_nlp(
    problem: DesignProblem, starts: int | None = None, workers: int = 1, warm: Routing | None = None, progress=None, hops: int | None = None,
    budget: float | None = None, note=None, method: Method | None = None,
) -> Result:
    """Inverse design as one NLP: multi-start (``method.starts``, the drive's ranking), then ``method.hops``
    rounds of basin hopping, or, where the design shows a corner-like target and no hops were asked for,
    the windowed corner search within ``budget`` seconds (default ``method.budget``; 0: none; two threads
    where the machine has two cores, the same result as one). ``warm``: one start from an earlier design
    (frames on its chain); ``workers`` > 1: the starts in a process pool; ``progress(done, total)`` after
    each start, hop and window; ``note(line)``: one line per round of the corner search; ``method``: how
    (default ``Method.of(problem.options)``; ``starts``, ``hops``, ``budget`` override its own).
    """
    m = method or Method.of(problem.options)
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    n_hops = max(0, m.hops if hops is None else hops)
    if warm is not None:
        jobs = [(problem, guess_from_routing(problem, pairing, warm), "chain", True, m)]
    else:
        n = max(1, m.starts if starts is None else starts)
        jobs = [(problem, g, "target", False, m) for g in start_guesses(problem, pairing, n)]
    total = len(jobs) + n_hops
    stats = drive.Stats()
    found = drive.multistart(_solve_start, jobs, workers=workers, progress=progress and (lambda done, _: progress(done, total)))
    best = drive.record_starts(found, stats)
    if warm is not None:
        best.stats["warm_start"] = True
    if n_hops:
        return stats.stamp(basin_hops(problem, best, n_hops, pairing, lambda k: progress and progress(len(jobs) + k, total), stats, m))
    budget, left = m.budget if budget is None else budget, drive.remaining()  # left: of the whole design's drive.budget
    if budget > 0 and corners.corner_like(problem, best):
        best = _corner_search(problem, best, pairing, budget if left is None else min(budget, left), workers, progress, note, len(jobs), m)
        if best.stats["search_budget_hit"]:
            drive.spent(best.stats["search_rounds"], SEARCH_ROUNDS, "corner search rounds")
        best.solve_time_s = time.perf_counter() - stats.started
        return best
    return stats.stamp(best)


def _corner_search(problem, best, pairing, budget, workers, progress, note, done, m: Method) -> Result:
    """corners.search with the full NLP as its polish: exact Hessian, frames on the design's chain, IPOPT's
    ordinary start (the windows' changes leave the design away from a KKT point: warm-start options cost
    more iterations there)."""
    def polish(routing: Routing) -> Result:
        r = _solve(problem, guess_from_routing(problem, pairing, routing), pairing, "chain", False, "exact", m.max_iter, m)
        r.stats["hessian"] = r.hessian = "exact (corner search polish)"
        return r

    threads = max(workers, min(2, os.cpu_count() or 1))
    report = (lambda k, total: progress(done + k, done + total)) if progress else None
    return corners.search(problem, best, pairing, polish, budget=budget, workers=threads, progress=report, note=note)


def basin_hops(problem: DesignProblem, result: Result, hops: int, pairing: Pairing | None = None, progress=None,
               stats: drive.Stats | None = None, method: Method | None = None) -> Result:
    """Basin hopping for rugged targets (corners): ``hops`` rounds of re-drawing theta and lambda of
    settings.WINDOW neighbouring segments (uniformly inside the bounds; the rest of the design, its lengths
    and frames kept) and solving again, keeping the better design (``drive.pick_best``). The window's middle
    segment is drawn with probability proportional to its squared error: the search goes where the design
    misses the target (a polyline's corners, separate local minima no single descent crosses).
    Deterministic for the method's seed; every hop's solves count in ``stats``. Stats hops, hops_accepted,
    hop_objectives, hop_iterations.
    """
    m, a = method or Method.of(problem.options), problem.actuator
    if m.hessian == "auto" and result.hessian.startswith("exact"):
        # Gauss-Newton did not converge on this target: do not try it again on every hop
        m = m.with_(hessian="exact")
    pairing = pairing or pair_points(problem.target, problem.options.points_per_segment)
    M = pairing.segments
    rng = np.random.default_rng([m.seed, 1])  # a stream apart from start_guesses'
    best, objectives, iterations, accepted = result, [], [], 0
    for k in range(hops):
        if drive.spent(k, hops, "hops"):
            break
        per_segment = corners.error_per_segment(problem, pairing, best) + 1e-300
        j = int(rng.choice(M, p=per_segment / per_segment.sum()))
        start = max(0, min(j - WINDOW // 2, M - WINDOW))
        w = slice(start, start + WINDOW)
        old = best.routing
        theta, lam = old.theta.copy(), old.lam.copy()
        theta[w] = variables.draw(variables.THETA, rng, a, theta[w].shape)
        if not a.shared_lambda:  # one shared lambda is not a property of a window
            lam[w] = variables.draw(variables.LAM, rng, a, lam[w].shape)
        # multiple shooting: frames inside the window follow the new values, the others stay where
        # the design put them, so the only continuity defect is at the window's end
        frames = chain_frames(old.theta, old.lam, old.length, problem.diameter, old.initial_pose)
        frames[start + 1 : start + WINDOW] = chain_frames(theta, lam, old.length, problem.diameter, old.initial_pose)[start + 1 : start + WINDOW]
        guess = Guess(theta, lam, old.length.copy(), old.initial_pose.copy(), frames)
        r = solve_from(problem, guess, pairing, frames="target", method=m)
        if stats is not None:
            stats.absorb(r)
        objectives.append(r.objective)
        iterations.append(r.iterations)
        if drive.pick_best([best, r]) == 1:
            best, accepted = r, accepted + 1
        if progress:
            progress(k + 1)
    best.stats |= {"hops": hops, "hops_accepted": accepted, "hop_objectives": objectives, "hop_iterations": iterations}
    return best
