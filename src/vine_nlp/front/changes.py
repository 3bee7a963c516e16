"""What changes from the robot that was built to the corrected one (``vine-nlp template ... --changes``).

A correction archive (``vine_nlp.io.correction``) holds the nominal of every build in ``/correction/builds/<b>``; the
last one is what was built and measured. For each segment whose lambda (or theta) differs in the corrected run, one row:
which stopper, longer or shorter, by how many millimetres. A stopper keeps a fraction lambda of the segment's actuator
path (length / cos theta; front.template's cut table), so its length changes by lambda' l / cos theta' - lambda l / cos
theta; the gap (or pinch) between stoppers takes the rest."""

from __future__ import annotations

import numpy as np

from vine_nlp.model.units import mm_per_unit

COLUMNS = ("segment", "s_start", "s_end", "lambda_built", "lambda_new", "theta_built_deg", "theta_new_deg",
           "stopper_built_mm", "stopper_new_mm", "stopper_change_mm", "action")
TOL = 1e-9


def built_nominal(archive):
    """The nominal last built, from a correction archive's /correction/builds (ValueError when there is none)."""
    if archive.kind.startswith("actuators"):
        raise ValueError("for one actuator (an archive of several: `template --run corrected` draws the corrected lines)")
    b = 0
    while f"correction/builds/{b}/lambda" in archive.extra:
        b += 1
    if b == 0:
        raise ValueError("not a correction archive (vine-nlp correct): nothing to compare the run with")
    k = f"correction/builds/{b - 1}"
    return (np.asarray(archive.extra[f"{k}/theta"], float), np.asarray(archive.extra[f"{k}/lambda"], float),
            np.asarray(archive.extra[f"{k}/length"], float))


def change_rows(archive, run: str = "corrected") -> list[dict]:
    """One dict per segment that changes (columns COLUMNS), lengths in millimetres, s in archive units."""
    mm = mm_per_unit(archive.units)
    if mm is None:
        raise ValueError(f"units {archive.units!r}: the change list needs mm, cm, m or in")
    th0, lam0, len0 = built_nominal(archive)
    r = archive.runs[run].routing
    if r.segments != lam0.size:
        raise ValueError(f"run {run!r} has {r.segments} segments, the built robot {lam0.size}")
    S = np.concatenate([[0.0], np.cumsum(r.length)])
    old = lam0 * len0 / np.cos(th0) * mm
    new = r.lam * r.length / np.cos(r.theta) * mm
    rows = []
    for j in range(r.segments):
        if abs(r.lam[j] - lam0[j]) <= TOL and abs(r.theta[j] - th0[j]) <= TOL:
            continue
        d = float(new[j] - old[j])
        rows.append({
            "segment": j, "s_start": float(S[j]), "s_end": float(S[j + 1]), "lambda_built": float(lam0[j]), "lambda_new": float(r.lam[j]),
            "theta_built_deg": float(np.degrees(th0[j])), "theta_new_deg": float(np.degrees(r.theta[j])),
            "stopper_built_mm": float(old[j]), "stopper_new_mm": float(new[j]), "stopper_change_mm": d,
            "action": "redraw" if abs(r.theta[j] - th0[j]) > TOL else ("longer" if d > 0 else "shorter"),
        })
    return rows


def changes_text(rows, units: str) -> str:
    """A readable table of the rows."""
    if not rows:
        return "no segment changes"
    head = f"{'segment':>7} {'s [' + units + ']':>16} {'lambda':>15} {'stopper [mm]':>22} {'change':>16}"
    out = [head]
    for r in rows:
        out.append(f"{r['segment']:>7} {r['s_start']:>7.2f}-{r['s_end']:<8.2f} {r['lambda_built']:>6.3f} -> {r['lambda_new']:<5.3f} "
                   f"{r['stopper_built_mm']:>8.1f} -> {r['stopper_new_mm']:<9.1f} {r['action']:>7} {abs(r['stopper_change_mm']):5.1f} mm")
    return "\n".join(out)
