"""The catalogue of hidden effects (names and estimate keys from `spec/diagnose.md`) and their text syntax.

An effect is written ``NAME`` or ``NAME:key=value,key=value``; a per-joint value is a bracketed pair
``key=[v1,v2]``. Two lists share that syntax: `CATALOGUE`, the effects the diagnosis names (exactly those of
`spec/diagnose.md`), and `BACKGROUND`, what else a real flexible arm does that no diagnosis is asked to name
(stiction with presliding hysteresis, a slow torque disturbance, a motor-angle-locked current ripple): they
make the default trial resemble the real one, and their values go to the truth's ``background``, not its
``effects``. Every effect also takes ``scale`` (default 1): it multiplies the effect's magnitude (its
departure from the clean trial), so ``scale=0`` reproduces the clean trial exactly. Omitted keys take the
defaults below (chosen to be clearly visible on a TUDOR-like arm, and resembling the real MERIt trial; the
background terms' defaults are the calibrated ones of problems/tudor_sim.toml).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ident_opt.errors import InputError


@dataclass(frozen=True)
class Key:
    """One key of an effect: its kind ("pair", "float", "joint"), default, lower bound and meaning."""

    kind: str
    default: object
    doc: str
    minimum: float | None = 0.0
    strict: bool = False  # minimum excluded
    choices: tuple[str, ...] = ()  # for kind "choice"


#: name -> (one-line meaning, keys). Defaults of `asymmetric_coulomb` are the datasheet's own per-direction
#: Coulomb levels (reflected through the gear ratio), filled in by `normalise` when omitted.
CATALOGUE: dict[str, tuple[str, dict[str, Key]]] = {
    "armature": (
        "extra reflected rotor inertia on the diagonal of M, beyond the datasheet's",
        {
            "inertia": Key("pair", (0.25, 0.025), "kg m^2, joint side, per joint"),
        },
    ),
    "asymmetric_coulomb": (
        "Coulomb friction that differs by direction (replaces the datasheet mean)",
        {
            "positive": Key("pair", None, "N m, level for dq > 0 (default: the datasheet's, x gear ratio)"),
            "negative": Key("pair", None, "N m, level for dq < 0 (default: the datasheet's, x gear ratio)"),
        },
    ),
    "stribeck": (
        "friction excess fs sgn(dq) exp(-(dq/vs)^2) above the Coulomb level at low speed",
        {
            "static": Key("pair", (0.3, 0.2), "N m, static excess fs over the Coulomb level, per joint"),
            "velocity": Key("pair", (0.05, 0.05), "rad/s, Stribeck velocity vs, per joint", 0.0, True),
        },
    ),
    "elasticity": (
        "a lightly damped mode: an elastic joint (two-mass, motor angle logged) or a flexible link",
        {
            "joint": Key("joint", 2, "1 or 2"),
            "frequency_hz": Key("float", 3.0, "Hz, the mode's natural frequency with the joints held", 0.0, True),
            "damping": Key("float", 0.02, "damping ratio of that mode"),
            "kind": Key(
                "choice",
                "joint",
                "joint: two-mass elastic joint; link: link `joint` cut in two halves joined by a spring",
                None,
                choices=("joint", "link"),
            ),
        },
    ),
    "payload": (
        "an unmodelled point mass at the tip of link 2",
        {
            "mass": Key("float", 0.2, "kg"),
        },
    ),
    "delay": (
        "the torque (or current) channel lags the encoder channel",
        {
            "seconds": Key("float", 0.02, "s"),
        },
    ),
    "joint_offset": (
        "encoder zero offsets: the true angle is the logged q + offset",
        {
            "offset": Key("pair", (0.02, -0.03), "rad, per joint", None),
        },
    ),
}

#: Background realism terms (see background.py for their equations): not part of the diagnosis catalogue.
BACKGROUND: dict[str, tuple[str, dict[str, Key]]] = {
    "stiction": (
        "presliding (Dahl) friction: F = σ0 z, dz/dt = v − σ0 |v| z / Fb; a resting joint holds a torque that "
        "depends on how it came to rest; adds Fb to the sliding friction",
        {
            "breakaway": Key("pair", (0.6, 0.6), "N m, Fb: the friction the bristles carry, per joint"),
            "stiffness": Key("pair", (300.0, 150.0), "N m/rad, σ0: presliding stiffness, per joint", 0.0, True),
        },
    ),
    "drift": (
        "a slow torque disturbance on the joints (cable drag, thermal): an Ornstein-Uhlenbeck process",
        {
            "std": Key("pair", (0.7, 0.2), "N m, its standard deviation, per joint"),
            "time": Key("float", 4.0, "s, its correlation time", 0.0, True),
        },
    ),
    "ripple": (
        "current (torque) ripple locked to the motor angle, amplitude ∝ joint speed: a v sin(c N q)",
        {
            "amplitude": Key("pair", (1.3, 0.75), "N m per rad/s of joint speed, a, per joint"),
            "cycles": Key("pair", (1.0, 1.0), "c: cycles per motor revolution, per joint", 0.0, True),
        },
    ),
}

#: Every name the syntax accepts: the diagnosis catalogue, then the background terms.
ALL_EFFECTS = {**CATALOGUE, **BACKGROUND}

_SCALE = Key("float", 1.0, "multiplies the effect's magnitude; 0 gives the clean trial")


def describe() -> str:
    """The catalogue as text for `--help`: each effect, its keys and default magnitudes."""
    lines = []
    for name, (meaning, keys) in CATALOGUE.items():
        lines.append(f"  {name}: {meaning}")
        for key, spec in keys.items():
            default = "datasheet" if spec.default is None else _show(spec.default)
            lines.append(f"      {key}={default}  ({spec.doc})")
    lines.append("  every effect also takes scale=1 (0 = effect off, the clean trial)")
    lines.append("background realism terms (not named by the diagnosis; off unless asked for):")
    for name, (meaning, keys) in BACKGROUND.items():
        lines.append(f"  {name}: {meaning}")
        for key, spec in keys.items():
            lines.append(f"      {key}={_show(spec.default)}  ({spec.doc})")
    lines.append("  they also take scale=1 (0 = off)")
    return "\n".join(lines)


def _show(value: object) -> str:
    if isinstance(value, tuple):
        return "[" + ",".join(f"{v:g}" for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


def parse_effect(text: str) -> tuple[str, dict]:
    """``"elasticity:joint=2,frequency_hz=8"`` -> ``("elasticity", {"joint": 2, "frequency_hz": 8.0})``.

    Only the keys written are returned (defaults are filled by `normalise`); raises `InputError` on an
    unknown effect, an unknown key or a bad value.
    """
    name, _, body = text.strip().partition(":")
    name = name.strip()
    if name not in ALL_EFFECTS:
        raise InputError(f"effect {text!r}: unknown effect {name!r}; known: {', '.join(ALL_EFFECTS)}")
    params: dict[str, object] = {}
    if body.strip():
        # Split on commas that are not inside brackets, so that key=[v1,v2] stays whole.
        for item in re.split(r",(?![^\[]*\])", body):
            key, eq, value = item.partition("=")
            key = key.strip()
            if not eq or not key:
                raise InputError(f"effect {text!r}: expected key=value, got {item.strip()!r}")
            if key in params:
                raise InputError(f"effect {text!r}: key {key!r} given twice")
            params[key] = _parse_value(text, name, key, value.strip())
    return name, params


def _parse_value(text: str, name: str, key: str, value: str) -> object:
    spec = _key(name, key, text)
    try:
        if spec.kind == "pair":
            inner = value[1:-1] if value.startswith("[") and value.endswith("]") else None
            if inner is None:
                raise ValueError
            return tuple(float(v) for v in inner.split(","))
        if spec.kind == "joint":
            return int(value)
        if spec.kind == "choice":
            return value
        return float(value)
    except ValueError:
        shape = "[v1,v2]" if spec.kind == "pair" else ("1 or 2" if spec.kind == "joint" else "a number")
        raise InputError(f"effect {text!r}: key {key!r} of {name} must be {shape}, got {value!r}") from None


def _key(name: str, key: str, where: str) -> Key:
    keys = ALL_EFFECTS[name][1]
    if key == "scale":
        return _SCALE
    if key not in keys:
        raise InputError(f"effect {where!r}: unknown key {key!r} for {name}; known: {', '.join(keys)}, scale")
    return keys[key]


def _check(name: str, key: str, value: object, where: str) -> object:
    """Validate one value against its key; returns it in canonical form (tuple of 2 floats, float, int)."""
    spec = _key(name, key, where)
    if spec.kind == "joint":
        if isinstance(value, bool) or value not in (1, 2):
            raise InputError(f"effect {where!r}: key 'joint' of {name} must be 1 or 2, got {value!r}")
        return int(value)
    if spec.kind == "choice":
        if value not in spec.choices:
            raise InputError(
                f"effect {where!r}: key {key!r} of {name} must be one of {', '.join(spec.choices)}, got {value!r}"
            )
        return value
    values = value if spec.kind == "pair" else (value,)
    if isinstance(values, str) or not isinstance(values, Sequence) or (spec.kind == "pair" and len(values) != 2):
        raise InputError(f"effect {where!r}: key {key!r} of {name} must be a pair [v1,v2], got {value!r}")
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"effect {where!r}: key {key!r} of {name} must be a finite number, got {v!r}")
        low = spec.minimum
        if low is not None and (v < low or (spec.strict and v == low)):
            bound = f"> {low:g}" if spec.strict else f">= {low:g}"
            raise InputError(f"effect {where!r}: key {key!r} of {name} must be {bound}, got {v!r}")
        out.append(float(v))
    return tuple(out) if spec.kind == "pair" else out[0]


def normalise(effects: Mapping[str, Mapping] | Sequence[str], coulomb: tuple[tuple, tuple]) -> dict[str, dict]:
    """Effects (a name -> keys mapping, or a sequence of effect strings) as name -> complete, checked keys.

    `coulomb` = (positive, negative) datasheet Coulomb levels [N m, joint side], the defaults of
    `asymmetric_coulomb`. `scale` is applied: each effect's magnitude is multiplied by it.
    """
    if isinstance(effects, str):
        effects = [effects]
    if isinstance(effects, Mapping):
        items = [(str(n), dict(p or {}), str(n)) for n, p in effects.items()]
    else:
        items = [(*parse_effect(e), e) if isinstance(e, str) else _bad(e) for e in effects]
    out: dict[str, dict] = {}
    for name, params, where in items:
        if name not in ALL_EFFECTS:
            raise InputError(f"effect {where!r}: unknown effect {name!r}; known: {', '.join(ALL_EFFECTS)}")
        if name in out:
            raise InputError(f"effect {where!r}: {name} given twice")
        full = {k: _check(name, k, v, where) for k, v in params.items()}
        for key, spec in ALL_EFFECTS[name][1].items():
            if key not in full:
                default = spec.default
                if default is None:  # asymmetric Coulomb levels: the datasheet's
                    default = coulomb[0] if key == "positive" else coulomb[1]
                full[key] = default
        scale = full.pop("scale", 1.0)
        out[name] = _scaled(name, full, scale, coulomb)
    return out


def _bad(entry: object):
    raise InputError(f"effect {entry!r}: effects are strings like 'payload:mass=0.3'")


def _scaled(name: str, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
    """Multiply an effect's magnitude by `s` (its departure from the clean trial)."""
    pair = lambda v: tuple(s * x for x in v)  # noqa: E731
    if name == "armature":
        p["inertia"] = pair(p["inertia"])
    elif name == "asymmetric_coulomb":
        # Departure from the datasheet's symmetric level (the clean trial's friction).
        mean = [0.5 * (a + b) for a, b in zip(*coulomb)]
        p["positive"] = tuple(m + s * (v - m) for m, v in zip(mean, p["positive"]))
        p["negative"] = tuple(m + s * (v - m) for m, v in zip(mean, p["negative"]))
    elif name == "stribeck":
        p["static"] = pair(p["static"])
    elif name == "elasticity":
        # Magnitude = compliance 1/k ∝ 1/f²: scale 0 is a rigid joint.
        p["frequency_hz"] = p["frequency_hz"] / math.sqrt(s) if s > 0 else math.inf
    elif name == "payload":
        p["mass"] *= s
    elif name == "delay":
        p["seconds"] *= s
    elif name == "joint_offset":
        p["offset"] = pair(p["offset"])
    elif name == "stiction":
        p["breakaway"] = pair(p["breakaway"])
    elif name == "drift":
        p["std"] = pair(p["std"])
    elif name == "ripple":
        p["amplitude"] = pair(p["amplitude"])
    return p


def is_active(name: str, p: Mapping, coulomb: tuple[tuple, tuple]) -> bool:
    """Whether an effect changes the trial at all (inactive ones are skipped: the trial is the clean one)."""
    if name == "armature":
        return any(p["inertia"])
    if name == "asymmetric_coulomb":
        mean = [0.5 * (a + b) for a, b in zip(*coulomb)]
        return any(v != m for m, v in zip(mean, p["positive"])) or any(v != m for m, v in zip(mean, p["negative"]))
    if name == "stribeck":
        return any(p["static"])
    if name == "elasticity":
        return math.isfinite(p["frequency_hz"])
    if name == "payload":
        return p["mass"] > 0
    if name == "delay":
        return p["seconds"] > 0
    if name == "joint_offset":
        return any(p["offset"])
    if name == "stiction":
        return any(p["breakaway"])
    if name == "drift":
        return any(p["std"])
    if name == "ripple":
        return any(p["amplitude"])
    return False
