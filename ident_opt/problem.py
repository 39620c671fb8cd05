"""Problem files (`problems/*.toml`): which robot, which data, and how to identify it.

The `[robot]` section is a contract, documented in `docs/problem-files.md` (datasheet values as printed:
motor-side friction and rotor inertia, everything else joint-side, SI units). The other sections are
documented in `docs/problem-files.md`; every key has a default, and an unknown key is an error so that a
typo never falls back silently to a default. Paths are relative to the problem file.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ident_opt.effects import parse_effect
from ident_opt.errors import InputError
from ident_opt.simulate.trajectories import TRAJECTORIES
from ident_opt.urdf_problem import UrdfRobot, data_columns, parse_urdf_robot

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
#: At most this many seeds (each is a full refit of every model) and mixture components.
MAX_SEEDS = 100
MAX_SEED = 2**32 - 1  # NumPy's and scikit-learn's range of random seeds
MAX_COMPONENTS = 50

#: Columns of the data format, in the order the loader reports them.
DATA_COLUMNS = ("t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau1", "tau2", "i1", "i2")


@dataclass(frozen=True)
class Friction:
    """A friction coefficient per direction of motion (motor side, as the datasheet prints it)."""

    positive: float
    negative: float

    @property
    def mean(self) -> float:
        return 0.5 * (self.positive + self.negative)


@dataclass(frozen=True)
class Link:
    """A link modelled as a uniform rectangular bar [m, kg/m^3]."""

    length: float
    width: float
    height: float
    density: float

    @property
    def mass(self) -> float:
        """Bar mass [kg]."""
        return self.density * self.length * self.width * self.height


@dataclass(frozen=True)
class Joint:
    """One actuator's datasheet: motor-side friction and rotor inertia, gear ratio N, torque constant."""

    torque_constant: float  # N m / A, motor side
    gear_ratio: float
    rotor_inertia: float  # kg m^2, motor side
    viscous_friction: Friction  # N m s / rad, motor side
    coulomb_friction: Friction  # N m, motor side
    motor_diameter: float  # m
    actuator_mass: float  # kg

    @property
    def current_to_torque(self) -> float:
        """Joint-side torque per ampere of motor current [N m / A]: torque constant × gear ratio."""
        return self.torque_constant * self.gear_ratio


@dataclass(frozen=True)
class InertialLink:
    """A link given by its measured or CAD inertials: `length` [m] (joint axis to the next axis or the tip),
    `mass` [kg] (everything it carries included), `com` [m] (along the link from its own joint axis) and
    `inertia` [kg m²] (about the centre of mass, around the joint axis)."""

    length: float
    mass: float
    com: float
    inertia: float


@dataclass(frozen=True)
class JointSide:
    """A joint given by joint-side values (`side = "joint"`): friction [N m s/rad, N m], reflected rotor
    inertia N² J [kg m²], and torque constant [N m/A] and gear ratio, needed only for currents."""

    viscous_friction: Friction
    coulomb_friction: Friction
    rotor_inertia: float
    torque_constant: float | None = None
    gear_ratio: float | None = None

    @property
    def current_to_torque(self) -> float | None:
        """Joint-side torque per ampere [N m / A], or None when the problem does not give it."""
        if self.torque_constant is None or self.gear_ratio is None:
            return None
        return self.torque_constant * self.gear_ratio


@dataclass(frozen=True)
class Robot:
    """The `[robot]` section: a two-link planar arm under gravity, as bars and cylinders (`description`
    "bars": a datasheet, motor-side friction and rotor inertia) or as measured inertials ("inertials":
    joint-side values)."""

    gravity: float
    convention: str  # "physical" or "paper"
    link1: Link | InertialLink
    link2: Link | InertialLink
    joint1: Joint | JointSide
    joint2: Joint | JointSide
    payload_mass: float = 0.0
    description: str = "bars"

    @property
    def joints(self) -> tuple[Joint | JointSide, ...]:
        """The joints, in order."""
        return (self.joint1, self.joint2)


