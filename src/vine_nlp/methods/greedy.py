"""The paper's greedy look-ahead design (Algorithm 1), as a faithful baseline for the NLP.

Algorithm (Blumenschein et al., IEEE T-RO 2021, Sec. VI-B): window 1 fits the initial pose (a rotation
vector relative to the geometric guess's rotation, plus a position) and segments 1..k together; each later
window of k segments starting at j is refit with everything before it fixed (its start frame a numeric
parameter), the windows shrinking near the tip (M windows in all). After window j, segment j is fixed; the
window's other values start the next window, and the segment entering it starts from its fitted
neighbour's theta and lambda, its length scaled to its own chord. First-window values as in the paper:
lambda 0.75, theta 0, dl the segment's target chord.

Shared with the NLP so that a comparison is about the algorithm: the pairing (``common.pair_points``), the
bounds (``common.design_bounds``), the segment model and the error: the window error is the sum of
SQUARED distances of the paired points from the window's start to its end (``common.path_error``, what the
NLP minimizes; the paper's sum of distances is not differentiable at a perfect fit and is used only for the
sPAM abandonment test, where its threshold is defined).

Each window is a small single-shooting NLP (:class:`WindowSolver`, D = 1), built once per window size and
variant and reused. Multi-start (for MATLAB's GlobalSearch with 2000 / 300 trial points): start 0 is the
carried-over values, the others draw theta and lambda uniformly in a box of half-width settings.GREEDY_SPREAD x (bound
range) around them (``options.greedy_starts``, settings.FIRST_WINDOW_FACTOR times more for the first window); the
best is kept.

sPAM (one shared lambda): an outer loop runs the greedy for each of settings.SPAM_CANDIDATES values in
[lambda_min, 1], then settings.SPAM_REFINE values within half a step of the best; a candidate is abandoned as soon as
a window's sum of distances reaches n k D / 2 (the paper's early stop). ``lowpass`` is the paper's optional
low-pass filter of theta(s) and lambda(s) (zero-phase Butterworth), re-evaluated so its cost shows.
"""

from __future__ import annotations

import dataclasses
import math
import time
from functools import lru_cache
from typing import Callable

import casadi as ca
import numpy as np

from vine_nlp.analysis.buildability import pieces
from vine_nlp.methods import blas, settings, variables
from vine_nlp.methods.buildable import Build, chain_bends, classify, lambda_bounds, unwind
from vine_nlp.methods.common import Pairing, clip_to_bounds, design_bounds, evaluate, geometric_guess, pair_points, path_error
from vine_nlp.methods.transcription import ipopt_status
from vine_nlp.model.chain import chain_points
from vine_nlp.model.segment import segment_parts, segment_transform, so3_exp
from vine_nlp.problem import DesignProblem, Result, Routing

__all__ = ["design_greedy", "design_greedy_buildable", "lowpass", "WindowSolver", "get_window_solver"]



# ---------------------------------------------------------------- the window NLP


