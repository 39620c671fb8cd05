"""The `[robot]` section of an arm from a URDF (`docs/problem-files.md`).

    [robot]
    urdf = "../data/kuka_lwr4/kuka_lwr4.urdf"     # relative to the problem file
    joints = ["lwr_0_joint", ..., "lwr_6_joint"]  # the revolute joints, base to tip
    gravity = 9.81                                # m/s² along −z of the base, or [gx, gy, gz]
    base = "lwr_base_link"                        # optional: the link the chain starts from (default: root)
    form = "auto"                                 # "auto", "planar" (refuse if not) or "n-joint"
    friction = true                               # fv_<joint>, fc_<joint> (default true)
    armature = true                               # ia_<joint> (default true)
    offsets = false                               # off_<joint>: constant torque offsets (default false)
    couplings = [["joint_6", "joint_5", 1.0]]     # optional: joint_6's drive also turns with joint_5 × 1.0
    prior_weight = 1e-7                           # λ of the log-det prior of the plausible fit
    mass_range = 0.5                              # each link's mass within ± 50 % of the URDF's (or false)
    com_box = 0.1                                 # centre of mass within ± 0.1 m of the URDF's (or false)
    [robot.lwr_0_joint]                           # optional, per joint (`ident_opt.problem.joints`)
    side = "motor"                                # where the values below are measured (default "motor")
    rotor_inertia = 1.2e-5                        # kg m²
    gear_ratio = 160.0
    torque_constant = 0.05                        # N m/A, motor side (for currents)
    viscous_friction = 0.0                        # default: the URDF's <dynamics damping>
    coulomb_friction = 0.0                        # default: the URDF's <dynamics friction>

Reading it builds the arm, so a URDF that does not parse, names joints the file lacks, or is not a serial chain
of revolute joints is refused at load time, naming the file and the element. Two joints with parallel axes (link
1's centre of mass on the line between them, gravity not along them) are the planar two-link arm
(`ident_opt.arm.planar_urdf`; their extras in [robot.joint1], [robot.joint2], joint side), unless
form = "n-joint"; anything else is the n-joint chain (`ident_opt.arm.chain.ChainRobot`).
"""

from __future__ import annotations

from pathlib import Path

from ident_opt.arm import planar_urdf
from ident_opt.arm.chain_robot import ChainRobot
from ident_opt.arm.urdf import UrdfJoint, parse_urdf
from ident_opt.errors import InputError
from ident_opt.problem.joints import joint_values
from ident_opt.problem.table import Table

#: At most this many joints (a sanity limit on `joints`).
MAX_JOINTS = 64
#: `form` in [robot]: which model a URDF becomes ("auto": planar when the URDF is a planar two-link arm).
FORMS = ("auto", "planar", "n-joint")


def _optional_fraction(table: Table, key: str, default: float) -> float | None:
    """A number in (0, 10], or false for "no bound"."""
    if table.raw.get(key) is False:
        table.raw.pop(key)
        return None
    return table.positive(key, default, high=10.0)


def _gravity(table: Table) -> tuple[float, float, float]:
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


def _couplings(table: Table, joints: list[str]) -> tuple[tuple[str, str, float], ...]:
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


def _joint_names(table: Table) -> list[str]:
    """`joints`: 1 to `MAX_JOINTS` distinct, non-empty joint names."""
    joints = table.take("joints", list)
    if not 0 < len(joints) <= MAX_JOINTS or not all(isinstance(j, str) and j for j in joints):
        raise InputError(f"{table.path}: key 'joints' in [robot] must be a list of 1 to {MAX_JOINTS} joint names")
    if len(set(joints)) != len(joints):
        raise InputError(f"{table.path}: key 'joints' in [robot] names a joint twice")
    return joints