@dataclass(frozen=True)
class DataSpec:
    """The `[data]` section: the trials and how to read them.

    `columns` maps a data-format name (q1, tau2, ...) to the file's column (a name, or a 0-based index);
    `conversions` holds (scale, offset) for the mapped columns that are converted on the way in:
    value = scale × raw + offset (scale −1 flips a sign, 0.01745 reads degrees, offset −π/2 moves a zero).
    With `standard_by_name`, a file whose header already has the standard names (t, q1, q2, ...) is read by
    name, whatever `columns` says.
    """

    trials: tuple[Path, ...] = ()
    header: bool = True
    sheet: str | None = None
    columns: dict[str, str | int] = field(default_factory=dict)
    derivative_cutoff_hz: float | str = 15.0  # Hz, or "auto"
    conversions: dict[str, tuple[float, float]] = field(default_factory=dict)
    standard_by_name: bool = True
    train: tuple[Path, ...] = ()  # training trials (`train = [...]`): their statistics add up
    test: tuple[Path, ...] = ()  # held-out trials (`test = [...]`), each scored and pooled
    ros_topic: str = "/joint_states"  # a ROS 2 bag's topic of sensor_msgs/msg/JointState messages
    ros_joints: tuple[str, ...] = ()  # a bag's joint names, base to tip: joint k is the k-th (`ident_opt.rosbag`)

    @property
    def training(self) -> tuple[Path, ...]:
        """The training trials: `train`, else the first of `trials` (the legacy reading)."""
        return self.train or self.trials[:1]

    @property
    def testing(self) -> tuple[Path, ...]:
        """The held-out trials: `test`, else the second of `trials` (the legacy unseen trial)."""
        return self.test if self.train or self.test else self.trials[1:2]


@dataclass(frozen=True)
class SplitSpec:
    """The `[split]` section: the paper's shuffled protocol and the chronological one."""

    train_fraction: float = 0.7
    seeds: tuple[int, ...] = tuple(range(10))


@dataclass(frozen=True)
class ResidualSpec:
    """The `[residual]` section: the Gaussian-mixture residual model."""

    components: int | None = None  # None: chosen on validation data among `candidates`
    candidates: tuple[int, ...] = (1, 2, 3, 4, 6, 8, 10)
    covariance: str = "full"
    reg_covar: float = 1e-4
    max_train_samples: int = 20000


@dataclass(frozen=True)
class SimulateSpec:
    """The `[simulate]` section: a trial from the built-in simulator instead of a data file."""

    trajectory: str = "tud01"
    duration: float = 80.0
    rate_hz: float = 100.0
    seed: int = 0
    effects: tuple[str, ...] = ()
    output: str = "torque"  # "torque" or "current"


@dataclass(frozen=True)
class Limits:
    """The `[limits]` section: what an excitation design must respect, per joint (tuples of n values).

    Joint angles in [position_min, position_max] [rad], |dq| ≤ velocity [rad/s], |ddq| ≤ acceleration
    [rad/s²] and, when given, |τ| ≤ torque [N m] (τ from the datasheet model)."""

    position_min: tuple[float, ...]
    position_max: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]
    torque: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Problem:
    """A parsed, validated problem file."""

    name: str
    path: Path
    robot: Robot
    data: DataSpec = field(default_factory=DataSpec)
    split: SplitSpec = field(default_factory=SplitSpec)
    residual: ResidualSpec = field(default_factory=ResidualSpec)
    simulate: SimulateSpec | None = None
    output_dir: Path | None = None
    limits: Limits | None = None
    reference: Reference | None = None


@dataclass(frozen=True)
class Reference:
    """`[reference]`: a published identification of the same arm to compare against (not ground truth):
    `label` and the grouped parameters by name (SI units, `docs/conventions.md`)."""

    label: str
    parameters: dict[str, float]


