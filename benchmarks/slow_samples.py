"""How a fit should read the samples where a joint is slow (issue 48, point 5): on every shipped real arm, and on
the simulated arm4 of `benchmarks/nominal_payload.py` whose true friction is known.

Four readings of the same trials, each fitted with least squares and with the arm's default estimator and scored
on the held-out trial (or the last 30 % of the one trial), every sample, against the measured torque:

- `as read`: every sample in every joint's equation, velocities as logged or estimated (`[data] rest_velocity =
  "as_read"`; before 2026-12-07, what every fit did);
- `slow out`: each joint's samples slower than its stick speed (`signals.stick_speed`, 2 % of its 95th-percentile
  speed) left out of its own equation;
- `rest held`: a joint at rest (`signals.resting`, the diagnosis's `split.at_rest`) has q̇ = 0, in training and
  held-out trials alike (sign(0) = 0: no Coulomb torque predicted where the joint does not move);
- `both`.

The model's Coulomb column is sign(q̇): where a joint rests, an estimated velocity's sign is noise, so a fit that
keeps those samples shrinks its Coulomb friction to hedge, and a prediction that reads them predicts ±fc at random.
Prints nMSE per joint and the fitted Coulomb levels. `python benchmarks/slow_samples.py [PROBLEM ...]`.

`python benchmarks/slow_samples.py plant`: the window of the rule, on the cut-off study's plant (the DFKI C.0 arm
with larger friction, `evaluation.cutoff_plant`; `passive`, `steps`, `driven` and `swing_up` trials of 20 s at 100 and
1000 Hz, seeds 71–72, never the study's): the recommended fit's parameter error (the study's `_error`) with the
velocities as read and with rests held over the diagnosis's 10 ms and the loader's 50 ms window. `passive`: the same
on the fresh cut-off study's passive trials (seeds 2000–2004, noise 0.5, 1000 and 250 Hz), where holding hurts."""

from __future__ import annotations

import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

import ident_opt as iopt
from ident_opt.data.dataset import chronological_split
from ident_opt.diagnosis.split import at_rest
from ident_opt.fitting import estimators
from ident_opt.fitting.stats import Stats
from ident_opt.metrics import nmse
from ident_opt.numerics import signals
from ident_opt.simulator.simulate import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
REAL = ["tudor_2dof", "dfki_c0", "dfki_a0", "kuka_lwr4", "franka_panda", "staubli_tx40"]
READINGS = {"as read": (False, False), "slow out": (True, False), "rest held": (False, True), "both": (True, True)}


def _statistics(arm, trials, slow_out: bool) -> Stats:
    total = Stats.zeros(arm.n_params, arm.n_joints)
    for d in trials:
        Y, tau = arm.regressor(d.q, d.dq, d.ddq), d.tau_fit
        if slow_out:  # a zero row adds nothing to G, b or s: the sample leaves that joint's equation only
            keep = (np.abs(d.dq) >= signals.stick_speed(d.dq)).astype(float)
            Y, tau = Y * keep[:, :, None], tau * keep
        total += Stats.from_regressor(Y, tau)
    return total


def _as_read(problem):
    """The problem with its trials' velocities read as they are (each reading below is made here)."""
    return replace(problem, data=replace(problem.data, rest_velocity="as_read"))


def _parts(problem) -> tuple[list, list]:
    training, testing = iopt.load_trials(_as_read(problem))
    if testing:
        return training, testing
    train, test = chronological_split(training[0].n, problem.split.train_fraction)
    return [training[0].subset(train)], [training[0].subset(test)]


def study(problem, training: list, testing: list) -> None:
    robot = problem.robot
    arm = robot.model(None)
    fc = [k for k, p in enumerate(arm.parameters) if p.name.startswith("fc")]
    print(
        f"\n{problem.name} ({arm.n_joints} joints; slow training samples per joint: "
        f"{np.round(np.mean(np.vstack([np.abs(d.dq) < signals.stick_speed(d.dq) for d in training]), 0), 2)})"
    )
    for name in dict.fromkeys(("ols", robot.default_estimator)):
        for label, (slow_out, rest_held) in READINGS.items():
            train = [at_rest(d) for d in training] if rest_held else training
            test = [at_rest(d) for d in testing] if rest_held else testing
            pi = estimators.fit_for(robot, name, _statistics(arm, train, slow_out), arm).pi
            scores = [nmse(d.tau, arm.predict(pi, d.q, d.dq, d.ddq)) for d in test]
            print(
                f"  {name:11s} {label:9s} nMSE {np.round(np.mean(scores, axis=0), 4).tolist()}  "
                f"fc {np.round(pi[fc], 3).tolist()}"
            )


