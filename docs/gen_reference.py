"""Reference pages generated from the code that they describe, so the two cannot drift apart.

Used two ways:

* as a MkDocs hook (``hooks:`` in mkdocs.yml): at every build it adds the pages
  ``reference/formats.md`` and ``reference/cli.md`` to the site;
* as a script: ``python3 docs/gen_reference.py formats|cli`` prints a page (``contract``: what
  docs/reference/contract.md, the lab's contract, names that the code no longer has).

The format page is made from the validators themselves:

* the keys a problem or sweep file may hold are the key tables that the reader in
  ``vine_nlp.io`` checks every file against (``_TOP_KEYS``, ``_CURVE_KEYS``, ...), and
  the allowed values are the choice tuples it checks values against;
* every key needs a description in ``DESCRIPTIONS`` below, and every description a key
  the validator accepts: a key added to (or removed from) a validator without the page
  following stops the build, and so does a key table this file does not know yet;
* every example shown is a bundled problem file, loaded through the same reader at
  build time (a file the reader rejects stops the build);
* the archive layout is ``vine_nlp.io.layout.CORE_LAYOUT``, checked against archives that
  the command line writes at build time (a small design and a forward problem) and that
  the archive reader reads back.

The command-line page is made from ``vine_nlp.front.cli.build_parser()``.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import re
import sys
import tempfile
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"

# Where the file readers live; the first module that defines a table is used (the reader is
# being split into problems / sweep_file / data_files / validate: all are looked at).
READER_MODULES = (
    "vine_nlp.io.validate",
    "vine_nlp.io.problems",
    "vine_nlp.io.sections",
    "vine_nlp.io.sweep_file",
    "vine_nlp.io.data_files",
    "vine_nlp.io.problem_file",
)
CHOICE_MODULES = ("vine_nlp.model.routing", "vine_nlp.problem", *READER_MODULES)


class DriftError(RuntimeError):
    """The reference and the code it describes disagree."""


# ------------------------------------------------------------------ descriptions
# One entry per key the validators accept. Lengths are in the file's `units`.
DESCRIPTIONS = {
    "top": {
        "name": "Name of the problem, stored in archives (default: the file name without `.toml`).",
        "units": 'Length unit of every length in the file and in its archives (default `"cm"`).',
        "tube": "Table `[tube]`: the tube.",
        "target": "Table `[target]`: the curve to design for (a **design** problem).",
        "targets": "Array of tables `[[targets]]`: one target per pressure level (a **multishape** sPAM problem).",
        "actuators": "Array of tables `[[actuators]]`: several actuators on one tube (with `[[states]]`; tutorial 10).",
        "states": "Array of tables `[[states]]`: the states of a tube with `[[actuators]]`: the actuators pulled, a target each.",
        "actuator": "Table `[actuator]`: kind of actuator and its bounds.",
        "design": "Table `[design]`: solver options.",
        "routing": "Table `[routing]`: a given routing (a **forward** problem, or the known routing of a **fit**); in a **design** problem only `initial_pose`, the base of `[design] base = \"fixed\"`.",
        "measured": "Table `[measured]`: points measured on a built robot (a **fit** problem).",
        "fit": "Table `[fit]`: what a fit estimates besides the rigid pose.",
        "tip": "Table `[tip]`: a tip position and direction to reach (a **tip** problem).",
        "obstacles": "Array of tables `[[obstacles]]`: obstacles the tube must keep clear of (see below).",
        "calibration": "Table `[calibration]`, or the name of a file holding one (as `vine-nlp calibrate` writes): systematic construction errors the design compensates.",
        "load": "Table `[load]`: self-weight and payload, in SI units (a **design** or **forward** problem; see below).",
    },
    "tube": {
        "diameter": "Tube diameter D (> 0).",
    },
    "target": {
        "curve": "Kind of target curve (choices below); decides which other keys apply.",
        "scale": "trefoil: `[m_x, m_y, m_z]` of the paper's knot equation.",
        "t_range": "trefoil: `[start, end]` of the curve parameter t (default `[-0.2 pi, 1.5 pi]`).",
        "samples": "Number of target points: equally spaced in t (trefoil, bezier) or in arc length (polyline, helix).",
        "control_points": "bezier, polyline: list of points `[x, y, z]` (2-D points mean z = 0).",
        "radius": "helix: radius of the target helix.",
        "pitch": "helix: pitch parameter b (the helix rises 2 pi b per turn).",
        "length": "helix: arc length of the target helix (> 0).",
        "file": "points: a data file of N rows `x y z`, base to tip (`.csv`, a header row allowed, or `.npy`).",
    },
    "actuator": {
        "kind": "`tendon` (tendon and stoppers), `programmed` (mechanically programmed) or `spam` (one lambda for the whole actuator).",
        "lambda_min": "Least contraction ratio lambda allowed, in (0, 1] (default 0.4; 0.5 for `spam`).",
        "theta_max_deg": "Largest drawn angle |theta| allowed, in degrees, in (0, 90) (default 60).",
    },
    "design": {
        "method": "`nlp` (one nonlinear program) or `greedy` (the paper's Algorithm 1).",
        "points_per_segment": "n: target points per helical segment (>= 1).",
        "lookahead": "k: segments per window of the greedy method (>= 1).",
        "starts": "Starts of the NLP's multi-start; the best design is kept (>= 1).",
        "hops": "Rounds of basin hopping after the starts, for targets with corners (>= 0; design problems only).",
        "greedy_starts": "Random trial starts per window of the greedy method (>= 1).",
        "seed": "Seed of every random choice (starts, hops, greedy trials) (>= 0).",
        "max_iter": "IPOPT iteration limit (>= 1).",
        "tol": "IPOPT tolerance (> 0).",
        "hessian": "Hessian of the NLP: `auto` (Gauss-Newton, exact where that does not converge), `exact` or `gauss-newton`.",
        "solver": "`auto` (default) or `ipopt`: both solve with IPOPT (the key is kept for existing files).",
        "budget": "Seconds the NLP's corner search may take where the first solve shows a corner-like target (>= 0, default 20; 0: off; design problems only).",
        "smoothness": "Table `[design.smoothness]`: weights of the smoothness terms.",
        "shared_pose": "multishape: all levels grow from one base pose (default true).",
        "obstacle_margin": "Required gap between the tube surface and every obstacle, in `units`.",
        "growth": "`while-actuated` (the tube grows already actuated) or `after` (the intermediate shapes of actuation after growth must clear the obstacles too).",
        "correction_margin": "Buildable designs: every lambda is exactly 1 (no actuator) or inside [lambda_min + margin, 1 - margin], so an as-built error can be corrected both ways (>= 0, default 0.05).",
        "min_feature": "Smallest stopper gap, pinch, pouch or piece, in `units` (>= 0; default 2 mm in the file's units).",
        "base": '`free` (the design chooses the base pose, with no arbitrary roll) or `fixed` (the pose is `[routing] initial_pose`).',
    },
    "design.smoothness": {
        "theta": "w_theta of (1/L) int (D theta')^2 ds against the mean squared error / D^2 (>= 0).",
        "lambda": "w_lambda of (1/L) int (D lambda')^2 ds (>= 0).",
    },
    "routing": {
        "length": "Total unactuated tube length L (> 0); with a `segment_length` array optional, and if given their sum.",
        "segment_length": "Length of each segment (the last one takes the rest) (> 0, <= length), or an array of one length per segment (each > 0): then M is its size.",
        "theta": "Drawn angle per segment, rad: a number, an array (one per segment) or an expression of s.",
        "theta_deg": "The same in degrees (instead of `theta`).",
        "phi": "Actuator angle around the tube at the segment ends, rad: a number, an array of M+1 values or an expression of s (instead of `theta`); with an expression theta_j = arctan((D/2) (phi(s_j+1) - phi(s_j)) / (s_j+1 - s_j)).",
        "lambda": "Contraction ratio per segment: a number, an array (one per segment) or an expression of s, in (0, 1].",
        "initial_pose": "4 x 4 pose T^0_w of the base (a rotation and a translation; default the identity).",
    },
    "measured": {
        "file": "Data file of measured points, rows `x y z` in any order and any pose (`.csv` or `.npy`).",
        "line": "Which line was measured: `center`, `inner` (actuator) or `outer` (opposite).",
    },
    "fit": {
        "free": 'What is estimated besides the rigid pose: `[]` or `["lambda"]`.',
    },
    "tip": {
        "position": "Tip position `[x, y, z]` to reach.",
        "direction": "Tip tangent `[x, y, z]` (optional; normalized on reading).",
        "length": "Tube length L, a design input.",
        "segments": "Number of segments M (each at least 0.2 L / M long).",
        "objective": "`contraction`: least sum (1 - lambda) dl; `turns`: least sum |tan theta| dl.",
        "initial_pose": "Fixed 4 x 4 base pose (default the identity).",
    },
    "obstacles": {
        "shape": "Kind of obstacle (the shapes below); decides which other keys apply.",
        "name": "Optional name, shown in reports and figures.",
        "center": "sphere, box: center `[x, y, z]`.",
        "radius": "sphere, capsule: radius.",
        "size": "box: edge lengths `[x, y, z]`.",
        "rotation": "box: 3 x 3 rotation matrix of the box's axes (optional).",
        "rotation_deg": "box: the rotation as x, y, z angles in degrees (optional; instead of `rotation`).",
        "p0": "capsule: one end of its axis `[x, y, z]`.",
        "p1": "capsule: the other end.",
        "point": "plane: a point on the plane.",
        "normal": "plane: its normal; the free side is along the normal.",
        "file": "mesh: a closed triangle mesh (`.stl`, `.obj`, `.ply`), relative to the problem file.",
    },
    "calibration": {
        "lambda_offset": "Built lambda = nominal lambda + this (within +-0.5).",
        "theta_offset_deg": "Built theta = nominal theta + this, in degrees (within +-45).",
        "length_scale": "Built segment length = nominal length times this (> 0).",
        "lambda_offset_se": "Standard error of `lambda_offset` (>= 0).",
        "theta_offset_deg_se": "Standard error of `theta_offset_deg` (>= 0).",
        "length_scale_se": "Standard error of `length_scale` (>= 0).",
        "prototypes": "Number of built prototypes the calibration was estimated from (>= 0).",
    },
    "load": {
        "gravity": "`[gx, gy, gz]` in m/s^2, in the problem's world frame (default `[0, 0, -9.81]`).",
        "pressure": "The tube's gauge pressure, kPa (> 0; required).",
        "mass_per_length": "kg per metre of grown tube: wall, actuators, everything grown (>= 0; required).",
        "tip_mass": "kg, a payload at the tip (>= 0; default 0).",
        "safety": "Every bending moment stays below capacity / safety (>= 1; default 1; not under zero gravity).",
    },
    "sweep": {
        "name": "Name of the sweep; items are named `<name>-<index:04d>` (letters, digits, `. _ + -`).",
        "base": "The design problem file each item changes, relative to the sweep file.",
        "methods": "Methods run on every item (any of the design methods).",
        "grid": "Table of dotted key paths to lists of values; the items are their cartesian product, in file order.",
    },
}

# Described before every reader accepts them (the obstacle problems are landing): no error while unused.
LANDING = {
    ("top", "obstacles"),
    ("top", "calibration"),
    *(
        ("calibration", k)
        for k in (
            "lambda_offset",
            "theta_offset_deg",
            "length_scale",
            "lambda_offset_se",
            "theta_offset_deg_se",
            "length_scale_se",
            "prototypes",
        )
    ),
    ("design", "obstacle_margin"),
    ("design", "growth"),
    *(
        ("obstacles", k)
        for k in ("shape", "name", "center", "radius", "size", "rotation", "rotation_deg", "p0", "p1", "point", "normal", "file")
    ),
}

# Validator table name -> (section in DESCRIPTIONS, what the table is).
KEY_TABLES = {
    "_ACTUATOR_KEYS": ("actuator", None),
    "_DESIGN_KEYS": ("design", "design"),
    "_MULTISHAPE_DESIGN_KEYS": ("design", "multishape"),
    "_OTHER_DESIGN_KEYS": ("design", "tip"),
    "_TIP_DESIGN_KEYS": ("design", "tip"),
    "_SMOOTHNESS_FIELDS": ("design.smoothness", None),
    "_ROUTING_KEYS": ("routing", None),
    "_MEASURED_KEYS": ("measured", None),
    "_FIT_KEYS": ("fit", None),
    "_TIP_KEYS": ("tip", None),
    "_SWEEP_KEYS": ("sweep", None),
    "_ALL_TARGET_KEYS": ("target", None),
}
# Tables the page uses in other ways (per kind, per curve) or that are derived from the above.
OTHER_TABLES = {"_BUILD_KEYS", "_TOP_KEYS", "_ALL_TOP_KEYS", "_CURVE_KEYS", "_OPTION_INTS", "_ANGLE_KEYS", "_CURVE_MAIN_KEY"}
CHOICES = {
    "ACTUATOR_KINDS": "`[actuator] kind`",
    "METHODS": "`[design] method`, a sweep's `methods`",
    "HESSIANS": "`[design] hessian`",
    "SOLVERS": "`[design] solver`",
    "MEASURED_LINES": "`[measured] line`",
    "TIP_OBJECTIVES": "`[tip] objective`",
    "FREE_CHOICES": "entries of `[fit] free`",
}
LIMITS = {
    "MAX_TARGET_POINTS": "target points of a curve (`samples`) or a point file",
    "MAX_SEGMENTS": "segments of a routing",
    "MAX_SWEEP_ITEMS": "items of a sweep",
    "MAX_LEVELS": "`[[targets]]` of a multishape problem",
    "MAX_TIP_SEGMENTS": "`segments` of a tip problem",
    "MAX_TOML_BYTES": "bytes of a problem, sweep or calibration file",
    "MAX_LINE_CHARS": "characters of a line of a CSV point file",
    "MAX_UNITS_CHARS": "characters of `units`",
    "MAX_NAME_CHARS": "characters of a name or key",
    "MAX_COORDINATE": "magnitude of a coordinate, length or diameter, in `units`",
    "MAX_DIAMETERS": "span of a target, routing or measurement, in tube diameters",
    "MIN_DIAMETERS": "(at least) span of a target, routing or measurement, in tube diameters",
}
EXAMPLES = {
    "design": "trefoil-m4.toml",
    "forward": "static-helix.toml",
    "fit": "fit-active-helix.toml",
    "multishape": "multishape-spam.toml",
    "tip": "tip-target.toml",
}


# ------------------------------------------------------------------ helpers
def _modules(names):
    found = []
    for name in names:
        try:
            found.append(importlib.import_module(name))
        except ModuleNotFoundError as exc:
            if exc.name != name:  # the module exists but one of its imports is missing: a real error
                raise
    return found


def _lookup(name: str, modules):
    for m in modules:
        if hasattr(m, name):
            return getattr(m, name), m.__name__
    raise DriftError(f"no reader module defines {name} (looked in {', '.join(m.__name__ for m in modules)})")


def _code(values) -> str:
    return ", ".join(f"`{v}`" for v in values)


def _cell(text: str) -> str:
    """Text safe inside a Markdown table cell."""
    return text.replace("|", "\\|")


def _key_table(section: str, keys, problems: list) -> list[str]:
    described = DESCRIPTIONS[section]
    lines = ["| key | meaning |", "|---|---|"]
    for key in keys:
        if key not in described:
            problems.append(f"{section}.{key}: accepted by the reader but not described in docs/gen_reference.py")
            continue
        lines.append(f"| `{key}` | {_cell(described[key])} |")
    return lines


# ------------------------------------------------------------------ formats page
def formats_page(archives: bool = True) -> str:
    """The file-format reference as Markdown; raises DriftError where the code and the page disagree.

    ``archives=False`` leaves out the archive layout (which solves two small problems).
    """
    readers = _modules(READER_MODULES)
    choice_modules = _modules(CHOICE_MODULES)
    problems: list[str] = []
    used: dict[str, set] = {section: set() for section in DESCRIPTIONS}
    origin = set()

    def table(name):
        value, module = _lookup(name, readers)
        origin.add(module)
        return value

    # every key table the readers define must be one this page knows
    for m in readers:
        for name in vars(m):
            if re.fullmatch(r"_[A-Z_]*_(KEYS|FIELDS)", name) and name not in KEY_TABLES and name not in OTHER_TABLES:
                problems.append(f"{m.__name__}.{name}: a key table this page does not describe yet")

    out = [
        "# File formats",
        "",
        '!!! note "Generated"',
        "    This page is generated at every documentation build by `docs/gen_reference.py` from the",
        "    code that validates the files: the key tables and choices below are the ones the reader",
        "    checks every file against, every example is a bundled problem loaded by that reader, and",
        "    the archive layout is checked against archives written and read back during the build.",
        "",
        "The contract is version 1 of [the lab's file and command contract](contract.md); this page is",
        "the version you have installed. Lengths are in the file's `units` (default `cm`); angles are",
        "radians unless the key ends in `_deg`. Paths inside a file are relative to that file.",
        "A bad file gives one line `error: <file>: <key>: <reason>` and exit status 2.",
        "",
        "## Problem files (TOML)",
        "",
        "The tables a file holds decide its kind; each kind accepts these top-level keys:",
        "",
        "| kind | decided by | top-level keys |",
        "|---|---|---|",
    ]
    top = table("_TOP_KEYS")
    decided = {
        "design": "`[target]`",
        "forward": "`[routing]` only",
        "fit": "`[measured]`",
        "multishape": "`[[targets]]`",
        "tip": "`[tip]`",
        "actuators": "`[[actuators]]`, `[[states]]` (forward: with `[routing]`)",
    }
    for kind, keys in top.items():
        if kind not in decided:
            problems.append(f"problem kind {kind!r}: not described in docs/gen_reference.py")
        out.append(f"| {kind} | {decided.get(kind, '?')} | {_code(keys)} |")
    all_top = list(dict.fromkeys(k for keys in top.values() for k in keys))
    out += ["", "### Top-level keys", "", *_key_table("top", all_top, problems)]
    used["top"].update(all_top)

    out += ["", "### `[tube]`", "", *_key_table("tube", ["diameter"], problems)]
    used["tube"].add("diameter")

    out += ["", "### `[target]`", ""]
    curves = table("_CURVE_KEYS")
    target_keys = table("_ALL_TARGET_KEYS")
    out += _key_table("target", target_keys, problems)
    used["target"].update(target_keys)
    out += ["", "Keys used by each `curve` (any other key is an error):", "", "| curve | keys |", "|---|---|"]
    for curve, keys in curves.items():
        out.append(f"| `{curve}` | {_code(keys)} |")
    out += [
        "",
        "Each `[[targets]]` table of a multishape problem takes the same keys, plus an optional",
        "`lambda` that fixes the contraction of that level.",
    ]

    # one table per section; a section read with different key tables per problem kind
    # ([design]) gets a column per kind saying which keys that kind accepts
    by_section: dict[str, list] = {}
    for name, (section, kind) in KEY_TABLES.items():
        if section not in ("target", "sweep"):
            by_section.setdefault(section, []).append((kind, list(table(name))))
    for section, variants in by_section.items():
        keys = list(dict.fromkeys(k for _, ks in variants for k in ks))
        used[section].update(keys)
        out += ["", f"### `[{section}]`", ""]
        if len(variants) == 1:
            out += _key_table(section, keys, problems)
            continue
        kinds = [kind for kind, _ in variants]
        out += [
            "| key | " + " | ".join(kinds) + " | meaning |",
            "|---|" + "---|" * len(kinds) + "---|",
        ]
        for key in keys:
            if key not in DESCRIPTIONS[section]:
                problems.append(f"{section}.{key}: accepted by the reader but not described in docs/gen_reference.py")
                continue
            marks = " | ".join("yes" if key in ks else "" for _, ks in variants)
            out.append(f"| `{key}` | {marks} | {_cell(DESCRIPTIONS[section][key])} |")

    build = list(table("_BUILD_KEYS"))
    used["design"].update(build)
    out += ["", "`[design]` keys of design problems for buildable designs:", "", *_key_table("design", build, problems)]
    if "obstacles" in all_top:
        out += obstacles_section(used, problems)
    if "calibration" in all_top:
        calibration = importlib.import_module("vine_nlp.io.calibration")
        used["calibration"].update(calibration.KEYS)
        out += ["", "### `[calibration]`", "", *_key_table("calibration", calibration.KEYS, problems)]
        out += [
            "",
            'A design problem may hold the table inline or name a file: `calibration = "CAL.toml"`',
            "(relative to the problem file), as `vine-nlp calibrate` writes it.",
        ]

    if "load" in all_top:
        loads = importlib.import_module("vine_nlp.io.loads")
        used["load"].update(loads.KEYS)
        out += ["", "### `[load]`", "", *_key_table("load", loads.KEYS, problems)]
        out += [
            "",
            "SI units whatever the file's `units` (which must be m, cm, mm or in). Every run of the problem gets the",
            "metrics `load_margin`, `collapse_at` and `min_pressure`; a run that does not hold with its safety factor",
            "is not ok (exit 1). The model and its assumptions: the tutorial *Will it stand?*.",
        ]

    out += ["", "### Choices", "", "| value of | allowed |", "|---|---|"]
    for name, where in CHOICES.items():
        values, module = _lookup(name, choice_modules)
        out.append(f"| {where} | {_code(values)} |")
    out += ["", "### Limits", "", "Guards against inputs that would exhaust memory:", "", "| limit | at most |", "|---|---|"]
    for name, what in LIMITS.items():
        value, _ = _lookup(name, [*readers, *_modules(["vine_nlp.io.limits"])])
        out.append(f"| {what} | {value:,} |" if isinstance(value, int) else f"| {what} | {value:g} |")

    out += ["", "### Expressions", ""]
    out += [
        "`theta`, `phi` and `lambda` of a routing may be expressions of `s` (length along the",
        "unactuated tube) with `+ - * / **`, parentheses, numbers, `pi`, `e` and",
        "`sin cos tan exp log sqrt abs`. They are parsed by a whitelist, never handed to",
        "`eval`. A per-segment value is taken at the segment's start.",
    ]

    # the bundled problems, each loaded by the reader
    load_problem, _ = _lookup("load_problem", readers)
    out += ["", "### Examples (bundled problems, each loaded by the reader at build time)", ""]
    for kind, file in EXAMPLES.items():
        path = PROBLEMS / file
        pf = load_problem(path)
        if pf.kind != kind:
            problems.append(f"{file}: read as a {pf.kind} problem, shown as {kind}")
        out += [f"#### {kind}: `problems/{file}`", "", "```toml", path.read_text().rstrip(), "```", ""]

    # sweeps
    sweep_path = PROBLEMS / "sweeps" / "trefoil125.toml"
    load_sweep, _ = _lookup("load_sweep", readers)
    sweep = load_sweep(sweep_path)
    sweep_keys = table("_SWEEP_KEYS")
    used["sweep"].update(sweep_keys)
    out += [
        "## Sweep files (TOML)",
        "",
        *_key_table("sweep", sweep_keys, problems),
        "",
        "A grid key is a dotted path into the base problem; an integer picks an array element",
        '(`"target.scale.0"`). Output: `DIR/<item>.h5` per item, `DIR/summary.csv` (one row per item',
        "and method: `item`, each grid key, `method`, `status`, `rmse`, `max_error`,",
        "`solve_time_s`) and `DIR/summary.png`. The same sweep into the same DIR skips finished items.",
        "",
        f"Example: `problems/sweeps/trefoil125.toml` ({len(sweep.items())} items, loaded by the reader at build time):",
        "",
        "```toml",
        sweep_path.read_text().rstrip(),
        "```",
        "",
    ]

    if archives:
        out += archive_section(problems)

    for section, described in DESCRIPTIONS.items():
        for key in described:
            if key not in used[section] and (section, key) not in LANDING:
                problems.append(f"{section}.{key}: described in docs/gen_reference.py but no reader accepts it")
    out += ["", f"<small>Generated from {', '.join(sorted(origin))}.</small>", ""]
    if problems:
        raise DriftError("the format reference and the readers disagree:\n  " + "\n  ".join(problems))
    return "\n".join(out)


def obstacles_section(used: dict, problems: list) -> list[str]:
    """`[[obstacles]]` from the obstacle reader's own tables (keys per shape, required keys, datasets)."""
    obstacles = importlib.import_module("vine_nlp.io.obstacles")
    analysis = importlib.import_module("vine_nlp.analysis.obstacles")
    keys = list(dict.fromkeys([*obstacles._COMMON, *(k for ks in obstacles._KEYS.values() for k in ks)]))
    used["obstacles"].update(keys)
    used["design"].update(obstacles.DESIGN_KEYS)
    out = ["", "### `[[obstacles]]`", "", *_key_table("obstacles", keys, problems)]
    out += ["", "Keys of each `shape` (**bold**: required; `shape` and `name` apply to all):", ""]
    out += ["| shape | keys | archive datasets `/obstacles/<k>/...` |", "|---|---|---|"]
    for shape, ks in obstacles._KEYS.items():
        required = set(obstacles._REQUIRED.get(shape, ()))
        shown = ", ".join(f"**`{k}`**" if k in required else f"`{k}`" for k in ks)
        data = ", ".join(
            f"`{name}` ({', '.join('n' if d is None else str(d) for d in dims)}{',' if len(dims) == 1 else ''})"
            for name, dims in obstacles._DATASETS.get(shape, {}).items()
        )
        out.append(f"| `{shape}` | {shown} | {data} |")
    out += [
        "",
        f"`[design]` keys for obstacles: {_code(obstacles.DESIGN_KEYS)}; `growth` is one of "
        f"{_code(analysis.GROWTH_MODES)} (default `{obstacles.DEFAULT_GROWTH}`). At most "
        f"{obstacles.MAX_OBSTACLES:,} obstacles, meshes of at most {obstacles.MAX_MESH_FACES:,} faces "
        f"({_code(obstacles.MESH_SUFFIXES)}), closed (watertight). Each obstacle is stored as "
        "`/obstacles/<k>` with attribute `shape`; runs get the metric `min_obstacle_gap` (tube surface "
        "to the nearest obstacle; negative is penetration).",
    ]
    return out


