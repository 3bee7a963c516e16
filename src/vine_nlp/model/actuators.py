"""Several actuators on one tube (spec "Several actuators on one tube", round 4): pure numpy.

Actuator k is a line drawn on the flattened tube: theta_k per segment, lambda_k per segment (exactly 1 where it
has no actuator) and its angle around the tube at the segment ends, phi_k[j+1] = phi_k[j] + (2/D) tan(theta_k[j]) l_j.
A state is the set of actuators pulled. In a state, segment j is the paper's helix of the one active line with
lambda_k[j] < 1 there (the frame turned about its tangent x on entering until y points at phi_k[j]), straight
with no turn where none is, and outside the model where two or more are (:class:`TwoLines`).

The chain is kept in the *material frame* G_j: the frame whose y axis points at material angle 0. A segment shaped
by line k moves it by Rx(phi_k[j]) H(theta_k, lambda_k, l_j) Rx(-phi_k[j+1]) (H the one-actuator segment
transform); a straight one by a translation l_j along x. Since a rotation about x commutes with a translation
along it, a segment with lambda_k = 1 moves G by exactly that translation: with one actuator the chain is the
one-actuator chain (its frames are G_j Rx(phi[j])).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vine_nlp.model.chain import segment_end_samples
from vine_nlp.model.routing import Routing, actuated
from vine_nlp.model.segment import segment_transform
from vine_nlp.model.shape import Shape


class TwoLines(ValueError):
    """A state with two or more active lines (lambda < 1) on one segment: outside the paper's model."""

    def __init__(self, state: str, segment: int, actuators: list):
        self.state, self.segment, self.actuators = state, segment, tuple(actuators)
        super().__init__(f"state '{state}': segment {segment + 1} has {len(actuators)} active lines "
                         f"({', '.join(actuators)}); the model allows one per segment")


@dataclass(frozen=True)
class Lines:
    """K actuator lines on one tube of M segments (shared lengths and base pose).

    theta, lam : (K, M); phi0 : (K,) angle of each line at the base (the first's is 0); length : (M,);
    initial_pose : (4, 4) the base's material frame T^0_w (y at material angle 0).
    """

    names: tuple
    theta: np.ndarray
    lam: np.ndarray
    phi0: np.ndarray
    length: np.ndarray
    initial_pose: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        K = len(self.names)
        length = np.asarray(self.length, float).reshape(-1)
        object.__setattr__(self, "length", length)
        for key in ("theta", "lam"):
            object.__setattr__(self, key, np.broadcast_to(np.asarray(getattr(self, key), float), (K, length.size)).copy())
        object.__setattr__(self, "phi0", np.asarray(self.phi0, float).reshape(K))
        object.__setattr__(self, "initial_pose", np.asarray(self.initial_pose, float).reshape(4, 4))

    @property
    def count(self) -> int:
        return len(self.names)

    @property
    def segments(self) -> int:
        return self.length.size

    def phi(self, D: float) -> np.ndarray:
        """(K, M+1) angle of each line around the tube at the segment ends."""
        steps = 2.0 / D * np.tan(self.theta) * self.length
        return np.column_stack([self.phi0, self.phi0[:, None] + np.cumsum(steps, axis=1)])

    def index(self, active) -> list:
        return [self.names.index(a) for a in active]

    def routing(self, k: int) -> Routing:
        """Line k alone as a one-actuator routing: its theta and lambda, the base rolled by phi_k[0] about x
        (the chain of a state whose only active line is k)."""
        return Routing(theta=self.theta[k], lam=self.lam[k], length=self.length, initial_pose=self.initial_pose @ roll(self.phi0[k]))


def roll(a) -> np.ndarray:
    """Rx(a): rotation about the tangent x (4x4, or (..., 4, 4) for an array of angles)."""
    a = np.asarray(a, float)
    T = np.zeros(a.shape + (4, 4))
    c, s = np.cos(a), np.sin(a)
    T[..., 0, 0] = T[..., 3, 3] = 1.0
    T[..., 1, 1], T[..., 1, 2], T[..., 2, 1], T[..., 2, 2] = c, -s, s, c
    return T


def owners(lines: Lines, active, state: str = "") -> np.ndarray:
    """(M,) the active line shaping each segment of the state (an index into lines), -1 where none does.
    TwoLines where two or more active lines have lambda < 1 on one segment."""
    idx = lines.index(active)
    on = actuated(lines.lam[idx]) if idx else np.zeros((0, lines.segments), bool)
    count = on.sum(axis=0)
    if np.any(count > 1):
        j = int(np.argmax(count > 1))
        raise TwoLines(state, j, [lines.names[idx[i]] for i in np.flatnonzero(on[:, j])])
    own = np.full(lines.segments, -1)
    for i, k in enumerate(idx):
        own[on[i]] = k
    return own


