"""Rebuild panda_trajectory_1.csv.gz from Gaz et al.'s logged Panda excitation (see NOTICE.md).

    python data/franka_panda/prepare.py SOURCE_DIR   # the folder holding Trajectory_1/rbt_log/*.txt

The log (≈1 kHz, irregular stamps) is interpolated onto a uniform 1 kHz grid, low-passed forward and
backward (4th-order Butterworth, 50 Hz: the excitation is below 2 Hz) and every 5th sample kept (200 Hz).
Columns t, q1..q7, dq1..dq7, tau1..tau7 (s, rad, rad/s, N m); no accelerations (the loader estimates them).
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import signal

RATE, STEP, CUTOFF = 1000.0, 5, 50.0


def main(source: Path) -> None:
    log = source / "Trajectory_1" / "rbt_log"
    t = np.loadtxt(log / "exciting_traj_time.txt")
    grid = np.arange(t[0], t[-1], 1.0 / RATE)
    b, a = signal.butter(4, CUTOFF / (0.5 * RATE))
    cols = {"t": grid[::STEP] - grid[0]}
    for name, key in (("q", "positions"), ("dq", "velocity"), ("tau", "torques")):
        x = np.loadtxt(log / f"exciting_traj_{key}.txt").reshape(-1, 7)
        uniform = np.column_stack([np.interp(grid, t, x[:, j]) for j in range(7)])
        smooth = signal.filtfilt(b, a, uniform, axis=0)[::STEP]
        cols.update({f"{name}{j + 1}": smooth[:, j] for j in range(7)})
    here = Path(__file__).resolve().parent
    pd.DataFrame(cols).to_csv(here / "panda_trajectory_1.csv.gz", index=False, float_format="%.7g")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