def _walk(h5) -> dict:
    """Every group and dataset of an HDF5 file: path with run names as ``<run>`` -> (kind, shape, attrs)."""
    import h5py

    from vine_nlp.io.layout import RUN

    found = {"/": ("group", None, set(h5.attrs))}

    def visit(name, obj):
        parts = name.split("/")
        if parts[0] == "runs" and len(parts) >= 2:
            parts[1] = RUN
        path = "/" + "/".join(parts)
        if isinstance(obj, h5py.Dataset):
            found[path] = ("dataset", obj.shape, set(obj.attrs))
        else:
            kind, shape, attrs = found.get(path, ("group", None, set()))
            found[path] = ("group", None, attrs | set(obj.attrs))

    h5.visititems(visit)
    return found


def _shape(symbols, sizes: dict) -> tuple:
    return tuple(sizes[v] if isinstance(v, str) else v for v in symbols)


def _shape_text(symbols) -> str:
    inner = ", ".join(str(v) for v in symbols)
    return f"({inner},)" if len(symbols) == 1 else f"({inner})"


ARCHIVE_PROBLEM = """\
name = "reference-helix"
units = "cm"
[tube]
diameter = 2.43
[target]
curve = "helix"
radius = 5.0
pitch = 2.0
length = 40.0
samples = 61
[design]
points_per_segment = 6
"""


