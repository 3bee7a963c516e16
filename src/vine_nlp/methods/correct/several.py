"""As-built correction of a tube with several actuators (spec "As-built correction", "Several actuators on one tube"):
the one-actuator rule per actuator (``deviations``), the lengths shared.

Estimate: the MAP estimate of ``estimate``'s posterior, per actuator: each measured actuator's theta deviation per
segment and lambda deviation where it has an actuator, the shared log length ratios, and the three systematic parts
(theta offset, lambda offset, log length scale: one construction method, whatever line it builds). Every measurement
is of one state of one build: its points pair with that state's line (``pairing.pair_with_line`` on
``model.actuators.state_line``), point to line; pairs are re-made until they stop moving (ICP). Each round is solved
by SciPy's trust-region least squares on the residuals and their exact Jacobian: each segment's start frame, line,
lambda and length as CasADi functions of the parameters, differentiated once per estimate, and each point's residual
in its segment's (the chain rule, per point; differentiating every round's residuals whole cost 1.5 s a command); the
Gauss-Newton Hessian at the estimate is the Laplace approximation's (the uncertainty). An actuator active in no measured state keeps its
nominal exactly (nothing shows its deviations).

Correction: the design NLP of ``methods.actuators_design`` over the realized lines, every state against its own target;
the base, the lengths and (unless adjusted) theta fixed, each measured actuator's lambda within ``lambda_bounds``, an
unmeasured one's fixed. The nominal to build is the solution minus the deviations, judged per actuator by
``analysis.buildability.correction_missed``.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.analysis.buildability import correction_missed
from vine_nlp.methods import blas, settings
from vine_nlp.methods.actuators import ActuatorsProblem, evaluate, standard_routing
from vine_nlp.methods.actuators_design import correction_nlp, rx
from vine_nlp.methods.buildable import Build
from vine_nlp.methods.correct.correction import ADJUST, CorrectionResult, lambda_bounds, recommend
from vine_nlp.methods.correct.deviations import Deviations, remove_deviations
from vine_nlp.methods.correct.estimate import Estimate, _cap
from vine_nlp.methods.correct.pairing import LINE_SIDE, pair_with_line
from vine_nlp.model.actuators import Lines, owners, state_line
from vine_nlp.model.routing import Routing, Sigmas, actuated, built_lambda
from vine_nlp.model.segment import segment_parts
from vine_nlp.problem import DesignProblem


def realized(nominal: Lines, devs: list) -> Lines:
    """What a robot with deviations ``devs`` (one per actuator, the length ratio shared) realizes built from ``nominal``."""
    th = nominal.theta + np.array([d.theta for d in devs])
    lam = np.array([built_lambda(nominal.lam[k], d.lam, d.lambda_min) for k, d in enumerate(devs)])
    return Lines(nominal.names, th, lam, nominal.phi0, nominal.length * devs[0].length_ratio, nominal.initial_pose)


def measured_actuators(lines: Lines, states: dict, measurements) -> list:
    """Indices of the actuators active in a measured state, in order."""
    return sorted({k for m in measurements for k in lines.index(states[m.state])})


class _Model:
    """The residuals of one ICP round in the parameters z = (theta deviations of each measured actuator (M each), its
    lambda deviations where it has an actuator, log length ratios (M), systematic parts (3)), SX."""

    def __init__(self, builds, states, measured, D, lambda_min):
        self.builds, self.states, self.D, self.measured = builds, states, D, measured
        latest = builds[-1]
        M, Km = latest.segments, len(measured)
        self.lam_at = [(k, j) for k in measured for j in np.flatnonzero(actuated(latest.lam[k]))]
        self.th_idx = {k: np.arange(i * M, (i + 1) * M) for i, k in enumerate(measured)}
        self.lam_idx = Km * M + np.arange(len(self.lam_at))
        self.rho_idx = Km * M + len(self.lam_at) + np.arange(M)
        self.n = Km * M + len(self.lam_at) + M + 3
        z = self.z = ca.SX.sym("z", self.n)
        self.dth = {k: z[at.tolist()] for k, at in self.th_idx.items()}
        self.dlam = {kj: z[int(i)] for kj, i in zip(self.lam_at, self.lam_idx)}
        self.rho, self.g = z[self.rho_idx.tolist()], z[self.n - 3:]
        # bounds: lambda of the latest build within [lambda_min, 1]; theta within +-1.45 rad; lengths within a factor 2
        lo, hi = np.full(self.n, -np.inf), np.full(self.n, np.inf)
        for k, at in self.th_idx.items():
            lo[at], hi[at] = -1.45 - latest.theta[k], 1.45 - latest.theta[k]
        for (k, j), i in zip(self.lam_at, self.lam_idx):
            lo[i], hi[i] = max(lambda_min[k], 0.05) - latest.lam[k, j], 1.0 - latest.lam[k, j]
        lo[self.rho_idx], hi[self.rho_idx] = math.log(0.5), math.log(2.0)
        self.bounds, self.chains, self.segment_fns = (lo, hi), {}, {}

    def lines(self, b):
        """Build b's realized theta, lambda (K x M nested lists of SX), lengths (M) and phi (K x M+1)."""
        nb, last, D = self.builds[b], b == len(self.builds) - 1, self.D
        K, M = nb.count, nb.segments
        th = [[nb.theta[k, j] + (self.dth[k][j] if k in self.dth else 0) for j in range(M)] for k in range(K)]
        lam = [[nb.lam[k, j] for j in range(M)] for k in range(K)]
        for k, j in self.lam_at:
            if actuated(nb.lam[k, j]):
                lam[k][j] = nb.lam[k, j] + self.dlam[k, j] if last else _cap(1.0, nb.lam[k, j] + self.dlam[k, j])
        length = [nb.length[j] * ca.exp(self.rho[j]) for j in range(M)]
        phi = [[nb.phi0[k]] for k in range(K)]
        for k in range(K):
            for j in range(M):
                phi[k].append(phi[k][-1] + 2.0 / D * ca.tan(th[k][j]) * length[j])
        return th, lam, length, phi

    def chain(self, s, b):
        """The state's material frames turned to the shaping line at every segment's start (R, p) and the segment's
        line and lambda, SX (model.actuators.material_frames), cached per (state, build)."""
        if (s, b) not in self.chains:
            th, lam, length, phi = self.lines(b)
            nb = self.builds[b]
            own, first = owners(nb, self.states[s], s), nb.index(self.states[s])[0]
            R, p, out = ca.SX(nb.initial_pose[:3, :3]), ca.SX(nb.initial_pose[:3, 3]), []
            for j, o in enumerate(own):
                k = o if o >= 0 else first
                la = lam[k][j] if o >= 0 else 1.0
                A = ca.mtimes(R, rx(phi[k][j]))
                out.append((A, p, th[k][j], la, length[j]))
                Rs, ps = _parts(th[k][j], la, length[j], self.D)
                R, p = ca.mtimes(ca.mtimes(A, Rs), rx(-phi[k][j + 1])), p + ca.mtimes(A, ps)
            self.chains[s, b] = out
        return self.chains[s, b]

    def segments(self, s, b) -> tuple:
        """Functions z -> G (15 x M: each segment's start frame A (column-major), p, its theta, lambda and length) and
        z -> dG/dz (15 M x n, G column-major) of a state on a build: differentiated once per estimate, not once per
        ICP round (the residuals' Jacobian follows by the chain rule, :meth:`residuals`)."""
        if (s, b) not in self.segment_fns:
            G = ca.horzcat(*[ca.vertcat(ca.vec(A), p, th, la, l) for A, p, th, la, l in self.chain(s, b)])
            self.segment_fns[s, b] = (ca.Function("G", [self.z], [G]), ca.Function("dG", [self.z], [ca.jacobian(ca.vec(G), self.z)]))
        return self.segment_fns[s, b]

    def residuals(self, z, m, pairs, weight, jacobian: bool = False):
        """Point-to-line residuals of measurement ``m`` at its pairs (settings.SLIDE of the tangent part kept) at z
        ((3 N,), point-major), or their Jacobian (3 N x n): each point's residual in its segment's G, times dG/dz."""
        G, dG = self.segments(m.state, m.build % len(self.builds))
        side, N = LINE_SIDE[m.line] * self.D, len(pairs.seg)
        args = (G(z)[:, pairs.seg.tolist()], ca.DM(pairs.frac).T, side, ca.DM(m.points).T, ca.DM(pairs.tangent).T)
        if not jacobian:
            return weight * np.asarray(_point(self.D).map(N)(*args)).ravel(order="F")
        dr = np.asarray(_point_jacobian(self.D).map(N)(*args)).reshape(3, 15, N, order="F")  # point i's 3 x 15 at [:, :, i]
        dg = np.asarray(dG(z)).reshape(-1, 15, self.n)[np.asarray(pairs.seg)]  # (N, 15, n)
        return weight * np.einsum("abn,nbz->naz", dr, dg).reshape(3 * N, self.n)


