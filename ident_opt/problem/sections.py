"""The sections of a problem file other than `[robot]`: `[data]`, `[split]`, `[residual]`, `[simulate]`,
`[limits]` and `[reference]` (`docs/problem-files.md`). Each parser takes its checked `Table` and returns the
section's spec (`ident_opt.problem.spec`).
"""

from __future__ import annotations

import math
from pathlib import Path

from ident_opt.columns import data_columns
from ident_opt.effects import parse_effect
from ident_opt.errors import InputError
from ident_opt.problem.spec import (
    MAX_COMPONENTS,
    MAX_SEED,
    MAX_SEEDS,
    DataSpec,
    Limits,
    Reference,
    ResidualSpec,
    SimulateSpec,
    SplitSpec,
)
from ident_opt.problem.table import LIMITS, Table, excerpt
from ident_opt.simulate.trajectories import TRAJECTORIES


def relative(base: Path, value: str) -> Path:
    path = Path(value)
    return path if path.is_absolute() else (base / path)


def _column(table: Table, key: str) -> tuple[str | int, tuple[float, float] | None]:
    """One `[data.columns]` entry: a name, a 0-based index, or {column, scale, offset} (a conversion)."""
    if isinstance(table.raw.get(key), dict):
        sub = table.table(key)
        source = sub.take("column", (str, int))
        conversion = (
            sub.number("scale", 1.0, -LIMITS["scale"], LIMITS["scale"]),
            sub.number("offset", 0.0, -LIMITS["offset"], LIMITS["offset"]),
        )
        sub.done()
        if conversion[0] == 0:
            raise InputError(f"{table.path}: key 'scale' in [{sub.where}] must not be 0")
    else:
        source, conversion = table.take(key, (str, int)), None
    if isinstance(source, int) and source < 0:
        raise InputError(f"{table.path}: key '{key}' in [data.columns] must be a 0-based index >= 0")
    return source, conversion


def _cutoff(table: Table) -> float | str:
    """`derivative_cutoff_hz`: a number [Hz] or "auto" (read from each trial's spectrum: `choose_cutoff`)."""
    if table.raw.get("derivative_cutoff_hz") == "auto":
        table.raw.pop("derivative_cutoff_hz")
        return "auto"
    return table.positive("derivative_cutoff_hz", DataSpec.derivative_cutoff_hz, high=LIMITS["rate_hz"])


def _paths(table: Table, key: str) -> list[str]:
    """A list of data files under `key` of [data] (strings), or []."""
    paths = table.take(key, list, [])
    for i, trial in enumerate(paths):
        if not isinstance(trial, str):
            raise InputError(f"{table.path}: key '{key}' in [data]: entry {i} must be a path string")
    return paths


def _names(table: Table, key: str, n_joints: int) -> list[str]:
    """`key` of [data]: a list of exactly `n_joints` distinct strings (joint names), or [] when absent."""
    names = table.take(key, list, [])
    if names and (
        len(names) != n_joints or not all(isinstance(n, str) and n for n in names) or len(set(names)) < n_joints
    ):
        raise InputError(
            f"{table.path}: key '{key}' in [data] must list {n_joints} distinct joint names, base to tip, "
            f"got {excerpt(names)}"
        )
    return names


def parse_data(table: Table, base: Path, n_joints: int = 2) -> DataSpec:
    known = data_columns(n_joints)
    trials, train, test = _paths(table, "trials"), _paths(table, "train"), _paths(table, "test")
    if trials and (train or test):
        raise InputError(
            f"{table.path}: [data] lists both 'trials' and 'train'/'test'; use 'train' and 'test' "
            "(or 'trials' alone: the first trains, the second is held out)"
        )
    if test and not train:
        raise InputError(f"{table.path}: key 'test' in [data] needs 'train' (the trials to identify on)")
    columns_table = table.table("columns", required=False)
    columns: dict[str, str | int] = {}
    conversions: dict[str, tuple[float, float]] = {}
    for key in list(columns_table.raw):
        if key not in known:
            raise InputError(f"{table.path}: unknown column '{key}' in [data.columns]; known: {', '.join(known)}")
        columns[key], conversion = _column(columns_table, key)
        if conversion is not None:
            conversions[key] = conversion
    spec = DataSpec(
        trials=tuple(relative(base, t) for t in trials) or tuple(relative(base, t) for t in train + test),
        train=tuple(relative(base, t) for t in train),
        test=tuple(relative(base, t) for t in test),
        header=table.take("header", bool, True),
        sheet=table.take("sheet", str, None),
        columns=columns,
        derivative_cutoff_hz=_cutoff(table),
        conversions=conversions,
        standard_by_name=table.take("standard_by_name", bool, True),
        ros_topic=table.take("ros_topic", str, DataSpec.ros_topic),
        ros_joints=tuple(_names(table, "ros_joints", n_joints)),
    )
    if not spec.header and any(isinstance(v, str) for v in columns.values()):
        raise InputError(f"{table.path}: [data] header = false needs 0-based column indices in [data.columns]")
    table.done()
    return spec


def _int_list(table: Table, key: str, default: list[int], low: int, high: int, longest: int) -> tuple[int, ...]:
    """A list of 1 to `longest` integers, each in [low, high] (booleans refused)."""
    values = table.take(key, list, default)
    if not 0 < len(values) <= longest or not all(
        isinstance(v, int) and not isinstance(v, bool) and low <= v <= high for v in values
    ):
        raise InputError(
            f"{table._name(key)} must be a list of 1 to {longest} integers in [{low}, {high}], got {excerpt(values)}"
        )
    return tuple(values)


