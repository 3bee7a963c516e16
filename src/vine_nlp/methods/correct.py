"""As-built correction: estimate what was built from measured points, then correct it.

Both steps are formulations on the one multiple-shooting transcription
(``design.transcription``); spec/formats.md, "As-built correction".

Deviations (the contract's rule). A robot built from the nominal (theta, lam, length)
realizes (theta_ab, lam_ab, length_ab). The deviations d_theta = theta_ab - theta,
d_lam = lam_ab - lam and the length ratio r = length_ab / length stay with the robot:
built from nominal (theta', lam', length') it realizes (theta' + d_theta, lam' + d_lam,
length' r) (:func:`apply_deviations`).

Estimation (MAP). The chain's theta_j, lam_j, dl_j ARE the as-built values of the latest
build; three global variables are the systematic parts g = (theta offset, lambda offset,
log length scale) shared by every segment. With Gaussian construction errors (sigmas as
in ``vine-nlp analyze``) and Gaussian measurement noise of standard deviation sigma_m,
the negative log posterior times 2 / N (N measured points) is

    (1/N) [ sum_i |P_i(q) - m_i|_perp^2 / sigma_m^2
            + sum_j ((theta_j - theta_nom,j - g0) / s_theta)^2 + ((lam_j - lam_nom,j - g1) / s_lam)^2
                    + ((dl_j - l_nom,j e^g2) / (s_len l_nom,j e^g2))^2
            + sum_k (g_k / s_sys,k)^2 ],

P_i the model point of measured point m_i on its line (center, or the inner/outer line
at D/2 along the normal) at the (segment, fraction) it is paired with. Pairing is
ICP-style (closest model point of the current estimate, numpy model); the residual is
the part of P_i - m_i across the line (the tangent at the pair projected out:
point-to-line, so the pairing itself does not pin material points along the tube),
except for points beyond an end of the line, which keep the full residual. Outer loop:
pair, solve warm, pair again until the pairs stop moving; coarse to fine, the noise sigma
of the fit shrinking by STAGE_FACTOR from D/2 down to sigma_m (the closest points of a robot
built far off its nominal are wrong at first) and pairs farther than TRIM sigmas of the stage
left out; COARSE_ROUNDS rounds per coarse stage, up to ICP_ROUNDS in the last. Each solve uses
the exact Hessian (ESTIMATE_HESSIAN) and IPOPT's warm-start settings (the answer moves little from
round to round; benchmarks/bench_correct.py). Each segment of each build has a fixed number S of
measurement slots (S from the pairing's fullest segment, rounded up to a multiple of SLOT_STEP); a
slot is one instance of one small SX block (the point-to-line residual of one point,
:func:`measure_block`) and holds its point, fraction, tangent and weight as data, unused slots weight
0. Re-pairing changes data only: one structure per (M, S, builds, free pose) serves every ICP round
and every measurement of that size, so it is built once and its functions are compiled
(``design.compiled``; the generated code holds the one-point block once, whatever S;
results/BENCHMARKS.md, "As-built correction").

Earlier builds (rounds): their nominals differ from the latest one by known amounts, so
each earlier build is a second chain of frames (extra stage variables) whose segments are
the latest as-built values shifted by the known differences; its measurements pair with
that chain. One set of deviations explains every measurement.

Pose: the chain's base is fixed at the archive's pose (the measurement is in the archive
frame). With ``free_pose`` the new measurements carry a rigid transform (6 more global
variables), started from a rigid ICP alignment (``design.fit.align``); earlier
measurements are already in the archive frame.

Uncertainty: Laplace approximation, the inverse of the Gauss-Newton Hessian of the MAP
objective (point-to-line residuals / sigma_m and prior residuals) with respect to the
per-segment values, the systematic parts and the pose, the frames eliminated (numpy chain:
a segment's change moves what follows it rigidly, so the Jacobian comes from one twist per
segment and variable, :func:`_line_jacobian`, not one chain evaluation per variable).

sPAM: one shared lambda (one pressure): the lambda deviation is the systematic offset
only (lam_ab = lam_nom + g1 for every segment).

Correction: the plain NLP on the target with the deviations kept. As-built values are the
variables, inside the nominal bounds shifted by the deviations (lam_ab in
[lambda_min + d_lam, 1 + d_lam]; theta fixed at the as-built values unless theta is
adjusted, then in [-theta_max + d_theta, theta_max + d_theta] and within a trust region of
2 sigma_theta around the as-built theta: the estimate holds near the measured shape); the lengths stay at the
as-built lengths (the nominal lengths do not change) and the pose at the archive's; the
nominal to build is the solution minus the deviations.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import ClassVar

import casadi as ca
import numpy as np

from vine_nlp.methods.blocks import BlockType
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.fit.align import PointSet, Polyline, fit_pose, polish_pose, pose_starts
from vine_nlp.methods.nlp import nlp_parameters
from vine_nlp.methods.settings import (
    COARSE_ROUNDS,
    CORRECTION_SCHEDULE,
    ESTIMATE,
    ESTIMATE_HESSIAN,
    ICP_ROUNDS,
    STAGE_FACTOR,
    STAGE_MERGE,
    Settings,
)
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Chain, Smoothness, SoftTip, Spec, get_solver
from vine_nlp.model.chain import chain_frames, chain_points, segment_end_samples
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import MEASURED_LINES, Routing, Sigmas
from vine_nlp.model.segment import segment_function, segment_transform, so3_exp, twist_parts
from vine_nlp.model.shape import routing_metrics
from vine_nlp.problem import DesignProblem, Result

_log = logging.getLogger(__name__)

# offset of each line from the center line along the frame's normal, in units of D
LINE_SIDE = {"center": 0.0, "inner": 0.5, "outer": -0.5}
ADJUST = (("lambda",), ("lambda", "theta"))
# weak priors on the systematic parts: wide against any construction method seen
DEFAULT_SYSTEMATIC_SIGMAS = (math.radians(10.0), 0.2, 0.2)
DEFAULT_MEASUREMENT_SIGMA_MM = 1.0
THETA_TRUST = 2.0  # with theta adjusted, the corrected theta stays within this many sigma_theta of the as-built one
TRIM = 4.0  # pairs farther than this many sigmas of the stage are left out of it
SAMPLES_PER_SEGMENT = 24  # pieces per segment of the model lines the pairing projects onto
SLOT_STEP = 8  # slots per segment are rounded up to a multiple of this (cached structures)


# ---------------------------------------------------------------- deviations (the contract's rule)


@dataclass(frozen=True)
class Deviations:
    """What stays with the robot from build to build: theta and lambda differences, length ratios (M,)."""

    theta: np.ndarray
    lam: np.ndarray
    length_ratio: np.ndarray


def deviations_of(nominal: Routing, as_built: Routing) -> Deviations:
    """The deviations of ``as_built`` from the ``nominal`` it was built from."""
    return Deviations(as_built.theta - nominal.theta, as_built.lam - nominal.lam, as_built.length / nominal.length)


def apply_deviations(nominal: Routing, dev: Deviations) -> Routing:
    """What a robot with deviations ``dev`` realizes when built from ``nominal`` (contract's rule)."""
    return Routing(nominal.theta + dev.theta, nominal.lam + dev.lam, nominal.length * dev.length_ratio, nominal.initial_pose)


def remove_deviations(as_built: Routing, dev: Deviations) -> Routing:
    """The nominal that realizes ``as_built`` on a robot with deviations ``dev``."""
    return Routing(as_built.theta - dev.theta, as_built.lam - dev.lam, as_built.length / dev.length_ratio, as_built.initial_pose)


# ---------------------------------------------------------------- measurements and builds


@dataclass(frozen=True)
class Measurement:
    """Points measured on one line of one build, in any order.

    ``frame``: "archive" (points in the archive's world frame) or "free" (an unknown rigid
    frame, estimated)."""

    points: np.ndarray  # (K, 3), problem units
    line: str = "outer"
    build: int = -1  # index into the builds; -1: the latest
    frame: str = "archive"
    file: str = ""

    def __post_init__(self):
        object.__setattr__(self, "points", np.asarray(self.points, float).reshape(-1, 3))
        if self.line not in MEASURED_LINES:
            raise ValueError(f"line must be one of {MEASURED_LINES}, not {self.line!r}")
        if self.frame not in ("archive", "free"):
            raise ValueError("frame must be 'archive' or 'free'")


def _moved(points: np.ndarray, m: Measurement, T: np.ndarray) -> np.ndarray:
    """``points`` of measurement ``m`` moved by the rigid transform T where m's frame is free."""
    return points @ T[:3, :3].T + T[:3, 3] if m.frame == "free" else points


def _line_points(routing: Routing, D: float, seg, frac, side: float, frames=None):
    """Points of the line at (seg, frac) and the unit tangents of the center frames there (``frames``: the
    routing's chain frames, when known)."""
    c, rot = chain_points(routing.theta, routing.lam, routing.length, D, seg, frac, routing.initial_pose, frames)
    return c + side * D * rot[:, :, 1], rot[:, :, 0]


@dataclass
class _Pairs:
    seg: np.ndarray
    frac: np.ndarray
    tangent: np.ndarray  # zero rows: beyond an end of the line (full residual)
    l: np.ndarray  # material coordinate
    point: np.ndarray  # the paired points of the model line


def pair_with_line(points: np.ndarray, routing: Routing, D: float, side: float, per_segment: int = SAMPLES_PER_SEGMENT) -> _Pairs:
    """Closest points of the model line (``side``: offset along the normal in D) for measured points."""
    seg, frac = segment_end_samples(routing.length, per_segment)
    F = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)
    P, _ = _line_points(routing, D, seg, frac, side, F)
    cum = np.concatenate([[0.0], np.cumsum(routing.length)])
    lmat = cum[seg] + frac * routing.length[seg]
    d = np.diff(P, axis=0)
    n2 = np.maximum(np.sum(d * d, axis=1), 1e-300)
    from scipy.spatial import cKDTree  # SciPy loads only where measurements are paired

    k = min(4, P.shape[0])
    _, idx = cKDTree(P).query(points, k=k)
    idx = idx.reshape(points.shape[0], k)
    cand = np.clip(np.concatenate([idx - 1, idx], axis=1), 0, d.shape[0] - 1)
    u = np.clip(np.einsum("kcj,kcj->kc", points[:, None, :] - P[cand], d[cand]) / n2[cand], 0.0, 1.0)
    q = P[cand] + u[..., None] * d[cand]
    best = np.argmin(np.sum((points[:, None, :] - q) ** 2, axis=2), axis=1)
    rows = np.arange(points.shape[0])
    piece, uu = cand[rows, best], u[rows, best]
    l = lmat[piece] + uu * (lmat[piece + 1] - lmat[piece])
    j = np.clip(np.searchsorted(cum, l, side="right") - 1, 0, routing.segments - 1)
    f = np.clip((l - cum[j]) / routing.length[j], 0.0, 1.0)
    Pj, t = _line_points(routing, D, j, f, side, F)
    end = ((piece == 0) & (uu <= 0.0)) | ((piece == d.shape[0] - 1) & (uu >= 1.0))
    t[end] = 0.0
    return _Pairs(j, f, t, l, Pj)


