"""A readable summary of a result archive (``vine-nlp show``)."""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.analysis.buildability import POUCH_LAMBDA_MIN, buildability, default_min_feature, digits
from vine_nlp.errors import InputError
from vine_nlp.io.archive import Archive, load_archive
from vine_nlp.io.validate import parse_toml
from vine_nlp.problem import ACTUATOR_KINDS, Actuator, DesignOptions

RUN_ORDER = ("nlp", "greedy", "greedy_filtered", "forward", "fit")
METRICS = ("rmse", "max_error", "r2", "tv_theta", "tv_lambda")
LENGTH_METRICS = ("rmse", "max_error")


def ordered_runs(archive: Archive) -> list[str]:
    """Run names, the known methods first (nlp, greedy, greedy_filtered, forward, fit), then the rest."""
    known = [r for r in RUN_ORDER if r in archive.runs]
    return known + [r for r in archive.runs if r not in known]


def source_table(archive: Archive, table: str) -> dict:
    """A table of the archived problem file's text ({} when absent or unreadable)."""
    try:  # parse_toml refuses control characters: nothing from the text reaches the terminal raw
        value = parse_toml("archive", archive.source or "").get(table, {})
    except InputError:
        return {}
    return value if isinstance(value, dict) else {}


def build_settings(archive: Archive) -> dict:
    """The buildability report's settings from the archived problem file (defaults where absent or not valid):
    kind, lambda_min, margin, min_feature, base_free."""
    act, des = source_table(archive, "actuator"), source_table(archive, "design")

    def number(table, key, default):
        v = table.get(key)
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 else default

    kind = act.get("kind") if act.get("kind") in ACTUATOR_KINDS else Actuator.kind
    mf = number(des, "min_feature", default_min_feature(archive.units))
    return {"kind": kind, "lambda_min": number(act, "lambda_min", 0.5 if kind == "spam" else Actuator.lambda_min),
            "margin": number(des, "correction_margin", DesignOptions.correction_margin), "min_feature": mf,
            "base_free": des.get("base") != "fixed"}


def _build_lines(a: Archive, routing) -> list[str]:
    """What ``show`` says of a run's buildability (analysis.buildability)."""
    b, u = build_settings(a), a.units
    with np.errstate(all="ignore"):
        rep = buildability(routing, a.diameter, **b)
    on = [p for p in rep.pieces if p.actuated]
    spans = ", ".join(f"{p.start}-{p.stop - 1}" for p in on[:6]) + (", ..." if len(on) > 6 else "")
    lines = [f"  actuated    {len(on)} piece(s) (segments {spans or '-'}), {sum(p.stop - p.start for p in rep.pieces if not p.actuated)}"
             " segment(s) without an actuator (lambda = 1)"]
    parts = rep.parts
    if "pouches" in parts:
        made = [f"{c} x {_num(length)} {u}" for c, length, _ in filter(None, parts["pouches"])]
        lines.append(f"  pouches     {', '.join(made) or '-'} (ideal pouch motor)" + "".join(f"; refused: {r}" for r in rep.refused))
    elif "pinches" in parts:
        lines.append(f"  pinches     {len(parts['pinches'])}")
    else:
        lines.append(f"  stoppers    {len(parts['stoppers'])}, tendon(s) {', '.join(_num(t) for t in parts['tendons']) or '-'} {u}")
    turns = [v / (2 * math.pi) for v in (rep.turning, rep.turning_unactuated, rep.turning_needed)]
    lines.append(f"  line turns  {turns[0]:.3g} in all, {turns[1]:.3g} where lambda = 1 (the routing needs {turns[2]:.3g} there)")
    if rep.smallest:
        v, mf = rep.smallest[0], rep.min_feature
        lines.append(f"  smallest    {digits(v, mf)} {u} {rep.smallest[1]} ({len(rep.below)} below min_feature {digits(mf, v)} {u})")
    if rep.violations:
        lines.append(f"  margin      {len(rep.violations)} segment(s) with lambda neither 1 nor in "
                     f"[{_num(b['lambda_min'] + b['margin'])}, {_num(1 - b['margin'])}]")
    lam = np.asarray(routing.lam, float)
    near = (lam != 1.0) & (lam > 1.0 - b["margin"])  # exactly 1 is no actuator (the design's rule); just below is one
    if near.any():
        turn = float(np.abs(2.0 / a.diameter * np.tan(routing.theta) * routing.length)[near].sum()) / (2 * math.pi)
        lines.append(f"  near 1      {int(near.sum())} segment(s) with lambda in (1 - margin, 1), not 1: an actuator that "
                     f"barely contracts; the line turns {turn:.3g} there")
    return lines


def build_warnings(a: Archive, run: str) -> list[str]:
    """What a template of ``run`` draws that the design's own rules refuse (analysis.buildability, judged as ``show``
    judges it): features below min_feature, lambda outside the margin band; one line, or none."""
    b = build_settings(a)
    with np.errstate(all="ignore"):
        rep = buildability(a.runs[run].routing, a.diameter, **b)
    out = []
    if rep.below:
        length, name, _ = rep.smallest
        out.append(f"{len(rep.below)} feature(s) below min_feature {digits(rep.min_feature, length)} {a.units} "
                   f"(smallest: {digits(length, rep.min_feature)} {a.units} {name})")
    if rep.violations:
        out.append(f"{len(rep.violations)} segment(s) with lambda neither 1 nor in [{_num(b['lambda_min'] + b['margin'])}, "
                   f"{_num(1 - b['margin'])}]")
    return [f"run {run}: not buildable as drawn: " + "; ".join(out)] if out else []


