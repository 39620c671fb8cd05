"""Modules imported on first use, so that the effect catalogue loads for `--help` and problem files without NumPy,
CasADi or SciPy."""

from __future__ import annotations

import importlib


class deferred:  # lower case: used like the module it stands for
    """A module imported on its first attribute access: `np = deferred("numpy")` reads like an import.

    The catalogue loads for `--help` and problem files without NumPy, CasADi or SciPy (0.1 s instead of about 1 s):
    a hook that needs them reaches them when it runs."""

    def __init__(self, module: str) -> None:
        self._module = module

    def __getattr__(self, attr: str):
        return getattr(importlib.import_module(self._module), attr)


#: What the hooks reach, name -> module, each imported on first use: NumPy, CasADi and the numerics below every
#: floor (`ident_opt.numerics`). Nothing here points up: the engines pass their context to the hooks instead.
DEFERRED = {
    "np": "numpy",
    "ca": "casadi",
    "damped_mode": "ident_opt.numerics.damped_mode",
    "least_squares": "ident_opt.numerics.least_squares",
    "nlp": "ident_opt.numerics.nlp",
    "signals": "ident_opt.numerics.signals",
}
