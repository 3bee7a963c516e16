"""``vine-nlp analyze``: self-collision, growth order, manufacturing tolerance and obstacle gaps of an archived design."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from vine_nlp.analysis.collision import collision_metrics, growth_contacts, helix_collisions, min_clearance, routing_clearance
from vine_nlp.analysis.obstacles import obstacle_report, report_rows
from vine_nlp.analysis.tolerance import tolerance_metrics, tolerance_report, tolerance_summary
from vine_nlp.errors import InputError
from vine_nlp.front.analysis_plots import clearance_figure, tolerance_figure
from vine_nlp.front.files import archive_run, check_figure, read_archive, sigmas, within_limits
from vine_nlp.front.load_plots import analyze_load
from vine_nlp.front.states import line_kinds, picked_states, state_lines, state_rates
from vine_nlp.io import limits
from vine_nlp.io.archive import add_metrics
from vine_nlp.io.archived import archived_problem
from vine_nlp.io.obstacles import DEFAULT_GROWTH, parse_obstacle_design
from vine_nlp.io.validate import parse_toml
from vine_nlp.methods.actuators import arc_pairing, state_arcs
from vine_nlp.model.actuators import Lines, owners, state_shape
from vine_nlp.model.helix import center_rates
from vine_nlp.model.routing import Routing, Sigmas, actuated, built_lambda


def cmd_analyze(args) -> int:
    """Self-collision, growth order and manufacturing tolerance of an archived design."""
    archive = read_archive(args.archive)
    run = archive_run(archive, args.archive, args.run)
    for flag in ("tolerance_figure", "clearance_figure", "load_figure"):
        check_figure(getattr(args, flag), True)
    r = archive.runs[run]
    D, u = archive.diameter, archive.units
    within_limits("analyze", archive, args.archive, [run])
    _check_costs(args, archive, r)
    _print_clearance(routing_clearance(r.routing, D, margin=args.margin), D, u)
    growth = growth_contacts(r.routing, D, margin=args.margin)
    final = [g for g in growth if not g.get("transient")]
    on_way = [g for g in growth if g.get("transient")]
    print(f"growth      grown while actuated: {len(final)} contact(s)"
          + "".join(f"; first at {g['growth_length']:.4g} {u} grown" for g in final[:1])
          + f"; actuated after growth: {len(final) + len(on_way)} contact(s) on the way"
          + ("" if not growth else f" (from t = {min(g['actuation_fraction'] for g in growth):.2f})"))
    print(f"helices     uniform sections of >= 1 turn self-colliding (paper condition): {len(helix_collisions(r.routing, D))}")
    metrics = collision_metrics(r, D, margin=args.margin)
    if archive.obstacles:
        metrics |= _analyze_obstacles(archive, r, u)
    metrics |= analyze_load(archive, args.archive, r.routing, getattr(args, "load_figure", None), f"{archive.name}: {run}")
    figures = []
    if archive.kind == "design" and archive.target is not None:
        problem = archived_problem(archive, args.archive, run)
        sig = sigmas(args)
        rep = tolerance_report(problem, r, sig, samples=args.samples, seed=args.seed)
        _print_tolerance(rep, args, u)
        metrics |= tolerance_metrics(rep)
        if args.tolerance_figure:
            tolerance_figure(rep, args.tolerance_figure, title=f"{archive.name}: {run}")
            figures.append(args.tolerance_figure)
    if args.clearance_figure:
        clearance_figure(r.routing, D, args.clearance_figure, units=u, growth=growth, title=f"{archive.name}: {run}")
        figures.append(args.clearance_figure)
    for f in figures:
        print(f"figure -> {f}")
    if args.write_metrics:
        # archived metrics are finite (archives are validated on read): one that does not apply is left
        # out (first_contact_growth_length of a tube that never touches itself)
        add_metrics(args.archive, run, {k: float(v) for k, v in metrics.items() if math.isfinite(float(v))})
        print(f"metrics -> {args.archive} (/runs/{run}/metrics)")
    return 0


def _print_clearance(cl: dict, D: float, u: str, indent: str = "") -> None:
    if math.isfinite(cl["clearance"]):
        print(f"{indent}clearance   min {cl['clearance']:.4g} {u} ({cl['clearance'] / D:.2f} D) at {cl['l_i']:.4g} / {cl['l_j']:.4g} {u} of tube; "
              f"{len(cl['regions'])} contact region(s)")
    else:  # no two distant parts of the tube come closer than their ends: no closest approach to report
        print(f"{indent}clearance   none to report: the tube never comes back toward itself; 0 contact region(s)")


def _print_tolerance(rep: dict, args, u: str, indent: str = "") -> None:
    fo, mc, nom = rep["first_order"], rep["monte_carlo"], rep["nominal"]
    length = f"{100 * args.sigma_length:g} %" if args.sigma_length_abs is None else f"{args.sigma_length_abs:g} {u}"
    ps = rep["per_segment"]
    share = ps["tip_var"] / max(float(ps["tip_var"].sum()), 1e-300)
    j = int(share.argmax())
    print(f"{indent}tolerance   sigma theta {args.sigma_theta_deg:g} deg, lambda {args.sigma_lambda:g}, length {length} (per segment, independent)\n"
          f"{indent}  rmse      nominal {nom['rmse']:.4g} {u}; first order {fo['rmse']:.4g} {u}; Monte Carlo mean {mc['mean_rmse']:.4g} / rms {mc['rms_rmse']:.4g} {u} ({mc['samples']} samples, seed {mc['seed']})\n"
          f"{indent}  tip       std {fo['tip_std']:.4g} {u} (first order) / {mc['tip_std']:.4g} {u} (Monte Carlo)\n"
          f"{indent}  worst     segment {j} at {ps['l_mid'][j]:.4g} {u} of tube: {100 * share[j]:.0f} % of the tip variance")


def _check_costs(args, archive, r) -> None:
    """The numbers of the command line against what they cost on this design (one line each)."""
    M, total = r.routing.segments, float(r.routing.length.sum())
    if args.samples * M > limits.MAX_DATASET_ELEMENTS:
        raise InputError("command line", "--samples", f"{args.samples} samples of {M} segments: at most {limits.MAX_DATASET_ELEMENTS // M} "
                         f"for this design (samples x segments <= vine_nlp.io.limits.MAX_DATASET_ELEMENTS)")
    if args.margin > total:
        raise InputError("command line", "--margin", f"{args.margin:g} is more than the tube's length {total:.4g} {archive.units}: "
                         "every part of the tube would be in contact with every other")


def _analyze_obstacles(archive, r, u) -> dict:
    """Print the distance to every obstacle along the tube and the contacts, final and intermediate shapes
    (margin and growth from the archived problem's [design]); the run metrics."""
    try:
        design = parse_toml("archive", archive.source).get("design", {})
        margin, growth = parse_obstacle_design(design if isinstance(design, dict) else {}, "archive")
    except InputError:
        margin, growth = 0.0, DEFAULT_GROWTH
    rep = obstacle_report(r.routing, archive.diameter, archive.obstacles, growth, margin)
    print(f"obstacles   {len(archive.obstacles)}; margin {margin:.4g} {u}; growth {growth}; "
          f"min gap {rep['min_gap']:.4g} {u} (final), {rep['min_gap_intermediate']:.4g} {u} (intermediate shapes); "
          + ("clear" if rep["clear"] else "NOT clear"))
    for row in report_rows(rep):
        name = f" '{row['name']}'" if row["name"] else ""
        line = (f"  obstacle {row['index']} {row['kind']}{name}: min gap {row['min_gap']:.4g} {u} at s = {row['s']:.4g} {u}; "
                f"{row['contacts']} contact(s)")
        if growth == "after":
            line += f"; actuated after growth: min gap {row['min_gap_after']:.4g} {u} at t = {row['t_worst']:.2f}"
        elif row["first_contact_length"] is not None:
            line += f"; first contact at {row['first_contact_length']:.4g} {u} grown"
        print(line)
    out = {"min_obstacle_gap": float(rep["min_gap"])}
    if growth == "after":
        out["min_obstacle_gap_after"] = float(rep["min_gap_intermediate"])
    return out


# ---------------------------------------------------------------- several actuators on one tube: each state


def cmd_analyze_states(args) -> int:
    """``analyze`` of an archive of several actuators: every state's (or --state's) self-collision and, where the
    state has a target, its tolerance, printed under the state's name; --write-metrics: the state's metrics."""
    a, run, r, targets, states = picked_states(args.archive, args.run, args.state)
    for flag in ("tolerance_figure", "clearance_figure", "load_figure"):
        if getattr(args, flag, None):
            raise InputError("command line", "--" + flag.replace("_", "-"), "not drawn for an archive of several actuators")
    within_limits("analyze", a, args.archive, [run])
    _check_costs(args, a, r)
    ls, D, u = r.lines, a.diameter, a.units
    written = {}
    for s, active in states.items():
        print(f"state {s} ({', '.join(active)})")
        written[s] = state_collision(ls, D, active, s, args.margin, u)
        if s in targets:
            seg, frac = arc_pairing(targets[s], state_arcs(ls, D, active))
            lmin = [m for _, m in line_kinds(a, ls.count)]
            rep = state_tolerance(ls, D, active, s, targets[s], seg, frac, sigmas(args), lmin, args.samples, args.seed)
            _print_tolerance(rep, args, u, "  ")
            written[s] |= tolerance_metrics(rep)
    if args.write_metrics:
        for s, m in written.items():  # /runs/<run>/states/<state>/metrics, beside the state's rmse and max_error
            add_metrics(args.archive, f"{run}/states/{s}", {k: float(v) for k, v in m.items() if math.isfinite(float(v))})
        print(f"metrics -> {args.archive} (/runs/{run}/states/<state>/metrics)")
    return 0


def state_collision(ls: Lines, D: float, active, state: str, margin: float = 0.0, u: str = "") -> dict:
    """Print and return (collision_metrics' keys) the self-collision of one state: min_clearance of its center line
    (sampled as export samples it, s its actuated arc length), contacts in growth order, the paper's helices."""
    th, lam = state_rates(ls, owners(ls, active, state))
    seg, frac, shape, _ = state_lines(ls, D, active, state)
    arc = ls.length * center_rates(th, lam, D)[2]
    s = np.r_[0.0, np.cumsum(arc)][seg] + frac * arc[seg]
    l = np.r_[0.0, np.cumsum(ls.length)][seg] + frac * ls.length[seg]
    cl = min_clearance(shape.center, D, s=s, margin=margin)
    cl["l_i"], cl["l_j"] = (float(np.interp(cl[k], s, l)) for k in ("s_i", "s_j"))
    grown = sorted(float(np.interp(cl["s"][g["pairs"][:, 1]].min(), s, l)) for g in cl["regions"])
    _print_clearance(cl, D, u, "  ")
    print(f"  growth      grown while actuated: {len(grown)} contact(s)" + "".join(f"; first at {g:.4g} {u} grown" for g in grown[:1]))
    helices = helix_collisions(Routing(theta=th, lam=lam, length=ls.length), D)
    print(f"  helices     uniform sections of >= 1 turn self-colliding (paper condition): {len(helices)}")
    return {"min_clearance": float(cl["clearance"]), "contacts": float(len(grown)), "first_contact_growth_length": grown[0] if grown else math.nan}


def state_tolerance(ls: Lines, D: float, active, state: str, target, seg, frac, sig: Sigmas, lambda_min, samples: int = 2000,
                    seed: int = 0) -> dict:
    """:func:`vine_nlp.analysis.tolerance.tolerance_report` of one state, its points at (seg, frac) paired with
    ``target``: every line's theta (on every segment: it moves the line around the tube) and lambda (where the line
    has an actuator) and the shared lengths err, per segment, independently. First order: the model's state shape
    differentiated by central differences (steps 1e-6 rad, 1e-6, 1e-6 of a length); Monte Carlo by the physical
    rule (model.routing.built_lambda, ``lambda_min`` per line)."""
    K, M = ls.count, ls.segments
    n = 2 * K + 1  # per segment: theta of each line, lambda of each line, the length
    q0 = np.column_stack([ls.theta.T, ls.lam.T, ls.length])

    def at(q):
        return state_shape(replace(ls, theta=q[:, :K].T, lam=q[:, K:2 * K].T, length=q[:, 2 * K]), D, active, seg, frac, state).center

    per = sig.per_segment(ls.length)
    sd = np.column_stack([np.repeat(per[:, :1], K, axis=1), per[:, 1:2] * actuated(ls.lam.T), per[:, 2]])  # (M, n)
    pts = at(q0)
    J = np.zeros((len(seg), 3, M * n))
    for c in np.flatnonzero(sd.ravel() > 0):
        h = np.zeros(M * n)
        h[c] = 1e-6 * (q0.flat[c] if c % n == 2 * K else 1.0)
        J[:, :, c] = (at(q0 + h.reshape(M, n)) - at(q0 - h.reshape(M, n))) / (2 * h[c])
    dq = np.random.default_rng(seed).standard_normal((samples, M, n)) * sd
    built = q0 + dq
    built[..., K:2 * K] = built_lambda(ls.lam.T, dq[..., K:2 * K], np.asarray(lambda_min, float))
    P = np.stack([at(q) for q in built])
    return tolerance_summary(pts, J * sd.ravel(), target, P, ls.length, sig, "", seed, kinds=[0] * K + [1] * K + [2])
