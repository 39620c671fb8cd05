"""The one switch between the kinds of arm: each feature that has an implementation per kind (the simulator's plant,
the diagnosis's engine) declares them in a `ByKind`, and `ByKind.of(robot)` picks the robot's. Nothing else asks
which kind of arm it has (`Robot.kind` is read here only)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Generic, TypeVar

from ident_opt.arm.base import Robot

T = TypeVar("T")

#: The kinds of arm (`Robot.kind`): the planar two-link closed form, and a chain of n joints from a URDF.
KINDS = ("planar", "chain")


@dataclass(frozen=True)
class ByKind(Generic[T]):
    """One implementation of a feature per kind of arm (module doc)."""

    planar: T
    chain: T

    def of(self, robot: Robot) -> T:
        """The implementation for `robot`'s kind."""
        if robot.kind not in KINDS:
            raise ValueError(f"unknown kind of arm {robot.kind!r}; known: {', '.join(KINDS)}")
        return getattr(self, robot.kind)