def archive_section(problems: list) -> list[str]:
    """The core archive layout (``vine_nlp.io.layout.CORE_LAYOUT``), checked against archives written now.

    ``vine-nlp design`` and ``vine-nlp forward`` write an archive each; both must be read
    back by the archive reader (which validates them), hold every node of the layout with
    its attributes and its shape, and hold nothing in the core groups the layout lacks.
    """
    import h5py

    from vine_nlp.front.cli import main
    from vine_nlp.io.archive import load_archive
    from vine_nlp.io.layout import CORE_LAYOUT

    layout = {node.path: node for node in CORE_LAYOUT}
    written = {}
    solver_attrs = set()
    with tempfile.TemporaryDirectory() as tmp:
        design_toml = Path(tmp) / "reference-helix.toml"
        design_toml.write_text(ARCHIVE_PROBLEM)
        jobs = {
            "design": ["design", str(design_toml), "-o", str(Path(tmp) / "design.h5")],
            "forward": ["forward", str(PROBLEMS / "static-helix.toml"), "-o", str(Path(tmp) / "forward.h5")],
        }
        for kind, argv in jobs.items():
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
                rc = main(argv)
            if rc != 0:
                raise DriftError(f"vine-nlp {' '.join(argv)} exited {rc}: {err.getvalue().strip()}")
            load_archive(argv[3])  # the reader validates what the writer wrote
            with h5py.File(argv[3], "r") as h5:
                tree = _walk(h5)
                run = h5["runs"][next(iter(h5["runs"]))]
                sizes = {"M": len(run["design/theta"]), "P": len(run["shape/center"])}
                sizes["M+1"] = sizes["M"] + 1
                if "target" in h5:
                    sizes["N"] = len(h5["target/points"])
                solver_attrs |= set(run["solver"].attrs) if "solver" in run else set()
            written[kind] = tree
            for path, (node_kind, shape, attrs) in tree.items():
                node = layout.get(path)
                if node is None:
                    problems.append(f"archive {path}: written by `vine-nlp {kind}` but not in vine_nlp.io.layout.CORE_LAYOUT")
                    continue
                if node.kind != node_kind:
                    problems.append(f"archive {path}: written as a {node_kind}, a {node.kind} in the layout")
                if node.kind == "dataset" and shape != _shape(node.shape, sizes):
                    problems.append(f"archive {path}: written with shape {shape}, the layout says {_shape_text(node.shape)}")
                missing = set(node.attrs) - attrs
                if missing:
                    problems.append(f"archive {path}: `vine-nlp {kind}` writes no attribute {sorted(missing)}")
            for node in CORE_LAYOUT:
                needed = node.when == "always" or (node.when == "design" and kind == "design")
                if needed and node.path not in tree:
                    problems.append(f"archive {node.path}: in the layout but not written by `vine-nlp {kind}`")

    lines = [
        "## Result archives (HDF5)",
        "",
        "Written by every command that solves something and read by every command that takes an",
        "archive. The core layout below is `vine_nlp.io.layout.CORE_LAYOUT`; at build time,",
        "`vine-nlp design` and `vine-nlp forward` write an archive each, the archive reader reads",
        "them back, and the build stops if they differ from this table in any group, dataset,",
        "shape or attribute. `<run>` stands for a run name; N is the number of target points, M of",
        "segments, P of shape points (P = N for design runs, where row i pairs with target row i).",
        "",
        "| path | kind | shape | attributes | present | meaning |",
        "|---|---|---|---|---|---|",
    ]
    for node in CORE_LAYOUT:
        shape = _shape_text(node.shape) if node.kind == "dataset" else ""
        present = {"always": "always", "design": "design problems", "optional": "most runs"}[node.when]
        lines.append(f"| `{node.path}` | {node.kind} | {shape} | {_code(node.attrs)} | {present} | {_cell(node.meaning)} |")
    lines += [
        "",
        f"This version's solver groups hold: {_code(sorted(solver_attrs))}.",
        "",
        "`design` names its run after the method (`nlp`, `greedy`), `forward` writes `forward`,",
        "`fit` writes `fit`, `compare` writes both design runs. Forward shapes include the segment",
        "ends, first to last (rows 0 and P-1 are the base and the tip). Other commands add groups",
        "of their own: fits `/measured` (and `/frames`), multishape designs `/targets/<k>` and",
        "`/runs/multishape/levels/<k>`, tip problems `/tip`, obstacle problems `/obstacles/<k>`.",
    ]
    return lines


