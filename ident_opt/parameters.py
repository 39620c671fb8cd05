"""What a model parameter is: its name, unit, meaning and physical kind.

Every parameter an arm or an effect adds to π is declared once, as a `Parameter`, next to the code that
gives it its column of the regressor Y. What physics says about its sign is read from its `kind` by
`ident_opt.consistency` (the one statement of physical consistency), never from its name.

| kind         | examples         | physics                                                              |
|--------------|------------------|----------------------------------------------------------------------|
| `inertia`    | a1, a3           | a sum of link inertias [kg m²]: ≥ 0, and implied by M(q) ≻ 0          |
| `coupling`   | a2               | m2 l1 lc2 [kg m²]: its sign follows the centre of mass's side        |
| `gravity`    | b1, b2, b1s, b2s | g·Σ m lc [N m]: its sign follows the centre of mass's side           |
| `friction`   | fv1, fc1p, fs2   | dissipative [N m s/rad or N m]: ≥ 0                                  |
| `armature`   | ia2              | reflected rotor inertia N² J [kg m²]: ≥ 0                            |
| `other`      | —                | no physical sign                                                     |
"""

from __future__ import annotations

from dataclasses import dataclass

#: The kinds of `Parameter.kind`, with whether physics fixes their sign to ≥ 0.
KINDS = {
    "inertia": True,
    "coupling": False,
    "gravity": False,
    "friction": True,
    "armature": True,
    "other": False,
}


@dataclass(frozen=True)
class Parameter:
    """One entry of π: `name` (the JSON name), `unit` (SI), `meaning` (one line), `kind` (see module doc), and
    `joint`: the joint (1-based) whose drive the term belongs to (its friction, armature, offset), None for a
    link's inertial or gravity parameter (`ident-opt fleet` reads a joint's friction so)."""

    name: str
    unit: str
    meaning: str
    kind: str = "other"
    joint: int | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"parameter {self.name}: unknown kind {self.kind!r}; known: {sorted(KINDS)}")

    @property
    def nonnegative(self) -> bool:
        """Whether physics says this parameter is ≥ 0 (its kind's sign)."""
        return KINDS[self.kind]