def simulate_build(nominal: Routing, dev: Deviations, D: float, line: str = "outer", count: int = 300, noise: float = 0.0,
                   seed: int = 0) -> np.ndarray:
    """Measured points of the robot ``nominal`` with deviations ``dev``: ``count`` points equally spaced in
    material coordinate along ``line``, Gaussian noise of standard deviation ``noise`` (problem units) per
    coordinate, shuffled (measurements come in any order). For tests, benchmarks and examples."""
    built = apply_deviations(nominal, dev)
    cum = np.concatenate([[0.0], np.cumsum(built.length)])
    l = np.linspace(0.0, cum[-1], count)
    j = np.clip(np.searchsorted(cum, l, side="right") - 1, 0, built.segments - 1)
    f = np.clip((l - cum[j]) / built.length[j], 0.0, 1.0)
    P, _ = _line_points(built, D, j, f, LINE_SIDE[line])
    rng = np.random.default_rng(seed)
    P = P + noise * rng.standard_normal(P.shape)
    return P[rng.permutation(count)]


def draw_deviations(nominal: Routing, sigmas: Sigmas, systematic=(0.0, 0.0, 0.0), seed: int = 0, D: float = 1.0) -> Deviations:
    """Random deviations: independent per-segment errors at ``sigmas`` plus the ``systematic`` parts
    (theta offset rad, lambda offset, length scale factor); relative length errors multiply."""
    rng = np.random.default_rng(seed)
    M = nominal.segments
    e = rng.standard_normal((M, 3))
    sl = sigmas.length if sigmas.relative_length else sigmas.length / nominal.length
    return Deviations(systematic[0] + sigmas.theta * e[:, 0], systematic[1] + sigmas.lam * e[:, 1],
                      systematic[2] * (1.0 + sl * e[:, 2]))


