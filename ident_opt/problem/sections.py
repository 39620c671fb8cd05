"""The sections of a problem file other than `[robot]`: `[data]`, `[split]`, `[residual]`, `[simulate]`,
`[limits]` and `[reference]` (`docs/problem-files.md`). Each parser takes its checked `Table` (and, where the
section depends on the arm, the robot `[robot]` describes) and returns the section's spec
(`ident_opt.problem.spec`).
"""

from __future__ import annotations

import math
from pathlib import Path

from ident_opt.arm.base import Robot
from ident_opt.columns import channel_names, data_columns
from ident_opt.effects import parse_effect
from ident_opt.errors import InputError
from ident_opt.problem.spec import (
    MAX_COMPONENTS,
    MAX_SEED,
    MAX_SEEDS,
    TRAJECTORIES,
    DataSpec,
    KnownLoad,
    Limits,
    Reference,
    ResidualSpec,
    SimulateSpec,
    SplitSpec,
)
from ident_opt.problem.table import LIMITS, Table, excerpt


def relative(base: Path, value: str) -> Path:
    """A path of the problem file: absolute as written, else relative to `base` (the problem file's folder)."""
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


def _unmapped(table: Table, key: str, n_joints: int) -> bool:
    """Whether `[data.columns]` entry `key` is `false`: do not read that standard column, even from a file with a
    column of its name (a file with both torques and currents is read by one of them). `true` means nothing, and
    t and q1 … qn cannot be left unread."""
    value = table.raw.get(key)
    if not isinstance(value, bool):
        return False
    if value:
        raise InputError(
            f"{table.path}: key '{key}' in [data.columns] must be a column name, a 0-based index, a table "
            "{column, scale, offset}, or false (leave the column unread); got true"
        )
    required = ("t", *channel_names(n_joints)["q"])
    if key in required:
        raise InputError(
            f"{table.path}: key '{key}' in [data.columns] cannot be false: {', '.join(required)} are always read "
            "(map it to the file's column instead)"
        )
    table.raw.pop(key)
    return True


def _cutoff(table: Table) -> float | str:
    """`derivative_cutoff_hz`: a number [Hz] or "auto" (read from each trial's spectrum: `choose_cutoff`)."""
    if table.raw.get("derivative_cutoff_hz", "auto") == "auto":
        table.raw.pop("derivative_cutoff_hz", None)
        return "auto"
    return table.positive("derivative_cutoff_hz", 15.0, high=LIMITS["rate_hz"])


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


def _payloads(table: Table, base: Path) -> dict[Path, KnownLoad]:
    """`[data.payloads]`: each trial file (a key, relative to `base`) → its known load, `{mass = kg, com = [m, ...]}`
    (`com` optional: the arm's tool point)."""
    out = {}
    for key in list(table.raw):
        sub = table.table(key)
        mass = sub.positive("mass", high=LIMITS["mass"])
        com = sub.take("com", list, None)
        if com is not None and (
            not 1 <= len(com) <= 3
            or not all(isinstance(c, int | float) and not isinstance(c, bool) and math.isfinite(c) for c in com)
            or any(abs(c) > LIMITS["length"] for c in com)
        ):
            raise InputError(
                f"{table.path}: key 'com' in [data.payloads.\"{key}\"] must list 1 to 3 finite numbers [m] (a "
                f"planar arm's: x along link 2; an n-joint arm's: x, y, z in the last link's frame), got {excerpt(com)}"
            )
        sub.done()
        out[relative(base, key)] = KnownLoad(mass, None if com is None else tuple(float(c) for c in com))
    table.done()
    return out


def parse_data(table: Table, base: Path, n_joints: int = 2) -> DataSpec:
    """`[data]` and `[data.columns]` of an arm of `n_joints` joints: the trials (relative to `base`), how to read
    them, and where each standard column is (a name, an index, a conversion, or false: not read)."""
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
    ignored: list[str] = []
    for key in list(columns_table.raw):
        if key not in known:
            raise InputError(f"{table.path}: unknown column '{key}' in [data.columns]; known: {', '.join(known)}")
        if _unmapped(columns_table, key, n_joints):
            ignored.append(key)
            continue
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
        rest_velocity=_rest_velocity(table),
        conversions=conversions,
        standard_by_name=table.take("standard_by_name", bool, True),
        ros_topic=table.take("ros_topic", str, DataSpec.ros_topic),
        ros_joints=tuple(_names(table, "ros_joints", n_joints)),
        ignored=tuple(ignored),
        payloads=_payloads(table.table("payloads", required=False), base),
    )
    if not spec.header and any(isinstance(v, str) for v in columns.values()):
        raise InputError(f"{table.path}: [data] header = false needs 0-based column indices in [data.columns]")
    table.done()
    return spec


