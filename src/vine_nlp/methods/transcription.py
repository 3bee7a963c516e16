"""One multiple-shooting transcription of the chain for every design formulation.

The chain of M segments (paper eq. iterativeTransform, T^{j+1}_w = T^j_w T^{j+1}_j) is written once here; each
formulation (nlp, multishape, tip, clearance, robust, correction, obstacles) states the terms and rows it adds and the
data it feeds in. Where each variable lives is ``methods.structure``; the per-stage pieces and their derivatives are
``methods.blocks``. Small global terms and rows (smoothness, tip rows) keep CasADi's automatic derivatives.

A solver is built once per ``Spec`` (structure, terms, Hessian, settings) and cached; the data (targets, weights,
fractions, guess rotations, smoothing weights) are parameters, so starts, hops and sweep items reuse it."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp import interrupt
from vine_nlp.methods import compiled, variables
from vine_nlp.methods.blocks import (
    BlockType,
    _c_functions,
    _sx_functions,
    block_derivatives,
    block_functions,
    pose_block,
    scatter,
    segment_block,
)
from vine_nlp.methods.settings import Settings
from vine_nlp.methods.structure import Layout, Structure
from vine_nlp.model.routing import Routing
from vine_nlp.model.segment import segment_function, so3_exp

# ---------------------------------------------------------------- statuses

# IPOPT return statuses as archived (spec: "optimal" | "acceptable" | "max_iter" | "failed" | ...)
IPOPT_STATUS = {
    "Solve_Succeeded": "optimal", "Solved_To_Acceptable_Level": "acceptable", "Maximum_Iterations_Exceeded": "max_iter",
    "Maximum_CpuTime_Exceeded": "max_time", "Restoration_Failed": "restoration_failed", "Infeasible_Problem_Detected": "infeasible",
    "Invalid_Number_Detected": "invalid_number", "Error_In_Step_Computation": "step_failed", "Search_Direction_Becomes_Too_Small": "small_step",
}


def ipopt_status(stats: dict, x=None) -> str:
    """Archived status of one solve; an interrupted solve raises KeyboardInterrupt (vine_nlp.interrupt).

    A solution ``x`` with anything non-finite is flagged "invalid_number" whatever IPOPT said."""
    raw = stats.get("return_status", "")
    interrupt.check(raw)
    if x is not None and not np.all(np.isfinite(x)):
        return "invalid_number"
    return IPOPT_STATUS.get(raw, str(raw or "failed"))


# ---------------------------------------------------------------- the chain a formulation builds on


@dataclass
class _Block:
    bt: BlockType
    index: np.ndarray  # (nv, count) global indices of the local variables
    data: ca.MX  # (nd, count)
    lb: np.ndarray  # (nr,) row bounds
    ub: np.ndarray
    term: str = "fit"  # the objective term its f reports to


class Pieces:
    """An NLP as pieces over a decision vector laid out by ``methods.structure.Layout``: per-stage blocks (each with its
    own SX derivatives), global objective terms and global rows, and its parameters. ``Assembled`` turns it into
    the functions IPOPT takes. The chain (:class:`Chain`) is one; the several-actuator NLP another."""

    def __init__(self, lay: Layout):
        self.lay = lay
        self.x = ca.MX.sym("x", lay.size)
        self.params: list[tuple[str, ca.MX]] = []
        self.blocks: list[_Block] = []
        self.terms: dict[str, ca.MX] = {}
        self.rows: list[tuple[str, ca.MX, np.ndarray, np.ndarray]] = []

    def gather(self, index: np.ndarray) -> ca.MX:
        """x at an (a, b) index array, as an (a, b) MX."""
        index = np.asarray(index, int)
        return ca.reshape(self.x[index.T.ravel().tolist()], *index.shape)

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


class Chain(Pieces):
    """Symbolic views of the chain's variables and the pieces a formulation adds to them.

    Views (MX, units of D): ``x``, ``theta``, ``dl`` (1 x M), ``lam_of(k)`` (1 x M),
    ``frames(k)`` (12 x (M+1)), ``tip(k)`` (3), ``extra`` (E x M). ``param(name, shape)``
    declares data; ``add_block``, ``add_term`` and ``add_rows`` add per-stage blocks, global
    objective terms and global rows. ``get_solver(spec)`` turns it into one solver."""

    def __init__(self, s: Structure):
        super().__init__(Layout(s))
        self.s, lay, x = s, self.lay, self.x
        self.theta = x[lay.theta.tolist()].T
        self.dl = x[lay.dl.tolist()].T
        self.extra = ca.reshape(x[lay.extra.ravel().tolist()], s.extra, s.M) if s.extra else None
        self.globals = x[lay.globals.tolist()] if s.globals else None
        M, K, n = s.M, s.K, s.n
        # the always-present blocks: base poses and the segment cells (continuity + point fit)
        self.cells = self.param("cells", (5 * n, M * K))  # per cell (j, k), j-major: u, target slots, w
        if s.pose != "fixed":
            self.R0g = self.param("R0g", (9, s.poses))
            idx = np.vstack([lay.pose[lay.pose_of_level].T, lay.X[0].T])  # (18, K)
            self.add_block(pose_block(), idx, self.R0g[:, lay.pose_of_level.tolist()])
        cells = [(j, k) for j in range(M) for k in range(K)]
        idx = np.array([np.r_[lay.X[j, k], lay.routing_at(j, k), lay.X[j + 1, k]] for j, k in cells]).T  # variables.CELL
        self.add_block(segment_block(n), idx, self.cells)

    # views
    def frames(self, k: int = 0) -> ca.MX:
        return ca.reshape(self.x[self.lay.X[:, k, :].ravel().tolist()], 12, self.s.M + 1)

    def tip(self, k: int = 0) -> ca.MX:
        return self.x[self.lay.X[-1, k, 9:].tolist()]

    def lam_of(self, k: int = 0) -> ca.MX:
        return self.x[self.lay.lam[:, k].tolist()].T


# ---------------------------------------------------------------- terms every chain may take


@dataclass(frozen=True)
class Smoothness:
    """w_theta (1/L) int (D theta')^2 ds (+ the same for lambda when it is per segment), the derivatives
    taken on the given arc-length steps h between segment middles: they replace the paper's low-pass
    filter and mean the same at any discretization. Parameters: smooth (2), h (M-1), L."""

    lam: bool = True

    def apply(self, c: Chain) -> None:
        M = c.s.M
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
    """Local variables of segment j of level k for blocks on its points (``variables.POINT``: X_j, then the routing's)."""
    return np.r_[c.lay.X[j, k], c.lay.routing_at(j, k)]


@dataclass(frozen=True)
class Spec:
    """A cache key for one built solver: structure, terms (frozen dataclasses with ``apply(chain)``),
    Hessian ("exact" | "gauss-newton") and how it is solved (``methods.settings.Settings``: IPOPT's options)."""

    structure: Structure
    terms: tuple = ()
    hessian: str = "exact"
    settings: Settings = field(default_factory=Settings)

    @property
    def options(self) -> tuple:
        """The solver's options as sorted items."""
        return tuple(sorted(self.settings.options().items()))


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


class Assembled:
    """The NLP of a chain: objective f and rows g (blocks, mapped SX, first; then global rows), their bounds,
    the objective per term, and the derivatives IPOPT takes (per block type SX, mapped and
    scattered; global parts automatic)."""

    def __init__(self, c: Chain, fns: dict, hessian: str):
        self.c, self.fns, self.hessian = c, fns, hessian
        f_blocks, g_parts, lbg, ubg = 0, [], [], []
        self.gathered, self.reported = [], dict(c.terms)  # reported: the objective per term (global and blocks)
        for b in c.blocks:
            count = b.index.shape[1]
            V = c.gather(b.index)
            fb, rb = fns[b.bt][0].map(count, "serial")(V, b.data)
            f_blocks = f_blocks + ca.sum2(fb)
            self.reported[b.term] = self.reported.get(b.term, 0) + ca.sum2(fb)
            if b.bt.nr:
                g_parts.append(ca.vec(rb))
                lbg.append(np.tile(b.lb, count))
                ubg.append(np.tile(b.ub, count))
            self.gathered.append((V, count))
        self.f_glob = sum(c.terms.values(), ca.MX(0))  # global terms: automatic derivatives
        self.g_glob = ca.vertcat(*[r for _, r, _, _ in c.rows]) if c.rows else ca.MX(0, 1)
        self.f = self.f_glob + f_blocks
        self.nb = int(sum(v.numel() for v in g_parts))
        self.g = ca.vertcat(*g_parts, self.g_glob)
        self.lbg = np.concatenate([np.zeros(0)] + lbg + [r[2] for r in c.rows])
        self.ubg = np.concatenate([np.zeros(0)] + ubg + [r[3] for r in c.rows])

    def derivatives(self):
        """(lam_f, lam_g, J, triu H) of the objective f."""
        c, x = self.c, self.c.x
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.g.size1())
        sigma = lam_f
        jac_blocks, hess_blocks, row = [], [], 0
        for b, (V, count) in zip(c.blocks, self.gathered):
            _, _, jac, hess, gn = self.fns[b.bt]
            h = gn if self.hessian == "gauss-newton" else hess
            nr = b.bt.nr
            LR = ca.reshape(lam_g[row : row + nr * count], nr, count) if nr else ca.MX(0, count)
            if nr:
                rows_idx = row + np.arange(nr * count).reshape(count, nr).T
                jac_blocks.append((jac.map(count, "serial")(V, b.data), jac.sparsity_out(0), rows_idx, b.index))
            hess_blocks.append((h.map(count, "serial")(V, b.data, sigma, LR), h.sparsity_out(0), b.index, b.index))
            row += nr * count
        J = scatter((self.nb, c.lay.size), jac_blocks, False)
        if c.rows:
            J = ca.vertcat(J, ca.jacobian(self.g_glob, x))
        glob = sigma * self.f_glob + (ca.dot(lam_g[self.nb :], self.g_glob) if c.rows else 0)
        H = scatter((c.lay.size, c.lay.size), hess_blocks, True) + ca.triu(ca.hessian(glob, x)[0])
        return lam_f, lam_g, J, H

    def gradient(self):
        """The gradient of f (compiled blocks carry no derivatives of their own for CasADi to chain)."""
        c = self.c
        grads = [(self.fns[b.bt][1].map(count, "serial")(V, b.data), self.fns[b.bt][1].sparsity_out(0), b.index,
                  np.zeros((1, count), int)) for b, (V, count) in zip(c.blocks, self.gathered)]
        return scatter((c.lay.size, 1), grads, False) + ca.gradient(self.f_glob, c.x)

    def ipopt(self, p, per_block: bool):
        """The problem and the derivative options of CasADi's IPOPT interface."""
        x, f, g = self.c.x, self.f, self.g
        lam_f, lam_g, J, H = self.derivatives()
        opts = {
            "jac_g": ca.Function("nlp_jac_g", [x, p], [g, J], ["x", "p"], ["g", "jac_g_x"]),
            "hess_lag": ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [H], ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"]),
        }
        if per_block:
            opts["grad_f"] = ca.Function("nlp_grad_f", [x, p], [f, self.gradient()], ["x", "p"], ["f", "grad_f_x"])
            # no gradient of the Lagrangian after the solve (multipliers of x and p, never read): it would
            # differentiate through the compiled blocks; IPOPT returns f and g itself
            opts |= {"no_nlp_grad": True, "calc_lam_p": False, "calc_lam_x": False, "calc_f": False, "calc_g": False}
        return {"x": x, "p": p, "f": f, "g": g}, opts


class Solver:
    """One NLP built from a Spec: ``solve(x0, values, lbx, ubx)`` runs IPOPT."""

    def __init__(self, spec: Spec):
        t0 = time.perf_counter()
        self.spec = spec
        c = self.chain = Chain(spec.structure)
        for term in spec.terms:
            term.apply(c)
        x = c.x
        p = ca.vertcat(*[ca.vec(q) for _, q in c.params])
        self._param_shapes = {name: q.shape for name, q in c.params}
        ends = np.cumsum([0] + [q.numel() for _, q in c.params])
        self._param_slices = {name: slice(int(a), int(b)) for (name, _), a, b in zip(c.params, ends[:-1], ends[1:])}
        # how the NLP's functions run: compiled as a whole (cached per structure); or, where a term's
        # structure changes from solve to solve (an active set: compile = "blocks"), interpreted with each
        # block type compiled on its own (cached per block type); or interpreted (compile = False)
        kinds = {getattr(t, "compile", True) for t in spec.terms}
        whole = kinds <= {True}
        per_block = not whole and kinds <= {True, "blocks"}
        nlp = Assembled(c, {b.bt: block_functions(b.bt, per_block) for b in c.blocks}, spec.hessian)
        self.lbg, self.ubg = nlp.lbg, nlp.ubg
        self.problem = {"x": x, "p": p, "f": nlp.f, "g": nlp.g}  # symbolic, for derivative checks and benchmarks
        code = repr((spec.structure, spec.terms, spec.hessian, "ipopt"))  # the generated code's: not the options
        # compiled C where a compiler is found (cached on disk per spec), else interpreted
        self.nlpsol = compiled.nlpsol("vine_nlp", code, lambda: nlp.ipopt(p, per_block), dict(spec.options), enabled=whole)
        self.term_names = list(nlp.reported)
        self._terms = ca.Function("terms", [x, p], [ca.MX(0) + v for v in nlp.reported.values()])
        self._g = ca.Function("g", [x, p], [nlp.g])
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

    def pack_x(self, frames, poses=None, lam_global=None, extra=None, globals_=None, **values) -> np.ndarray:
        return self.layout.pack_x(frames, poses, lam_global, extra, globals_, **values)  # structure.Layout's

    def unpack(self, x) -> dict:
        return self.layout.unpack(x)

    def bounds(self, X0=None, **boxes) -> tuple[np.ndarray, np.ndarray]:
        return self.layout.bounds(X0, **boxes)

    def terms(self, x, p) -> dict:
        return {k: float(v) for k, v in zip(self.term_names, self._terms.call([x, p]))}  # a list for any number of terms

    def solve(self, x0, p, lbx, ubx, lbg=None, ubg=None, multipliers: bool = False, duals: tuple | None = None) -> "Solution":
        """One IPOPT solve from x0 clipped into the bounds: its :class:`Solution` (which unpacks as (x, status,
        stats)); ``multipliers``: also the bound multipliers lam_x (> 0 at an active upper bound, < 0 at a lower
        one: minus the objective's gradient where a variable is fixed; unpacked fourth); ``duals``: (lam_x, lam_g)
        to start from (a warm start), and stats["duals"] holds the answer's."""
        build = 0.0 if self._built else self.build_time_s
        self._built = True
        x0 = np.clip(np.asarray(x0, float), lbx, ubx)
        lbg = self.lbg if lbg is None else lbg
        ubg = self.ubg if ubg is None else ubg
        t0 = time.perf_counter()
        start = {} if duals is None else {"lam_x0": duals[0], "lam_g0": duals[1]}
        sol = interrupt.call(self.nlpsol, x0=x0, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **start)
        st = self.nlpsol.stats()
        elapsed = time.perf_counter() - t0
        x = np.array(sol["x"]).ravel()
        f = float(sol["f"])
        status = ipopt_status(st, x)
        gv = np.array(sol["g"]).ravel()
        viol = float(np.max(np.maximum(lbg - gv, 0) + np.maximum(gv - ubg, 0))) if gv.size else 0.0
        stats = {
            "solver": "ipopt",
            "return_status": st.get("return_status", ""),
            "build_time_s": build,
            "objective": f,
            "iterations": int(st.get("iter_count", 0)),
            "solve_time_s": elapsed,
            "ipopt_time_s": elapsed,  # the solver's alone (solve_time_s may grow to cover a whole method)
            "max_constraint_violation": viol,
            "hessian": self.spec.hessian,
        } | {f"objective_{k}": v for k, v in self.terms(x, p).items()}
        if duals is not None and "lam_g" in sol:
            stats["duals"] = (np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel())
        lam_x = np.array(sol.get("lam_x", np.zeros(x.size))).ravel() if multipliers else None
        return Solution(self, x, np.asarray(p, float), status, stats, lam_x)


@dataclass
class Solution:
    """One solve's answer (rockit's ``sol``): ``value(expr)`` evaluates any expression of the chain (its views
    ``x``, ``theta``, ``frames(k)``, ``tip(k)``, ``extra``, parameters, terms) at the solution; ``routing(D, base,
    k)`` builds level k's routing by name from the declarations; ``unpack()`` gives every declared variable by
    name. ``stats`` is the solve's record, archived by the methods' results (``objective`` is read from it here,
    once). Unpacks as (x, status, stats), with lam_x fourth where the solve was asked for the multipliers."""

    solver: Solver
    x: np.ndarray
    p: np.ndarray
    status: str
    stats: dict
    lam_x: np.ndarray | None = None

    @property
    def objective(self) -> float:
        return float(self.stats["objective"])

    def value(self, expr) -> np.ndarray:
        s, params = self.solver, self.solver.chain.params
        args = [np.reshape(self.p[s.param_slice(n)], s._param_shapes[n], order="F") for n, _ in params]
        return np.array(ca.Function("value", [s.chain.x, *[q for _, q in params]], [ca.MX(expr)])(self.x, *args)).squeeze()

    def unpack(self) -> dict:
        return self.solver.unpack(self.x)

    def routing(self, D: float, base: np.ndarray, k: int = 0) -> Routing:
        return routing_of(self.solver, self.x, D, base, k)

    def __iter__(self):
        yield from (self.x, self.status, self.stats) + (() if self.lam_x is None else (self.lam_x,))

    def __getitem__(self, i):
        return tuple(self)[i]


def routing_of(solver: Solver, x, D: float, base: np.ndarray, k: int = 0) -> Routing:
    """The routing (problem units) of level k in a solution x. ``base``: for a free pose the guess rotation
    R0g (3 x 3) that the pose variables turn; for a fixed pose the base frame itself (4 x 4), kept exactly."""
    v = solver.unpack(x)
    if solver.structure.pose == "fixed":
        T0 = base
    else:
        q = solver.layout.pose_of_level[k]
        T0 = np.eye(4)
        T0[:3, :3] = base @ so3_exp(v["poses"][q, :3])
        T0[:3, 3] = v["poses"][q, 3:] * D
    declared = solver.structure.variables
    return variables.routing({d.name: v[d.name][:, k] if d.levels else v[d.name] for d in declared}, T0, D, declared)


# ---------------------------------------------------------------- data of the plain chain


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
