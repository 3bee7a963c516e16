"""Problem, sweep and data files (spec/formats.md): the entry the command line and scripts import.

The readers live in their own modules: ``vine_nlp.io.problems`` (the problem kinds: design, forward, fit, multishape,
tip), ``vine_nlp.io.sweep_file`` (sweeps), ``vine_nlp.io.data_files`` (.csv and .npy points) and
``vine_nlp.io.validate`` (the checks they share). Every bad input raises :class:`vine_nlp.errors.InputError` ``(file,
key, reason)``."""

from vine_nlp.io.data_files import read_points
from vine_nlp.io.problems import ProblemFile, load_problem, parse_problem
from vine_nlp.io.sweep_file import Sweep, apply_override, load_sweep

__all__ = ["ProblemFile", "Sweep", "apply_override", "load_problem", "load_sweep", "parse_problem", "read_points"]
