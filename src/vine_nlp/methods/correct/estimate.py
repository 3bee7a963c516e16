"""The as-built estimate: the MAP estimate of what was built, from measured points of one or more builds.

The chain's theta_j, lam_j, dl_j ARE the as-built values of the latest build; three global variables are
the systematic parts g = (theta offset, lambda offset, log length scale) shared by every segment. With
Gaussian construction errors (sigmas as in ``vine-nlp analyze``) and Gaussian measurement noise sigma_m,
the negative log posterior times 2 / N (N measured points) is

    (1/N) [ sum_i |P_i(q) - m_i|_perp^2 / sigma_m^2
            + sum_j ((theta_j - theta_nom,j - g0) / s_theta)^2 + a_j ((lam_j - lam_nom,j - g1) / s_lam)^2
                    - 2 c_j log(1 - Phi((1 - lam_nom,j - g1) / s_lam)) + ((dl_j - l_nom,j e^g2) / (s_len l_nom,j e^g2))^2
            + sum_k (g_k / s_sys,k)^2 ],

P_i the model point paired with measured point m_i (``pairing``, point-to-line). The physical rule: a_j = 1
and lam_j in [lambda_min, 1] where the latest nominal has an actuator, else lam_j = 1 and a_j = 0; an actuator
at lambda 1 is clipped (c_j = 1, a_j = 0, from the round before): only its error's probability to reach 1 is
known (else the clipped ones would pull the lambda offset down, the others' selection push it down). sPAM: the
lambda deviation is the systematic offset only. Earlier builds are second chains of frames (extra stage
variables) of the latest as-built values shifted by their known differences, lambda min(1, lam_j + shift)
(shift 1 where that build had no actuator); free-frame measurements carry a rigid transform (6 more globals),
started from a rigid ICP alignment. A warm start (the previous round's estimate) skips the coarsest stage.

The ICP loop (:class:`_ICP`, a rule of ``drive.refine``): pair, solve warm, pair again until the pairs stop
moving; coarse to fine, the fit's noise sigma shrinking by settings.STAGE_FACTOR from D/2 to sigma_m, pairs
beyond settings.TRIM sigmas left out. Each segment of each build has S slots (rounded up to settings.SLOT_STEP), each an instance
of the one-point block :func:`measure_block` with its point, fraction, tangent and weight as data: re-pairing
changes data only, and one structure per (M, S, builds, free pose) serves every round, compiled once.
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

from vine_nlp.methods import drive, settings, variables
from vine_nlp.methods.blocks import BlockType
from vine_nlp.methods.correct.deviations import Deviations, apply_deviations, deviations_of
from vine_nlp.methods.correct.laplace import laplace
from vine_nlp.methods.correct.pairing import LINE_SIDE, in_frame, pair_with_line, rigid_start
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Chain, Spec, get_solver
from vine_nlp.methods.variables import CELL, POINT
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import Routing, Sigmas, actuated
from vine_nlp.model.segment import segment_function, so3_exp, twist_parts
from vine_nlp.problem import Result

_log = logging.getLogger(__name__)



# data rows of one measurement slot (measure_block): shift (3), u, m (3), tangent (3), sqrt weight, side
# [, centroid (3), free flag], lambda cap
SLOT_DATA = 13
SLOT_DATA_FREE = 17
NO_CAP = 10.0  # no lambda cap (min(NO_CAP, lam + shift) = lam + shift)


def _cap(cap, lam):  # min(cap, lam) rounded over settings.CAP_ROUND: a kink at the solution stalls IPOPT (a build clipped near 1)
    return 0.5 * (cap + lam - ca.sqrt((cap - lam) ** 2 + settings.CAP_ROUND**2))


@lru_cache(maxsize=2)
def measure_block(free: bool) -> BlockType:
    """Point-to-line residual of one measured point (one slot of one segment of one build), SX.

    One block instance per slot: the generated code holds the point's function and its derivatives once,
    whatever the number of slots (module docstring).
    v = (X_j (12), theta, lam, dl[, w (3), t (3)]): the segment's local variables of the latest
    as-built chain (and the rigid transform of free-frame measurements);
    d = (shift (3): theta and lambda added, length factor (the build's nominal against the latest),
    u, m (3), t (3) tangent, w square root of the weight, side [, c (3) centroid, flag], cap: lambda is
    min(cap, lam + shift): 1 where the shift may pass 1 (the physical rule), NO_CAP elsewhere).
    Residual w (I - (1 - settings.SLIDE) t t^T)(P - m) (the square root as data: a zero-weight slot has finite derivatives);
    a free-frame point (flag 1) is moved by exp(w) (m - c) + c + t first (m stored as given, c their centroid)."""
    slots = POINT + ((("w", 3), ("p", 3)) if free else ())  # variables.POINT, then the free frame's rotation and shift
    nd = SLOT_DATA_FREE if free else SLOT_DATA
    v, d = ca.SX.sym("v", slots.size), ca.SX.sym("d", nd)
    X, th, la, dl = POINT.split(v)
    th, la, dl = th + d[0], _cap(d[nd - 1], la + d[1]), dl * d[2]
    u, mi, tg, w, side = d[3], d[4:7], d[7:10], d[10], d[11]
    R, p = ca.reshape(X[:9], 3, 3), X[9:12]
    kappa, tau, lc = center_rates(th, la, 1.0)
    Rs, q = twist_parts(kappa, tau, u * dl * lc)
    local = ca.vertcat(q[0] + side * Rs[0][1], q[1] + side * Rs[1][1], q[2] + side * Rs[2][1])
    P = p + ca.mtimes(R, local)
    if free:
        c, flag = d[12:15], d[15]
        mi = mi + flag * (ca.mtimes(so3_exp(v[slots["w"]]), mi - c) + c + v[slots["p"]] - mi)
    e = P - mi
    res = w * (e - (1.0 - settings.SLIDE) * tg * ca.dot(tg, e))
    return BlockType(f"measure{'f' if free else ''}", ca.Function("measure_block", [v, d], [ca.sumsqr(res), ca.SX(0, 1)]),
                     ca.Function("measure_res", [v, d], [res]))


@lru_cache(maxsize=1)
def shifted_segment_block() -> BlockType:
    """Continuity of an earlier build's chain: X'_{j+1} = X'_j T(theta + d_theta, min(cap, lam + d_lam), dl f).
    v = ``variables.CELL`` (X'_j (12), theta, lam, dl, X'_{j+1} (12)); d = (d_theta, d_lam, f, cap)."""
    v, d = ca.SX.sym("v", CELL.size), ca.SX.sym("d", 4)
    X, th, la, dl, _ = CELL.split(v)
    Xn, _ = segment_function(1)(X, th + d[0], _cap(d[3], la + d[1]), dl * d[2], 0.0)
    return BlockType("shifted_segment", ca.Function("shifted_block", [v, d], [ca.SX(0), Xn - v[CELL["next"]]]),
                     ca.Function("shifted_res", [v, d], [ca.SX(0, 1)]))


@dataclass(frozen=True)
class AsBuiltTerm:
    """The MAP estimate's terms (module docstring) for ``builds`` builds (the last is the chain itself,
    the others extra frames) with ``S`` slots per segment and build; ``free``: a rigid transform of the
    free-frame measurements in globals 3..8. Parameters: meas (nd x M B S, one column per slot), shift (3 x M (B-1)),
    prior (5 x M: nominal theta, lam, dl of the latest build, a_j, c_j), prior_sig (8: s_theta, s_lam, s_len_rel,
    s_len_abs (D), s_sys (3), scale)."""

    S: int
    builds: int = 1
    free: bool = False
    # the pairing is data (slot fractions, points, weights 0 on unused slots): one structure per (M, S, builds,
    # free) serves every ICP round and every measurement of that size, worth compiling (methods.compiled)
    compile: ClassVar[bool] = True

    def apply(self, c: Chain) -> None:
        s, lay = c.s, c.lay
        M, B, S = s.M, self.builds, self.S
        bt = measure_block(self.free)
        nd = bt.fn.size1_in(1)
        meas = c.param("meas", (nd, M * B * S))  # slot k of segment j of build b: column (b M + j) S + k
        shift = c.param("shift", (4, max(M * (B - 1), 1)))
        prior, sig = c.param("prior", (5, M)), c.param("prior_sig", (8, 1))

        def frame(b, j):
            if b == B - 1 or j == 0:
                return lay.X[j, 0]
            return lay.extra[j - 1, 12 * b : 12 * b + 12]

        glob = lay.globals[3:9] if self.free else np.zeros(0, int)
        cols = [np.r_[frame(b, j), lay.routing_at(j), glob] for b in range(B) for j in range(M)]
        c.add_block(bt, np.hstack([np.repeat(col[:, None], S, axis=1) for col in cols]), meas, term="fit")
        if B > 1:
            idx = [np.r_[frame(b, j), lay.routing_at(j), lay.extra[j, 12 * b : 12 * b + 12]]
                   for b in range(B - 1) for j in range(M)]
            c.add_block(shifted_segment_block(), np.array(idx).T, shift)
        g = c.globals
        L = prior[2, :] * ca.exp(g[2])
        r_th = (c.theta - prior[0, :] - g[0]) / sig[0]
        r_len = (c.dl - L) / (sig[2] * L + sig[3])
        val = ca.sumsqr(r_th) + ca.sumsqr(r_len) + ca.sumsqr(g[:3] / sig[4:7])
        if s.lam == "segment":
            val += ca.sumsqr(prior[3, :] * (c.lam_of(0) - prior[1, :] - g[1]) / sig[1])
            z = ca.fmin((1.0 - prior[1, :] - g[1]) / (sig[1] * math.sqrt(2.0)), 5.0)
            val -= 2.0 * ca.dot(prior[4, :], ca.log(0.5 * (1.0 - ca.erf(z)) + 1e-300))
        else:
            c.add_rows("spam_offset", c.lam_of(0)[0] - prior[1, 0] - g[1], 0.0, 0.0)
        c.add_term("prior", sig[7] * val)


@dataclass
class Estimate:
    """The estimated as-built robot (latest build) and how well it is known: ``systematic`` (theta offset rad,
    lambda offset, length scale) and ``systematic_std``; ``std`` (M, 3): of theta, lambda, length per segment;
    ``transform``: 4x4 moving free-frame measurements into the archive frame; ``residuals``: per measurement,
    its points' distances to the estimated line."""

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


