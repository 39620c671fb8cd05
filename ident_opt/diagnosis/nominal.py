"""An identified arm as the diagnosis's nominal model (`ident-opt diagnose --nominal FIT`, `docs/effects.md`,
"What changed since a model"): "this is my arm as identified before; what is different in these trials?"

`FIT` is what ident-opt wrote of an identified arm: a `compare --json` (its fit `estimator`, default its
`recommended`) or an `export` sidecar (`ARM.urdf.json`, `ARM.xml.json`: every identified value with its standard
error). Its parameters take the place of the problem's datasheet (URDF inertials and joint values) wherever the
nominal model has them — inertials, friction, armature and constant torque offsets alike — so the diagnosis's
`datasheet` model becomes the identified arm, and the JSON calls that baseline `nominal`. A parameter the fit does
not give keeps the datasheet's value and is said; one the nominal model does not have (a model extension the fit
carried) is an InputError naming it: the diagnosis would silently compare against another model.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ident_opt.errors import InputError
from ident_opt.outputs import shown
from ident_opt.warnings import ResultWarning


@dataclass(frozen=True)
class NominalFit:
    """An identified arm read from `path`: the fit's `estimator` and its parameters by name (the model's units)."""

    path: str
    estimator: str
    parameters: dict[str, float]

    def vector(self, names: tuple[str, ...] | list[str], datasheet: np.ndarray) -> tuple[np.ndarray, list[str]]:
        """(π over `names`: the fit's value where it gives one, else the datasheet's (`datasheet`, same order); the
        names whose datasheet value was kept). A fit parameter `names` lacks is an InputError."""
        unknown = [k for k in self.parameters if k not in names]
        if unknown:
            listed = ", ".join(unknown[:8]) + (", …" if len(unknown) > 8 else "")
            raise InputError(
                f"--nominal {self.path}: the {self.estimator} fit has {len(unknown)} parameter(s) the diagnosis's "
                f"nominal model does not ({listed}): a fit with model extensions cannot be the nominal; give a fit "
                "of the problem's own model"
            )
        pi = np.array(datasheet, dtype=float)
        kept = []
        for k, name in enumerate(names):
            if name in self.parameters:
                pi[k] = self.parameters[name]
            else:
                kept.append(name)
        return pi, kept

    def as_json(self) -> dict:
        """What the JSON's `nominal` says of it: the file and the estimator."""
        return {"file": self.path, "estimator": self.estimator}

    def warning(self, kept: list[str]) -> list[ResultWarning]:
        """A warning naming the parameters the fit did not give (their datasheet values were kept)."""
        if not kept:
            return []
        return [
            ResultWarning(
                "nominal_incomplete",
                f"--nominal {self.path}: the {self.estimator} fit gives no value for {', '.join(kept)}; the "
                "problem's datasheet values were kept for them",
            )
        ]


def read_nominal(path: str | Path, estimator: str | None = None) -> NominalFit:
    """The identified arm in `path` (a `compare --json` or an `export` sidecar; module doc). `estimator`: which fit
    of a compare JSON (default its `recommended`); a sidecar holds one fit, and another name is an InputError."""
    where = shown(path)
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"--nominal {where}: cannot read the identified arm ({exc})") from None
    if not isinstance(raw, dict) or not isinstance(raw.get("parameters"), dict):
        raise InputError(
            f"--nominal {where}: not an identified arm (expected a `compare --json` or an `export` sidecar, an "
            "object with a 'parameters' object)"
        )
    if "recommended" in raw:  # compare --json: parameters per fit
        name = estimator or raw.get("recommended")
        ran = raw.get("fits") or raw["parameters"]  # the fits compare ran, not the datasheets it scored beside them
        fits = {k: v for k, v in raw["parameters"].items() if k in ran}
        if not isinstance(name, str) or not isinstance(fits.get(name), dict):
            raise InputError(f"--nominal {where}: no fit {name!r} in it; it has {', '.join(sorted(fits)) or 'none'}")
        values = fits[name]
    else:  # export sidecar: one fit, each value with its standard error
        name = str(raw.get("estimator") or "unknown")
        if estimator is not None and estimator != name:
            raise InputError(f"--nominal {where}: the sidecar holds the {name} fit, not {estimator}")
        values = {k: (v.get("value") if isinstance(v, dict) else v) for k, v in raw["parameters"].items()}
    return NominalFit(shown(path), name, _numbers(values, where))


def _numbers(values: dict, where: str) -> dict[str, float]:
    """The parameters as finite floats; anything else is an InputError naming the parameter."""
    out = {}
    for k, v in values.items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"--nominal {where}: parameter {k} = {v!r} is not a finite number")
        out[str(k)] = float(v)
    return out
