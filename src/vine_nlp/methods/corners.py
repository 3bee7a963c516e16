"""Corner-like targets: a windowed search after the first solve of the design NLP (issue 18).

A target with corners (the paper's polyline (d)) has many local minima: each corner can be taken on several
sides and swings, and no single descent crosses between them. ``corner_like`` recognizes such a target from
the first solve; ``search`` then improves that design window by window:

* A *window* is W = settings.WINDOW neighbouring segments a..b-1. Everything before it is held (the frame at
  its start is a fixed number), everything after it is held *as a rigid body* attached to the window's end
  frame, so its points' error is a quadratic form in the 12 numbers of that frame (rotation R, position p):

      sum_i w_i |R q_i + p - t_i|^2 = c + W |p|^2 + 2 p.(R Q) - 2 <R, C> - 2 p.T,

  q_i the points in the end frame, Q = sum w_i q_i, C = sum w_i t_i q_i^T, T = sum w_i t_i, W = sum w_i.
  The window NLP (single shooting, a few variables) thus minimizes the *whole* design's point error over the
  window's theta, lambda and lengths.
* Each window is solved from settings.WINDOW_STARTS starts (the current values, theta mirrored, random draws inside
  the bounds), tasks for ``workers`` threads (CasADi releases the GIL inside IPOPT; each thread has its own
  solver) read back in start order; the best (``drive.pick_best``) replaces the window if it lowers the error
  by settings.WINDOW_GAIN. A round visits the settings.WINDOW_SHARE of the windows of largest error, largest first.
* A round that changed a window ends with one polish: the full NLP from the new design (exact Hessian,
  frames on its chain). The search stops after settings.SEARCH_ROUNDS, when a round changes nothing or its polish does
  not improve, or when the budget is spent (a round cut short is not polished; its changes are dropped).

Deterministic for a given ``options.seed``: a window's work does not depend on which thread ran it, and the
budget is only a safety stop (stats ``search_budget_hit`` says when it cut the search). The constants are
methods.settings'; what a round gains on the polyline (d) is in results/BENCHMARKS.md ("compare")."""

from __future__ import annotations

import queue
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import Callable

import casadi as ca
import numpy as np

from vine_nlp.methods import blas, drive, settings, variables
from vine_nlp.methods.structure import frames12
from vine_nlp.methods.transcription import ipopt_status
from vine_nlp.model.chain import chain_frames, chain_points
from vine_nlp.model.pairing import Pairing
from vine_nlp.model.routing import Routing
from vine_nlp.model.segment import segment_function
from vine_nlp.problem import DesignProblem, Result

__all__ = ["corner_like", "search", "clear_caches"]

def corner_like(problem: DesignProblem, result: Result) -> bool:
    """Whether the first solve ``result`` of ``problem`` shows a corner-like target: Gauss-Newton did not
    converge on it (``result.hessian``) and its RMSE is above settings.CORNER_RMSE tube diameters, large
    residuals the smooth paper cases never show."""
    gauss_newton = result.hessian == "gauss-newton" and result.status == "optimal"
    return (not gauss_newton) and float(result.metrics["rmse"]) > settings.CORNER_RMSE * problem.diameter


# ---------------------------------------------------------------- the window NLP


@lru_cache(maxsize=None)
def _window_nlp(W: int, n1: int, shared: bool):
    """SX of the window NLP: x per segment (theta, lam unless shared, dl); p = (X_a (12), u (n1 W),
    targets (3 n1 W, slot-major), weights (n1 W), shared lambda, tail: c, W, Q (3), C (9), T (3))."""
    per = 2 if shared else 3
    x, X = ca.SX.sym("x", per * W), ca.SX.sym("Xa", 12)
    u, tgt, w = ca.SX.sym("u", n1, W), ca.SX.sym("tgt", 3 * n1, W), ca.SX.sym("w", n1, W)
    lam_shared = ca.SX.sym("lam")
    c, Ws, Q, C, T = ca.SX.sym("c"), ca.SX.sym("W"), ca.SX.sym("Q", 3), ca.SX.sym("C", 9), ca.SX.sym("T", 3)
    seg = segment_function(n1)
    f, Xj = 0, X
    for j in range(W):
        theta = x[per * j]
        lam = lam_shared if shared else x[per * j + 1]
        Xj, pts = seg(Xj, theta, lam, x[per * j + per - 1], u[:, j])
        err = pts - ca.reshape(tgt[:, j], 3, n1)
        f = f + ca.sum2(w[:, j].T * ca.sum1(err * err))
    R, pe = ca.reshape(Xj[:9], 3, 3), Xj[9:]
    f = f + c + Ws * ca.dot(pe, pe) + 2 * ca.dot(pe, ca.mtimes(R, Q)) - 2 * ca.dot(ca.vec(R), C) - 2 * ca.dot(pe, T)
    p = ca.vertcat(X, ca.vec(u), ca.vec(tgt), ca.vec(w), lam_shared, c, Ws, Q, C, T)
    return {"x": x, "p": p, "f": f}


