"""What a problem file says about one joint's drive: friction, rotor inertia, gear ratio, torque constant.

`JointSide` holds joint-side values (friction at the joint [N m s/rad, N m], the rotor inertia reflected to it
N² J [kg m²]) and, for currents, the motor's torque constant [N m/A] and the gear ratio N: τ = N k i. Both arm
implementations take their joints' nominal values from it (the planar arm's measured-inertials form and a
URDF arm's `[robot.<joint>]` tables; the planar bars datasheet keeps its motor-side `Joint`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Friction:
    """A friction coefficient per direction of motion (motor side, as the datasheet prints it)."""

    positive: float
    negative: float

    @property
    def mean(self) -> float:
        return 0.5 * (self.positive + self.negative)


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


def reflected(friction: Friction, ratio: float, power: int) -> Friction:
    """A motor-side friction coefficient seen at the joint through a gear of `ratio` N: × N^power (viscous
    friction and inertia go with N², Coulomb friction with N)."""
    return Friction(friction.positive * ratio**power, friction.negative * ratio**power)