def _planar(table: Table, urdf: Path, joints: list[str], gravity: tuple[float, float, float], base: str | None):
    """The planar two-link robot (`ident_opt.arm.planar_urdf`) when `form` asks for it or allows it and the URDF
    is one; None for the n-joint path. A URDF that is not planar is an error under form = "planar", and when the
    section has the planar form's [robot.joint1] / [robot.joint2] tables (the reason named: not "unknown key")."""
    form = table.take("form", str, "auto")
    if form not in FORMS:
        raise InputError(f"{table.path}: key 'form' in [robot] must be one of {', '.join(FORMS)}, got {form!r}")
    if form == "n-joint" or (form == "auto" and len(joints) != 2):
        return None
    if len(joints) != 2:
        raise InputError(f'{table.path}: form = "planar" in [robot] needs exactly two joints, got {len(joints)}')
    try:
        geometry = planar_urdf.planar_geometry(urdf, tuple(joints), gravity, base)
    except planar_urdf.NotPlanar as exc:
        planar_only = [f"joint{k}" for k in (1, 2) if f"joint{k}" in table.raw and f"joint{k}" not in joints]
        if form == "planar":
            raise
        if planar_only:
            raise InputError(
                f"{exc}. {table.path}: [robot.{planar_only[0]}] is the planar two-link form's table, and this arm "
                f"is not one, so it is read as an n-joint arm: give its joints' values as [robot.<joint name>] "
                f'({", ".join(f"[robot.{j}]" for j in joints)}), motor side unless side = "joint"'
            ) from None
        return None
    for name in joints:
        if name in table.raw:
            raise InputError(
                f"{table.path}: [robot.{name}]: a planar two-link URDF arm takes its joints' extras in "
                f"[robot.joint{joints.index(name) + 1}] (joint side, as the inertials form)"
            )
    values, notes = [], []
    for j, dynamics in enumerate(geometry.dynamics):
        joint, said = joint_values(table.table(f"joint{j + 1}", required=False), dynamics, ("joint",), "joint")
        values.append(joint)
        notes += said
    table.done()
    return planar_urdf.planar_robot(urdf, tuple(joints), geometry, tuple(values), tuple(notes))


def _chain_joints(table: Table, joints: list[str], parsed: dict[str, UrdfJoint]) -> tuple[tuple, list[str]]:
    """Each joint's nominal values: its [robot.<name>] table over the URDF's <dynamics> (`ident_opt.problem.joints`,
    motor side unless `side = "joint"`), and the notes to print."""
    values, notes = [], []
    for name in joints:
        dynamics = (parsed[name].damping, parsed[name].friction)
        sub = table.table(name, required=False)
        joint, said = joint_values(sub, dynamics, ("motor", "joint"), "motor")
        values.append(joint)
        notes += said
    return tuple(values), notes


def parse_urdf_robot(table: Table, base_dir: Path):
    """The `[robot]` section of an arm from a URDF (module doc), the URDF's path relative to `base_dir`; builds
    the arm to check it. Two revolute joints with parallel axes give the planar two-link robot, unless
    form = "n-joint"; anything else the n-joint `ChainRobot`."""
    urdf = Path(table.take("urdf", str))
    urdf = urdf if urdf.is_absolute() else base_dir / urdf
    joints = _joint_names(table)
    gravity, base = _gravity(table), table.take("base", str, None)
    planar = _planar(table, urdf, joints, gravity, base)
    if planar is not None:
        return planar
    _, parsed, _ = parse_urdf(urdf)
    missing = [name for name in joints if name not in parsed]
    if missing:
        close = ", ".join(sorted(parsed)) or "none"
        raise InputError(f"{urdf}: joint {missing[0]!r} is not in the URDF (its joints: {close})")
    values, notes = _chain_joints(table, joints, parsed)
    robot = ChainRobot(
        urdf=urdf,
        joint_names=tuple(joints),
        gravity=gravity,
        joints=values,
        base=base,
        friction=table.take("friction", bool, True),
        armature=table.take("armature", bool, True),
        offsets=table.take("offsets", bool, False),
        prior_weight=table.positive("prior_weight", 1e-7, high=1e6),
        mass_range=_optional_fraction(table, "mass_range", 0.5),
        com_box=_optional_fraction(table, "com_box", 0.1),
        couplings=_couplings(table, joints),
        notes=tuple(notes),
    )
    table.done()
    robot.arm  # noqa: B018  (build it now: a bad URDF is an error of the problem file)
    return robot
