"""One joint's table of a problem file (`[robot.jointN]`, `[robot.<joint name>]`): friction, rotor inertia, gear
ratio and torque constant, read into joint-side values (`ident_opt.arm.joints.JointSide`).

`side` says where the table's friction and rotor inertia are measured: "joint" (as they act at the joint) or
"motor" (a motor datasheet's values, reflected through the gear ratio N: viscous friction and rotor inertia × N²,
Coulomb friction × N). Friction not given defaults to the URDF's <dynamics> (joint side) where there is one.
"""

from __future__ import annotations

from typing import Any

from ident_opt.arm.joints import Friction, JointSide, reflected
from ident_opt.errors import InputError
from ident_opt.problem.table import _REQUIRED, LIMITS, Table


def friction(table: Table, key: str, default: Any = _REQUIRED) -> Friction:
    """A friction coefficient: `{positive, negative}`, or (where a default exists) one number for both."""
    if default is not _REQUIRED and key not in table.raw:
        return Friction(default, default)
    if not isinstance(table.raw.get(key), dict) and default is not _REQUIRED:
        value = table.non_negative(key, high=LIMITS["friction"])
        return Friction(value, value)
    sub = table.table(key)
    limit = LIMITS["friction"]
    value = Friction(sub.non_negative("positive", high=limit), sub.non_negative("negative", high=limit))
    sub.done()
    return value


def _optional_positive(table: Table, key: str) -> float | None:
    """A positive number under `key`, or None when the table does not give it."""
    if key not in table.raw:
        return None
    return table.number(key, None, 0.0, LIMITS[key], open_low=True)


def joint_values(
    table: Table, dynamics: tuple[float, float] = (0.0, 0.0), sides: tuple[str, ...] = ("joint",), side: Any = _REQUIRED
) -> tuple[JointSide, list[str]]:
    """(The joint's joint-side values, notes to print) from its table (module doc): `dynamics` the URDF's
    (damping [N m s/rad], friction [N m]) defaults, `sides` the values `side` may take, `side` its default
    (required when not given). Motor-side values need the gear ratio to be reflected."""
    chosen = table.take("side", str, side)
    if chosen not in sides:
        allowed = " or ".join(f'"{s}"' for s in sides)
        raise InputError(f"{table.path}: key 'side' in [{table.where}] must be {allowed}, got {chosen!r}")
    notes = [
        f"[{table.where}] {key} replaces the URDF's <dynamics> value {value:g}"
        for key, value in (("viscous_friction", dynamics[0]), ("coulomb_friction", dynamics[1]))
        if key in table.raw and value
    ]
    given = any(k in table.raw for k in ("viscous_friction", "coulomb_friction", "rotor_inertia"))
    torque_constant, gear_ratio = _optional_positive(table, "torque_constant"), _optional_positive(table, "gear_ratio")
    motor = chosen == "motor"
    if motor and given and gear_ratio is None:
        raise InputError(
            f"{table.path}: [{table.where}] gives motor-side friction or rotor inertia but no 'gear_ratio' to reflect "
            'them to the joint; add it, or say side = "joint"'
        )
    ratio = gear_ratio if motor and gear_ratio is not None else 1.0
    viscous, coulomb = (
        reflected(friction(table, key, default), ratio, power) if key in table.raw else Friction(default, default)
        for key, default, power in (("viscous_friction", dynamics[0], 2), ("coulomb_friction", dynamics[1], 1))
    )
    values = JointSide(
        viscous_friction=viscous,
        coulomb_friction=coulomb,
        rotor_inertia=table.non_negative("rotor_inertia", 0.0, high=LIMITS["inertia"]) * ratio**2,
        torque_constant=torque_constant,
        gear_ratio=gear_ratio,
    )
    table.done()
    return values, notes
