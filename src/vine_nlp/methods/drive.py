"""One drive under every formulation: multi-start, the Hessian schedule, active-set rounds, one stats record.

A formulation states what to solve: a solver (spec and data), its starts, and for an active set
a *rule* (how to solve the current set, how to judge a round, how to refresh the set). The drive
owns the loops, their caps, the ranking and the accounting, so every formulation ends, ranks and
counts the same way (rockit keeps the method apart from the problem in the same spirit):

- :func:`multistart`: solve from every start in order (or in a process pool, in order), or stop
  at the first acceptable one; one ranking (:func:`rank`), one tie rule (:func:`pick_best`);
- :func:`schedule`: the Hessian schedule, steps tried in order until one converges;
- :func:`refine`: the active-set protocol (clearance pairs, obstacle rows, the ICP pairing of an
  as-built estimate are rules of one loop);
- :class:`Stats`: every solve's iterations and solver time summed in one record;
- :func:`budget`: a deadline for every loop of one design (starts, hops, rounds after the first): a loop it
  cuts returns its best so far and says what it cut (:func:`spent`).
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Callable, Protocol

from vine_nlp.methods.settings import TIE_RTOL
from vine_nlp.problem import Result


@dataclass
class Stats:
    """Every solve of one method: how many, their iterations and the solvers' own time; the wall time since
    the record was made. ``stamp`` writes the totals onto the method's result."""

    solves: int = 0
    iterations: int = 0
    solver_time_s: float = 0.0
    started: float = field(default_factory=time.perf_counter)

    def absorb(self, result: Result) -> Result:
        """Count a solve's or a whole sub-method's result (its solves, iterations and solver time)."""
        self.solves += int(result.stats.get("solves", 1))
        self.iterations += int(result.iterations)
        self.solver_time_s += float(result.stats.get("ipopt_time_s", result.solve_time_s))
        return result

    def stamp(self, result: Result) -> Result:
        """The totals onto ``result``: iterations, solve_time_s (wall), stats solves, ipopt_iterations and
        ipopt_time_s (the solvers' own time)."""
        result.iterations = self.iterations
        result.solve_time_s = time.perf_counter() - self.started
        result.stats.update(solves=self.solves, ipopt_iterations=self.iterations, ipopt_time_s=self.solver_time_s)
        return result


# ---------------------------------------------------------------- the budget of one design

_DEADLINE: ContextVar = ContextVar("deadline", default=None)


@contextmanager
def budget(seconds: float | None):
    """Every loop of the drive within ``seconds`` from now (None: unbounded): a loop runs its first step, and no
    step after the deadline. Yields the list of what the budget cut (one line per loop cut, see :func:`spent`)."""
    cut: list = []
    token = _DEADLINE.set(None if seconds is None else (time.perf_counter() + seconds, cut))
    try:
        yield cut
    finally:
        _DEADLINE.reset(token)


def remaining() -> float | None:
    """Seconds left of the current :func:`budget` (0 when spent), None when there is none."""
    d = _DEADLINE.get()
    return None if d is None else max(0.0, d[0] - time.perf_counter())


def spent(done: int, total: int, what: str) -> bool:
    """Whether the budget is spent before step ``done`` + 1 of ``total`` of a loop (``what``: "starts", "hops",
    "rounds"); if so, ``"{done} of {total} {what}"`` is recorded as cut."""
    d = _DEADLINE.get()
    if d is None or time.perf_counter() < d[0]:
        return False
    d[1].append(f"{done} of {total} {what}")
    return True


# ---------------------------------------------------------------- ranking and multi-start


def rank(result: Result, clear: bool = True, miss: float | None = None) -> tuple:
    """The one ranking of candidate designs, (not converged, not clear, value): converged first, then clear
    of every hard requirement (``clear``, as the formulation judges it); within a tier the lower value: the
    objective of a clear design, else ``miss`` (how far it is from its requirements; default the objective)."""
    value = (float("inf") if result.objective is None else result.objective) if clear or miss is None else miss
    return not result.converged, not clear, float(value)


def pick_best(candidates, key: Callable = rank) -> int:
    """Index of the best candidate by ``key`` (tiers, then a value last): the best tiers, then the FIRST whose
    value is within TIE_RTOL of their lowest, so the choice does not depend on timing or worker order."""
    keys = [tuple(key(c)) for c in candidates]
    tier = min(k[:-1] for k in keys)
    low = min(k[-1] for k in keys if k[:-1] == tier)
    return next(i for i, k in enumerate(keys) if k[:-1] == tier and k[-1] <= low + TIE_RTOL * abs(low) + 1e-15)


@dataclass
class Starts:
    """What a multi-start found: the best result, its index among the starts tried, every result in order."""

    best: Result
    index: int
    results: list