#: The values of `[data] rest_velocity` (`DataSpec.rest_velocity`).
REST_VELOCITY = ("auto", "zero", "as_read")


def _rest_velocity(table: Table) -> str:
    """`rest_velocity`: one of `REST_VELOCITY`."""
    value = table.take("rest_velocity", str, "auto")
    if value not in REST_VELOCITY:
        raise InputError(
            f"{table._name('rest_velocity')} must be one of {', '.join(REST_VELOCITY)}, got {excerpt(value)}"
        )
    return value


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
    """`[split]`: the training fraction of the chronological and shuffled splits, and the paper's seeds."""
    # Both parts of a split must hold enough samples to fit and to score: 5 % .. 95 %.
    fraction = table.number("train_fraction", SplitSpec.train_fraction, 0.05, 0.95)
    seeds = _int_list(table, "seeds", list(SplitSpec.seeds), 0, MAX_SEED, MAX_SEEDS)
    table.done()
    return SplitSpec(fraction, seeds)


def parse_residual(table: Table) -> ResidualSpec:
    """`[residual]`: the GMR residual model's components, candidates, covariance and regulariser."""
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


def parse_simulate(table: Table) -> SimulateSpec:
    """`[simulate]`: the built-in simulator's trajectory, duration [s], rate [Hz], seed, effects and output."""
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


#: The `[limits]` keys and the range of each value: (low, high, whether low itself is excluded); an angle [rad],
#: a speed [rad/s], an acceleration [rad/s²], a torque [N m]. A value beyond is a typo or a unit mistake.
_LIMIT_RANGES = {
    "position_min": (-100.0, 100.0, False),
    "position_max": (-100.0, 100.0, False),
    "velocity": (0.0, 1e3, True),
    "acceleration": (0.0, 1e5, True),
    "torque": (0.0, 1e5, True),
}
#: The attribute of a URDF's <limit> that is each key's default (`Robot.limits`), for messages.
_URDF_LIMIT = {"position_min": "lower", "position_max": "upper", "velocity": "velocity", "torque": "effort"}


def _joint_label(robot: Robot, j: int) -> str:
    """ "joint 3 (elbow)": joint j (0-based) by its number and, where it has one of its own, its name."""
    name = robot.joint_names[j]
    return f"joint {j + 1}" if name == f"joint{j + 1}" else f"joint {j + 1} ({name})"


def _in_range(value: object, key: str) -> bool:
    """Whether `value` is a finite number (not a boolean) within the range of `[limits]` key `key`."""
    low, high, open_low = _LIMIT_RANGES[key]
    if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
        return False
    return (value > low if open_low else value >= low) and value <= high


def _range_text(key: str) -> str:
    low, high, open_low = _LIMIT_RANGES[key]
    return f"{'(' if open_low else '['}{low:g}, {high:g}]"


def _per_joint(table: Table, key: str, robot: Robot) -> tuple[float, ...]:
    """`key` of [limits] as one value per joint, in the key's unit: a list of n finite numbers in its range
    (n = the robot's joints, in its `joints` order), or one such number for every joint."""
    n, what = robot.n_joints, _range_text(key)
    value = table.take(key, (float, list))
    if not isinstance(value, list):
        if not _in_range(value, key):
            raise InputError(
                f"{table._name(key)} must be a finite number in {what} (for every joint) or a list of {n}, one per "
                f"joint, got {excerpt(value)}"
            )
        return (float(value),) * n
    if len(value) != n:
        names = ", ".join(robot.joint_names[:8]) + (", …" if n > 8 else "")
        why = (
            f"{_joint_label(robot, len(value))} has none"
            if len(value) < n
            else f"{len(value) - n} more than the arm's joints"
        )
        raise InputError(
            f"{table._name(key)} must list {n} numbers, one per joint ({names}), or be one number for every "
            f"joint; it lists {len(value)} ({excerpt(value)}): {why}"
        )
    return _in_ranges(
        table,
        key,
        value,
        lambda j: f"{_joint_label(robot, j)} has {excerpt(value[j])}; each value must be a finite number in {what}",
    )


