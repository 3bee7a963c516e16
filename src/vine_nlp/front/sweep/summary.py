"""The sweep's results in words and in summary.csv: SweepReport, format_report, method_stats, write_summary."""

from __future__ import annotations

import csv
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from vine_nlp.model.units import mm_per_unit

SPEC_COLUMNS = ("method", "status", "rmse", "max_error", "solve_time_s")
EXTRA_COLUMNS = ("iterations", "units", "error")
SUMMARY_CSV = "summary.csv"
SUMMARY_PNG = "summary.png"
FAILED = "failed"
_CONVERGED = ("optimal", "acceptable")


@dataclass
class SweepReport:
    name: str
    out_dir: Path
    total: int  # items in the sweep
    done: int = 0  # solved in this run, every method finished (archive written)
    skipped: int = 0  # finished earlier: rows rebuilt from the archive
    failed: int = 0  # solved in this run, at least one method raised
    replaced: int = 0  # existing archives that did not belong to this sweep item (redone)
    wall_time_s: float = 0.0
    item_wall_s: float = 0.0  # sum over the items solved in this run of their time in a worker
    item_cpu_s: float = 0.0  # ... and of the CPU time they used there (less than the wall on a busy machine)
    executor: str = ""
    created_dir: bool = False
    interrupted: bool = False
    summary_csv: Path | None = None
    summary_png: Path | None = None
    archives: list = field(default_factory=list)  # paths of every archive of the sweep in DIR
    rows: list = field(default_factory=list)  # summary rows (dicts), grid order
    failures: list = field(default_factory=list)  # (item, method, error)
    figure_error: str = ""
    archived_here: int = 0  # archives this process wrote: the workers could not reach out_dir

    @property
    def solved(self) -> int:
        return self.done + self.failed

    @property
    def items_per_s(self) -> float:
        return self.solved / self.wall_time_s if self.wall_time_s > 0 else 0.0

    @property
    def not_converged(self) -> int:
        return sum(1 for r in self.rows if r["status"] not in _CONVERGED and r["status"] != FAILED)

    @property
    def short(self) -> int:
        """Runs that converged but miss a hard requirement of their problem (obstacle margin, bounds)."""
        return sum(1 for r in self.rows if r["status"] in _CONVERGED and r.get("error"))


def format_report(report: SweepReport) -> str:
    """A few lines for the command line: counts, time, RMSE per method, where the files are."""
    r = report
    head = f"sweep {r.name}: {r.total} items: {r.done} solved, {r.skipped} skipped (done before), {r.failed} failed"
    if r.interrupted:
        head += f", {r.total - r.done - r.skipped - r.failed} not run (interrupted)"
    lines = [head]
    if r.solved:
        lines.append(f"{r.wall_time_s:.1f} s wall, {r.items_per_s:.3g} items/s, {r.executor}; "
                     f"items took {r.item_wall_s:.1f} s in the workers ({r.item_cpu_s:.1f} s CPU)")
    elif r.wall_time_s:
        lines.append(f"{r.wall_time_s:.1f} s wall, nothing to solve")
    if r.archived_here:
        lines.append(f"{r.archived_here} archives were written by this process: the workers could not reach {r.out_dir}")
    if r.replaced:
        lines.append(f"{r.replaced} existing archives were from another version of the sweep and were replaced")
    for method, s in method_stats(r.rows).items():
        if not s["count"]:
            lines.append(f"{method}: no finished runs")
            continue
        u = s["units"]
        lines.append(f"{method}: RMSE mean {s['rmse_mean']:.3g} {u}, worst {s['rmse_max']:.3g} {u} ({s['worst_item']}), "
                     f"{s['converged']}/{s['count']} converged, median solve time {s['time_median']:.3g} s")
    if r.short:
        lines.append(f"{r.short} converged runs miss a hard requirement of their problem (see the error column)")
    for item, method, error in r.failures[:5]:
        lines.append(f"failed: {item} {method}: {error}")
    if len(r.failures) > 5:
        lines.append(f"... and {len(r.failures) - 5} more failed runs (see the error column)")
    created = " (created)" if r.created_dir else ""
    lines.append(f"archives -> {r.out_dir}{os.sep}<item>.h5{created}")
    if r.summary_csv:
        lines.append(f"summary -> {r.summary_csv}")
    if r.summary_png:
        lines.append(f"figure -> {r.summary_png}")
    if r.figure_error:
        lines.append(f"figure not written: {r.figure_error}")
    return "\n".join(lines)


def method_stats(rows) -> dict:
    """Per method: finished runs, converged runs, RMSE mean/worst (in mm when the units allow), median time."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        ok = [r for r in rows if r["method"] == method and r["rmse"] is not None]
        s = {"count": len(ok), "failed": sum(1 for r in rows if r["method"] == method and r["status"] == FAILED)}
        if ok:
            factor, unit = _mm(ok[0]["units"])
            rmse = [r["rmse"] * factor for r in ok]
            worst = max(range(len(ok)), key=lambda k: rmse[k])
            times = sorted(r["solve_time_s"] for r in ok)
            s.update(units=unit, rmse_mean=sum(rmse) / len(rmse), rmse_max=rmse[worst], worst_item=ok[worst]["item"],
                     max_error_max=max(r["max_error"] for r in ok) * factor, converged=sum(1 for r in ok if r["status"] in _CONVERGED),
                     time_median=times[len(times) // 2], time_total=sum(times))
        out[method] = s
    return out


def _mm(units: str):
    factor = mm_per_unit(units)  # the figure and the report in millimetres
    return (factor, "mm") if factor else (1.0, units)


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (int, str)):
        return str(value)
    return json.dumps(value)


def write_summary(path, rows, grid_keys) -> None:
    """summary.csv (atomically): spec columns, then iterations, units, error."""
    from vine_nlp.io.archive import write_atomic
    columns = ["item", *grid_keys, *SPEC_COLUMNS, *(c for c in EXTRA_COLUMNS if c not in grid_keys)]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in columns])
    write_atomic(path, lambda tmp: Path(tmp).write_text(buf.getvalue(), encoding="utf-8"))


def cells(result) -> dict:
    """The summary's numbers of one Result (what a worker sends back for each run it archived)."""
    m = result.metrics
    return {"status": result.status, "rmse": float(m["rmse"]) if "rmse" in m else None,
            "max_error": float(m["max_error"]) if "max_error" in m else None, "solve_time_s": float(result.solve_time_s),
            "iterations": int(result.iterations), "shortfall": "; ".join(result.shortfall)}  # shortfall: the hard requirements missed


def make_row(item, overrides, method, units, numbers=None, error=None) -> dict:
    """A summary row: ``numbers`` from :func:`cells`, or None for a failed run (``error``: why). The error
    column of a run that finished says what hard requirement of its problem it misses (pipeline.judge),
    as `vine-nlp design` says it: "misses: ..."."""
    row = {"item": item, **overrides, "method": method, "units": units}
    if numbers is None:
        row.update(status=FAILED, rmse=None, max_error=None, solve_time_s=None, iterations=None, error=error or "")
    else:
        short = numbers.get("shortfall", "")
        row.update({k: v for k, v in numbers.items() if k != "shortfall"}, error=f"misses: {short}" if short else "")
    return row


def read_summary(path) -> list[dict]:
    """Rows of a summary.csv, numbers as floats (None where empty), for :func:`plot_summary`."""
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            for key in ("rmse", "max_error", "solve_time_s"):
                row[key] = float(row[key]) if row.get(key) not in (None, "") else None
            rows.append(row)
    return rows