@lru_cache(maxsize=4)
def _segment(D: float):
    """(theta, lambda, length) -> (R (3x3), p) of the paper's segment (model.segment), an SX function: called on
    symbols, its graph is copied in C++."""
    th, lam, l = ca.SX.sym("th"), ca.SX.sym("lam"), ca.SX.sym("l")
    R, p = segment_parts(th, lam, l, D)
    return ca.Function("segment", [th, lam, l], [ca.vertcat(*[ca.horzcat(*r) for r in R]), ca.vertcat(*p)])


def _parts(th, lam, l, D):
    return _segment(float(D))(th, lam, l)


@lru_cache(maxsize=4)
def _point(D: float):
    """The point-to-line residual (g (15): A, p, theta, lambda, length of the segment; fraction, side, measured point,
    tangent) -> (3,)."""
    g, m, t = ca.SX.sym("g", 15), ca.SX.sym("m", 3), ca.SX.sym("t", 3)
    f, side = ca.SX.sym("f"), ca.SX.sym("side")
    A, p, th, lam, l = ca.reshape(g[:9], 3, 3), g[9:12], g[12], g[13], g[14]
    Rs, ps = _parts(th, lam, f * l, D)
    R = ca.mtimes(A, Rs)
    e = p + ca.mtimes(A, ps) + side * R[:, 1] - m
    return ca.Function("point", [g, f, side, m, t], [e - (1.0 - settings.SLIDE) * t * ca.dot(t, e)])


