"""Design of a tube with several actuators: one NLP over every line's theta_k, lambda_k and phi_k, the shared
segment lengths and the one base pose, every state's shape paired with its own target (spec "Several actuators
on one tube"; the model is ``vine_nlp.model.actuators``).

Transcription (the house's: ``methods.variables`` declares each variable once, ``methods.structure`` lays them
out in stage order; in units of D): per segment j the declared variables :func:`declared` (every line's theta_k,
lambda_k and phi_k at the segment's end, the shared length, the pairing's segment end on each state's target);
the head the one base pose (a rotation vector about the guess's and a position; none for a fixed base), each
line's phi_k[0] (globals; the first's 0) and each state's first frame (fixed by its bounds: the base if fixed,
else unused). Each state is a level: its material frames G_j are variables (multiple shooting), tied by one
segment's motion. A segment of a state moves G by the product of its active lines' motions
G_k = Rx(phi_k[j]) H(theta_k, lambda_k, l_j) Rx(-phi_k[j+1]), separated by translations -l_j along x: every G_k
with lambda_k = 1 is a translation l_j, so the product is the model exactly wherever at most one active line has
lambda < 1 (and a smooth stand-in where several do, used only on the way). phi_k[j+1] = phi_k[j] + 2 tan(theta_k[j])
l_j / D are constraints. Each (state, segment) is one block of ``methods.blocks`` (its continuity rows and its points'
fit, with its own SX derivatives, mapped over the segments and scattered by ``methods.transcription``'s assembly; a
free base's pose enters the first segment's); the tips, the smoothness, the penalty and the phi, pairing and width
rows are global (CasADi's derivatives).
Expanded whole to SX instead, the Lagrangian's Hessian was 5.2 million instructions and 24 ms an evaluation.

Pairing: a state's model points sit at n equal fractions of each segment; where each segment's ends fall on the
state's target (fractions of its chord) are variables too, so the shared segment lengths can serve shapes whose
actuated parts differ (no fixed pairing of target points with segments has to hold for every state). The target
is linearized around the pairing of the solve before (a parameter) and re-linearized between solves.

No two active lines on one segment (the method): lines that are active together in some state are *exclusive*.
1. A relaxed solve with the exclusive pairs' lambdas free, a small penalty on (1 - lambda_a)(1 - lambda_b).
2. Each segment is assigned, line by line in order of how much it contracts there, to lines not exclusive with one
   already assigned; every other line's lambda is fixed to exactly 1 by its bounds, and the design is polished
   (same NLP). The polished design has at most one active line per segment in every state by construction.
3. Buildable (``analysis.buildability``'s rules per line): each lambda near 1 (within half the correction margin) is
   fixed to exactly 1, the others kept inside [lambda_min + margin, 1 - margin], every stopper gap (alone or with its
   partner's) and stopper at least min_feature, and the design is polished again. Then each line's runs without an
   actuator are unwound (:func:`unwound`: no pointless turning; every state's shape unchanged).
Chosen over a complementarity constraint because IPOPT handles fixed bounds exactly and an MPCC poorly (no
constraint qualification at the solution); the assignment is what a builder decides anyway (which tendon runs
where). Lines not exclusive keep (w_a + w_b)/2 apart around the circumference on every segment where both may
carry an actuator (1 - cos(phi_a - phi_b) >= 1 - cos((w_a + w_b)/D), at both ends); a pair that cannot ever be
that far apart ((w_a + w_b)/2 > pi D/2) is made exclusive.
"""

from __future__ import annotations

import functools
import itertools
import math
import time
from dataclasses import replace
from types import SimpleNamespace

import casadi as ca
import numpy as np

from vine_nlp.analysis.buildability import default_min_feature, partners, pieces, wrap_angle
from vine_nlp.methods import settings
from vine_nlp.methods.actuators import ActuatorsProblem, ActuatorsResult, evaluate
from vine_nlp.methods.blocks import BlockType, block_functions
from vine_nlp.methods.common import geometric_guess, pair_points
from vine_nlp.methods.settings import CHAIN, EXACT_BOUNDS, quiet
from vine_nlp.methods.structure import Layout, Structure, frames12
from vine_nlp.methods.transcription import Assembled, Pieces
from vine_nlp.methods.variables import LAM, LENGTH, THETA, Var, box
from vine_nlp.model.actuators import Lines, roll
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import actuated
from vine_nlp.model.segment import so3_exp, twist_parts
from vine_nlp.problem import DesignProblem