@lru_cache(maxsize=None)
def _window_objective(W: int, n1: int, shared: bool) -> ca.Function:
    nlp = _window_nlp(W, n1, shared)
    return ca.Function("window_f", [nlp["x"], nlp["p"]], [nlp["f"]])


@lru_cache(maxsize=None)
def _window_solver(W: int, n1: int, shared: bool, slot: int) -> ca.Function:
    """One IPOPT solver of the window NLP per thread slot: a CasADi solver keeps its workspace in
    itself, so two threads never share one."""
    opts = settings.quiet(settings.CORNER_WINDOW_MAX_ITER, settings.WINDOW_TOL) | settings.CORNER_WINDOW
    blas.one_thread()
    return ca.nlpsol(f"vine_window{slot}", "ipopt", _window_nlp(W, n1, shared), opts)


def clear_caches() -> None:
    """Forget every built window solver (benchmarks: time a cold start)."""
    for f in (_window_nlp, _window_objective, _window_solver):
        f.cache_clear()


# ---------------------------------------------------------------- one window of a design


class _Window:
    """The data of window a..b-1 of ``routing`` (units of D): start frame, slot targets, rigid tail."""

    def __init__(self, problem: DesignProblem, pairing: Pairing, routing: Routing, a: int, W: int):
        D, tgt = problem.diameter, problem.target / problem.diameter
        # slots per segment: n, one more where the window holds the tip (the last segment's extra point)
        n1 = int(np.bincount(pairing.seg, minlength=pairing.segments)[a : a + W].max())
        self.a, self.b, self.W, self.n1 = a, a + W, W, n1
        self.shared = problem.actuator.shared_lambda
        N = tgt.shape[0]
        frames = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)
        u, slots, w = np.zeros((n1, W)), np.zeros((3 * n1, W)), np.zeros((n1, W))
        for j in range(a, self.b):
            idx = np.flatnonzero(pairing.seg == j)
            k = idx - idx[0]
            u[k, j - a] = pairing.frac[idx]
            for c in range(3):
                slots[3 * k + c, j - a] = tgt[idx, c]
            w[k, j - a] = 1.0 / N
        tail = np.flatnonzero(pairing.seg >= self.b)
        c = Ws = 0.0
        Q, C, T = np.zeros(3), np.zeros((3, 3)), np.zeros(3)
        if tail.size:
            pts, _ = chain_points(routing.theta, routing.lam, routing.length, D, pairing.seg[tail], pairing.frac[tail],
                                  routing.initial_pose, frames)
            Rb, pb = frames[self.b, :3, :3], frames[self.b, :3, 3] / D
            q = (pts / D - pb) @ Rb  # the tail's points in the end frame
            t, wt = tgt[tail], np.full(tail.size, 1.0 / N)
            c = float(np.sum(wt * (np.sum(q * q, 1) + np.sum(t * t, 1))))
            Ws, Q, C, T = float(wt.sum()), wt @ q, (wt[:, None] * t).T @ q, wt @ t
        lam_shared = float(routing.lam[0]) if self.shared else 0.0
        self.p = np.r_[frames12(frames[a : a + 1], D)[:, 0], u.ravel(order="F"), slots.ravel(order="F"), w.ravel(order="F"), lam_shared,
                       c, Ws, Q, C.ravel(order="F"), T]
        a_, chord = problem.actuator, pairing.segment_chord[a : self.b] / D
        # the window's variables per segment: the routing's declared ones (no lambda where one is shared)
        self.names = [v.name for v in variables.ROUTING if not (self.shared and v.levels)]
        box = variables.box(a_, chord, only=self.names)
        self.lbx, self.ubx = (np.column_stack([box[n][i] for n in self.names]).ravel() for i in (0, 1))
        cur = {"theta": routing.theta[a : self.b], "lam": routing.lam[a : self.b], "length": routing.length[a : self.b] / D}
        self.x = np.column_stack([cur[n] for n in self.names]).ravel()
        self.per = len(self.names)

    def objective(self, x) -> float:
        return float(_window_objective(self.W, self.n1, self.shared)(x, self.p))

    def starts(self, rng, count: int) -> list[np.ndarray]:
        """The current values, theta mirrored, then random theta (and lambda) inside the bounds; ``count`` in all."""
        out = [self.x.copy()]
        mirrored = self.x.copy()
        mirrored[0 :: self.per] *= -1
        out.append(mirrored)
        while len(out) < count:
            x = self.x.copy()
            x[0 :: self.per] = rng.uniform(self.lbx[0 :: self.per], self.ubx[0 :: self.per])
            if not self.shared:
                x[1 :: self.per] = rng.uniform(self.lbx[1 :: self.per], self.ubx[1 :: self.per])
            out.append(x)
        return out[:count]

    def apply(self, routing: Routing, x, D: float) -> Routing:
        values = {"theta": routing.theta.copy(), "lam": routing.lam.copy(), "length": routing.length.copy()}
        v = np.asarray(x, float).reshape(self.W, self.per)
        for i, name in enumerate(self.names):
            values[name][self.a : self.b] = v[:, i] * D if name == "length" else v[:, i]
        return Routing(**values, initial_pose=routing.initial_pose.copy())


