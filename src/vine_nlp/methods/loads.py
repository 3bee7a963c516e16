"""Design under self-weight and payload (issue 45): the plain NLP plus rows that keep every section standing.

Per segment j the stage carries 4 extra variables: mu_j, the moment at the section where segment j starts
(3, in units of S_M = pi P r^3 / safety, the unactuated section's allowed moment), and Lambda_j, the grown
length beyond it (units of D). Per-stage blocks tie them by the recursion over segments

    mu_j = mu_{j+1} + (p_{j+1} - p_j) x g^ (a Lambda_{j+1} + b) + a (dl_j / S) sum_i (q_i - p_j) x g^
    Lambda_j = Lambda_{j+1} + dl_j                                   (mu_M = 0, Lambda_M = 0 at the tip)

(q_i: S points of segment j at the middles of S equal pieces, each carrying dl_j / S of its weight; g^ the
direction of gravity; a = w |g| D^2 / S_M, b = m_tip |g| D / S_M), and ask

    c_j^2 / tau^2 - |mu_j - (mu_j . t_j) t_j|^2 >= 0

(c_j: 1, or analysis.loads.WRINKLED where segment j or j - 1 is actuated; t_j the tangent; tau >= 1 a tightening). Every
row reads one stage and the next: the banded structure stays. The rows see the section at each segment's start; the
analysis (analysis.loads.load_report) checks 20 per segment and every grown prefix. Where a grown prefix is short, rows
for it join (an active set; :func:`prefix_block`: by the recursion's linearity, two stages' variables); where the final
shape is, tau grows by the shortfall; and the design is solved again from where it is.

The design starts from the design without the load (the buildable one: its classes, lambda exactly 1 where
there is no actuator, are kept, so which sections are actuated is known: the capacities are data) and is
kept as it is where it already stands. A design that stands only BUDGET D (RMSE) or more off the target is no
design of that target: the design on it stays the problem's design (it folds, and the judge says where and
the pressure it needs) and the one that stands is kept beside it as run RUN (:func:`load_runs`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.analysis.loads import METRES_PER_UNIT, WRINKLED, collapse_moment, load_metrics, load_report
from vine_nlp.methods import drive
from vine_nlp.methods.blocks import BlockType
from vine_nlp.methods.buildable import inherited_bounds
from vine_nlp.methods.common import pair_points
from vine_nlp.methods.nlp import chain_guess, nlp_parameters, result_of, start_x
from vine_nlp.methods.settings import LOAD_BUDGET as BUDGET
from vine_nlp.methods.settings import LOAD_POINTS as S
from vine_nlp.methods.settings import LOAD_ROUNDS as ROUNDS
from vine_nlp.methods.settings import LOAD_TIGHTEN as TIGHTEN
from vine_nlp.methods.settings import Settings
from vine_nlp.methods.structure import Structure, frames12
from vine_nlp.methods.transcription import Smoothness, SoftTip, Spec, get_solver
from vine_nlp.methods.variables import POINT, Slots
from vine_nlp.model.chain import chain_frames, chain_points
from vine_nlp.model.segment import segment_function
from vine_nlp.problem import DesignProblem, Result

RUN = "nlp_load"  # the design that stands, kept beside the design on the target where it gives up more


# a block's local variables by name (variables.Slots): segment j's point block, the next frame's position, E_j
LOAD = POINT + (("p_next", 3), ("E", 4))
LOAD_NEXT = LOAD + (("E_next", 4),)  # and E_{j+1}, but for the last segment
PREFIX = Slots(("X", 12), ("mu", 3), ("p_k", 3), ("E_k", 4))  # section j's frame and mu_j; the prefix end's p_k, E_k


@lru_cache(maxsize=2)
def load_block(last: bool) -> BlockType:
    """The recursion (4 equality rows) and the section's row (1) of one segment. v = ``LOAD`` (X_j, theta, lam,
    length, p_{j+1} (3), E_j (4)) or ``LOAD_NEXT`` (and E_{j+1} (4), unless ``last``); d = (a, b, g^ (3), c / tau, u (S))."""
    sl = LOAD if last else LOAD_NEXT
    v, d = ca.SX.sym("v", sl.size), ca.SX.sym("d", 6 + S)
    X, dl, p1, E = v[sl["X"]], v[sl["length"]], v[sl["p_next"]], v[sl["E"]]
    p0 = X[9:12]  # the frame's position (model.segment: X = (vec R, p))
    _, q = segment_function(S)(*POINT.split(v), d[6:])
    a, b, g, cap = d[0], d[1], d[2:5], d[5]
    E_next = ca.SX.zeros(4) if last else v[sl["E_next"]]
    mu_next, lam_next = E_next[:3], E_next[3]
    own = ca.cross(ca.sum2(q) - S * p0, g) * a * dl / S
    mu = mu_next + ca.cross(p1 - p0, g) * (a * lam_next + b) + own
    t = X[:3]
    bend2 = ca.sumsqr(E[:3]) - ca.dot(E[:3], t) ** 2
    r = ca.vertcat(E[:3] - mu, E[3] - lam_next - dl, cap**2 - bend2)
    return BlockType(f"load{'_last' if last else ''}", ca.Function("load_block", [v, d], [ca.SX(0), r]))


@lru_cache(maxsize=1)
def prefix_block() -> BlockType:
    """A grown prefix's row: the section at segment j's start with the tube grown to segment k's start (k > j),
    the payload there. By the recursion's linearity its moment is mu_j - mu_k - (p_k - p_j) x g^ a Lambda_k (the
    weight beyond k taken off, the payload moved to p_k). v = ``PREFIX`` (X_j, mu_j, p_k, E_k = (mu_k, Lambda_k));
    d = (a, g^ (3), c / tau)."""
    v, d = ca.SX.sym("v", PREFIX.size), ca.SX.sym("d", 5)
    X, mu_j, p_k, E_k = (v[PREFIX[k]] for k in ("X", "mu", "p_k", "E_k"))
    mu = mu_j - E_k[:3] - ca.cross(p_k - X[9:12], d[1:4]) * d[0] * E_k[3]
    r = d[4] ** 2 - (ca.sumsqr(mu) - ca.dot(mu, X[:3]) ** 2)
    return BlockType("load_prefix", ca.Function("prefix_block", [v, d], [ca.SX(0), r]))


@dataclass(frozen=True)
class LoadRows:
    """The load rows on the chain (module docstring); extra stage variables E_j = (mu_j, Lambda_j): the
    structure's ``extra`` = 4. Parameter ``load`` (6 + S, M): per segment (a, b, g^, c_j / tau, u); with
    ``pairs`` ((j, k), ...: grown prefixes, an active set), ``load_prefix`` (5, P): (a, g^, c_j / tau)."""

    pairs: tuple = ()

    @property
    def compile(self):  # an active set of prefixes: each block type compiled on its own (as the obstacle rows)
        return "blocks" if self.pairs else True

    def apply(self, c) -> None:
        lay, M = c.lay, c.s.M
        data = c.param("load", (6 + S, M))
        rows = (np.zeros(5), np.r_[np.zeros(4), np.inf])

        def index(j, last):
            return np.r_[lay.X[j, 0], lay.routing_at(j), lay.X[j + 1, 0, 9:], lay.extra[j, :4], [] if last else lay.extra[j + 1, :4]]

        if M > 1:
            c.add_block(load_block(False), np.array([index(j, False) for j in range(M - 1)]).T, data[:, : M - 1], *rows, term="load")
        c.add_block(load_block(True), index(M - 1, True)[:, None], data[:, M - 1], *rows, term="load")
        if self.pairs:
            idx = np.array([np.r_[lay.X[j, 0], lay.extra[j, :3], lay.X[k, 0, 9:], lay.extra[k, :4]] for j, k in self.pairs]).T
            c.add_block(prefix_block(), idx, c.param("load_prefix", (5, len(self.pairs))), 0.0, np.inf, term="load")


def prefix_pairs(rep: dict, length) -> set:
    """(j, k) of the grown prefixes that load a section past its allowed moment in ``rep`` (analysis.loads): the
    segment start nearest the section, the one nearest the prefix's end (k > j, short of the tip)."""
    cum = np.r_[0.0, np.cumsum(length)]
    bad = np.flatnonzero((rep["moment_growth"] * rep["safety"] > rep["capacity"]) & (rep["prefix_end"] < cum[-1] * (1 - 1e-9)))
    j = np.clip(np.abs(cum[None, :-1] - rep["l"][bad, None]).argmin(axis=1), 0, len(length) - 1)
    k = np.abs(cum[None, :-1] - rep["prefix_end"][bad, None]).argmin(axis=1)
    return {(int(a), int(b)) for a, b in zip(j, k) if b > a}


