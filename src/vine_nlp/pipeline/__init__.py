"""Layer 5: one pipeline behind every door.

The command line (``front.cli``), the Python API (``api``) and sweeps (``front.sweep``) are thin adapters: they parse
their arguments into a problem and a :class:`Request`, check it (:func:`check_request`, before any solver loads), call
:func:`run`, and format the :class:`Outcome`. Nothing else decides which runs a problem makes, from which start, or
whether the result meets the problem's requirements."""

from vine_nlp.pipeline.request import DESIGN_METHODS, Request, check_request

_RUNS = ("KINDS", "Outcome", "calibrated", "judge", "run")
__all__ = ["DESIGN_METHODS", "Request", "check_request", *_RUNS]


def __getattr__(name):
    # the solvers load when a door runs a problem, not when it only parses one (a sweep's parent
    # forks its workers before any solver exists: front.sweep.executors.fork_is_safe)
    if name in _RUNS:
        from vine_nlp.pipeline import runs

        return getattr(runs, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
