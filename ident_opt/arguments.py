"""Every number on the command line, validated while parsing: finite, in a sane range for its unit, an integer
where an integer is meant. `cli.build_parser` gives each `type=int` / `type=float` flag of every subcommand the
`number` type with its range from `RANGES` (unlisted flags: finite, within `DEFAULT`), so a bad value is a
usage error (exit 2) naming the flag, before any work."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

#: Seeds: NumPy's and scikit-learn's range. GMR components: the problem file's limit (problem.MAX_COMPONENTS).
MAX_SEED = 2**32 - 1
MAX_COMPONENTS = 50

#: (subcommand, flag dest) -> (low, high), both included. A flag of any subcommand may be keyed by dest alone.
RANGES: dict[tuple[str, str] | str, tuple[float, float]] = {
    ("compare", "margin"): (0.0, 1.0),  # kg m²: M(q) ⪰ margin·I; a link's inertia is far below 1 kg m²
    ("compare", "constraints_study"): (1, 1000),
    ("online", "snapshot_every"): (0, 10**9),
    ("online", "checks"): (0, 10_000),
    ("simulate", "duration"): (1.0, 3600.0),  # s
    ("simulate", "rate"): (1.0, 5000.0),  # Hz
    ("simulate", "bandwidth"): (1.0, 40.0),  # Hz: simulate.trial.MIN_BANDWIDTH, MAX_BANDWIDTH
    ("simulate", "noise_scale"): (0.0, 100.0),  # simulate.trial.MAX_NOISE_SCALE
    ("excite", "duration"): (2.0, 3600.0),  # s
    ("excite", "rate"): (10.0, 10_000.0),  # Hz
    ("excite", "starts"): (1, 100),
    ("excite", "harmonics"): (1, 20),
    ("excite", "base_hz"): (1e-4, 100.0),  # Hz
    ("fleet", "workers"): (1, 4096),
    ("fleet", "baseline_days"): (2, 3650),  # days: a scatter needs two
    ("fleet", "connect_timeout"): (0.1, 3600.0),  # s
    ("detect", "margin"): (1.0, 100.0),  # a factor on the calibrated collision-free level
    "components": (1, MAX_COMPONENTS),
    "seed": (0, MAX_SEED),
}
#: Any other numeric flag: finite and within ± this.
DEFAULT = (-1e12, 1e12)


def range_of(command: str, dest: str) -> tuple[float, float]:
    """The accepted range of `command`'s flag `dest`."""
    return RANGES.get((command, dest)) or RANGES.get(dest) or DEFAULT


def number(kind: type, low: float, high: float) -> Callable[[str], float | int]:
    """An argparse `type`: the text as `kind` (int or float), finite and in [low, high]; else a usage error."""

    def parse(text: str) -> float | int:
        what = "an integer" if kind is int else "a number"
        shown = text if len(text) <= 40 else text[:37] + "..."
        try:
            value = kind(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what} in [{low:g}, {high:g}], got {shown!r}") from None
        if not ((kind is int or math.isfinite(value)) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"must be {what} in [{low:g}, {high:g}], got {shown!r}")
        return value

    parse.__name__ = "integer" if kind is int else "number"  # argparse names the type in its messages
    return parse


def validate_numbers(command: str, parser: argparse.ArgumentParser) -> None:
    """Give every `type=int` / `type=float` flag of `parser` (the subcommand `command`) the checked type."""
    for action in parser._actions:  # argparse has no public list of a parser's actions
        if action.type in (int, float):
            action.type = number(action.type, *range_of(command, action.dest))