@lru_cache(maxsize=4)
def _point_jacobian(D: float):
    """d(point)/dg (3 x 15) of :func:`_point`."""
    fn = _point(D)
    g, f, side, m, t = (ca.SX.sym(n, *fn.size_in(i)) for i, n in enumerate(("g", "f", "side", "m", "t")))
    return ca.Function("point_jacobian", [g, f, side, m, t], [ca.jacobian(fn(g, f, side, m, t), g)])


def _deviations(z, model: _Model, latest: Lines, lambda_min) -> list:
    """Deviations per actuator of the parameters z (zero for an actuator no measurement saw)."""
    dth, dlam = np.zeros(latest.theta.shape), np.zeros(latest.lam.shape)
    for k, at in model.th_idx.items():
        dth[k] = z[at]
    for (k, j), i in zip(model.lam_at, model.lam_idx):
        dlam[k, j] = z[i]
    return [Deviations(dth[k], dlam[k], np.exp(z[model.rho_idx]), lambda_min[k]) for k in range(latest.count)]


def _pack(model: _Model, devs: list, systematic) -> np.ndarray:
    """The parameters of deviations per actuator and systematic parts (a warm start)."""
    z = np.zeros(model.n)
    for k, at in model.th_idx.items():
        z[at] = devs[k].theta
    z[model.lam_idx] = [devs[k].lam[j] for k, j in model.lam_at]
    z[model.rho_idx] = np.log(devs[0].length_ratio)
    if systematic is not None:
        z[model.n - 3:] = systematic[0], systematic[1], math.log(systematic[2])
    return z


