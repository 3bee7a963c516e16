"""What the command line prints of an outcome: one line per run (more for multi-shape levels and tip
targets), the comparison table, and the shortfall of every run that is not ok."""

from __future__ import annotations

import dataclasses
import math

from vine_nlp.methods.buildable import missed
from vine_nlp.methods.fit import describe_fit
from vine_nlp.pipeline import Outcome


def _len(v: float, units: str) -> str:
    return f"{v:.4g} {units}"


def _solved(r) -> str:
    return f"solve time {r.solve_time_s:.3f} s, {r.iterations} iterations"


def run_lines(name: str, r, problem, units: str) -> list[str]:
    """The lines of one run, by its method."""
    m = r.metrics
    if getattr(r, "lines", None) is not None:  # several actuators (methods.actuators)
        return actuator_lines(name, r, units)
    if r.method == "forward":
        rt, tip = r.routing, ", ".join(f"{v:.4g}" for v in r.shape.center[-1])
        return [f"{name}: {rt.segments} segments, tube length {_len(float(rt.length.sum()), units)}, tip at ({tip}) {units}"]
    if r.method == "fit":
        return [f"{name}: " + describe_fit(r, units)]
    if r.method == "multishape":
        lines = [f"{name}: {r.status}, {r.count} levels, RMSE {_len(m['rmse'], units)}, max error {_len(m['max_error'], units)}, {_solved(r)}"]
        for k in range(r.count):
            lm, tag = r.level_metrics[k], "fixed" if r.fixed and r.fixed[k] else "free"
            lines.append(f"  level {k}: lambda {r.levels[k]:.6g} ({tag}), RMSE {_len(lm['rmse'], units)}, max error {_len(lm['max_error'], units)}")
        return lines
    if r.method == "tip":
        lines = _tip_lines(name, r, problem, units)
    else:
        lines = [f"{name}: {r.status}, RMSE {_len(m['rmse'], units)}, max error {_len(m['max_error'], units)}, {_solved(r)}"]
    if "min_obstacle_gap" in m:
        lines.append(f"  min obstacle gap {_len(m['min_obstacle_gap'], units)} (margin {problem.obstacle_margin:g})"
                     + (f", {_len(m['min_obstacle_gap_after'], units)} actuated after growth" if "min_obstacle_gap_after" in m else ""))
    return lines


def actuator_lines(name: str, r, units: str) -> list[str]:
    """A run of several actuators: the run, then one line per state (its active actuators; RMSE or tip)."""
    ls, m = r.lines, r.metrics
    head = f"{name}: {ls.count} actuators, {ls.segments} segments, tube length {_len(float(ls.length.sum()), units)}"
    lines = [head if r.method == "forward" else f"{head}; {r.status}, RMSE {_len(m['rmse'], units)}, {_solved(r)}"]
    states = r.stats.get("states") or {}
    for s, shape in r.shapes.items():
        sm, act = r.state_metrics.get(s), ", ".join(states.get(s, ()))
        what = (f"RMSE {_len(sm['rmse'], units)}, max error {_len(sm['max_error'], units)}" if sm else
                "tip at (" + ", ".join(f"{v:.4g}" for v in shape.center[-1]) + f") {units}")
        lines.append(f"  state {s}" + (f" ({act})" if act else "") + f": {what}")
    return lines


def _tip_lines(name, r, problem, units) -> list[str]:
    m = r.metrics
    reach = "reachable" if r.converged else ("NOT reachable" if r.status == "infeasible" else "not solved")
    lines = [f"{name}: {r.status}, tip {reach}, tip error {_len(m['tip_error'], units)}, {_solved(r)}"]
    if r.stats.get("closest_approach"):
        lines[0] += " (nearest approach: " + r.stats.get("infeasible_reason", "") + ")"
    if "direction_error" in m:
        lines.append(f"  direction error {math.degrees(m['direction_error']):.4g} deg")
    lines.append(f"  objective ({problem.objective}) {r.stats['objective_actuation']:.6g}; contraction sum (1-lambda) dl = "
                 f"{_len(m['actuation_contraction'], units)}, actuator turning = {m['actuation_turning']:.4g} rad, "
                 f"tube length {_len(m['tube_length'], units)}")
    return lines


def outcome_lines(outcome: Outcome) -> list[str]:
    """Every run's lines, in the archive's order."""
    pf = outcome.problem_file
    return [line for name, r in outcome.runs.items() for line in run_lines(name, r, pf.problem, pf.units)]


def rules_missed(problem, r) -> list[str]:
    """The buildable rules run ``r`` misses, one line each, judged as every buildable design is (methods.buildable.missed),
    whatever its method: the free runs of a comparison too."""
    return missed(problem, dataclasses.replace(r, method="nlp"))


# the runs of a comparison compared with each other: (label, nlp's run, greedy's run)
PAIRS = (("buildable", "nlp", "greedy_buildable"), ("free", "nlp_free", "greedy"))


def comparison_table(runs: dict, units: str, problem=None) -> str:
    """``vine-nlp compare``'s table: status, errors, time, iterations (greedy: window solves), total variations, and
    (given the ``problem``) whether each run is buildable; then the rules each run misses, one line each, and the nlp
    against the greedy, buildable against buildable and free against free."""
    head = (f"{'run':<18}{'status':<12}{'RMSE [' + units + ']':>14}{'max [' + units + ']':>14}{'time [s]':>10}{'iter/solves':>13}"
            f"{'TV theta':>10}{'TV lambda':>11}" + ("  buildable" if problem is not None else ""))
    lines, misses = [head, "-" * len(head)], []
    for name, r in runs.items():
        m, rules = r.metrics, [] if problem is None else rules_missed(problem, r)
        misses += [f"{name} misses: {line}" for line in rules]
        lines.append(f"{name:<18}{r.status:<12}{m['rmse']:>14.5g}{m['max_error']:>14.5g}{r.solve_time_s:>10.3f}"
                     f"{r.stats.get('window_solves', r.iterations):>13}{m['tv_theta']:>10.4g}{m['tv_lambda']:>11.4g}"
                     + ("" if problem is None else f"  {'no' if rules else 'yes'}"))
    lines += misses
    for label, a, b in PAIRS:
        if a in runs and b in runs and runs[a].solve_time_s > 0:
            ra, rb = runs[a], runs[b]
            lines.append(f"{label}: {a} is {rb.solve_time_s / ra.solve_time_s:.1f}x faster than {b}, RMSE {ra.metrics['rmse']:.4g} "
                         f"against {rb.metrics['rmse']:.4g} {units}")
    return "\n".join(lines)