def multistart(solve: Callable, starts, *, key: Callable = rank, accept: Callable | None = None, workers: int = 1,
               progress: Callable | None = None) -> Starts:
    """Solve from each start in order and keep the best (:func:`pick_best` by ``key``).

    ``accept``: stop at the first result it accepts (the later starts are fallbacks); sequential.
    ``workers`` > 1 (and no ``accept``): a process pool, results in start order (the same choice as one
    process); ``solve`` and the starts must then pickle. ``progress(done, total)`` after each start.
    A start may be a callable: it is called when its turn comes (a start that costs a solve to make).
    No start after the first begins once the :func:`budget` is spent."""
    starts = list(starts)
    results = []

    def done(r):
        results.append(r)
        if progress:
            progress(len(results), len(starts))

    if workers > 1 and len(starts) > 1 and accept is None:
        with ProcessPoolExecutor(max_workers=min(workers, len(starts))) as pool:
            for f in [pool.submit(solve, s) for s in starts]:  # taken in start order: a deterministic choice
                done(f.result())
                if len(results) < len(starts) and spent(len(results), len(starts), "starts"):
                    pool.shutdown(cancel_futures=True)
                    break
    else:
        for s in starts:
            if results and spent(len(results), len(starts), "starts"):
                break
            done(solve(s() if callable(s) else s))
            if accept is not None and accept(results[-1]):
                break
    k = pick_best(results, key)
    return Starts(results[k], k, results)


def record_starts(found: Starts, stats: Stats, always: bool = False) -> Result:
    """Every start's solves counted in ``stats``; the multi-start's figures on its winner (stats starts,
    best_start, start_objectives, start_iterations) where there were several starts (``always``: also one)."""
    best = found.best
    for r in found.results:
        stats.absorb(r)
    if always or len(found.results) > 1:
        best.runs = tuple(found.results)
        best.stats.update(starts=len(found.results), best_start=found.index,
                          start_objectives=[r.objective for r in found.results],
                          start_iterations=[r.iterations for r in found.results])
    return best


# ---------------------------------------------------------------- the Hessian schedule


def schedule(solve: Callable, steps) -> Result:
    """The Hessian schedule: ``solve(hessian, max_iter, previous)`` for each ``(hessian, max_iter)`` step in
    order until one is optimal (``previous``: the step before's result, None at first). Returns that one,
    else the best step by :func:`rank`, with every step's iterations and solver time counted in it."""
    stats, tried = Stats(), []
    for hessian, max_iter in steps:
        tried.append(stats.absorb(solve(hessian, max_iter, tried[-1] if tried else None)))
        if tried[-1].status == "optimal":
            break
    best = tried[-1] if tried[-1].status == "optimal" else tried[pick_best(tried)]
    best.runs = tuple(tried)
    best.stats["hessian_schedule"] = "; ".join(f"{h}: {r.status}" for (h, _), r in zip(steps, tried))
    return stats.stamp(best)


# ---------------------------------------------------------------- active sets


@dataclass
class Verdict:
    """How one round did: ``done`` ends the loop; ``key`` ranks the rounds (as :func:`rank`'s: the best round
    is kept), or None: the round supersedes every earlier one (an estimate refined round by round);
    ``report``: what the rule measured (kept with the best round)."""

    done: bool
    key: tuple | None
    report: object = None


class Rule(Protocol):
    """An active set: what the drive asks of a formulation that refines its rows between solves."""

    def solve(self, x, round: int, last: bool) -> tuple:
        """Solve the current set from ``x`` (None: the rule's own start); (x, Result of the round)."""

    def judge(self, result: Result) -> Verdict:
        """Measure the round's design (a report against the exact requirement)."""

    def refresh(self, result: Result, verdict: Verdict, x):
        """Update the set (and the data) for the next round; returns the next round's start x."""


@dataclass
class Refined:
    """The best round of an active-set loop, its verdict, and how many rounds ran."""

    best: Result
    verdict: Verdict
    rounds: int


def refine(rule: Rule, max_rounds: int, x=None, stats: Stats | None = None) -> Refined:
    """The active-set protocol: solve, judge, keep the best round (by the verdicts' keys, the earlier on a
    tie; with no key the latest), stop when a round is done or after ``max_rounds`` (>= 1); else refresh and
    solve again. Every round's solves count in ``stats``; no round after the first once the :func:`budget` is spent."""
    stats = stats if stats is not None else Stats()
    best = verdict_best = None
    for k in range(max_rounds):
        x, res = rule.solve(x, k, k == max_rounds - 1)
        stats.absorb(res)
        verdict = rule.judge(res)
        if best is None or verdict.key is None or pick_best([verdict_best, verdict], key=lambda v: v.key) == 1:
            best, verdict_best = res, verdict
        if verdict.done or k == max_rounds - 1 or spent(k + 1, max_rounds, "rounds"):
            break
        x = rule.refresh(res, verdict, x)
    return Refined(best, verdict_best, k + 1)