class WindowSolver:
    """Single-shooting NLP of one window: K segments, n slots per segment, D = 1.

    Decision vector: [w (3), dp (3)] if ``first`` (pose: rotation vector relative to
    the parameter R0, position offset from the parameter p0), then per segment
    theta, lambda (unless ``shared``), dl.
    Parameters: R0 (9, column-major), p0 (3), slot targets (3 x nK), slot weights
    (nK), slot fractions (n x K), end target (3), lambda (1; used when ``shared``).
    Objective: sum_slots w |r - r_d|^2 + |r_end - r_end,d|^2 (D-scaled).
    """

    def __init__(self, K: int, n: int, first: bool, shared: bool, max_iter: int = settings.GREEDY_WINDOW_MAX_ITER, tol: float = settings.TOL):
        t0 = time.perf_counter()
        self.K, self.n, self.first, self.shared = K, n, first, shared
        self.per_seg = 2 if shared else 3
        self.npose = 6 if first else 0
        self.size = self.npose + self.per_seg * K
        x = ca.SX.sym("x", self.size)
        P_R0, P_p0, P_tgt = ca.SX.sym("R0", 9), ca.SX.sym("p0", 3), ca.SX.sym("tgt", 3, n * K)
        P_w, P_u, P_end, P_lam = ca.SX.sym("w", n * K), ca.SX.sym("u", n, K), ca.SX.sym("end", 3), ca.SX.sym("lam")
        params = [P_R0, P_p0, P_tgt, P_w, P_u, P_end, P_lam]
        self._param_sizes = [q.numel() for q in params]

        R = ca.reshape(P_R0, 3, 3)
        p = P_p0
        if first:
            R = ca.mtimes(R, so3_exp(x[0:3]))
            p = p + x[3:6]
        sq = dist = 0
        for c in range(K):
            off = self.npose + self.per_seg * c
            theta = x[off]
            lam = P_lam if shared else x[off + 1]
            dl = x[off + self.per_seg - 1]
            for s in range(n):
                _, q = segment_parts(theta, lam, P_u[s, c] * dl, 1.0)
                d = p + ca.mtimes(R, ca.vertcat(*q)) - P_tgt[:, c * n + s]
                d2 = ca.dot(d, d)
                sq += P_w[c * n + s] * d2
                dist += P_w[c * n + s] * ca.sqrt(d2)
            Rs, ps = segment_parts(theta, lam, dl, 1.0)
            p = p + ca.mtimes(R, ca.vertcat(*ps))
            R = ca.mtimes(R, ca.vertcat(*[ca.horzcat(*row) for row in Rs]))
        d = p - P_end
        sq += ca.dot(d, d)
        dist += ca.sqrt(ca.dot(d, d))
        pvec = ca.vertcat(*[ca.vec(q) for q in params])
        # the n slots of a segment repeat its helix rates: merging them speeds up the build
        sq, dist = ca.vertsplit(ca.cse(ca.vertcat(sq, dist)))
        opts = settings.quiet(max_iter, tol) | settings.GREEDY_WINDOW
        blas.one_thread()
        self.solver = ca.nlpsol(f"greedy_window_{K}", "ipopt", {"x": x, "p": pvec, "f": sq}, opts)
        self.terms = ca.Function("window_terms", [x, pvec], [sq, dist])
        self.build_time_s = time.perf_counter() - t0

    # -- packing ---------------------------------------------------------------------------------

    def pack_params(self, R0, p0, tgt, w, u, end, lam) -> np.ndarray:
        vals = [np.asarray(R0, float).ravel(order="F"), p0, np.asarray(tgt, float).ravel(order="F"), w,
                np.asarray(u, float).ravel(order="F"), end, [lam]]
        out = np.concatenate([np.asarray(v, float).ravel() for v in vals])
        assert out.size == sum(self._param_sizes)
        return out

    def pack_x(self, theta, lam, dl, pose=None) -> np.ndarray:
        cols = [theta, dl] if self.shared else [theta, lam, dl]
        x = np.vstack([np.asarray(c, float).reshape(-1) for c in cols]).ravel(order="F")
        if self.first:
            x = np.concatenate([np.zeros(6) if pose is None else pose, x])
        return x

    def unpack_x(self, x):
        x = np.asarray(x, float).ravel()
        pose = x[: self.npose]
        st = x[self.npose :].reshape(self.per_seg, self.K, order="F")
        return pose, st[0], None if self.shared else st[1], st[-1]  # pose, theta, lam, dl

    def bounds(self, lo, hi):
        """Box bounds from per-segment (theta, lam, dl) bounds of the window's segments (scaled)."""
        rows = [0, 2] if self.shared else [0, 1, 2]
        lbx = np.vstack([lo[r] for r in rows]).ravel(order="F")
        ubx = np.vstack([hi[r] for r in rows]).ravel(order="F")
        if self.first:
            lbx = np.concatenate([np.full(6, -np.inf), lbx])
            ubx = np.concatenate([np.full(6, np.inf), ubx])
        return lbx, ubx


@lru_cache(maxsize=64)
def get_window_solver(K: int, n: int, first: bool, shared: bool, max_iter: int = settings.GREEDY_WINDOW_MAX_ITER, tol: float = settings.TOL) -> WindowSolver:
    """Cached window solver: one per window size and variant, reused for every window."""
    return WindowSolver(K, n, first, shared, max_iter, tol)