def _solve_start(window: _Window, x0: np.ndarray, slots: queue.SimpleQueue, stop: threading.Event):
    """Solve the window from one start on a free solver slot: (objective, x, converged, iterations), or
    None once the search is stopping. The answer does not depend on the slot (each is the same solver)."""
    if stop.is_set():
        return None
    slot = slots.get()
    try:
        solver = _window_solver(window.W, window.n1, window.shared, slot)
        sol = solver(x0=np.clip(x0, window.lbx, window.ubx), p=window.p, lbx=window.lbx, ubx=window.ubx)
        st = solver.stats()
    finally:
        slots.put(slot)
    x = np.array(sol["x"]).ravel()
    status = ipopt_status(st, x)  # an interrupted solve raises KeyboardInterrupt
    return float(sol["f"]), x, status in ("optimal", "acceptable"), int(st.get("iter_count", 0))


def error_per_segment(problem: DesignProblem, pairing: Pairing, result: Result) -> np.ndarray:
    """Squared error of ``result``'s points to the target, summed per segment."""
    err2 = np.sum((result.shape.center - problem.target) ** 2, axis=1)
    return np.bincount(pairing.seg, weights=err2, minlength=pairing.segments)


# ---------------------------------------------------------------- the search


def search(problem: DesignProblem, result: Result, pairing: Pairing, polish: Callable[[Routing], Result],
           budget: float = settings.Method.budget, workers: int = 2, progress: Callable[[int, int], None] | None = None,
           note: Callable[[str], None] | None = None, rounds: int = settings.SEARCH_ROUNDS) -> Result:
    """Improve the design ``result`` of a corner-like target window by window (module docstring).

    ``polish(routing) -> Result``: the full NLP from a design (ends every round); ``budget``: seconds from the call, no
    window or polish started that the time measured so far says would not fit; ``workers``: threads sharing a window's
    starts; ``progress(done, total)`` after every window and polish; ``note(line)``: one line per round (the command
    line prints it on stderr); ``rounds``: at most. Returns the best design found (``result`` itself if nothing was
    better), with stats search_rounds, search_windows, search_accepted, search_objectives (after each polish),
    search_time_s, search_budget_hit, search_workers, search_window_iterations; its iterations are the first solve's and
    the polishes', its solve time includes the search."""
    run = _Search(problem, result, pairing, budget, workers, progress, rounds)
    try:
        for rnd in range(max(1, rounds)):
            changed = run.windows(rnd)
            run.rounds += 1
            if not changed or run.hit:  # a round the budget cut short is not polished: its design stays as it was
                if note:
                    note(f"corner search round {rnd + 1}: " + ("stopped by the budget" if run.hit else "no window changed")
                         + f", objective {run.best.objective:.6g} ({time.perf_counter() - run.t0:.1f} s)")
                break
            if run.polish_time and time.perf_counter() + run.polish_time > run.deadline:
                run.hit = True
                break
            tp = time.perf_counter()
            polished = polish(run.routing)
            run.polish_time = max(run.polish_time, time.perf_counter() - tp)
            run.iterations += polished.iterations
            run.objectives.append(polished.objective)
            run.accepted += changed
            run.report((rnd + 1) * run.per_round)
            if note:
                note(f"corner search round {rnd + 1}: {changed} windows changed, objective {run.best.objective:.6g} -> "
                     f"{polished.objective:.6g} ({time.perf_counter() - run.t0:.1f} s)")
            if drive.pick_best([run.best, polished]) == 0:  # not better (ties keep the earlier design)
                break
            run.best, run.routing = polished, polished.routing
            if time.perf_counter() > run.deadline:
                run.hit = True
                break
    except BaseException:
        run.stop.set()  # Ctrl-C or an error: no further window solve starts
        raise
    finally:
        run.pool.shutdown(wait=True, cancel_futures=True)
    return run.finish(result)


