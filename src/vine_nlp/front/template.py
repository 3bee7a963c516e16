"""1:1 fabrication templates of a design (``vine-nlp template``), as in the paper's Fig. 12(a).

The tube is slit along c = 0 and unrolled: the horizontal axis is s, the length
along the unactuated tube, the vertical axis the circumferential position
c(s) = (D/2) phi(s), wrapped at the circumference pi D (the band; its two edges
are the same line on the tube). Within a segment the actuator path is straight
on the unrolled tube (dc/ds = tan theta), of length dl / cos(theta).

Each segment's path is split into the part that stays (stopper, or unpinched
material: blue, a fraction lambda of the path) and the part removed or pinched
(gap between stoppers, or material taped together: red, 1 - lambda). The red gap
is centred in its segment, so the stoppers of neighbouring segments meet at the
segment ends (drawn as small ticks). sPAM designs (actuator kind "spam") have one
lambda for the whole muscle: the path is drawn in one color, without stoppers.

Pages are drawn at real scale: 1 cm on paper is 1 cm of tube (problem units cm or
mm). A tube longer than a page is cut into strips, several per page when the
band is narrow; neighbouring strips share 1 cm (the shaded end of a strip, with
alignment crosses at both ends of the shared part), and a wide band is cut the
same way around the circumference. Every page carries a 10 cm scale bar.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from matplotlib.ticker import MultipleLocator  # noqa: E402

from vine_nlp.front.show import source_table  # noqa: E402
from vine_nlp.io.archive import Archive, load_archive, write_atomic  # noqa: E402
from vine_nlp.model.chain import phi_from_theta  # noqa: E402

PAPERS_MM = {"A4": (210.0, 297.0), "Letter": (215.9, 279.4)}
CM_PER_UNIT = {"cm": 1.0, "mm": 0.1}
STOPPER_COLOR = "#1f5fbf"  # blue: stays (stopper / unpinched)
GAP_COLOR = "#d62728"  # red: removed or pinched
SPAM_COLOR = "#6a3d9a"
CSV_COLUMNS = (
    "segment", "s_start", "s_end", "theta_deg", "lambda", "phi_start_rad", "phi_end_rad",
    "c_start", "c_end", "actuator_length", "stopper_length", "gap_length",
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


def pick_run(archive: Archive, run: str | None = None) -> str:
    """``run`` if given, else the archive's default run (``Archive.default_run``)."""
    if run is not None:
        if run not in archive.runs:
            raise ValueError(f"no run {run!r} in the archive (runs: {', '.join(archive.runs) or 'none'})")
        return run
    if not archive.runs:
        raise ValueError("the archive has no runs")
    return archive.default_run()


def cut_table(archive: Archive, run: str) -> dict:
    """Per-segment fabrication numbers (the CUTS.csv columns) as arrays, in the problem's units."""
    r = archive.runs[run].routing
    D = archive.diameter
    S = np.concatenate([[0.0], np.cumsum(r.length)])
    phi = phi_from_theta(r.theta, r.length, D)
    C = math.pi * D
    c = 0.5 * D * phi
    actuator = r.length / np.cos(r.theta)
    return {
        "segment": np.arange(r.segments),
        "s_start": S[:-1],
        "s_end": S[1:],
        "theta_deg": np.degrees(r.theta),
        "lambda": r.lam,
        "phi_start_rad": phi[:-1],
        "phi_end_rad": phi[1:],
        "c_start": wrap(c[:-1], C),
        "c_end": wrap(c[1:], C),
        "actuator_length": actuator,
        "stopper_length": r.lam * actuator,
        "gap_length": (1.0 - r.lam) * actuator,
    }


def wrap(c, circumference: float) -> np.ndarray:
    """Circumferential positions wrapped into [0, pi D)."""
    w = np.mod(np.asarray(c, float), circumference)
    return np.where(w >= circumference, 0.0, w)


def cuts_csv(table: dict) -> str:
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for i in range(len(table["segment"])):
        w.writerow([int(table["segment"][i])] + [f"{float(table[k][i]):.10g}" for k in CSV_COLUMNS[1:]])
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