class _Table:
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
            raise InputError(f"{self._name(key)} must be {_kind_name(kinds)}, got {_excerpt(value)}")
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
            raise InputError(f"{self._name(key)} must be {what} (finite, at most {high:g}), got {_excerpt(value)}")
        return value

    def integer(self, key: str, default: Any, low: int, high: int) -> int:
        """A whole number in [low, high] (a float such as 0.5 is refused, not truncated)."""
        value = self.take(key, int, default)
        if not low <= value <= high:
            raise InputError(f"{self._name(key)} must be an integer in [{low}, {high}], got {_excerpt(value)}")
        return value

    def positive(self, key: str, default: Any = _REQUIRED, high: float = 1e6) -> float:
        """A finite number in (0, high]."""
        return self.number(key, default, 0.0, high, open_low=True)

    def non_negative(self, key: str, default: Any = _REQUIRED, high: float = 1e6) -> float:
        """A finite number in [0, high]."""
        return self.number(key, default, 0.0, high)

    def table(self, key: str, required: bool = True) -> _Table:
        where = f"{self.where}.{key}" if self.where else key
        if key not in self.raw:
            if required:
                raise InputError(f"{self.path}: section [{where}] is required but missing{self._misspelt(key)}")
            return _Table({}, where, self.path)
        return _Table(self.raw.pop(key), where, self.path)

    def done(self) -> None:
        if self.raw:
            keys = ", ".join(sorted(self.raw))
            place = f"[{self.where}]" if self.where else "the top level"
            raise InputError(f"{self.path}: unknown key(s) {keys} in {place} (check the spelling)")


def _excerpt(value: Any, limit: int = 60) -> str:
    """A short repr of a value for a message (a huge list must not become a megabyte-long line)."""
    text = repr(value)
    return (
        text if len(text) <= limit else text[: limit - 5] + " ...]" if isinstance(value, list) else text[:limit] + "..."
    )


def _kind_name(kinds: tuple[type, ...]) -> str:
    names = {float: "a number", int: "an integer", str: "a string", bool: "true or false", list: "a list"}
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def _friction(table: _Table, key: str, default: Any = _REQUIRED) -> Friction:
    """A friction coefficient: `{positive, negative}`, or (joint-side tables) one number for both."""
    if default is not _REQUIRED and key not in table.raw:
        return Friction(default, default)
    if not isinstance(table.raw.get(key), dict) and default is not _REQUIRED:
        value = table.non_negative(key, high=LIMITS["friction"])
        return Friction(value, value)
    sub = table.table(key)
    limit = LIMITS["friction"]
    friction = Friction(sub.non_negative("positive", high=limit), sub.non_negative("negative", high=limit))
    sub.done()
    return friction


#: The numeric keys of a bar link and of a datasheet joint: key -> (sign rule, the `LIMITS` unit of its range).
_BAR_FIELDS = {
    "length": ("positive", "length"),
    "width": ("positive", "length"),
    "height": ("positive", "length"),
    "density": ("positive", "density"),
}
_DATASHEET_FIELDS = {
    "torque_constant": ("positive", "torque_constant"),
    "gear_ratio": ("positive", "gear_ratio"),
    "rotor_inertia": ("non_negative", "inertia"),
    "motor_diameter": ("positive", "length"),
    "actuator_mass": ("non_negative", "mass"),
}


def _numbers(table: _Table, fields: dict[str, tuple[str, str]]) -> dict[str, float]:
    """Each key of `fields` read as a finite number with its sign rule and its unit's range."""
    return {key: getattr(table, sign)(key, high=LIMITS[unit]) for key, (sign, unit) in fields.items()}


def _link(table: _Table) -> Link:
    link = Link(**_numbers(table, _BAR_FIELDS))
    table.done()
    return link


def _joint(table: _Table) -> Joint:
    joint = Joint(
        viscous_friction=_friction(table, "viscous_friction"),
        coulomb_friction=_friction(table, "coulomb_friction"),
        **_numbers(table, _DATASHEET_FIELDS),
    )
    table.done()
    return joint


def _com(table: _Table) -> float:
    """`com` along the link [m]; a table {x, y} is accepted only on the link's line (y = 0)."""
    if not isinstance(table.raw.get("com"), dict):
        return table.number("com", _REQUIRED, -LIMITS["length"], LIMITS["length"])
    sub = table.table("com")
    x = sub.number("x", _REQUIRED, -LIMITS["length"], LIMITS["length"])
    y = sub.number("y", 0.0, -LIMITS["length"], LIMITS["length"])
    sub.done()
    if y != 0:
        raise InputError(
            f"{table.path}: key 'y' in [{sub.where}]: a centre of mass off the link's line (y = {y:g} m) is not "
            "supported yet; the grouped parameters assume y = 0"
        )
    return x


def _inertial_link(table: _Table) -> InertialLink:
    link = InertialLink(
        length=table.positive("length", high=LIMITS["length"]),
        mass=table.positive("mass", high=LIMITS["mass"]),
        com=_com(table),
        inertia=table.non_negative("inertia", high=LIMITS["inertia"]),
    )
    table.done()
    return link