def scales(problem: DesignProblem) -> tuple[float, float, np.ndarray]:
    """(a, b, g^) of the module docstring for ``problem``'s load and tube."""
    load, k = problem.load, METRES_PER_UNIT[problem.units]
    Dm = problem.diameter * k
    SM = float(collapse_moment(load.pressure, Dm / 2)) / load.safety
    g = np.asarray(load.gravity, float)
    gn = float(np.linalg.norm(g))
    return load.mass_per_length * gn * Dm**2 / SM, load.tip_mass * gn * Dm / SM, g / max(gn, 1e-300)


def section_caps(lam) -> np.ndarray:
    """c_j: 1 where the section at segment j's start is unactuated on both sides, WRINKLED where not."""
    act = np.asarray(lam) < 1.0 - 1e-9
    return np.where(act | np.r_[False, act[:-1]], WRINKLED, 1.0)


def load_data(problem: DesignProblem, lam, tau: float) -> np.ndarray:
    a, b, g = scales(problem)
    cap = section_caps(lam) / tau
    M = cap.size
    u = (np.arange(S) + 0.5) / S
    return np.vstack([np.full(M, a), np.full(M, b), np.tile(g[:, None], M), cap, np.tile(u[:, None], M)])


def prefix_data(problem: DesignProblem, lam, tau: float, pairs) -> np.ndarray:
    a, _, g = scales(problem)
    cap = section_caps(lam) / tau
    return np.array([[a, *g, cap[j]] for j, _ in pairs]).T.reshape(5, len(pairs))