# ---------------------------------------------------------------- blocks of the estimation NLP


# data rows of one measurement slot (measure_block): shift (3), u, m (3), tangent (3), sqrt weight, side
# [, centroid (3), free flag]
SLOT_DATA = 12
SLOT_DATA_FREE = 16


@lru_cache(maxsize=2)
def measure_block(free: bool) -> BlockType:
    """Point-to-line residual of one measured point (one slot of one segment of one build), SX.

    One block instance per slot: the generated code holds the point's function and its derivatives once,
    whatever the number of slots (module docstring).
    v = (X_j (12), theta, lam, dl[, w (3), t (3)]): the segment's local variables of the latest
    as-built chain (and the rigid transform of free-frame measurements);
    d = (shift (3): theta and lambda added, length factor (the build's nominal against the latest),
    u, m (3), t (3) tangent, w square root of the weight, side [, c (3) centroid, flag]).
    Residual w (I - t t^T)(P - m) (the square root as data: a zero-weight slot has finite derivatives);
    a free-frame point (flag 1) is moved by exp(w) (m - c) + c + t first (m stored as given, c their centroid)."""
    nv = 21 if free else 15
    nd = SLOT_DATA_FREE if free else SLOT_DATA
    v, d = ca.SX.sym("v", nv), ca.SX.sym("d", nd)
    th, la, dl = v[12] + d[0], v[13] + d[1], v[14] * d[2]
    u, mi, tg, w, side = d[3], d[4:7], d[7:10], d[10], d[11]
    R, p = ca.reshape(v[:9], 3, 3), v[9:12]
    kappa, tau, lc = center_rates(th, la, 1.0)
    Rs, q = twist_parts(kappa, tau, u * dl * lc)
    local = ca.vertcat(q[0] + side * Rs[0][1], q[1] + side * Rs[1][1], q[2] + side * Rs[2][1])
    P = p + ca.mtimes(R, local)
    if free:
        c, flag = d[12:15], d[15]
        mi = mi + flag * (ca.mtimes(so3_exp(v[15:18]), mi - c) + c + v[18:21] - mi)
    e = P - mi
    res = w * (e - tg * ca.dot(tg, e))
    return BlockType(f"measure{'f' if free else ''}", ca.Function("measure_block", [v, d], [ca.sumsqr(res), ca.SX(0, 1)]),
                     ca.Function("measure_res", [v, d], [res]))


@lru_cache(maxsize=1)
def shifted_segment_block() -> BlockType:
    """Continuity of an earlier build's chain: X'_{j+1} = X'_j T(theta + d_theta, lam + d_lam, dl f).
    v = (X'_j (12), theta, lam, dl, X'_{j+1} (12)); d = (d_theta, d_lam, f)."""
    v, d = ca.SX.sym("v", 27), ca.SX.sym("d", 3)
    Xn, _ = segment_function(1)(v[:12], v[12] + d[0], v[13] + d[1], v[14] * d[2], 0.0)
    return BlockType("shifted_segment", ca.Function("shifted_block", [v, d], [ca.SX(0), Xn - v[15:]]),
                     ca.Function("shifted_res", [v, d], [ca.SX(0, 1)]))


@dataclass(frozen=True)
class AsBuiltTerm:
    """The MAP estimate's terms (module docstring) for ``builds`` builds (the last is the chain itself,
    the others extra frames) with ``S`` slots per segment and build; ``free``: a rigid transform of the
    free-frame measurements in globals 3..8. Parameters: meas (nd x M B S, one column per slot), shift (3 x M (B-1)),
    prior (3 x M: nominal theta, lam, dl of the latest build), prior_sig (8: s_theta, s_lam, s_len_rel,
    s_len_abs (D), s_sys (3), scale)."""

    S: int
    builds: int = 1
    free: bool = False
    # the pairing is data (slot fractions, points, weights 0 on unused slots): one structure per (M, S, builds,
    # free) serves every ICP round and every measurement of that size, worth compiling (design.compiled)
    compile: ClassVar[bool] = True

    def apply(self, c: Chain) -> None:
        s, lay = c.s, c.lay
        M, B, S = s.M, self.builds, self.S
        bt = measure_block(self.free)
        nd = bt.fn.size1_in(1)
        meas = c.param("meas", (nd, M * B * S))  # slot k of segment j of build b: column (b M + j) S + k
        shift = c.param("shift", (3, max(M * (B - 1), 1)))
        prior, sig = c.param("prior", (3, M)), c.param("prior_sig", (8, 1))

        def frame(b, j):
            if b == B - 1 or j == 0:
                return lay.X[j, 0]
            return lay.extra[j - 1, 12 * b : 12 * b + 12]

        glob = lay.globals[3:9] if self.free else np.zeros(0, int)
        cols = [np.r_[frame(b, j), lay.theta[j], lay.lam[j, 0], lay.dl[j], glob] for b in range(B) for j in range(M)]
        c.add_block(bt, np.hstack([np.repeat(col[:, None], S, axis=1) for col in cols]), meas, term="fit")
        if B > 1:
            idx = [np.r_[frame(b, j), lay.theta[j], lay.lam[j, 0], lay.dl[j], lay.extra[j, 12 * b : 12 * b + 12]]
                   for b in range(B - 1) for j in range(M)]
            c.add_block(shifted_segment_block(), np.array(idx).T, shift)
        g = c.globals
        L = prior[2, :] * ca.exp(g[2])
        r_th = (c.theta - prior[0, :] - g[0]) / sig[0]
        r_len = (c.dl - L) / (sig[2] * L + sig[3])
        val = ca.sumsqr(r_th) + ca.sumsqr(r_len) + ca.sumsqr(g[:3] / sig[4:7])
        if s.lam == "segment":
            val += ca.sumsqr((c.lam_of(0) - prior[1, :] - g[1]) / sig[1])
        else:
            c.add_rows("spam_offset", c.lam_of(0)[0] - prior[1, 0] - g[1], 0.0, 0.0)
        c.add_term("prior", sig[7] * val)


