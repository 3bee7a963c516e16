"""A start around the obstacles: the target (or a chain) pushed out of them and designed by the plain NLP.

A design through an obstacle is a poor start for the rows: IPOPT spends most of its iterations pushing the tube out. The
target is pushed out of the obstacles across itself (:func:`pushed_target`): past a primitive along the distance
gradient, a run of points through one obstacle to one side; through a mesh, a run along ONE direction across its chord,
of settings.PUSH_DIRECTIONS the one with the least total push (sphere tracing on the exact signed distance: the shortest
way round; a gradient push sent the tube round the long way). The plain NLP designs that from its own geometric guess,
and the rows start from its chain. Without a mesh, where that chain still does not clear (it cannot follow the pushed
target's corners), its own points are pushed out the same way and designed once more (settings.REPUSH): a curve the
model can follow, pushed. The start is a function of the problem alone, and so is the design (the obstacle-free design
decides only whether there is anything to do, the samples per segment and which primitives get slots: discrete choices
that a tiny change of it leaves alone). Started from the obstacle-free design, which may cross a mesh deeper than a
solve moves a frame, the first solve's rows contradicted each other and the rounds took routes that changed with a
change of 1e-8 in the start."""

from __future__ import annotations

import dataclasses

import numpy as np

from vine_nlp.analysis.obstacles import sample_chain
from vine_nlp.methods import settings
from vine_nlp.methods.common import pair_points
from vine_nlp.methods.nlp import solve_from
from vine_nlp.methods.obstacles.plan import Plan
from vine_nlp.model.obstacles import Mesh
from vine_nlp.problem import DesignOptions, DesignProblem, Routing, TipProblem


def push_need(plan: Plan) -> float:
    """Center distance (units) a pushed start clears by: D/2 + margin + settings.PUSH_EXTRA D (settings.MESH_PUSH_EXTRA with a mesh)."""
    return plan.D * (0.5 + (settings.MESH_PUSH_EXTRA if plan.has_mesh else settings.PUSH_EXTRA)) + plan.margin


def _march(obstacle, p, w, need: float, tmax: float) -> np.ndarray:
    """Per row of p, the first t >= 0 with signed distance(p + t w) >= need (a hair beyond: a second pass
    finds the point clear), sphere tracing along w: the signed distance is 1-Lipschitz, so a step of
    need - distance never passes that point; at most tmax."""
    t = np.zeros(len(p))
    act = np.ones(len(p), bool)
    tol = 1e-6 * tmax
    for _ in range(settings.MARCH_STEPS):
        idx = np.flatnonzero(act)
        if not idx.size:
            break
        step = need + tol - np.asarray(obstacle.distance(p[idx] + t[idx, None] * w[idx]), float).reshape(-1)
        go = step > 0
        t[idx[go]] += step[go] + tol
        act[idx[~go]] = False
        act &= t < tmax
    return np.minimum(t, tmax)


