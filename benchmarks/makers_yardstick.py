"""The recommended fit against the makers' own identified parameters, on held-out trials of the DFKI double pendulum
(designs C.0 and A.0): held-out torque RMSE per joint, ours / theirs, computed on the same samples.

    .venv/bin/python benchmarks/makers_yardstick.py

Each split trains on some of a design's shipped trials with the problem's default settings (the derivative cut-off
"auto", the recommended fit) and tests on the others. The makers' parameters are the problem's [reference]
(C.0's model_3.0, A.0's model_2.0, from the makers' repository). The makers fitted them on their recordings 00-13
of one day (C.0: 2022-09-14, A.0: 2022-08-15), so on every split drawn from those days their parameters have seen
the test trial and ours have not. The last two splits test on A.0's open-loop sines of 2022-08-12, which neither
fit saw; their torque is the commanded one (the older log format has no measured torque), which in open loop is
what the driver was asked to apply, free of the measured torque's white noise. Also prints the share of the makers'
squared error that lies above the test trials' derivative cut-off (on measured torque mostly white noise, which no
model of the motion predicts, so it bounds the ratio from below), the ratio in the motion band below the cut-off, and
the recommended fit's parameters against theirs. Writes nothing; the issue-29 closing note quotes its output.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

import ident_opt as io
from ident_opt.data.dataset import Dataset
from ident_opt.data.loader import load_dataset
from ident_opt.fitting.recommend import choose
from ident_opt.numerics.derivatives import lowpass

ROOT = Path(__file__).resolve().parents[1]


def trajectories(*ids: str) -> tuple[str, ...]:
    """The shipped trials trajectory_<id>.csv.gz."""
    return tuple(f"trajectory_{i}.csv.gz" for i in ids)


#: A.0's 2022-08-12 open-loop sines (data/dfki_a0/NOTICE.md): the older log format, commanded torque.
SINES = ("sines_20220812_055032.csv.gz", "sines_20220812_055640.csv.gz", "sines_20220812_055903.csv.gz")
#: How the older format's columns map (angles 0 hanging, as in the newer one).
OLD_FORMAT = {"t": "time", "q1": "pos1", "q2": "pos2", "tau1": "tau1", "tau2": "tau2"}

# (problem, folder, training files, test files, test columns): the shipped splits, the other way round where it
# makes sense, and the split that neither side has seen.
SPLITS = (
    ("dfki_c0.toml", "dfki", trajectories("00", "01", "02", "03", "04", "05", "06", "13"), trajectories("12"), None),
    ("dfki_c0.toml", "dfki", trajectories("03", "04", "05", "06", "12", "13"), trajectories("00", "01", "02"), None),
    ("dfki_a0.toml", "dfki_a0", trajectories("11"), trajectories("00"), None),
    ("dfki_a0.toml", "dfki_a0", trajectories("00"), trajectories("11"), None),
    ("dfki_a0.toml", "dfki_a0", trajectories("11"), SINES, OLD_FORMAT),
    ("dfki_a0.toml", "dfki_a0", trajectories("00", "11"), SINES, OLD_FORMAT),
)


def named(files: tuple[str, ...]) -> str:
    """The trials as the output names them: 00 + 11, sines_20220812_055032 + …"""
    return " + ".join(f.removesuffix(".csv.gz").removeprefix("trajectory_") for f in files)


def load(problem, paths: list[Path], columns: dict[str, str] | None) -> list[Dataset]:
    """The trials at `paths`, read with the problem's [data] or, given `columns`, with that column map (the
    problem's conversions kept: q1's zero moved to the horizontal)."""
    spec = problem.data if columns is None else replace(problem.data, columns=columns)
    return [load_dataset(p, spec, problem.robot) for p in paths]


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
    for name, folder, train_files, test_files, columns in SPLITS:
        problem = io.load_problem(ROOT / "problems" / name)
        train = load(problem, [ROOT / "data" / folder / f for f in train_files], None)
        test = load(problem, [ROOT / "data" / folder / f for f in test_files], columns)
        arm = problem.robot.model()
        found = choose(problem, train, model=arm)
        fit = found.fit(problem.robot, arm, train)
        makers = np.array([problem.reference.parameters[n] for n in arm.names])
        theirs = rmse(arm, makers, test)
        ratio = rmse(arm, fit.pi, test) / theirs
        # The share of their error above the cut-off: white torque noise there, which no model of the motion predicts.
        floor = 1.0 - (rmse(arm, makers, test, band=True) / theirs) ** 2
        band = rmse(arm, fit.pi, test, band=True) / rmse(arm, makers, test, band=True)
        print(f"{name}: train {named(train_files)} -> test {named(test_files)}")
        print(f"  recommended: {found.estimator} ({found.why})")
        print(f"  cut-offs [Hz]: {', '.join(f'{d.cutoff_hz:.1f}' for d in found.at_cutoff(train))}")
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