# ---------------------------------------------------------------- estimation


@dataclass
class Estimate:
    """The estimated as-built robot (latest build) and how well it is known.

    ``systematic``: (theta offset rad, lambda offset, length scale factor) and ``systematic_std``
    their standard deviations (the scale's by the delta method); ``std`` (M, 3): standard
    deviations of theta, lambda and length (problem units) per segment; ``transform``: 4x4 moving
    free-frame measurements into the archive frame (identity without them); ``residuals``: per
    measurement, the distances of its points to the estimated line (problem units)."""

    routing: Routing
    deviations: Deviations
    systematic: np.ndarray
    systematic_std: np.ndarray
    std: np.ndarray
    transform: np.ndarray
    residuals: list
    status: str
    iterations: int
    solve_time_s: float
    rounds: int
    stats: dict = field(default_factory=dict)

    @property
    def rmse(self) -> float:
        d = np.concatenate(self.residuals) if self.residuals else np.zeros(1)
        return float(np.sqrt(np.mean(d**2)))


def _estimation_spec(M: int, shared: bool, builds: int, S: int, free: bool, hessian: str) -> Spec:
    st = Structure(M, 1, 1, "shared" if shared else "segment", "fixed", extra=12 * (builds - 1), globals=9 if free else 3)
    return Spec(st, (AsBuiltTerm(S, builds, free),), hessian,
                ESTIMATE)


def _rigid_start(measurements, routings, D):
    """A rigid transform (4x4) of the free-frame measurements onto the model lines of their builds (ICP)."""
    sets = []
    for ms in measurements:
        if ms.frame != "free":
            continue
        r = routings[ms.build]
        seg, frac = segment_end_samples(r.length, 8)
        P, _ = _line_points(r, D, seg, frac, LINE_SIDE[ms.line])
        sets.append(PointSet(ms.points, Polyline(P)))
    if not sets:
        return np.eye(4)
    X = np.concatenate([s.points for s in sets])
    Y = np.concatenate([s.line.p for s in sets])
    return polish_pose(sets, fit_pose(sets, pose_starts(X, Y, 24, 0)).T)[0]