def load_extra(problem: DesignProblem, routing) -> np.ndarray:
    """The extra variables (4, M) of ``routing``: the recursion evaluated (numpy), units of D and S_M."""
    D, M = problem.diameter, routing.segments
    a, b, g = scales(problem)
    frames = chain_frames(routing.theta, routing.lam, routing.length, D, routing.initial_pose)
    p = frames[:, :3, 3] / D
    u = (np.arange(S) + 0.5) / S
    q, _ = chain_points(routing.theta, routing.lam, routing.length, D, np.repeat(np.arange(M), S), np.tile(u, M),
                        routing.initial_pose, frames=frames)
    q = q.reshape(M, S, 3) / D
    dl = routing.length / D
    E = np.zeros((4, M + 1))
    for j in range(M - 1, -1, -1):
        own = np.cross(q[j].sum(axis=0) - S * p[j], g) * a * dl[j] / S
        E[:3, j] = E[:3, j + 1] + np.cross(p[j + 1] - p[j], g) * (a * E[3, j + 1] + b) + own
        E[3, j] = E[3, j + 1] + dl[j]
    return E[:, :M]


def load_spec(problem: DesignProblem, pairing, pairs: tuple = ()) -> Spec:
    """The plain NLP plus the load rows, exact Hessian; the base pose free, or fixed where the problem fixes it."""
    o = problem.options
    s = Structure(pairing.segments, pairing.n, 1, "shared" if problem.actuator.shared_lambda else "segment",
                  "fixed" if o.base == "fixed" else "free", extra=4)
    return Spec(s, (Smoothness(), SoftTip(), LoadRows(tuple(sorted(pairs)))), "exact", Settings(o.max_iter, o.tol, hard=True))


