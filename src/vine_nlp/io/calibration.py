"""The ``[calibration]`` table (spec/formats.md, "As-built correction"): read from a design problem (inline
or ``calibration = "CAL.toml"``, relative to the problem file) and written by ``vine-nlp calibrate``."""

from __future__ import annotations

from pathlib import Path

from vine_nlp.io.archive import write_atomic
from vine_nlp.io.validate import SourceFile, parse_toml, read_text
from vine_nlp.model.calibration import Calibration

MAX_VALUE = 1e6  # any value of the table (standard errors, prototypes); offsets and scale have tighter ranges below
KEYS = ("lambda_offset", "theta_offset_deg", "length_scale", "lambda_offset_se", "theta_offset_deg_se", "length_scale_se", "prototypes")


def calibration_of(f: SourceFile, data: dict) -> Calibration | None:
    """The calibration a design problem names (``data["calibration"]``: a table or a file name), or None."""
    if "calibration" not in data:
        return None
    value = data["calibration"]
    if isinstance(value, str):
        return read_calibration(f.dir / value, f.path)
    if isinstance(value, dict):
        return _table(f, value, "calibration")
    raise f.error("calibration", "must be a [calibration] table or the name of a calibration file")


def _table(f: SourceFile, t: dict, prefix: str) -> Calibration:
    vals = {}
    for k, v in t.items():
        key = f"{prefix}.{k}"
        if k not in KEYS:
            raise f.error(key, f"unknown key (known: {', '.join(KEYS)})")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= MAX_VALUE:
            raise f.error(key, f"must be a finite number of magnitude <= {MAX_VALUE:g}, got {str(v)[:40]}")
        if k.endswith("_se") and v < 0:
            raise f.error(key, f"must be >= 0, got {v!r}")
        if k == "prototypes":
            if int(v) != v or v < 0:
                raise f.error(key, f"must be a whole number >= 0, got {v!r}")
            v = int(v)
        vals[k] = v if k == "prototypes" else float(v)
    if "length_scale" in vals and not 0 < vals["length_scale"] <= 10:
        raise f.error(f"{prefix}.length_scale", f"must be > 0 and <= 10, got {vals['length_scale']!r}")
    if "lambda_offset" in vals and not abs(vals["lambda_offset"]) < 0.5:
        raise f.error(f"{prefix}.lambda_offset", f"must be within +-0.5, got {vals['lambda_offset']!r}")
    if "theta_offset_deg" in vals and not abs(vals["theta_offset_deg"]) < 45:
        raise f.error(f"{prefix}.theta_offset_deg", f"must be within +-45, got {vals['theta_offset_deg']!r}")
    return Calibration(**vals)


def check_calibration(values: dict, path) -> Calibration:
    """``values`` (keys of KEYS) by the rules of a [calibration] table; InputError ``(path, calibration.<key>, reason)``."""
    return _table(SourceFile(str(path)), {k: float(v) if k != "prototypes" else v for k, v in values.items()}, "calibration")


def calibration_toml(cal: Calibration) -> str:
    """The [calibration] table as TOML text."""
    lines = ["# made by vine-nlp calibrate: built = nominal + offsets, lengths times length_scale", "[calibration]"]
    for k in KEYS:
        v = getattr(cal, k)
        lines.append(f"{k} = {v!r}" if isinstance(v, int) else f"{k} = {float(v)!r}")
    return "\n".join(lines) + "\n"


def write_calibration(path, cal: Calibration) -> None:
    """Write the table atomically (it reads back with :func:`read_calibration`: values it would refuse are an
    InputError naming ``path`` and the key, and nothing is written)."""
    text = calibration_toml(cal)
    check_calibration(parse_toml(str(path), text)["calibration"], path)
    write_atomic(path, lambda t: Path(t).write_text(text, encoding="utf-8"))


def read_calibration(path, named_by=None) -> Calibration:
    """A calibration file (made by ``vine-nlp calibrate``; ``named_by``: the problem file naming it), InputError
    naming the file and key when bad."""
    f = SourceFile(str(path))
    doc = parse_toml(f.path, read_text(f.path, named_by, "calibration" if named_by else "file"))
    if not isinstance(doc.get("calibration"), dict):
        raise f.error("calibration", "missing: the file needs a [calibration] table")
    return _table(f, doc["calibration"], "calibration")