def _window_data(problem: DesignProblem, pairing: Pairing, j: int, K: int):
    """Slot targets, weights and fractions (D-scaled) of the window of segments j..j+K-1.

    Segment i's slots hold the target points bounds[i] .. bounds[i+1]-1 (seg == i);
    the window's end point bounds[j+K] pairs with the end of segment j+K-1 (for the
    tip this is the pairing's own rule; elsewhere it is the start of segment j+K,
    the same point).
    """
    n, D = pairing.n, problem.diameter
    b = pairing.bounds
    tgt = np.zeros((3, n * K))
    w = np.zeros(n * K)
    u = np.zeros((n, K))
    for c in range(K):
        i = j + c
        idx = np.arange(b[i], b[i + 1])
        assert np.all(pairing.seg[idx] == i)
        s = idx - b[i]
        tgt[:, c * n + s] = problem.target[idx].T / D
        w[c * n + s] = 1.0
        u[s, c] = pairing.frac[idx]
    end = problem.target[b[j + K]] / D
    return tgt, w, u, end


def _window_solver_for(problem, n, K, first):
    o = problem.options
    return get_window_solver(K, n, first, problem.actuator.shared_lambda,
                             min(int(o.max_iter), settings.GREEDY_WINDOW_MAX_ITER), float(o.tol))


# ---------------------------------------------------------------- one greedy pass


class _Counter:
    def __init__(self, total: int, progress: Callable | None):
        self.done, self.total, self.progress = 0, total, progress

    def step(self, k: int = 1):
        if k <= 0:
            return
        self.done = min(self.total, self.done + k)
        if self.progress is not None:
            self.progress(self.done, self.total)


def _greedy_pass(problem: DesignProblem, pairing: Pairing, counter: _Counter, lam_fixed: float | None = None,
                 abandon_at: float | None = None, bounds: dict | None = None) -> dict:
    """Algorithm 1 once (per-segment lambda, or a fixed shared lambda when ``lam_fixed`` is given); ``bounds``:
    per-segment bounds (lo, hi) of "theta" or "lam" instead of the actuator's."""
    o = problem.options
    D = problem.diameter
    M, k = pairing.segments, max(1, int(o.lookahead))
    shared = lam_fixed is not None
    rng = np.random.default_rng(o.seed)
    box = design_bounds(problem, pairing) | (bounds or {})
    (tl, tu), (ll, lu), (dlo, dhi) = box["theta"], box["lam"], box["length"]
    chord = pairing.segment_chord

    theta, lam, dl = variables.clip({"theta": np.zeros(M), "lam": np.full(M, float(lam_fixed) if shared else settings.LAMBDA_START),
                                     "length": chord}, box).values()
    guess = geometric_guess(problem, pairing)
    T = guess.initial_pose.copy()  # frame at the current window's start (fixed numeric parameter)
    T0 = T.copy()

    starts_first = settings.FIRST_WINDOW_FACTOR * max(1, int(o.greedy_starts))
    starts_later = max(1, int(o.greedy_starts))
    tally = {"solves": 0, "iterations": 0, "statuses": {}}
    window_status, window_sq, window_dist = [], [], []
    abandoned = False
    for j in range(M):
        K = min(k, M - j)
        first = j == 0
        solver = _window_solver_for(problem, pairing.n, K, first)
        sl = slice(j, j + K)
        tgt, w, u, end = _window_data(problem, pairing, j, K)
        p = solver.pack_params(T[:3, :3], T[:3, 3] / D, tgt, w, u, end, lam_fixed if shared else 0.0)
        lbx, ubx = solver.bounds((tl[sl], ll[sl], dlo[sl] / D), (tu[sl], lu[sl], dhi[sl] / D))
        x_carry = np.clip(solver.pack_x(theta[sl], lam[sl], dl[sl] / D), lbx, ubx)
        best = _window_starts(solver, p, lbx, ubx, x_carry, starts_first if first else starts_later, shared, K, rng, tally)
        f, x, status = best
        window_status.append(status)
        pose, th_w, lam_w, dl_w = solver.unpack_x(x)
        theta[sl] = th_w
        if not shared:
            lam[sl] = lam_w
        dl[sl] = dl_w * D
        if first:
            T0 = np.eye(4)
            T0[:3, :3] = guess.initial_pose[:3, :3] @ so3_exp(pose[:3])
            T0[:3, 3] = guess.initial_pose[:3, 3] + pose[3:] * D
            T = T0.copy()
        sq, dist = (float(v) for v in solver.terms(x, p))
        window_sq.append(sq * D**2)
        window_dist.append(dist * D)
        # fix segment j: the next window starts at its end
        T = T @ segment_transform(theta[j], lam[j], dl[j], D)
        # the segment entering the next window starts from its fitted neighbour
        nxt = j + K
        if nxt < M and K == k:
            theta[nxt] = np.clip(theta[nxt - 1], tl[nxt], tu[nxt])
            lam[nxt] = np.clip(lam[nxt - 1], ll[nxt], lu[nxt])
            dl[nxt] = np.clip(chord[nxt] * dl[nxt - 1] / chord[nxt - 1], dlo[nxt], dhi[nxt])
        counter.step()
        if abandon_at is not None and window_dist[-1] >= abandon_at:
            abandoned = True
            counter.step(M - 1 - j)
            break
    return tally | {"routing": Routing(theta=theta, lam=lam, length=dl, initial_pose=T0), "window_status": window_status, "window_sq": window_sq, "window_dist": window_dist, "abandoned": abandoned,
            "windows_done": len(window_status), "starts": (starts_first, starts_later)}


