"""Point data files (.csv, .npy) named by problem files or given on the command line.

Errors name the data file: "line N" for a bad CSV line, "values" for the content as a whole."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from vine_nlp import targets
from vine_nlp.errors import InputError
from vine_nlp.io import files, limits
from vine_nlp.io.validate import SourceFile, check, nonempty_text


def read_points(path, ordered: bool = False) -> np.ndarray:
    """Points of a .csv or .npy data file given on the command line (``fit --frames``), checked as a problem file's."""
    path = Path(path)
    return data_points(SourceFile(str(path)), "--frames", path.name, ordered)


def data_points(f: SourceFile, key: str, value, ordered: bool) -> np.ndarray:
    """Points of a .csv or .npy file named by ``key``; ordered points must also pass targets.check_points."""
    name = nonempty_text(f, key, value)
    path = f.dir / name
    if path.suffix.lower() not in (".csv", ".npy"):
        raise f.error(key, f"unsupported file type '{path.suffix}' (use .csv or .npy)")
    data_file = SourceFile(str(path))
    points = read_npy(data_file, f.path, key) if path.suffix.lower() == ".npy" else read_csv(data_file, f.path, key)
    return points_of(data_file, "values", points, ordered)


def points_of(f: SourceFile, key: str, value, ordered: bool) -> np.ndarray:
    """(N, 3) float points (2-D columns mean z = 0), finite, at most MAX_TARGET_POINTS: ``ordered`` (a target)
    by ``targets.check_points``'s rules, else (measured points, in any order, repeats fine) at least 3."""
    try:
        p = targets.check_points(value) if ordered else targets.as_3d(value, least=3)
    except ValueError as err:
        raise f.error(key, str(err)) from None
    finite = np.all(np.isfinite(p), axis=1)
    check(f, key, finite.all(), f"point {int(np.argmin(finite)) + 1} is not finite")
    check(f, key, p.shape[0] <= limits.MAX_TARGET_POINTS, f"has {p.shape[0]} points; at most {limits.MAX_TARGET_POINTS}")
    return p


def check_spread(file, points: np.ndarray, diameter: float, least: int) -> None:
    """Measured points must show a robot: ``least`` distinct points spread over at least
    MIN_SPREAD tube diameters (400 copies of one point fit any routing and say nothing)."""
    distinct = len(np.unique(points, axis=0))
    extent = float(np.linalg.norm(np.ptp(points, axis=0)))
    if distinct < least or not extent >= MIN_SPREAD * diameter:
        raise InputError(file, "values", f"{distinct} distinct points spread over {extent:.4g}: a measurement needs at least "
                         f"{least} distinct points spread over {MIN_SPREAD:g} tube diameters ({MIN_SPREAD * diameter:.4g})")


MIN_SPREAD = 2.0  # tube diameters
_NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf|infinity|nan)", re.IGNORECASE)
_SEPARATOR = re.compile(r"\s*,\s*|\s+")


def read_csv(f: SourceFile, named_by=None, key="file") -> np.ndarray:
    """Rows of x y z (or x y), separated by commas or whitespace; one header line and # comments allowed.
    Read line by line: more than MAX_TARGET_POINTS rows stop the reading there."""
    rows: list[list[float]] = []
    header_seen = False
    for number, line in files.text_lines(f.path, named_by, key):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = _SEPARATOR.split(line)
        values = [float(x) if _NUMBER.fullmatch(x) else None for x in fields]
        if not rows and not header_seen and all(v is None for v in values):
            header_seen = True
            continue
        where = f"line {number}"
        for text_value, v in zip(fields, values):
            if v is None:
                raise f.error(where, f"'{text_value[:40]}' is not a number")
            if not math.isfinite(v):
                raise f.error(where, f"'{text_value[:40]}' is not finite")
        columns = len(rows[0]) if rows else None
        if columns is None and len(values) not in (2, 3):
            raise f.error(where, f"expected 3 values (x y z) or 2 (x y), got {len(values)}")
        if columns is not None and len(values) != columns:
            raise f.error(where, f"expected {columns} values like the first row, got {len(values)}")
        if len(rows) == limits.MAX_TARGET_POINTS:
            raise f.error("values", f"more than {limits.MAX_TARGET_POINTS} points (vine_nlp.io.limits.MAX_TARGET_POINTS)")
        rows.append(values)
    if not rows:
        raise f.error("values", "no data rows")
    return np.array(rows, dtype=float)


def read_npy(f: SourceFile, named_by=None, key="file") -> np.ndarray:
    """An (N, 3) or (N, 2) array of real numbers, its header checked before the data is read."""
    fmt = np.lib.format
    with files.open_input(f.path, named_by, key) as fh:
        try:
            version = fmt.read_magic(fh)
            shape, _, dtype = (fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0)(fh)
            if dtype.kind not in "iuf" or dtype.fields or dtype.subdtype:
                raise f.error("values", "must hold an array of real numbers")
            if len(shape) != 2 or shape[1] not in (2, 3) or not 0 < shape[0] <= limits.MAX_TARGET_POINTS:
                raise f.error("values", f"must be an N x 3 (or N x 2) array, N <= {limits.MAX_TARGET_POINTS} "
                              f"(vine_nlp.io.limits.MAX_TARGET_POINTS), got shape {shape}")
            fh.seek(0)
            array = np.load(fh, allow_pickle=False)  # never unpickle user files
        except (OSError, ValueError, EOFError):
            raise f.error("values", "not a readable .npy array file") from None
    array = array.astype(float)
    finite = np.all(np.isfinite(array), axis=1)
    if not finite.all():
        raise f.error("values", f"row {int(np.argmin(finite)) + 1} is not finite")
    return array
