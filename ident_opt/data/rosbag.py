"""ROS 2 bags as trials: `/joint_states`-style messages (sensor_msgs/msg/JointState: name, position, velocity,
effort) read with the `rosbags` library (no ROS installation), joints picked by name.

A bag is the folder `ros2 bag record` writes (metadata.yaml beside one .mcap or .db3 file, MCAP or SQLite3
storage); giving that .mcap/.db3 file is the same. `[data] ros_joints` names the joints, base to tip (joint k of
the model is the k-th name); `ros_topic` the topic (default "/joint_states"). The trial comes out in the data
format's names: t [s] from the messages' header stamps (the bag's receive time when a stamp is zero), relative
to the first; q_k = position, dq_k = velocity (when the messages carry velocities), tau_k = effort. Units are
ROS's: rad, rad/s, N m. `[data.columns]` can still convert them (`q1 = { column = "q1", offset = … }`).

Every file of the bag's folder must be a regular file (`regular_bag_files`), checked before `rosbags` (and SQLite)
open any: a named pipe there would block the open for good, unreachable even by SIGTERM.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.errors import InputError

#: File names of a ROS 2 bag's storage (its folder holds metadata.yaml beside them).
BAG_SUFFIXES = (".mcap", ".db3")


def is_bag(path: Path) -> bool:
    """A ROS 2 bag: a folder with metadata.yaml, or a .mcap / .db3 storage file."""
    return (path.is_dir() and (path / "metadata.yaml").exists()) or path.name.lower().endswith(BAG_SUFFIXES)


def read_bag(path: Path, topic: str, joints: tuple[str, ...]) -> pd.DataFrame:
    """The bag's `topic` as a table t, q1…qn, dq1…dqn (if logged), tau1…taun for the named `joints`."""
    # Deferred: rosbags (and its message type store) is needed only for bags.
    from rosbags.highlevel import AnyReader, AnyReaderError

    if not joints:
        raise InputError(f'{path}: a ROS bag needs [data] ros_joints = ["…", "…"] (its joint names, base to tip)')
    folder = path if path.is_dir() else path.parent
    if not (folder / "metadata.yaml").exists():
        raise InputError(f"{path}: not a ROS 2 bag: its folder has no metadata.yaml (give the bag's folder)")
    outputs.declare_inputs([folder])  # the bag is its folder: metadata.yaml and the storage files in it
    regular_bag_files(path, folder)
    rows: list[tuple[float, np.ndarray, np.ndarray | None, np.ndarray]] = []
    try:
        with AnyReader([folder]) as reader:
            connections = [c for c in reader.connections if c.topic == topic]
            if not connections:
                have = ", ".join(sorted(reader.topics)) or "none"
                raise InputError(f"{path}: the bag has no topic '{topic}' ([data] ros_topic); its topics: {have}")
            other = sorted({c.msgtype for c in connections} - {JOINT_STATE})
            if other:
                raise InputError(
                    f"{path}: the topic '{topic}' ([data] ros_topic) carries {other[0]} messages, not {JOINT_STATE}"
                )
            for connection, stamp, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, connection.msgtype)
                rows.append(_sample(path, msg, stamp, joints, message_label(len(rows), topic)))
    except InputError:
        raise
    except (AnyReaderError, OSError, ValueError, KeyError, AttributeError) as exc:
        raise InputError(f"{path}: cannot read the ROS bag ({type(exc).__name__}: {exc})") from None
    if not rows:
        raise InputError(f"{path}: the topic '{topic}' has no messages")
    return _frame(rows, len(joints))


def regular_bag_files(path: Path, folder: Path) -> None:
    """InputError naming the culprit unless metadata.yaml and every other file in the bag's `folder` (following
    links; subfolders aside) is a regular file: `rosbags` reads metadata.yaml whole and SQLite opens the .db3,
    and a named pipe blocks that open (SIGTERM included: the wait is in C), a device is read without end. Checked
    by `os.stat` only, before anything opens them."""
    try:
        entries = sorted(os.scandir(folder), key=lambda e: e.name)
    except OSError as exc:
        raise InputError(f"{path}: cannot read the ROS bag's folder {folder} ({exc.strerror})") from None
    for entry in [folder / "metadata.yaml", *(Path(e.path) for e in entries if e.name != "metadata.yaml")]:
        kind = outputs.file_kind(entry)
        if kind is not None and (kind != outputs.FOLDER or entry.name == "metadata.yaml"):
            raise InputError(
                f"{entry}: this file of the ROS 2 bag {folder} is {kind}, not a regular file; a bag's metadata.yaml "
                "and storage files (.db3, .mcap) are read only when they are regular files"
            )


#: The message type a bag's topic must carry.
JOINT_STATE = "sensor_msgs/msg/JointState"


def message_label(index: int, topic: str) -> str:
    """Message `index` (0-based, in the bag's order) of `topic` as messages name it: counted from 1."""
    return f"message {index + 1} of topic '{topic}'"


def _sample(path: Path, msg, stamp_ns: int, joints: tuple[str, ...], where: str):
    """(t [s], q, dq or None, tau) of one JointState message (`where`: its `message_label`), in the order of
    `joints`."""
    names = list(getattr(msg, "name", []))
    missing = [j for j in joints if j not in names]
    if missing:
        raise InputError(
            f"{path}: {where} has no joint '{missing[0]}' ([data] ros_joints); its joints: {', '.join(names) or 'none'}"
        )
    at = [names.index(j) for j in joints]
    position, velocity, effort = (np.asarray(getattr(msg, k), dtype=float) for k in ("position", "velocity", "effort"))
    if len(effort) != len(names):
        raise InputError(f"{path}: {where} has no effort for its joints (tau comes from effort)")
    if len(position) != len(names):
        raise InputError(f"{path}: {where} has no position for its joints (q comes from position)")
    header = getattr(msg, "header", None)
    t = header.stamp.sec + 1e-9 * header.stamp.nanosec if header is not None else 0.0
    t = t if t > 0 else 1e-9 * stamp_ns
    dq = velocity[at] if len(velocity) == len(names) else None
    return t, position[at], dq, effort[at]


def _frame(rows: list, n: int) -> pd.DataFrame:
    """The samples as the data format's columns (t relative to the first sample)."""
    t = np.array([r[0] for r in rows])
    cols: dict[str, np.ndarray] = {"t": t - t[0]}
    q, tau = np.array([r[1] for r in rows]), np.array([r[3] for r in rows])
    with_dq = all(r[2] is not None for r in rows)
    dq = np.array([r[2] for r in rows]) if with_dq else None
    for j in range(n):
        cols[f"q{j + 1}"] = q[:, j]
        if dq is not None:
            cols[f"dq{j + 1}"] = dq[:, j]
        cols[f"tau{j + 1}"] = tau[:, j]
    return pd.DataFrame(cols)
