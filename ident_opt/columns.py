"""The data format's column names, for an arm of any number of joints (`docs/data-format.md`).

One sample is one row: time `t` [s], then per joint j = 1 … n (in the problem's joint order) the angle `qj`
[rad], optionally `dqj` [rad/s] and `ddqj` [rad/s²], and either the joint torque `tauj` [N m] or the motor
current `ij` [A]. Every reader and writer of trials (the loader, the stream, the simulator, the excitation
design) takes its names from here, and the loader and the stream map a table's own columns onto them by one set of
rules (`locate`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ident_opt.errors import InputError

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


def locate(
    header: Sequence[str] | None, width: int, spec, n_joints: int, where: str
) -> tuple[dict[str, int], dict[str, tuple[float, float]]]:
    """How a table's columns become the data format's names, for the loader and the stream alike: ({standard name:
    0-based column position}, {standard name: (scale, offset)} of the conversions that apply), for a table of
    `width` columns whose header row is `header` (None: no header row) read under `spec` (a `DataSpec`).

    Rules (`docs/data-format.md`): a name set false in `[data.columns]` is never read; a mapped name is read from the
    column it names (by its header name, or its 0-based index); an unmapped standard name is read by name from a
    header; and with `standard_by_name`, a header that has the standard names (t and every qj) is read by name
    whenever the mapping is for another layout (a name it lacks, or an index). InputError naming `where` for a
    mapped column the table lacks or an index beyond it."""
    names = None if header is None else [str(c).strip() for c in header]
    columns, conversions = dict(spec.columns), dict(spec.conversions)
    if names is not None and spec.standard_by_name and columns:
        fits = all(isinstance(v, str) and v in names for v in columns.values())
        if not fits and {"t", *joint_columns("q", n_joints)} <= set(names):
            columns, conversions = {}, {}
    found: dict[str, int] = {}
    for name in data_columns(n_joints):
        source = columns.get(name, name if names is not None else None)
        if source is None or name in spec.ignored:
            continue
        if isinstance(source, int):
            if source >= width:
                raise InputError(f"{where}: column index {source} for '{name}' is beyond the {width} columns")
            found[name] = source
        elif names is not None and source in names:
            found[name] = names.index(source)
        elif name in columns:
            have = ", ".join((names or [])[:30])
            raise InputError(
                f"{where}: column '{source}' (mapped to '{name}' by [data.columns]) not found; the table has: {have}"
            )
    return found, {k: v for k, v in conversions.items() if k in found}