def estimate_as_built(nominals: list, measurements: list, D: float, sigmas: Sigmas, shared_lambda: bool = False,
                      measurement_sigma: float | None = None, systematic_sigmas=DEFAULT_SYSTEMATIC_SIGMAS,
                      hessian: str | None = None, rounds: int = ICP_ROUNDS, units_per_mm: float = 0.1) -> Estimate:
    """MAP estimate of the as-built robot from measurements of one or more builds (module docstring).

    Parameters
    ----------
    nominals : list of Routing
        The nominal routing of each build, oldest first; the last is the one the estimate is of.
        All have the same segments and initial pose (the robot's base).
    measurements : list of Measurement
        Points of any build (``build`` indexes ``nominals``; -1 the latest), any line, any order.
    D : float
        Tube diameter (problem units).
    sigmas : Sigmas
        Standard deviations of the per-segment construction errors (the prior).
    shared_lambda : bool
        sPAM: one lambda (its deviation is the lambda offset only).
    measurement_sigma : float, optional
        Standard deviation of the measurement noise, problem units (default 1 mm).
    systematic_sigmas : (3,)
        Prior standard deviations of theta offset (rad), lambda offset, log length scale.
    hessian : str, optional
        "exact" or "gauss-newton", of the transcription's blocks (default ESTIMATE_HESSIAN, exact).
    rounds : int
        Pair-and-solve rounds of the last stage of the coarse-to-fine loop, at most (COARSE_ROUNDS
        for each earlier stage).
    units_per_mm : float
        Problem units per millimetre (for the default measurement sigma).

    Returns
    -------
    Estimate

    Raises
    ------
    ValueError
        Sigmas that are not > 0.
    """
    t_all, cpu_all = time.perf_counter(), time.process_time()
    hessian = hessian or ESTIMATE_HESSIAN
    B, latest = len(nominals), nominals[-1]
    M, T0 = latest.segments, latest.initial_pose
    sig_m = (DEFAULT_MEASUREMENT_SIGMA_MM * units_per_mm) if measurement_sigma is None else float(measurement_sigma)
    ms = [replace(m, build=m.build % B) for m in measurements]
    N = sum(m.points.shape[0] for m in ms)
    free = any(m.frame == "free" for m in ms)
    scale = 1.0 / N
    # shifts of every build against the latest nominal (known differences of what was built)
    shifts = [(n.theta - latest.theta, n.lam - latest.lam, n.length / latest.length) for n in nominals]
    T_free = _rigid_start(ms, nominals, D) if free else np.eye(4)
    pts = [_moved(m.points, m, T_free) for m in ms]
    centroid = np.mean(np.concatenate([p for p, m in zip(pts, ms) if m.frame == "free"]), axis=0) if free else np.zeros(3)
    g_free = np.zeros(6)

    def routings_of(ab: Routing):
        return [Routing(ab.theta + a, ab.lam + b, ab.length * c, T0) for a, b, c in shifts]

    def pts_now(Tc):
        return [_moved(p, m, Tc) for p, m in zip(pts, ms)]

    def pairs_of(ab, Tcorr):
        rs = routings_of(ab)
        return [pair_with_line(q, rs[m.build], D, LINE_SIDE[m.line]) for q, m in zip(pts_now(Tcorr), ms)]

    def slots_needed(pairs):
        cnt = np.zeros((B, M), int)
        for pr, m in zip(pairs, ms):
            cnt[m.build] += np.bincount(pr.seg, minlength=M)
        return max(1, int(cnt.max()))

    def meas_data(pairs, S, s_stage, moved, trim):
        nd = SLOT_DATA_FREE if free else SLOT_DATA
        data = np.zeros((nd, B * M * S))  # padding slots: weight 0, fraction 0
        for b in range(B):
            cols = slice(b * M * S, (b + 1) * M * S)
            for k in range(3):
                data[k, cols] = np.repeat(shifts[b][k], S)
        if free:
            data[12:15] = (centroid / D)[:, None]
        fill = np.zeros(B * M, int)
        for pr, m, p, q in zip(pairs, ms, pts, moved):
            keep = np.linalg.norm(pr.point - q, axis=1) <= trim
            cell = m.build * M + pr.seg
            # each point's rank among the points of its cell, in order: the next free slots of the cell
            order = np.argsort(cell, kind="stable")
            sorted_cells = cell[order]
            rank = np.empty(cell.size, int)
            rank[order] = np.arange(cell.size) - np.searchsorted(sorted_cells, sorted_cells, side="left")
            col = cell * S + fill[cell] + rank
            fill += np.bincount(cell, minlength=B * M)
            data[3, col] = pr.frac
            data[4:7, col] = (p / D).T
            data[7:10, col] = pr.tangent.T
            data[10, col] = np.where(keep, math.sqrt(scale) * D / s_stage, 0.0)
            data[11, col] = LINE_SIDE[m.line]
            if free:
                data[15, col] = 1.0 if m.frame == "free" else 0.0
        return data

    s_rel, s_abs = (sigmas.length, 0.0) if sigmas.relative_length else (0.0, sigmas.length / D)
    prior_sig = np.array([sigmas.theta, sigmas.lam, s_rel, s_abs, *systematic_sigmas, scale])
    if np.any(prior_sig[:2] <= 0) or (s_rel <= 0 and s_abs <= 0):
        raise ValueError("the construction-error sigmas must be > 0")
    prior = np.vstack([latest.theta, latest.lam, latest.length / D])

    ab, Tcorr = latest, np.eye(4)
    x = solver = None
    pairs = pairs_of(ab, Tcorr)
    S = int(math.ceil(1.25 * slots_needed(pairs) / SLOT_STEP) * SLOT_STEP)
    iterations, status, rounds_done, st = 0, "failed", 0, {}
    shift_data = np.vstack([np.concatenate([shifts[b][k] for b in range(B - 1)]) for k in range(3)]) if B > 1 else np.zeros((3, 1))
    # coarse to fine: the noise sigma of the fit starts at D/2 and halves down to the measurement's
    # (closest-point pairs of a robot built far off its nominal are wrong at first), pairs farther than
    # TRIM sigmas are left out at each stage
    stages = []
    s_k = 0.5 * D
    while s_k > STAGE_MERGE * sig_m:
        stages.append(s_k)
        s_k *= STAGE_FACTOR
    stages.append(sig_m)
    for s_stage in stages:
        for _ in range(rounds if s_stage == stages[-1] else min(rounds, COARSE_ROUNDS)):
            need = slots_needed(pairs)
            if need > S:
                S = int(math.ceil(need / SLOT_STEP) * SLOT_STEP)
                solver = None
            if solver is None:
                solver = get_solver(_estimation_spec(M, shared_lambda, B, S, free, hessian))
                x = None
            lay = solver.layout
            data = meas_data(pairs, S, s_stage, pts_now(Tcorr), TRIM * max(s_stage, sig_m))
            p = solver.pack_params({"cells": np.zeros((5, M)), "meas": data, "shift": shift_data, "prior": prior,
                                    "prior_sig": prior_sig})
            if x is None:
                x = _start_x(solver, ab, D, routings_of(ab), B, lay)
                if free:
                    x[lay.globals[3:9]] = g_free
            lbx, ubx = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
            lbx[lay.X[0, 0]] = ubx[lay.X[0, 0]] = np.r_[T0[:3, :3].ravel(order="F"), T0[:3, 3] / D]
            lbx[lay.dl], ubx[lay.dl] = 0.2 * latest.length / D, 5.0 * latest.length / D
            lbx[lay.lam_global if shared_lambda else lay.lam[:, 0]] = 0.05
            lbx[lay.theta], ubx[lay.theta] = -1.45, 1.45
            x, status, st = solver.solve(x, p, lbx, ubx)
            iterations += st["iterations"]
            rounds_done += 1
            v = solver.unpack(x)
            lam_ab = np.full(M, v["lam_global"][0]) if shared_lambda else v["lam"][:, 0]
            ab = Routing(v["theta"], lam_ab, v["dl"] * D, T0)
            if free:
                g_free = v["globals"][3:9].copy()
                Tcorr = _free_transform(v["globals"], centroid, D)
            new = pairs_of(ab, Tcorr)
            moved = max(float(np.max(np.abs(a.l - b.l))) for a, b in zip(new, pairs))
            pairs = new
            _log.debug("estimate: stage sigma %.3g, %s after %d iterations, pairs moved up to %.2g D", s_stage, status,
                       st["iterations"], moved / D)
            if moved < 1e-3 * D:
                break
    g = solver.unpack(x)["globals"]
    # Laplace approximation around the estimate
    std, sys_std, residuals = _laplace(ab, g[:3], shifts, ms, pts, pairs, D, sig_m, sigmas, systematic_sigmas, prior, shared_lambda,
                                       free, centroid, Tcorr)
    return Estimate(
        routing=ab, deviations=deviations_of(latest, ab), systematic=np.array([g[0], g[1], math.exp(g[2])]), systematic_std=sys_std,
        std=std, transform=Tcorr @ T_free, residuals=residuals, status=status, iterations=iterations, solve_time_s=time.perf_counter() - t_all,
        rounds=rounds_done,
        stats={"measurement_sigma": sig_m, "slots_per_segment": S, "points": N, "builds": B, "hessian": hessian,
               "objective": st.get("objective", float("nan")), "free_pose": free, "cpu_time_s": time.process_time() - cpu_all},
    )


