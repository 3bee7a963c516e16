"""Each design variable declared once: its name (the paper's), size, bounds rule, start spread and unit.

CasADi's multiple-shooting example appends each variable with its bounds and guess together (w, lbw, ubw,
w0); rockit declares a control once (``stage.control()``). Here the per-segment variables of a routing
are :data:`ROUTING`, in stage order, and everything that knows them derives from the declarations: the
decision vector's layout (``methods.structure.Layout``), a block's local variables (:class:`Slots`:
:data:`POINT`, :data:`CELL`), packing and unpacking (``Solver.pack_x``, ``Solver.unpack``), box bounds
(:func:`box`, ``Solver.bounds``), start perturbations (:func:`perturb`) and the routing of a solution
(:func:`routing`). A formulation with other rules declares its own (``dataclasses.replace(LENGTH, ...)``);
a new per-segment variable is one more ``Var`` in the structure's ``variables``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vine_nlp.methods.settings import LENGTH_FACTOR, START_SPREAD
from vine_nlp.model.routing import Routing


@dataclass(frozen=True)
class Var:
    """One per-segment design variable.

    ``name``: the paper's (and ``Routing``'s field); ``size``: entries per segment; ``bounds(actuator, ref)``:
    (lower, upper), scalars or per segment, from the actuator and a reference length per segment (the target's
    chord of the segment, in the units the caller works in); ``spread``: the standard deviation of a random
    start's perturbation (0: not perturbed); ``length``: a length (held in units of the tube diameter D in the
    NLP); ``levels``: the structure's lambda sharing applies (``Structure.lam``: one per segment, one shared,
    one per level)."""

    name: str
    bounds: Callable = field(repr=False, compare=False)
    size: int = 1
    spread: float = 0.0
    length: bool = False
    levels: bool = False


THETA = Var("theta", lambda a, ref: (-a.theta_max, a.theta_max), spread=START_SPREAD["theta"])
LAM = Var("lam", lambda a, ref: (a.lambda_min, 1.0), spread=START_SPREAD["lam"], levels=True)
LENGTH = Var("length", lambda a, ref: (LENGTH_FACTOR[0] * ref, LENGTH_FACTOR[1] * ref), length=True)
ROUTING = (THETA, LAM, LENGTH)  # a routing's variables per segment, in stage order (paper eq. phi(s_j))


def box(actuator, ref, variables=ROUTING, only=None) -> dict:
    """{name: (lower, upper)} per segment of ``variables`` (``only``: these names): arrays of the reference's
    shape (M,), (M, size) for a variable of several entries."""
    ref = np.asarray(ref, float)
    out = {}
    for v in variables:
        if only is None or v.name in only:
            shape = ref.shape + ((v.size,) if v.size > 1 else ())
            bounds = (np.asarray(b, float) for b in v.bounds(actuator, ref))
            out[v.name] = tuple(np.broadcast_to(b[..., None] if b.shape == ref.shape and v.size > 1 else b, shape).copy() for b in bounds)
    return out


def clip(values: dict, bounds: dict) -> dict:
    """``values`` (by name) clipped into ``bounds`` (``box``'s); names without bounds kept as they are."""
    return {k: np.clip(v, *bounds[k]) if k in bounds else v for k, v in values.items()}


def perturb(var: Var, base, rng, actuator) -> np.ndarray:
    """A random start's value of ``var``: ``base`` plus a normal draw of the declared spread, clipped into its bounds."""
    lo, hi = var.bounds(actuator, None)
    return np.clip(base + rng.normal(0.0, var.spread, np.shape(base)), lo, hi)


def draw(var: Var, rng, actuator, size=None):
    """Uniform draws of ``var`` inside its bounds (a basin hop's or a window's random start)."""
    lo, hi = var.bounds(actuator, None)
    return rng.uniform(lo, hi, size)


def routing(values: dict, initial_pose, D: float = 1.0, variables=ROUTING) -> Routing:
    """The routing of per-segment ``values`` by name (lengths in units of ``D``: scaled back)."""
    return Routing(**{v.name: values[v.name] * D if v.length else values[v.name] for v in variables}, initial_pose=initial_pose)


class Slots:
    """Named consecutive parts of a block's local vector: ``Slots(("X", 12), ("theta", 1), ...)``.
    ``slots[name]``: its slice; ``size``; ``split(v, at)``: the parts of ``v[at:at + size]`` in order."""

    def __init__(self, *parts):
        self.parts, self.slices, i = tuple(parts), {}, 0
        for name, size in self.parts:
            self.slices[name], i = slice(i, i + size), i + size
        self.size = i

    def __getitem__(self, name: str) -> slice:
        return self.slices[name]

    def __add__(self, parts) -> "Slots":
        return Slots(*self.parts, *parts)

    def split(self, v, at: int = 0) -> list:
        return [v[at + s.start : at + s.stop] for s in self.slices.values()]


def slots(variables=ROUTING, before=()) -> Slots:
    """A segment's declared variables as a block's local vector, after the parts ``before`` (("X", 12): its start frame)."""
    return Slots(*before, *((v.name, v.size) for v in variables))


ROUTE = slots()  # (theta_j, lam_j, length_j): one segment's routing
POINT = slots(before=(("X", 12),))  # (X_j, theta_j, lam_j, length_j): the model's points of segment j
CELL = POINT + (("next", 12),)  # and X_{j+1}: the segment block (continuity and point fit)