def _in_ranges(table: Table, key: str, values, why) -> tuple[float, ...]:
    """`values` (one per joint) as floats when each is a finite number in the range of `[limits]` key `key`
    (`_in_range`); else an InputError naming the key, `why(j)` saying what is wrong with the first joint j."""
    bad = next((j for j, v in enumerate(values) if not _in_range(v, key)), None)
    if bad is not None:
        raise InputError(f"{table._name(key)}: {why(bad)}")
    return tuple(float(v) for v in values)


def _default(table: Table, key: str, robot: Robot) -> tuple[float, ...] | None:
    """The value of a `[limits]` key the file leaves out: the URDF's <limit> when it gives it for every joint
    (within the key's range). A key it gives for some joints only is an error naming the others, `torque`
    included: a design must not drop silently the efforts the URDF states. Without any URDF value, `torque` is
    None (no torque limit) and the other keys are required."""
    given = robot.limits().get(key)
    if given is None or all(v is None for v in given):
        if key != "torque":
            table.take(key, float)  # absent: raises "required but missing" (naming a near spelling, if any)
        return None
    attribute = _URDF_LIMIT[key]
    lacking = [_joint_label(robot, j) for j, v in enumerate(given) if v is None]
    if lacking:
        hint = " (a continuous joint has no lower or upper)" if key.startswith("position") else ""
        raise InputError(
            f"{table._name(key)} is required: the URDF's <limit {attribute}=…> is missing for {', '.join(lacking)}"
            f"{hint}; give {key} in [limits], a list of {robot.n_joints} or one number for every joint"
        )
    return _in_ranges(
        table,
        key,
        given,
        lambda j: (
            f"the URDF's <limit {attribute}={given[j]:g}> of {_joint_label(robot, j)} is not in "
            f"{_range_text(key)}; give {key} in [limits]"
        ),
    )


def parse_limits(table: Table, robot: Robot) -> Limits:
    """`[limits]` of an arm of n joints (`docs/problem-files.md`): each key a list of n values or one for every
    joint; a key left out is the URDF's <limit> (`_default`); position_min < position_max for every joint."""
    defaulted = {key for key in _LIMIT_RANGES if key not in table.raw}
    values = {
        key: _default(table, key, robot) if key in defaulted else _per_joint(table, key, robot) for key in _LIMIT_RANGES
    }
    for j, (a, b) in enumerate(zip(values["position_min"], values["position_max"])):
        if not a < b:
            source = " (from the URDF's <limit>)" if defaulted & {"position_min", "position_max"} else ""
            raise InputError(
                f"{table.path}: keys 'position_min' and 'position_max' in [limits]: {_joint_label(robot, j)} has "
                f"min {a:g} ≥ max {b:g} rad{source}"
            )
    table.done()
    return Limits(**values)


def parse_reference(table: Table, robot: Robot, base: Path) -> Reference:
    """`[reference]` (`docs/problem-files.md`): `label` and either [reference.parameters] (names of the robot's
    model → values, finite, |v| ≤ 10⁶) or `urdf` (relative to the problem file: a URDF of the same arm, read by
    `Robot.reference_urdf`). The names are checked against the robot's model
    (`Robot.reference`) here, so a bad reference stops every command, `check` included."""
    label = table.take("label", str)
    if ("urdf" in table.raw) == ("parameters" in table.raw):
        given = "both" if "urdf" in table.raw else "neither"
        raise InputError(
            f"{table.path}: [reference] needs either 'urdf' (a URDF of the same arm: its inertials and <dynamics>) "
            f"or [reference.parameters] (the parameters by name), got {given}"
        )
    urdf, where = None, f"{table.path}: [reference.parameters]"
    if "urdf" in table.raw:
        urdf = relative(base, table.take("urdf", str))
        where = f"{table.path}: key 'urdf' in [reference] ({urdf})"
        try:
            params = robot.reference_urdf(urdf)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
    else:
        values = table.table("parameters")
        params = {str(k): values.number(str(k), None, -1e6, 1e6) for k in list(values.raw)}
        values.done()
        if not params:
            raise InputError(f"{where} is empty; give the parameters by name (a1 = …, or m_<link> = …)")
    table.done()
    try:
        robot.reference(params)
    except InputError as exc:
        message = str(exc).removeprefix("[reference.parameters]: ")
        raise InputError(f"{where}: {message}") from None
    return Reference(label, params, urdf)
