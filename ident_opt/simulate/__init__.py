"""The built-in simulator: a flexible two-link arm with known truth, under closed-loop control.

Modules: `effects` (the catalogue, the background terms and their text syntax), `trajectories` (tud01,
fourier), `truth` (the true plant), `background` (stiction, drift, ripple: realism outside the catalogue),
`flexible_link` (a link cut in two halves with a spring: a Lagrangian planar chain), `closed_loop`
(1 kHz controller + RK4), `measurement` (what the logger records), `trial` (`simulate_trial`, `SimTrial`),
`cache` (`problem_trials` for a problem's `[simulate]` section), `calibration` (default vs the real exp1).
"""

from ident_opt.simulate.cache import problem_trials
from ident_opt.simulate.effects import CATALOGUE, parse_effect
from ident_opt.simulate.trial import SimTrial, simulate_trial, truth_path

__all__ = ["CATALOGUE", "SimTrial", "parse_effect", "problem_trials", "simulate_trial", "truth_path"]