def _levels(path) -> list[str]:
    """One line per level of a multi-shape archive: its lambda, fixed or designed, its RMSE, and whether an sPAM
    can hold it with room to correct (inside [max(lambda_min, 2/pi) + margin, 1 - margin])."""
    from vine_nlp.io.formulations import read_multishape_archive
    a, r, _ = read_multishape_archive(path)
    b = build_settings(a)
    lo, hi = max(b["lambda_min"], POUCH_LAMBDA_MIN) + b["margin"], 1.0 - b["margin"]
    out = []
    for k, (lam, fixed, m) in enumerate(zip(r.levels, r.fixed, r.level_metrics)):
        room = "" if lo - 1e-9 <= lam <= hi + 1e-9 else f"; outside [{_num(lo)}, {_num(hi)}]: no room to correct"
        out.append(f"  level {k:<5d} lambda {_num(float(lam))} ({'fixed' if fixed else 'free'}), "
                   f"rmse {_num(m.get('rmse', math.nan))} {a.units}{room}")
    return out


def _actuator_lines(path, run: str, a: Archive) -> list[str]:
    """Several actuators on one tube (io.actuators): per actuator its angles, pieces, stoppers and turning (the
    line alone, as one actuator's routing); per state its active actuators and RMSE."""
    from vine_nlp.io.actuators import read_actuators_archive
    _, r, _ = read_actuators_archive(path, run)
    ls, out = r.lines, []
    for k, name in enumerate(ls.names):
        out += [f"  actuator {name}: starts at phi = {_num(math.degrees(ls.phi0[k]))} deg around the tube",
                f"  theta       {_range(np.round(np.degrees(ls.theta[k]), 4))} deg", f"  lambda      {_range(np.round(ls.lam[k], 6))}"]
        out += _build_lines(a, ls.routing(k))
    for s, active in r.stats["states"].items():
        m = r.state_metrics.get(s)
        out.append(f"  state {s} ({', '.join(active)})" + (f": RMSE {_num(m['rmse'])} {a.units}, max error {_num(m['max_error'])} {a.units}" if "rmse" in (m or {}) else ""))
    return out


def _num(v: float) -> str:
    return f"{v:.6g}"


def _range(values: np.ndarray) -> str:
    """"a to b"; an Archive built in Python (not loaded, so not validated) may hold NaN: say so."""
    bad = int(np.count_nonzero(~np.isfinite(values)))
    if bad:
        return f"{bad} of {values.size} values not finite"
    return f"{_num(values.min() + 0.0)} to {_num(values.max() + 0.0)}"  # + 0.0: no -0


def summarize(archive, path=None) -> str:
    """Multi-line summary of an archive (an Archive, or a path loaded and so validated by ``load_archive``: an
    InputError when missing or invalid): problem, software, target, and every run; a multi-shape run's every level
    and an archive of several actuators' lines and states (read from the file: ``path``, or ``archive`` given as a path)."""
    a = archive if isinstance(archive, Archive) else load_archive(archive)
    path = archive if path is None and not isinstance(archive, Archive) else path
    u = a.units
    lines = [f"problem   {a.name} ({a.kind})"]
    kind = source_table(a, "actuator").get("kind")
    tube = f"tube      D = {_num(a.diameter)} {u}, units {u}" + (f", actuator {kind}" if isinstance(kind, str) else "")
    lines += [tube, f"software  vine_nlp {a.software_version}, format {a.format_version}, created {a.created or '-'}"]
    if a.target is not None:
        t = np.asarray(a.target)
        chord = float(np.linalg.norm(np.diff(t, axis=0), axis=1).sum()) if len(t) > 1 else 0.0
        lines.append(f"target    {len(t)} points, length {_num(chord)} {u}")
    for key, value in a.extra.items():
        lines.append(f"{key:<9s} {np.shape(value)[0]} rows")
    if not a.runs:
        lines.append("runs      none")
    for name in ordered_runs(a):
        r = a.runs[name]
        ro = r.routing
        lines += ["", f"run {name}", f"  method      {r.method}", f"  status      {r.status}", f"  iterations  {r.iterations}",
                  f"  solve time  {r.solve_time_s:.3f} s", f"  segments    {ro.segments}",
                  f"  tube length {_num(float(ro.length.sum()))} {u}"]
        if name == "multishape" and path is not None:
            lines += _levels(path)
        if a.kind.startswith("actuators") and path is not None:
            lines += _actuator_lines(path, name, a)
        elif ro.segments:
            lines.append(f"  theta       {_range(np.round(np.degrees(ro.theta), 4))} deg")  # 1e-4 deg: below any build
            lines.append(f"  lambda      {_range(np.round(ro.lam, 6))}")
            lines += _build_lines(a, ro)
        for m in METRICS:
            if m in r.metrics:
                unit = f" {u}" if m in LENGTH_METRICS else (" rad" if m == "tv_theta" else "")
                lines.append(f"  {m:<11s} {_num(r.metrics[m])}{unit}")
        for m, v in r.metrics.items():
            if m not in METRICS:
                lines.append(f"  {m:<11s} {_num(v)}" + {"collapse_at": f" {u}", "min_pressure": " kPa"}.get(m, ""))
    return "\n".join(lines)