def _joint_side(table: _Table) -> JointSide:
    side = table.take("side", str)
    if side != "joint":
        raise InputError(f"{table.path}: key 'side' in [{table.where}] must be \"joint\" for inertial links")
    joint = JointSide(
        viscous_friction=_friction(table, "viscous_friction", 0.0),
        coulomb_friction=_friction(table, "coulomb_friction", 0.0),
        rotor_inertia=table.non_negative("rotor_inertia", 0.0, high=LIMITS["inertia"]),
        torque_constant=table.number("torque_constant", None, 0.0, LIMITS["torque_constant"], open_low=True)
        if "torque_constant" in table.raw
        else None,
        gear_ratio=table.number("gear_ratio", None, 0.0, LIMITS["gear_ratio"], open_low=True)
        if "gear_ratio" in table.raw
        else None,
    )
    table.done()
    return joint


#: Keys that tell the two per-link descriptions apart (a file uses exactly one).
_BAR_KEYS, _INERTIAL_KEYS = {"width", "height", "density"}, {"mass", "com", "inertia"}


def _description(table: _Table) -> str:
    """ "bars" or "inertials", from the keys of [robot.link1] and [robot.link2]; mixing them is an error."""
    kinds = set()
    for name in ("link1", "link2"):
        keys = set(table.raw.get(name, {})) if isinstance(table.raw.get(name), dict) else set()
        if keys & _BAR_KEYS and keys & _INERTIAL_KEYS:
            raise InputError(
                f"{table.path}: [robot.{name}] mixes a bar ({', '.join(sorted(keys & _BAR_KEYS))}) and measured "
                f"inertials ({', '.join(sorted(keys & _INERTIAL_KEYS))}); use one description"
            )
        kinds.add("inertials" if keys & _INERTIAL_KEYS else "bars")
    if len(kinds) > 1:
        raise InputError(f"{table.path}: [robot.link1] and [robot.link2] use different descriptions; use one")
    return kinds.pop()


def _robot(table: _Table) -> Robot | UrdfRobot:
    if "urdf" in table.raw:  # an n-joint arm from a URDF: ident_opt.urdf_problem
        return parse_urdf_robot(table, table.path.resolve().parent)
    description = _description(table)
    default = "physical" if description == "inertials" else _REQUIRED
    convention = table.take("convention", str, default)
    if convention not in ("physical", "paper"):
        raise InputError(
            f'{table.path}: key \'convention\' in [robot] must be "physical" or "paper", got {_excerpt(convention)}'
        )
    if description == "inertials" and convention != "physical":
        raise InputError(f"{table.path}: key 'convention' in [robot]: measured inertials are read \"physical\" only")
    gravity = table.positive("gravity", high=LIMITS["gravity"])
    link, joint = (_inertial_link, _joint_side) if description == "inertials" else (_link, _joint)
    link1, link2 = link(table.table("link1")), link(table.table("link2"))
    joint1, joint2 = joint(table.table("joint1")), joint(table.table("joint2"))
    payload = table.table("payload", required=False)
    payload_mass = payload.non_negative("mass", 0.0, high=LIMITS["mass"])
    payload.done()
    table.done()
    return Robot(gravity, convention, link1, link2, joint1, joint2, payload_mass, description)


def _relative(base: Path, value: str) -> Path:
    path = Path(value)
    return path if path.is_absolute() else (base / path)


def _column(table: _Table, key: str) -> tuple[str | int, tuple[float, float] | None]:
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


def _cutoff(table: _Table) -> float | str:
    """`derivative_cutoff_hz`: a number [Hz] or "auto" (chosen from each trial's spectrum, `data.choose_cutoff`)."""
    if table.raw.get("derivative_cutoff_hz") == "auto":
        table.raw.pop("derivative_cutoff_hz")
        return "auto"
    return table.positive("derivative_cutoff_hz", DataSpec.derivative_cutoff_hz, high=LIMITS["rate_hz"])


def _paths(table: _Table, key: str) -> list[str]:
    """A list of data files under `key` of [data] (strings), or []."""
    paths = table.take(key, list, [])
    for i, trial in enumerate(paths):
        if not isinstance(trial, str):
            raise InputError(f"{table.path}: key '{key}' in [data]: entry {i} must be a path string")
    return paths