def layout(length_cm: float, circumference_cm: float, paper: str, orientation: str = "auto", unit_per_cm: float = 1.0) -> Layout:
    """Strips and pages for a tube ``length_cm`` long with a band ``circumference_cm`` wide.

    orientation "auto" takes the orientation with fewer pages (then fewer strips; landscape on a tie).
    Tile coordinates are returned in problem units (``unit_per_cm`` units per cm).
    """
    name, (pw, ph) = _paper(paper)
    options = {"portrait": (pw, ph), "landscape": (ph, pw)}
    if orientation not in ("auto", *options):
        raise ValueError(f"orientation must be auto, portrait or landscape, not {orientation!r}")
    best = None
    for ori in (("landscape", "portrait") if orientation == "auto" else (orientation,)):
        W, H = options[ori]
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
    for i, (a, b, e) in enumerate(s_cuts):
        for j, (c0, c1, ce) in enumerate(c_cuts):
            k = len(tiles)
            u = unit_per_cm
            label = f"strip {k + 1}/{n}:  s = {a * u:.4g} to {b * u:.4g}"
            if len(c_cuts) > 1:
                label += f",  c = {c0 * u:.4g} to {c1 * u:.4g}"
            tiles.append(Tile(k, a * u, b * u, e * u, c0 * u, c1 * u, ce * u, label))
    return tiles, per_page


def write_template(archive_path_or_archive, pdf_path, csv_path=None, paper: str = "A4", run: str | None = None,
                   spam: bool | None = None, orientation: str = "auto") -> dict:
    """Write the 1:1 fabrication template of one run as a multi-page PDF (and CUTS.csv).

    run: default the first of nlp, greedy, forward present. spam: default from the
    archived problem file's [actuator] kind. Units must be cm or mm (ValueError
    otherwise). Both files are written atomically. Returns {"pages", "strips",
    "paper", "paper_mm" (width, height as printed), "orientation", "run", "spam",
    "segments", "stoppers" (segments drawn with a stopper/gap split), "gaps"
    (segments with a gap drawn), "tube_length"}.
    """
    a = archive_path_or_archive if isinstance(archive_path_or_archive, Archive) else load_archive(archive_path_or_archive)
    if a.units not in CM_PER_UNIT:
        raise ValueError(f"a 1:1 template needs lengths in cm or mm, not {a.units!r}")
    name = pick_run(a, run)
    spam = source_table(a, "actuator").get("kind") == "spam" if spam is None else bool(spam)
    table = cut_table(a, name)
    k = CM_PER_UNIT[a.units]
    D = a.diameter
    C = math.pi * D
    L = float(table["s_end"][-1]) if len(table["s_end"]) else 0.0
    lay = layout(L * k, C * k, paper, orientation, unit_per_cm=1.0 / k)

    def write_pdf(tmp):
        with PdfPages(tmp, metadata={"Title": f"{a.name} fabrication template ({name})", "Creator": "vine_nlp"}) as pdf:
            for page in range(lay.pages):
                pdf.savefig(_page(a, name, table, lay, page, spam))  # no bbox_inches: the page stays exactly the paper size
        if csv_path is not None:
            write_atomic(csv_path, lambda t: Path(t).write_text(cuts_csv(table)))

    write_atomic(pdf_path, write_pdf)
    return {
        "pages": lay.pages,
        "strips": len(lay.tiles),
        "paper": lay.paper,
        "paper_mm": (lay.width_mm, lay.height_mm),
        "orientation": lay.orientation,
        "run": name,
        "spam": spam,
        "segments": int(len(table["segment"])),
        **split_counts(table, spam),
        "tube_length": L,
    }


# ------------------------------------------------------------------ drawing


def _segment_parts(table, j, spam):
    """(t0, t1, kind) parts of segment j along its path: stopper, gap (centred), stopper; or one muscle part."""
    if spam:
        return [(0.0, 1.0, "muscle")]
    lam = float(table["lambda"][j])
    h = 0.5 * lam
    parts = [(0.0, h, "stopper"), (h, 1.0 - h, "gap"), (1.0 - h, 1.0, "stopper")]
    return [p for p in parts if p[1] - p[0] > 1e-9]