def _unit_scale(D):
    s = np.ones((4, 4))
    s[:3, 3] = 1.0 / D
    return s


def _free_transform(g, centroid, D):
    """The transform x -> exp(w) (x - c) + c + t of the globals 3..8 (t in units of D)."""
    R = so3_exp(np.asarray(g[3:6], float))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, centroid - R @ centroid + np.asarray(g[6:9], float) * D
    return T


def _start_x(solver, ab, D, routings, B, lay):
    frames = chain_frames(ab.theta, ab.lam, ab.length, D, ab.initial_pose) * _unit_scale(D)
    x = solver.pack_x(ab.theta, ab.lam, ab.length / D, frames12(frames)[None], lam_global=np.mean(ab.lam),
                      globals_=np.zeros(lay.globals.size))
    for b in range(B - 1):
        r = routings[b]
        fb = frames12(chain_frames(r.theta, r.lam, r.length, D, r.initial_pose) * _unit_scale(D))
        x[lay.extra[:, 12 * b : 12 * b + 12]] = fb[:, 1:].T
    return x


def _line_jacobian(r: Routing, D: float, seg, frac, side: float, step: float = 1e-6):
    """Points of the line at (seg, frac) and their derivatives (3, N, 3 M) with respect to (theta, lam, length)
    of every segment: a segment's change moves everything after it rigidly (a world-frame twist
    F_k dA_k A_k^-1 F_k^-1 applied to the point), and moves the points on it through their own local transform
    (central differences of the segment transform only, vectorized: a handful of model calls instead of one
    chain evaluation per variable)."""
    M = r.segments
    F = chain_frames(r.theta, r.lam, r.length, D, r.initial_pose)
    A = segment_transform(r.theta, r.lam, r.length, D)
    seg, frac = np.asarray(seg, int), np.asarray(frac, float)
    y = np.array([0.0, side * D, 0.0, 1.0])
    local = segment_transform(r.theta[seg], r.lam[seg], frac * r.length[seg], D)
    P = (F[seg] @ local) @ y  # (N, 4)
    Finv = np.linalg.inv(F[:-1])
    Ainv = np.linalg.inv(A)
    J = np.zeros((3, seg.size, 3 * M))
    before = np.arange(M)[:, None] < seg[None, :]  # (M, N): segment k lies before point i
    args = [r.theta, r.lam, r.length]
    largs = [r.theta[seg], r.lam[seg], r.length[seg]]
    for q in range(3):
        h = step * (r.length if q == 2 else np.ones(M))
        up, dn = list(args), list(args)
        up[q], dn[q] = args[q] + h, args[q] - h
        dA = (segment_transform(*up, D) - segment_transform(*dn, D)) / (2 * h)[:, None, None]
        Xi = F[:-1] @ dA @ Ainv @ Finv  # (M, 4, 4)
        moved = np.einsum("kij,nj->ikn", Xi[:, :3, :], P) * before[None]  # (3, M, N)
        hl = h[seg]
        lu, ld = list(largs), list(largs)
        lu[q], ld[q] = largs[q] + hl, largs[q] - hl
        lu[2], ld[2] = frac * lu[2], frac * ld[2]
        dloc = (segment_transform(*lu, D) - segment_transform(*ld, D)) / (2 * hl)[:, None, None]
        own = ((F[seg][:, :3, :] @ dloc) @ y).T  # (3, N)
        block = moved.transpose(0, 2, 1)  # (3, N, M)
        block[:, np.arange(seg.size), seg] += own
        J[:, :, q * M : (q + 1) * M] = block
    return P[:, :3], J