def _names(table: _Table, key: str, n_joints: int) -> list[str]:
    """`key` of [data]: a list of exactly `n_joints` distinct strings (joint names), or [] when absent."""
    names = table.take(key, list, [])
    if names and (
        len(names) != n_joints or not all(isinstance(n, str) and n for n in names) or len(set(names)) < n_joints
    ):
        raise InputError(
            f"{table.path}: key '{key}' in [data] must list {n_joints} distinct joint names, base to tip, "
            f"got {_excerpt(names)}"
        )
    return names


def _data(table: _Table, base: Path, n_joints: int = 2) -> DataSpec:
    known = DATA_COLUMNS if n_joints == 2 else data_columns(n_joints)
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
        trials=tuple(_relative(base, t) for t in trials) or tuple(_relative(base, t) for t in train + test),
        train=tuple(_relative(base, t) for t in train),
        test=tuple(_relative(base, t) for t in test),
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


def _int_list(table: _Table, key: str, default: list[int], low: int, high: int, longest: int) -> tuple[int, ...]:
    """A list of 1 to `longest` integers, each in [low, high] (booleans refused)."""
    values = table.take(key, list, default)
    if not 0 < len(values) <= longest or not all(
        isinstance(v, int) and not isinstance(v, bool) and low <= v <= high for v in values
    ):
        raise InputError(
            f"{table._name(key)} must be a list of 1 to {longest} integers in [{low}, {high}], got {_excerpt(values)}"
        )
    return tuple(values)


def _split(table: _Table) -> SplitSpec:
    # Both parts of a split must hold enough samples to fit and to score: 5 % .. 95 %.
    fraction = table.number("train_fraction", SplitSpec.train_fraction, 0.05, 0.95)
    seeds = _int_list(table, "seeds", list(SplitSpec.seeds), 0, MAX_SEED, MAX_SEEDS)
    table.done()
    return SplitSpec(fraction, seeds)


def _residual(table: _Table) -> ResidualSpec:
    components = table.take("components", (int, str), "auto")
    if components == "auto":
        components = None
    elif not isinstance(components, int) or not 1 <= components <= MAX_COMPONENTS:
        raise InputError(
            f"{table.path}: key 'components' in [residual] must be \"auto\" or an integer in [1, {MAX_COMPONENTS}], "
            f"got {_excerpt(components)}"
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


def _simulate(table: _Table) -> SimulateSpec:
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


def _per_joint(table: _Table, key: str, low: float, high: float, *, open_low: bool) -> tuple[float, ...]:
    """A list of one finite number per joint (2) in [low, high] (or (low, high] with `open_low`)."""
    value = table.take(key, list)
    ok = len(value) == 2 and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ok = ok and all(math.isfinite(v) and (v > low if open_low else v >= low) and v <= high for v in value)
    if not ok:
        what = f"{'(' if open_low else '['}{low:g}, {high:g}]"
        raise InputError(f"{table._name(key)} must be a list of 2 finite numbers in {what}, got {_excerpt(value)}")
    return tuple(float(v) for v in value)


def _limits(table: _Table) -> Limits:
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


def load_problem(path: str | Path) -> Problem:
    """Read and validate a problem file; raise `InputError` naming the file and key on any fault."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: problem file not found")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML file ({exc})") from None
    top = _Table(raw, "", path)
    base = path.resolve().parent
    name = top.take("name", str)
    robot = _robot(top.table("robot"))
    sections = {  # each section fills the `Problem` field of its name, read in this order
        "data": _data(top.table("data", required=False), base, getattr(robot, "n_joints", 2)),
        "split": _split(top.table("split", required=False)),
        "residual": _residual(top.table("residual", required=False)),
    }
    for key, parse in _OPTIONAL_SECTIONS.items():
        sections[key] = parse(top.table(key)) if key in top.raw else None
    output = top.table("output", required=False)
    out_dir = output.take("dir", str, None)
    output.done()
    top.done()
    return Problem(
        name=name, path=path, robot=robot, output_dir=_relative(base, out_dir) if out_dir else None, **sections
    )


def _reference(table: _Table) -> Reference:
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
_OPTIONAL_SECTIONS = {"simulate": _simulate, "limits": _limits, "reference": _reference}
