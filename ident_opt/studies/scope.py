"""Which commands take an n-joint arm from a URDF (`ChainRobot`): `identify`, `compare`, `codegen` and `check`.
The others model the two-link arm only (datasheet, simulator, online updates, diagnosis), so they refuse such a
problem with one sentence (exit 2) before any work, instead of failing inside with a traceback. A planar
two-joint URDF becomes the two-link robot (`ident_opt.arm.planar_urdf`) and passes.

Light on purpose: every command calls `two_joint_only` first, and a two-link run must not pay for loading
Pinocchio or the URDF studies.
"""

from __future__ import annotations

from ident_opt.errors import InputError

#: The commands that support an arm from a URDF (`ident_opt.commands.urdf`, and `check`).
URDF_COMMANDS = ("identify", "compare", "codegen", "check")


def two_joint_only(command: str, *problem_paths: str | None) -> None:
    """InputError (exit 2) when one of `problem_paths` (None: not given) describes an arm from a URDF, which
    `command` does not support; a bad problem file raises the loader's own InputError."""
    from ident_opt.arm.chain import ChainRobot
    from ident_opt.problem import load_problem  # deferred: it loads the effect catalogue; --help must stay fast

    for path in problem_paths:
        if path is None:
            continue
        robot = load_problem(path).robot
        if isinstance(robot, ChainRobot):  # a planar two-joint URDF is a two-link PlanarRobot, not this
            how = ' on the n-joint path (its axes are not parallel, or form = "n-joint")' if robot.n_joints == 2 else ""
            raise InputError(
                f"{command} supports two-joint problems only; {path} describes a {robot.n_joints}-joint URDF arm{how} "
                f"(the commands for URDF arms: {', '.join(URDF_COMMANDS)})"
            )