def estimate_as_built(nominals: list, measurements: list, D: float, sigmas: Sigmas, shared_lambda: bool = False,
                      measurement_sigma: float | None = None, systematic_sigmas=settings.DEFAULT_SYSTEMATIC_SIGMAS,
                      hessian: str | None = None, rounds: int = settings.ICP_ROUNDS, units_per_mm: float = 0.1,
                      lambda_min: float = 0.0, start: Deviations | None = None, start_systematic=None) -> Estimate:
    """MAP estimate of the as-built robot (module docstring). ``nominals``: of each build, oldest first (the
    estimate is of the last); ``measurements``: of any build (``build`` indexes ``nominals``); ``sigmas``: the
    prior; ``measurement_sigma``: default settings.DEFAULT_MEASUREMENT_SIGMA_MM; ``systematic_sigmas``: the prior of
    (theta offset rad, lambda offset, log length scale); ``rounds``: of the last stage; ``start``,
    ``start_systematic``: a warm start (an earlier round's deviations and systematic parts). ValueError: sigmas <= 0."""
    stats, cpu = drive.Stats(), time.process_time()
    sig_m = (settings.DEFAULT_MEASUREMENT_SIGMA_MM * units_per_mm) if measurement_sigma is None else float(measurement_sigma)
    icp = _ICP(nominals, measurements, D, sigmas, shared_lambda, sig_m, systematic_sigmas, hessian or settings.ESTIMATE_HESSIAN, rounds,
               lambda_min, start, start_systematic)
    found = drive.refine(icp, sum(icp.caps), stats=stats)
    g = icp.solver.unpack(icp.x)["globals"]
    # Laplace approximation around the estimate
    std, sys_std, residuals = laplace(icp.ab, g[:3], icp.shifts, icp.ms, icp.pts, icp.pairs, D, sig_m, sigmas, systematic_sigmas,
                                      icp.prior, shared_lambda, icp.free, icp.centroid, icp.Tcorr)
    latest = nominals[-1]
    # the clip at 1 hides how far beyond it an actuator's error goes: hold what may be clipped
    held = actuated(latest.lam) & (icp.ab.lam >= 1.0 - settings.HELD_SIGMAS * std[:, 1]) if not shared_lambda else None
    dev = replace(deviations_of(latest, icp.ab, lambda_min), held=held)
    return Estimate(
        routing=icp.ab, deviations=dev, systematic=np.array([g[0], g[1], math.exp(g[2])]),
        systematic_std=sys_std, std=std, transform=icp.Tcorr @ icp.T_free, residuals=residuals, status=found.best.status,
        iterations=stats.iterations, solve_time_s=time.perf_counter() - stats.started, rounds=found.rounds,
        stats={"measurement_sigma": sig_m, "slots_per_segment": icp.S, "points": icp.N, "builds": icp.B, "hessian": icp.hessian,
               "objective": float("nan") if found.best.objective is None else found.best.objective, "free_pose": icp.free, "cpu_time_s": time.process_time() - cpu, "warm_start": start is not None},
    )


