"""The arm: one interface, two implementations, everything ident-opt knows about a robot's rigid-body dynamics.

| module        | what it holds                                                                                  |
|---------------|------------------------------------------------------------------------------------------------|
| `base`        | `Robot` (what a problem's `[robot]` describes: joints, nominal values, fits, what it serves) and |
|               | `Arm` (the identification model: τ = Y(q, dq, ddq) π, M, C, G, F in CasADi, the mass LMIs)     |
| `planar`      | `PlanarArm`: the planar two-link closed form in the paper's grouped parameters, with extensions |
| `datasheet`   | `PlanarRobot`: a planar arm as a datasheet (bars and motors) or measured inertials; its π       |
| `planar_urdf` | `UrdfPlanarRobot`: a planar arm read from a URDF (its angle offsets and signs)                 |
| `chain`       | `ChainArm`: the identification model of an arm of n revolute joints (Pinocchio, CasADi RNEA)   |
| `chain_robot` | `ChainRobot`: an arm of n revolute joints from a URDF, its nominal values and datasheets       |
| `kinds`       | `ByKind`: the one factory that picks an implementation by the robot's kind ("planar", "chain") |
| `urdf`        | reading and checking a URDF (joints, links, inertials, `<dynamics>`, `<limit>`), Pinocchio's model |
| `rnea`        | the recursive Newton–Euler algorithm in CasADi                                                 |
| `joints`      | a joint's drive values: friction, reflected rotor inertia, torque constant, gear ratio         |
| `bodies`      | a fixed-base robot of rigid bodies, as `export` writes it                                      |
| `realise`     | an identified π realised exactly as rigid bodies (`Robot.bodies`); `realise_planar` the planar |
|               | arm's                                                                                          |

Nothing outside this package asks which kind of arm it has: it asks the robot (`Robot.serves`,
`Robot.estimators`, `Robot.model()`, …), and where a package has one implementation per kind (the diagnosis's
engines, the simulator's plants) `kinds.ByKind` picks it. Adding an arm means one more pair of `Robot` and `Arm`
here, and one more entry in each `ByKind`.

The public names load on first use, as the package's own (`ident_opt.Arm`, …).
"""

from __future__ import annotations

import importlib

#: Each public name → the module of this package that defines it.
_EXPORTS = {
    "Arm": "base",
    "Robot": "base",
    "PlanarArm": "planar",
    "PlanarRobot": "datasheet",
    "UrdfPlanarRobot": "planar_urdf",
    "ChainArm": "chain",
    "ChainRobot": "chain_robot",
    "RobotDescription": "bodies",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """A public name, imported from its module on first use."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ident_opt.arm' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"ident_opt.arm.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value
