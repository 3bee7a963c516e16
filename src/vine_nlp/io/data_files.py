"""Point data files (.csv, .npy) named by problem files or given on the command line.

Errors name the data file: "line N" for a bad CSV line, "values" for the content as a whole.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from vine_nlp import targets
from vine_nlp.io import limits
from vine_nlp.io.validate import SourceFile, check, nonempty_text


def read_points(path, ordered: bool = False) -> np.ndarray:
    """Points of a .csv or .npy data file given on the command line (e.g. ``fit --frames``).

    Bad files raise InputError naming the data file, exactly as when a problem file names them.
    """
    path = Path(path)
    f = SourceFile(str(path))
    if not path.is_file():
        raise f.error("--frames", "no such file")
    return data_points(SourceFile(str(path.parent / path.name)), "--frames", path.name, ordered)



def data_points(f: SourceFile, key: str, value, ordered: bool) -> np.ndarray:
    """Points of a .csv or .npy file named by ``key``; ordered points must also pass targets.check_points."""
    name = nonempty_text(f, key, value)
    path = f.dir / name
    if path.suffix.lower() not in (".csv", ".npy"):
        raise f.error(key, f"unsupported file type '{path.suffix}' (use .csv or .npy)")
    if not path.is_file():
        raise f.error(key, f"no such file: {path}")
    data_file = SourceFile(str(path))
    size = path.stat().st_size
    check(data_file, "values", size <= limits.MAX_FILE_BYTES, f"file of {size} bytes is larger than the limit MAX_FILE_BYTES = {limits.MAX_FILE_BYTES}")
    points = read_npy(data_file) if path.suffix.lower() == ".npy" else read_csv(data_file)
    check(data_file, "values", points.shape[0] <= limits.MAX_TARGET_POINTS,
          f"{points.shape[0]} points is more than the limit MAX_TARGET_POINTS = {limits.MAX_TARGET_POINTS}")
    if ordered:
        try:
            return targets.check_points(points)
        except ValueError as err:
            raise data_file.error("values", str(err)) from None
    # Measured points come in any order, so repeats are fine; the fit needs a few of them.
    check(data_file, "values", points.shape[0] >= 3, f"needs at least 3 points, got {points.shape[0]}")
    return np.column_stack([points, np.zeros(points.shape[0])]) if points.shape[1] == 2 else points



def read_csv(f: SourceFile) -> np.ndarray:
    """Rows of x y z (or x y), separated by commas or whitespace; one header line and # comments allowed."""
    try:
        text = Path(f.path).read_text(encoding="utf-8-sig")  # -sig: spreadsheets write a BOM
    except UnicodeDecodeError:
        raise f.error("values", "not a UTF-8 text file") from None
    except OSError as err:
        raise f.error("values", f"cannot read the file ({err.strerror})") from None
    rows: list[list[float]] = []
    header_seen = False
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = re.split(r"\s*,\s*|\s+", line)
        values = [_float_or_none(x) for x in fields]
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
        rows.append(values)
    if not rows:
        raise f.error("values", "no data rows")
    return np.array(rows, dtype=float)



def read_npy(f: SourceFile) -> np.ndarray:
    try:
        array = np.load(f.path, allow_pickle=False)  # never unpickle user files
    except (OSError, ValueError, EOFError, MemoryError):
        raise f.error("values", "not a readable .npy array file") from None
    if not isinstance(array, np.ndarray) or not (
        np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)
    ):
        raise f.error("values", "must hold an array of real numbers")
    if array.ndim != 2 or array.shape[1] not in (2, 3) or array.shape[0] == 0:
        raise f.error("values", f"must be an N x 3 (or N x 2) array, got shape {array.shape}")
    array = array.astype(float)
    finite = np.all(np.isfinite(array), axis=1)
    if not finite.all():
        raise f.error("values", f"row {int(np.argmin(finite)) + 1} is not finite")
    return array



def _float_or_none(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None
