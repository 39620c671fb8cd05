"""The recommended fit against the makers' own identified parameters, on held-out trials of the DFKI double pendulum
(designs C.0 and A.0): held-out torque RMSE per joint, ours / theirs, computed on the same samples.

    .venv/bin/python benchmarks/makers_yardstick.py

Each split trains on some of a design's shipped trials with the problem's default settings (the derivative cut-off
"auto", the recommended fit) and tests on the others. The makers' parameters are the problem's [reference]
(model_2.0 of each design, from the makers' repository). Also prints the share of the makers' squared error that
lies above the test trials' derivative cut-off (the torque's white noise there: no model of the motion predicts it,
so it bounds the ratio from below), the ratio in the motion band below the cut-off, and the recommended fit's
parameters against theirs. Writes nothing; the issue-29 closing note quotes its output.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import ident_opt as io
from ident_opt.data import Dataset
from ident_opt.derivatives import lowpass
from ident_opt.studies.recommend import recommended_fit

ROOT = Path(__file__).resolve().parents[1]

# (problem, folder, training trials, test trials): the shipped splits, and the other way round where it makes sense.
SPLITS = (
    ("dfki_c0.toml", "dfki", ("00", "01", "02", "03", "04", "05", "06", "13"), ("12",)),
    ("dfki_c0.toml", "dfki", ("03", "04", "05", "06", "12", "13"), ("00", "01", "02")),
    ("dfki_a0.toml", "dfki_a0", ("11",), ("00",)),
    ("dfki_a0.toml", "dfki_a0", ("00",), ("11",)),
)


def rmse(arm, pi: np.ndarray, trials: list[Dataset], band: bool = False) -> np.ndarray:
    """Per-joint RMSE [N·m] of the torque that parameters `pi` predict on `trials`; `band`: the error's part below
    each trial's derivative cut-off (the motion band, where a prediction from the filtered derivatives lives),
    through the derivative estimate's own zero-phase low-pass (`derivatives.lowpass`)."""
    errors = [d.tau - arm.predict(pi, d.q, d.dq, d.ddq) for d in trials]
    if band:
        errors = [lowpass(d.t, e, d.cutoff_hz) for d, e in zip(trials, errors)]
    return np.sqrt((np.vstack(errors) ** 2).mean(axis=0))


def main() -> None:
    """Print, per split, the recommended fit's held-out RMSE over the makers' and its parameters over theirs."""
    for name, folder, train_ids, test_ids in SPLITS:
        problem = io.load_problem(ROOT / "problems" / name)
        path = ROOT / "data" / folder / "trajectory_{}.csv.gz"
        train, test = io.load_trials(
            problem, data=[str(path).format(i) for i in train_ids], test=[str(path).format(i) for i in test_ids]
        )
        arm = problem.robot.model()
        fit, found = recommended_fit(problem.robot, arm, train, problem)
        makers = np.array([problem.reference.parameters[n] for n in arm.names])
        theirs = rmse(arm, makers, test)
        ratio = rmse(arm, fit.pi, test) / theirs
        # The share of their error above the cut-off: white torque noise there, which no model of the motion predicts.
        floor = 1.0 - (rmse(arm, makers, test, band=True) / theirs) ** 2
        band = rmse(arm, fit.pi, test, band=True) / rmse(arm, makers, test, band=True)
        print(f"{name}: train {'+'.join(train_ids)} -> test {'+'.join(test_ids)}")
        print(f"  recommended: {found.recommendation.estimator} ({found.recommendation.why})")
        print(f"  cut-offs [Hz]: {', '.join(f'{d.cutoff_hz:.1f}' for d in found.trials)}")
        print(f"  held-out RMSE / makers': {'  '.join(f'joint {j + 1} {r:.3f}' for j, r in enumerate(ratio))}")
        print(
            "  share of the makers' squared error above the test trials' cut-off: "
            + "  ".join(f"joint {j + 1} {x:.2f}" for j, x in enumerate(floor))
            + "; below it (the motion band), RMSE / makers': "
            + "  ".join(f"joint {j + 1} {r:.3f}" for j, r in enumerate(band))
        )
        ours = fit.as_dict()
        print(
            "  parameters / makers': "
            + "  ".join(f"{k} {ours[k] / v:.3f}" for k, v in problem.reference.parameters.items() if k in ours and v)
        )


if __name__ == "__main__":
    main()
