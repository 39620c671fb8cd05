"""`ident-opt detect` end to end (`docs/contacts.md`, the spec's "detect"): simulated trials written by `ident-opt
simulate` (with and without a `contact`), the CSV's columns exactly `t, alarm, tau_ext1..n`, the JSON's keys, the
alarm over the push, no alarm on a contact-free trial, bad input refused with exit 2 naming the culprit."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import ident_opt as iopt
from ident_opt.cli import main
from ident_opt.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PLANAR = str(ROOT / "problems" / "tudor_sim.toml")
PUSH = "contact:joint=2,torque=3,start=8,duration=1.0"


def _no_nan(constant: str):
    raise AssertionError(f"non-finite JSON value {constant}")


@pytest.fixture(scope="module")
def trials(tmp_path_factory) -> dict[str, str]:
    """Three contact-free trials (two calibrate, one is watched) and one pushed on joint 2 at 8–9 s, 20 s each."""
    folder = tmp_path_factory.mktemp("detect_trials")
    effects = list(iopt.load_problem(PLANAR).simulate.effects)
    out = {}
    for name, seed, extra in (("free1", 31, []), ("free2", 32, []), ("free3", 33, []), ("pushed", 34, [PUSH])):
        path = folder / f"{name}.csv"
        flags = [f"--effect={e}" for e in [*effects, *extra]]
        assert (
            main(["simulate", "--problem", PLANAR, "--out", str(path), "--seed", str(seed), "--duration", "20", *flags])
            == 0
        )
        out[name] = str(path)
    return out


@pytest.fixture(scope="module")
def detected(trials, tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("detect_out")
    code = main(
        [
            "detect",
            "--problem",
            PLANAR,
            "--calibrate",
            trials["free1"],
            "--calibrate",
            trials["free2"],
            "--data",
            trials["pushed"],
            "--data",
            trials["free3"],
            "--out",
            str(out),
            "--json",
            str(out / "detect.json"),
        ]
    )
    assert code == 0
    return out, json.loads((out / "detect.json").read_text(), parse_constant=_no_nan)


def test_csv_columns_and_alarm_over_the_push(detected):
    out, _ = detected
    frame = pd.read_csv(out / "pushed.csv")
    assert list(frame.columns) == ["t", "alarm", "tau_ext1", "tau_ext2"]
    assert len(frame) == 2000 and set(frame["alarm"].unique()) <= {0, 1}
    inside = (frame["t"] > 8.3) & (frame["t"] < 8.9)
    assert frame.loc[inside, "alarm"].all() and frame.loc[frame["t"] < 7.9, "alarm"].sum() == 0
    # τ_ext reads the push [N m], less what a resting joint's friction (≈ 1.3 N m in this plant) holds of it
    assert 1.5 < frame.loc[inside, "tau_ext2"].mean() < 3.5
    free = pd.read_csv(out / "free3.csv")
    assert free["alarm"].sum() == 0
    assert (out / "pushed.png").stat().st_size > 0 and (out / "free3.png").stat().st_size > 0


def test_json_keys(detected, trials):
    _, payload = detected
    assert {"thresholds", "persistence", "calibration", "trials", "estimator", "warnings"} <= set(payload)
    assert payload["estimator"] == "constrained" and payload["persistence"] >= 2
    assert [t["joint"] for t in payload["thresholds"]] == [1, 2]
    assert all(t["moving"] > 0 and t["resting"] > 0 for t in payload["thresholds"])
    assert [c["source"].endswith(n) for c, n in zip(payload["calibration"], ("free1.csv", "free2.csv"))] == [True] * 2
    assert all(c["false_alarms_per_minute"] >= 0 for c in payload["calibration"])
    pushed, free = payload["trials"]
    assert len(pushed["alarms"]) == 1 and free["alarms"] == []
    alarm = pushed["alarms"][0]
    assert set(alarm) == {"start", "end", "joint", "peak"} and alarm["joint"] == 2
    assert 8.0 <= alarm["start"] <= 8.3 and 8.9 <= alarm["end"] <= 9.3 and alarm["peak"] > 1.5


def test_bad_input_exit_2(trials, tmp_path, capsys):
    missing = str(tmp_path / "nope.csv")
    assert main(["detect", "--problem", PLANAR, "--data", missing, "--out", str(tmp_path / "o")]) == 2
    assert "nope.csv" in capsys.readouterr().err
    assert (
        main(
            [
                "detect",
                "--problem",
                PLANAR,
                "--data",
                trials["free3"],
                "--calibrate",
                missing,
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert "nope.csv" in capsys.readouterr().err
    args = ["detect", "--problem", PLANAR, "--data", trials["free3"], "--out", str(tmp_path / "o")]
    assert main([*args, "--margin", "0.5"]) == 2 and "margin" in capsys.readouterr().err
    assert main([*args, "--estimator", "magic"]) == 2 and "magic" in capsys.readouterr().err
    assert main(["detect", "--problem", PLANAR, "--out", str(tmp_path / "o")]) == 2  # --data is required


def test_api_detect_types():
    problem = iopt.load_problem(PLANAR)
    with pytest.raises(InputError, match="training"):
        iopt.detect(problem, [], calibration="free.csv")
    with pytest.raises(InputError, match="margin"):
        iopt.detect(problem, [], margin=float("nan"))
    with pytest.raises(InputError, match="problem"):
        iopt.detect("problems/tudor_sim.toml", [])
    assert np.isfinite(iopt.Thresholds((50.0,), (1.0,), (1.0,), (0.1,), 3, 2.0, 0.01).limits(np.zeros(1))).all()


def test_a_trial_named_like_mathematics_is_written_as_text(trials, tmp_path):
    """matplotlib reads "$…$" in a title as mathematics and fails on `$x^$`: a trial so named is text in its
    figure's title (`report.figures.text`), and the run writes its figure and page."""
    named = tmp_path / "$x^$.csv"
    shutil.copyfile(trials["pushed"], named)
    out = tmp_path / "o"
    argv = ["detect", "--problem", PLANAR, "--calibrate", trials["free1"], "--data", str(named), "--out", str(out)]
    assert main(argv) == 0
    assert (out / "$x^$.png").is_file() and "$x^$" in (out / "index.html").read_text()