def _across(p: np.ndarray, i0: int, i1: int) -> np.ndarray:
    """settings.PUSH_DIRECTIONS unit directions across the chord of the run p[i0:i1] (from the point before it to the
    point after it), evenly round it: a set that a mirror image of the run maps onto itself."""
    c = p[min(i1, len(p) - 1)] - p[max(i0 - 1, 0)]
    c /= max(float(np.linalg.norm(c)), 1e-300)
    e1 = np.cross(c, [1.0, 0.0, 0.0] if abs(c[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    ang = 2 * np.pi * np.arange(settings.PUSH_DIRECTIONS) / settings.PUSH_DIRECTIONS
    return np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * np.cross(c, e1)


def _fewer_push(obstacle, q: np.ndarray, own: np.ndarray, need: float, tmax: float) -> np.ndarray:
    """The directions that push the run ``q`` out of ``obstacle`` least in all (the sum of :func:`_march`):
    each point along its ``own`` direction, or ONE direction across the run's chord (:func:`_across`) for
    all. The side of the obstacle is chosen by geometry, the shortest way round: a run beside a slot's wall
    whose end points' outward directions point round the wall's far edge (their gradient off the wall's end
    faces, the target's tangent taken out) goes back into the slot as its middle does, not 20 cm round."""
    n = len(q)
    W = _across(np.vstack([q[:1], q, q[-1:]]), 1, n + 1)
    t = _march(obstacle, np.tile(q, (settings.PUSH_DIRECTIONS, 1)), np.repeat(W, n, axis=0), need, tmax).reshape(settings.PUSH_DIRECTIONS, n)
    k = int(np.argmin(t.sum(axis=1)))
    if t[k].sum() < _march(obstacle, q, np.ascontiguousarray(own), need, tmax).sum():
        return np.broadcast_to(W[k], q.shape)
    return own


def _push_mesh(p: np.ndarray, mesh: Mesh, d: np.ndarray, need: float) -> np.ndarray:
    """Every run of points closer than ``need`` to ``mesh`` (``d``: their signed distances) moved out along
    ONE direction across the run's chord: of settings.PUSH_DIRECTIONS directions around it, the one whose pushes
    (each point the least that clears it, :func:`_march`) sum least over settings.PUSH_PROBES points of the run,
    the shortest way round the mesh. It depends on the target and the mesh alone, never on a design."""
    p = p.copy()
    lo, hi = mesh.bounds()
    tmax = float(np.linalg.norm(hi - lo)) + 2 * need
    m = np.concatenate([[False], d < need, [False]]).astype(int)
    for i0, i1 in zip(np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)):
        W = _across(p, i0, i1)
        probe = p[np.unique(np.linspace(i0, i1 - 1, settings.PUSH_PROBES).round().astype(int))]
        n = len(probe)
        t = _march(mesh, np.tile(probe, (settings.PUSH_DIRECTIONS, 1)), np.repeat(W, n, axis=0), need, tmax).reshape(settings.PUSH_DIRECTIONS, n)
        w = W[int(np.argmin(t.sum(axis=1)))]
        q = p[i0:i1]
        p[i0:i1] = q + _march(mesh, q, np.broadcast_to(w, q.shape), need, tmax)[:, None] * w
    return p


def pushed_target(target: np.ndarray, obstacles, need: float, passes: int = settings.PUSH_PASSES) -> np.ndarray:
    """The target with every point closer than ``need`` (center distance, units) to an obstacle moved out across the
    target: along the distance gradient with its component along the target's tangent taken out (a target through an
    obstacle is pushed to one side of it, not back along itself), a run of points through one obstacle to ONE side
    (their mean direction) unless their directions cancel (a run along the obstacle, a helix round a cylinder: each
    point along its own); a run through a mesh along the one direction across its chord that pushes least
    (:func:`_push_mesh`); repeated ``passes`` times (a point pushed out of one obstacle may land in another)."""
    p = np.array(target, float)
    span = float(np.ptp(p, axis=0).max())

    def tmax(ob):  # no push goes farther than across the target and the obstacle's box (a plane's is unbounded)
        box = ob.bounds()
        size = float(np.linalg.norm(np.subtract(box[1], box[0]))) if box is not None else span
        return span + size + 2 * need

    tan = np.gradient(p, axis=0)
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-300)
    h = 1e-6 * max(1.0, float(np.ptp(p)))
    for _ in range(passes):
        moved = False
        for ob in obstacles:
            d = np.asarray(ob.distance(p), float).reshape(-1)
            low = d < need
            if not low.any():
                continue
            moved = True
            if isinstance(ob, Mesh):
                p = _push_mesh(p, ob, d, need)
                continue
            g = np.zeros_like(p)
            q = p[low]  # the gradient only where a point moves (a mesh's distance is not cheap)
            steps = np.concatenate([q + h * e for e in np.eye(3)] + [q - h * e for e in np.eye(3)])
            f = np.asarray(ob.distance(steps), float).reshape(6, -1)
            g[low] = ((f[:3] - f[3:]) / (2 * h)).T
            g -= np.sum(g * tan, axis=1, keepdims=True) * tan
            m = np.concatenate([[False], low, [False]]).astype(int)
            for i0, i1 in zip(np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)):
                run = slice(i0, i1)
                gn = np.linalg.norm(g[run], axis=1)
                w = g[run].mean(axis=0)
                n = float(np.linalg.norm(w))
                if n >= 0.5 * float(gn.mean()) and n > 1e-12:  # a pass through the obstacle: all to one side
                    dirs = np.broadcast_to(w / n, g[run].shape)
                elif np.all(gn > 1e-12):  # a run along the obstacle (a helix round a cylinder): each point outward,
                    # unless one side pushes less in all (a run beside a wall whose ends point round its far edge)
                    dirs = _fewer_push(ob, p[run], g[run] / gn[:, None], need, tmax(ob))
                else:  # dead center: any side across the tangent
                    w = np.cross(tan[i0], [0.0, 0.0, 1.0] if abs(tan[i0, 2]) < 0.9 else [1.0, 0.0, 0.0])
                    dirs = np.broadcast_to(w / np.linalg.norm(w), g[run].shape)
                # each point the least along its direction that clears this obstacle (sphere tracing on the
                # exact signed distance): a Newton step overshot where the push runs along the surface
                # (beside a slot's wall: through the slot and the far wall)
                p[run] += _march(ob, p[run], np.ascontiguousarray(dirs), need, tmax(ob))[:, None] * dirs
        if not moved:
            break
    return p


