"""Simulated trials for a problem file's `[simulate]` section: generated on first use, then cached.

Two trials (seeds s and s + 1) so that the unseen-trial protocol works. The cache lives in `.cache/sim/`
of the project that holds the problem file (the nearest folder above it with a `pyproject.toml`, else the
problem's own folder), or in `$IDENT_OPT_CACHE` when set; files are keyed by a hash of the robot, the
settings and the simulator's version, so a changed setting never reuses a stale trial.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

from ident_opt.cache import cache_root
from ident_opt.errors import InputError
from ident_opt.simulator.trial import simulate_trial

SIMULATOR_VERSION = 5  # bump when the simulator's output changes for the same settings


def cache_dir(problem_path: Path) -> Path:
    """Where simulated trials of this problem are cached."""
    return cache_root(problem_path) / "sim"


def settings_key(robot, spec, seed: int) -> str:
    """A short hash of everything that determines the trial."""
    payload = {"robot": asdict(robot), "simulate": asdict(spec), "seed": seed, "version": SIMULATOR_VERSION}
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def spec_trial(robot, spec, seed: int, effects: list[str] | None = None):
    """The trial (`SimTrial`) a `[simulate]` section `spec` describes for `robot` at `seed`; `effects`
    (effect strings) instead of the section's own when given."""
    return simulate_trial(
        robot,
        trajectory=spec.trajectory,
        duration=spec.duration,
        rate_hz=spec.rate_hz,
        seed=seed,
        effects=list(spec.effects) if effects is None else effects,
        output=spec.output,
    )


def problem_trials(problem) -> list[Path]:
    """The problem's two simulated trials (seeds s and s + 1) as CSV paths, simulating any not yet cached."""
    spec = problem.simulate
    if spec is None:
        raise ValueError(f"{problem.path}: the problem has no [simulate] section")
    folder = cache_dir(problem.path)
    paths = []
    for seed in (spec.seed, spec.seed + 1):
        path = folder / f"{problem.name}-seed{seed}-{settings_key(problem.robot, spec, seed)}.csv"
        if not path.is_file():
            try:
                trial = spec_trial(problem.robot, spec, seed)
            except InputError as exc:  # name the file and section the bad setting came from
                raise InputError(f"{problem.path}: [simulate]: {exc}") from None
            trial.write(path)
        paths.append(path)
    return paths
