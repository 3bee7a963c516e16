"""A readable summary of a result archive (``vine-nlp show``)."""

from __future__ import annotations

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.io.archive import Archive, load_archive
from vine_nlp.io.validate import parse_toml

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


def _num(v: float) -> str:
    return f"{v:.6g}"


def _range(values: np.ndarray) -> str:
    """"a to b"; an Archive built in Python (not loaded, so not validated) may hold NaN: say so."""
    bad = int(np.count_nonzero(~np.isfinite(values)))
    if bad:
        return f"{bad} of {values.size} values not finite"
    return f"{_num(values.min())} to {_num(values.max())}"


def summarize(archive) -> str:
    """Multi-line summary of an archive (an Archive or a path): problem, software, target, and every run.

    Parameters
    ----------
    archive : Archive or path-like
        A path is loaded (and so validated) with :func:`vine_nlp.io.archive.load_archive`.

    Returns
    -------
    str

    Raises
    ------
    InputError
        For a path whose archive is missing or invalid.
    """
    a = archive if isinstance(archive, Archive) else load_archive(archive)
    u = a.units
    lines = [f"problem   {a.name} ({a.kind})"]
    kind = source_table(a, "actuator").get("kind")
    tube = f"tube      D = {_num(a.diameter)} {u}, units {u}"
    if isinstance(kind, str):
        tube += f", actuator {kind}"
    lines.append(tube)
    lines.append(f"software  vine_nlp {a.software_version}, format {a.format_version}, created {a.created or '-'}")
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
        lines.append("")
        lines.append(f"run {name}")
        lines.append(f"  method      {r.method}")
        lines.append(f"  status      {r.status}")
        lines.append(f"  iterations  {r.iterations}")
        lines.append(f"  solve time  {r.solve_time_s:.3f} s")
        lines.append(f"  segments    {ro.segments}")
        lines.append(f"  tube length {_num(float(ro.length.sum()))} {u}")
        if ro.segments:
            lines.append(f"  theta       {_range(np.degrees(ro.theta))} deg")
            lines.append(f"  lambda      {_range(ro.lam)}")
        for m in METRICS:
            if m in r.metrics:
                unit = f" {u}" if m in LENGTH_METRICS else (" rad" if m == "tv_theta" else "")
                lines.append(f"  {m:<11s} {_num(r.metrics[m])}{unit}")
        for m, v in r.metrics.items():
            if m not in METRICS:
                lines.append(f"  {m:<11s} {_num(v)}")
    return "\n".join(lines)
