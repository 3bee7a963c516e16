"""Size limits on what vine_nlp reads (archives, problem files, CSV data), in one place.

Each limit keeps one run within about 2 GB of memory on an ordinary machine; input
beyond it is refused with one line naming the limit (``InputError``) instead of
running out of memory or for days. The README lists them ("Limits").
"""

from __future__ import annotations

# Points of one target curve (target.samples, point files, archives' /target/points, /targets/<k>/points,
# /measured/points): the readers of problems and of archives share every limit, so what one writes the other reads.
MAX_TARGET_POINTS = 100_000
# Segments of one routing (problem files, archives' /runs/<run>/design/*).
# A forward run of that many segments takes about 8 s and stays under 1 GB of address space.
MAX_SEGMENTS = 100_000
# Rows of one modelled line in an archive (/runs/<run>/shape/*): forward runs sample each segment.
MAX_SHAPE_POINTS = 2_000_000
# Runs in one archive, levels of one multi-shape run ([[targets]]): reading one costs about 15 ms on a shared
# machine (h5py looks each name up), so 100 of them about 2 s.
MAX_RUNS = 100
MAX_LEVELS = 100
# Elements of any other dataset of an archive (measured points, frames, future groups).
MAX_DATASET_ELEMENTS = 10_000_000
# Characters of a text attribute (the archived problem file's source, solver options).
MAX_TEXT_CHARS = 10_000_000
# Bytes of an input file (archives, CSV and .npy point files); CSV is read line by line.
MAX_FILE_BYTES = 1 << 30
# Bytes of a TOML file (problem, sweep, calibration): with a sweep item's note, an archive's source.
MAX_TOML_BYTES = 8 << 20
MAX_NOTE_CHARS = 2_000
# Characters of one line of a CSV point file.
MAX_LINE_CHARS = 10_000
# Bytes of a mesh file (.stl, .obj, .ply): one of MAX_MESH_FACES faces (io/obstacles.py) takes under 8 MB in any of them.
MAX_MESH_BYTES = 16 << 20
# An archive as a whole (declared sizes, checked before reading): values of all datasets, objects.
# Objects and attributes cost about 1 ms each to check (5 000: a few seconds); groups nest at most
# MAX_ARCHIVE_DEPTH deep (a name is looked up part by part: 2 000 nested groups took minutes).
MAX_ARCHIVE_VALUES = 40_000_000
MAX_ARCHIVE_OBJECTS = 5_000
MAX_ARCHIVE_DEPTH = 16
# Names and one-line texts (names, units, keys, obstacle names): printable characters only.
MAX_NAME_CHARS = 255
MAX_UNITS_CHARS = 32
# Coordinates and lengths (in units), a problem's span in tube diameters: float64's working range.
MAX_COORDINATE = 1e9
MAX_DIAMETERS = 1e6
MIN_DIAMETERS = 1e-6
# Angles of a routing: |theta| below 90 deg (at 90 deg the actuator line winds around the tube without end).
MAX_THETA_DEG = 90.0
_RAD = 0.017453292519943295  # pi / 180
# The actuator line's length, sum l_j / cos(theta_j), over the tube's: at most MAX_WINDING (a line wound at 89.4 deg
# all along). Commands sample the line by its length: at 89.9 deg (520x) analyze and animate need more than 1 GB,
# just below 90 deg template asks for terabytes.
MAX_WINDING = 100.0


# The one set of per-segment rules of a routing, wherever it is read (problem files, the Python API, archives:
# io.validate.validate_routing, routing_rule): (name, the values that keep it, the rule, the value as shown, unit).
ROUTING_RULES = (
    ("theta", lambda t: abs(t) < MAX_THETA_DEG * _RAD, f"|theta| must be < {MAX_THETA_DEG:g} deg", lambda t: t / _RAD, " deg"),
    ("lambda", lambda v: (v > 0) & (v <= 1), "must be in (0, 1]", float, ""),
    ("length", lambda v: v > 0, "must be > 0", float, ""),
)