def _laplace(ab, g, shifts, ms, pts, pairs, D, sig_m, sigmas, sys_sig, prior, shared, free, centroid, Tcorr):
    """Standard deviations from the inverse Gauss-Newton Hessian of the MAP objective (module docstring).

    The measurement residuals' Jacobian is assembled from the chain's twists (``_line_jacobian``); the
    prior's (cheap, no model) and the free pose's (six variables) by central differences."""
    M = ab.segments
    nl = 1 if shared else M
    n_free = 6 if free else 0
    T0 = ab.initial_pose

    def unpack(q):
        th, la = q[:M], q[M : M + nl]
        la = np.full(M, la[0]) if shared else la
        ln, gg = q[M + nl : 2 * M + nl], q[2 * M + nl : 2 * M + nl + 3]
        return th, la, ln, gg, q[2 * M + nl + 3 :]

    def moved(p, m, pose):
        if m.frame != "free":
            return p
        return (_moved(p, m, Tcorr) - centroid) @ so3_exp(pose[:3]).T + centroid + pose[3:]

    def prior_residuals(q):
        th, la, ln, gg, _ = unpack(q)
        L = prior[2] * D * math.exp(gg[2])
        sl = sigmas.length * L if sigmas.relative_length else np.full(M, sigmas.length)
        out = [(th - prior[0] - gg[0]) / sigmas.theta]
        if not shared:
            out.append((la - prior[1] - gg[1]) / sigmas.lam)
        out += [(ln - L) / sl, np.asarray(gg) / np.asarray(sys_sig)]
        return np.concatenate(out)

    q0 = np.concatenate([ab.theta, ab.lam[:1] if shared else ab.lam, ab.length, g, np.zeros(n_free)])
    nq = q0.size
    rows, dists = [], []
    for p, m, pr in zip(pts, ms, pairs):
        a, b, c = shifts[m.build]
        r = Routing(ab.theta + a, ab.lam + b, ab.length * c, T0)
        P, JP = _line_jacobian(r, D, pr.seg, pr.frac, LINE_SIDE[m.line])
        t = pr.tangent
        dists.append(np.linalg.norm(P - moved(p, m, np.zeros(6)), axis=1))
        # point-to-line: the tangent at the pair projected out, as in the estimate
        JP = JP - t.T[:, :, None] * np.einsum("in,ink->nk", t.T, JP)[None]
        Jm = np.zeros((3, P.shape[0], nq))
        Jm[:, :, :M] = JP[:, :, :M]
        if shared:
            Jm[:, :, M] = JP[:, :, M : 2 * M].sum(axis=2)
        else:
            Jm[:, :, M : 2 * M] = JP[:, :, M : 2 * M]
        Jm[:, :, M + nl : 2 * M + nl] = c * JP[:, :, 2 * M :]  # the build's lengths are the latest ones times c
        if m.frame == "free":
            for k in range(6):
                dq = np.zeros(6)
                dq[k] = 1e-6 * (D if k >= 3 else 1.0)
                de = -(moved(p, m, dq) - moved(p, m, -dq)) / (2 * dq[k])
                de = de - t * np.sum(t * de, axis=1, keepdims=True)
                Jm[:, :, nq - 6 + k] = de.T
        rows.append(Jm.transpose(1, 0, 2).reshape(-1, nq) / sig_m)
    steps = np.concatenate([np.full(M, 1e-6), np.full(nl, 1e-6), ab.length * 1e-6, np.full(3, 1e-6), np.full(n_free, 1e-6 * D)])
    Jp = np.empty((prior_residuals(q0).size, nq))
    for k in range(nq):
        dq = np.zeros_like(q0)
        dq[k] = steps[k]
        Jp[:, k] = (prior_residuals(q0 + dq) - prior_residuals(q0 - dq)) / (2 * steps[k])
    J = np.vstack(rows + [Jp])
    from scipy.linalg import blas, lapack  # SciPy loads only where measurements are paired

    # BLAS/LAPACK kernels that stay single-threaded at this size: numpy's J.T @ J and inv() go through
    # threaded OpenBLAS paths, tens to hundreds of times slower on a loaded 2-core machine
    H = blas.dsyrk(1.0, J, trans=1, lower=0)  # upper triangle of J^T J
    U, info = lapack.dpotrf(H, lower=0, clean=1)  # H = U^T U
    if info == 0:
        # the prior makes H positive definite (every variable but the pose has one, the pose is measured);
        # diag(H^-1) = row sums of squares of U^-1
        Ui, info = lapack.dtrtri(U, lower=0)
    if info == 0:
        var = np.sum(Ui * Ui, axis=1)
    else:
        Hs = np.triu(H) + np.triu(H, 1).T
        var = np.diag(np.linalg.pinv(Hs, rcond=1e-12, hermitian=True))
    sd = np.sqrt(np.maximum(var, 0.0))
    th_sd, la_sd, ln_sd, g_sd, _ = unpack(sd)
    if shared:
        la_sd = np.full(M, g_sd[1])
    sys_std = np.array([g_sd[0], g_sd[1], math.exp(g[2]) * g_sd[2]])
    return np.column_stack([th_sd, la_sd, ln_sd]), sys_std, dists


# ---------------------------------------------------------------- correction


def correction_spec(M: int, n: int, shared: bool, max_iter: int, tol: float, hessian: str) -> Spec:
    """The plain NLP with the base pose fixed (the robot's base stays where it was built)."""
    return Spec(Structure(M, n, 1, "shared" if shared else "segment", "fixed"), (Smoothness(), SoftTip()), hessian,
                Settings(max_iter, tol, repeated=True))


def correct_routing(problem: DesignProblem, as_built: Routing, dev: Deviations, adjust=("lambda",),
                    built: Routing | None = None, theta_trust: float | None = None) -> tuple[Routing, Routing, str, dict]:
    """Nominal values to build next so that the robot, its deviations kept, matches the target.

    ``built``: the nominal that was built; its lengths (and, unless theta is adjusted, its theta) are
    copied to the result exactly (default: as_built minus the deviations, equal to round-off).
    ``theta_trust``: with theta adjusted, the bound (rad) on |theta - theta as built| (None: only the
    design's bounds).
    Returns (nominal to build, its predicted as-built routing, status, solver stats).
    """
    adjust = tuple(adjust)
    if adjust not in ADJUST:
        raise ValueError(f"adjust must be one of {', '.join(','.join(a) for a in ADJUST)}")
    D, a, o = problem.diameter, problem.actuator, problem.options
    pairing = pair_points(problem.target, o.points_per_segment)
    M = pairing.segments
    if M != as_built.segments:
        raise ValueError(f"the design has {as_built.segments} segments, the problem's pairing {M}")
    shared = a.shared_lambda
    best = None
    total_iterations = 0
    for hessian, cap in CORRECTION_SCHEDULE:
        solver = get_solver(correction_spec(M, pairing.n, shared, min(cap or o.max_iter, o.max_iter), o.tol, hessian))
        p = solver.pack_params(nlp_parameters(problem, pairing, as_built.initial_pose[:3, :3]))
        if "theta" in adjust:
            th = (-a.theta_max + dev.theta, a.theta_max + dev.theta)
            if theta_trust is not None:
                th = (np.maximum(th[0], as_built.theta - theta_trust), np.minimum(th[1], as_built.theta + theta_trust))
        else:
            th = (as_built.theta, as_built.theta)
        dl = as_built.length / D
        f12 = frames12(chain_frames(as_built.theta, as_built.lam, as_built.length, D, as_built.initial_pose) * _unit_scale(D))
        if shared:
            off = float(np.mean(dev.lam))
            lam_b = (np.full(M, a.lambda_min + off), np.full(M, 1.0 + off))
        else:
            lam_b = (a.lambda_min + dev.lam, 1.0 + dev.lam)
        lbx, ubx = solver.bounds(th, lam_b, (dl, dl), X0=f12[:, 0][None])
        x0 = solver.pack_x(as_built.theta, as_built.lam, dl, f12[None], lam_global=float(np.mean(as_built.lam)))
        x, status, st = solver.solve(x0, p, lbx, ubx)
        total_iterations += st["iterations"]
        _log.debug("correction %s: %s, %d iterations, %.2f s", hessian, status, st["iterations"], st["solve_time_s"])
        if status == "optimal" or best is None:
            best = (x, status, st, solver)
        if status == "optimal":
            break
    x, status, st, solver = best
    st = dict(st, iterations=total_iterations)
    v = solver.unpack(x)
    lam = np.full(M, v["lam_global"][0]) if shared else v["lam"][:, 0]
    realized = Routing(v["theta"], lam, as_built.length, as_built.initial_pose)
    nominal = remove_deviations(realized, dev)
    base = built if built is not None else remove_deviations(as_built, dev)
    # what the builder does not change stays exactly what was built
    nominal = Routing(base.theta if "theta" not in adjust else nominal.theta, nominal.lam, base.length, base.initial_pose)
    return nominal, realized, status, st


