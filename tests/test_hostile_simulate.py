"""Hostile input, third round (issue 32), on simulate, diagnose and calibrate: each case exits 2 naming the culprit,
without a traceback or a hang, writes nothing, and any JSON written is strict."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_opt.cli import main

ROOT = Path(__file__).resolve().parents[1]
TUDOR = ROOT / "problems" / "tudor_2dof.toml"


def _refused(args: list[str], capsys, folder: Path, *words: str) -> str:
    """`ident-opt args` exits 2, names every word, prints no traceback and leaves `folder` empty."""
    t0 = time.perf_counter()
    assert main(args) == 2
    assert time.perf_counter() - t0 < 60, "refused, not after minutes of work"
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for word in words:
        assert word in err, (word, err)
    assert not list(folder.iterdir()), "nothing written"
    return err


@pytest.mark.parametrize(
    "effect, words",
    [
        ("elasticity:frequency_hz=1e9", ["frequency_hz", "at most 500"]),
        ("payload:mass=1e300", ["mass", "at most 1000"]),
        ("payload:scale=1e300", ["scale", "at most 1000"]),
        ("load_friction:coefficient=[1e9,1e9]", ["coefficient", "at most 0.9"]),
    ],
)
def test_magnitudes_beyond_the_simulators_bounds_are_refused(tmp_path, capsys, effect, words):
    out = tmp_path / "out"
    out.mkdir()
    args = ["simulate", "--problem", str(TUDOR), "--out", str(out / "t.csv"), "--duration", "1", "--effect", effect]
    _refused(args, capsys, out, effect, *words)


def test_a_trajectory_file_with_huge_values_is_refused_naming_the_cell(tmp_path, capsys):
    t = np.arange(0.0, 2.0, 0.01)
    frame = pd.DataFrame({c: np.zeros_like(t) for c in ("q1", "q2", "dq1", "dq2", "ddq1", "ddq2")})
    frame.insert(0, "t", t)
    frame.loc[50, "q2"] = 1e200
    path = tmp_path / "huge.csv"
    frame.to_csv(path, index=False)
    out = tmp_path / "out"
    out.mkdir()
    args = ["simulate", "--problem", str(TUDOR), "--out", str(out / "t.csv"), "--duration", "1.5"]
    _refused([*args, "--trajectory-file", str(path)], capsys, out, str(path), "column q2", "data row 51")


def test_currents_without_torque_constants_name_the_joint(tmp_path, capsys):
    """A planar arm given by its inertials, without torque constants: --current names the joint's table (was a
    TypeError)."""
    text = (ROOT / "problems" / "dfki_c0.toml").read_text()
    text = "\n".join(line for line in text.splitlines() if not line.startswith(("torque_constant", "gear_ratio")))
    problem = tmp_path / "p.toml"
    problem.write_text(
        text.replace('"../data/', f'"{ROOT.as_posix()}/data/').replace('dir = "../results/dfki"', 'dir = "out"')
    )
    out = tmp_path / "out"
    out.mkdir()
    args = ["simulate", "--problem", str(problem), "--out", str(out / "t.csv"), "--duration", "1", "--current"]
    _refused(args, capsys, out, "[robot.joint1]", "torque_constant")


def test_diagnose_refuses_an_arm_that_never_moves(tmp_path, capsys):
    rows = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[:3000]
    fixed = {2: "1.0", 3: "0.5", 5: "0", 6: "0", 15: "0", 16: "0"}  # q1, q2 held, dq and ddq 0 (tudor_2dof's columns)
    still = [",".join(fixed.get(i, c) for i, c in enumerate(row.split(","))) for row in rows]
    data = tmp_path / "still.csv"
    data.write_text("\n".join(still) + "\n")
    out = tmp_path / "out"
    out.mkdir()
    args = ["diagnose", "--problem", str(TUDOR), "--data", str(data), "--out", str(out / "d"), "--no-progress"]
    _refused(args, capsys, out, "joint1 (q1)", "never move")


def test_calibrate_names_an_unknown_channel(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    args = ["calibrate", "--problem", str(ROOT / "problems" / "tudor_sim.toml"), "--real", str(TUDOR)]
    _refused([*args, "--channel", "nosuch", "--out", str(out / "c")], capsys, out, "--channel 'nosuch'", "col10")
