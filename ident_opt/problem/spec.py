"""What a problem file says, once parsed and checked: one frozen dataclass per section (`docs/problem-files.md`).

The robot itself (`[robot]`) is an arm description of `ident_opt.arm`; the rest is here. Nothing in this
module reads files: `ident_opt.problem.load_problem` builds these.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ident_opt.arm.base import ALL_COMMANDS, Robot
from ident_opt.errors import InputError

#: At most this many seeds (each is a full refit of every model) and mixture components.
MAX_SEEDS = 100
MAX_SEED = 2**32 - 1  # NumPy's and scikit-learn's range of random seeds
MAX_COMPONENTS = 50


@dataclass(frozen=True)
class KnownLoad:
    """A load a trial carries and the problem knows (`[data.payloads]`): a point mass `mass` [kg] on the last link at
    `com` [m] in that link's frame (a planar arm's: (x,) along link 2; None: the arm's tool point)."""

    mass: float
    com: tuple[float, ...] | None = None


@dataclass(frozen=True)
class DataSpec:
    """The `[data]` section: the trials and how to read them.

    `columns` maps a data-format name (q1, tau2, ...) to the file's column (a name, or a 0-based index);
    `conversions` holds (scale, offset) for the mapped columns that are converted on the way in:
    value = scale × raw + offset (scale −1 flips a sign, 0.01745 reads degrees, offset −π/2 moves a zero).
    With `standard_by_name`, a file whose header already has the standard names (t, q1, q2, ...) is read by
    name, whatever `columns` says. `ignored` are the standard names un-mapped with `name = false`: never read,
    even from a file that has a column of that name (so a file with both torques and currents can be read by
    one of the two).
    """

    trials: tuple[Path, ...] = ()
    header: bool = True
    sheet: str | None = None
    columns: dict[str, str | int] = field(default_factory=dict)
    derivative_cutoff_hz: float | str = "auto"  # Hz, or "auto": read from each trial (`derivatives.cutoff_choice`)
    #: A resting joint's velocity: "zero" (held at 0, `data.dataset.at_rest`), "as_read" (as logged or estimated), or
    #: "auto": zero where the loader estimated the velocities (their sign at rest is the filter's noise), as read
    #: where the file logged them (a logger's velocity may carry what the drive measured).
    rest_velocity: str = "auto"
    conversions: dict[str, tuple[float, float]] = field(default_factory=dict)
    standard_by_name: bool = True
    train: tuple[Path, ...] = ()  # training trials (`train = [...]`): their statistics add up
    test: tuple[Path, ...] = ()  # held-out trials (`test = [...]`), each scored and pooled
    ros_topic: str = "/joint_states"  # a ROS 2 bag's topic of sensor_msgs/msg/JointState messages
    ros_joints: tuple[str, ...] = ()  # a bag's joint names, base to tip: joint k is the k-th (`ident_opt.data.rosbag`)
    ignored: tuple[str, ...] = ()  # standard names not to read (`[data.columns]` name = false)
    #: The loads some trials carry (`[data.payloads]`: trial file → its known load); what splits a drive's gain
    #: from the dynamics' scale (`fitting.drive_gains`).
    payloads: dict[Path, KnownLoad] = field(default_factory=dict)

    def load_of(self, source: str | Path) -> KnownLoad | None:
        """The known load of the trial read from `source` (None: none declared)."""
        path = Path(source)
        for declared, load in self.payloads.items():
            if declared == path or declared.resolve() == path.resolve():
                return load
        return None

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


#: The simulator's reference trajectories by name (`simulator.trajectories`), as a `[simulate]` section names them.
TRAJECTORIES = ("tud01", "fourier", "mixed")


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
    """The `[limits]` section: what an excitation design must respect, per joint (tuples of n values, n the
    robot's joints, in its `joint_names` order; a key the file leaves out is the URDF's <limit> value).

    Joint angles in [position_min, position_max] [rad], |dq| ≤ velocity [rad/s], |ddq| ≤ acceleration
    [rad/s²] and, when given, |τ| ≤ torque [N m] (τ from the nominal model; None: no torque limit)."""

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

    def require(self, command: str) -> None:
        """InputError (exit 2) when `command` does not serve this problem's arm (`Robot.serves`), before any work."""
        robot = self.robot
        if command not in robot.serves:
            serving = ", ".join(c for c in ALL_COMMANDS if c in robot.serves)
            raise InputError(
                f"{command} supports two-joint problems only; {self.path} describes {robot.described_as} "
                f"(the commands for this arm: {serving})"
            )


@dataclass(frozen=True)
class Reference:
    """`[reference]`: a published identification of the same arm to compare against (not ground truth):
    `label` and its parameters by the names of the robot's model (the planar arm's grouped π, an n-joint arm's
    standard parameters; SI units, `docs/conventions.md`), so that `robot.reference(parameters)` gives its
    (arm, π). `urdf` is the URDF they were read from (`[reference] urdf = "…"`), None when given by name."""

    label: str
    parameters: dict[str, float]
    urdf: Path | None = None
