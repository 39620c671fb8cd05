"""Rebuild tx40.csv.gz from FIGAROH's Stäubli TX40 recording (see NOTICE.md).

    python data/staubli_tx40/prepare.py SOURCE_DIR   # the folder holding pos_read_data.csv, curr_data.csv

Motor side → joint side as FIGAROH does it: q = N⁻¹ q_motor with N = diag(32, 32, 45, −48, 45, 32) and the
coupled wrist N[5, 4] = 32, then q2 −= π/2, q3 += π/2; τ = Nᵀ · current (FIGAROH's red_tau: it treats the
signal as motor torque [N m]; the unit is not documented). Positions (5 kHz, encoder quantum ≈ 3e-5 rad)
and torques are low-passed alike (4th-order Butterworth, forward and backward, 20 Hz), differentiated by
central differences (velocities, then accelerations, the velocity low-passed again), and every 20th sample is
kept (250 Hz). Columns t, q1..q6, dq1..dq6, ddq1..ddq6, tau1..tau6 (s, rad, rad/s, rad/s², N m).
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import signal

RATE, STEP, CUTOFF = 5000.0, 20, 20.0


def main(source: Path) -> None:
    N = np.diag([32.0, 32.0, 45.0, -48.0, 45.0, 32.0])
    N[5, 4] = 32.0
    q_motor = pd.read_csv(source / "pos_read_data.csv").to_numpy(dtype=float)
    current = pd.read_csv(source / "curr_data.csv").to_numpy(dtype=float)
    q = q_motor @ np.linalg.inv(N).T
    q[:, 1] -= np.pi / 2
    q[:, 2] += np.pi / 2
    tau = current @ N  # τ_j = Σ_m N[m, j] τ_m = Nᵀ τ_motor
    b, a = signal.butter(4, CUTOFF / (0.5 * RATE))
    t = np.arange(len(q)) / RATE
    q_f = signal.filtfilt(b, a, q, axis=0)
    dq = np.gradient(q_f, t, axis=0)
    ddq = np.gradient(signal.filtfilt(b, a, dq, axis=0), t, axis=0)
    tau_f = signal.filtfilt(b, a, tau, axis=0)
    cols = {"t": t}
    for name, x in (("q", q_f), ("dq", dq), ("ddq", ddq), ("tau", tau_f)):
        cols.update({f"{name}{j + 1}": x[:, j] for j in range(6)})
    frame = pd.DataFrame(cols).iloc[::STEP]
    frame.to_csv(Path(__file__).resolve().parent / "tx40.csv.gz", index=False, float_format="%.7g")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
