"""1:1 fabrication templates of a design (``vine-nlp template``), as in the paper's Fig. 12(a).

The tube is slit along c = 0 and unrolled: the horizontal axis is s, the length
along the unactuated tube, the vertical axis the circumferential position
c(s) = (D/2) phi(s), wrapped at the circumference pi D (the band; its two edges
are the same line on the tube). Within a segment the actuator path is straight
on the unrolled tube (dc/ds = tan theta), of length dl / cos(theta).

Each segment's path is split into the part that stays (stopper, or unpinched
material: blue, a fraction lambda of the path) and the part removed or pinched
(gap between stoppers, or material taped together: red, 1 - lambda). The red gap
is centred in its segment, or, where it would be shorter than min_feature, joined
with its partner's at their common end (analysis.buildability.gap_fractions), so the
stoppers of neighbouring segments meet (segment ends drawn as small ticks). A
segment with lambda exactly 1 has no actuator: red dashed, "removed" (no stopper,
pouch or pinch). sPAM designs (actuator kind "spam") have one lambda for the whole
muscle: the path is drawn in one color, without stoppers. The CSV adds the
fabrication numbers of analysis.buildability per actuator kind.

Pages are drawn at real scale: 1 cm on paper is 1 cm of tube (problem units cm or
mm). A tube longer than a page is cut into strips, several per page when the
band is narrow; neighbouring strips share 1 cm (the shaded end of a strip, with
alignment crosses at both ends of the shared part), and a wide band is cut the
same way around the circumference. Every page carries a 10 cm scale bar.

Several actuators on one tube (:func:`write_actuators_template`): every line on the one band, each from where it
starts around the tube (phi_k[0], marked at the base), its stoppers, pouches and the parts where it has no
actuator in its own colour (palette.LINES), gaps red as for one actuator; in SVG and DXF each line has its own
layers (``actuator_path-<name>``, ``stoppers-<name>``, ``removed-<name>``); the CSV has a row per line and segment.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle
from matplotlib.ticker import MultipleLocator

from vine_nlp.analysis.buildability import buildability, gap_fractions
from vine_nlp.front import palette
from vine_nlp.front.files import output_format
from vine_nlp.front.show import build_settings, source_table
from vine_nlp.front.states import line_kinds, picked_states
from vine_nlp.io.archive import Archive, load_archive, write_atomic
from vine_nlp.model.chain import phi_from_theta
from vine_nlp.model.units import MM_PER_UNIT
from vine_nlp.problem import Routing

PAPERS_MM = {"A4": (210.0, 297.0), "Letter": (215.9, 279.4)}
CM_PER_UNIT = {u: MM_PER_UNIT[u] / 10 for u in ("cm", "mm")}  # the units a template takes
STOPPER_COLOR = palette.ACTUATOR  # the actuator line's colour (plot, view, animate): stays (stopper / unpinched)
GAP_COLOR = palette.REMOVED  # red: removed or pinched
SPAM_COLOR = palette.ACTUATOR  # an sPAM's path: the actuator, all of it
CHANGE_COLOR = palette.CHANGE  # orange: a segment that changes against the robot built last (--changes)
CSV_COLUMNS = (
    "segment", "s_start", "s_end", "theta_deg", "lambda", "phi_start_rad", "phi_end_rad",
    "c_start", "c_end", "actuator_length", "stopper_length", "gap_length",
    # analysis.buildability: piece = index of the actuated piece; gap_* along the line from the base (stoppers fill the
    # rest of a piece); tendon_length (tendon), pinch_length (programmed), pouches and pouch_length (spam) per piece
    "actuated", "piece", "gap_start", "gap_end", "tendon_length", "pinch_length", "pouches", "pouch_length",
)

# page layout, mm
MARGIN = 10.0  # every edge (printers need ~5 mm)
LEFT_LABELS = 13.0  # room for the circumference tick labels left of a strip
RIGHT_ROOM = 4.0
TITLE_H = 13.0  # title lines at the top
FOOT_H = 15.0  # scale bar and legend at the bottom
STRIP_LABEL_H = 4.5  # strip label above a strip
MARK_H = 4.0  # room for alignment crosses above and below the band (inside the strip axes)
TICKS_H = 6.0  # s tick labels below a strip
STRIP_GAP = 3.0  # between strips
OVERLAP_CM = 1.0  # shared length of neighbouring strips
SCALE_BAR_CM = 10.0
CROSS_MM = 1.8  # half size of an alignment cross
FONT = 7


@dataclass
class Tile:
    """One strip: s from s0 to s1 (its own part) plus the shared part up to s1 + overlap."""

    index: int
    s0: float
    s1: float
    s_end: float  # drawn up to here (s1 + overlap, or the tube's end)
    c0: float
    c1: float
    c_end: float
    label: str


@dataclass
class Layout:
    paper: str
    orientation: str
    width_mm: float
    height_mm: float
    tiles: list
    per_page: int

    @property
    def pages(self) -> int:
        return math.ceil(len(self.tiles) / self.per_page)


def _paper(paper: str) -> tuple[str, tuple[float, float]]:
    for name, size in PAPERS_MM.items():
        if str(paper).lower() == name.lower():
            return name, size
    raise ValueError(f"paper must be one of {', '.join(PAPERS_MM)}, not {paper!r}")


def cut_table(archive: Archive, run: str, kind: str | None = None, routing=None, phi0: float = 0.0, settings=None) -> dict:
    """Per-segment fabrication numbers (the CUTS.csv columns) as arrays, in the problem's units; NaN where a
    column does not apply. ``kind``: the actuator kind (default: the archived problem's); ``routing``, ``phi0``
    and ``settings``: one line of several (default: the run's routing, from phi = 0, build_settings)."""
    r = archive.runs[run].routing if routing is None else routing
    D = archive.diameter
    S = np.concatenate([[0.0], np.cumsum(r.length)])
    phi = phi0 + phi_from_theta(r.theta, r.length, D)
    C = math.pi * D
    c = 0.5 * D * phi
    actuator = r.length / np.cos(r.theta)
    act = r.lam != 1.0
    settings = (build_settings(archive) if settings is None else settings) | ({"kind": kind} if kind else {})
    frac = gap_fractions(r.lam, actuator, settings["min_feature"])
    rep = buildability(r, D, **settings)
    extra = {k: np.full(r.segments, np.nan) for k in CSV_COLUMNS[-7:]}
    line = np.concatenate([[0.0], np.cumsum(actuator)])[:-1]
    extra["gap_start"], extra["gap_end"] = line + frac[:, 0] * actuator, line + frac[:, 1] * actuator
    pouches = rep.parts.get("pouches", [])
    for k, p in enumerate(q for q in rep.pieces if q.actuated):
        extra["piece"][p.start:p.stop] = k
        if settings["kind"] == "tendon":
            extra["tendon_length"][p.start:p.stop] = p.path
        if pouches and pouches[k] is not None:
            extra["pouches"][p.start:p.stop], extra["pouch_length"][p.start:p.stop] = pouches[k][:2]
    if settings["kind"] == "programmed":
        extra["pinch_length"] = np.where(act, (1.0 - r.lam) * actuator, np.nan)
    return {
        "segment": np.arange(r.segments), "s_start": S[:-1], "s_end": S[1:], "theta_deg": np.degrees(r.theta),
        "lambda": r.lam, "phi_start_rad": phi[:-1], "phi_end_rad": phi[1:], "c_start": wrap(c[:-1], C),
        "c_end": wrap(c[1:], C), "actuator_length": actuator, "stopper_length": np.where(act, r.lam, 0.0) * actuator,
        "gap_length": np.where(act, 1.0 - r.lam, 0.0) * actuator, "actuated": act.astype(float), **extra,
        "refused": rep.refused, "gap_fractions": frac,
    }


def wrap(c, circumference: float) -> np.ndarray:
    """Circumferential positions wrapped into [0, pi D)."""
    w = np.mod(np.asarray(c, float), circumference)
    return np.where(w >= circumference, 0.0, w)


def cuts_csv(*tables) -> str:
    """The CUTS.csv of one line's table, or of several lines' (a first column ``actuator``, a row per line and segment)."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    several = "name" in tables[0]
    w.writerow(("actuator",) * several + CSV_COLUMNS)
    for table in tables:
        for i in range(len(table["segment"])):
            w.writerow(([table["name"]] if several else []) + [int(table["segment"][i])]
                       + [f"{float(table[k][i]):.10g}" if np.isfinite(table[k][i]) else "" for k in CSV_COLUMNS[1:]])
    return out.getvalue()


def _pieces(s_a, c_a, s_b, c_b, C):
    """Split the straight piece (s_a, c_a) -> (s_b, c_b) (c unwrapped) where it crosses
    a multiple of C; each part shifted into [0, C]."""
    ks = np.arange(math.floor(min(c_a, c_b) / C) + 1, math.ceil(max(c_a, c_b) / C))
    ts = sorted({0.0, 1.0, *((k * C - c_a) / (c_b - c_a) for k in ks if c_b != c_a)})
    out = []
    for t0, t1 in zip(ts[:-1], ts[1:]):
        if t1 - t0 <= 1e-12:
            continue
        sa, sb = s_a + t0 * (s_b - s_a), s_a + t1 * (s_b - s_a)
        ca, cb = c_a + t0 * (c_b - c_a), c_a + t1 * (c_b - c_a)
        shift = math.floor(0.5 * (ca + cb) / C) * C
        out.append(((sa, sb), (ca - shift, cb - shift)))
    return out


def layout(length_cm: float, circumference_cm: float, paper: str, unit_per_cm: float = 1.0) -> Layout:
    """Strips and pages for a tube ``length_cm`` long with a band ``circumference_cm`` wide, in the orientation with
    fewer pages (then fewer strips; landscape on a tie). Tile coordinates in problem units (``unit_per_cm`` per cm)."""
    name, (pw, ph) = _paper(paper)
    best = None
    for ori, (W, H) in (("landscape", (ph, pw)), ("portrait", (pw, ph))):
        L = _layout_one(length_cm, circumference_cm, W, H, unit_per_cm)
        cand = Layout(name, ori, W, H, *L)
        key = (cand.pages, len(cand.tiles))
        if best is None or key < best[0]:
            best = (key, cand)
    return best[1]


def _cuts(total_cm: float, room_mm: float) -> list[tuple[float, float, float]]:
    """(start, own end, drawn end) in cm of pieces that fit ``room_mm`` with 1 cm shared between neighbours.
    Pieces are whole centimetres long, so strip boundaries fall on round values of s."""
    room_cm = room_mm / 10.0
    if total_cm <= room_cm + 1e-9:
        return [(0.0, total_cm, total_cm)]
    step = math.floor(room_cm - OVERLAP_CM)
    if step < 1:
        raise ValueError("the paper is too small for a strip")
    out, a = [], 0.0
    while a < total_cm - 1e-9:
        b = min(a + step, total_cm)
        out.append((a, b, min(b + OVERLAP_CM, total_cm)))
        a = b
    return out


def _layout_one(length_cm, circumference_cm, W, H, unit_per_cm):
    strip_room = W - 2 * MARGIN - LEFT_LABELS - RIGHT_ROOM
    height_room = H - 2 * MARGIN - TITLE_H - FOOT_H
    fixed = STRIP_LABEL_H + 2 * MARK_H + TICKS_H + STRIP_GAP
    band_room = height_room - fixed
    s_cuts = _cuts(length_cm, strip_room)
    c_cuts = _cuts(circumference_cm, band_room)
    band_mm = 10.0 * max(c[2] - c[0] for c in c_cuts)
    per_page = max(1, int((height_room + 1e-6) // (band_mm + fixed)))
    tiles = []
    n = len(s_cuts) * len(c_cuts)
    for a, b, e in s_cuts:
        for c0, c1, ce in c_cuts:
            k = len(tiles)
            u = unit_per_cm
            label = f"strip {k + 1}/{n}:  s = {a * u:.4g} to {b * u:.4g}"
            if len(c_cuts) > 1:
                label += f",  c = {c0 * u:.4g} to {c1 * u:.4g}"
            tiles.append(Tile(k, a * u, b * u, e * u, c0 * u, c1 * u, ce * u, label))
    return tiles, per_page


TEMPLATE_FORMATS = (".pdf", ".svg", ".dxf")
template_format = partial(output_format, formats=TEMPLATE_FORMATS, what="template")  # an output's format by its extension (ValueError)


def write_template(archive_path_or_archive, pdf_path, csv_path=None, paper: str = "A4", run: str | None = None,
                   spam: bool | None = None, changes: list | None = None) -> dict:
    """Write the 1:1 fabrication template of ``run`` (default: the archive's default run): a multi-page PDF, or
    one SVG or DXF sheet in millimetres (by the extension of ``pdf_path``), and CUTS.csv, all atomically.

    spam: default from the archived problem file's [actuator] kind. Units must be cm or mm (ValueError otherwise).
    Strips are cut for ``paper`` in every format (SVG and DXF stack them on one sheet, :func:`template_sheet`).
    changes: rows of ``front.changes.change_rows`` (a correction archive against the robot built last); each
    changing segment is framed in orange with its stopper change ("+2.3 mm longer", "-1.1 mm shorter", "redraw"),
    and the legend says so. Returns {"pages" (1 for SVG and DXF), "strips", "paper", "paper_mm" (width, height as
    printed; the sheet's for SVG and DXF), "orientation", "run", "spam", "segments", "stoppers" (segments drawn
    with a stopper/gap split), "gaps" (segments with a gap drawn), "unactuated" (segments without an actuator),
    "refused" (analysis.buildability's reasons), "tube_length", "format", "changes" (segments marked)}.
    """
    a = archive_path_or_archive if isinstance(archive_path_or_archive, Archive) else load_archive(archive_path_or_archive)
    name = a.pick_run(run)
    kind = source_table(a, "actuator").get("kind")
    spam = kind == "spam" if spam is None else bool(spam)
    table = cut_table(a, name, "spam" if spam else (None if kind in ("tendon", "programmed") else "tendon"))
    table |= {"changes": {int(r["segment"]): r for r in (changes or [])}, "spam": spam, "style": STYLE}
    info = _write(a, name, [table], pdf_path, csv_path, paper)
    return info | {"spam": spam, **split_counts(table, spam), "changes": len(table["changes"]), "unactuated": _none_count(table),
                   "refused": table["refused"]}


def write_actuators_template(path, out, csv_path=None, paper: str = "A4", run: str | None = None) -> dict:
    """:func:`write_template` of an archive of several actuators (module docstring): every line, from its phi_k[0],
    by its own [[actuators]] kind and lambda_min. Returns write_template's keys but spam, changes and the counts,
    and "actuators" ({name: dict(spam, stoppers, gaps, unactuated, refused)})."""
    a, name, r, _, _ = picked_states(path, run)
    base, ls, tables = build_settings(a), r.lines, []
    for k, (line, (kind, lmin)) in enumerate(zip(ls.names, line_kinds(a, ls.count))):
        routing = Routing(theta=ls.theta[k], lam=ls.lam[k], length=ls.length)
        tables.append(cut_table(a, name, routing=routing, phi0=float(ls.phi0[k]), settings=base | {"kind": kind, "lambda_min": lmin})
                      | {"name": line, "spam": kind == "spam", "style": line_style(k, line), "changes": {}})
    info = _write(a, name, tables, out, csv_path, paper)
    return info | {"actuators": {t["name"]: {"spam": t["spam"], **split_counts(t, t["spam"]), "unactuated": _none_count(t),
                                             "refused": t["refused"]} for t in tables}}


def _write(a: Archive, name: str, tables: list, path, csv_path, paper: str) -> dict:
    """Lay out and write the template of ``tables`` (one per line, the first's ends and segments drawn for all)."""
    fmt = template_format(path)
    if a.units not in CM_PER_UNIT:
        raise ValueError(f"a 1:1 template needs lengths in cm or mm, not {a.units!r}")
    table = tables[0]
    k = CM_PER_UNIT[a.units]
    L = float(table["s_end"][-1]) if len(table["s_end"]) else 0.0
    lay = layout(L * k, math.pi * a.diameter * k, paper, unit_per_cm=1.0 / k)
    pages, size = lay.pages, (lay.width_mm, lay.height_mm)

    def write_cuts():
        if csv_path is not None:
            write_atomic(csv_path, lambda t: Path(t).write_text(cuts_csv(*tables)))

    if fmt == ".pdf":
        def write_pdf(tmp):
            with PdfPages(tmp, metadata={"Title": f"{a.name} fabrication template ({name})", "Creator": "vine_nlp"}) as pdf:
                for page in range(lay.pages):
                    pdf.savefig(_page(a, name, tables, lay, page))  # no bbox_inches: the page stays exactly the paper size
            write_cuts()

        write_atomic(path, write_pdf)
    else:
        sheet = template_sheet(a, name, tables, lay)
        data = sheet_svg(sheet) if fmt == ".svg" else sheet_dxf(sheet)

        def write_sheet(tmp):
            Path(tmp).write_bytes(data)
            write_cuts()

        write_atomic(path, write_sheet)
        pages, size = 1, (sheet.width_mm, sheet.height_mm)
    return {"pages": pages, "strips": len(lay.tiles), "paper": lay.paper, "paper_mm": size, "orientation": lay.orientation,
            "run": name, "segments": int(len(table["segment"])), "tube_length": L, "format": fmt[1:]}


# ------------------------------------------------------------------ drawing


def _segment_parts(table, j, spam):
    """(t0, t1, kind) parts of segment j along its path: stopper, gap, stopper; one muscle part; or "none" (no actuator)."""
    if not table["actuated"][j]:
        return [(0.0, 1.0, "none")]
    if spam:
        return [(0.0, 1.0, "muscle")]
    a, b = table["gap_fractions"][j]
    parts = [(0.0, a, "stopper"), (a, b, "gap"), (b, 1.0, "stopper")]
    return [p for p in parts if p[1] - p[0] > 1e-9]


def _title(a: Archive, run: str, tables: list) -> tuple:
    """The title's first line and the rest of what it says of the tube (PDF and sheets alike)."""
    table, D, u = tables[0], a.diameter, a.units
    what = (f"{len(tables)} actuators ({', '.join(t['name'] for t in tables)}), each from the base mark of its colour"
            if "name" in table else f"{_none_count(table)} without an actuator")
    refused = [f"refused: {t['name'] + ': ' if 'name' in t else ''}{reason}" for t in tables for reason in t["refused"]]
    return (f"{a.name}: fabrication template of run {run} ({a.runs[run].method}), D = {D:.4g} {u}",
            f"tube length {float(table['s_end'][-1]):.4g} {u}, {len(table['segment'])} segments ({what}), "
            f"circumference \u03c0D = {math.pi * D:.4g} {u}", refused[:1])  # the title has room for one refusal


def _page(a: Archive, run: str, tables: list, lay: Layout, page: int):
    """One page of the template: a figure exactly the paper's size."""
    W, H = lay.width_mm, lay.height_mm
    k = CM_PER_UNIT[a.units]
    u = a.units
    fig = Figure(figsize=(W / 25.4, H / 25.4))
    fx, fy = (lambda mm: mm / W), (lambda mm: mm / H)
    head, tube, refused = _title(a, run, tables)
    lines = [head, tube + ". Print at 100 % (actual size, no fit to page): 1 cm on paper = 1 cm of tube.",
             "s: length along the unactuated tube. c = (D/2) \u03c6: position around the tube, wrapped at \u03c0D "
             "(both band edges are the same line on the tube).", *refused]
    fig.text(fx(MARGIN), fy(H - MARGIN), lines[0], fontsize=8, va="top", ha="left", weight="bold")
    for i, line in enumerate(lines[1:]):
        fig.text(fx(MARGIN), fy(H - MARGIN - 4.2 - 3.3 * i), line, fontsize=FONT, va="top", ha="left")
    fig.text(fx(W - MARGIN), fy(MARGIN), f"page {page + 1}/{lay.pages}", fontsize=FONT, ha="right", va="bottom")

    tiles = lay.tiles[page * lay.per_page:(page + 1) * lay.per_page]
    top = H - MARGIN - TITLE_H
    for tile in tiles:
        band_mm = (tile.c_end - tile.c0) * k * 10.0
        ax_h = band_mm + 2 * MARK_H
        width_mm = (tile.s_end - tile.s0) * k * 10.0
        y_top = top - STRIP_LABEL_H
        ax = fig.add_axes((fx(MARGIN + LEFT_LABELS), fy(y_top - ax_h), fx(width_mm), fy(ax_h)))
        mark = MARK_H / (10.0 * k)  # the mark room in problem units
        ax.set_xlim(tile.s0, tile.s_end)
        ax.set_ylim(tile.c0 - mark, tile.c_end + mark)
        _strip(ax, a, tables, tile)
        fig.text(fx(MARGIN + LEFT_LABELS), fy(top - 0.5), tile.label + f" {u}", fontsize=FONT, va="top", ha="left")
        top = y_top - ax_h - TICKS_H - STRIP_GAP
    _footer(fig, W, H, tables)
    return fig


@dataclass
class StripGeometry:
    """What one strip shows, in problem units (s along the tube, c around it), for every output
    format (PDF, SVG, DXF draw the same strips from this). Lines are ((s, c), (s, c)) pairs,
    already clipped to the band."""

    band: tuple  # (s0, c0, s1, c1): this strip's part of the band (the cut outline)
    shared: list  # (s0, c0, s1, c1) rectangles that go under the neighbouring strip
    references: list  # c of the band edges c = 0 and c = pi D inside the strip
    crosses: list  # alignment crosses, as lines
    ends: list  # (s, "base" | "tip")
    paths: dict  # kind (stopper, gap, muscle) -> lines of the actuator path
    ticks: list  # segment-end ticks across the path
    labels: list  # (s, c, text): segment indices
    mark_c: tuple  # c of the mark rows below and above the band (base/tip words)
    changes: list = field(default_factory=list)  # (frame lines, (s, c, text) or None): segments that change (--changes)
    starts: list = field(default_factory=list)  # (s, c, text): where a line of several starts around the tube


def _clip(p, q, box):
    """Line p-q clipped to the rectangle box = (s0, c0, s1, c1) (Liang-Barsky); None if outside."""
    (x0, y0), (x1, y1) = p, q
    dx, dy = x1 - x0, y1 - y0
    t0, t1 = 0.0, 1.0
    for pk, qk in ((-dx, x0 - box[0]), (dx, box[2] - x0), (-dy, y0 - box[1]), (dy, box[3] - y0)):
        if abs(pk) < 1e-15:
            if qk < -1e-12:
                return None
            continue
        t = qk / pk
        if pk < 0:
            t0 = max(t0, t)
        else:
            t1 = min(t1, t)
    if t1 - t0 <= 1e-12:
        return None
    return (x0 + t0 * dx, y0 + t0 * dy), (x0 + t1 * dx, y0 + t1 * dy)


def strip_geometry(table: dict, tile: Tile, D: float, units: str, spam: bool) -> StripGeometry:
    """The geometry of one strip of the template (the one place it is computed)."""
    k = CM_PER_UNIT[units]
    C = math.pi * D
    cm = 1.0 / k  # one centimetre in problem units
    band_top = min(tile.c_end, C)
    box = (tile.s0, tile.c0, tile.s_end, band_top)
    shared = []
    if tile.s_end > tile.s1 + 1e-12:
        shared.append((tile.s1, tile.c0, tile.s_end, band_top))
    if tile.c_end > tile.c1 + 1e-12:
        shared.append((tile.s0, tile.c1, tile.s_end, tile.c_end))
    references = [c for c in (0.0, C) if tile.c0 - 1e-9 <= c <= tile.c_end + 1e-9]
    s_marks = _shared_ends(tile.s0, tile.s1, tile.s_end, cm)
    c_marks = _shared_ends(tile.c0, tile.c1, tile.c_end, cm)
    outside = 0.5 * MARK_H / (10 * k)
    centres = [(s, c) for s in s_marks for c in (tile.c0 - outside, band_top + outside)]
    centres += [(s, c) for s in (tile.s0 + 0.5 * cm, tile.s_end - 0.5 * cm) for c in c_marks]  # around the tube: inside
    h = CROSS_MM / (10 * k)
    crosses = [seg for s, c in centres for seg in (((s - h, c), (s + h, c)), ((s, c - h), (s, c + h)))]
    L = float(table["s_end"][-1])
    ends = ([(0.0, "base")] if tile.s0 <= 0.0 else []) + ([(L, "tip")] if tile.s_end >= L - 1e-9 else [])

    S0, S1 = table["s_start"], table["s_end"]
    c_unwrapped = 0.5 * D * np.concatenate([table["phi_start_rad"][:1], table["phi_end_rad"]])
    paths = {"stopper": [], "gap": [], "muscle": [], "none": []}
    ticks, labels, changes = [], [], []
    tick = 1.2 / (10 * k)  # segment-end ticks: 1.2 mm either side of the path
    last_label = -np.inf
    for j in range(len(S0)):
        if S1[j] < tile.s0 or S0[j] > tile.s_end:
            continue
        sa, sb, ca, cb = S0[j], S1[j], c_unwrapped[j], c_unwrapped[j + 1]
        for t0, t1, kind in _segment_parts(table, j, spam):
            for (s_a, s_b), (c_a, c_b) in _pieces(sa + t0 * (sb - sa), ca + t0 * (cb - ca), sa + t1 * (sb - sa), ca + t1 * (cb - ca), C):
                line = _clip((s_a, c_a), (s_b, c_b), box)
                if line is not None:
                    paths[kind].append(line)
        # segment boundary tick across the path, and its index where there is room
        cw = float(table["c_start"][j])
        if tile.s0 <= sa <= tile.s_end:
            line = _clip((sa, cw - tick), (sa, cw + tick), box)
            if line is not None:
                ticks.append(line)
            room = min(sa - tile.s0, tile.s_end - sa) * k * 10  # mm to the strip's ends
            if (sa - last_label) * k * 10 >= 7.0 and room >= 2.5 and tile.c0 <= cw <= band_top:
                up = cw + 2.0 / (10 * k) if cw < band_top - 3.0 / (10 * k) else cw - 2.0 / (10 * k)
                labels.append((sa, up, str(j)))
                last_label = sa
        row = table.get("changes", {}).get(j)
        if row is not None:
            changes.append(_change_mark(row, sa, sb, ca, cb, C, box, k, tile.s0 <= 0.5 * (sa + sb) < max(tile.s1, tile.s0 + 1e-12)
                                        or (0.5 * (sa + sb) >= tile.s1 and tile.s_end >= L - 1e-9)))
    c = float(table["c_start"][0])
    starts = [(0.0, c, f"{table['name']}: \u03c6 = {math.degrees(table['phi_start_rad'][0]):.4g}\u00b0")] \
        if "name" in table and tile.s0 <= 0.0 and tile.c0 <= c <= band_top else []
    return StripGeometry(box, shared, references, crosses, ends, paths, ticks, labels,
                         (tile.c0 - outside, band_top + outside), changes, starts)


def change_text(row) -> str:
    """The words on the template for one changing segment (a row of ``front.changes.change_rows``)."""
    d = float(row["stopper_change_mm"])
    if row["action"] == "redraw":
        return f"{row['segment']}: redraw, stopper {d:+.1f} mm"
    return f"{row['segment']}: {d:+.1f} mm {row['action']}"


def _change_mark(row, sa, sb, ca, cb, C, box, k, with_text=True):
    """A frame around the segment's actuator path (clipped to the strip) and its change text above it
    (``with_text``: on the one strip that holds the segment's middle, so each segment is labelled once)."""
    pad = 1.5 / (10 * k)  # 1.5 mm around the path
    lines = []
    for (s_a, s_b), (c_a, c_b) in _pieces(sa, ca, sb, cb, C):
        lo, hi = min(c_a, c_b) - pad, max(c_a, c_b) + pad
        for p, q in (((s_a, lo), (s_b, lo)), ((s_b, lo), (s_b, hi)), ((s_b, hi), (s_a, hi)), ((s_a, hi), (s_a, lo))):
            line = _clip(p, q, box)
            if line is not None:
                lines.append(line)
    text = change_text(row)
    # centred on the segment's part in this strip, whole inside the strip (about 1.1 mm per character at 6 pt):
    # a text cut at the strip's end would misread ("-10.2 mm" showing as "0.2 mm")
    half = 0.65 * len(text) / (10 * k)
    lo_s, hi_s = max(sa, box[0]), min(sb, box[2])
    s_mid = min(max(0.5 * (lo_s + hi_s), box[0] + half), box[2] - half)
    t = min(max((s_mid - sa) / (sb - sa), 0.0), 1.0) if sb > sa else 0.5
    c_mid = float(np.mod(ca + t * (cb - ca), C))
    c_text = c_mid + 4.0 / (10 * k) if c_mid < box[3] - 6.0 / (10 * k) else c_mid - 4.0 / (10 * k)
    return lines, ((s_mid, min(max(c_text, box[1]), box[3]), text) if with_text else None)


NONE_DASH = (0, (3, 2))  # no actuator: dashed
NONE_LEGEND = "removed: no actuator (\u03bb = 1): no stopper, pouch or pinch"
# each part of a line's path: (colour, width pt, dashed, sheet layer: None for the path's layer alone); "path": that layer
STYLE = {"stopper": (STOPPER_COLOR, 1.6, False, "stoppers"), "gap": (GAP_COLOR, 2.4, False, "removed"),
         "muscle": (SPAM_COLOR, 1.6, False, None), "none": (GAP_COLOR, 0.8, True, "removed"), "path": "actuator_path"}


def line_style(k: int, name: str) -> dict:
    """STYLE of line k of several: its stoppers, muscle and parts without an actuator in palette.LINES[k], its
    gaps red; its own sheet layers."""
    c = palette.LINES[k % len(palette.LINES)]
    return {"stopper": (c, 1.6, False, f"stoppers-{name}"), "gap": (GAP_COLOR, 2.4, False, f"removed-{name}"),
            "muscle": (c, 1.6, False, None), "none": (c, 0.8, True, f"removed-{name}"), "path": f"actuator_path-{name}"}


def _strip(ax, a: Archive, tables: list, tile: Tile):
    k = CM_PER_UNIT[a.units]
    C = math.pi * a.diameter
    cm = 1.0 / k  # one centimetre in problem units
    geoms = [strip_geometry(t, tile, a.diameter, a.units, t["spam"]) for t in tables]
    g = geoms[0]
    for side in ("top", "right", "left"):
        ax.spines[side].set_visible(False)
    ax.spines["bottom"].set_linewidth(0.5)
    ax.xaxis.set_major_locator(MultipleLocator(5 * cm))
    ax.xaxis.set_minor_locator(MultipleLocator(cm))
    ax.tick_params(axis="x", labelsize=FONT, length=3, width=0.5, pad=1)
    ax.tick_params(axis="x", which="minor", length=1.5, width=0.4)
    ax.set_yticks([v for v in (0.0, 0.25 * C, 0.5 * C, 0.75 * C, C) if tile.c0 - 1e-9 <= v <= tile.c_end + 1e-9])
    ax.yaxis.set_major_formatter(lambda v, pos: f"{v:.3g}")
    ax.tick_params(axis="y", labelsize=FONT, length=2, width=0.5, pad=1)
    ax.set_ylabel(f"c [{a.units}]", fontsize=FONT, labelpad=1)
    ax.patch.set_visible(False)

    s0, c0, s1, c1 = g.band
    ax.add_patch(Rectangle((s0, c0), s1 - s0, c1 - c0, facecolor="0.96", edgecolor="none", zorder=0))
    for c in g.references:
        ax.axhline(c, color="0.35", lw=0.6, ls=(0, (6, 3)), zorder=1)
    for r in g.shared:  # shaded: they go under the neighbouring strip
        ax.add_patch(Rectangle((r[0], r[1]), r[2] - r[0], r[3] - r[1], facecolor="0.82", edgecolor="none", zorder=0.5))
    ax.add_collection(LineCollection(g.crosses, colors="k", linewidths=0.5, clip_on=False, zorder=6))
    for s, word in g.ends:
        ax.axvline(s, color="k", lw=0.8)
        ax.text(s, g.mark_c[1], "  base" if word == "base" else "tip  ", fontsize=FONT,
                ha="left" if word == "base" else "right", va="center")
    for t, gk in zip(tables, geoms):
        for kind, lines in gk.paths.items():
            color, width, dashed, _ = t["style"][kind]
            if lines:
                ax.add_collection(LineCollection(lines, colors=color, linewidths=width, linestyles=NONE_DASH if dashed else "solid",
                                                 capstyle="butt", zorder=3))
        if gk.ticks:
            ax.add_collection(LineCollection(gk.ticks, colors="k", linewidths=0.5, zorder=4))
        for s, c, text in gk.starts:
            ax.plot([s], [c], marker=">", ms=5, color=t["style"]["stopper"][0], clip_on=False, zorder=6)
            ax.text(s + 0.3 * cm, c, text, fontsize=6, ha="left", va="bottom", color=t["style"]["stopper"][0], zorder=6)
    for s, c, text in g.labels:
        ax.text(s, c, text, fontsize=6, ha="center", va="center", color="0.25", zorder=5, clip_on=True)
    for lines, label in g.changes:
        ax.add_collection(LineCollection(lines, colors=CHANGE_COLOR, linewidths=0.9, zorder=4.5))
        if label is not None:
            s, c, text = label
            ax.text(s, c, text, fontsize=6, ha="center", va="center", color=CHANGE_COLOR, weight="bold", zorder=5.5, clip_on=True)


def _shared_ends(a: float, b: float, end: float, cm: float) -> list[float]:
    """Where the alignment crosses of a piece from a to b (drawn to end) go: both ends of the
    centimetre shared with the previous piece (if a > 0) and with the next one (if end > b)."""
    marks = [a, a + min(OVERLAP_CM * cm, end - a)] if a > 0 else []
    marks += [b, end] if end > b + 1e-12 else []
    return sorted(set(round(v, 12) for v in marks))


def _none_count(table: dict) -> int:
    return int((table["actuated"] == 0).sum())


def _muscle_lambda(table: dict) -> float:
    """The sPAM's one lambda: of the segments with an actuator (1 where there is none)."""
    lam = table["lambda"][table["actuated"] == 1]
    return float(np.mean(lam)) if lam.size else 1.0


def _legend(tables: list) -> list[tuple[tuple, str]]:
    """The legend's rows of the PDF and the sheets: (style (colour, width, dashed, layer), text)."""
    rows = []
    for t in tables:
        st, who = t["style"], f"{t['name']}: " if "name" in t else ""
        rows += ([((*st["muscle"][:3], st["path"]), f"{who}sPAM muscle path, one \u03bb = {_muscle_lambda(t):.3g}")] if t["spam"] else
                 [(st["stopper"], f"{who}stays: stopper / unpinched (\u03bb)")])
    if any("name" in t and not t["actuated"].all() for t in tables):
        rows.append((("#808080", 0.8, True, "removed-<line>"), "dashed, in a line's colour: no actuator on that line (\u03bb = 1): "
                     "no stopper, pouch or pinch"))
    if not all(t["spam"] for t in tables):
        rows.append((tables[0]["style"]["gap"], "removed: gap / pinched (1 \u2212 \u03bb)"))
    if not tables[0]["actuated"].all() and "name" not in tables[0]:
        rows.append((STYLE["none"], NONE_LEGEND))
    if tables[0].get("changes"):
        rows.append(((CHANGE_COLOR, 0.9, False, "changes"), f"framed: {len(tables[0]['changes'])} segment(s) to change against the robot built last"))
    return rows


def split_counts(table: dict, spam: bool) -> dict:
    """Segments drawn with a stopper/gap split ("stoppers") and with a gap ("gaps"); both 0 for sPAM."""
    counts = {"stoppers": 0, "gaps": 0}
    for j in range(len(table["segment"])):
        kinds = {p[2] for p in _segment_parts(table, j, spam)}
        counts["stoppers"] += int("stopper" in kinds and "gap" in kinds)
        counts["gaps"] += int("gap" in kinds)
    return counts


def _footer(fig, W, H, tables):
    fx, fy = (lambda mm: mm / W), (lambda mm: mm / H)
    x0, y0 = MARGIN, MARGIN + 9.0
    x1 = x0 + SCALE_BAR_CM * 10.0
    fig.add_artist(Line2D([fx(x0), fx(x1)], [fy(y0), fy(y0)], color="k", lw=1.2, solid_capstyle="butt"))
    for i in range(int(SCALE_BAR_CM) + 1):
        h = 2.0 if i % 5 == 0 else 1.0
        fig.add_artist(Line2D([fx(x0 + 10 * i)] * 2, [fy(y0), fy(y0 + h)], color="k", lw=0.6))
    fig.text(fx(x0), fy(y0 - 1.5), f"scale check: this bar must measure {SCALE_BAR_CM * 10:.0f} mm ({SCALE_BAR_CM:.0f} cm) on the print",
             fontsize=FONT, va="top", ha="left")
    lx = x1 + 8.0
    items = [(*style[:3], text) for style, text in _legend(tables)]
    items.append((None, 0, False, "+ alignment marks, shaded: 1 cm overlap"))
    step = min(3.6, (FOOT_H + 3.0) / len(items))  # several lines: rows closer together
    for i, (color, lw, dashed, text) in enumerate(items):
        y = y0 + 3.0 - step * i
        if color is not None:
            fig.add_artist(Line2D([fx(lx), fx(lx + 7)], [fy(y), fy(y)], color=color, lw=lw, ls=NONE_DASH if dashed else "-"))
        fig.text(fx(lx + 9), fy(y), text, fontsize=FONT, va="center", ha="left")


# ------------------------------------------------------------------ SVG and DXF sheets

# layers of the SVG and DXF templates, for cutting plotters and laser cutters: name -> (colour, line width mm, DXF ACI)
LAYERS = {
    "outline": ("#000000", 0.25, 7),  # the band of each strip: cut here
    "actuator_path": ("#7f7f7f", 0.2, 8),  # the whole actuator path
    "stoppers": (STOPPER_COLOR, 0.6, 5),  # stays: stoppers / unpinched
    "removed": (GAP_COLOR, 0.8, 1),  # removed: gaps / pinched
    "marks": ("#000000", 0.15, 3),  # alignment crosses, segment ticks, band edges, base and tip, s ruler
    "text": ("#404040", 0.15, 2),
    "changes": (CHANGE_COLOR, 0.3, 30),  # segments that change against the robot built last (--changes), and by how much
    "scale": ("#000000", 0.3, 6),  # the 10 cm scale bar: 100 mm in the file
}
TEXT_MM = 2.5  # text height


@dataclass
class Sheet:
    """A drawing in millimetres, y up, origin at the sheet's lower left corner."""

    width_mm: float
    height_mm: float
    lines: list = field(default_factory=list)  # (layer, [(x, y), ...], closed)
    layers: dict = field(default_factory=lambda: dict(LAYERS))  # LAYERS and each line's of several
    texts: list = field(default_factory=list)  # (layer, x, y, text, height, anchor: start | middle | end)

    def line(self, layer, points, closed=False):
        self.lines.append((layer, [(float(x), float(y)) for x, y in points], closed))

    def text(self, layer, x, y, text, height=TEXT_MM, anchor="start"):
        self.texts.append((layer, float(x), float(y), str(text), float(height), anchor))


def _sheet_strip(sh: Sheet, tables: list, geoms: list, tile, x0: float, y_ax: float, mm: float, mark: float) -> None:
    """One strip's band, marks, every line's path, labels and changes on the sheet, its lower left corner at (x0, y_ax)."""
    g = geoms[0]

    def xy(s, c):
        return x0 + (s - tile.s0) * mm, y_ax + (c - (tile.c0 - mark)) * mm

    s0, c0, s1, c1 = g.band
    sh.line("outline", [xy(s0, c0), xy(s1, c0), xy(s1, c1), xy(s0, c1)], closed=True)
    for r in g.shared:  # the part under the neighbouring strip
        sh.line("marks", [xy(r[0], r[1]), xy(r[2], r[1]), xy(r[2], r[3]), xy(r[0], r[3])], closed=True)
    for c in g.references:
        sh.line("marks", [xy(s0, c), xy(s1, c)])
    for p, q in g.crosses + g.ticks:
        sh.line("marks", [xy(*p), xy(*q)])
    for s, word in g.ends:
        sh.line("marks", [xy(s, tile.c0 - mark), xy(s, tile.c_end + mark)])
        x, y = xy(s, g.mark_c[1])
        sh.text("text", x + (1.0 if word == "base" else -1.0), y - 0.8, word, anchor="start" if word == "base" else "end")
    for t, gk in zip(tables, geoms):
        for kind, lines in gk.paths.items():
            for p, q in lines:
                sh.line(t["style"]["path"], [xy(*p), xy(*q)])
                if t["style"][kind][3]:
                    sh.line(t["style"][kind][3], [xy(*p), xy(*q)])
        for s, c, text in gk.starts:  # a triangle at the base pointing along the line, and its start
            x, y = xy(s, c)
            sh.line(t["style"]["path"], [(x, y - 1.0), (x + 1.7, y), (x, y + 1.0)], closed=True)
            sh.text(t["style"]["path"], x + 2.2, y + 0.3, text, 2.0)
    for s, c, text in g.labels:
        x, y = xy(s, c)
        sh.text("text", x, y - 0.7, text, 2.0, "middle")
    for lines, label in g.changes:
        for p, q in lines:
            sh.line("changes", [xy(*p), xy(*q)])
        if label is not None:
            x, y = xy(label[0], label[1])
            sh.text("changes", x, y - 0.7, label[2], 2.0, "middle")


def template_sheet(a: Archive, run: str, tables: list, lay: Layout) -> Sheet:
    """Every strip of ``lay`` stacked on one sheet at 1:1 in mm (the strips of the PDF, from
    :func:`strip_geometry`), with the title, the 10 cm scale bar and the legend."""
    k = CM_PER_UNIT[a.units]
    mm = 10.0 * k  # mm per problem unit
    D, u = a.diameter, a.units
    mark = MARK_H / mm
    heights = [(t.c_end - t.c0) * mm + 2 * MARK_H for t in lay.tiles]
    widths = [(t.s_end - t.s0) * mm for t in lay.tiles]
    W = 2 * MARGIN + LEFT_LABELS + RIGHT_ROOM + max(widths + [SCALE_BAR_CM * 10.0 + 90.0])
    H = 2 * MARGIN + TITLE_H + sum(h + STRIP_LABEL_H + TICKS_H + STRIP_GAP for h in heights) + FOOT_H
    sh = Sheet(W, H)
    for t in tables if "name" in tables[0] else ():  # each line's own layers, in its colour
        color = t["style"]["stopper"][0]
        sh.layers |= {t["style"]["path"]: (color, 0.2, 7), t["style"]["stopper"][3]: (color, 0.6, 7), t["style"]["gap"][3]: (GAP_COLOR, 0.8, 1)}
    head, tube, refused = _title(a, run, tables)
    sh.text("text", MARGIN, H - MARGIN - 3.0, f"{head}, {tube}", 3.0)
    for reason in refused:
        sh.text("text", MARGIN, H - MARGIN - 14.0, reason, 2.2)
    sh.text("text", MARGIN, H - MARGIN - 8.0, f"Drawn 1:1, true size at 100 % (the sheet's own unit is 1 mm); lengths, strips and the s ruler in {u}; "
            "s: length along the unactuated tube.", 2.2)
    sh.text("text", MARGIN, H - MARGIN - 11.0, "c = (D/2) \u03c6: position around the tube, wrapped at \u03c0D (both band edges are the "
            "same line on the tube).", 2.2)
    top = H - MARGIN - TITLE_H
    x0 = MARGIN + LEFT_LABELS
    for tile, ax_h in zip(lay.tiles, heights):
        y_ax = top - STRIP_LABEL_H - ax_h
        sh.text("text", x0, top - 3.5, tile.label + f" {u}")
        _sheet_strip(sh, tables, [strip_geometry(t, tile, D, u, t["spam"]) for t in tables], tile, x0, y_ax, mm, mark)
        # the s ruler under the strip: a tick every cm, labelled every 5 cm
        sh.line("marks", [(x0, y_ax), (x0 + (tile.s_end - tile.s0) * mm, y_ax)])
        for n in range(math.ceil(tile.s0 * k - 1e-9), math.floor(tile.s_end * k + 1e-9) + 1):
            x = x0 + (n / k - tile.s0) * mm
            sh.line("marks", [(x, y_ax), (x, y_ax - (3.0 if n % 5 == 0 else 1.5))])
            if n % 5 == 0:
                sh.text("text", x, y_ax - 5.5, f"{n / k:.4g}", 2.0, "middle")
        sh.text("text", x0 - 2.0, y_ax - 5.5, f"s [{u}]", 2.0, "end")
        top = y_ax - TICKS_H - STRIP_GAP
    # scale bar and legend
    bx, by = MARGIN, MARGIN + 9.0
    sh.line("scale", [(bx, by), (bx + SCALE_BAR_CM * 10.0, by)])
    for i in range(int(SCALE_BAR_CM) + 1):
        sh.line("scale", [(bx + 10.0 * i, by), (bx + 10.0 * i, by + (2.0 if i % 5 == 0 else 1.0))])
    sh.text("text", bx, by - 4.0, f"scale check: this bar must measure {SCALE_BAR_CM * 10:.0f} mm ({SCALE_BAR_CM:.0f} cm)", 2.2)
    lx = bx + SCALE_BAR_CM * 10.0 + 8.0
    legend = [(style[3], text) for style, text in _legend(tables)] + [("marks", "alignment marks; outlined: 1 cm overlap")]
    step = min(3.6, (FOOT_H + 3.0) / len(legend))
    for i, (layer, text) in enumerate(legend):
        y = by + 3.0 - step * i
        sh.text("text", lx, y - 0.8, f"[{layer}] {text}", 2.2)  # by layer name: nothing on the cut layers but the strips
    return sh


def sheet_svg(sheet: Sheet) -> bytes:
    """The sheet as SVG in millimetres (viewBox units = mm), one Inkscape layer per layer."""
    import xml.etree.ElementTree as ET

    ink = "http://www.inkscape.org/namespaces/inkscape"
    ET.register_namespace("", "http://www.w3.org/2000/svg")
    ET.register_namespace("inkscape", ink)
    W, H = sheet.width_mm, sheet.height_mm
    root = ET.Element("{http://www.w3.org/2000/svg}svg", {
        "width": f"{W:.3f}mm", "height": f"{H:.3f}mm", "viewBox": f"0 0 {W:.3f} {H:.3f}", "version": "1.1"})
    groups = {}
    for name, (color, width, _) in sheet.layers.items():
        groups[name] = ET.SubElement(root, "{http://www.w3.org/2000/svg}g", {
            "id": f"layer-{name}", f"{{{ink}}}groupmode": "layer", f"{{{ink}}}label": name,
            "fill": "none" if name != "text" else color, "stroke": color if name != "text" else "none",
            "stroke-width": f"{width:g}", "stroke-linecap": "butt"})
    for layer, pts, closed in sheet.lines:
        attrs = {"points": " ".join(f"{x:.4f},{H - y:.4f}" for x, y in pts)}
        ET.SubElement(groups[layer], "{http://www.w3.org/2000/svg}polygon" if closed else "{http://www.w3.org/2000/svg}polyline", attrs)
    for layer, x, y, text, height, anchor in sheet.texts:
        el = ET.SubElement(groups[layer], "{http://www.w3.org/2000/svg}text", {
            "x": f"{x:.4f}", "y": f"{H - y:.4f}", "font-size": f"{height:g}", "font-family": "sans-serif", "text-anchor": anchor,
            "fill": sheet.layers[layer][0], "stroke": "none"})  # filled in its layer's colour, whatever the layer strokes
        el.text = text
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def sheet_dxf(sheet: Sheet) -> bytes:
    """The sheet as DXF (R2010) in millimetres ($INSUNITS = 4), one DXF layer per layer."""
    import ezdxf
    from ezdxf import units
    from ezdxf.enums import TextEntityAlignment

    doc = ezdxf.new("R2010", setup=True)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1  # metric
    for name, (color, width, aci) in sheet.layers.items():  # a line of several: its own colour, exactly
        doc.layers.add(name, color=aci, lineweight=int(round(width * 100)), true_color=None if name in LAYERS else int(color[1:], 16))
    msp = doc.modelspace()
    for layer, pts, closed in sheet.lines:
        if len(pts) == 2 and not closed:
            msp.add_line(pts[0], pts[1], dxfattribs={"layer": layer})
        else:
            msp.add_lwpolyline(pts, close=closed, dxfattribs={"layer": layer})
    align = {"start": TextEntityAlignment.BOTTOM_LEFT, "middle": TextEntityAlignment.BOTTOM_CENTER,
             "end": TextEntityAlignment.BOTTOM_RIGHT}
    for layer, x, y, text, height, anchor in sheet.texts:
        msp.add_text(text, height=height, dxfattribs={"layer": layer}).set_placement((x, y), align=align[anchor])
    out = io.StringIO()
    doc.write(out)
    return out.getvalue().encode("utf-8")