def parse_split(table: Table) -> SplitSpec:
    # Both parts of a split must hold enough samples to fit and to score: 5 % .. 95 %.
    fraction = table.number("train_fraction", SplitSpec.train_fraction, 0.05, 0.95)
    seeds = _int_list(table, "seeds", list(SplitSpec.seeds), 0, MAX_SEED, MAX_SEEDS)
    table.done()
    return SplitSpec(fraction, seeds)


def parse_residual(table: Table) -> ResidualSpec:
    components = table.take("components", (int, str), "auto")
    if components == "auto":
        components = None
    elif not isinstance(components, int) or not 1 <= components <= MAX_COMPONENTS:
        raise InputError(
            f"{table.path}: key 'components' in [residual] must be \"auto\" or an integer in [1, {MAX_COMPONENTS}], "
            f"got {excerpt(components)}"
        )
    candidates = _int_list(table, "candidates", list(ResidualSpec.candidates), 1, MAX_COMPONENTS, MAX_COMPONENTS)
    covariance = table.take("covariance", str, ResidualSpec.covariance)
    if covariance not in ("full", "diag"):
        raise InputError(f'{table.path}: key \'covariance\' in [residual] must be "full" or "diag"')
    spec = ResidualSpec(
        components=components,
        candidates=candidates,
        covariance=covariance,
        reg_covar=table.positive("reg_covar", ResidualSpec.reg_covar, high=1e3),
        max_train_samples=table.integer("max_train_samples", ResidualSpec.max_train_samples, 100, 10**7),
    )
    table.done()
    return spec


def _simulate(table: Table) -> SimulateSpec:
    effects = table.take("effects", list, [])
    if not all(isinstance(e, str) for e in effects):
        raise InputError(f"{table.path}: key 'effects' in [simulate] must be a list of strings")
    for effect in effects:
        try:
            parse_effect(effect)
        except InputError as exc:
            raise InputError(f"{table.path}: key 'effects' in [simulate]: {exc}") from None
    output = table.take("output", str, SimulateSpec.output)
    if output not in ("torque", "current"):
        raise InputError(f'{table.path}: key \'output\' in [simulate] must be "torque" or "current"')
    trajectory = table.take("trajectory", str, SimulateSpec.trajectory)
    if trajectory not in TRAJECTORIES:
        known = ", ".join(f'"{name}"' for name in TRAJECTORIES)
        raise InputError(f"{table.path}: key 'trajectory' in [simulate] must be one of {known}")
    spec = SimulateSpec(
        trajectory=trajectory,
        duration=table.positive("duration", SimulateSpec.duration),
        rate_hz=table.positive("rate_hz", SimulateSpec.rate_hz),
        seed=table.take("seed", int, SimulateSpec.seed),
        effects=tuple(effects),
        output=output,
    )
    table.done()
    return spec


#: Sane magnitudes of the `[limits]` keys: angle [rad], speed [rad/s], acceleration [rad/s²], torque [N m].
_LIMIT_RANGES = {"position": 100.0, "velocity": 1e3, "acceleration": 1e5, "torque": 1e5}


def _per_joint(table: Table, key: str, low: float, high: float, *, open_low: bool) -> tuple[float, ...]:
    """A list of one finite number per joint (2) in [low, high] (or (low, high] with `open_low`)."""
    value = table.take(key, list)
    ok = len(value) == 2 and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ok = ok and all(math.isfinite(v) and (v > low if open_low else v >= low) and v <= high for v in value)
    if not ok:
        what = f"{'(' if open_low else '['}{low:g}, {high:g}]"
        raise InputError(f"{table._name(key)} must be a list of 2 finite numbers in {what}, got {excerpt(value)}")
    return tuple(float(v) for v in value)


def _limits(table: Table) -> Limits:
    angle = _LIMIT_RANGES["position"]
    low = _per_joint(table, "position_min", -angle, angle, open_low=False)
    high = _per_joint(table, "position_max", -angle, angle, open_low=False)
    for j, (a, b) in enumerate(zip(low, high)):
        if not a < b:
            raise InputError(
                f"{table.path}: keys 'position_min' and 'position_max' in [limits]: joint {j + 1} has "
                f"min {a:g} ≥ max {b:g} rad"
            )
    limits = Limits(
        position_min=low,
        position_max=high,
        velocity=_per_joint(table, "velocity", 0.0, _LIMIT_RANGES["velocity"], open_low=True),
        acceleration=_per_joint(table, "acceleration", 0.0, _LIMIT_RANGES["acceleration"], open_low=True),
        torque=_per_joint(table, "torque", 0.0, _LIMIT_RANGES["torque"], open_low=True)
        if "torque" in table.raw
        else None,
    )
    table.done()
    return limits


def _reference(table: Table) -> Reference:
    """`[reference]`: label = "…" and [reference.parameters] name = value (finite numbers, |v| ≤ 10⁶)."""
    label = table.take("label", str)
    values = table.table("parameters")
    params = {str(k): values.number(str(k), None, -1e6, 1e6) for k in list(values.raw)}
    values.done()
    table.done()
    if not params:
        raise InputError(f"{table.path}: [reference.parameters] is empty; give the parameters by name (a1 = …)")
    return Reference(label, params)


#: The sections a problem file may leave out (its `Problem` field is then None): name -> parser.
OPTIONAL_SECTIONS = {"simulate": _simulate, "limits": _limits, "reference": _reference}