def routing_rule(theta, lam, length, diameter: float) -> tuple[str, str] | None:
    """The first rule a routing (per-segment theta in rad, lambda, length; the tube's diameter) breaks, as
    (``theta`` | ``lambda`` | ``length``, reason), or None: at least one segment, every value finite,
    ROUTING_RULES, and a whole length within MAX_COORDINATE and MIN_DIAMETERS..MAX_DIAMETERS tube diameters."""
    import numpy as np

    if len(theta) < 1:
        return "theta", "a routing needs at least one segment"
    for (name, ok, rule, shown, unit), values in zip(ROUTING_RULES, (theta, lam, length)):
        values = np.asarray(values, float)
        good = np.isfinite(values) & ok(np.where(np.isfinite(values), values, 0.0))
        if not good.all():
            j = int(np.argmin(good))
            return name, f"{rule} (segment {j + 1}: {shown(values[j]):.6g}{unit})"
    if reason := winding_rule(theta, length):
        return "theta", reason
    total = float(np.sum(length))
    if total > MAX_COORDINATE:
        return "length", f"the tube is {total:.4g} long: at most {MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE)"
    if not MIN_DIAMETERS * diameter <= total <= MAX_DIAMETERS * diameter:
        return "length", (f"the tube is {total:.4g} long, {total / diameter:.4g} tube diameters: must be {MIN_DIAMETERS:g} to "
                          f"{MAX_DIAMETERS:g} (vine_nlp.io.limits.MIN_DIAMETERS, MAX_DIAMETERS)")
    return None


def winding_rule(theta, length) -> str | None:
    """Why a routing's actuator line is too long for the tube (MAX_WINDING), or None; theta within MAX_THETA_DEG."""
    import numpy as np

    share = np.asarray(length, float) / np.sum(length)  # <= 1: no overflow below
    factor = float(np.sum(share / np.cos(np.asarray(theta, float))))
    if factor <= MAX_WINDING:
        return None
    return (f"the actuator line is {factor:.4g} times as long as the tube (theta near 90 deg): at most {MAX_WINDING:g} "
            "(vine_nlp.io.limits.MAX_WINDING)")


# Command-line numbers (front/cli.py), each bounding what it costs: Monte Carlo samples of analyze (and
# samples x segments <= MAX_DATASET_ELEMENTS), starts and basin-hopping rounds of a design, frames of a
# movie (about 55 ms of CPU each, both panels of a trefoil design: 150 in about 9 s of one core; measured on a shared
# 2-core machine, whose wall time was 2-3x that), processes, seconds of a budget (a week).
MAX_SAMPLES = 100_000
MAX_STARTS = 1_000
MAX_HOPS = 1_000
MAX_FRAMES = 150
MAX_FPS = 120
MAX_WORKERS = 1_024
MAX_SEED = 2**32 - 1
MAX_SECONDS = 604_800.0
# What one command draws, meshes or analyzes within about 10 s and 1 GB (measured on a shared 2-core machine,
# a tube at both limits at once): segments and tube length in diameters of the runs it uses (plot and view: all
# runs together), lower than MAX_SEGMENTS and MAX_DIAMETERS, which only the reader and forward reach. Templates
# are 1:1: at most MAX_TEMPLATE_MM of tube (PDF pages; SVG and DXF: 5 m in 2-9 s). Beyond them the command says so in one line.
COMMAND_LIMITS = {"plot": (5_000, 300), "view": (5_000, 300), "animate": (5_000, 300), "export": (5_000, 300),
                  "template": (5_000, 300), "analyze": (2_000, 200)}
MAX_TEMPLATE_MM = 5_000.0
# Items of a sweep one view shows (each item's archive is loaded and drawn: about 50 ms each).
MAX_VIEW_ITEMS = 200
