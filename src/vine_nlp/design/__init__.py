"""Layer 3: design methods over one Problem, each returning one Result.

``run_design(problem, method)`` is the single entry point; methods are
interchangeable strategies sharing pairing, error, bounds and guesses
(design.common).
"""

from __future__ import annotations


def run_design(problem, method: str | None = None, **kw):
    method = method or problem.options.method
    if method == "nlp":
        from vine_nlp.design.nlp import design_nlp

        return design_nlp(problem, **kw)
    if method == "greedy":
        from vine_nlp.design.greedy import design_greedy

        return design_greedy(problem, **kw)
    raise ValueError(f"unknown design method {method!r}")
