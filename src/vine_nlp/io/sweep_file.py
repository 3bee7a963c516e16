"""Sweep files (spec/formats.md, "Sweep files"): a base design problem and a grid of overrides.

Every item of the grid is validated when the file is read: a bad item is bad input
before any work is done, reported against the sweep file with the item named."""

from __future__ import annotations

import copy
import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path

from vine_nlp.errors import InputError
from vine_nlp.io import limits
from vine_nlp.io.problems import ProblemFile, parse_problem
from vine_nlp.io.validate import SourceFile, check, check_keys, choice, nonempty_text, parse_toml, read_text, required_value
from vine_nlp.problem import METHODS

MAX_SWEEP_ITEMS = 100_000

_SWEEP_KEYS = ("name", "base", "methods", "grid")

_SWEEP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
MAX_KEY_PARTS = 32  # of a dotted grid key ("target.scale.0": 3); problem files nest far less deep


@dataclass
class Sweep:
    path: str
    source: str
    name: str
    base_path: str
    base_data: dict
    methods: list[str]
    grid: dict[str, list]  # dotted key -> values, in file order
    base_source: str = ""
    _items: list | None = field(default=None, repr=False, compare=False)

    def items(self) -> list[tuple[str, dict, ProblemFile]]:
        """(item name, {dotted key: value}, problem) for the cartesian product of the grid, in grid order.

        Item names are ``<sweep name>-<index:04d>``; each item's problem is named after it."""
        if self._items is None:
            self._items = _expand(self)
        return list(self._items)


def load_sweep(path) -> Sweep:
    """Read a sweep file and validate its base problem and every item."""
    path = str(path)
    f = SourceFile(path)
    source = read_text(path, path, "file")  # a FIFO or device is refused unopened (io.files)
    data = parse_toml(path, source)  # refuses a dotted key of more parts than any grid key may have
    bad = _unprintable(data)
    if bad is not None:
        raise f.error("file", f"keys and texts must be printable (no control characters), got {bad[:60]!r}")
    check_keys(f, data, "", _SWEEP_KEYS)
    name = data.get("name", re.sub(r"[^A-Za-z0-9._+-]", "_", Path(path).stem).lstrip(".") or "sweep")
    name = nonempty_text(f, "name", name)
    check(f, "name", _SWEEP_NAME.fullmatch(name) is not None, "must be a plain file name (letters, digits, . _ + -)")

    base = nonempty_text(f, "base", required_value(f, data, "base", ""))
    base_path = str(f.dir / base)
    base_source = read_text(base_path, path, "base")
    base_data = parse_toml(base_path, base_source)
    if parse_problem(base_data, base_path, base_source).kind != "design":
        raise f.error("base", "must be a design problem file (one with [target])")

    methods = data.get("methods", ["nlp"])
    check(f, "methods", isinstance(methods, list) and len(methods) > 0, "must be a non-empty list of methods")
    for m in methods:
        choice(f, "methods", m, METHODS)
    check(f, "methods", len(set(methods)) == len(methods), "lists a method twice")

    grid_table = data.get("grid", {})
    check(f, "grid", isinstance(grid_table, dict), "must be a table")
    grid = _flatten(grid_table)
    size = 1
    for key, values in grid.items():
        check(f, "grid", key.count(".") < MAX_KEY_PARTS, f"a key of more than {MAX_KEY_PARTS} parts: {key[:60]!r}...")
        if not (isinstance(values, list) and values):
            raise f.error(f"grid.{key}", "must be a non-empty list of values")
        size *= len(values)
    check(f, "grid", size <= MAX_SWEEP_ITEMS, f"has {size} items; at most {MAX_SWEEP_ITEMS}")

    sweep = Sweep(path, source, name, base_path, base_data, list(methods), grid, base_source)
    sweep.items()  # bad items are bad input: fail now, before any work is done
    return sweep


def apply_override(data: dict, dotted_key: str, value, file: str = "<sweep>") -> dict:
    """A deep copy of ``data`` with the value at ``dotted_key`` replaced ("target.scale.0" = element 0).

    Missing tables are created (a sweep may set a key the base leaves at its default); an index needs an existing array
    and must be in range. Bad paths raise ``InputError(file, dotted_key, ...)``."""
    data = copy.deepcopy(data)
    _set(data, dotted_key, value, file)
    return data


def _expand(sweep: Sweep) -> list[tuple[str, dict, ProblemFile]]:
    keys = list(sweep.grid)
    items = []
    for index, combo in enumerate(itertools.product(*(sweep.grid[k] for k in keys))):
        item = f"{sweep.name}-{index:04d}"
        overrides = dict(zip(keys, combo))
        data = copy.deepcopy(sweep.base_data)
        for key, value in overrides.items():
            _set(data, key, value, sweep.path)
        data["name"] = item
        described = ", ".join(f"{k} = {v!r}" for k, v in overrides.items())[: limits.MAX_NOTE_CHARS] or "the base problem"
        # The archive stores the source; the note makes the item reproducible from it.
        source = sweep.base_source.rstrip("\n") + f"\n\n# sweep '{sweep.name}' item {item}: {described}\n"
        try:
            problem = parse_problem(data, sweep.base_path, source)
        except InputError as err:
            if err.file != sweep.base_path:
                raise  # a data file's own error
            raise InputError(sweep.path, err.key, f"{err.reason} (item {item}: {described})") from None
        items.append((item, overrides, problem))
    return items


def _set(data: dict, dotted_key: str, value, file: str) -> None:
    def fail(reason):
        return InputError(file, dotted_key, reason)

    if not isinstance(dotted_key, str) or not all(dotted_key.split(".")):
        raise fail("not a dotted key like target.scale.0")
    parts = dotted_key.split(".")
    node = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[: depth + 1])
        if isinstance(node, dict):
            if last:
                node[part] = value
            elif part not in node:
                if parts[depth + 1].isdigit():
                    raise fail(f"'{where}' is not in the base problem; an index needs an existing array")
                node[part] = {}
            node = node[part]
        elif isinstance(node, list):
            if not part.isdigit():
                raise fail(f"'{'.'.join(parts[:depth])}' is an array; '{part}' is not an index")
            i = int(part)
            if i >= len(node):
                raise fail(f"index {i} is out of range ('{'.'.join(parts[:depth])}' has {len(node)} elements)")
            if last:
                node[i] = value
            node = node[i]
        else:
            raise fail(f"'{'.'.join(parts[:depth])}' is a value, not a table or array")


def _flatten(table: dict, prefix: str = "") -> dict:
    # [grid] target.scale.0 = [...] (bare dotted key) arrives as nested tables.
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _unprintable(data):
    """The first key or text in ``data`` (tables, arrays) that is not printable, or None."""
    todo = [data]
    while todo:
        value = todo.pop()
        if isinstance(value, dict):
            todo += [*value, *value.values()]
        elif isinstance(value, list):
            todo += value
        elif isinstance(value, str) and not value.isprintable():
            return value
    return None
