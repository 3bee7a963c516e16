"""One multiple-shooting transcription of the chain for every design formulation.

The chain of M segments (paper eq. iterativeTransform, T^{j+1}_w = T^j_w T^{j+1}_j)
is written once here; each formulation (nlp, multishape, tip, clearance, robust,
correction, obstacles) states the terms and rows it adds and the data it feeds in.

Variables, created in stage order so the constraint Jacobian and the Lagrangian
Hessian are block-banded and an IPOPT iteration costs O(M):

    head     the base pose(s) (w, p): a rotation vector relative to a guessed
             rotation R0g, and a position; none for a fixed pose, one shared by all
             K levels, or one per level; the global lambda variables (one for an
             sPAM, one per level for multi-shape); the base frames X_0(k)
    stage j  theta_j, lam_j (per-segment lambda only), dl_j, the formulation's
             extra stage variables, the frames X_{j+1}(k) of every level k

A frame X is 12 numbers: the rotation column-major, then the position. Lengths are
in units of the tube diameter (D = 1), so one built solver serves every tube.

Each per-stage piece is a *block*: an SX function of a few local variables v (a
gather of x) and data d, giving a share of the objective f and rows r. Every block
carries its own SX derivatives, mapped over its instances and scattered into the
global matrices (``_scatter``): CasADi's automatic MX derivatives would colour the
whole banded matrix and sweep the mapped function once per colour, several times
the cost per iteration (results/BENCHMARKS.md, "Derivatives"). Small global terms
and rows (smoothness, tip rows) keep CasADi's automatic derivatives.

Blocks every chain has:
  pose      X_0(k) = [vec(R0g exp(w)); p]          (not for a fixed pose: bounds fix X_0)
  segment   X_{j+1}(k) = X_j(k) T^{j+1}_j(theta_j, lam_j(k), dl_j)   (continuity)
            and the point fit sum_i w_i |r_c(u_i) - r_d,i|^2 of the slots of the cell

Stage form (``Structure(stages=True)``, the plain chain only): for a solver that factors the
KKT system stage by stage (Fatrop, a Riccati recursion), every Hessian entry must lie inside
one stage (x_k, u_k) and the rows must be x_{k+1} - F(x_k, u_k), stage by stage. The
smoothness penalty couples theta_j with theta_{j-1}, two stages; so each stage carries c_j =
(theta_j, lam_j) to the next as a state, and the penalty on theta_j - c_{j-1} lies in the stage
whose controls are segment j's:

    stage 0  x = (w, p)                    row  X_0 - [vec(R0g exp(w)); p]
    stage 1  x = X_0, u = (theta_0, lam_0, dl_0)
    stage j+1  x = (c_{j-1}, X_j), u = (theta_j, lam_j, dl_j)
             rows  c_j - (theta_j, lam_j), X_{j+1} - X_j T^{j+1}_j

The objective is the plain NLP's, term for term (tests compare them).

A solver is built once per ``Spec`` (structure, terms, Hessian, IPOPT options) and
cached; the data (targets, weights, fractions, guess rotations, smoothing weights)
are parameters, so starts, hops and sweep items reuse it.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import casadi as ca
import numpy as np

from vine_nlp import interrupt
from vine_nlp.methods import compiled
from vine_nlp.model.segment import segment_function, so3_exp

# ---------------------------------------------------------------- IPOPT settings and statuses

# IPOPT return statuses as archived (spec: "optimal" | "acceptable" | "max_iter" | "failed" | ...)
IPOPT_STATUS = {
    "Solve_Succeeded": "optimal",
    "Solved_To_Acceptable_Level": "acceptable",
    "Maximum_Iterations_Exceeded": "max_iter",
    "Maximum_CpuTime_Exceeded": "max_time",
    "Restoration_Failed": "restoration_failed",
    "Infeasible_Problem_Detected": "infeasible",
    "Invalid_Number_Detected": "invalid_number",
    "Error_In_Step_Computation": "step_failed",
    "Search_Direction_Becomes_Too_Small": "small_step",
}


def ipopt_quiet(max_iter: int, tol: float) -> dict:
    """IPOPT prints nothing inside library code: callers report progress themselves."""
    return {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": int(max_iter), "ipopt.tol": float(tol)}


def ipopt_options(max_iter: int, tol: float, warm: bool = False) -> dict:
    """IPOPT settings of the whole-chain formulations: quiet, adaptive mu, a stop on objective
    plateaus, results inside the original bounds; ``warm`` for starts near the answer."""
    opts = ipopt_quiet(max_iter, tol) | {
        "ipopt.acceptable_tol": 1e-4,
        # stop on a plateau (corners of polyline targets): the objective no longer moves
        "ipopt.acceptable_obj_change_tol": 1e-8,
        "ipopt.acceptable_iter": 10,
        "ipopt.mu_strategy": "adaptive",
        # return points inside the original bounds, not IPOPT's relaxed ones
        "ipopt.honor_original_bounds": "yes",
    }
    if warm:
        # a warm start is near the answer already: do not push it back into the interior
        opts.update({
            "ipopt.warm_start_init_point": "yes",
            "ipopt.mu_init": 1e-6,
            "ipopt.warm_start_bound_push": 1e-9,
            "ipopt.warm_start_mult_bound_push": 1e-9,
            "ipopt.warm_start_slack_bound_push": 1e-9,
        })
    return opts


# rows that are hard requirements (clearance, obstacles, tip): held tightly, no "acceptable" stop
HARD_ROWS = {"ipopt.acceptable_tol": 1e-6, "ipopt.acceptable_iter": 15, "ipopt.constr_viol_tol": 1e-10,
             "ipopt.acceptable_constr_viol_tol": 1e-9}


def ipopt_status(stats: dict, x=None) -> str:
    """Archived status of one solve; an interrupted solve raises KeyboardInterrupt (vine_nlp.interrupt).

    A solution ``x`` with anything non-finite is flagged "invalid_number" whatever IPOPT said.
    """
    raw = stats.get("return_status", "")
    interrupt.check(raw)
    if x is not None and not np.all(np.isfinite(x)):
        return "invalid_number"
    return IPOPT_STATUS.get(raw, str(raw or "failed"))


# Fatrop (the stage form's solver): its objective is the NLP's times this (its tolerances are absolute, and
# a close fit's objective is orders of magnitude below one); its barrier starts low (the starts are close)
FATROP_SCALE = 100.0


def fatrop_options(max_iter: int, tol: float) -> dict:
    """Fatrop's settings: quiet, the NLP's tolerance, a low initial barrier (results/BENCHMARKS.md, "Fatrop")."""
    return {"fatrop.print_level": 0, "fatrop.tol": float(tol), "fatrop.max_iter": int(max_iter), "fatrop.mu_init": 1e-6, "print_time": False}


def fatrop_status(stats: dict, x, max_iter) -> str:
    """Archived status of one Fatrop solve: "optimal" on success, "max_iter" at the limit, else "failed";
    like ``ipopt_status``, a solution with anything non-finite is "invalid_number"."""
    interrupt.check()
    if not np.all(np.isfinite(x)):
        return "invalid_number"
    if stats.get("success"):
        return "optimal"
    return "max_iter" if max_iter is not None and int(stats.get("iter_count", 0)) >= int(max_iter) else "failed"


def fatrop_safe(x0, p, lbx, ubx) -> bool:
    """Whether a solve may go to Fatrop: it loops without end where an evaluation gives NaN or inf (IPOPT
    reports those), so only finite data and starts and consistent bounds go to it."""
    return bool(np.all(np.isfinite(x0)) and np.all(np.isfinite(p)) and np.all(lbx <= ubx))


def frames12(frames: np.ndarray, D: float = 1.0) -> np.ndarray:
    """(M+1, 4, 4) -> (12, M+1): rotation column-major, then position / D (the transcription's frame layout)."""
    R = frames[:, :3, :3].transpose(0, 2, 1).reshape(-1, 9)
    return np.hstack([R, frames[:, :3, 3] / D]).T


# ---------------------------------------------------------------- structure and layout

POSES = ("free", "fixed", "shared", "level")
LAMBDAS = ("segment", "shared", "level")


@dataclass(frozen=True)
class Structure:
    """What fixes the NLP's shape: M segments, n point slots per segment, K levels, how lambda and
    the base pose are shared, and extra variables per stage requested by terms."""

    M: int
    n: int = 1
    K: int = 1
    lam: str = "segment"  # "segment" (one per segment) | "shared" (one, sPAM) | "level" (one per level)
    pose: str = "free"  # "free" | "fixed" | "shared" (one for all levels) | "level" (one per level)
    extra: int = 0  # extra variables per stage
    globals: int = 0  # extra global variables (head), e.g. systematic construction errors
    stages: bool = False  # stage form ("Stage form" below): the plain chain for a stage-structured solver

    def __post_init__(self):
        if self.M < 1 or self.n < 1 or self.K < 1:
            raise ValueError(f"a chain needs M, n, K >= 1 (got {self.M}, {self.n}, {self.K})")
        if self.lam not in LAMBDAS or self.pose not in POSES:
            raise ValueError(f"lam must be one of {LAMBDAS}, pose one of {POSES}")
        if self.stages and (self.K, self.lam, self.pose, self.extra, self.globals) != (1, "segment", "free", 0, 0):
            raise ValueError("the stage form is the plain chain: one level, lambda per segment, a free pose, no extra variables")

    @property
    def poses(self) -> int:
        return {"free": 1, "shared": 1, "fixed": 0, "level": self.K}[self.pose]


class Layout:
    """Where each quantity lives in the decision vector (stage order; module docstring)."""

    def __init__(self, s: Structure):
        M, K, E = s.M, s.K, s.extra
        i = 0

        def take(count: int) -> np.ndarray:  # the next ``count`` entries of x
            nonlocal i
            i += count
            return np.arange(i - count, i)

        self.pose = take(6 * s.poses).reshape(s.poses, 6)
        self.lam_global = take({"segment": 0, "shared": 1, "level": K}[s.lam])
        self.globals = take(s.globals)
        X = np.zeros((M + 1, K, 12), int)
        X[0] = take(12 * K).reshape(K, 12)
        self.theta, self.dl = np.zeros(M, int), np.zeros(M, int)
        self.lam = np.zeros((M, K), int)
        self.extra = np.zeros((M, E), int)
        self.carry = np.zeros((M, 2 if s.stages else 0), int)  # stage form: (theta_j, lam_j) carried to stage j+1
        for j in range(M):
            self.theta[j] = take(1)[0]
            if s.lam == "segment":
                self.lam[j, :] = take(1)[0]
            self.dl[j] = take(1)[0]
            self.extra[j] = take(E)
            self.carry[j] = take(self.carry.shape[1])
            X[j + 1] = take(12 * K).reshape(K, 12)
        if s.lam == "shared":
            self.lam[:, :] = self.lam_global[0]
        elif s.lam == "level":
            self.lam[:, :] = self.lam_global[None, :]
        self.X = X  # (M+1, K, 12)
        self.pose_of_level = np.zeros(K, int) if s.poses == 1 else np.arange(K)
        self.size = i


# ---------------------------------------------------------------- blocks


@dataclass(frozen=True)
class Samples:
    """A block that is ``sub`` at each of S samples (one segment's sample points, say): sample i reads the
    block's data d[index[:, i]] (``index``: nd_sub x S), and the block's rows are vec(R)[order] of the
    samples' rows R (nr_sub x S). Compiled, the small ``sub`` serves every S (block_functions)."""

    sub: "BlockType"
    index: tuple
    order: tuple


@dataclass(frozen=True, eq=False)
class BlockType:
    """A per-stage piece: ``fn`` (v (nv), d (nd)) -> (f (1), r (nr)), SX; ``residual`` (v, d) -> res,
    the weighted residuals whose 2 J^T J is the block's Gauss-Newton Hessian (None: exact); ``samples``:
    the same piece as a map of a smaller one (None: none)."""

    name: str
    fn: ca.Function
    residual: ca.Function | None = None
    samples: Samples | None = None

    @property
    def nv(self) -> int:
        return self.fn.size1_in(0)

    @property
    def nr(self) -> int:
        return self.fn.size1_out(1)


@lru_cache(maxsize=None)
def block_derivatives(bt: BlockType):
    """(jac (v, d) -> dr/dv, hess (v, d, sigma, lam_r) -> triu, gauss_newton (same inputs) -> triu), SX, once per type."""
    v, d = ca.SX.sym("v", bt.nv), ca.SX.sym("d", bt.fn.size1_in(1))
    sigma, lr = ca.SX.sym("sigma"), ca.SX.sym("lam_r", bt.nr)
    f, r = bt.fn(v, d)
    ell = sigma * f + (ca.dot(lr, r) if bt.nr else 0)
    H, _ = ca.hessian(ell, v)
    args = [v, d, sigma, lr]
    jac = ca.Function(f"{bt.name}_jac", [v, d], [ca.jacobian(r, v)])
    hess = ca.Function(f"{bt.name}_hess", args, [ca.triu(H)])
    if bt.residual is None:
        return jac, hess, hess
    Jr = ca.jacobian(bt.residual(v, d), v)
    gn = ca.Function(f"{bt.name}_gn", args, [sigma * ca.triu(2 * ca.mtimes(Jr.T, Jr))])
    return jac, hess, gn


def block_functions(bt: BlockType, as_c: bool = False) -> tuple:
    """(fn, grad (v, d) -> df/dv, jac, hess, gauss_newton) of a block type: SX, or with ``as_c`` compiled on
    their own where design.compiled allows (codegen on or auto, a compiler, within its BLOCK_BUDGET)."""
    if not as_c:
        return _sx_functions(bt)
    return _c_functions(bt, compiled.mode(), str(compiled.cache_dir()), tuple(compiled.compiler() or ()))


@lru_cache(maxsize=None)
def _sx_functions(bt: BlockType) -> tuple:
    v, d = ca.SX.sym("v", bt.nv), ca.SX.sym("d", bt.fn.size1_in(1))
    f, _ = bt.fn(v, d)
    return (bt.fn, ca.Function(f"{bt.name}_grad", [v, d], [ca.gradient(f, v)]), *block_derivatives(bt))


@lru_cache(maxsize=None)
def _c_functions(bt: BlockType, *setting) -> tuple:
    # ``setting``: codegen mode, cache directory and compiler, so a changed environment finds the right copy
    if bt.samples is not None:
        # the one-sample block, compiled once for every sample count (no library, and no derivatives of the
        # whole block, per sample count)
        sub = _c_functions(bt.samples.sub, *setting)
        return _sampled(bt, sub) if sub is not _sx_functions(bt.samples.sub) else _sx_functions(bt)
    fn, grad, jac, hess, gn = sx = _sx_functions(bt)
    v, d = ca.SX.sym("v", bt.nv), ca.SX.sym("d", bt.fn.size1_in(1))
    own = [ca.Function(f"{bt.name}_f", [v, d], bt.fn(v, d)), grad, jac, hess] + ([gn] if gn is not hess else [])
    c = compiled.block_functions(bt.name, own)
    return sx if c is None else (*c[:4], c[4] if gn is not hess else c[3])


def _sampled(bt: BlockType, sub: tuple) -> tuple:
    """(fn, grad, jac, hess, gauss_newton) of a Samples block from its sub-block's (compiled) functions,
    mapped over the samples: rows and Jacobian rows gathered, gradients and Hessians summed (every sample
    shares the block's variables v)."""
    fn_s, grad_s, jac_s, hess_s, gn_s = sub
    idx, order = np.array(bt.samples.index, int), list(bt.samples.order)
    nd_s, S = idx.shape
    nv, nr_s = bt.nv, bt.samples.sub.nr
    inverse = np.argsort(order).tolist()
    v, d = ca.MX.sym("v", nv), ca.MX.sym("d", bt.fn.size1_in(1))
    sigma, lr = ca.MX.sym("sigma"), ca.MX.sym("lam_r", bt.nr)
    V, Ds = ca.repmat(v, 1, S), ca.reshape(d[idx.T.ravel().tolist()], nd_s, S)
    LS = ca.reshape(lr[inverse], nr_s, S) if bt.nr else ca.MX(0, S)

    def summed(blocks):  # nv x (nv S) -> the sum of its S blocks
        return sum(ca.horzsplit(blocks, nv), ca.MX(nv, nv))

    f_s, r_s = fn_s.map(S)(V, Ds)
    fn = ca.Function(f"{bt.name}_f", [v, d], [ca.sum2(f_s), ca.vec(r_s)[order]])
    grad = ca.Function(f"{bt.name}_grad", [v, d], [ca.sum2(grad_s.map(S)(V, Ds))])
    J = ca.vertcat(*ca.horzsplit(jac_s.map(S)(V, Ds), nv)) if bt.nr else ca.MX(0, nv)
    jac = ca.Function(f"{bt.name}_jac", [v, d], [J[order, :]])
    args = [v, d, sigma, lr]
    hess = ca.Function(f"{bt.name}_hess", args, [summed(hess_s.map(S)(V, Ds, ca.repmat(sigma, 1, S), LS))])
    gn = hess if gn_s is hess_s else ca.Function(f"{bt.name}_gn", args, [summed(gn_s.map(S)(V, Ds, ca.repmat(sigma, 1, S), LS))])
    return fn, grad, jac, hess, gn


@lru_cache(maxsize=None)
def segment_block(n: int) -> BlockType:
    """Continuity and point fit of one (segment, level) cell.

    v = (X_j (12), theta, lam, dl, X_{j+1} (12)); d = (u (n), target slots (3 n, slot-major), w (n)).
    f = sum_i w_i |r_c(u_i) - r_d,i|^2; r = X_j T^{j+1}_j - X_{j+1}. Gauss-Newton: 2 J^T J of the
    weighted residuals, the constraint curvature left out (always PSD, cheap, linear convergence on
    large-residual targets)."""

    def build():
        v, d = ca.SX.sym("v", 27), ca.SX.sym("d", 5 * n)
        u, tgt, w = d[:n], ca.reshape(d[n : 4 * n], 3, n), d[4 * n :].T
        Xn, pts = segment_function(n)(v[:12], v[12], v[13], v[14], u)
        err = pts - tgt
        f = ca.sum2(w * ca.sum1(err * err))
        res = ca.vec(ca.repmat(ca.sqrt(w), 3, 1) * err)
        return [ca.Function("segment_block", [v, d], [f, Xn - v[15:]]), ca.Function("segment_res", [v, d], [res])]

    fn, res = compiled.stored(f"segment_block{n}", build)
    return BlockType(f"segment{n}", fn, res)


@lru_cache(maxsize=None)
def pose_block() -> BlockType:
    """X_0 = [vec(R0g exp(w)); p]: the base rotation stays a proper rotation. v = (w, p, X_0); d = vec(R0g)."""
    v, d = ca.SX.sym("v", 18), ca.SX.sym("d", 9)
    R = ca.mtimes(ca.reshape(d, 3, 3), so3_exp(v[:3]))
    r = ca.vertcat(ca.vec(R), v[3:6]) - v[6:]
    return BlockType("pose", ca.Function("pose_block", [v, d], [ca.SX(0), r]), ca.Function("pose_res", [v, d], [ca.SX(0, 1)]))


@lru_cache(maxsize=None)
def stage_blocks(n: int) -> tuple[BlockType, BlockType, BlockType]:
    """The blocks of the stage form (module docstring): (pose, segment, smoothness).

    Rows close the gap to the next stage's state, x_{k+1} - F(x_k, u_k): the sign a stage-structured
    solver reads its dynamics from. pose: v = (w, p, X_0), rows X_0 - [vec(R0g exp(w)); p].
    segment: v = (X_j, theta_j, lam_j, dl_j, c_j, X_{j+1}), rows (c_j - (theta_j, lam_j), X_{j+1} - X_j T),
    and the point fit. smoothness: v = (c_{j-1}, theta_j, lam_j), d = (w_theta, w_lambda) / (h_j L), no rows:
    Smoothness's penalty on the step between segments j-1 and j, inside stage j."""
    seg, pose = segment_block(n), pose_block()
    v, d = ca.SX.sym("v", 18), ca.SX.sym("d", 9)
    f, r = pose.fn(v, d)
    stage_pose = BlockType("stage_pose", ca.Function("stage_pose", [v, d], [f, -r]), pose.residual)
    v, d = ca.SX.sym("v", 29), ca.SX.sym("d", 5 * n)
    cell = ca.vertcat(v[:15], v[17:])  # the segment block's variables
    f, r = seg.fn(cell, d)
    segment = BlockType(f"stage_segment{n}", ca.Function("stage_segment", [v, d], [f, ca.vertcat(v[15:17] - v[12:14], -r)]),
                        ca.Function("stage_segment_res", [v, d], [seg.residual(cell, d)]))
    v, d = ca.SX.sym("v", 4), ca.SX.sym("d", 2)
    step = v[2:] - v[:2]
    smooth = BlockType("stage_smooth", ca.Function("stage_smooth", [v, d], [ca.dot(d, step**2), ca.SX(0, 1)]),
                       ca.Function("stage_smooth_res", [v, d], [ca.sqrt(d) * step]))
    return stage_pose, segment, smooth


def _scatter(shape, blocks, symmetric: bool):
    """Sparse MX of ``shape`` from per-instance dense-pattern blocks.

    ``blocks``: (values, pattern, rows, cols) with ``values`` the horizontally
    concatenated block outputs of a mapped call, ``pattern`` one block's sparsity and
    ``rows``/``cols`` (local size x instances) the global index of each local row/column.
    Entries that land on the same place (a shared variable of several blocks) are summed;
    ``symmetric`` stores each entry in the upper triangle.
    """
    R, C, V = [], [], []
    for values, pattern, rows, cols in blocks:
        r, c = (np.asarray(v) for v in pattern.get_triplet())
        if r.size == 0:
            continue
        a, b = rows[r, :].T.ravel(), cols[c, :].T.ravel()  # instance-major, as the mapped outputs
        if symmetric:
            a, b = np.minimum(a, b), np.maximum(a, b)
        R.append(a)
        C.append(b)
        V.append(ca.vec(values.nz[:]))  # a column whatever the block's shape (a one-row Jacobian gives a row)
    if not R:
        return ca.MX(*shape)
    R, C, V = np.concatenate(R), np.concatenate(C), ca.vertcat(*V)
    key = C.astype(np.int64) * shape[0] + R  # column-major: the order of a CasADi sparsity's nonzeros
    uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    single = counts[inverse] == 1
    order = np.flatnonzero(single)[np.argsort(key[single], kind="stable")]
    out = ca.MX(ca.Sparsity.triplet(*shape, R[order].tolist(), C[order].tolist()), V[order.tolist()])
    if np.any(counts > 1):
        # entries several blocks share (a shared lambda, a base frame): one sparse sum
        dup = np.flatnonzero(counts[inverse] > 1)
        sel = ca.DM(ca.Sparsity.triplet(int(counts[counts > 1].size), dup.size, np.searchsorted(uniq[counts > 1], key[dup]).tolist(),
                                        list(range(dup.size))), 1.0)
        sums = ca.mtimes(sel, V[dup.tolist()])
        k = uniq[counts > 1]
        out = out + ca.MX(ca.Sparsity.triplet(*shape, (k % shape[0]).tolist(), (k // shape[0]).tolist()), sums)
    return out


# ---------------------------------------------------------------- the chain a formulation builds on


@dataclass
class _Block:
    bt: BlockType
    index: np.ndarray  # (nv, count) global indices of the local variables
    data: ca.MX  # (nd, count)
    lb: np.ndarray  # (nr,) row bounds
    ub: np.ndarray
    term: str = "fit"  # the objective term its f reports to


class Chain:
    """Symbolic views of the chain's variables and the pieces a formulation adds to them.

    Views (MX, units of D): ``x``, ``theta``, ``dl`` (1 x M), ``lam_of(k)`` (1 x M),
    ``frames(k)`` (12 x (M+1)), ``tip(k)`` (3), ``extra`` (E x M). ``param(name, shape)``
    declares data; ``add_block``, ``add_term`` and ``add_rows`` add per-stage blocks, global
    objective terms and global rows. ``get_solver(spec)`` turns it into one solver.
    """

    def __init__(self, s: Structure):
        self.s, self.lay = s, Layout(s)
        lay = self.lay
        self.x = x = ca.MX.sym("x", lay.size)
        self.params: list[tuple[str, ca.MX]] = []
        self.blocks: list[_Block] = []
        self.terms: dict[str, ca.MX] = {}
        self.rows: list[tuple[str, ca.MX, np.ndarray, np.ndarray]] = []
        self.theta = x[lay.theta.tolist()].T
        self.dl = x[lay.dl.tolist()].T
        self.extra = ca.reshape(x[lay.extra.ravel().tolist()], s.extra, s.M) if s.extra else None
        self.globals = x[lay.globals.tolist()] if s.globals else None
        M, K, n = s.M, s.K, s.n
        # the always-present blocks: base poses and the segment cells (continuity + point fit)
        self.cells = self.param("cells", (5 * n, M * K))  # per cell (j, k), j-major: u, target slots, w
        if s.stages:
            self._stage_blocks()
            return
        if s.pose != "fixed":
            self.R0g = self.param("R0g", (9, s.poses))
            idx = np.vstack([lay.pose[lay.pose_of_level].T, lay.X[0].T])  # (18, K)
            self.add_block(pose_block(), idx, self.R0g[:, lay.pose_of_level.tolist()])
        cells = [(j, k) for j in range(M) for k in range(K)]
        idx = np.array([np.r_[lay.X[j, k], lay.theta[j], lay.lam[j, k], lay.dl[j], lay.X[j + 1, k]] for j, k in cells]).T
        self.add_block(segment_block(n), idx, self.cells)

    def _stage_blocks(self) -> None:
        """The stage form's blocks; rows stage by stage: pose, then segment j = 0 .. M-1. Smoothness's
        parameters are declared here (its penalty is a block of every stage j >= 1)."""
        lay, M, X = self.lay, self.s.M, self.lay.X[:, 0, :]
        self.R0g = self.param("R0g", (9, 1))
        w, h, L = self.param("smooth", (2, 1)), self.param("h", (max(M - 1, 1), 1)), self.param("L", (1, 1))
        pose, segment, smooth = stage_blocks(self.s.n)
        self.add_block(pose, np.r_[lay.pose[0], X[0]], self.R0g)
        self.add_block(segment, np.array([np.r_[X[j], lay.theta[j], lay.lam[j, 0], lay.dl[j], lay.carry[j], X[j + 1]]
                                          for j in range(M)]).T, self.cells)
        if M > 1:
            idx = np.array([np.r_[lay.carry[j - 1], lay.theta[j], lay.lam[j, 0]] for j in range(1, M)]).T
            self.add_block(smooth, idx, ca.mtimes(w / L, 1 / h[: M - 1].T), term="smooth")

    # views
    def frames(self, k: int = 0) -> ca.MX:
        return ca.reshape(self.x[self.lay.X[:, k, :].ravel().tolist()], 12, self.s.M + 1)

    def tip(self, k: int = 0) -> ca.MX:
        return self.x[self.lay.X[-1, k, 9:].tolist()]

    def lam_of(self, k: int = 0) -> ca.MX:
        return self.x[self.lay.lam[:, k].tolist()].T

    def gather(self, index: np.ndarray) -> ca.MX:
        """x at an (a, b) index array, as an (a, b) MX."""
        index = np.asarray(index, int)
        return ca.reshape(self.x[index.T.ravel().tolist()], *index.shape)

    # pieces
    def param(self, name: str, shape) -> ca.MX:
        if any(name == n for n, _ in self.params):
            raise ValueError(f"parameter {name!r} declared twice")
        p = ca.MX.sym(name, *shape)
        self.params.append((name, p))
        return p

    def add_block(self, bt: BlockType, index, data, lb=None, ub=None, term: str = "fit") -> None:
        index = np.asarray(index, int).reshape(bt.nv, -1)
        lb = np.zeros(bt.nr) if lb is None else np.broadcast_to(np.asarray(lb, float), (bt.nr,)).copy()
        ub = np.zeros(bt.nr) if ub is None else np.broadcast_to(np.asarray(ub, float), (bt.nr,)).copy()
        self.blocks.append(_Block(bt, index, data, lb, ub, term))

    def add_term(self, name: str, expr) -> None:
        self.terms[name] = self.terms.get(name, 0) + expr

    def add_rows(self, name: str, expr, lb, ub) -> None:
        expr = ca.vec(expr)
        n = expr.numel()
        self.rows.append((name, expr, np.broadcast_to(np.asarray(lb, float), (n,)).copy(), np.broadcast_to(np.asarray(ub, float), (n,)).copy()))


# ---------------------------------------------------------------- terms the formulations plug in


@dataclass(frozen=True)
class Smoothness:
    """w_theta (1/L) int (D theta')^2 ds (+ the same for lambda when it is per segment), the derivatives
    taken on the given arc-length steps h between segment middles: they replace the paper's low-pass
    filter and mean the same at any discretization. Parameters: smooth (2), h (M-1), L."""

    lam: bool = True

    def apply(self, c: Chain) -> None:
        M = c.s.M
        if c.s.stages:
            return  # a stage cost of the stage form (Chain._stage_blocks)
        w, h, L = c.param("smooth", (2, 1)), c.param("h", (max(M - 1, 1), 1)), c.param("L", (1, 1))
        if M == 1:
            return
        c.add_term("smooth", w[0] * ca.sum1(ca.diff(c.theta.T) ** 2 / h) / L)
        if self.lam and c.s.lam == "segment":
            c.add_term("smooth", w[1] * ca.sum1(ca.diff(c.lam_of(0).T) ** 2 / h) / L)


@dataclass(frozen=True)
class SoftTip:
    """The target's last point pairs with the chain's end: sum_k wtip_k |X_M(k) - tip_k|^2 (part of the fit)."""

    def apply(self, c: Chain) -> None:
        K = c.s.K
        tip, w = c.param("tip", (3, K)), c.param("wtip", (1, K))
        c.add_term("fit", ca.sum2(w * ca.sum1((ca.horzcat(*[c.tip(k) for k in range(K)]) - tip) ** 2)))


def segment_point_index(c: Chain, j: int, k: int = 0) -> np.ndarray:
    """Local variables (X_j (12), theta, lam, dl) of segment j of level k, for blocks on its points."""
    lay = c.lay
    return np.r_[lay.X[j, k], lay.theta[j], lay.lam[j, k], lay.dl[j]]


@dataclass(frozen=True)
class Spec:
    """A cache key for one built solver: structure, terms (frozen dataclasses with ``apply(chain)``),
    Hessian ("exact" | "gauss-newton"), the solver's options (a sorted tuple of items) and the solver
    ("ipopt" | "fatrop")."""

    structure: Structure
    terms: tuple = ()
    hessian: str = "exact"
    options: tuple = ()
    backend: str = "ipopt"  # "ipopt" | "fatrop" (the stage form, compiled only: ``fatrop_nlpsol``)


@lru_cache(maxsize=32)
def get_solver(spec: Spec) -> "Solver":
    """The solver of ``spec``, built once per process (building costs more than one solve)."""
    return Solver(spec)


def clear_caches() -> None:
    """Forget every built solver and SX derivative (benchmarks: time a cold start)."""
    get_solver.cache_clear()
    block_derivatives.cache_clear()
    _sx_functions.cache_clear()
    _c_functions.cache_clear()
    segment_block.cache_clear()
    pose_block.cache_clear()
    segment_function.cache_clear()


def options_key(opts: dict) -> tuple:
    return tuple(sorted(opts.items()))


class Solver:
    """One NLP built from a Spec: ``solve(x0, values, lbx, ubx)`` runs IPOPT."""

    def __init__(self, spec: Spec):
        t0 = time.perf_counter()
        self.spec = spec
        c = self.chain = Chain(spec.structure)
        for term in spec.terms:
            term.apply(c)
        x, lay = c.x, c.lay
        p = ca.vertcat(*[ca.vec(q) for _, q in c.params])
        self._param_shapes = {name: q.shape for name, q in c.params}
        ends = np.cumsum([0] + [q.numel() for _, q in c.params])
        self._param_slices = {name: slice(int(a), int(b)) for (name, _), a, b in zip(c.params, ends[:-1], ends[1:])}
        # how the NLP's functions run: compiled as a whole (cached per structure); or, where a term's
        # structure changes from solve to solve (an active set: compile = "blocks"), interpreted with each
        # block type compiled on its own (cached per block type); or interpreted (compile = False)
        kinds = {getattr(t, "compile", True) for t in spec.terms}
        whole = kinds <= {True}
        per_block = not whole and kinds <= {True, "blocks"} and spec.backend != "fatrop"
        fns = {b.bt: block_functions(b.bt, per_block) for b in c.blocks}
        # objective and rows: blocks (mapped SX) first, then global rows
        f_blocks, g_parts, lbg, ubg = 0, [], [], []
        gathered, reported = [], dict(c.terms)  # reported: the objective per term (global and blocks)
        for b in c.blocks:
            count = b.index.shape[1]
            V = c.gather(b.index)
            F = fns[b.bt][0].map(count, "serial")
            fb, rb = F(V, b.data)
            f_blocks = f_blocks + ca.sum2(fb)
            reported[b.term] = reported.get(b.term, 0) + ca.sum2(fb)
            if b.bt.nr:
                g_parts.append(ca.vec(rb))
                lbg.append(np.tile(b.lb, count))
                ubg.append(np.tile(b.ub, count))
            gathered.append((V, count))
        f_glob = sum(c.terms.values(), ca.MX(0))  # global terms: automatic derivatives
        g_glob = ca.vertcat(*[r for _, r, _, _ in c.rows]) if c.rows else ca.MX(0, 1)
        f = f_glob + f_blocks
        nb = int(sum(v.numel() for v in g_parts))
        g = ca.vertcat(*g_parts, g_glob)
        self.lbg = np.concatenate([np.zeros(0)] + lbg + [r[2] for r in c.rows])
        self.ubg = np.concatenate([np.zeros(0)] + ubg + [r[3] for r in c.rows])

        def derivatives(scale: float = 1.0):
            # per block type SX, mapped and scattered; global parts automatic. (lam_f, lam_g, J, triu H) of
            # the objective scale * f
            lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.size1())
            sigma = lam_f if scale == 1.0 else scale * lam_f
            jac_blocks, hess_blocks, row = [], [], 0
            for b, (V, count) in zip(c.blocks, gathered):
                _, _, jac, hess, gn = fns[b.bt]
                h = gn if spec.hessian == "gauss-newton" else hess
                nr = b.bt.nr
                LR = ca.reshape(lam_g[row : row + nr * count], nr, count) if nr else ca.MX(0, count)
                if nr:
                    rows_idx = row + np.arange(nr * count).reshape(count, nr).T
                    jac_blocks.append((jac.map(count, "serial")(V, b.data), jac.sparsity_out(0), rows_idx, b.index))
                hess_blocks.append((h.map(count, "serial")(V, b.data, sigma, LR), h.sparsity_out(0), b.index, b.index))
                row += nr * count
            J = _scatter((nb, lay.size), jac_blocks, False)
            if c.rows:
                J = ca.vertcat(J, ca.jacobian(g_glob, x))
            lam_glob = lam_g[nb:]
            glob = sigma * f_glob + (ca.dot(lam_glob, g_glob) if c.rows else 0)
            H = _scatter((lay.size, lay.size), hess_blocks, True) + ca.triu(ca.hessian(glob, x)[0])
            return lam_f, lam_g, J, H

        def gradient():
            # compiled blocks carry no derivatives of their own for CasADi to chain: the gradient of f, as J and H
            grads = [(fns[b.bt][1].map(count, "serial")(V, b.data), fns[b.bt][1].sparsity_out(0), b.index, np.zeros((1, count), int))
                     for b, (V, count) in zip(c.blocks, gathered)]
            return _scatter((lay.size, 1), grads, False) + ca.gradient(f_glob, x)

        def problem_and_derivatives():
            lam_f, lam_g, J, H = derivatives()
            opts = {
                "jac_g": ca.Function("nlp_jac_g", [x, p], [g, J], ["x", "p"], ["g", "jac_g_x"]),
                "hess_lag": ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [H], ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"]),
            }
            if per_block:
                opts["grad_f"] = ca.Function("nlp_grad_f", [x, p], [f, gradient()], ["x", "p"], ["f", "grad_f_x"])
                # no gradient of the Lagrangian after the solve (multipliers of x and p, never read): it would
                # differentiate through the compiled blocks; IPOPT returns f and g itself
                opts |= {"no_nlp_grad": True, "calc_lam_p": False, "calc_lam_x": False, "calc_f": False, "calc_g": False}
            return {"x": x, "p": p, "f": f, "g": g}, opts

        def fatrop_functions():
            # the functions Fatrop's interface imports, of the objective FATROP_SCALE * f; the full Hessian
            lam_f, lam_g, J, H = derivatives(FATROP_SCALE)
            fs = FATROP_SCALE * f
            ell = lam_f * fs + ca.dot(lam_g, g)
            gl = ca.gradient(ell, x)
            xp, lag = ["x", "p"], ["x", "p", "lam_f", "lam_g"]
            return [ca.Function("nlp", [x, p], [fs, g], xp, ["f", "g"]), ca.Function("nlp_f", [x, p], [fs], xp, ["f"]),
                    ca.Function("nlp_g", [x, p], [g], xp, ["g"]),
                    ca.Function("nlp_grad_f", [x, p], [ca.gradient(fs, x)], xp, ["grad_f_x"]),
                    ca.Function("nlp_jac_g", [x, p], [g, J], xp, ["g", "jac_g_x"]),
                    ca.Function("nlp_grad", [x, p, lam_f, lam_g], [fs, g, gl, ca.gradient(ell, p)], lag, ["f", "g", "grad_gamma_x", "grad_gamma_p"]),
                    ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [gl, H + ca.triu(H, False).T], lag, ["grad_gamma_x", "hess_gamma_x_x"])]

        self.problem = {"x": x, "p": p, "f": f, "g": g}  # symbolic, for derivative checks and benchmarks
        code = repr(dataclasses.replace(spec, options=()))  # what the generated code depends on: not the solver's settings
        if spec.backend == "fatrop":
            if not spec.structure.stages:
                raise ValueError("Fatrop solves the stage form only (Structure(stages=True))")
            self.nlpsol = compiled.fatrop_nlpsol("vine_nlp_fatrop", code, fatrop_functions, dict(spec.options), self.lbg == self.ubg)
        else:
            # compiled C where a compiler is found (cached on disk per spec), else interpreted
            self.nlpsol = compiled.nlpsol("vine_nlp", code, problem_and_derivatives, dict(spec.options), enabled=whole)
        self.term_names = list(reported)
        self._terms = ca.Function("terms", [x, p], [ca.MX(0) + v for v in reported.values()])
        self._g = ca.Function("g", [x, p], [g])
        self.build_time_s = time.perf_counter() - t0
        self._built = False

    @property
    def layout(self) -> Layout:
        return self.chain.lay

    @property
    def structure(self) -> Structure:
        return self.spec.structure

    # data
    def pack_params(self, values: dict) -> np.ndarray:
        missing = [k for k in self._param_shapes if k not in values]
        if missing:
            raise ValueError(f"parameters missing: {missing}")
        out = []
        for name, shape in self._param_shapes.items():
            v = np.asarray(values[name], float)
            if v.size != shape[0] * shape[1]:
                raise ValueError(f"parameter {name!r}: {v.size} values for shape {shape}")
            out.append(v.reshape(shape, order="F").ravel(order="F"))
        return np.concatenate(out) if out else np.zeros(0)

    def param_slice(self, name: str) -> slice:
        """Where parameter ``name`` sits in the packed parameter vector."""
        return self._param_slices[name]

    def pack_x(self, theta, lam, dl, frames, poses=None, lam_global=None, extra=None, globals_=None) -> np.ndarray:
        """x from per-segment theta, dl (M,), lam (M,) or (M, K), frames (K, 12, M+1), poses (P, 6),
        global lambdas (shared or level), extra (E, M), extra globals (G,)."""
        s, lay = self.structure, self.layout
        x = np.zeros(lay.size)
        x[lay.theta], x[lay.dl] = theta, dl
        if s.lam == "segment":
            x[lay.lam[:, 0]] = np.asarray(lam, float).reshape(s.M, -1)[:, 0]
        elif lam_global is not None:
            x[lay.lam_global] = lam_global
        else:
            x[lay.lam_global] = np.mean(lam) if s.lam == "shared" else np.asarray(lam, float).reshape(s.M, s.K)[0]
        frames = np.asarray(frames, float).reshape(s.K, 12, s.M + 1)
        for k in range(s.K):
            x[lay.X[:, k, :].T] = frames[k]
        if poses is not None and s.poses:
            x[lay.pose] = np.asarray(poses, float).reshape(s.poses, 6)
        if extra is not None and s.extra:
            x[lay.extra.T] = np.asarray(extra, float).reshape(s.extra, s.M)
        if globals_ is not None and s.globals:
            x[lay.globals] = globals_
        if s.stages:  # the carried copies hold their rows at the start
            x[lay.carry[:, 0]], x[lay.carry[:, 1]] = x[lay.theta], x[lay.lam[:, 0]]
        return x

    def unpack(self, x) -> dict:
        s, lay = self.structure, self.layout
        x = np.asarray(x, float)
        return {
            "theta": x[lay.theta].copy(),
            "lam": x[lay.lam].copy(),  # (M, K)
            "dl": x[lay.dl].copy(),
            "poses": x[lay.pose].copy(),
            "lam_global": x[lay.lam_global].copy(),
            "frames": np.stack([x[lay.X[:, k, :].T] for k in range(s.K)]),  # (K, 12, M+1)
            "extra": x[lay.extra.T].copy() if s.extra else None,
            "globals": x[lay.globals].copy(),
        }

    def bounds(self, theta, lam, dl, X0=None) -> tuple[np.ndarray, np.ndarray]:
        """Box bounds from (lo, hi) pairs: theta, lam (per segment (M,) or per level (K,) or scalars), dl;
        ``X0``: (K, 12) fixed base frames for a fixed pose. Extra and global variables are free: set
        their entries of the returned arrays (``layout.extra``, ``layout.globals``) to bound them."""
        s, lay = self.structure, self.layout
        lbx, ubx = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
        lbx[lay.theta], ubx[lay.theta] = theta
        lbx[lay.dl], ubx[lay.dl] = dl
        if s.lam == "level":
            lbx[lay.lam_global], ubx[lay.lam_global] = lam
        else:
            lo, hi = (np.broadcast_to(np.asarray(v, float), (s.M,)) for v in lam)
            if s.lam == "shared":
                lbx[lay.lam_global], ubx[lay.lam_global] = lo[0], hi[0]
            else:
                lbx[lay.lam[:, 0]], ubx[lay.lam[:, 0]] = lo, hi
        if s.pose == "fixed":
            if X0 is None:
                raise ValueError("a fixed pose needs its base frames X0")
            X0 = np.asarray(X0, float).reshape(s.K, 12)
            for k in range(s.K):
                lbx[lay.X[0, k]] = ubx[lay.X[0, k]] = X0[k]
        return lbx, ubx

    def terms(self, x, p) -> dict:
        return {k: float(v) for k, v in zip(self.term_names, self._terms(x, p))}

    def solve(self, x0, p, lbx, ubx, lbg=None, ubg=None) -> tuple[np.ndarray, str, dict]:
        """One solve, IPOPT's or Fatrop's (``spec.backend``), from x0 clipped into the bounds: (x, status, stats).
        Fatrop loops without end on non-finite data: callers check ``fatrop_safe`` first."""
        build = 0.0 if self._built else self.build_time_s
        self._built = True
        x0 = np.clip(np.asarray(x0, float), lbx, ubx)
        lbg = self.lbg if lbg is None else lbg
        ubg = self.ubg if ubg is None else ubg
        t0 = time.perf_counter()
        try:
            sol = interrupt.call(self.nlpsol, x0=x0, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
            st = self.nlpsol.stats()
        except RuntimeError:
            if self.spec.backend != "fatrop":
                raise
            # Fatrop raises where IPOPT returns a status (a failed factorization, say): a failed solve
            sol, st = {"x": x0, "f": np.nan, "g": np.full(lbg.shape, np.nan)}, {}
        elapsed = time.perf_counter() - t0
        x = np.array(sol["x"]).ravel()
        f = float(sol["f"])
        if self.spec.backend == "fatrop":
            status = fatrop_status(st, x, dict(self.spec.options).get("fatrop.max_iter"))
            x, f = np.clip(x, lbx, ubx), f / FATROP_SCALE  # its answers may sit at rounding outside a bound
        else:
            status = ipopt_status(st, x)
        gv = np.array(sol["g"]).ravel()
        viol = float(np.max(np.maximum(lbg - gv, 0) + np.maximum(gv - ubg, 0))) if gv.size else 0.0
        stats = {
            "solver": self.spec.backend,
            "return_status": st.get("return_status", ""),
            "build_time_s": build,
            "objective": f,
            "iterations": int(st.get("iter_count", 0)),
            "solve_time_s": elapsed,
            "ipopt_time_s": elapsed,  # the solver's alone, IPOPT's or Fatrop's (solve_time_s may grow to cover a whole method)
            "max_constraint_violation": viol,
            "hessian": self.spec.hessian,
        } | {f"objective_{k}": v for k, v in self.terms(x, p).items()}
        return x, status, stats


# ---------------------------------------------------------------- multi-start: one ranking, one tie rule

# objectives this close (relative) are the same optimum reached from different starts
TIE_RTOL = 1e-6


def pick_best(results, objective: Callable = lambda r: r.stats["objective"], converged: Callable = lambda r: r.converged) -> int:
    """Index of the best result: converged before not converged, then the lowest objective; the FIRST
    within TIE_RTOL of the best wins, so the choice does not depend on timing or worker order."""
    rank = [(0 if converged(r) else 1, objective(r)) for r in results]
    best = min(rank)
    return next(k for k, (c, o) in enumerate(rank) if c == best[0] and o <= best[1] * (1 + TIE_RTOL) + 1e-15)


def multistart(solve: Callable, guesses, progress=None, **pick) -> tuple:
    """Solve from every guess in order; (best result, its index, all results). ``progress(done, total)``."""
    results = []
    for g in guesses:
        results.append(solve(g))
        if progress:
            progress(len(results), len(guesses))
    k = pick_best(results, **pick)
    return results[k], k, results


def record_starts(best, k: int, results, t0: float) -> None:
    """The multi-start's stats on the winner: starts, start_objectives, start_iterations, best_start, total time
    and iterations."""
    best.stats["starts"] = len(results)
    best.stats["start_objectives"] = [r.stats["objective"] for r in results]
    best.stats["start_iterations"] = [r.iterations for r in results]
    best.stats["best_start"] = k
    best.solve_time_s = time.perf_counter() - t0
    best.iterations = sum(r.iterations for r in results)


def cell_data(pairing, target_scaled: np.ndarray, weight: float, K: int = 1, k: int = 0, out: np.ndarray | None = None) -> np.ndarray:
    """The segment cells' data (5 n, M K) of one level k: slot fractions u, paired target points (units of D)
    and weights (``weight`` per paired point, 0 for unused slots). The last target point is not in a slot:
    it pairs with the chain's end (SoftTip)."""
    M, n = pairing.segments, pairing.n
    out = np.zeros((5 * n, M * K)) if out is None else out
    i = np.arange(target_scaled.shape[0] - 1)
    within = i - pairing.bounds[pairing.seg[i]]
    col = pairing.seg[i] * K + k
    out[within, col] = pairing.frac[i]
    for c in range(3):
        out[n + 3 * within + c, col] = target_scaled[i, c]
    out[4 * n + within, col] = weight
    return out


def smoothing_steps(chord: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, float]:
    """Arc-length steps between segment middles and the total arc length (same units as ``chord``)."""
    mids = 0.5 * (chord[bounds[:-1]] + chord[bounds[1:]])
    return (np.diff(mids) if mids.size > 1 else np.ones(1)), float(chord[-1])
