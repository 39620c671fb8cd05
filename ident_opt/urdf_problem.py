"""The `[robot]` section of a problem file for an n-joint arm from a URDF (`docs/problem-files.md`).

    [robot]
    urdf = "../data/kuka_lwr4/kuka_lwr4.urdf"     # relative to the problem file
    joints = ["lwr_0_joint", ..., "lwr_6_joint"]  # the revolute joints, base to tip
    gravity = 9.81                                # m/s² along −z of the base, or [gx, gy, gz]
    base = "lwr_base_link"                        # optional: the link the chain starts from (default: root)
    friction = true                               # fv_<joint>, fc_<joint> (default true)
    armature = true                               # ia_<joint> (default true)
    offsets = false                               # off_<joint>: constant torque offsets (default false)
    couplings = [["joint_6", "joint_5", 1.0]]     # optional: joint_6's drive also turns with joint_5 × 1.0
    prior_weight = 1e-7                           # λ of the log-det prior of the plausible fit
    mass_range = 0.5                              # each link's mass within ± 50 % of the URDF's (or false)
    com_box = 0.1                                 # centre of mass within ± 0.1 m of the URDF's (or false)
    [robot.lwr_0_joint]                           # optional, per joint
    rotor_inertia = 0.0                           # kg m², motor side
    gear_ratio = 1.0
    torque_constant = 1.0                         # N m/A, motor side

Reading it builds the arm (`ident_opt.urdf_arm.UrdfArm`), so a URDF that does not parse, names joints the
file lacks, or is not a serial chain of revolute joints is refused at load time, naming the file and the
element. The data columns of such a problem are t, q1…qn, dq1…dqn, ddq1…ddqn, tau1…taun, i1…in.

Two joints with parallel axes (link 1's centre of mass on the line between them, gravity not along them) are
the two-link planar arm instead: `ident_opt.urdf_planar` builds the measured-inertials `Robot` from the URDF
(keys urdf, joints, gravity, base, [robot.joint1], [robot.joint2]), and the two-link pipeline runs on it.
`form = "n-joint"` keeps such an arm on the n-joint path; `form = "planar"` makes a URDF that is not one an
error naming the reason (default "auto": planar when it is one, else n-joint).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ident_opt.errors import InputError

if TYPE_CHECKING:  # problem.py imports this module: the two-link Robot is named for the type checker only
    from ident_opt.problem import Robot

#: The per-sample signals of an n-joint data file, each with one column per joint.
SIGNALS = ("q", "dq", "ddq", "tau", "i")
#: At most this many joints (a sanity limit on `joints`).
MAX_JOINTS = 64


def data_columns(n_joints: int) -> tuple[str, ...]:
    """The data-format column names of an n-joint arm: t, q1…qn, dq1…dqn, ddq1…ddqn, tau1…taun, i1…in."""
    return ("t", *(f"{s}{j + 1}" for s in SIGNALS for j in range(n_joints)))


@dataclass(frozen=True)
class UrdfJointSpec:
    """Optional per-joint drive data: rotor inertia [kg m², motor side], gear ratio, torque constant [N m/A]."""

    rotor_inertia: float = 0.0
    gear_ratio: float = 1.0
    torque_constant: float = 1.0


@dataclass(frozen=True)
class UrdfRobot:
    """The `[robot]` section of an n-joint arm from a URDF (module doc)."""

    urdf: Path
    joints: tuple[str, ...]
    gravity: tuple[float, float, float]
    base: str | None = None
    friction: bool = True
    armature: bool = True
    offsets: bool = False
    prior_weight: float = 1e-7
    mass_range: float | None = 0.5
    com_box: float | None = 0.1
    drives: dict[str, UrdfJointSpec] = field(default_factory=dict)
    couplings: tuple[tuple[str, str, float], ...] = ()
    description: str = "urdf"

    @property
    def n_joints(self) -> int:
        """n, the number of joints."""
        return len(self.joints)

    @cached_property
    def arm(self):
        """The `UrdfArm` (built once; InputError naming the file and element on a bad URDF)."""
        from ident_opt.urdf_arm import UrdfArm  # deferred: Pinocchio and CasADi are heavy imports

        return UrdfArm(
            str(self.urdf),
            self.joints,
            self.gravity,
            self.base,
            self.friction,
            self.armature,
            self.offsets,
            self.couplings,
        )


def _optional_fraction(table: Any, key: str, default: float) -> float | None:
    """A number in (0, 10], or false for "no bound"."""
    if table.raw.get(key) is False:
        table.raw.pop(key)
        return None
    return table.positive(key, default, high=10.0)


def _gravity(table: Any) -> tuple[float, float, float]:
    """`gravity`: a magnitude along −z of the base [m/s²] or a 3-vector in the base frame."""
    raw = table.raw.get("gravity")
    if isinstance(raw, list):
        value = table.take("gravity", list)
        if len(value) != 3 or not all(isinstance(g, (int, float)) and not isinstance(g, bool) for g in value):
            raise InputError(f"{table.path}: key 'gravity' in [robot] must be a number or a list of 3 numbers")
        if not all(abs(g) <= 100.0 for g in value):
            raise InputError(f"{table.path}: key 'gravity' in [robot]: components above 100 m/s²")
        return tuple(float(g) for g in value)  # type: ignore[return-value]
    return (0.0, 0.0, -table.positive("gravity", high=100.0))


def _couplings(table: Any, joints: list[str]) -> tuple[tuple[str, str, float], ...]:
    """`couplings`: [[drive joint, other joint, ratio], ...]: that drive turns at dq_drive + ratio · dq_other."""
    out = []
    for entry in table.take("couplings", list, []):
        ok = isinstance(entry, list) and len(entry) == 3 and all(isinstance(e, str) for e in entry[:2])
        ok = ok and isinstance(entry[2], (int, float)) and not isinstance(entry[2], bool) and abs(entry[2]) <= 1e3
        if not ok or entry[0] not in joints or entry[1] not in joints or entry[0] == entry[1]:
            raise InputError(
                f"{table.path}: key 'couplings' in [robot]: each entry must be [drive joint, other joint, ratio] with "
                f"two different joints of 'joints' and |ratio| ≤ 1000, got {entry!r}"
            )
        out.append((entry[0], entry[1], float(entry[2])))
    return tuple(out)


#: `form` in [robot]: which model a URDF becomes ("auto": planar when the URDF is a planar two-link arm).
FORMS = ("auto", "planar", "n-joint")


def _joint_names(table: Any) -> list[str]:
    """`joints`: 1 to `MAX_JOINTS` distinct, non-empty joint names."""
    joints = table.take("joints", list)
    if not 0 < len(joints) <= MAX_JOINTS or not all(isinstance(j, str) and j for j in joints):
        raise InputError(f"{table.path}: key 'joints' in [robot] must be a list of 1 to {MAX_JOINTS} joint names")
    if len(set(joints)) != len(joints):
        raise InputError(f"{table.path}: key 'joints' in [robot] names a joint twice")
    return joints


def _planar(table: Any, urdf: Path, joints: list[str], gravity: tuple[float, float, float], base: str | None):
    """The planar two-link robot (`ident_opt.urdf_planar`) when `form` asks for it or allows it and the URDF
    is one; None for the n-joint path. A URDF that is not planar is an error only under form = "planar"."""
    form = table.take("form", str, "auto")
    if form not in FORMS:
        raise InputError(f"{table.path}: key 'form' in [robot] must be one of {', '.join(FORMS)}, got {form!r}")
    if form == "n-joint" or (form == "auto" and len(joints) != 2):
        return None
    if len(joints) != 2:
        raise InputError(f'{table.path}: form = "planar" in [robot] needs exactly two joints, got {len(joints)}')
    from ident_opt import urdf_planar  # deferred: it imports ident_opt.problem, which imports this module

    try:
        geometry = urdf_planar.planar_geometry(urdf, tuple(joints), gravity, base)
    except urdf_planar.NotPlanar:
        if form == "planar":
            raise
        return None
    return urdf_planar.planar_robot(table, urdf, tuple(joints), geometry)


def parse_urdf_robot(table: Any, base_dir: Path) -> Robot | UrdfRobot:
    """The URDF `[robot]` section from problem.py's checked table (`take`, `positive`, `table`, `done`), the
    URDF's path relative to `base_dir`; builds the arm to check it (module doc). Two revolute joints with
    parallel axes give the planar two-link `Robot` (`ident_opt.urdf_planar.UrdfPlanarRobot`), unless
    form = "n-joint"; anything else the n-joint `UrdfRobot`."""
    urdf = Path(table.take("urdf", str))
    urdf = urdf if urdf.is_absolute() else base_dir / urdf
    joints = _joint_names(table)
    gravity, base = _gravity(table), table.take("base", str, None)
    planar = _planar(table, urdf, joints, gravity, base)
    if planar is not None:
        return planar
    drives = {}
    for joint in joints:
        if joint in table.raw:
            sub = table.table(joint)
            drives[joint] = UrdfJointSpec(
                sub.non_negative("rotor_inertia", 0.0, high=1e3),
                sub.positive("gear_ratio", 1.0, high=1e5),
                sub.positive("torque_constant", 1.0, high=1e3),
            )
            sub.done()
    robot = UrdfRobot(
        urdf=urdf,
        joints=tuple(joints),
        gravity=gravity,
        base=base,
        friction=table.take("friction", bool, True),
        armature=table.take("armature", bool, True),
        offsets=table.take("offsets", bool, False),
        prior_weight=table.positive("prior_weight", 1e-7, high=1e6),
        mass_range=_optional_fraction(table, "mass_range", 0.5),
        com_box=_optional_fraction(table, "com_box", 0.1),
        drives=drives,
        couplings=_couplings(table, joints),
    )
    table.done()
    robot.arm  # noqa: B018  (build it now: a bad URDF is an error of the problem file)
    return robot