def estimate_lines(builds: list, measurements: list, states: dict, D: float, sigmas: Sigmas, lambda_min, measurement_sigma: float,
                   systematic_sigmas=settings.DEFAULT_SYSTEMATIC_SIGMAS, start: list | None = None, start_systematic=None,
                   rounds: int = settings.ICP_ROUNDS) -> Estimate:
    """MAP estimate of the robot built last (module docstring). ``builds``: the nominal Lines of each build, oldest
    first; ``measurements``: ``pairing.Measurement`` with ``state`` (of ``states``) and ``build``; ``lambda_min`` per
    actuator; ``start``: a warm start (Deviations per actuator). Returns an ``Estimate`` whose routing is the as-built
    Lines, deviations one Deviations per actuator and std {actuator: (M, 3)}; stats["measured"] the measured actuators."""
    from scipy.optimize import least_squares  # SciPy loads only where a robot of several actuators is corrected

    t0, latest = time.perf_counter(), builds[-1]
    M = latest.segments
    measured = measured_actuators(latest, states, measurements)
    model = _Model(builds, states, measured, D, lambda_min)
    N = sum(len(m.points) for m in measurements)
    s_len = sigmas.length * np.ones(M) if sigmas.relative_length else sigmas.length / latest.length
    prior = ca.vertcat(*[(model.dth[k] - model.g[0]) / sigmas.theta for k in measured],
                       *[(model.dlam[kj] - model.g[1]) / sigmas.lam for kj in model.lam_at],
                       (model.rho - model.g[2]) / ca.DM(s_len), model.g / ca.DM(systematic_sigmas))
    prior_fn, prior_jac = ca.Function("prior", [model.z], [prior]), ca.Function("prior_J", [model.z], [ca.jacobian(prior, model.z)])
    z = np.zeros(model.n)
    if start is not None:  # the previous round's deviations and systematic parts
        z = _pack(model, start, start_systematic)
    z = np.clip(z, *model.bounds)
    devs = _deviations(z, model, latest, lambda_min)
    iters, status, done, moved = 0, "optimal", 0, np.inf
    for _ in range(rounds):
        done += 1
        pairs = _pairs(builds, devs, states, measurements, D)
        fun, jac = _least_squares(model, measurements, pairs, 1.0 / measurement_sigma, prior_fn, prior_jac)
        with blas.limited():
            sol = least_squares(fun, z, jac=jac, bounds=model.bounds, method="trf", xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200)
        z, iters, status = sol.x, iters + sol.nfev, "optimal" if sol.status > 0 else "max_iter"
        devs = _deviations(z, model, latest, lambda_min)
        new = _pairs(builds, devs, states, measurements, D)
        moved = max(float(np.max(np.abs(a.l - b.l))) for a, b in zip(new, pairs))
        if moved < 1e-3 * D:
            break
    with blas.limited():  # the Laplace approximation: the Gauss-Newton Hessian's inverse
        J = jac(z)
        sd = np.sqrt(np.maximum(np.diag(np.linalg.pinv(J.T @ J)), 0.0))
    ab = realized(latest, devs)
    std = {n: np.column_stack([np.zeros((M, 2)), ab.length * sd[model.rho_idx]]) for n in latest.names}
    for k, at in model.th_idx.items():
        std[latest.names[k]][:, 0] = sd[at]
    for (k, j), i in zip(model.lam_at, model.lam_idx):
        std[latest.names[k]][j, 1] = sd[i]
    # the clip at 1 hides how far beyond it an actuator's error goes: hold what may be clipped
    devs = [replace(d, held=actuated(latest.lam[k]) & (ab.lam[k] >= 1.0 - settings.HELD_SIGMAS * std[latest.names[k]][:, 1]))
            for k, d in enumerate(devs)]
    final = _pairs(builds, devs, states, measurements, D)
    resid = [np.linalg.norm(pr.point - m.points, axis=1) for m, pr in zip(measurements, final)]
    g, sg = z[model.n - 3:], sd[model.n - 3:]
    return Estimate(routing=ab, deviations=devs, systematic=np.array([g[0], g[1], math.exp(g[2])]),
                    systematic_std=np.array([sg[0], sg[1], math.exp(g[2]) * sg[2]]), std=std, transform=np.eye(4), residuals=resid,
                    status=status, iterations=iters, solve_time_s=time.perf_counter() - t0, rounds=done,
                    stats={"measurement_sigma": measurement_sigma, "points": N, "builds": len(builds),
                           "measured": [latest.names[k] for k in measured], "free_pose": False, "pairs_moved": moved})


def _least_squares(model: _Model, measurements, pairs, weight, prior_fn, prior_jac):
    """(residuals, Jacobian) of one ICP round as functions of z: every measurement's at its pairs, then the prior."""

    def fun(z):
        return np.concatenate([model.residuals(z, m, pr, weight) for m, pr in zip(measurements, pairs)] + [np.asarray(prior_fn(z)).ravel()])

    def jac(z):
        return np.vstack([model.residuals(z, m, pr, weight, jacobian=True) for m, pr in zip(measurements, pairs)] + [np.asarray(prior_jac(z))])

    return fun, jac


def _pairs(builds, devs, states, measurements, D) -> list:
    """Each measurement's pairs with its state's line on its build as the deviations realize it."""
    out, made = [], {}
    for m in measurements:
        b = m.build % len(builds)
        if b not in made:
            made[b] = realized(builds[b], devs)
        lines = made[b]
        out.append(pair_with_line(m.points, Routing(theta=lines.theta[0], lam=lines.lam[0], length=lines.length), D, LINE_SIDE[m.line],
                                  line=state_line(lines, D, states[m.state], m.state)))
    return out


def line_problem(problem: ActuatorsProblem, k: int) -> DesignProblem:
    """Actuator k's one-actuator problem (its bounds and kind, the tube's options): the rules of one line."""
    return DesignProblem(problem.name, problem.diameter, next(iter(problem.targets.values())), problem.actuators[k].actuator,
                         problem.options, units=problem.units)


