"""Column mapping with conversions, files with standard names read by name, and the loader's checks on
duplicate headers, time units and estimated derivatives (the data format's mapping; hostile-input
reproducers 11 and 12)."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.problem import DataSpec, load_problem

from .conftest import kept
from .test_data import minimal_problem, trial_frame


def test_conversion_offset_and_scale_from_the_problem_file(tmp_path):
    # A robot whose zero hangs down and logs degrees with the opposite sign on joint 2.
    frame = trial_frame()
    foreign = frame.rename(columns={"q1": "pos1", "q2": "pos2"})
    foreign["pos1"] = frame["q1"] + np.pi / 2
    foreign["pos2"] = -np.degrees(frame["q2"])
    path = tmp_path / "foreign.csv"
    foreign.to_csv(path, index=False)
    problem = load_problem(
        minimal_problem(
            tmp_path,
            '\n[data.columns]\nq1 = { column = "pos1", offset = -1.5707963267948966 }\n'
            f'q2 = {{ column = "pos2", scale = {-np.pi / 180!r} }}\n',
        )
    )
    assert problem.data.conversions == {"q1": (1.0, -np.pi / 2), "q2": (-np.pi / 180, 0.0)}
    data = load_dataset(path, problem.data, problem.robot)
    assert np.allclose(data.q, kept(frame, data)[["q1", "q2"]].to_numpy(), atol=1e-12)


def test_conversion_of_a_torque_column_and_zero_scale_refused(tmp_path):
    frame = trial_frame()
    path = tmp_path / "mNm.csv"
    frame.assign(tau1=1e3 * frame["tau1"]).to_csv(path, index=False)
    spec = DataSpec(columns={"tau1": "tau1"}, conversions={"tau1": (1e-3, 0.0)}, standard_by_name=False)
    robot = load_problem(minimal_problem(tmp_path)).robot
    data = load_dataset(path, spec, robot)
    assert np.allclose(data.tau[:, 0], kept(frame, data)["tau1"], atol=1e-12)
    bad = minimal_problem(tmp_path, '\n[data.columns]\nq1 = { column = "q1", scale = 0.0 }\n')
    with pytest.raises(InputError, match=r"'scale'.*must not be 0"):
        load_problem(bad)


def test_standard_file_is_read_by_name_despite_a_foreign_mapping(tmp_path, physical_problem):
    # The MERIt problem maps 0-based indices of a header-less export; a simulator CSV with the standard
    # names must still be read by name (unless [data] standard_by_name = false).
    frame = trial_frame()
    path = tmp_path / "standard.csv"
    frame.to_csv(path, index=False)
    data = load_dataset(path, physical_problem.data, physical_problem.robot)
    assert np.allclose(data.q, kept(frame, data)[["q1", "q2"]].to_numpy())
    strict = DataSpec(header=False, columns=dict(physical_problem.data.columns), standard_by_name=False)
    with pytest.raises(InputError):
        load_dataset(path, strict, physical_problem.robot)


def test_duplicate_column_names_are_refused(tmp_path, capsys):
    # Reproducer 11: `t,q1,...,i2,q1` used to be accepted, the second q1 silently renamed q1.1.
    frame = trial_frame()
    path = tmp_path / "dup.csv"
    text = frame.to_csv(index=False).splitlines()
    rows = [text[0] + ",q1"] + [line + ",0.5" for line in text[1:]]
    path.write_text("\n".join(rows) + "\n")
    problem = minimal_problem(tmp_path)
    with pytest.raises(InputError, match="'q1' appears twice"):
        load_dataset(path, DataSpec(), load_problem(problem).robot)
    assert main(["check", "--problem", str(problem), "--data", str(path)]) == 2
    assert "appears twice" in capsys.readouterr().err


def test_time_in_the_wrong_unit_is_refused(tmp_path, capsys):
    # Reproducer 12: time stamps x 1e-6 gave "0.00 s at 1e+08 Hz" and velocities ~1e-16, exit 0.
    frame = trial_frame()
    path = tmp_path / "us.csv"
    frame.assign(t=frame["t"] * 1e-6).to_csv(path, index=False)
    problem = minimal_problem(tmp_path)
    with pytest.raises(InputError, match=r"column 't'.*sampling rate.*seconds"):
        load_dataset(path, DataSpec(), load_problem(problem).robot)
    assert main(["check", "--problem", str(problem), "--data", str(path)]) == 2
    # ... and with --allow-implausible the user may still proceed (its unsettled ends left out, as any trial's).
    data = load_dataset(path, DataSpec(), load_problem(problem).robot, allow_implausible=True)
    assert 0.9 * len(frame) < data.n <= len(frame)


def test_estimated_derivatives_are_checked(tmp_path):
    # Milliseconds logged as seconds: a plausible rate is impossible to tell, but the accelerations are not.
    frame = trial_frame(n=400, rate=1000.0)
    frame["q1"] = 50.0 * np.sin(2 * np.pi * 40 * frame["t"])
    path = tmp_path / "fast.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(InputError, match=r"'dq1'.*estimated from q and t"):
        load_dataset(path, DataSpec(derivative_cutoff_hz=200.0), load_problem(minimal_problem(tmp_path)).robot)


def test_conversion_on_a_standard_named_file_is_applied(tmp_path):
    # A mapping that names this file's own columns is for this file: its conversion must not be skipped.
    frame = trial_frame()
    path = tmp_path / "deg.csv"
    frame.assign(q2=np.degrees(frame["q2"])).to_csv(path, index=False)
    spec = DataSpec(columns={"q2": "q2"}, conversions={"q2": (np.pi / 180, 0.0)})
    data = load_dataset(path, spec, load_problem(minimal_problem(tmp_path)).robot)
    assert np.allclose(data.q[:, 1], kept(frame, data)["q2"], atol=1e-12)


def test_logged_accelerations_are_kept_when_only_velocities_are_missing(tmp_path):
    frame = trial_frame()
    frame["ddq1"], frame["ddq2"] = 0.123, -0.456  # deliberately not the derivative of q
    path = tmp_path / "acc.csv"
    frame.to_csv(path, index=False)
    data = load_dataset(path, DataSpec(), load_problem(minimal_problem(tmp_path)).robot)
    assert np.all(data.ddq[:, 0] == 0.123) and np.all(data.ddq[:, 1] == -0.456)
    assert "accelerations as logged" in data.derivatives