def material_frames(lines: Lines, D: float, own: np.ndarray) -> np.ndarray:
    """(M+1, 4, 4) the material frames G_j of a state whose segments are shaped by ``own`` (module docstring)."""
    phi = lines.phi(D)
    G = np.empty((lines.segments + 1, 4, 4))
    G[0] = lines.initial_pose
    for j, k in enumerate(own):
        if k < 0:
            step = np.eye(4)
            step[0, 3] = lines.length[j]
        else:
            step = roll(phi[k, j]) @ segment_transform(lines.theta[k, j], lines.lam[k, j], lines.length[j], D) @ roll(-phi[k, j + 1])
        G[j + 1] = G[j] @ step
    return G


def _at(lines: Lines, D: float, active, seg, frac, state: str):
    """The frames at fraction ``frac`` of segments ``seg`` of a state, turned to the angle of the line shaping each
    segment (of the state's first active line where none does; straight pieces: lambda 1, the line only turns around
    the tube), and that line's angle there. TwoLines as :func:`owners`."""
    own = owners(lines, active, state)
    seg, frac = np.asarray(seg, int), np.asarray(frac, float)
    k = np.where(own[seg] < 0, lines.index(active)[0], own[seg])
    phi, l = lines.phi(D), frac * lines.length[seg]
    lam = np.where(own[seg] >= 0, lines.lam[k, seg], 1.0)
    world = material_frames(lines, D, own)[seg] @ roll(phi[k, seg]) @ segment_transform(lines.theta[k, seg], lam, l, D)
    return world, phi[k, seg] + 2.0 / D * np.tan(lines.theta[k, seg]) * l


def state_shape(lines: Lines, D: float, active, seg, frac, state: str = "") -> Shape:
    """Center, actuator and opposite lines of a state at fraction ``frac`` of segments ``seg``.

    The actuator line is the line of the active actuator shaping the segment, or of the state's first active
    actuator where none does (with one actuator: exactly the one-actuator shape). TwoLines as :func:`owners`.
    """
    world = _at(lines, D, active, seg, frac, state)[0]
    center, normal = world[:, :3, 3], world[:, :3, 1]
    return Shape(center, center + 0.5 * D * normal, center - 0.5 * D * normal)


def state_line(lines: Lines, D: float, active, state: str = ""):
    """(seg, frac, side) -> (points side D along the normal of :func:`state_shape`'s frames, their unit tangents):
    a state's center (side 0), actuator (1/2) or opposite (-1/2) line, what a measurement of the state sees."""
    def at(seg, frac, side):
        world = _at(lines, D, active, seg, frac, state)[0]
        return world[:, :3, 3] + side * D * world[:, :3, 1], world[:, :3, 0]
    return at


def actuator_lines(lines: Lines, D: float, active, seg, frac, state: str = "") -> dict:
    """{actuator: (P, 3)} where every actuator's line lies on the tube in a state, at the points of
    :func:`state_shape` (the material frame there turned to the line's angle around the tube)."""
    world, moved = _at(lines, D, active, seg, frac, state)
    world = world @ roll(-moved)  # the material frame at each point
    phi, l, seg = lines.phi(D), np.asarray(frac, float) * lines.length[np.asarray(seg, int)], np.asarray(seg, int)
    out = {}
    for i, name in enumerate(lines.names):
        a = phi[i, seg] + 2.0 / D * np.tan(lines.theta[i, seg]) * l
        out[name] = world[:, :3, 3] + 0.5 * D * (world[:, :3, 1] * np.cos(a)[:, None] + world[:, :3, 2] * np.sin(a)[:, None])
    return out


def forward_states(lines: Lines, D: float, states: dict, per_segment=None) -> dict:
    """{state: Shape} at every segment end and ``per_segment`` pieces inside (default: pieces <= D/4)."""
    if per_segment is None:
        per_segment = np.maximum(1, np.ceil(lines.length / (0.25 * D))).astype(int)
    seg, frac = segment_end_samples(lines.length, per_segment)
    return {name: state_shape(lines, D, active, seg, frac, name) for name, active in states.items()}


def too_close(lines: Lines, D: float, widths) -> list:
    """(j, a, b) for every segment j where lines a and b both carry an actuator and, at either end of the
    segment, are closer than (w_a + w_b) / 2 around the circumference."""
    phi, on, out = lines.phi(D), actuated(lines.lam), []
    for a in range(lines.count):
        for b in range(a + 1, lines.count):
            gap = np.abs(np.angle(np.exp(1j * (phi[a] - phi[b])))) * D / 2  # (M+1,) around the circumference
            need = (widths[a] + widths[b]) / 2
            for j in np.flatnonzero(on[a] & on[b]):
                if min(gap[j], gap[j + 1]) < need * (1 - 1e-9):
                    out.append((int(j), a, b))
    return out
