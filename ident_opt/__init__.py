"""ident-opt: identify, diagnose and ship the dynamics of robot arms with any number of joints.

The stable names of the Python API (`docs/api.md`) are importable from here; each is loaded on first use, so
`import ident_opt` stays light (NumPy, CasADi, Pinocchio load when a name that needs them is used). Every stage
function takes the parsed problem first and gives what its command gives, with the command's defaults::

    import ident_opt as iopt

    problem = iopt.load_problem("problems/kuka_lwr4.toml")
    training, testing = iopt.load_trials(problem)
    fit = iopt.fit(problem, training)              # the recommended fit
    comparison = iopt.compare(problem, training, testing)
    diagnosis = iopt.diagnose(problem, training, testing)
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Each public name → (the module that defines it, its name there).
_EXPORTS = {
    # problem files and trials
    "load_problem": ("ident_opt.problem", "load_problem"),
    "Problem": ("ident_opt.problem", "Problem"),
    "load_trials": ("ident_opt.api", "load_trials"),
    "trial": ("ident_opt.api", "trial"),
    "check": ("ident_opt.api", "check"),
    "Dataset": ("ident_opt.data.dataset", "Dataset"),
    # the arm: its interface and its two implementations
    "Arm": ("ident_opt.arm.base", "Arm"),
    "Robot": ("ident_opt.arm.base", "Robot"),
    "PlanarArm": ("ident_opt.arm.planar", "PlanarArm"),
    "PlanarRobot": ("ident_opt.arm.datasheet", "PlanarRobot"),
    "ChainArm": ("ident_opt.arm.chain", "ChainArm"),
    "ChainRobot": ("ident_opt.arm.chain_robot", "ChainRobot"),
    # identification: one fit, every fit side by side, every model under every protocol
    "fit": ("ident_opt.api", "fit"),
    "ArmFit": ("ident_opt.fitting.recommend", "ArmFit"),
    "Choice": ("ident_opt.fitting.recommend", "Choice"),
    "Stats": ("ident_opt.fitting.stats", "Stats"),
    "LinearFit": ("ident_opt.fitting.fit", "LinearFit"),
    "compare": ("ident_opt.evaluation.compare", "compare"),
    "Comparison": ("ident_opt.evaluation.compare", "Comparison"),
    "identify": ("ident_opt.evaluation.identify", "identify"),
    "IdentifyResult": ("ident_opt.evaluation.identify", "IdentifyResult"),
    "read_run": ("ident_opt.runs", "read_run"),  # two runs side by side (compare --against)
    "summarize": ("ident_opt.runs", "summarize"),
    "side_by_side": ("ident_opt.runs", "side_by_side"),
    "SideBySide": ("ident_opt.runs", "SideBySide"),
    # what the model gets wrong, a simulated trial, the motion to record next
    "diagnose": ("ident_opt.diagnosis", "diagnose"),
    "Diagnosis": ("ident_opt.diagnosis", "Diagnosis"),
    "simulate": ("ident_opt.simulator.simulate", "simulate"),
    "simulate_trial": ("ident_opt.simulator.trial", "simulate_trial"),
    "excite": ("ident_opt.excitation.excite", "excite"),
    "Design": ("ident_opt.excitation.design", "Design"),
    # online identification: the offline start, then the rest of the trial replayed sample by sample
    "online": ("ident_opt.adaptation.replay", "online"),
    "Replay": ("ident_opt.adaptation.replay", "Replay"),
    # contacts and collisions: the external-torque observer, its thresholds and alarms
    "detect": ("ident_opt.api", "detect"),
    "Detection": ("ident_opt.contact.detect", "Detection"),
    "Thresholds": ("ident_opt.contact.thresholds", "Thresholds"),
    # shipping: a robot description, C for the controller
    "export": ("ident_opt.api", "export"),  # the shipping writers behind the command line's output checks
    "codegen": ("ident_opt.api", "codegen"),
    # a fleet: every robot every day, and what changed (Dask)
    "run_fleet": ("ident_opt.fleet.run", "run_fleet"),
    "FleetResult": ("ident_opt.fleet.result", "FleetResult"),
    "simulate_fleet": ("ident_opt.fleet.simulated", "simulate_fleet"),
    # the paper's own view of its robot
    "audit": ("ident_opt.paper.audit", "audit"),
    # bad input
    "InputError": ("ident_opt.errors", "InputError"),
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str):
    """A public name, imported from its module on first use (module doc)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ident_opt' has no attribute {name!r}")
    module, attribute = _EXPORTS[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value  # later uses skip this function
    return value


def __dir__() -> list[str]:
    """The public names only (`__all__`): the subpackages are the implementation, reached through these."""
    return list(__all__)
