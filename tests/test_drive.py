"""The drive under every formulation (methods.drive): one ranking and tie rule, multi-start (sequential, first
acceptable, process pool), the Hessian schedule, the active-set protocol, one stats record."""

from __future__ import annotations

import numpy as np
import pytest

from vine_nlp.methods import drive
from vine_nlp.problem import Result, Routing

ROUTING = Routing(theta=np.zeros(2), lam=np.ones(2), length=np.ones(2))


def _r(objective, status="optimal", iterations=1, time_s=0.5, **stats):
    return Result("x", ROUTING, None, status, iterations=iterations, stats={"objective": objective, "ipopt_time_s": time_s} | stats,
                  objective=objective)


def test_rank_puts_converged_then_clear_first_then_the_lower_value():
    ranked = [drive.rank(_r(5.0)), drive.rank(_r(1.0), clear=False, miss=0.1), drive.rank(_r(0.1, "max_iter")),
              drive.rank(_r(0.1, "max_iter"), clear=False, miss=3.0)]
    assert ranked == sorted(ranked)
    assert drive.rank(_r(2.0), clear=False, miss=0.5) == (False, True, 0.5)  # not clear: ranked by its miss
    assert drive.rank(_r(2.0), clear=False) == (False, True, 2.0)  # no miss given: the objective
    assert drive.rank(_r(2.0, "acceptable")) == (False, False, 2.0)  # acceptable counts as converged


def test_the_tie_rule_picks_the_first_within_tie_rtol():
    low = 1.0
    near, far = low * (1 + 0.5 * drive.TIE_RTOL), low * (1 + 2 * drive.TIE_RTOL)
    assert drive.pick_best([_r(near), _r(low)]) == 0  # the same optimum: the earlier start, whatever arrived later
    assert drive.pick_best([_r(far), _r(low)]) == 1  # a lower optimum wins
    assert drive.pick_best([_r(0.1, "failed"), _r(9.0)]) == 1  # converged before a lower unconverged objective
    assert drive.pick_best([(1, 5.0), (0, 7.0), (0, 7.0)], key=lambda k: k) == 1  # any key: tiers first, then the value
    assert drive.pick_best([(0, -2.0), (0, -2.0 * (1 - 0.5 * drive.TIE_RTOL))], key=lambda k: k) == 0  # negative values too


def test_multistart_keeps_the_best_and_records_every_start():
    objectives = [3.0, 1.0, 2.0]
    found = drive.multistart(lambda k: _r(objectives[k], iterations=k + 1), range(3))
    assert (found.index, found.best.stats["objective"]) == (1, 1.0) and len(found.results) == 3
    stats = drive.Stats()
    best = drive.record_starts(found, stats)
    assert best.stats["start_objectives"] == objectives and best.stats["start_iterations"] == [1, 2, 3]
    assert (best.stats["starts"], best.stats["best_start"]) == (3, 1)
    assert (stats.solves, stats.iterations, stats.solver_time_s) == (3, 6, 1.5)


def test_multistart_stops_at_the_first_accepted_start_and_makes_later_starts_never():
    made, done = [], []

    def later(k):  # a start that costs something to make: called only when its turn comes
        def make():
            made.append(k)
            return k
        return make

    found = drive.multistart(lambda k: _r(10.0 - k, "optimal" if k == 1 else "failed"), [0, later(1), later(2), later(3)],
                             accept=lambda r: r.status == "optimal", progress=lambda d, n: done.append((d, n)))
    assert made == [1] and len(found.results) == 2 and found.index == 1
    assert done == [(1, 4), (2, 4)]


def _solve_in_a_worker(k):
    # every start reaches the same optimum within the tie tolerance but the first, which is worse
    return _r(2.0 if k == 0 else 1.0 * (1 + 1e-9 * k), iterations=k)


def test_a_process_pool_picks_what_one_process_picks():
    sequential = drive.multistart(_solve_in_a_worker, range(5))
    pooled = drive.multistart(_solve_in_a_worker, range(5), workers=2)
    assert sequential.index == pooled.index == 1
    assert [r.iterations for r in pooled.results] == [r.iterations for r in sequential.results] == [0, 1, 2, 3, 4]