@dataclass
class CorrectionResult:
    """``as_built``: the estimated effective routing (shape at the target's pairing; metrics rmse/max_error
    against the measurements, target_rmse/target_max_error against the target); ``corrected``: the nominal
    to build next (shape: what it will realize; metrics: the predicted error to the target);
    ``built``: the nominal of the build measured last; ``estimate``: the full estimate."""

    built: Routing
    as_built: Result
    corrected: Result
    estimate: Estimate
    measurements: list  # Measurement in the archive frame (free-frame ones moved by the estimated transform)
    adjust: tuple = ("lambda",)


def correct(problem: DesignProblem, nominals: list, measurements: list, *, adjust=("lambda",), sigmas: Sigmas | None = None,
            measurement_sigma: float | None = None, systematic_sigmas=DEFAULT_SYSTEMATIC_SIGMAS, units_per_mm: float = 0.1,
            theta_trust: float | None = None) -> CorrectionResult:
    """Estimate the built robot and correct it (module docstring): the design layer, no file I/O.

    Parameters
    ----------
    problem : DesignProblem
        The target the robot should match (the archive's design problem).
    nominals : list of Routing
        The nominal of each build measured so far, oldest first; the last is the one just built.
    measurements : list of Measurement
        Their measured points (``build`` indexes ``nominals``).
    adjust : ("lambda",) or ("lambda", "theta")
        What the builder changes.
    sigmas : Sigmas
        Construction errors (default 1 deg, 0.02, 2 %), the prior of the estimate.
    theta_trust : float, optional
        With theta adjusted: how far (rad) the corrected theta may move from the as-built one (default
        THETA_TRUST sigma_theta). The estimate is made around the measured shape; a redrawn line far from it
        would extrapolate the estimated deviations (Bezier (a): the median gain of round 1 was 4x without
        this bound, 38x with 2 sigma).

    Returns
    -------
    CorrectionResult
    """
    t0 = time.perf_counter()
    sigmas = sigmas or Sigmas.from_degrees(1.0, 0.02, 0.02)
    D = problem.diameter
    est = estimate_as_built(nominals, measurements, D, sigmas, problem.actuator.shared_lambda, measurement_sigma, systematic_sigmas,
                            units_per_mm=units_per_mm)
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    ab_res = evaluate(problem, est.routing, pairing, "as_built", status=est.status, solve_time_s=est.solve_time_s,
                      iterations=est.iterations, stats=dict(est.stats) | {"icp_rounds": est.rounds})
    ab_res.metrics = {"target_rmse": ab_res.metrics["rmse"], "target_max_error": ab_res.metrics["max_error"]}
    d = np.concatenate(est.residuals)
    ab_res.metrics.update(rmse=float(np.sqrt(np.mean(d**2))), max_error=float(d.max()), **routing_metrics(est.routing))
    t1 = time.perf_counter()
    trust = THETA_TRUST * sigmas.theta if theta_trust is None else theta_trust
    nominal, realized, status, st = correct_routing(problem, est.routing, est.deviations, adjust, nominals[-1], theta_trust=trust)
    pred = evaluate(problem, realized, pairing, "corrected")
    corr = Result(method="corrected", routing=nominal, shape=pred.shape, status=status, solve_time_s=time.perf_counter() - t1,
                  iterations=st.pop("iterations"), diameter=D, metrics=pred.metrics | routing_metrics(nominal),
                  stats={k: v for k, v in st.items() if k != "solve_time_s"} | {"adjust": ",".join(adjust), "shape": "predicted as built"}
                  | ({"theta_trust_rad": float(trust)} if "theta" in adjust else {}))
    moved = [replace(m, points=_moved(m.points, m, est.transform), frame="archive", build=m.build % len(nominals)) for m in measurements]
    ab_res.stats["total_time_s"] = time.perf_counter() - t0
    return CorrectionResult(nominals[-1], ab_res, corr, est, moved, tuple(adjust))


# ---------------------------------------------------------------- systematic parts over prototypes


def combine_systematic(estimates, std) -> tuple[np.ndarray, np.ndarray, float]:
    """Inverse-variance mean of systematic estimates (P, 3) with standard errors (P, 3); the length scale
    is combined in log space. Where the prototypes scatter more than their standard errors say
    (Birge ratio sqrt(chi^2 / (P - 1)) > 1, per part), the standard error is inflated by it.
    Returns (mean (3,), standard error (3,), largest Birge ratio)."""
    x = np.array(estimates, float).reshape(-1, 3).copy()
    s = np.array(std, float).reshape(-1, 3).copy()
    s[:, 2] = s[:, 2] / x[:, 2]
    x[:, 2] = np.log(x[:, 2])
    s = np.maximum(s, 1e-15)
    w = 1.0 / s**2
    mean = np.sum(w * x, axis=0) / np.sum(w, axis=0)
    se = 1.0 / np.sqrt(np.sum(w, axis=0))
    P = x.shape[0]
    birge = np.ones(3)
    if P > 1:
        chi2 = np.sum(w * (x - mean) ** 2, axis=0)
        birge = np.sqrt(chi2 / (P - 1))
        se = se * np.maximum(birge, 1.0)
    out, out_se = mean.copy(), se.copy()
    out[2] = math.exp(mean[2])
    out_se[2] = out[2] * se[2]
    return out, out_se, float(birge.max())
