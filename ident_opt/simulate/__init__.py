"""The built-in simulator: a flexible two-link arm with known truth, under closed-loop control.

Modules: `trajectories` (tud01, fourier), `truth` (the true plant: the datasheet arm with the hidden effects
of `ident_opt.effects`), `background` (the loop's realism terms of `ident_opt.effects.background`),
`flexible_link` (a link cut in two halves with a spring: a Lagrangian planar chain), `closed_loop`
(1 kHz controller + RK4), `measurement` (what the logger records), `trial` (`simulate_trial`, `SimTrial`),
`cache` (`problem_trials` for a problem's `[simulate]` section), `calibration` (default vs the real exp1).
"""

from importlib import import_module

from ident_opt.effects import CATALOGUE, parse_effect

# The integrator side (CasADi, SciPy) is imported on first use only: the CLI's --help and problem-file
# loading need just the catalogue in `ident_opt.effects`, and must not pay for the whole simulator.
_LAZY = {"SimTrial": "trial", "simulate_trial": "trial", "truth_path": "trial", "problem_trials": "cache"}

__all__ = ["CATALOGUE", "SimTrial", "parse_effect", "problem_trials", "simulate_trial", "truth_path"]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(import_module(f"ident_opt.simulate.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
