"""The shape of the chain NLP: its structure (segments, slots, levels, shared variables) and where each
quantity lives in the decision vector.

Variables are created in stage order, so the constraint Jacobian and the Lagrangian Hessian are
block-banded and an IPOPT iteration costs O(M):

    head     the base pose(s) (w, p): a rotation vector relative to a guessed rotation R0g, and a
             position; none for a fixed pose, one shared by all K levels, or one per level; the global
             lambda variables (one for an sPAM, one per level for multi-shape); extra globals; the
             base frames X_0(k)
    stage j  the structure's declared variables of segment j in order (``methods.variables``: theta_j,
             lam_j (per-segment lambda only), length_j), the formulation's extra stage variables, the
             frames X_{j+1}(k) of every level k

A frame X is 12 numbers: the rotation column-major, then the position. Lengths are in units of the
tube diameter (D = 1), so one built solver serves every tube.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vine_nlp.methods.variables import ROUTING


def frames12(frames: np.ndarray, D: float = 1.0) -> np.ndarray:
    """(M+1, 4, 4) -> (12, M+1): rotation column-major, then position / D (the transcription's frame layout)."""
    R = frames[:, :3, :3].transpose(0, 2, 1).reshape(-1, 9)
    return np.hstack([R, frames[:, :3, 3] / D]).T


POSES = ("free", "fixed", "shared", "level")
LAMBDAS = ("segment", "shared", "level")


@dataclass(frozen=True)
class Structure:
    """What fixes the NLP's shape: M segments, n point slots per segment, K levels, how lambda and
    the base pose are shared, extra variables per stage requested by terms, and the declared design
    variables per segment (``methods.variables``)."""

    M: int
    n: int = 1
    K: int = 1
    lam: str = "segment"  # "segment" (one per segment) | "shared" (one, sPAM) | "level" (one per level)
    pose: str = "free"  # "free" | "fixed" | "shared" (one for all levels) | "level" (one per level)
    extra: int = 0  # extra variables per stage
    globals: int = 0  # extra global variables (head), e.g. systematic construction errors
    variables: tuple = ROUTING  # the declared per-segment variables, in stage order

    def __post_init__(self):
        if self.M < 1 or self.n < 1 or self.K < 1:
            raise ValueError(f"a chain needs M, n, K >= 1 (got {self.M}, {self.n}, {self.K})")
        if self.lam not in LAMBDAS or self.pose not in POSES:
            raise ValueError(f"lam must be one of {LAMBDAS}, pose one of {POSES}")

    @property
    def poses(self) -> int:
        return {"free": 1, "shared": 1, "fixed": 0, "level": self.K}[self.pose]


class Layout:
    """Where each quantity lives in the decision vector (stage order: module docstring). ``var[name]``: the
    entries of a declared variable, (M,) for size 1 ((M, K) where the lambda sharing applies), else (M, size);
    ``theta``, ``lam``, ``dl`` (the length's): those of the routing."""

    def __init__(self, s: Structure):
        M, K, E = s.M, s.K, s.extra
        self.s, self.variables, i = s, s.variables, 0

        def take(count: int) -> np.ndarray:  # the next ``count`` entries of x
            nonlocal i
            i += count
            return np.arange(i - count, i)

        self.pose = take(6 * s.poses).reshape(s.poses, 6)
        self.lam_global = take({"segment": 0, "shared": 1, "level": K}[s.lam])
        self.globals = take(s.globals)
        X = np.zeros((M + 1, K, 12), int)
        X[0] = take(12 * K).reshape(K, 12)
        self.var = {v.name: np.zeros((M, K) if v.levels else (M,) if v.size == 1 else (M, v.size), int) for v in s.variables}
        self.extra = np.zeros((M, E), int)
        for j in range(M):
            for v in s.variables:
                if not v.levels:
                    self.var[v.name][j] = take(v.size)[0] if v.size == 1 else take(v.size)
                elif s.lam == "segment":
                    self.var[v.name][j, :] = take(1)[0]
            self.extra[j] = take(E)
            X[j + 1] = take(12 * K).reshape(K, 12)
        for v in s.variables:
            if v.levels and s.lam != "segment":
                self.var[v.name][:, :] = self.lam_global[0] if s.lam == "shared" else self.lam_global[None, :]
        self.theta, self.lam, self.dl = self.var["theta"], self.var["lam"], self.var["length"]
        self.X = X  # (M+1, K, 12)
        self.pose_of_level = np.zeros(K, int) if s.poses == 1 else np.arange(K)
        self.size = i

    def routing_at(self, j: int, k: int = 0, variables=ROUTING) -> np.ndarray:
        """Entries of segment j's ``variables`` (level k) in order: by default the routing's (after X_j,
        ``variables.POINT``'s; the blocks of the model); ``layout.variables``: every declared one."""
        return np.r_[tuple(self.var[v.name][j, k] if v.levels else self.var[v.name][j] for v in variables)]

    def pack_x(self, frames, poses=None, lam_global=None, extra=None, globals_=None, **values) -> np.ndarray:
        """x from the declared variables by name (``values``: ``var``'s shapes, lengths in units of D), frames
        (K, 12, M+1), poses (P, 6), global lambdas (shared or level), extra (E, M), extra globals (G,)."""
        s, x = self.s, np.zeros(self.size)
        for v in s.variables:
            val, at = values[v.name], self.var[v.name]
            if not v.levels:
                x[at] = np.reshape(val, at.shape) if np.size(val) == at.size else val
            elif s.lam == "segment":
                x[at[:, 0]] = np.asarray(val, float).reshape(s.M, -1)[:, 0]
            elif lam_global is not None:
                x[self.lam_global] = lam_global
            else:
                x[self.lam_global] = np.mean(val) if s.lam == "shared" else np.asarray(val, float).reshape(s.M, s.K)[0]
        frames = np.asarray(frames, float).reshape(s.K, 12, s.M + 1)
        for k in range(s.K):
            x[self.X[:, k, :].T] = frames[k]
        for got, at in ((poses, self.pose), (extra, self.extra.T), (globals_, self.globals)):
            if got is not None and at.size:
                x[at] = np.asarray(got, float).reshape(at.shape)
        return x

    def unpack(self, x) -> dict:
        """``pack_x``'s parts of a decision vector ``x`` by name (the declared variables, poses, lam_global, frames,
        extra, globals)."""
        x = np.asarray(x, float)
        return {v.name: x[self.var[v.name]].copy() for v in self.variables} | {
            "poses": x[self.pose].copy(),
            "lam_global": x[self.lam_global].copy(),
            "frames": np.stack([x[self.X[:, k, :].T] for k in range(self.s.K)]),
            "extra": x[self.extra.T].copy() if self.s.extra else None,
            "globals": x[self.globals].copy(),
        }

    def bounds(self, X0=None, **boxes) -> tuple[np.ndarray, np.ndarray]:
        """Box bounds of the declared variables by name from (lo, hi) pairs (``variables.box``'s; lam per level
        (K,) for lambda per level); ``X0``: (K, 12) fixed base frames for a fixed pose; everything else free."""
        s = self.s
        lbx, ubx = np.full(self.size, -np.inf), np.full(self.size, np.inf)
        for v in s.variables:
            b = boxes[v.name]
            if not v.levels:
                lbx[self.var[v.name]], ubx[self.var[v.name]] = b
            elif s.lam == "level":
                lbx[self.lam_global], ubx[self.lam_global] = b
            else:
                lo, hi = (np.broadcast_to(np.asarray(e, float), (s.M,)) for e in b)
                if s.lam == "shared":
                    lbx[self.lam_global], ubx[self.lam_global] = lo[0], hi[0]
                else:
                    lbx[self.var[v.name][:, 0]], ubx[self.var[v.name][:, 0]] = lo, hi
        if s.pose == "fixed":
            if X0 is None:
                raise ValueError("a fixed pose needs its base frames X0")
            X0 = np.asarray(X0, float).reshape(s.K, 12)
            for k in range(s.K):
                lbx[self.X[0, k]] = ubx[self.X[0, k]] = X0[k]
        return lbx, ubx
