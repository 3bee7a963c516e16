"""Command-line reports of the formulations with results of their own (multi-shape levels, tip targets)."""

from __future__ import annotations

import math

from vine_nlp.methods.multishape import RUN as MULTISHAPE_RUN
from vine_nlp.methods.multishape import MultiShapeResult
from vine_nlp.methods.tip import RUN as TIP_RUN
from vine_nlp.problem import Result, TipProblem


def multishape_report(result: MultiShapeResult, units: str) -> list[str]:
    """The CLI's lines: one overall, one per level."""
    m = result.metrics
    lines = [
        f"{MULTISHAPE_RUN}: {result.status}, {result.count} levels, RMSE {m['rmse']:.4g} {units}, max error {m['max_error']:.4g} {units}, "
        f"solve time {result.solve_time_s:.3f} s, {result.iterations} iterations"
    ]
    for k in range(result.count):
        lm = result.level_metrics[k]
        tag = "fixed" if result.fixed and result.fixed[k] else "free"
        lines.append(f"  level {k}: lambda {result.levels[k]:.6g} ({tag}), RMSE {lm['rmse']:.4g} {units}, max error {lm['max_error']:.4g} {units}")
    return lines


def tip_report(result: Result, problem: TipProblem, units: str) -> list[str]:
    """The CLI's lines: status and tip error, direction error, actuation."""
    m = result.metrics
    reach = "reachable" if result.converged else ("NOT reachable" if result.status == "infeasible" else "not solved")
    lines = [
        f"{TIP_RUN}: {result.status}, tip {reach}, tip error {m['tip_error']:.4g} {units}, "
        f"solve time {result.solve_time_s:.3f} s, {result.iterations} iterations"
    ]
    if result.stats.get("closest_approach"):
        lines[0] += " (nearest approach: " + result.stats.get("infeasible_reason", "") + ")"
    if "direction_error" in m:
        lines.append(f"  direction error {math.degrees(m['direction_error']):.4g} deg")
    lines.append(
        f"  objective ({problem.objective}) {result.stats['objective_actuation']:.6g}; "
        f"contraction sum (1-lambda) dl = {m['actuation_contraction']:.4g} {units}, "
        f"actuator turning = {m['actuation_turning']:.4g} rad, tube length {m['tube_length']:.4g} {units}"
    )
    if "min_obstacle_gap" in m:
        lines.append(f"  min obstacle gap {m['min_obstacle_gap']:.4g} {units} (margin {problem.obstacle_margin:g})"
                     + (f", {m['min_obstacle_gap_after']:.4g} {units} actuated after growth" if "min_obstacle_gap_after" in m else ""))
    return lines