def simulated() -> None:
    """arm4 (tests/arms/arm4.toml), logged as t, q, τ at 250 Hz: trained on `mixed` + `tud01`, tested on another
    `tud01`; its true Coulomb levels are in its problem file."""
    problem = iopt.load_problem(ROOT / "tests" / "arms" / "arm4.toml")
    with tempfile.TemporaryDirectory() as folder:
        paths = []
        for seed, trajectory in ((1100, "mixed"), (1101, "tud01"), (1107, "tud01")):
            trial = simulate_trial(
                problem.robot,
                trajectory=trajectory,
                duration=60.0,
                rate_hz=250.0,
                seed=seed,
                limits=problem.limits,
                progress=False,
            )
            frame = trial.frame[[c for c in trial.frame.columns if not c.startswith(("dq", "ddq"))]]
            paths.append(Path(folder) / f"trial_{seed}.csv")
            frame.to_csv(paths[-1], index=False)
        study(problem, *iopt.load_trials(_as_read(problem), paths[:2], paths[2:]))


def plant(kinds=("passive", "steps", "driven", "swing_up"), rates=(100.0, 1000.0), seeds=(71, 72), noise=1.0) -> None:
    """The window of the rule on the cut-off study's plant (module doc)."""
    from ident_opt.evaluation.cutoff_plant import Condition, simulate
    from ident_opt.evaluation.cutoff_study import _error, truth
    from ident_opt.fitting.recommend import choose
    from ident_opt.numerics.signals import HOLD_WINDOW_S, REST_WINDOW_S
    from ident_opt.problem import DataSpec

    dfki = iopt.load_problem(ROOT / "problems" / "dfki_c0.toml")
    arm, pi = truth(dfki.robot)
    problem = replace(dfki, data=DataSpec(derivative_cutoff_hz="auto", rest_velocity="as_read"))
    ratios: dict[float, list[float]] = {REST_WINDOW_S: [], HOLD_WINDOW_S: []}
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "trial.csv"
        for kind in kinds:
            for rate in rates:
                for seed in seeds:
                    simulate(arm, pi, Condition(kind, rate, noise), seed, duration=20.0).to_csv(path, index=False)
                    d = iopt.load_trials(problem, [path], fit=True)[0][0]
                    errors = {}
                    for window in (None, REST_WINDOW_S, HOLD_WINDOW_S):
                        read = d if window is None else at_rest(d, window)
                        errors[window] = _error(
                            arm, choose(problem, [read], model=arm).fit(dfki.robot, arm, [read]).pi, pi
                        )
                    line = "  ".join(f"{w * 1000:g} ms {errors[w] / errors[None]:.3f}" for w in ratios)
                    print(f"  {kind:9s} {rate:6g} Hz seed {seed}: as read {errors[None]:.4g}; held ÷ as read: {line}")
                    for w in ratios:
                        ratios[w].append(errors[w] / errors[None])
    for w, r in ratios.items():
        print(f"window {w * 1000:g} ms: held ÷ as read median {np.median(r):.3f}, min {min(r):.3f}, max {max(r):.3f}")


def main() -> None:
    names = sys.argv[1:] or REAL
    for name in names:
        if name == "plant":
            plant()
        elif name == "passive":  # the fresh cut-off study's passive trials (seeds 2000-2004, noise 0.5)
            plant(("passive",), (1000.0, 250.0), tuple(range(2000, 2005)), 0.5)
        elif name == "arm4":
            simulated()
        else:
            problem = iopt.load_problem(ROOT / "problems" / f"{name}.toml")
            study(problem, *_parts(problem))


if __name__ == "__main__":
    main()