def declared(problem: ActuatorsProblem, M: int) -> tuple:
    """(variables, bounds): one segment's variables (every line's theta_k and lambda_k, ``THETA``'s and ``LAM``'s
    rules; phi_k at the segment's end, free; the shared length, ``LENGTH``'s rule; where the segment's end falls on
    each state's target, a fraction of its chord, the last segment's exactly 1) and the lines' bounds as the one
    actuator those rules read: theta_max and lambda_min per segment and line (``box``'s shape)."""
    K, S = len(problem.actuators), len(problem.states)
    per = {key: np.broadcast_to([getattr(a.actuator, key) for a in problem.actuators], (M, K)).reshape((M, K) if K > 1 else (M,))
           for key in ("theta_max", "lambda_min")}
    return (replace(THETA, size=K), replace(LAM, size=K, levels=False), Var("phi", lambda a, ref: (-np.inf, np.inf), size=K),
            LENGTH, Var("b", lambda a, ref: (np.arange(ref.size) == ref.size - 1, 1.0), size=S)), SimpleNamespace(**per)


def rx(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def local_motion(th, lam, ph, dl, u):
    """(R, p) of a state's segment in its material frame at fraction u (SX): the product of the active lines'
    motions with translations -u dl between (module docstring). th, lam, ph: one entry per active line."""
    R, p = ca.SX.eye(3), ca.SX.zeros(3)
    for i in range(len(th)):
        kc, tc, lc = center_rates(th[i], lam[i], 1.0)
        Rs, ps = twist_parts(kc, tc, u * dl * lc)
        if i:
            p = p + ca.mtimes(R, ca.vertcat(-u * dl, 0, 0))
        Rin = rx(ph[i])
        out = ph[i] + 2 * ca.tan(th[i]) * u * dl
        p = p + ca.mtimes(R, ca.mtimes(Rin, ca.vertcat(*ps)))
        R = ca.mtimes(R, ca.mtimes(ca.mtimes(Rin, ca.vertcat(*[ca.horzcat(*r) for r in Rs])), rx(-out)))
    return R, p


@functools.lru_cache(maxsize=None)
def _functions(a: int, n: int):
    """SX functions of ``a`` active lines: step (X, th, lam, ph, dl) -> X', points (X, th, lam, ph, dl) -> 3 x n
    at u = 0, 1/n, ..., (n-1)/n, and the tip (u = 1)."""
    X, th, lam, ph, dl = ca.SX.sym("X", 12), ca.SX.sym("th", a), ca.SX.sym("lam", a), ca.SX.sym("ph", a), ca.SX.sym("dl")
    R0, p0 = ca.reshape(X[:9], 3, 3), X[9:]
    lines = [th[i] for i in range(a)], [lam[i] for i in range(a)], [ph[i] for i in range(a)]
    Rl, pl = local_motion(*lines, dl, 1.0)
    step = ca.Function("step", [X, th, lam, ph, dl], [ca.vertcat(ca.vec(ca.mtimes(R0, Rl)), p0 + ca.mtimes(R0, pl))])
    pts = [p0 + ca.mtimes(R0, local_motion(*lines, dl, i / n)[1]) for i in range(n)]
    return step, ca.Function("pts", [X, th, lam, ph, dl], [ca.horzcat(*pts)])


@functools.lru_cache(maxsize=None)
def _segment_block(a: int, n: int, head: str) -> BlockType:
    """One segment of one state with ``a`` active lines: its continuity rows X_{j+1} - step(...) and its points' fit
    w sum_i |r(u_i) - T_i|^2, T_i the target linearized at the pairing (module docstring), with its own SX derivatives
    (``methods.blocks``: CasADi's automatic derivatives of the whole NLP cost several times more per iteration).
    v: the segment's start (``head`` "X": the frame X_j (12); "X0": the first segment's, a fixed base's; "pose": the
    first segment's from a free base's pose w, p (6), X_0 = [vec(R0g exp(w)); p]), the active lines' theta, lambda and
    phi at the start (a each), the length, the pairing's ends b_j (none for the first segment: 0) and b_{j+1}, then
    X_{j+1} (12); d: per point its c0, the target there and its slope in c (7 n), the weight w (and R0g, "pose")."""
    step, pts = _functions(a, n)
    nh, first = (6 if head == "pose" else 12), head != "X"
    v, d = ca.SX.sym("v", nh + 3 * a + 2 + (not first) + 12), ca.SX.sym("d", 7 * n + 1 + 9 * (head == "pose"))
    h, th, lam, ph = v[:nh], v[nh: nh + a], v[nh + a: nh + 2 * a], v[nh + 2 * a: nh + 3 * a]
    dl, b0, b1, Xn = v[nh + 3 * a], 0 if first else v[-14], v[-13], v[-12:]
    X = ca.vertcat(ca.vec(ca.mtimes(ca.reshape(d[-9:], 3, 3), so3_exp(h[:3]))), h[3:]) if head == "pose" else h
    q = ca.reshape(d[: 7 * n], 7, n)
    c = b0 + (b1 - b0) * ca.DM(np.arange(n) / n).T
    T = q[1:4, :] + q[4:7, :] * ca.repmat(c - q[0, :], 3, 1)
    f = d[7 * n] * ca.sumsqr(pts(X, th, lam, ph, dl) - T)
    return BlockType(f"actuators_segment_{a}_{n}_{head}", ca.Function("actuators_segment", [v, d], [f, Xn - step(X, th, lam, ph, dl)]),
                     budget=settings.ACTUATORS_BLOCK_BUDGET)


_BUILT: dict = {}  # the solvers built in this process, per structure, the latest settings.ACTUATORS_KEPT (:meth:`_NLP.solver`)


class _NLP:
    """The NLP of one problem: per state and segment one block (:func:`_segment_block`, SX with its own derivatives,
    mapped over the segments and scattered: ``methods.transcription``'s assembly), the rest global; the stages and
    pairing rounds change only bounds and parameters. Its solvers are built once per structure in a process
    (segments, points, the states' lines, the exclusive and spaced pairs, the base, IPOPT's limit and tolerance): the
    data (targets, the guess's lengths, the smoothness weights, the base's rotation) are parameters (``data``), so
    every door, correction round and sweep item of one structure reuses them. ``lay``: where each declared variable
    lives (``methods.structure.Layout``, a level per state)."""

    def __init__(self, problem: ActuatorsProblem, M: int, R0g: np.ndarray, h: np.ndarray):
        D, o, fixed = problem.diameter, problem.options, problem.options.base == "fixed"
        K, S = len(problem.actuators), len(problem.states)
        self.K, self.M, self.S, self.D = K, M, S, D
        n, idx = o.points_per_segment, {nm: k for k, nm in enumerate(problem.names)}
        lay = self.lay = Layout(Structure(M, K=S, pose="fixed" if fixed else "shared", globals=K, variables=declared(problem, M)[0]))
        pc = self.pieces = Pieces(lay)
        x = pc.x
        th, lam, phi, dl, b = (ca.reshape(x[lay.var[v].reshape(M, -1).ravel().tolist()], -1, M) for v in ("theta", "lam", "phi", "length", "b"))
        ph = ca.horzcat(x[lay.globals.tolist()], phi)  # (K, M+1): phi_k[0] and at every segment's end
        b = ca.horzcat(ca.DM.zeros(S, 1), b).T  # (M+1, S): the pairing's segment ends (fractions of each target's chord)
        self.P = n * M + 1  # model points per state: n per segment and the tip
        # the stage-1 penalty weight, then per state the model points' fractions c0 of the state's length at the
        # pairing, the target there and its derivative in c (the pairing linearized: exact where c = c0)
        par = self.p = pc.param("p", (1 + 7 * self.P * S + M + 11, 1))
        hp, wt, wl = par[-M - 11: -11], par[-11], par[-10]  # the data: the guess's lengths, the smoothness weights
        Rg = par[-9:]  # and the guess's base rotation (column-major)
        self.data = np.r_[h, o.smooth_theta, o.smooth_lambda, np.asarray(R0g, float).ravel(order="F")]
        at = {v: lay.var[v].reshape(M, -1) for v in ("theta", "lam", "phi", "length", "b")}
        w, lines = 1.0 / (S * self.P), []
        for s, active in enumerate(problem.states.values()):
            ks = [idx[a] for a in active]
            lines.append(tuple(ks))
            q = ca.reshape(par[1 + 7 * self.P * s: 1 + 7 * self.P * (s + 1)], 7, self.P)
            Q = ca.vertcat(ca.reshape(q[:, : n * M], 7 * n, M), ca.DM.ones(1, M) * w)
            for js, head in ((range(1), "X0" if fixed else "pose"), (range(1, M), "X")):
                if not js:
                    continue
                index = np.array([np.r_[lay.pose[0] if head == "pose" else lay.X[j, s], at["theta"][j, ks], at["lam"][j, ks],
                                        lay.globals[ks] if j == 0 else at["phi"][j - 1, ks], at["length"][j],
                                        [] if j == 0 else at["b"][j - 1, s], at["b"][j, s], lay.X[j + 1, s]] for j in js]).T
                data = Q[:, js.start: js.stop]
                pc.add_block(_segment_block(len(ks), n, head), index, ca.vertcat(data, Rg) if head == "pose" else data)
            # the tip pairs with the target's end (c = 1)
            pc.add_term("fit", w * ca.sumsqr(x[lay.X[M, s, 9:].tolist()] - q[1:4, -1] - q[4:7, -1] * (1 - q[0, -1])))
        # smoothness of theta and lambda along the tube (h: the guess's segment lengths, L their sum)
        if M > 1:
            hm = (0.5 * (hp[1:] + hp[:-1])).T
            pc.add_term("smooth", wt / ca.sum1(hp) * ca.sum2(ca.sum1(ca.diff(th, 1, 1) ** 2) / hm))
            pc.add_term("smooth", wl / ca.sum1(hp) * ca.sum2(ca.sum1(ca.diff(lam, 1, 1) ** 2) / hm))
        # exclusive pairs (stage 1 penalty) and widths (1 - cos(phi_a - phi_b) at every segment end)
        self.exclusive, pairs = exclusive_pairs(problem)
        mu = par[0]
        for a, c in self.exclusive:
            pc.add_term("exclusive", mu * ca.sum2((1 - lam[a, :]) * (1 - lam[c, :])) / M)
        pc.add_rows("phi", ph[:, 1:] - ph[:, :-1] - 2 * ca.tan(th) * ca.repmat(dl, K, 1), 0.0, 0.0)
        pc.add_rows("pieces", ca.diff(b, 1, 0), settings.ACTUATORS_MIN_PIECE / M, np.inf)  # each piece a fraction of 1/M at least
        wd = problem.widths
        for a, c in pairs:
            pc.add_rows("widths", (1 - ca.cos(ph[a, :] - ph[c, :])).T, 1 - math.cos(min(math.pi, (wd[a] + wd[c]) / D)), np.inf)
        path = ca.repmat(dl, K, 1) / ca.cos(th)  # each line's length along it per segment (K, M)
        gap = (1 - lam) * path  # the stopper gaps: alone, partners' together, and the stoppers (``features``)
        self.features = ca.vertcat(*(ca.vec(e) for e in (gap, gap[:, :-1] + gap[:, 1:], lam * path)))
        pc.add_rows("features", self.features, -np.inf, np.inf)  # bounded per stage (``_stage``)
        # compiled where methods.compiled allows (cached on disk per block; interpreted while the compiler works:
        # the same arithmetic, so a first run and later runs take the same steps)
        self.assembled = Assembled(pc, {bl.bt: block_functions(bl.bt, True) for bl in pc.blocks}, "exact")
        own = self.assembled.lbg.size - self.features.numel()  # the rows before the features
        self.lbg, self.ubg = self.assembled.lbg[:own], self.assembled.ubg[:own]
        self.opts = quiet(o.max_iter, o.tol) | CHAIN | EXACT_BOUNDS | {"ipopt.constr_mult_init_max": 0.0}
        self.key = (M, n, fixed, tuple(lines), K, tuple(self.exclusive), tuple(pairs), o.max_iter, o.tol)

    def solver(self):
        """The solver (built on first use in the process, per structure), with the features' rows: bounded in the
        last stage, free (-inf) before it. One build, not one with and one without them (a build cost seconds when
        the NLP was expanded whole). The constraint multipliers start at 0 (``self.opts``): IPOPT's least-squares
        estimate gave the free rows multipliers that cost iterations (the three-way tube of bench_actuators: 683
        iterations, 463 from 0, 262 with two solvers; results/benchmarks/actuators.md)."""
        solver = _BUILT.pop(self.key, None)
        if solver is None:
            problem, derivatives = self.assembled.ipopt(self.p, per_block=True)
            solver = ca.nlpsol("actuators", "ipopt", problem, self.opts | derivatives)
        _BUILT[self.key] = solver  # the latest used last
        for key in list(_BUILT)[: -settings.ACTUATORS_KEPT]:
            del _BUILT[key]
        return solver

    def params(self, mu: float, paired: np.ndarray) -> np.ndarray:
        """The parameter vector: the stage's penalty weight, the targets at the pairing, the data."""
        return np.r_[mu, paired, self.data]

    def at(self, name: str) -> np.ndarray:
        """Where a declared variable lives in x, a row per line (state, for the pairing): (K, M)."""
        return self.lay.var[name].reshape(self.M, -1).T

    def get(self, x, name: str) -> np.ndarray:
        """A declared variable of a solution x, a row per line (state, for the pairing): (K, M)."""
        return np.asarray(x)[self.at(name)]

    def pairing(self, x) -> np.ndarray:
        """(M+1, S) each segment's ends as fractions of each state's target chord."""
        return np.vstack([np.zeros(self.S), self.get(x, "b").T])


def exclusive_pairs(problem: ActuatorsProblem):
    """(exclusive, spaced): pairs of lines active together in some state (or too wide to ever share a segment),
    and the other pairs, which keep their widths apart."""
    K, idx = len(problem.actuators), {nm: k for k, nm in enumerate(problem.names)}
    together = {tuple(sorted((idx[a], idx[b]))) for act in problem.states.values() for a, b in itertools.combinations(act, 2)}
    w = problem.widths
    too_wide = {(a, b) for a, b in itertools.combinations(range(K), 2) if (w[a] + w[b]) / 2 > math.pi * problem.diameter / 2}
    ex = sorted(together | too_wide)
    return ex, [p for p in itertools.combinations(range(K), 2) if p not in ex]


def initial_lines(problem: ActuatorsProblem, M: int) -> Lines:
    """Each line from the geometric guess of its first state (a state where it acts alone first); the shared
    lengths the mean of those guesses'; the base the first line's guess; each phi_k[0] the roll of its guess."""
    D, n = problem.diameter, problem.options.points_per_segment
    order = sorted(problem.states.items(), key=lambda s: len(s[1]))
    guesses = []
    for nm in problem.names:
        state = next(s for s, act in order if nm in act)
        one = DesignProblem(problem.name, D, problem.targets[state], problem.actuators[problem.names.index(nm)].actuator, problem.options)
        guesses.append(geometric_guess(one, pair_points(problem.targets[state], n)))
    B = guesses[0].initial_pose
    phi0 = [0.0] + [math.atan2(g.initial_pose[:3, 1] @ B[:3, 2], g.initial_pose[:3, 1] @ B[:3, 1]) for g in guesses[1:]]
    return Lines(problem.names, [g.theta for g in guesses], [g.lam for g in guesses], phi0, np.mean([g.length for g in guesses], axis=0), B)


def _rollout(problem, lines: Lines, D: float) -> np.ndarray:
    """(S, 12, M+1) the material frames of every state from a design (the step functions evaluated)."""
    phi, dl, out = lines.phi(D), lines.length / D, []
    for active in problem.states.values():
        ks = lines.index(active)
        step, _ = _functions(len(ks), 1)
        X = [frames12(lines.initial_pose[None], D)[:, 0]]
        for j in range(lines.segments):
            X.append(np.asarray(step(X[-1], lines.theta[ks, j], lines.lam[ks, j], phi[ks, j], dl[j])).ravel())
        out.append(np.column_stack(X))
    return np.stack(out)


def design_actuators(problem: ActuatorsProblem, starts: int | None = None) -> ActuatorsResult:
    """One design of every line for every state (module docstring); the run ``nlp``. One start (``starts`` is
    accepted for the pipeline and not used yet)."""
    t0 = time.perf_counter()
    D, o = problem.diameter, problem.options
    n, K = o.points_per_segment, len(problem.actuators)
    M = math.ceil((next(iter(problem.targets.values())).shape[0] - 1) / n)
    guess = initial_lines(problem, M)
    B = np.asarray(o.base_pose, float) if o.base == "fixed" else guess.initial_pose
    guess = Lines(guess.names, guess.theta, guess.lam, guess.phi0, guess.length, B)
    nlp = _NLP(problem, M, B[:3, :3], guess.length / D)
    x0, lbx, ubx, lims = start(problem, nlp, guess)
    L, lmin = nlp.at("lam"), np.reshape(lims.lambda_min, (M, K))[0]  # L: (K, M) where each lambda lives
    iters, status, rounds, lbg = 0, "optimal", 0, nlp.lbg
    stages = ["relaxed"] + (["assigned"] if nlp.exclusive else []) + (["margin"] if o.correction_margin > 0 else [])
    for stage in stages:
        keep = np.ones((K, M), bool)
        if stage == "assigned":
            keep = assign(x0[L], nlp.exclusive)
        elif stage == "margin":  # buildable: lambda exactly 1, or inside [lambda_min + margin, 1 - margin]
            margin = np.minimum(o.correction_margin, (1 - lmin) / 2)
            keep = dither(x0[L], margin)
            free = keep & (lbx[L] < ubx[L])
            lbx[L], ubx[L] = np.where(free, (lmin + margin)[:, None], lbx[L]), np.where(free, 1 - margin[:, None], ubx[L])
            lbg = features(nlp, problem, keep, lbx)
            x0[L] = np.clip(x0[L], lbx[L], ubx[L])
        x0[L[~keep]] = lbx[L[~keep]] = ubx[L[~keep]] = 1.0
        mu = settings.ACTUATORS_PENALTY if stage == "relaxed" else 0.0
        x0, status, n_it, n_r = _stage(nlp, problem, x0, (lbx, ubx, lbg), mu, B, settings.ACTUATORS_ROUNDS if stage == stages[-1] else 1)
        iters, rounds = iters + n_it, rounds + n_r
    stats = {"segments": M, "points_per_segment": n, "stages": len(stages), "rounds": rounds, "exclusive_pairs": len(nlp.exclusive),
             "base": o.base, "states": {s: list(a) for s, a in problem.states.items()}}
    lines = unwound(_lines(nlp, problem, x0, B), D, o.base == "fixed", np.reshape(lims.theta_max, (M, K))[0])
    return evaluate(problem, lines, "nlp", bounds=nlp.pairing(x0).T, status=status,
                    solve_time_s=time.perf_counter() - t0, iterations=iters, stats=stats)


def start(problem: ActuatorsProblem, nlp: _NLP, lines: Lines):
    """(x0, lbx, ubx, the lines' bounds): the NLP's start at ``lines`` (its base the pose's) and the declared variables'
    bounds, each state's first frame fixed at the base and the first line's phi_k[0] at 0."""
    D, M, n, lay = problem.diameter, nlp.M, problem.options.points_per_segment, nlp.lay
    frames, B = _rollout(problem, lines, D), lines.initial_pose
    x0 = lay.pack_x(frames, poses=np.r_[0.0, 0.0, 0.0, B[:3, 3] / D], globals_=lines.phi0, theta=lines.theta.T, lam=lines.lam.T,
                    phi=lines.phi(D)[:, 1:].T, length=lines.length / D, b=np.column_stack([c[n::n] for c in _fractions(problem, lines, n)]))
    lims = declared(problem, M)[1]
    lbx, ubx = lay.bounds(X0=frames[:, :, 0], **box(lims, np.full(M, lines.length.mean() / D), lay.variables))
    lbx[lay.X[0]] = ubx[lay.X[0]] = frames[:, :, 0]  # each state's first frame: the base (fixed) or unused (a free base's pose)
    lbx[lay.globals[0]] = ubx[lay.globals[0]] = 0.0  # the first line starts at phi = 0
    return x0, lbx, ubx, lims


def correction_nlp(problem: ActuatorsProblem, lines: Lines, bounds: dict):
    """(realized Lines, status, stats) of the NLP from ``lines`` with the base, the lengths and every phi_k[0] fixed;
    line k's theta and lambda within ``bounds[k]`` = ((lo, hi) of theta, (lo, hi) of lambda), fixed for a line not
    in it (the correction of a built robot: methods.correct.several)."""
    t0, D = time.perf_counter(), problem.diameter
    pf = replace(problem, options=replace(problem.options, base="fixed", base_pose=lines.initial_pose))
    nlp = _NLP(pf, lines.segments, lines.initial_pose[:3, :3], lines.length / D)
    x0, lbx, ubx, _ = start(pf, nlp, lines)
    T, L = nlp.at("theta"), nlp.at("lam")
    for at in (nlp.lay.var["length"], nlp.lay.globals, T, L):
        lbx[at] = ubx[at] = x0[at]
    for k, (th, lam) in bounds.items():
        for at, (lo, hi) in ((T[k], th), (L[k], lam)):
            lbx[at], ubx[at] = lo, hi
            x0[at] = np.clip(x0[at], lo, hi)
    x, status, iters, rounds = _stage(nlp, pf, x0, (lbx, ubx, nlp.lbg), 0.0, lines.initial_pose, settings.ACTUATORS_ROUNDS)
    return _lines(nlp, pf, x, lines.initial_pose), status, {"iterations": iters, "rounds": rounds, "solve_time_s": time.perf_counter() - t0}


def _stage(nlp: _NLP, problem, x0, box, mu, B, rounds: int):
    """One stage: solves from ``x0``, the target re-linearized at the pairing of the solve before, while a round
    lowers the objective; the round whose design meets the targets best (evaluate) is kept.
    Returns (x, status, iterations, solves)."""
    n, (lbx, ubx, lbg) = problem.options.points_per_segment, box
    f, best, iters, solves = np.inf, None, 0, 0
    for _ in range(rounds):
        c = _pairing_fractions(nlp.pairing(x0), n)
        solver, rows = nlp.solver(), nlp.features.numel()
        free = np.full(rows - (lbg.size - nlp.lbg.size), -np.inf)  # the features' rows the stage leaves free
        sol = solver(x0=x0, p=nlp.params(mu, _paired(problem, c)), lbx=lbx, ubx=ubx, lbg=np.r_[lbg, free], ubg=np.r_[nlp.ubg, np.full(rows, np.inf)])
        st = solver.stats()
        x0, iters, solves = np.asarray(sol["x"]).ravel(), iters + int(st.get("iter_count", 0)), solves + 1
        status = {"Solve_Succeeded": "optimal", "Solved_To_Acceptable_Level": "acceptable",
                  "Maximum_Iterations_Exceeded": "max_iter"}.get(st.get("return_status"), "failed")
        b = nlp.pairing(x0)
        err = evaluate(problem, _lines(nlp, problem, x0, B), bounds=b.T).metrics["rmse"] if rounds > 1 else 0.0
        if best is None or err < best[0]:
            best = (err, x0.copy(), status)
        moved = max(np.abs(a - q).max() for a, q in zip(c, _pairing_fractions(b, n)))
        f, f_prev = float(sol["f"]), f
        if moved < settings.ACTUATORS_REPAIR_TOL or f > (1 - settings.ACTUATORS_GAIN) * f_prev:
            break
    return best[1], best[2], iters, solves


def _lines(nlp: _NLP, problem, x, B) -> Lines:
    v, pose = nlp.lay.unpack(x), np.array(B, float)
    if v["poses"].size:
        pose[:3, :3], pose[:3, 3] = B[:3, :3] @ so3_exp(v["poses"][0, :3]), v["poses"][0, 3:] * nlp.D
    return Lines(problem.names, nlp.get(x, "theta"), np.minimum(nlp.get(x, "lam"), 1.0), v["globals"], v["length"] * nlp.D, pose)


def features(nlp: _NLP, problem: ActuatorsProblem, keep: np.ndarray, lbx: np.ndarray) -> np.ndarray:
    """The lower bounds of the constraints for features at least min_feature (``analysis.buildability``'s, times
    settings.FEATURE_SLACK) where ``keep`` (K, M) has an actuator: each stopper gap, alone or with its partner's, and
    the stoppers either side (lambda path / 2 each); every segment at least that long (``lbx`` changed)."""
    o, M = problem.options, nlp.M
    least = settings.FEATURE_SLACK * (default_min_feature(problem.units) if o.min_feature is None else o.min_feature) / nlp.D
    mate = np.array([partners(k) for k in keep])
    pair = keep[:, :-1] & (mate[:, :-1] == np.arange(1, M))
    lbx[nlp.lay.var["length"]] = np.maximum(lbx[nlp.lay.var["length"]], least)
    return np.concatenate([nlp.lbg] + [np.where(c, f * least, -np.inf).ravel(order="F") for c, f in ((keep & (mate < 0), 1), (pair, 1), (keep, 2))])


def unwound(lines: Lines, D: float, fixed: bool, theta_max) -> Lines:
    """Each line's runs without an actuator the shortest way round at constant slope (``methods.buildable.unwind``'s
    rule, per line): a last run straight; a first run straight into the line's phi_k[0] (the first line's into the
    base's roll, every phi_k[0] turned with it), or from phi = 0 with a fixed base. Every state's shape is unchanged
    (it depends on each line's angle where it has an actuator only), but where a short run needs a slope above theta_max."""
    phi, theta, M = lines.phi(D), lines.theta.copy(), lines.segments
    phi0 = phi[:, 0].copy()
    for k in range(lines.count):
        for p in (p for p in pieces(actuated(lines.lam[k]), lines.length, lines.length) if not p.actuated):
            run, net = slice(p.start, p.stop), phi[k, p.stop] - phi[k, p.start]
            if p.stop == M or (p.start == 0 and (k or not fixed)):
                theta[k, run], phi0[k] = 0.0, phi0[k] + (net if p.stop < M else 0.0)
            else:
                theta[k, run] = np.arctan(0.5 * D * wrap_angle(net) / (p.s1 - p.s0))
    theta = np.clip(theta, -theta_max[:, None], theta_max[:, None])
    return Lines(lines.names, theta, lines.lam, wrap_angle(phi0 - phi0[0]), lines.length, lines.initial_pose @ roll(phi0[0]))


def _fractions(problem: ActuatorsProblem, lines: Lines, n: int) -> list:
    """Per state, the fraction of the state's length at each model point (n per segment, then the tip); where
    several active lines contract on one segment (on the way only) the segment's length is the smooth stand-in's."""
    idx, out = {nm: k for k, nm in enumerate(problem.names)}, []
    lc = center_rates(lines.theta, lines.lam, problem.diameter)[2]
    for active in problem.states.values():
        arc = lines.length * np.maximum(0.05, 1 + (lc[[idx[a] for a in active]] - 1).sum(axis=0))
        A = np.r_[0.0, np.cumsum(arc)]
        out.append(np.r_[(A[:-1, None] + arc[:, None] * np.arange(n)[None] / n).ravel(), A[-1]] / A[-1])
    return out


def _pairing_fractions(b: np.ndarray, n: int) -> list:
    """Per state, the fraction of the target's chord paired with each model point (n per segment, then the tip)."""
    return [np.r_[(bs[:-1, None] + np.diff(bs)[:, None] * np.arange(n)[None] / n).ravel(), 1.0] for bs in b.T]


def _paired(problem: ActuatorsProblem, fractions) -> np.ndarray:
    """Per state (stacked, 7 rows of P columns, column-major): the fractions c, the target there (linear on its
    chord) and its derivative in c, in units of D."""
    out = []
    for tgt, c in zip(problem.targets.values(), fractions):
        chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(tgt, axis=0), axis=1))]
        x = c * chord[-1]
        k = np.clip(np.searchsorted(chord, x, side="right") - 1, 0, len(chord) - 2)
        slope = (tgt[k + 1] - tgt[k]) / np.maximum(chord[k + 1] - chord[k], 1e-300)[:, None] * chord[-1]
        at = np.column_stack([np.interp(x, chord, tgt[:, i]) for i in range(3)])
        out.append(np.column_stack([c, at / problem.diameter, slope / problem.diameter]).ravel())
    return np.concatenate(out)