def design_with_load(problem: DesignProblem, start: Result, rounds: int = ROUNDS) -> Result:
    """The design of ``problem`` that stands under its [load] (module docstring), from ``start`` (the design
    without the load), returned as it is (with its load metrics) where it already stands. Method "nlp_load";
    metrics load_margin, collapse_at, min_pressure (analysis.loads); stats load_rounds, load_tighten,
    load_prefix_rows, start_rmse, start_load_margin; iterations and solver time summed over the solves with rows."""
    growth = problem.growth
    first = load_report(start.routing, problem.diameter, problem.units, problem.load, growth)
    stats0 = {"start_rmse": float(start.metrics["rmse"]), "start_load_margin": first["margin"]}
    if first["holds"]:
        best = dataclasses.replace(start, metrics=dict(start.metrics) | load_metrics(first), stats=dict(start.stats))
        best.stats.update(stats0 | {"load_rounds": 0})
        return best
    stats = drive.Stats()
    pairing = pair_points(problem.target, problem.options.points_per_segment)
    D, R0g = problem.diameter, start.routing.initial_pose[:3, :3].copy()
    params = nlp_parameters(problem, pairing, R0g)
    fixed = problem.options.base == "fixed"
    base = start.routing.initial_pose if fixed else R0g  # a fixed base where the problem fixes it
    pairs = prefix_pairs(first, start.routing.length) if growth == "while-actuated" else set()
    x, tau, best, best_rep, res = None, 1.0, None, None, start
    for k in range(rounds):
        solver = get_solver(load_spec(problem, pairing, tuple(sorted(pairs))))
        if x is None:  # the prefixes' rows add no variables: one start, one set of bounds (a buildable start's classes kept)
            bounds = solver.bounds(X0=frames12(base[None], D).T if fixed else None, **inherited_bounds(problem, pairing, start))
            x = start_x(solver, chain_guess(problem, start.routing), D, "chain")
            x[solver.layout.extra.T] = load_extra(problem, start.routing)
        # the capacities of the latest design's sections
        data = {"load": load_data(problem, res.routing.lam, tau)}
        if pairs:
            data["load_prefix"] = prefix_data(problem, res.routing.lam, tau, sorted(pairs))
        sol = solver.solve(x, solver.pack_params(params | data), *bounds)
        x = sol.x
        res, done = stats.absorb(result_of(problem, pairing, sol, base, "nlp_load")), k + 1
        rep = load_report(res.routing, D, problem.units, problem.load, growth)
        key = drive.rank(res, rep["holds"], problem.load.safety - rep["margin"])
        if best is None or key < drive.rank(best, best_rep["holds"], problem.load.safety - best_rep["margin"]):
            best, best_rep = res, rep
        if res.converged and (rep["holds"] or res.metrics["rmse"] > stats0["start_rmse"] + BUDGET * D):
            break  # it stands; or it stands only far off the target, where tightening goes farther (load_runs)
        new = prefix_pairs(rep, res.routing.length) - pairs if growth == "while-actuated" else set()
        pairs |= new  # a grown prefix short: its rows; else the rows tightened by the shortfall
        tau *= 1.0 if new else max(problem.load.safety / rep["margin"], 1.0) * TIGHTEN if rep["margin"] > 0 else 1.5
    best = stats.stamp(best)
    best.metrics.update(load_metrics(best_rep))
    best.stats.update(stats0 | {"load_rounds": done, "load_tighten": tau, "load_prefix_rows": len(pairs)})
    return best


def load_runs(problem: DesignProblem, start: Result) -> dict:
    """The design runs under the load: {"nlp": the design that stands} where it stays within BUDGET D (RMSE) of
    ``start``'s fit, else {"nlp": ``start``, RUN: the design that stands (or tried to)}."""
    loaded = design_with_load(problem, start)
    rmse, rmse0 = loaded.metrics["rmse"], start.metrics["rmse"]
    stood = loaded.routing is start.routing  # the start stood as it was (design_with_load solved nothing): no stats read
    if stood or (loaded.converged and loaded.metrics["load_margin"] >= problem.load.safety
                                            and rmse <= rmse0 + BUDGET * problem.diameter):
        return {"nlp": loaded}
    start.stats["load_design"] = f"kept on the target: the design that stands ({RUN}) is {rmse:.4g} {problem.units} RMSE off it"
    return {"nlp": start, RUN: loaded}