class _ICP:
    """The estimate's ICP loop, a rule of ``drive.refine`` (module docstring): solve with the pairs (warm), pair
    again; a stage ends when the pairs stop moving or after its rounds. Every round supersedes the one before."""

    def __init__(self, nominals, measurements, D, sigmas, shared, sig_m, systematic_sigmas, hessian, rounds, lambda_min, start, start_sys):
        B, latest = len(nominals), nominals[-1]
        self.latest, self.B, self.M, self.T0, self.D = latest, B, latest.segments, latest.initial_pose, D
        self.shared, self.hessian, self.sig_m = shared, hessian, sig_m
        self.ms = [replace(m, build=m.build % B) for m in measurements]
        self.N = sum(m.points.shape[0] for m in self.ms)
        self.free = any(m.frame == "free" for m in self.ms)
        # shifts of every build against the latest nominal (known differences of what was built; lambda: 1 where that
        # build has no actuator, so that min(1, lam + shift) is exactly 1)
        self.act, self.lambda_min = actuated(latest.lam), max(lambda_min, 0.05)
        self.shifts = [(n.theta - latest.theta, np.where(actuated(n.lam) | (b == B - 1), n.lam - latest.lam, 1.0), n.length / latest.length)
                       for b, n in enumerate(nominals)]
        self.T_free = rigid_start(self.ms, nominals, D) if self.free else np.eye(4)
        self.pts = [in_frame(m.points, m, self.T_free) for m in self.ms]
        self.centroid = np.mean(np.concatenate([p for p, m in zip(self.pts, self.ms) if m.frame == "free"]), axis=0) if self.free else np.zeros(3)
        s_rel, s_abs = (sigmas.length, 0.0) if sigmas.relative_length else (0.0, sigmas.length / D)
        self.prior_sig = np.array([sigmas.theta, sigmas.lam, s_rel, s_abs, *systematic_sigmas, 1.0 / self.N])
        if np.any(self.prior_sig[:2] <= 0) or (s_rel <= 0 and s_abs <= 0):
            raise ValueError("the construction-error sigmas must be > 0")
        self.prior = np.vstack([latest.theta, latest.lam, latest.length / D, self.act, np.zeros(self.M)])
        # min(1, lam + shift) only where the shift may pass 1 (elsewhere lam <= 1 holds it: no kink at the bound)
        self.cap = [np.where(sh[1] > 0, 1.0, NO_CAP) for sh in self.shifts]
        self.shift_data = (np.vstack([np.concatenate([(*self.shifts[b], self.cap[b])[k] for b in range(B - 1)]) for k in range(4)])
                           if B > 1 else np.zeros((4, 1)))
        self.ab = latest if start is None else apply_deviations(latest, replace(start, lambda_min=self.lambda_min))
        self.g0 = np.zeros(3) if start_sys is None else np.r_[start_sys[:2], math.log(start_sys[2])]
        self.Tcorr, self.g_free = np.eye(4), np.zeros(6)
        self.pairs = self._pairs()
        self.S = int(math.ceil(1.25 * self._slots_needed() / settings.SLOT_STEP) * settings.SLOT_STEP)
        self.solver = None
        # coarse to fine: the fit's noise sigma from D/2 down to the measurement's
        self.stages, s_k = [], 0.5 * D
        while s_k > settings.STAGE_MERGE * sig_m:
            self.stages.append(s_k)
            s_k *= settings.STAGE_FACTOR
        self.stages = self.stages[1 if start is not None and len(self.stages) > 1 else 0 :] + [sig_m]
        self.caps = [min(rounds, settings.COARSE_ROUNDS)] * (len(self.stages) - 1) + [rounds]
        self.stage, self.k = 0, 0

    def _routings(self) -> list:
        """Every build's as-built routing: the estimate shifted by the build's known differences."""
        return [Routing(theta=self.ab.theta + a, lam=np.minimum(1.0, self.ab.lam + b), length=self.ab.length * c, initial_pose=self.T0) for a, b, c in self.shifts]

    def _pairs(self):
        rs = self._routings()
        return [pair_with_line(in_frame(p, m, self.Tcorr), rs[m.build], self.D, LINE_SIDE[m.line]) for p, m in zip(self.pts, self.ms)]

    def _slots_needed(self) -> int:
        cnt = np.zeros((self.B, self.M), int)
        for pr, m in zip(self.pairs, self.ms):
            cnt[m.build] += np.bincount(pr.seg, minlength=self.M)
        return max(1, int(cnt.max()))

    def solve(self, x, round, last):
        M, D, need = self.M, self.D, self._slots_needed()
        if need > self.S:
            self.S, self.solver = int(math.ceil(need / settings.SLOT_STEP) * settings.SLOT_STEP), None
        if self.solver is None:  # a new structure: its own start
            st = Structure(M, 1, 1, "shared" if self.shared else "segment", "fixed", extra=12 * (self.B - 1), globals=9 if self.free else 3)
            self.solver, x = get_solver(Spec(st, (AsBuiltTerm(self.S, self.B, self.free),), self.hessian, settings.ESTIMATE)), None
        solver, lay, s_stage = self.solver, self.solver.layout, self.stages[self.stage]
        data = self._data(s_stage, settings.TRIM * max(s_stage, self.sig_m))
        self.prior[4] = self.act & (self.ab.lam >= 1.0 - 1e-6)  # clipped in the round before (module docstring)
        self.prior[3] = self.act & ~(self.prior[4] > 0)
        p = solver.pack_params({"cells": np.zeros((5, M)), "meas": data, "shift": self.shift_data, "prior": self.prior,
                                "prior_sig": self.prior_sig})
        if x is None:
            x = _start_x(solver, self.ab, D, self._routings(), self.B, lay)
            x[lay.globals[:3]] = self.g0
            if self.free:
                x[lay.globals[3:9]] = self.g_free
        lbx, ubx = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
        lbx[lay.X[0, 0]] = ubx[lay.X[0, 0]] = np.r_[self.T0[:3, :3].ravel(order="F"), self.T0[:3, 3] / D]
        lbx[lay.dl], ubx[lay.dl] = settings.LENGTH_FACTOR[0] * self.latest.length / D, settings.LENGTH_FACTOR[1] * self.latest.length / D
        lam = lay.lam_global if self.shared else lay.lam[:, 0]
        lbx[lam], ubx[lam] = np.where(self.act, self.lambda_min, 1.0)[: np.size(lam)], 1.0
        lbx[lay.theta], ubx[lay.theta] = -1.45, 1.45
        sol = solver.solve(x, p, lbx, ubx)
        self.x, st = sol.x, sol.stats
        v = sol.unpack()
        self.ab = variables.routing(v | {"lam": v["lam"][:, 0]}, self.T0, D)
        if self.free:
            self.g_free, self.Tcorr = v["globals"][3:9].copy(), _free_transform(v["globals"], self.centroid, D)
        return self.x, Result("as_built", self.ab, None, sol.status, iterations=st.pop("iterations"), stats=st, objective=sol.objective)

    def judge(self, res):
        new = self._pairs()
        moved = max(float(np.max(np.abs(a.l - b.l))) for a, b in zip(new, self.pairs))
        self.pairs, self.k = new, self.k + 1
        self.stage_done = moved < 1e-3 * self.D or self.k == self.caps[self.stage]
        _log.debug("estimate: stage sigma %.3g, %s, pairs moved up to %.2g D", self.stages[self.stage], res.status, moved / self.D)
        return drive.Verdict(self.stage_done and self.stage == len(self.stages) - 1, None, moved)

    def refresh(self, res, verdict, x):
        if self.stage_done:
            self.stage, self.k = self.stage + 1, 0
        return x

    def _data(self, s_stage, trim):
        """The slots' data: each measured point in the next free slot of its (build, segment) cell, weighted
        by the stage's sigma where its pair is within ``trim`` (else 0); padding slots weight 0, fraction 0."""
        B, M, S, D = self.B, self.M, self.S, self.D
        data = np.zeros((SLOT_DATA_FREE if self.free else SLOT_DATA, B * M * S))
        data[-1] = np.repeat(np.concatenate(self.cap), S)
        for b in range(B):
            for k in range(3):
                data[k, b * M * S : (b + 1) * M * S] = np.repeat(self.shifts[b][k], S)
        if self.free:
            data[12:15] = (self.centroid / D)[:, None]
        fill = np.zeros(B * M, int)
        for pr, m, p in zip(self.pairs, self.ms, self.pts):
            keep = np.linalg.norm(pr.point - in_frame(p, m, self.Tcorr), axis=1) <= trim
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
            data[10, col] = np.where(keep, math.sqrt(1.0 / self.N) * D / s_stage, 0.0)
            data[11, col] = LINE_SIDE[m.line]
            if self.free:
                data[15, col] = 1.0 if m.frame == "free" else 0.0
        return data


def _free_transform(g, centroid, D):
    """The transform x -> exp(w) (x - c) + c + t of the globals 3..8 (t in units of D)."""
    R = so3_exp(np.asarray(g[3:6], float))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, centroid - R @ centroid + np.asarray(g[6:9], float) * D
    return T


def _start_x(solver, ab, D, routings, B, lay):
    frames = chain_frames(ab.theta, ab.lam, ab.length, D, ab.initial_pose)
    x = solver.pack_x(frames12(frames, D)[None], lam_global=np.mean(ab.lam), globals_=np.zeros(lay.globals.size), theta=ab.theta,
                      lam=ab.lam, length=ab.length / D)
    for b in range(B - 1):
        r = routings[b]
        fb = frames12(chain_frames(r.theta, r.lam, r.length, D, r.initial_pose), D)
        x[lay.extra[:, 12 * b : 12 * b + 12]] = fb[:, 1:].T
    return x


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