def dither(lam: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """(K, M) which lambdas stay free (inside [lambda_min + margin, 1 - margin]) rather than exactly 1: those at or
    below 1 - margin, and of those above, along each line, as many as keep its running contraction sum(1 - lambda)
    (error diffusion: a run of slight contraction becomes a few segments at 1 - margin among segments at 1)."""
    keep = lam <= 1 - margin[:, None]
    for k in range(lam.shape[0]):
        acc = 0.0
        for j in np.flatnonzero(~keep[k]):
            acc += 1 - lam[k, j]
            if acc >= margin[k] / 2:
                keep[k, j], acc = True, acc - margin[k]
    return keep


def assign(lam: np.ndarray, exclusive) -> np.ndarray:
    """(K, M) which lines keep a free lambda: per segment, lines in order of contraction, each unless it is
    exclusive with one already kept; lines that do not contract keep theirs where no exclusive line is kept."""
    K, M = lam.shape
    ex = {(a, b) for a, b in exclusive} | {(b, a) for a, b in exclusive}
    keep = np.zeros((K, M), bool)
    for j in range(M):
        for k in np.argsort(lam[:, j], kind="stable"):
            if not any(keep[i, j] and (i, k) in ex for i in range(K)) and (1 - lam[k, j] > settings.ACTUATORS_ON or not any((i, k) in ex for i in range(K))):
                keep[k, j] = True
    return keep


__all__ = ["design_actuators", "correction_nlp", "exclusive_pairs", "initial_lines", "assign", "rx"]