def _window_starts(solver, p, lbx, ubx, x_carry, starts: int, shared: bool, K: int, rng, tally: dict) -> tuple:
    """One window from ``starts`` starts: the carried-over values, then theta and lambda uniformly in a box
    around them inside the bounds; (objective, x, status) of the lowest (the carried-over values where every
    start failed numerically). ``tally``: solves, iterations and IPOPT's statuses, counted."""
    best = None
    for s in range(starts):
        x0 = x_carry.copy()
        if s > 0:
            for r in ([0] if shared else [0, 1]):
                idx = solver.npose + r + solver.per_seg * np.arange(K)
                half = settings.GREEDY_SPREAD * (ubx[idx] - lbx[idx])
                x0[idx] = rng.uniform(np.maximum(lbx[idx], x_carry[idx] - half), np.minimum(ubx[idx], x_carry[idx] + half))
        sol = solver.solver(x0=x0, p=p, lbx=lbx, ubx=ubx)
        st = solver.solver.stats()
        status = ipopt_status(st)
        tally["solves"] += 1
        tally["iterations"] += int(st.get("iter_count", 0))
        rs = st.get("return_status", "failed")
        tally["statuses"][rs] = tally["statuses"].get(rs, 0) + 1
        f = float(sol["f"])
        x = np.clip(np.array(sol["x"]).ravel(), lbx, ubx)  # IPOPT may relax bounds by ~1e-8
        if np.isfinite(f) and np.all(np.isfinite(x)) and (best is None or f < best[0]):
            best = (f, x, status)
    if best is None:
        f_c, _ = solver.terms(x_carry, p)
        best = (float(f_c), x_carry, "invalid_number")
    return best


def _overall_status(window_status) -> str:
    bad = [s for s in window_status if s not in ("optimal", "acceptable")]
    return bad[0] if bad else ("acceptable" if "acceptable" in window_status else "optimal")


def _total_error(problem, pairing, routing) -> float:
    pts, _ = chain_points(routing.theta, routing.lam, routing.length, problem.diameter, pairing.seg, pairing.frac, routing.initial_pose)
    return path_error(pts, problem.target)


# ---------------------------------------------------------------- public API


