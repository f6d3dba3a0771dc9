"""Checking the tables of the TOML files users write (scenarios, airframes, sensor
profiles, readiness profiles, campaigns): one place for the three checks every reader
makes, so every file refuses bad input in the same words, naming the field.

Each takes the exception type its reader raises (``AirframeError``, ``ValueError`` ...).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any


def check_fields(table: Mapping[str, Any], known: Iterable[str], where: str,
                 error: type[Exception] = ValueError) -> None:
    """Refuse a field the reader does not know (a typo must not be ignored)."""
    known = set(known)
    unknown = sorted(set(table) - known)
    if unknown:
        raise error(f"{where}: unknown field(s) {', '.join(unknown)}; known: "
                    f"{', '.join(sorted(known))}")


def subtable(data: Mapping[str, Any], key: str, where: str,
             error: type[Exception] = ValueError) -> dict[str, Any]:
    """``data[key]`` as a table ({} when absent)."""
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise error(f"{where} must be a table")
    return value


def array_of_tables(data: Mapping[str, Any], key: str, where: str, known: Iterable[str],
                    error: type[Exception] = ValueError) -> list[tuple[str, dict[str, Any]]]:
    """``[[key]]``: each table with the name its errors give (``where i``), its fields
    checked against ``known``; [] when absent."""
    value = data.get(key, [])
    if not isinstance(value, list):
        raise error(f"{where} must be an array of tables ([[{key}]])")
    known = set(known)
    out = []
    for i, table in enumerate(value):
        at = f"{where} {i}"
        if not isinstance(table, dict):
            raise error(f"{at} must be a table")
        check_fields(table, known, at, error)
        out.append((at, table))
    return out


def number(value: Any, where: str, low: float = -math.inf, high: float = math.inf, *,
           low_open: bool = False, unit: str = "", allow_inf: bool = False,
           error: type[Exception] = ValueError) -> float:
    """A TOML (or JSON) number, not a boolean, in [low, high] (``(low`` if ``low_open``),
    finite unless ``allow_inf`` and ``high`` is infinite (a window that never ends); the
    error says the range and its unit."""
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or not (math.isfinite(value) or (allow_inf and value == high == math.inf))
            or value > high or (value <= low if low_open else value < low)):
        raise error(f"{where} must be {_range_text(low, high, low_open, unit)}, got {value!r}")
    return float(value)


def _range_text(low: float, high: float, low_open: bool, unit: str) -> str:
    unit = f" {unit}" if unit else ""
    if math.isinf(low) and math.isinf(high):
        return "a finite number"
    if math.isinf(high):
        return f"a finite number {'>' if low_open else '>='} {low:g}{unit}"
    if math.isinf(low):
        return f"a finite number <= {high:g}{unit}"
    return f"a number in {'(' if low_open else '['}{low:g}, {high:g}]{unit}"