class _Search:
    """The corner search's state: the best design and its routing, the budget, the window threads and
    solver slots, and what the stats report."""

    def __init__(self, problem, result, pairing, budget, workers, progress, rounds):
        self.problem, self.pairing, self.progress, self.rounds_asked = problem, pairing, progress, rounds
        self.t0 = time.perf_counter()
        self.deadline = self.t0 + max(0.0, budget)
        M = pairing.segments
        self.W = min(settings.WINDOW, M)
        self.rng = np.random.default_rng([problem.options.seed, 2])  # a stream apart from the starts' and hops'
        self.best, self.routing = result, result.routing
        self.objectives, self.windows_done, self.accepted, self.rounds, self.hit = [], 0, 0, 0, False
        self.iterations, self.window_time, self.polish_time, self.window_iterations = result.iterations, 0.0, 0.0, 0
        n = M - self.W + 1
        self.per_round = max(min(settings.MIN_WINDOWS, n), int(np.ceil(settings.WINDOW_SHARE * n))) + 1  # windows + the polish
        self.workers = max(1, workers)
        self.stop = threading.Event()
        self.pool = ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix="vine-nlp-window")
        self.slots = queue.SimpleQueue()  # one window solver per thread: a CasADi solver keeps its workspace in itself
        for k in range(self.workers):
            self.slots.put(k)

    def report(self, done: int) -> None:
        if self.progress:
            self.progress(done, self.per_round * max(1, self.rounds_asked))

    def windows(self, rnd: int) -> int:
        """One round's windows, those of largest error first; returns how many changed the routing."""
        problem, W = self.problem, self.W
        err = error_per_segment(problem, self.pairing, self.best)
        order = np.argsort(-np.convolve(err, np.ones(W), "valid"), kind="stable")  # the corners first
        order = order[: max(min(settings.MIN_WINDOWS, order.size), int(np.ceil(settings.WINDOW_SHARE * order.size)))]
        changed = 0
        for i, a in enumerate(order):
            now = time.perf_counter()
            if now >= self.deadline or (self.windows_done and now + self.window_time / self.windows_done > self.deadline):
                self.hit = True
                break
            tw = time.perf_counter()
            win = _Window(problem, self.pairing, self.routing, int(a), W)
            f_cur = win.objective(win.x)
            # one task per start, in start order; results are read back in that order: the choice does not
            # depend on which thread finished first
            tasks = [self.pool.submit(_solve_start, win, x0, self.slots, self.stop) for x0 in win.starts(self.rng, settings.WINDOW_STARTS)]
            solved = [f.result() for f in tasks]
            f_new, x_new, ok, _ = solved[drive.pick_best(solved, key=lambda r: (not r[2], r[0]))]
            self.window_iterations += sum(r[3] for r in solved if r is not None)
            if ok and f_new < f_cur * (1 - settings.WINDOW_GAIN):
                self.routing = win.apply(self.routing, x_new, problem.diameter)
                changed += 1
            self.windows_done += 1
            self.window_time += time.perf_counter() - tw
            self.report(rnd * self.per_round + i + 1)
        return changed

    def finish(self, result: Result) -> Result:
        self.report(self.per_round * max(1, self.rounds_asked))  # done
        elapsed = time.perf_counter() - self.t0
        best = self.best
        best.stats |= {"search_rounds": self.rounds, "search_windows": self.windows_done, "search_accepted": self.accepted,
                       "search_objectives": self.objectives, "search_time_s": elapsed, "search_budget_hit": self.hit,
                       "search_workers": self.workers, "search_window_iterations": self.window_iterations}
        best.iterations = self.iterations
        best.solve_time_s = result.solve_time_s + elapsed
        return best
