"""The built-in simulator: an arm with known truth, any number of joints, under closed-loop control, with hidden
effects from the catalogue (`ident_opt.effects`) switched on, off and scaled.

Modules: `trajectories` (tud01, fourier, mixed, or a file), `fourier` (a periodic Fourier trajectory), `truth` and
`flexible_link` (the planar two-link arm's true plant: its datasheet read physically, flexible links),
`chain_plant` (any arm's true plant: its nominal model with the hidden effects on any joint), `closed_loop` and
`chain_loop` (1 kHz controller + RK4), `background` (the planar loop's realism terms), `measurement` (what the logger
records), `trial` (`simulate_trial`, `SimTrial`), `cache` (`problem_trials` for a problem's `[simulate]`
section), `unseen` (plants the diagnosis was not tuned on).
"""

from importlib import import_module

from ident_opt.effects import CATALOGUE, parse_effect

# The integrator side (CasADi, SciPy) is imported on first use only: the CLI's --help and problem-file
# loading need just the catalogue in `ident_opt.effects`, and must not pay for the whole simulator.
_LAZY = {"SimTrial": "trial", "simulate_trial": "trial", "truth_path": "trial", "problem_trials": "cache"}

__all__ = ["CATALOGUE", "SimTrial", "parse_effect", "problem_trials", "simulate_trial", "truth_path"]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(import_module(f"ident_opt.simulator.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
