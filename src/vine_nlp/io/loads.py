"""The ``[load]`` table (spec/formats.md, "Self-weight and payload (round 4)"): SI units whatever the file's
length units, which must convert to metres (analysis.loads.METRES_PER_UNIT)."""

from __future__ import annotations

from vine_nlp.analysis.loads import METRES_PER_UNIT
from vine_nlp.io.validate import SourceFile, check, real_array, real_number, required_value, sub_table
from vine_nlp.problem import Load

KEYS = ("gravity", "pressure", "mass_per_length", "tip_mass", "safety")
MAX_VALUE = 1e6  # any value of the table: kPa, kg/m, kg, m/s^2, a factor


def load_of(f: SourceFile, data: dict, units: str) -> Load | None:
    """The problem's [load], or None without one."""
    if "load" not in data:
        return None
    t = sub_table(f, data, "load", KEYS)
    check(f, "units", units in METRES_PER_UNIT, f"must be one of {', '.join(METRES_PER_UNIT)} with [load] (its SI values need metres)")

    def number(key, least, strict, default=None):
        v = real_number(f, f"load.{key}", required_value(f, t, key, "load.") if default is None else t.get(key, default))
        check(f, f"load.{key}", v > least if strict else v >= least, f"must be {'>' if strict else '>='} {least:g}, got {v:g}")
        check(f, f"load.{key}", v <= MAX_VALUE, f"must be <= {MAX_VALUE:g}")
        return v

    gravity = real_array(f, "load.gravity", t.get("gravity", list(Load.gravity)), 3)
    check(f, "load.gravity", all(abs(g) <= MAX_VALUE for g in gravity), f"must be at most {MAX_VALUE:g} m/s^2 in magnitude")
    zero = not any(gravity)
    check(f, "load.safety", not (zero and "safety" in t), "asks for a safety factor under zero gravity: nothing weighs (give gravity)")
    load = Load(pressure=number("pressure", 0.0, True), mass_per_length=number("mass_per_length", 0.0, False),
                tip_mass=number("tip_mass", 0.0, False, 0.0), gravity=tuple(float(g) for g in gravity),
                safety=number("safety", 1.0, False, Load.safety))
    return load
