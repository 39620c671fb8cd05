"""ROS 2 bags (MCAP and SQLite3) as trials: `/joint_states` messages mapped by joint name, written here with the
same `rosbags` library from a real DFKI trial, read back to the same samples as the CSV; bad bags exit 2."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_typestore

from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.problem import load_problem

from .conftest import PROBLEMS

CSV = PROBLEMS.parent / "data" / "dfki" / "trajectory_00.csv.gz"
STORE = get_typestore(Stores.ROS2_HUMBLE)
JOINT_STATE = STORE.types["sensor_msgs/msg/JointState"]


def write_bag(folder, frame: pd.DataFrame, storage=StoragePlugin.MCAP, topic="/joint_states", velocity=True):
    """One JointState per row: joints ("rail", "shoulder", "elbow") in that order, 'rail' fixed at 0."""
    header, stamp = STORE.types["std_msgs/msg/Header"], STORE.types["builtin_interfaces/msg/Time"]
    with Writer(folder, version=9, storage_plugin=storage) as writer:
        connection = writer.add_connection(topic, JOINT_STATE.__msgtype__, typestore=STORE)
        for row in frame.itertuples():
            t = 100.0 + row.time  # a wall-clock-like stamp: the trial starts at t = 0 again
            sec = int(t)
            msg = JOINT_STATE(
                header=header(stamp=stamp(sec=sec, nanosec=round((t - sec) * 1e9)), frame_id=""),
                name=["rail", "shoulder", "elbow"],
                position=np.array([0.0, row.pos_meas1, row.pos_meas2]),
                velocity=np.array([0.0, row.vel_meas1, row.vel_meas2]) if velocity else np.array([], dtype=float),
                effort=np.array([0.0, row.tau_meas1, row.tau_meas2]),
            )
            writer.write(connection, round(t * 1e9), STORE.serialize_cdr(msg, JOINT_STATE.__msgtype__))
    return folder


def bag_problem(tmp_path, joints='["shoulder", "elbow"]', topic=None):
    """The DFKI robot reading a bag: joints by name, q1 from the hanging-down zero."""
    robot = (PROBLEMS / "dfki_c0.toml").read_text(encoding="utf-8").split("# Angles are 0")[0]
    data = f'[data]\nderivative_cutoff_hz = "auto"\nros_joints = {joints}\n'
    data += f'ros_topic = "{topic}"\n' if topic else ""
    data += '\n[data.columns]\nq1 = { column = "q1", offset = -1.5707963267948966 }\nq2 = "q2"\ntau1 = "tau1"\n'
    data += 'tau2 = "tau2"\n'
    path = tmp_path / "bag.toml"
    path.write_text(robot + data, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def frame():
    return pd.read_csv(CSV).iloc[:1500]


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_a_bag_reads_as_the_same_trial_as_its_csv(tmp_path, frame, storage):
    bag = write_bag(tmp_path / "bag", frame, storage)
    problem = load_problem(bag_problem(tmp_path))
    d = load_dataset(bag, problem.data, problem.robot)
    t = (frame["time"] - frame["time"].iloc[0]).to_numpy()
    first = int(np.argmin(np.abs(t - d.t[0])))  # accelerations estimated: the unsettled ends are left out
    rows = frame.iloc[first : first + d.n]
    assert 0.85 * len(frame) < d.n < len(frame)
    np.testing.assert_allclose(d.t, t[first : first + d.n], atol=2e-9)
    np.testing.assert_allclose(d.q[:, 0], rows["pos_meas1"] - np.pi / 2, atol=1e-12)  # by name, converted
    np.testing.assert_allclose(d.q[:, 1], rows["pos_meas2"], atol=1e-12)
    np.testing.assert_allclose(d.tau, rows[["tau_meas1", "tau_meas2"]], atol=1e-12)
    np.testing.assert_allclose(d.dq, rows[["vel_meas1", "vel_meas2"]], atol=1e-12)  # logged velocities kept
    storage_file = next((tmp_path / "bag").glob("*.mcap" if storage == StoragePlugin.MCAP else "*.db3"))
    assert load_dataset(storage_file, problem.data, problem.robot).n == d.n  # the storage file works too


def test_check_reports_a_bag_without_velocities(tmp_path, frame):
    bag = write_bag(tmp_path / "bag", frame, velocity=False)
    out = tmp_path / "check.json"
    assert main(["check", "--problem", str(bag_problem(tmp_path)), "--data", str(bag), "--json", str(out)]) == 0
    trial = json.loads(out.read_text())["trials"][0]
    assert 0.85 * len(frame) < trial["samples"] < len(frame) and "estimated" in trial["derivatives"]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"joints": '["shoulder", "wrist"]'}, ["'wrist'", "rail, shoulder, elbow"]),
        ({"topic": "/robot/joint_states"}, ["/robot/joint_states", "/joint_states"]),
        ({"joints": "[]"}, ["ros_joints"]),
    ],
)
def test_a_bag_that_does_not_match_the_problem_exits_2_naming_it(tmp_path, frame, capsys, change, words):
    bag = write_bag(tmp_path / "bag", frame.iloc[:50])
    out = tmp_path / "check.json"
    assert (
        main(["check", "--problem", str(bag_problem(tmp_path, **change)), "--data", str(bag), "--json", str(out)]) == 2
    )
    err = capsys.readouterr().err
    assert all(w in err for w in words), err
    assert not out.exists()


def test_a_broken_bag_exits_2(tmp_path, frame, capsys):
    bag = write_bag(tmp_path / "bag", frame.iloc[:50])
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [not, a, bag", encoding="utf-8")
    assert main(["check", "--problem", str(bag_problem(tmp_path)), "--data", str(bag)]) == 2
    assert "cannot read the ROS bag" in capsys.readouterr().err
    lone = tmp_path / "lone.mcap"
    lone.write_bytes(b"\x89MCAP0\r\n")
    assert main(["check", "--problem", str(bag_problem(tmp_path)), "--data", str(lone)]) == 2
    assert "metadata.yaml" in capsys.readouterr().err


@pytest.mark.parametrize("joints", ['["shoulder"]', '["shoulder", "shoulder"]', '["shoulder", 3]'])
def test_ros_joints_must_name_each_joint_once(tmp_path, capsys, joints):
    assert main(["check", "--problem", str(bag_problem(tmp_path, joints=joints))]) == 2
    assert "ros_joints" in capsys.readouterr().err
