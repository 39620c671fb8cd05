"""The effect catalogue: one module per cause the diagnosis can name, everything about it in that module.

Each module of this package (besides `base`) defines ``EFFECT``, an `base.Effect`: its name, summary and keys
(the ``NAME:key=value`` syntax of `--effect` and problem files), its model extension where it is linear in
its parameters (`PlanarArm(extensions=...)`), its plant term in the simulator, its candidate family in the
diagnosis, its resolution rule and report sentence, and how a hidden instance is drawn and judged. The
modules are found by listing the package, so a new cause is one new module. `background` holds the
simulator's realism terms that no diagnosis names (stiction, drift, ripple, and a contact: an external push) the same
way; `docs/effects.md` describes the catalogue.

Everything that handles effects (the simulator, the diagnosis, the model, the problem-file parser, the CLI,
the reports, the benchmarks) iterates `CATALOGUE` / `BACKGROUND`; nothing else names a cause.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from ident_opt.effects.background import BACKGROUND
from ident_opt.effects.base import Effect, discover
from ident_opt.effects.keys import Joints, Key, as_joints
from ident_opt.errors import InputError

#: The causes the diagnosis can name, name -> `Effect`, in catalogue order.
CATALOGUE: dict[str, Effect] = discover(__name__, __path__)
#: Every name the syntax accepts: the diagnosis catalogue, then the background terms.
ALL_EFFECTS: dict[str, Effect] = {**CATALOGUE, **BACKGROUND}
#: The model extensions: the causes linear in their parameters, name -> `Effect`, in catalogue order.
EXTENSIONS: dict[str, Effect] = {name: e for name, e in CATALOGUE.items() if e.parameters}
_ALIASES = {alias: e for e in EXTENSIONS.values() for alias in e.aliases}

__all__ = ["ALL_EFFECTS", "BACKGROUND", "CATALOGUE", "EXTENSIONS", "Effect", "Key", "describe", "parse_effect"]


def extension(name: str) -> Effect:
    """The model extension called `name` (or one of its aliases); `KeyError` when there is none."""
    return EXTENSIONS[name] if name in EXTENSIONS else _ALIASES[name]


def is_extension(name: str) -> bool:
    """Whether `name` is a model extension (or one of its aliases)."""
    return name in EXTENSIONS or name in _ALIASES


def cause(name: str) -> Effect | None:
    """The catalogue's cause called `name`; None for "none" (the diagnosis's no-cause answer)."""
    return CATALOGUE.get(name)


def describe() -> str:
    """The catalogue as text for `--help`: each effect, its keys and default magnitudes."""
    lines = [line for e in CATALOGUE.values() for line in e.describe()]
    lines.append("  every effect also takes scale=1 (0 = effect off, the clean trial)")
    lines.append("background realism terms (not named by the diagnosis; off unless asked for):")
    lines += [line for e in BACKGROUND.values() for line in e.describe()]
    lines.append("  they also take scale=1 (0 = off)")
    return "\n".join(lines)


def _effect(name: str, where: str) -> Effect:
    if name not in ALL_EFFECTS:
        raise InputError(f"effect {where!r}: unknown effect {name!r}; known: {', '.join(ALL_EFFECTS)}")
    return ALL_EFFECTS[name]


def parse_effect(text: str, joints: Joints | None = None) -> tuple[str, dict]:
    """``"elasticity:joint=2,frequency_hz=8"`` -> ``("elasticity", {"joint": 2, "frequency_hz": 8.0})``.

    Only the keys written are returned (defaults are filled by `normalise`); raises `InputError` on an
    unknown effect, an unknown key or a bad value (said for the arm of `joints` when given).
    """
    name, _, body = text.strip().partition(":")
    name = name.strip()
    return name, _effect(name, text).parse(body, text, joints)


def normalise(effects: Mapping[str, Mapping] | Sequence[str], coulomb: tuple[tuple, tuple]) -> dict[str, dict]:
    """Effects (a name -> keys mapping, or a sequence of effect strings) as name -> complete, checked keys.

    `coulomb` = (positive, negative) datasheet Coulomb levels [N m, joint side], the nominal friction some
    effects depart from. `scale` is applied: each effect's magnitude is multiplied by it.
    """
    if isinstance(effects, str):
        effects = [effects]
    if isinstance(effects, Mapping):
        items = [(str(n), dict(p or {}), str(n)) for n, p in effects.items()]
    else:
        joints = as_joints(coulomb)
        items = [(*parse_effect(e, joints), e) if isinstance(e, str) else _bad(e) for e in effects]
    out: dict[str, dict] = {}
    for name, params, where in items:
        effect = _effect(name, where)
        if name in out:
            raise InputError(f"effect {where!r}: {name} given twice")
        out[name] = effect.complete(params, where, coulomb)
    return out


def _bad(entry: object):
    raise InputError(f"effect {entry!r}: effects are strings like 'payload:mass=0.3'")


def is_active(name: str, p: Mapping, coulomb: tuple[tuple, tuple]) -> bool:
    """Whether an effect changes the trial at all (inactive ones are skipped: the trial is the clean one)."""
    return ALL_EFFECTS[name].is_active(p, coulomb)
