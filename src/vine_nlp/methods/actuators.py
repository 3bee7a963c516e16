"""Several actuators on one tube: the problem, the result, forward shapes and their evaluation against targets
(spec "Several actuators on one tube"; the model is ``vine_nlp.model.actuators``, the design
``vine_nlp.methods.actuators_design``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vine_nlp.analysis.buildability import buildability, default_min_feature
from vine_nlp.model.actuators import Lines, TwoLines, forward_states, owners, state_shape, too_close
from vine_nlp.model.routing import Routing
from vine_nlp.model.shape import error_metrics, routing_metrics
from vine_nlp.problem import Actuator, DesignOptions, Result


@dataclass(frozen=True)
class Line:
    """One actuator of the tube: its name, kind and bounds, and its width on the tube (length units)."""

    name: str
    actuator: Actuator = Actuator()
    width: float = 0.0


@dataclass(frozen=True, eq=False)
class ActuatorsProblem:
    """A tube with several actuators and its states (state name -> the actuators pulled in it).

    Design problems give ``targets`` (state -> (N, 3), the same N for every state); forward problems ``lines``.
    """

    name: str
    diameter: float
    actuators: tuple  # Line per actuator
    states: dict  # state -> tuple of actuator names
    targets: dict | None = None
    lines: Lines | None = None
    options: DesignOptions = DesignOptions()
    units: str = "cm"

    @property
    def names(self) -> tuple:
        return tuple(a.name for a in self.actuators)

    @property
    def widths(self) -> np.ndarray:
        return np.array([a.width for a in self.actuators])


@dataclass(eq=False)
class ActuatorsResult(Result):
    """A Result whose ``routing`` is actuator 0's line with the shared lengths and base and whose ``shape`` is the
    first state's (the archive's standard part), plus every line, every state's shape and per-state metrics."""

    lines: Lines | None = None
    shapes: dict = field(default_factory=dict)  # state -> Shape
    state_metrics: dict = field(default_factory=dict)  # state -> {rmse, max_error}


def standard_routing(lines: Lines) -> Routing:
    return Routing(theta=lines.theta[0], lam=lines.lam[0], length=lines.length, initial_pose=lines.initial_pose)


def check_states(problem: ActuatorsProblem, lines: Lines) -> None:
    """TwoLines for the first state with two active lines on one segment."""
    for name, active in problem.states.items():
        owners(lines, active, name)


def run_forward(problem: ActuatorsProblem) -> ActuatorsResult:
    """Every state's shape at every segment end and inside (``vine-nlp forward``)."""
    lines, D = problem.lines, problem.diameter
    shapes = forward_states(lines, D, problem.states)
    first = next(iter(shapes.values()))
    return ActuatorsResult(method="forward", routing=standard_routing(lines), shape=first, status="optimal",
                           metrics=routing_metrics(standard_routing(lines)), diameter=D, lines=lines, shapes=shapes,
                           stats={"states": {s: list(a) for s, a in problem.states.items()}})


def arc_pairing(target: np.ndarray, arcs: np.ndarray):
    """(seg, frac) pairing each target point with the model point at the same fraction of the total length:
    the target's chord against the model's segment arcs ``arcs`` (M,)."""
    chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(target, axis=0), axis=1))]
    A = np.r_[0.0, np.cumsum(arcs)]
    x = chord / chord[-1] * A[-1]
    seg = np.clip(np.searchsorted(A, x, side="right") - 1, 0, arcs.size - 1)
    return seg, np.clip((x - A[seg]) / arcs[seg], 0.0, 1.0)


def state_arcs(lines: Lines, D: float, active) -> np.ndarray:
    """(M,) the center-line length of every segment in a state."""
    from vine_nlp.model.helix import center_rates

    own = owners(lines, active)
    k = np.maximum(own, 0)
    lam_c = center_rates(lines.theta[k, np.arange(lines.segments)], lines.lam[k, np.arange(lines.segments)], D)[2]
    return lines.length * np.where(own >= 0, lam_c, 1.0)


