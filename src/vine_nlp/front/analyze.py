"""``vine-nlp analyze``: self-collision, growth order, manufacturing tolerance and obstacle gaps of an archived design."""

from __future__ import annotations

import math

from vine_nlp.analysis.collision import collision_metrics, growth_contacts, helix_collisions, routing_clearance
from vine_nlp.analysis.obstacles import obstacle_report, report_rows
from vine_nlp.analysis.tolerance import tolerance_metrics, tolerance_report
from vine_nlp.errors import InputError
from vine_nlp.front.analysis_plots import clearance_figure, tolerance_figure
from vine_nlp.front.files import archive_run, check_figure, read_archive, sigmas, within_limits
from vine_nlp.front.load_plots import analyze_load
from vine_nlp.io import limits
from vine_nlp.io.archive import add_metrics
from vine_nlp.io.archived import archived_problem
from vine_nlp.io.obstacles import DEFAULT_GROWTH, parse_obstacle_design
from vine_nlp.io.validate import parse_toml


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
    cl = routing_clearance(r.routing, D, margin=args.margin)
    if math.isfinite(cl["clearance"]):
        print(f"clearance   min {cl['clearance']:.4g} {u} ({cl['clearance'] / D:.2f} D) at {cl['l_i']:.4g} / {cl['l_j']:.4g} {u} of tube; "
              f"{len(cl['regions'])} contact region(s)")
    else:  # no two distant parts of the tube come closer than their ends: no closest approach to report
        print("clearance   none to report: the tube never comes back toward itself; 0 contact region(s)")
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
        fo, mc, nom = rep["first_order"], rep["monte_carlo"], rep["nominal"]
        length = f"{100 * args.sigma_length:g} %" if args.sigma_length_abs is None else f"{args.sigma_length_abs:g} {u}"
        print(f"tolerance   sigma theta {args.sigma_theta_deg:g} deg, lambda {args.sigma_lambda:g}, length {length} (per segment, independent)")
        print(f"  rmse      nominal {nom['rmse']:.4g} {u}; first order {fo['rmse']:.4g} {u}; Monte Carlo mean {mc['mean_rmse']:.4g} / rms {mc['rms_rmse']:.4g} {u} ({mc['samples']} samples, seed {mc['seed']})")
        print(f"  tip       std {fo['tip_std']:.4g} {u} (first order) / {mc['tip_std']:.4g} {u} (Monte Carlo)")
        ps = rep["per_segment"]
        share = ps["tip_var"] / max(float(ps["tip_var"].sum()), 1e-300)
        j = int(share.argmax())
        print(f"  worst     segment {j} at {ps['l_mid'][j]:.4g} {u} of tube: {100 * share[j]:.0f} % of the tip variance")
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


