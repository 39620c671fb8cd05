"""ident-opt: identify, diagnose and ship the dynamics of robot arms with any number of joints.

The stable names of the Python API (`docs/api.md`) are importable from here; each is loaded on first use, so
`import ident_opt` stays light (NumPy, CasADi, Pinocchio load when a name that needs them is used)::

    import ident_opt as io

    problem = io.load_problem("problems/kuka_lwr4.toml")
    training, testing = io.load_trials(problem)
    fit = io.fit(problem, training)
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Each public name → the module that defines it.
_EXPORTS = {
    # problem files and trials
    "load_problem": "ident_opt.problem",
    "Problem": "ident_opt.problem",
    "load_trials": "ident_opt.api",
    "load_dataset": "ident_opt.data.dataset",
    "Dataset": "ident_opt.data.dataset",
    # the arm: its interface and its two implementations
    "Arm": "ident_opt.arm.base",
    "Robot": "ident_opt.arm.base",
    "PlanarArm": "ident_opt.arm.planar",
    "PlanarRobot": "ident_opt.arm.datasheet",
    "ChainArm": "ident_opt.arm.chain",
    "ChainRobot": "ident_opt.arm.chain",
    # identification
    "Stats": "ident_opt.fitting.stats",
    "LinearFit": "ident_opt.fitting.fit",
    "fit": "ident_opt.api",
    "compare": "ident_opt.api",
    "Comparison": "ident_opt.evaluation.compare",
    # diagnosis, simulation, export
    "diagnose": "ident_opt.diagnosis",
    "Diagnosis": "ident_opt.diagnosis",
    "simulate_trial": "ident_opt.simulator",
    "export": "ident_opt.api",
    # a fleet: every robot every day, and what changed (Dask)
    "run_fleet": "ident_opt.fleet.run",
    "FleetResult": "ident_opt.fleet.run",
    "simulate_fleet": "ident_opt.fleet.simulated",
    # bad input
    "InputError": "ident_opt.errors",
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str):
    """A public name, imported from its module on first use (module doc)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ident_opt' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value  # later uses skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