def test_the_hessian_schedule_stops_at_the_first_optimal_step_and_counts_every_step():
    seen = []

    def step(hessian, max_iter, previous):
        seen.append((hessian, max_iter, previous.status if previous else None))
        return _r(1.0, "max_iter" if hessian == "gauss-newton" else "optimal", iterations=max_iter)

    r = drive.schedule(step, (("gauss-newton", 50), ("exact", 300), ("never", 7)))
    assert seen == [("gauss-newton", 50, None), ("exact", 300, "max_iter")]
    assert r.status == "optimal" and r.iterations == 350 and r.stats["solves"] == 2
    assert r.stats["hessian_schedule"] == "gauss-newton: max_iter; exact: optimal"
    # no step optimal: the best by the ranking (an acceptable one before a lower failed one)
    r = drive.schedule(lambda h, m, p: _r(m, "acceptable" if h == "b" else "failed"), (("a", 1.0), ("b", 5.0), ("c", 2.0)))
    assert r.stats["objective"] == 5.0 and r.iterations == 3


class _Scripted:
    """A rule whose rounds return the scripted (objective, clear, done), a round that is not clear missing by its
    objective; records what the drive asked."""

    def __init__(self, script, key=True):
        self.script, self.key, self.calls = script, key, []

    def solve(self, x, round, last):
        self.calls.append(("solve", x, round, last))
        return round + 100, _r(self.script[round][0], iterations=10)

    def judge(self, res):
        _, clear, done = self.script[len([c for c in self.calls if c[0] == "solve"]) - 1]
        return drive.Verdict(done, drive.rank(res, clear, res.stats["objective"]) if self.key else None, {"clear": clear})

    def refresh(self, res, verdict, x):
        self.calls.append(("refresh", x))
        return x + 1000


def test_refine_keeps_the_best_round_and_stops_when_a_round_is_done():
    rule = _Scripted([(1.0, False, False), (5.0, True, False), (3.0, True, True), (0.5, True, False)])
    stats = drive.Stats()
    found = drive.refine(rule, 10, x=7, stats=stats)
    assert found.rounds == 3 and found.best.stats["objective"] == 3.0 and found.verdict.report == {"clear": True}
    # each round starts where the refresh of the round before put it; no refresh after the last round
    assert rule.calls == [("solve", 7, 0, False), ("refresh", 100), ("solve", 1100, 1, False), ("refresh", 101),
                          ("solve", 1101, 2, False)]
    assert (stats.solves, stats.iterations) == (3, 30)


def test_refine_stops_at_its_round_cap_and_tells_the_last_round():
    rule = _Scripted([(4.0, False, False), (2.0, False, False), (3.0, False, False)])
    found = drive.refine(rule, 3)
    assert found.rounds == 3 and found.best.stats["objective"] == 2.0  # none clear: the smallest miss
    assert [c[3] for c in rule.calls if c[0] == "solve"] == [False, False, True]
    assert [c[0] for c in rule.calls].count("refresh") == 2


def test_refine_without_keys_keeps_the_latest_round():
    rule = _Scripted([(1.0, True, False), (9.0, False, False), (5.0, False, True)], key=False)
    assert drive.refine(rule, 5).best.stats["objective"] == 5.0


def test_stats_sum_every_solve_and_stamp_the_totals():
    stats = drive.Stats()
    one = _r(1.0, iterations=4, time_s=0.25)  # one solve
    inner = _r(1.0, iterations=5, time_s=1.0, solves=3)  # a whole sub-method: its own solves
    assert stats.absorb(one) is one and stats.absorb(inner) is inner
    untimed = Result("x", ROUTING, None, iterations=6, solve_time_s=0.5)  # no solver time of its own: its time
    stats.absorb(untimed)
    out = stats.stamp(_r(2.0))
    assert (stats.solves, out.iterations) == (5, 15)
    assert out.stats["solves"] == 5 and out.stats["ipopt_iterations"] == 15
    assert out.stats["ipopt_time_s"] == pytest.approx(1.75)
    assert out.solve_time_s >= 0.0
