"""`ident-opt simulate`: a trial of the problem's arm from the built-in simulator, the problem's `[simulate]` section
overridden by what is given (`simulate_trial` does the work; `SimTrial.write` writes it)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from ident_opt.problem.spec import Problem, SimulateSpec
from ident_opt.simulator.trial import SimTrial, simulate_trial


def simulate(
    problem: Problem,
    *,
    effects: Sequence[str] | None = None,
    trajectory: str | None = None,
    duration: float | None = None,
    rate_hz: float | None = None,
    seed: int | None = None,
    output: str | None = None,
    noise: bool = True,
    exact_derivatives: bool = False,
    bandwidth_hz: float | None = None,
    noise_scale: float | Sequence[float] | None = None,
    progress: bool = False,
) -> SimTrial:
    """`ident-opt simulate`: one trial of `problem`'s arm within its `[limits]`, with hidden `effects` (effect strings,
    `ident_opt.effects`; None: the problem's `[simulate]` effects, none without that section). `trajectory`,
    `duration` [s], `rate_hz` [Hz], `seed`, `output` ("torque" or "current"): given, else the problem's `[simulate]`
    values, else the defaults of `SimulateSpec`; `bandwidth_hz` [Hz] and `noise_scale` as `simulate_trial`'s."""
    problem.require("simulate")
    spec = problem.simulate or SimulateSpec()
    given = {"trajectory": trajectory, "duration": duration, "rate_hz": rate_hz, "seed": seed, "output": output}
    spec = replace(spec, **{key: value for key, value in given.items() if value is not None})
    extra = {k: v for k, v in (("bandwidth_hz", bandwidth_hz), ("noise_scale", noise_scale)) if v is not None}
    trial = simulate_trial(
        problem.robot,
        trajectory=spec.trajectory,
        duration=spec.duration,
        rate_hz=spec.rate_hz,
        seed=spec.seed,
        effects=list(spec.effects) if effects is None else list(effects),
        output=spec.output,
        noise=noise,
        exact_derivatives=exact_derivatives,
        limits=problem.limits,
        progress=progress,
        **extra,
    )
    urdf = getattr(problem.robot, "urdf", None)
    made_from = [problem.path, urdf, *problem.data.trials, *problem.data.train, *problem.data.test]
    return replace(trial, inputs=tuple(Path(p) for p in made_from if p is not None))