def pushed_start(problem: DesignProblem, plan: Plan) -> Routing:
    """A start around the obstacles: the plain design of the pushed target (:func:`pushed_target`, center distance D/2 +
    margin + settings.PUSH_EXTRA D, settings.MESH_PUSH_EXTRA with a mesh) from its own geometric guess, to
    settings.PUSH_TOL; without a mesh, where it does not clear, the plain design of its own chain pushed out
    (settings.REPUSH times); a function of the problem alone (module docstring, "Start")."""
    need = push_need(plan)
    tg, passes = problem.target, 0 if plan.has_mesh else settings.REPUSH
    # the exact Hessian from the start: Gauss-Newton does not converge on a pushed target's corners, and
    # "auto" then solves the same start again with it (the same design, ~100 Gauss-Newton iterations later)
    method = settings.Method.of(problem.options)
    method = method.with_(hessian="exact") if method.hessian == "auto" else method
    method = method.with_(tol=max(method.tol, settings.PUSH_TOL))
    for k in range(passes + 1):
        tg = pushed_target(tg, problem.obstacles, need)
        res = solve_from(dataclasses.replace(problem, target=tg, obstacles=()), None,
                         pair_points(tg, problem.options.points_per_segment), frames="target", method=method)
        if k == passes or plan.report(res.routing)["min_gap"] >= plan.margin:
            break
        # the chain cuts an obstacle where it could not follow the pushed target's corners: push the
        # chain itself (a curve the model follows) and design that
        tg = np.asarray(res.shape.center, float)
    return res.routing


def pushed_chain(problem: TipProblem, plan: Plan, routing: Routing) -> Routing:
    """A tip problem's start around the obstacles: the chain of ``routing`` pushed out of them
    (:func:`pushed_target`, as the design's pushed start) and followed by the plain design of as many
    segments, from the problem's base pose. A chain through an obstacle's center gives its rows no
    direction out (the distance's gradient vanishes there); the push picks a side."""
    D, n = problem.diameter, DesignOptions().points_per_segment
    tg = pushed_target(sample_chain(routing, D, n)["points"], problem.obstacles, push_need(plan))
    fit = DesignProblem(problem.name, D, tg, problem.actuator, DesignOptions(points_per_segment=n, hessian="exact"), problem.units)
    r = solve_from(fit, None, pair_points(tg, n), frames="target").routing
    return Routing(theta=r.theta, lam=r.lam, length=r.length, initial_pose=routing.initial_pose)
