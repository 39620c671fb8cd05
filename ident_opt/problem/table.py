"""Reading a TOML table of a problem file: every key taken is checked, every key left over is an error.

`Table` is what every section parser (`ident_opt.problem.sections`, `ident_opt.problem.robot`) reads through:
a key of the wrong type, out of its range or misspelt is an `InputError` naming the file, the section and
the key; `done()` refuses keys nobody took, so a typo never falls back silently to a default.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

from ident_opt.errors import InputError, excerpt

_REQUIRED = object()

#: Upper limits of a sane value per unit: a number above these is a typo or a unit mistake, and would overflow
#: the arithmetic downstream (lengths in m, densities in kg/m³, masses in kg, inertias in kg m², gravity in
#: m/s², torque constants in N m/A, friction in N m or N m s/rad, rates in Hz).
LIMITS = {
    "length": 100.0,
    "density": 1e5,
    "mass": 1e4,
    "inertia": 1e3,
    "gravity": 100.0,
    "torque_constant": 1e3,
    "gear_ratio": 1e5,
    "friction": 1e4,
    "rate_hz": 1e6,
    "scale": 1e6,  # a column conversion's factor (dimensionless or a unit conversion)
    "offset": 1e6,  # a column conversion's offset, in the column's SI unit
}


class Table:
    """A TOML table being read: every key taken is checked, every key left over is an error."""

    def __init__(self, raw: Any, where: str, path: Path):
        if not isinstance(raw, dict):
            raise InputError(f"{path}: [{where}] must be a table, got {type(raw).__name__}")
        self.raw = dict(raw)
        self.where = where
        self.path = path

    def _name(self, key: str) -> str:
        return f"{self.path}: key '{key}' in [{self.where}]" if self.where else f"{self.path}: key '{key}'"

    def _misspelt(self, key: str) -> str:
        close = difflib.get_close_matches(key, [str(k) for k in self.raw], n=1)
        return f" (is '{close[0]}' a misspelling of it?)" if close else ""

    def take(self, key: str, kind: type | tuple[type, ...], default: Any = _REQUIRED) -> Any:
        if key not in self.raw:
            if default is _REQUIRED:
                raise InputError(f"{self._name(key)} is required but missing{self._misspelt(key)}")
            return default
        value = self.raw.pop(key)
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if isinstance(value, bool) and bool not in kinds:
            raise InputError(f"{self._name(key)} must be {_kind_name(kinds)}, got a boolean")
        if not isinstance(value, kinds):
            raise InputError(f"{self._name(key)} must be {_kind_name(kinds)}, got {excerpt(value)}")
        return value

    def number(self, key: str, default: Any, low: float, high: float, *, open_low: bool = False) -> float:
        """A finite number in [low, high] (or (low, high] with `open_low`), in the key's SI unit."""
        value = self.take(key, float, default)
        below = value <= low if open_low else value < low
        if not math.isfinite(value) or below or value > high:
            if low == 0:
                what = "a positive number" if open_low else "zero or positive"
            else:
                what = f"a number in {'(' if open_low else '['}{low:g}, {high:g}]"
            raise InputError(f"{self._name(key)} must be {what} (finite, at most {high:g}), got {excerpt(value)}")
        return value

    def integer(self, key: str, default: Any, low: int, high: int) -> int:
        """A whole number in [low, high] (a float such as 0.5 is refused, not truncated)."""
        value = self.take(key, int, default)
        if not low <= value <= high:
            raise InputError(f"{self._name(key)} must be an integer in [{low}, {high}], got {excerpt(value)}")
        return value

    def positive(self, key: str, default: Any = _REQUIRED, high: float = 1e6) -> float:
        """A finite number in (0, high]."""
        return self.number(key, default, 0.0, high, open_low=True)

    def non_negative(self, key: str, default: Any = _REQUIRED, high: float = 1e6) -> float:
        """A finite number in [0, high]."""
        return self.number(key, default, 0.0, high)

    def table(self, key: str, required: bool = True) -> Table:
        where = f"{self.where}.{key}" if self.where else key
        if key not in self.raw:
            if required:
                raise InputError(f"{self.path}: section [{where}] is required but missing{self._misspelt(key)}")
            return Table({}, where, self.path)
        return Table(self.raw.pop(key), where, self.path)

    def done(self) -> None:
        if self.raw:
            keys = ", ".join(sorted(self.raw))
            place = f"[{self.where}]" if self.where else "the top level"
            raise InputError(f"{self.path}: unknown key(s) {keys} in {place} (check the spelling)")


def _kind_name(kinds: tuple[type, ...]) -> str:
    names = {float: "a number", int: "an integer", str: "a string", bool: "true or false", list: "a list"}
    return " or ".join(names.get(k, k.__name__) for k in kinds)
