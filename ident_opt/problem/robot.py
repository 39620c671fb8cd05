"""The `[robot]` section of a problem file for a planar two-link arm given by bars and motors (a datasheet) or
by measured inertials (`docs/problem-files.md`). An arm from a URDF is `ident_opt.problem.urdf`'s.
"""

from __future__ import annotations

from ident_opt.arm.datasheet import InertialLink, Joint, Link, PlanarRobot
from ident_opt.arm.joints import JointSide
from ident_opt.errors import InputError
from ident_opt.problem.joints import friction, joint_values
from ident_opt.problem.table import _REQUIRED, LIMITS, Table, excerpt

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


def _numbers(table: Table, fields: dict[str, tuple[str, str]]) -> dict[str, float]:
    """Each key of `fields` read as a finite number with its sign rule and its unit's range."""
    return {key: getattr(table, sign)(key, high=LIMITS[unit]) for key, (sign, unit) in fields.items()}


def _link(table: Table) -> Link:
    link = Link(**_numbers(table, _BAR_FIELDS))
    table.done()
    return link


def _joint(table: Table) -> Joint:
    joint = Joint(
        viscous_friction=friction(table, "viscous_friction"),
        coulomb_friction=friction(table, "coulomb_friction"),
        **_numbers(table, _DATASHEET_FIELDS),
    )
    table.done()
    return joint


def _com(table: Table) -> float:
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


def _inertial_link(table: Table) -> InertialLink:
    link = InertialLink(
        length=table.positive("length", high=LIMITS["length"]),
        mass=table.positive("mass", high=LIMITS["mass"]),
        com=_com(table),
        inertia=table.non_negative("inertia", high=LIMITS["inertia"]),
    )
    table.done()
    return link


def _joint_side(table: Table) -> JointSide:
    """[robot.jointN] of the measured-inertials form: joint-side values (`side = "joint"` required)."""
    return joint_values(table)[0]


#: Keys that tell the two per-link descriptions apart (a file uses exactly one).
_BAR_KEYS, _INERTIAL_KEYS = {"width", "height", "density"}, {"mass", "com", "inertia"}


def _description(table: Table) -> str:
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


def parse_planar(table: Table) -> PlanarRobot:
    """The planar two-link arm of a `[robot]` section without `urdf`: bars and motors (a datasheet) or
    measured inertials (the contract, `docs/problem-files.md`)."""
    description = _description(table)
    default = "physical" if description == "inertials" else _REQUIRED
    convention = table.take("convention", str, default)
    if convention not in ("physical", "paper"):
        raise InputError(
            f'{table.path}: key \'convention\' in [robot] must be "physical" or "paper", got {excerpt(convention)}'
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
    return PlanarRobot(gravity, convention, link1, link2, joint1, joint2, payload_mass, description)
