"""Rebuild the CSV trials of this folder from FloBaRoID's KUKA LWR4+ measurements (see NOTICE.md).

    python data/kuka_lwr4/prepare.py SOURCE_DIR   # the folder holding measurements_{1,2,3}.npz

Each .npz (≈200 Hz, already filtered and differentiated upstream) becomes measurements_<k>.csv.gz with the
data format's columns t, q1..q7, dq1..dq7, ddq1..ddq7, tau1..tau7 (rad, rad/s, rad/s², N m; t from 0 s),
every 2nd sample kept (≈100 Hz: the motion is below 2 Hz and upstream already low-passed every signal).
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd

STEP = 2


def main(source: Path) -> None:
    here = Path(__file__).resolve().parent
    for k in (1, 2, 3):
        z = np.load(source / f"measurements_{k}.npz", allow_pickle=False)
        cols = {"t": z["times"] - z["times"][0]}
        for name, key in (("q", "positions"), ("dq", "velocities"), ("ddq", "accelerations"), ("tau", "torques")):
            cols.update({f"{name}{j + 1}": z[key][:, j] for j in range(7)})
        frame = pd.DataFrame(cols).iloc[::STEP]
        frame.to_csv(here / f"measurements_{k}.csv.gz", index=False, float_format="%.7g")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