def design_greedy(problem: DesignProblem, pairing: Pairing | None = None, progress: Callable[[int, int], None] | None = None,
                  bounds: dict | None = None) -> Result:
    """The paper's greedy Algorithm 1 (sPAM variant when ``problem.actuator.kind == "spam"``).

    ``progress(done, total)``, if given, is called after each window solve round. ``bounds``: per-segment
    bounds (lo, hi) of "theta" or "lam" instead of the actuator's (sPAM: the lambda candidates span lo[0] to hi[0]).
    Returns a Result with method "greedy"; ``stats`` records window solves, windows,
    starts per window, the lookahead and (sPAM) the lambda candidates.
    """
    t_start = time.perf_counter()
    o = problem.options
    pairing = pairing or pair_points(problem.target, o.points_per_segment)
    M = pairing.segments
    k = max(1, int(o.lookahead))
    stats: dict = {"lookahead": k, "windows": M, "points_per_segment": pairing.n, "segments": M,
                   "greedy_starts": int(o.greedy_starts), "seed": int(o.seed), "error": "sum of squared distances"}

    if not problem.actuator.shared_lambda:
        counter = _Counter(M, progress)
        best = _greedy_pass(problem, pairing, counter, bounds=bounds)
        runs = [best]
    else:
        a = problem.actuator
        threshold = pairing.n * k * problem.diameter / 2.0
        total = M * (settings.SPAM_CANDIDATES + settings.SPAM_REFINE)
        counter = _Counter(total, progress)
        runs, tried = [], []

        def run_candidate(lam_c, abandon=True):
            r = _greedy_pass(problem, pairing, counter, lam_fixed=float(lam_c), abandon_at=threshold if abandon else None, bounds=bounds)
            r["lambda"] = float(lam_c)
            r["error"] = math.inf if r["abandoned"] else _total_error(problem, pairing, r["routing"])
            runs.append(r)
            tried.append(float(lam_c))
            return r

        span = (a.lambda_min, 1.0) if "lam" not in (bounds or {}) else (float(bounds["lam"][0][0]), float(bounds["lam"][1][0]))
        grid = np.linspace(*span, settings.SPAM_CANDIDATES)
        for lam_c in grid:
            run_candidate(lam_c)
        step = grid[1] - grid[0] if grid.size > 1 else 0.0
        done = [r for r in runs if not r["abandoned"]]
        refine_new = 0
        if done and step > 0:
            center = min(done, key=lambda r: r["error"])["lambda"]
            for lam_c in np.linspace(center - step / 2, center + step / 2, settings.SPAM_REFINE):
                lam_c = float(np.clip(lam_c, *span))
                if any(abs(lam_c - t) < 1e-12 for t in tried):
                    continue
                run_candidate(lam_c)
                refine_new += 1
        counter.step(M * (settings.SPAM_REFINE - refine_new))  # skipped refinement values
        done = [r for r in runs if not r["abandoned"]]
        if not done:
            # every candidate hit the threshold: finish the one that got furthest, without abandonment
            far = max(runs, key=lambda r: (r["windows_done"], -r["window_dist"][-1]))
            counter.total += M
            run_candidate(far["lambda"], abandon=False)
            done = [runs[-1]]
        best = min(done, key=lambda r: r["error"])
        stats.update({
            "lambda": best["lambda"], "lambda_candidates": [r["lambda"] for r in runs],
            "lambda_candidate_errors": [None if r["abandoned"] else r["error"] for r in runs],  # sum sq.
            "lambda_candidates_tried": len(runs), "lambda_candidates_abandoned": int(sum(r["abandoned"] for r in runs)),
            "abandoned_lambdas": [r["lambda"] for r in runs if r["abandoned"]], "abandon_threshold": threshold,
        })
    statuses: dict = {}
    for r in runs:
        for key, v in r["statuses"].items():
            statuses[key] = statuses.get(key, 0) + v
    stats.update({
        "window_solves": int(sum(r["solves"] for r in runs)), "starts_per_window": best["starts"][1],
        "starts_first_window": best["starts"][0], "return_statuses": statuses, "window_status": best["window_status"],
        "window_error_max": float(max(best["window_sq"])) if best["window_sq"] else 0.0, "solver": "ipopt (window)",
    })
    iterations = int(sum(r["iterations"] for r in runs))
    elapsed = time.perf_counter() - t_start
    counter.step(counter.total - counter.done)
    return evaluate(problem, best["routing"], pairing, "greedy", status=_overall_status(best["window_status"]),
                    solve_time_s=elapsed, iterations=iterations, stats=stats)


def _carriers(act, base_free: bool) -> np.ndarray:
    """Where the buildable greedy's line may turn: actuated segments, and the last segment of each unactuated run
    before an actuated piece (a first run's only with a fixed base: a free base rolls instead). Elsewhere theta 0:
    on a straight run only its net turning moves the shape, and a window's equal choices of it stall IPOPT."""
    out = np.array(act, bool)
    for p in pieces(out, np.ones(out.size), np.ones(out.size)):
        if not p.actuated and p.stop < out.size and (p.start > 0 or not base_free):
            out[p.stop - 1] = True
    return out


