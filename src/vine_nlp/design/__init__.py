"""Layer 3: design methods over one problem, each returning one Result.

The formulations (nlp, multishape, tip, clearance, robust, ...) are terms, rows and
guesses on one multiple-shooting transcription (``design.transcription``); the greedy
baseline is its own algorithm on the same model, pairing, error and bounds
(``design.common``). ``run_design(problem, method)`` picks a method by name
(``design.methods``); it is loaded on first use, so reading an archive or a problem
file does not load CasADi.
"""

from __future__ import annotations

import importlib


def __getattr__(name: str):
    if name == "run_design":
        return importlib.import_module("vine_nlp.design.methods").run_design
    raise AttributeError(f"module 'vine_nlp.design' has no attribute {name!r}")
