"""Length units: the one table of the units the tool converts (an archive names its units; lengths are in them)."""

from __future__ import annotations

MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "inch": 25.4}
METRES_PER_UNIT = {u: mm / 1000 for u, mm in MM_PER_UNIT.items()}  # loads are in SI, glTF in metres


def mm_per_unit(units: str) -> float | None:
    """Millimetres per one of ``units`` (case and surrounding blanks ignored); None for a unit not in MM_PER_UNIT."""
    return MM_PER_UNIT.get(str(units).strip().lower())