# ------------------------------------------------------------------ command line page
def cli_page() -> str:
    """The command-line reference as Markdown, from the program's own argument parser."""
    import argparse

    from vine_nlp.front.cli import build_parser

    parser = build_parser()
    parser.prog = "vine-nlp"
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {choice.dest: choice.help for choice in sub._choices_actions}
    out = [
        "# Command line",
        "",
        '!!! note "Generated"',
        "    This page is generated at every documentation build by `docs/gen_reference.py` from",
        "    `vine_nlp.front.cli.build_parser()`: it lists exactly what `vine-nlp --help` accepts.",
        "",
        "`vine-nlp` and `python3 -m vine_nlp` are the same program. Exit status: 0 done; 1 the",
        "solver did not reach its tolerance (the archive is still written, with that status; a",
        "sweep: an item failed or did not converge); 2 bad input (one line",
        "`error: <file>: <key>: <reason>` on stderr, nothing written); 130 interrupted (no",
        "partial file is left). Existing outputs are not overwritten without `--force`.",
        "",
        "| command | does |",
        "|---|---|",
    ]
    for name in sub.choices:
        out.append(f"| [`{name}`](#{name}) | {helps.get(name, '')} |")
    for name, p in sub.choices.items():
        p.prog = f"vine-nlp {name}"
        usage = " ".join(p.format_usage().replace("usage: ", "").split())
        out += [
            "",
            f"## {name}",
            "",
            helps.get(name, "") or "",
            "",
            "```text",
            textwrap.fill(usage, 96, subsequent_indent="    "),
            "```",
            "",
        ]
        out += ["| argument | meaning |", "|---|---|"]
        for action in p._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            flags = ", ".join(action.option_strings) or (action.metavar or action.dest)
            if action.option_strings and action.nargs != 0:
                flags += f" {action.metavar or action.dest.upper()}"
            text = action.help or ""
            if not action.option_strings and not text:
                text = " or ".join(POSITIONALS.get(m, "") for m in flags.split("|") if POSITIONALS.get(m))
                if "SWEEPDIR" in flags:
                    text += " or a sweep's output directory"
            if action.choices and not isinstance(action.choices, dict):
                text += (" " if text else "") + "Choices: " + _code(action.choices) + "."
            if action.required and action.option_strings:
                text += " Required."
            out.append(f"| `{flags}` | {text.replace('|', '&#124;')} |")
    return "\n".join(out) + "\n"


