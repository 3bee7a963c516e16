"""Layer 5: one pipeline behind every door.

The command line (``front.cli``), the Python API (``api``) and sweeps (``front.sweep``) are thin
adapters: they parse their arguments into a problem and a :class:`Request`, call :func:`run`, and
format the :class:`Outcome`. Nothing else decides which runs a problem makes, from which start, or
whether the result meets the problem's requirements.
"""

from vine_nlp.pipeline.runs import KINDS, Outcome, Request, calibrated, judge, run

__all__ = ["KINDS", "Outcome", "Request", "calibrated", "judge", "run"]