def _page(a: Archive, run: str, table: dict, lay: Layout, page: int, spam: bool):
    """One page of the template: a figure exactly the paper's size."""
    W, H = lay.width_mm, lay.height_mm
    k = CM_PER_UNIT[a.units]
    u = a.units
    D = a.diameter
    C = math.pi * D
    fig = Figure(figsize=(W / 25.4, H / 25.4))
    fx, fy = (lambda mm: mm / W), (lambda mm: mm / H)
    r = a.runs[run]
    lines = [
        f"{a.name}: fabrication template of run {run} ({r.method}), D = {D:.4g} {u}",
        f"tube length {float(table['s_end'][-1]):.4g} {u}, {len(table['segment'])} segments, circumference \u03c0D = {C:.4g} {u}. "
        "Print at 100 % (actual size, no fit to page): 1 cm on paper = 1 cm of tube.",
        "s: length along the unactuated tube. c = (D/2) \u03c6: position around the tube, wrapped at \u03c0D "
        "(both band edges are the same line on the tube).",
    ]
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
        _strip(ax, a, table, tile, spam, lay)
        fig.text(fx(MARGIN + LEFT_LABELS), fy(top - 0.5), tile.label + f" {u}", fontsize=FONT, va="top", ha="left")
        top = y_top - ax_h - TICKS_H - STRIP_GAP
    _footer(fig, W, H, spam, table)
    return fig


def _strip(ax, a: Archive, table: dict, tile: Tile, spam: bool, lay: Layout):
    k = CM_PER_UNIT[a.units]
    D = a.diameter
    C = math.pi * D
    cm = 1.0 / k  # one centimetre in problem units
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

    band_top = min(tile.c_end, C)
    band = Rectangle((tile.s0, tile.c0), tile.s_end - tile.s0, band_top - tile.c0, facecolor="0.96", edgecolor="none", zorder=0)
    ax.add_patch(band)
    for c, text in ((0.0, "c = 0"), (C, "c = \u03c0D")):
        if tile.c0 - 1e-9 <= c <= tile.c_end + 1e-9:
            ax.axhline(c, color="0.35", lw=0.6, ls=(0, (6, 3)), zorder=1)
    # shared parts (shaded: they go under the neighbouring strip) and alignment crosses at both of their ends
    shared = {"facecolor": "0.82", "edgecolor": "none", "zorder": 0.5}
    if tile.s_end > tile.s1 + 1e-12:
        ax.add_patch(Rectangle((tile.s1, tile.c0), tile.s_end - tile.s1, band_top - tile.c0, **shared))
    if tile.c_end > tile.c1 + 1e-12:
        ax.add_patch(Rectangle((tile.s0, tile.c1), tile.s_end - tile.s0, tile.c_end - tile.c1, **shared))
    s_marks = _shared_ends(tile.s0, tile.s1, tile.s_end, cm)
    c_marks = _shared_ends(tile.c0, tile.c1, tile.c_end, cm)
    outside = 0.5 * MARK_H / (10 * k)
    crosses = [(s, c) for s in s_marks for c in (tile.c0 - outside, band_top + outside)]
    crosses += [(s, c) for s in (tile.s0 + 0.5 * cm, tile.s_end - 0.5 * cm) for c in c_marks]  # around the tube: inside
    h = CROSS_MM / (10 * k)
    ax.add_collection(LineCollection([seg for s, c in crosses for seg in (((s - h, c), (s + h, c)), ((s, c - h), (s, c + h)))],
                                     colors="k", linewidths=0.5, clip_on=False, zorder=6))
    # base and tip
    if tile.s0 <= 0.0:
        ax.axvline(0.0, color="k", lw=0.8, ymin=0, ymax=1)
        ax.text(0.0, band_top + 0.5 * MARK_H / (10 * k), "  base", fontsize=FONT, ha="left", va="center")
    L = float(table["s_end"][-1])
    if tile.s_end >= L - 1e-9:
        ax.axvline(L, color="k", lw=0.8)
        ax.text(L, band_top + 0.5 * MARK_H / (10 * k), "tip  ", fontsize=FONT, ha="right", va="center")

    # the actuator path, clipped to this strip's part of the band
    clip = Rectangle((tile.s0, tile.c0), tile.s_end - tile.s0, band_top - tile.c0, transform=ax.transData, visible=False)
    ax.add_patch(clip)
    S0, S1 = table["s_start"], table["s_end"]
    c_unwrapped = 0.5 * D * np.concatenate([table["phi_start_rad"][:1], table["phi_end_rad"]])
    colors = {"stopper": STOPPER_COLOR, "gap": GAP_COLOR, "muscle": SPAM_COLOR}
    widths = {"stopper": 1.6, "gap": 2.4, "muscle": 1.6}
    lines = {kind: [] for kind in colors}
    ticks = []
    tick = 1.2 / (10 * k)  # segment-end ticks: 1.2 mm either side of the path
    last_label = -np.inf
    for j in range(len(S0)):
        if S1[j] < tile.s0 or S0[j] > tile.s_end:
            continue
        sa, sb, ca, cb = S0[j], S1[j], c_unwrapped[j], c_unwrapped[j + 1]
        for t0, t1, kind in _segment_parts(table, j, spam):
            lines[kind] += _pieces(sa + t0 * (sb - sa), ca + t0 * (cb - ca), sa + t1 * (sb - sa), ca + t1 * (cb - ca), C)
        # segment boundary tick across the path, and its index where there is room
        cw = float(table["c_start"][j])
        if tile.s0 <= sa <= tile.s_end:
            ticks.append(((sa, sa), (cw - tick, cw + tick)))
            room = min(sa - tile.s0, tile.s_end - sa) * k * 10  # mm to the strip's ends
            if (sa - last_label) * k * 10 >= 7.0 and room >= 2.5 and tile.c0 <= cw <= band_top:
                up = cw + 2.0 / (10 * k) if cw < band_top - 3.0 / (10 * k) else cw - 2.0 / (10 * k)
                ax.text(sa, up, str(j), fontsize=6, ha="center", va="center", color="0.25", zorder=5, clip_on=True)
                last_label = sa
    for kind, pieces in lines.items():
        if pieces:
            lc = LineCollection([np.transpose(p) for p in pieces], colors=colors[kind], linewidths=widths[kind],
                                capstyle="butt", zorder=3)
            ax.add_collection(lc)
            lc.set_clip_path(clip)
    if ticks:
        lc = LineCollection([np.transpose(p) for p in ticks], colors="k", linewidths=0.5, zorder=4)
        ax.add_collection(lc)
        lc.set_clip_path(clip)