def sample_states(lines: Lines, D: float, states: dict, N: int) -> dict:
    """{state: (N, 3)} every state's center line at N points equally spaced in its own length (targets that
    the design's pairing matches exactly)."""
    even = np.linspace(0.0, 1.0, N)[:, None] * [1.0, 0.0, 0.0]  # a chord of N equal steps
    return {name: state_shape(lines, D, active, *arc_pairing(even, state_arcs(lines, D, active)), name).center for name, active in states.items()}


def evaluate(problem: ActuatorsProblem, lines: Lines, method: str = "nlp", bounds=None, **kw) -> ActuatorsResult:
    """Every state's shape paired with its target, per-state RMSE and max error; the run's rmse/max_error over all
    points of all states. Target row i pairs with the model point at the same fraction of the length, or with
    ``bounds`` (S, M+1): each segment's ends as fractions of each state's target chord (the design's pairing)."""
    D, shapes, sm, d2 = problem.diameter, {}, {}, []
    for s, (name, active) in enumerate(problem.states.items()):
        tgt = problem.targets[name]
        if bounds is None:
            seg, frac = arc_pairing(tgt, state_arcs(lines, D, active))
        else:
            seg, frac = arc_pairing(tgt, np.diff(bounds[s]))
        shapes[name] = state_shape(lines, D, active, seg, frac, name)
        sm[name] = error_metrics(shapes[name].center, tgt)
        d2.append(np.sum((shapes[name].center - tgt) ** 2, axis=1))
    d2 = np.concatenate(d2)
    metrics = {"rmse": float(np.sqrt(d2.mean())), "max_error": float(np.sqrt(d2.max()))} | routing_metrics(standard_routing(lines))
    r = ActuatorsResult(method=method, routing=standard_routing(lines), shape=next(iter(shapes.values())), metrics=metrics,
                        diameter=D, lines=lines, shapes=shapes, state_metrics=sm, **kw)
    r.shortfall = shortfall(problem, lines)
    return r


def shortfall(problem: ActuatorsProblem, lines: Lines) -> tuple:
    """The hard requirements a design misses: each actuator's bounds, one line per segment, the widths."""
    out = []
    for k, a in enumerate(problem.actuators):
        b = a.actuator
        if np.any(np.abs(lines.theta[k]) > b.theta_max * (1 + 1e-9)):
            out.append(f"actuator {a.name}: |theta| above its bound {np.degrees(b.theta_max):g} deg")
        if np.any(lines.lam[k] < b.lambda_min * (1 - 1e-9)) or np.any(lines.lam[k] > 1 + 1e-9):
            out.append(f"actuator {a.name}: lambda outside [{b.lambda_min:g}, 1]")
    try:
        check_states(problem, lines)
    except TwoLines as e:
        out.append(str(e))
    for j, a, b in too_close(lines, problem.diameter, problem.widths):
        out.append(f"segment {j + 1}: lines {problem.names[a]} and {problem.names[b]} closer than their widths")
        break
    return tuple(out + unbuilt(problem, lines))


def unbuilt(problem: ActuatorsProblem, lines: Lines) -> list:
    """The buildable rules (``analysis.buildability.Report.missed``) each actuator's line misses, one line each,
    judged with the problem's margin and min_feature; the turning before a line's first actuator is free (its
    phi_k[0] is designed; the first line's: the base's roll) unless the base is fixed."""
    o, out = problem.options, []
    mf = default_min_feature(problem.units) if o.min_feature is None else o.min_feature
    for k, a in enumerate(problem.actuators):
        b = a.actuator
        rep = buildability(lines.routing(k), problem.diameter, b.kind, b.lambda_min, o.correction_margin, mf, k > 0 or o.base != "fixed")
        lo = b.lambda_min + o.correction_margin
        out += [f"actuator {a.name}: not buildable: {m}" for m in rep.missed(lo, max(lo, 1 - o.correction_margin), problem.units)]
    return out

