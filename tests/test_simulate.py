"""The simulator: known truth recovered exactly, the API, the effect syntax and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PlanarArm
from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.effects import BACKGROUND
from ident_opt.errors import InputError
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem import DataSpec, load_problem
from ident_opt.simulator import CATALOGUE, measurement, parse_effect, simulate_trial

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "tudor_2dof.toml"
MODEL = PlanarArm(("armature",))


@pytest.fixture(scope="module")
def robot():
    return load_problem(PROBLEM).robot


def ols(trial):
    d = trial.dataset()
    return solve_ols(Stats.from_data(MODEL, d.q, d.dq, d.ddq, d.tau))


@pytest.mark.parametrize("trajectory", ["tud01", "fourier"])
def test_rigid_noise_free_trial_gives_back_the_datasheet_pi(robot, trajectory):
    trial = simulate_trial(
        robot, trajectory=trajectory, duration=8.0, noise=False, exact_derivatives=True, progress=False
    )
    truth = MODEL.vector(trial.truth["pi"])
    np.testing.assert_allclose(truth, MODEL.vector(datasheet_pi(robot, "physical")), rtol=0, atol=0)
    np.testing.assert_allclose(ols(trial), truth, rtol=1e-6)


def test_same_seed_same_trial_other_seed_other_trial(robot):
    a = simulate_trial(robot, duration=3.0, seed=4, progress=False)
    b = simulate_trial(robot, duration=3.0, seed=4, progress=False)
    c = simulate_trial(robot, duration=3.0, seed=5, progress=False)
    pd.testing.assert_frame_equal(a.frame, b.frame)
    assert not np.allclose(a.frame["tau1"], c.frame["tau1"])


def test_frame_has_the_data_format_columns_and_rate(robot):
    trial = simulate_trial(robot, duration=2.0, rate_hz=1000.0, output="current", progress=False)
    f = trial.frame
    for col in ("t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "i1", "i2"):
        assert col in f
    assert "tau1" not in f
    assert len(f) == 2000 and np.allclose(np.diff(f["t"]), 1e-3)
    k = np.array([j.current_to_torque for j in robot.joints])
    torque = simulate_trial(robot, duration=2.0, rate_hz=1000.0, progress=False)
    np.testing.assert_allclose(trial.dataset().tau, torque.frame[["tau1", "tau2"]].to_numpy(), rtol=1e-12)
    np.testing.assert_allclose(f[["i1", "i2"]].to_numpy() * k, trial.dataset().tau, rtol=1e-12)


def test_parse_effect_reads_scalars_and_pairs():
    assert parse_effect("elasticity:joint=2,frequency_hz=8") == (
        "elasticity",
        {"joint": 2, "frequency_hz": 8.0},
    )
    assert parse_effect("asymmetric_coulomb:positive=[0.8,0.4],negative=[0.2, 0.6]") == (
        "asymmetric_coulomb",
        {"positive": (0.8, 0.4), "negative": (0.2, 0.6)},
    )
    assert parse_effect("payload") == ("payload", {})


@pytest.mark.parametrize(
    "text, words",
    [
        ("wind", "unknown effect 'wind'"),
        ("payload:mas=1", "unknown key 'mas'"),
        ("payload:mass=heavy", "must be a number"),
        ("payload:mass=-1", "must be >= 0"),
        ("elasticity:joint=3", "must be 1 or 2"),
        ("elasticity:frequency_hz=0", "must be > 0"),
        ("armature:inertia=[0.1]", "pair"),
        ("delay:seconds", "key=value"),
    ],
)
def test_bad_effect_text_is_an_input_error_naming_it(robot, text, words):
    with pytest.raises(InputError, match=None) as info:
        simulate_trial(robot, duration=1.0, effects=[text], progress=False)
    assert words in str(info.value) and text in str(info.value)


def test_bad_settings_are_input_errors(robot):
    bad = (
        {"rate_hz": 300.0},
        {"rate_hz": float("nan")},
        {"rate_hz": 0.0},
        {"rate_hz": 20000.0},
        {"output": "volts"},
        {"trajectory": "zigzag"},
        {"duration": 0.1},
        {"duration": float("inf")},
        {"seed": -1},
        {"seed": 1.5},
        {"bandwidth_hz": 0.5},
        {"bandwidth_hz": float("nan")},
        {"noise_scale": -1.0},
        {"noise_scale": float("inf")},
        {"noise_scale": (1.0, 2.0, 3.0)},
        {"noise_scale": (1.0, -1.0)},
    )
    for kwargs in bad:
        with pytest.raises(InputError):
            simulate_trial(robot, progress=False, **{"duration": 1.0, **kwargs})


def test_noise_scale_multiplies_the_torque_noise(robot):
    # Same seed: the trajectory, the loop and the noise draws are the same; only σ differs.
    runs = {s: simulate_trial(robot, duration=4.0, seed=3, noise_scale=s, progress=False) for s in (0.0, 1.0, 3.0)}
    clean = runs[0.0].frame[["tau1", "tau2"]].to_numpy()
    noise = {s: runs[s].frame[["tau1", "tau2"]].to_numpy() - clean for s in (1.0, 3.0)}
    np.testing.assert_allclose(noise[3.0], 3.0 * noise[1.0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(noise[1.0].std(axis=0), measurement.TORQUE_NOISE, rtol=0.1)
    assert runs[3.0].truth["measurement"]["torque_noise_std"] == pytest.approx(
        [3 * s for s in measurement.TORQUE_NOISE]
    )
    # One factor per joint: each joint's noise scaled by its own.
    each = simulate_trial(robot, duration=4.0, seed=3, noise_scale=(2.0, 5.0), progress=False)
    np.testing.assert_allclose(
        each.frame[["tau1", "tau2"]].to_numpy() - clean, noise[1.0] * [2.0, 5.0], rtol=1e-9, atol=1e-12
    )
    assert each.truth["settings"]["noise_scale"] == [2.0, 5.0]
    assert each.truth["measurement"]["torque_noise_std"] == pytest.approx(
        [2 * measurement.TORQUE_NOISE[0], 5 * measurement.TORQUE_NOISE[1]]
    )


def test_bandwidth_sets_the_controller_gains_and_the_tracking(robot):
    # A payload the controller does not know: only the PD corrects it, the stiffer the loop the closer it tracks.
    trials = {
        bw: simulate_trial(robot, duration=6.0, seed=2, bandwidth_hz=bw, effects=["payload:mass=0.3"], progress=False)
        for bw in (3.0, 12.0)
    }
    gains = {bw: t.truth["controller"] for bw, t in trials.items()}
    assert gains[12.0]["bandwidth_hz"] == 12.0
    # Kp = J ω², Kd = 2 J ω: a 4x bandwidth is 16x the stiffness and 4x the damping.
    np.testing.assert_allclose(np.array(gains[12.0]["kp"]) / gains[3.0]["kp"], 16.0)
    np.testing.assert_allclose(np.array(gains[12.0]["kd"]) / gains[3.0]["kd"], 4.0)
    rms = {bw: np.array(t.truth["tracking"]["rms_error"]) for bw, t in trials.items()}
    assert np.all(rms[12.0] < 0.5 * rms[3.0])


def test_cli_writes_a_trial_the_loader_reads_back(tmp_path, robot):
    out = tmp_path / "trial.csv"
    rc = main(
        [
            "simulate",
            "--problem",
            str(PROBLEM),
            "--out",
            str(out),
            "--duration",
            "3",
            "--seed",
            "2",
            "--effect",
            "elasticity:joint=2,frequency_hz=8",
            "--effect",
            "payload:mass=0.1",
        ]
    )
    assert rc == 0
    truth = json.loads(out.with_name("trial.truth.json").read_text())
    assert truth["effects"]["elasticity"]["joint"] == 2 and truth["effects"]["elasticity"]["frequency_hz"] == 8.0
    assert truth["effects"]["payload"] == {"mass": 0.1}
    data = load_dataset(out, DataSpec(), robot)
    assert data.n == 300 and data.derivatives == "given"
    np.testing.assert_allclose(data.tau, pd.read_csv(out)[["tau1", "tau2"]].to_numpy())


def test_cli_bad_effect_exits_2_without_traceback(tmp_path, capsys):
    rc = main(["simulate", "--problem", str(PROBLEM), "--out", str(tmp_path / "x.csv"), "--effect", "warp:x=1"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "unknown effect 'warp'" in err and "Traceback" not in err
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize(("flag", "value"), [("--bandwidth", "0"), ("--bandwidth", "100"), ("--noise-scale", "-2")])
def test_cli_bad_bandwidth_or_noise_scale_exits_2_naming_the_flag(tmp_path, capsys, flag, value):
    rc = main(["simulate", "--problem", str(PROBLEM), "--out", str(tmp_path / "x.csv"), flag, value])
    assert rc == 2
    err = capsys.readouterr().err
    assert flag in err and "Traceback" not in err
    assert not (tmp_path / "x.csv").exists()


def test_cli_bandwidth_and_noise_scale_reach_the_truth(tmp_path):
    out = tmp_path / "t.csv"
    args = ["simulate", "--problem", str(PROBLEM), "--out", str(out), "--duration", "2"]
    assert main([*args, "--bandwidth", "10", "--noise-scale", "2"]) == 0
    truth = json.loads(out.with_name("t.truth.json").read_text())
    assert truth["settings"]["bandwidth_hz"] == 10.0 and truth["controller"]["bandwidth_hz"] == 10.0
    assert truth["settings"]["noise_scale"] == 2.0


def test_command_line_ranges_match_the_simulator():
    from ident_opt.arguments import RANGES
    from ident_opt.simulator import trial

    assert RANGES[("simulate", "bandwidth")] == (trial.MIN_BANDWIDTH, trial.MAX_BANDWIDTH)
    assert RANGES[("simulate", "noise_scale")] == (0.0, trial.MAX_NOISE_SCALE)


def short_sim_problem(tmp_path, duration=3.0):
    text = (ROOT / "problems" / "tudor_sim.toml").read_text()
    path = tmp_path / "sim.toml"
    path.write_text(text.replace("duration = 80.0", f"duration = {duration}"))
    return load_problem(path)


def test_problem_trials_are_two_seeds_generated_once_and_cached(tmp_path, monkeypatch):
    from ident_opt.simulator import problem_trials

    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path / "cache"))
    problem = short_sim_problem(tmp_path)
    paths = problem_trials(problem)
    assert len(paths) == 2 and all(p.is_file() and p.parent == tmp_path / "cache" / "sim" for p in paths)
    truths = [json.loads(p.with_name(p.stem + ".truth.json").read_text()) for p in paths]
    assert [t["settings"]["seed"] for t in truths] == [problem.simulate.seed, problem.simulate.seed + 1]
    assert set(truths[0]["effects"]) == {"elasticity", "asymmetric_coulomb", "stribeck"}
    stamps = [p.stat().st_mtime_ns for p in paths]
    assert problem_trials(problem) == paths and [p.stat().st_mtime_ns for p in paths] == stamps
    (tmp_path / "other").mkdir()
    longer = problem_trials(short_sim_problem(tmp_path / "other", duration=4.0))
    assert set(longer).isdisjoint(paths)  # a changed setting never reuses a cached trial


def test_common_load_reads_the_simulated_trials_of_a_sim_problem(tmp_path, monkeypatch):
    from argparse import Namespace

    from ident_opt.commands.common import load

    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path / "cache"))
    problem = short_sim_problem(tmp_path)
    args = Namespace(problem=str(problem.path), data=None, allow_implausible=False, drop_invalid=False)
    loaded = load(args, "identify")
    assert len(loaded.trials) == 2 and loaded.train.n == 300
    assert not np.allclose(loaded.train.tau[:50], loaded.unseen.tau[:50])


def test_bad_simulate_settings_in_a_problem_file_name_the_file(tmp_path, monkeypatch):
    from ident_opt.simulator import problem_trials

    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path / "cache"))
    text = (ROOT / "problems" / "tudor_sim.toml").read_text().replace('"asymmetric_coulomb",', '"friction:x=1",')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        problem_trials(load_problem(path))
    assert str(path) in str(info.value) and "unknown effect 'friction'" in str(info.value)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=60))
def test_parse_effect_never_fails_with_anything_but_an_input_error(text):
    try:
        name, params = parse_effect(text)
    except InputError:
        return
    assert (name in CATALOGUE or name in BACKGROUND) and isinstance(params, dict)


def test_gzipped_output_is_written_compressed_and_read_back(tmp_path, robot):
    trial = simulate_trial(robot, duration=1.0, progress=False)
    path = trial.write(tmp_path / "t.csv.gz")
    assert path.read_bytes()[:2] == b"\x1f\x8b" and (tmp_path / "t.truth.json").is_file()
    assert load_dataset(path, DataSpec(), robot).n == 100
    with pytest.raises(InputError, match="name it"):
        trial.write(tmp_path / "t.txt")


def test_cli_current_output_is_read_back_as_the_same_torques(tmp_path, robot):
    out = tmp_path / "cur.csv"
    args = [
        "simulate",
        "--problem",
        str(PROBLEM),
        "--out",
        str(out),
        "--duration",
        "2",
        "--current",
        "--rate",
        "1000",
        "--no-noise",
        "--exact-derivatives",
        "--trajectory",
        "fourier",
        "--seed",
        "3",
    ]
    assert main(args) == 0
    data = load_dataset(out, DataSpec(), robot)
    same = simulate_trial(
        robot,
        duration=2.0,
        rate_hz=1000.0,
        noise=False,
        exact_derivatives=True,
        trajectory="fourier",
        seed=3,
        progress=False,
    )
    assert "i1" in pd.read_csv(out).columns and data.n == 2000
    np.testing.assert_allclose(data.tau, same.dataset().tau, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(data.ddq, same.dataset().ddq, rtol=1e-12, atol=1e-12)