def _shared_ends(a: float, b: float, end: float, cm: float) -> list[float]:
    """Where the alignment crosses of a piece from a to b (drawn to end) go: both ends of the
    centimetre shared with the previous piece (if a > 0) and with the next one (if end > b)."""
    marks = [a, a + min(OVERLAP_CM * cm, end - a)] if a > 0 else []
    marks += [b, end] if end > b + 1e-12 else []
    return sorted(set(round(v, 12) for v in marks))


def split_counts(table: dict, spam: bool) -> dict:
    """Segments drawn with a stopper/gap split ("stoppers") and with a gap ("gaps"); both 0 for sPAM."""
    counts = {"stoppers": 0, "gaps": 0}
    for j in range(len(table["segment"])):
        kinds = {p[2] for p in _segment_parts(table, j, spam)}
        counts["stoppers"] += int("stopper" in kinds and "gap" in kinds)
        counts["gaps"] += int("gap" in kinds)
    return counts


def _footer(fig, W, H, spam, table):
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
    items = ([(SPAM_COLOR, 1.6, f"sPAM muscle path, one \u03bb = {float(np.mean(table['lambda'])):.3g}")] if spam else
             [(STOPPER_COLOR, 1.6, "stays: stopper / unpinched (\u03bb)"), (GAP_COLOR, 2.4, "removed: gap / pinched (1 \u2212 \u03bb)")])
    items.append((None, 0, "+ alignment marks, shaded: 1 cm overlap"))
    for i, (color, lw, text) in enumerate(items):
        y = y0 + 3.0 - 3.6 * i
        if color is not None:
            fig.add_artist(Line2D([fx(lx), fx(lx + 7)], [fy(y), fy(y)], color=color, lw=lw))
        fig.text(fx(lx + 9), fy(y), text, fontsize=FONT, va="center", ha="left")