def correct_lines(problem: ActuatorsProblem, est: Estimate, built: Lines, adjust=("lambda",), theta_trust: float = 0.0):
    """(nominal Lines to build next, what they realize, status, stats) (module docstring)."""
    ab, devs, measured = est.routing, est.deviations, [built.names.index(n) for n in est.stats["measured"]]
    bounds = {}
    for k in range(built.count):
        if k not in measured:
            continue
        one = line_problem(problem, k)
        lam = lambda_bounds(one, Routing(theta=built.theta[k], lam=built.lam[k], length=built.length), replace(devs[k], lambda_min=one.actuator.lambda_min))
        th = (ab.theta[k], ab.theta[k])
        if "theta" in adjust:  # up to the line's last actuator (beyond it theta would only turn the line pointlessly)
            a, after = one.actuator.theta_max, np.arange(built.segments) > np.flatnonzero(actuated(built.lam[k])).max()
            th = (np.maximum(-a + devs[k].theta, ab.theta[k] - theta_trust), np.minimum(a + devs[k].theta, ab.theta[k] + theta_trust))
            th = tuple(np.where(after, ab.theta[k], v) for v in th)
        bounds[k] = th, lam
    real, status, stats = correction_nlp(problem, ab, bounds)
    theta, lam = built.theta.copy(), built.lam.copy()
    for k in measured:
        r = Routing(theta=real.theta[k], lam=real.lam[k], length=real.length, initial_pose=real.initial_pose)
        nom = remove_deviations(r, devs[k], actuated(built.lam[k]))
        lam[k] = nom.lam
        if "theta" in adjust:
            theta[k] = nom.theta
    nominal = Lines(built.names, theta, lam, built.phi0, built.length, built.initial_pose)
    return nominal, realized(nominal, devs), status, stats


def correct_several(problem: ActuatorsProblem, builds: list, measurements: list, *, adjust=None, sigmas: Sigmas | None = None,
                    measurement_sigma: float = 0.1, start=None, start_systematic=None) -> CorrectionResult:
    """Estimate the robot built last from ``builds`` (nominal Lines, oldest first) and correct it on both routes, taking
    ``adjust`` (None: the recommended one, ``correction.recommend``), no file I/O; a ``CorrectionResult`` whose runs are
    ``ActuatorsResult``s."""
    t0, sigmas = time.perf_counter(), sigmas or Sigmas.from_degrees(1.0, 0.02, 0.02)
    lmin = [a.actuator.lambda_min for a in problem.actuators]
    est = estimate_lines(builds, measurements, problem.states, problem.diameter, sigmas, lmin, measurement_sigma, start=start,
                         start_systematic=start_systematic)
    ab = evaluate(problem, est.routing, "as_built", status=est.status, solve_time_s=est.solve_time_s, iterations=est.iterations,
                  stats=dict(est.stats) | {"icp_rounds": est.rounds})
    d = np.concatenate(est.residuals)
    ab.metrics |= {"target_rmse": ab.metrics["rmse"], "target_max_error": ab.metrics["max_error"], "rmse": float(np.sqrt(np.mean(d**2))),
                   "max_error": float(d.max())}
    ab.shortfall = ()
    routes = {",".join(r): _route(problem, est, builds[-1], r, settings.THETA_TRUST * sigmas.theta) for r in ADJUST}
    ab.stats["total_time_s"] = time.perf_counter() - t0
    return recommend(CorrectionResult(builds[-1], ab, None, est, list(measurements), (), routes), adjust)


def _route(problem: ActuatorsProblem, est: Estimate, built: Lines, adjust, trust: float):
    """One route's correction (an ActuatorsResult: the nominal to build, its predicted shapes), judged by
    ``correction_missed`` per measured actuator."""
    t1 = time.perf_counter()
    nominal, pred, status, st = correct_lines(problem, est, built, adjust, trust)
    res = evaluate(problem, pred, "corrected", status=status, iterations=st.pop("iterations"),
                   stats=st | {"adjust": ",".join(adjust), "shape": "predicted as built", "states": {s: list(a) for s, a in problem.states.items()}})
    res.lines, res.routing = nominal, standard_routing(nominal)
    res.shortfall = () if res.converged else (f"the correction did not converge ({status})",)
    for k, name in enumerate(nominal.names):
        if name in est.stats["measured"]:
            b = Build.of(line_problem(problem, k))
            one = Routing(theta=nominal.theta[k], lam=nominal.lam[k], length=nominal.length)
            res.shortfall += tuple(f"actuator {name}: not buildable: {line}"
                                   for line in correction_missed(one, built.lam[k], b.D, b.kind, b.lambda_min, b.min_feature, problem.units))
    res.solve_time_s = time.perf_counter() - t1
    return res
