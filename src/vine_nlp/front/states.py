"""The states of an archive of several actuators on one tube, as the commands read them: the states a command
picks (``--state``), and a state's shape sampled as ``export`` samples a routing (spec "Several actuators on one
tube")."""

from __future__ import annotations

import math
import re

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io import limits
from vine_nlp.io.actuators import read_actuators_archive
from vine_nlp.io.validate import parse_toml
from vine_nlp.model.actuators import Lines, actuator_lines, owners, state_shape
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.helix import center_rates
from vine_nlp.problem import ACTUATOR_KINDS, Actuator

# the faces between two rings run straight: where the center line turns by a between them, the tube loses about
# a^2 / 8 of its volume there (a tight bend sampled at D/8 only: 0.3 %); 2 deg keeps that below 0.02 %
MAX_TURN = math.radians(2.0)


def samples(theta, lam, length, D: float, spacing: float | None = None):
    """(seg, frac) at most ``spacing`` (default D/8) apart along the material and MAX_TURN apart in the center
    line's direction, every segment end included."""
    spacing = D / 8 if spacing is None else float(spacing)
    kappa_c, _, _ = center_rates(theta, lam, D)  # the center line's turn per unit of material
    per = np.ceil(np.maximum(length / spacing, np.abs(kappa_c) * length / MAX_TURN))
    return segment_end_samples(length, np.maximum(1, per).astype(int))


def state_rates(lines: Lines, own) -> tuple:
    """(theta, lam) per segment of a state whose segments ``own`` (model.actuators.owners) shapes: the owner's,
    lambda 1 where none (the paper's segment of either is the state's segment, up to the turn entering it)."""
    k, j = np.maximum(own, 0), np.arange(lines.segments)
    return lines.theta[k, j], np.where(np.asarray(own) >= 0, lines.lam[k, j], 1.0)


def state_lines(lines: Lines, D: float, active, state: str = "", spacing: float | None = None):
    """A state of several actuators sampled as :func:`samples` samples a routing (each segment by the line that
    shapes it, straight where none does): (seg, frac, Shape (model.actuators.state_shape), {actuator: its line})."""
    seg, frac = samples(*state_rates(lines, owners(lines, active, state)), lines.length, D, spacing)
    return seg, frac, state_shape(lines, D, active, seg, frac, state), actuator_lines(lines, D, active, seg, frac, state)


def line_kinds(a, count: int) -> list:
    """(kind, lambda_min) of each of ``count`` lines from the archived problem's [[actuators]] (the reader's
    defaults where a value is absent or not valid)."""
    try:
        items = parse_toml("archive", a.source or "").get("actuators", [])
    except InputError:
        items = []
    items = [t if isinstance(t, dict) else {} for t in (items if isinstance(items, list) else [])] + [{}] * count
    kinds = [t.get("kind") if t.get("kind") in ACTUATOR_KINDS else Actuator.kind for t in items[:count]]
    return [(kind, float(t["lambda_min"]) if isinstance(t.get("lambda_min"), (int, float)) else 0.5 if kind == "spam" else Actuator.lambda_min)
            for kind, t in zip(kinds, items)]


def picked_states(path, run: str | None = None, state: str | None = None):
    """(Archive, run, ActuatorsResult, {state: target}, {state: active}) of an archive of several actuators: every
    state, or ``state`` alone (one error line naming --state or --run for one the archive does not have)."""
    try:
        a, r, targets = read_actuators_archive(path, run)
    except ValueError as e:  # no such run (an ArchiveError is an InputError: raised as it is)
        if isinstance(e, InputError):
            raise
        raise InputError(path, "--run", str(e)) from None
    states = {s: tuple(v) for s, v in r.stats["states"].items()}
    for s in states:  # names go into file names (export): plain, as the problem reader wants them
        if not (re.fullmatch(r"[A-Za-z0-9._-]+", s) and len(s) <= limits.MAX_NAME_CHARS):
            raise InputError(path, f"/runs/{a.pick_run(run)}@states", f"state name {s[:40]!r} is not plain: letters, digits, '-', '_' or '.'")
    if state is not None:
        if state not in states:
            raise InputError(path, "--state", f"no state {state!r} (states: {', '.join(states)})")
        states = {state: states[state]}
    return a, a.pick_run(run), r, targets, states