def design_greedy_buildable(problem: DesignProblem, pairing: Pairing | None = None, progress: Callable[[int, int], None] | None = None,
                            start: Result | None = None) -> Result:
    """The greedy under the buildable rules (method "greedy_buildable"): Algorithm 1 again, with the lambda bounds
    (methods.buildable.lambda_bounds: exactly 1 without an actuator, the correction margin and min_feature with one)
    of the classes its free design ``start`` (default: run here; its time counted either way) bends for (``classify`` on its
    ``chain_bends``: the greedy has no reclassification, and at a corner the target bends within one segment where
    a tube spreads it over several); then each unactuated run's turning the shortest way round (``unwind``: the
    same shape). stats buildable_actuated, buildable_free_rmse."""
    t0 = time.perf_counter()
    pairing = pairing or pair_points(problem.target, problem.options.points_per_segment)
    before = 0.0 if start is None else start.solve_time_s  # the free design's time, counted as the nlp's buildable design does
    start = start or design_greedy(problem, pairing, progress)
    build = Build.of(problem)
    act = classify(chain_bends(start.routing, problem.diameter), pairing.segment_chord, build)
    box = design_bounds(problem, pairing)
    turns = _carriers(act, build.pose is None)
    theta = (np.where(turns, box["theta"][0], 0.0), np.where(turns, box["theta"][1], 0.0))
    res = design_greedy(problem, pairing, progress, bounds={"lam": lambda_bounds(act, pairing.segment_chord, build), "theta": theta})
    # the greedy fits its own base pose, a fixed one too: its pose is the one kept
    r = unwind(res.routing, act, build if build.pose is None else dataclasses.replace(build, pose=res.routing.initial_pose))
    stats = res.stats | {"buildable": True, "buildable_actuated": int(act.sum()), "buildable_free_rmse": float(start.metrics["rmse"]),
                         "correction_margin": build.margin, "min_feature": build.min_feature}
    out = evaluate(problem, r, pairing, "greedy_buildable", status=res.status, iterations=res.iterations, stats=stats,
                   solve_time_s=before + time.perf_counter() - t0)
    out.buildable = True
    return out


def lowpass(result_or_routing, problem: DesignProblem, pairing: Pairing | None = None, cutoff: float = 0.5) -> Result:
    """The paper's optional low-pass filter of theta(s) and lambda(s) (method "greedy_filtered").

    Zero-phase Butterworth (``scipy.signal.butter`` order 2 + ``filtfilt``) along the
    segment index, ``cutoff`` as a fraction of the Nyquist frequency. Segment lengths
    and the initial pose are kept; a shared (sPAM) lambda stays as it is. A chain too
    short for filtfilt's default padding is returned unfiltered (stats["filtered"] False).
    Values are clipped to the bounds and the shape re-evaluated, so the RMSE cost shows.
    """
    from scipy.signal import butter, filtfilt

    if not 0.0 < cutoff < 1.0:
        raise ValueError("cutoff is a fraction of the Nyquist frequency: 0 < cutoff < 1")
    src = result_or_routing
    routing = src.routing if isinstance(src, Result) else src
    pairing = pairing or pair_points(problem.target, problem.options.points_per_segment)
    b, a = butter(settings.FILTER_ORDER, cutoff)
    padlen = 3 * max(len(a), len(b))
    theta, lam = routing.theta.copy(), routing.lam.copy()
    filtered = theta.size > padlen
    if filtered:
        theta = filtfilt(b, a, theta)
        if not problem.actuator.shared_lambda:
            lam = filtfilt(b, a, lam)
    new = Routing(**clip_to_bounds(problem, pairing, theta=theta, lam=lam, length=routing.length), initial_pose=routing.initial_pose)
    stats = dict(src.stats) if isinstance(src, Result) else {}
    stats.update({"filter": "butterworth+filtfilt", "filter_order": settings.FILTER_ORDER, "cutoff": float(cutoff),
                  "filtered": bool(filtered)})
    kw = {"status": src.status, "solve_time_s": src.solve_time_s, "iterations": src.iterations} if isinstance(src, Result) else {}
    return evaluate(problem, new, pairing, "greedy_filtered", stats=stats, **kw)