# Positional arguments have no help text in the parser; what each kind of file is.
POSITIONALS = {
    "PROBLEM.toml": "a problem file ([file formats](formats.md#problem-files-toml))",
    "SWEEP.toml": "a sweep file ([file formats](formats.md#sweep-files-toml))",
    "OUT.h5": "a result archive ([file formats](formats.md#result-archives-hdf5))",
    "ARCHIVE.h5": "a result archive ([file formats](formats.md#result-archives-hdf5))",
}


def contract_drift() -> list[str]:
    """What the contract (docs/reference/contract.md) names that this version no longer has: a command of its
    tables that ``vine-nlp`` does not accept, a path of its archive layout missing from CORE_LAYOUT."""
    import argparse

    from vine_nlp.front.cli import build_parser
    from vine_nlp.io.layout import CORE_LAYOUT

    text = (ROOT / "docs" / "reference" / "contract.md").read_text()
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    problems = [f"contract.md names `vine-nlp {c}`, which vine-nlp does not accept"
                for c in sorted(set(re.findall(r"^\| `vine-nlp ([a-z]+)", text, re.M))) if c not in sub.choices]
    layout = text.split("## Result archives (HDF5)", 1)[1].split("```")[1]
    paths = {node.path.rstrip("/") or "/" for node in CORE_LAYOUT}
    for line in layout.splitlines():
        path = line.split()[0].rstrip("/") or "/" if line.startswith("/") else None
        if path and path not in paths:
            problems.append(f"contract.md's archive layout names {path}, which vine_nlp.io.layout.CORE_LAYOUT does not hold")
    return problems


def contract_check(files, config):
    """MkDocs hook part: the build stops where the contract names what this version no longer has."""
    problems = contract_drift()
    if problems:
        from mkdocs.exceptions import PluginError

        raise PluginError("the contract and the code disagree:\n  " + "\n  ".join(problems))


PAGES = {"reference/formats.md": formats_page, "reference/cli.md": cli_page}


# ------------------------------------------------------------------ MkDocs hook
def on_files(files, config):
    """MkDocs hook: add the generated reference pages to the site (and check the contract page)."""
    from mkdocs.exceptions import PluginError
    from mkdocs.structure.files import File

    contract_check(files, config)

    for uri, make in PAGES.items():
        try:
            content = make()
        except DriftError as exc:
            raise PluginError(str(exc)) from None
        existing = files.get_file_from_path(uri)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, uri, content=content))
    return files


if __name__ == "__main__":
    which = sys.argv[1] if len(sys.argv) > 1 else "formats"
    if which == "contract":
        print("\n".join(contract_drift()) or "the contract and the code agree")
    else:
        print({"formats": formats_page, "cli": cli_page}[which]())
