"""Blocks: the per-stage pieces of the chain NLP, each with its own SX derivatives.

A *block* is an SX function of a few local variables v (a gather of x) and data d, giving a share of the objective f and
rows r. Every block carries its own SX derivatives, mapped over its instances and scattered into the global matrices
(:func:`scatter`): CasADi's automatic MX derivatives would colour the whole banded matrix and sweep the mapped function
once per colour, several times the cost per iteration (results/BENCHMARKS.md, "Derivatives").

Blocks every chain has:
  pose      X_0(k) = [vec(R0g exp(w)); p]          (not for a fixed pose: bounds fix X_0)
  segment   X_{j+1}(k) = X_j(k) T^{j+1}_j(theta_j, lam_j(k), dl_j)   (continuity)
            and the point fit sum_i w_i |r_c(u_i) - r_d,i|^2 of the slots of the cell"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.methods import compiled
from vine_nlp.methods.variables import CELL, POINT, Slots
from vine_nlp.model.segment import segment_function, so3_exp

POSE = Slots(("w", 3), ("p", 3), ("X", 12))  # the pose block's variables: rotation vector, position, X_0


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
    the same piece as a map of a smaller one (None: none); ``budget``: compiled on its own up to this many
    SX instructions (None: settings.BLOCK_BUDGET)."""

    name: str
    fn: ca.Function
    residual: ca.Function | None = None
    samples: Samples | None = None
    budget: int | None = None

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
    their own where methods.compiled allows (codegen on or auto, a compiler, within its BLOCK_BUDGET)."""
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
        # whole block, per sample count); interpreted, the same map of it: the same sums in the same order, so
        # a first run (interpreted while the compiler works) and later runs take the same steps (issue 46)
        return _sampled(bt, _c_functions(bt.samples.sub, *setting))
    fn, grad, jac, hess, gn = sx = _sx_functions(bt)
    v, d = ca.SX.sym("v", bt.nv), ca.SX.sym("d", bt.fn.size1_in(1))
    own = [ca.Function(f"{bt.name}_f", [v, d], bt.fn(v, d)), grad, jac, hess] + ([gn] if gn is not hess else [])
    c = compiled.block_functions(bt.name, own, bt.budget)
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

    v = ``variables.CELL`` (X_j (12), theta, lam, length, X_{j+1} (12)); d = (u (n), target slots (3 n, slot-major), w
    (n)). f = sum_i w_i |r_c(u_i) - r_d,i|^2; r = X_j T^{j+1}_j - X_{j+1}. Gauss-Newton: 2 J^T J of the weighted
    residuals, the constraint curvature left out (always PSD, cheap, linear convergence on large-residual targets)."""

    def build():
        v, d = ca.SX.sym("v", CELL.size), ca.SX.sym("d", 5 * n)
        u, tgt, w = d[:n], ca.reshape(d[n : 4 * n], 3, n), d[4 * n :].T
        Xn, pts = segment_function(n)(*POINT.split(v), u)
        err = pts - tgt
        f = ca.sum2(w * ca.sum1(err * err))
        res = ca.vec(ca.repmat(ca.sqrt(w), 3, 1) * err)
        return [ca.Function("segment_block", [v, d], [f, Xn - v[CELL["next"]]]), ca.Function("segment_res", [v, d], [res])]

    fn, res = compiled.stored(f"segment_block{n}", build)
    return BlockType(f"segment{n}", fn, res)


@lru_cache(maxsize=None)
def pose_block() -> BlockType:
    """X_0 = [vec(R0g exp(w)); p]: the base rotation stays a proper rotation. v = (w, p, X_0); d = vec(R0g)."""
    v, d = ca.SX.sym("v", POSE.size), ca.SX.sym("d", 9)
    w, p, X0 = POSE.split(v)
    r = ca.vertcat(ca.vec(ca.mtimes(ca.reshape(d, 3, 3), so3_exp(w))), p) - X0
    return BlockType("pose", ca.Function("pose_block", [v, d], [ca.SX(0), r]), ca.Function("pose_res", [v, d], [ca.SX(0, 1)]))


def scatter(shape, blocks, symmetric: bool):
    """Sparse MX of ``shape`` from per-instance dense-pattern blocks.

    ``blocks``: (values, pattern, rows, cols) with ``values`` the horizontally concatenated block outputs of a mapped
    call, ``pattern`` one block's sparsity and ``rows``/``cols`` (local size x instances) the global index of each local
    row/column. Entries that land on the same place (a shared variable of several blocks) are summed; ``symmetric``
    stores each entry in the upper triangle."""
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
