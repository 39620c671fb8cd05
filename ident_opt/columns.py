"""The data format's column names, for an arm of any number of joints (`docs/data-format.md`).

One sample is one row: time `t` [s], then per joint j = 1 … n (in the problem's joint order) the angle `qj`
[rad], optionally `dqj` [rad/s] and `ddqj` [rad/s²], and either the joint torque `tauj` [N m] or the motor
current `ij` [A]. Every reader and writer of trials (the loader, the stream, the simulator, the excitation
design) takes its names from here.
"""

from __future__ import annotations

import numpy as np

#: The per-joint signals of a trial, in the order the loader reports them.
SIGNALS = ("q", "dq", "ddq", "tau", "i")
#: The signals that give the load: joint torques or motor currents (one of the two per trial).
LOADS = ("tau", "i")


def joint_columns(signal: str, n_joints: int) -> tuple[str, ...]:
    """`signal`1 … `signal`n: one column name per joint (e.g. q1, q2 for `joint_columns("q", 2)`)."""
    return tuple(f"{signal}{j}" for j in range(1, n_joints + 1))


def channel_names(n_joints: int) -> dict[str, tuple[str, ...]]:
    """Every signal's column names for an arm of `n_joints` joints: {"q": (q1 … qn), "dq": …, "i": …}."""
    return {signal: joint_columns(signal, n_joints) for signal in SIGNALS}


def data_columns(n_joints: int) -> tuple[str, ...]:
    """Every standard column of an n-joint trial: t, q1…qn, dq1…dqn, ddq1…ddqn, tau1…taun, i1…in."""
    return ("t", *(name for names in channel_names(n_joints).values() for name in names))


def kinematic_columns(n_joints: int) -> tuple[str, ...]:
    """t, q1…qn, dq1…dqn, ddq1…ddqn: the columns of a motion without its load (a trajectory file)."""
    return ("t", *(name for signal in ("q", "dq", "ddq") for name in joint_columns(signal, n_joints)))


def columns_of(signals: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each signal's array (N, n) as one column per joint: {"q": (N, 2)} → {"q1": (N,), "q2": (N,)}."""
    return {
        name: array[:, j]
        for signal, array in signals.items()
        for j, name in enumerate(joint_columns(signal, array.shape[1]))
    }
