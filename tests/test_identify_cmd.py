"""End to end: `ident-opt identify` on two short simulated trials writes every table, figure and the JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from ident_opt.cli import main
from ident_opt.problem import load_problem
from ident_opt.simulator.trial import simulate_trial

REPO = Path(__file__).resolve().parents[1]
MODELS = {"rr", "dm", "dm_physical", "pbr", "cpbr"}
TABLES = (
    "identify_reproduction",
    "identify_seeds",
    "identify_parameters",
    "identify_coverage",
    "identify_metrics",
    "identify_ridge",
)
FIGURES = (
    "torque_j1",
    "torque_j2",
    "error_j1",
    "error_j2",
    "parity",
    "interval_pbr",
    "seeds",
    "cross_trial_j1",
    "cross_trial_j2",
    "cross_trial_interval_pbr",
)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("identify")
    source = (REPO / "problems" / "tudor_2dof.toml").read_text(encoding="utf-8")
    robot_part = source.split("[data]")[0].split("# The real MERIt")[0]
    problem_file = tmp / "sim.toml"
    problem_file.write_text(
        robot_part + "\n[split]\nseeds = [0, 1]\n\n[residual]\ncandidates = [1, 2, 4]\nmax_train_samples = 1500\n",
        encoding="utf-8",
    )
    robot = load_problem(problem_file).robot
    trials = []
    for seed in (1, 2):
        sim = simulate_trial(
            robot, duration=15.0, seed=seed, progress=False, effects=["elasticity:joint=2,frequency_hz=3"]
        )
        trials.append(sim.write(tmp / f"trial{seed}.csv"))
    out = tmp / "results"
    argv = [
        "identify",
        "--problem",
        str(problem_file),
        "--data",
        str(trials[0]),
        "--test-data",
        str(trials[1]),
        "--out",
        str(out),
        "--json",
        str(out / "identify.json"),
    ]
    return main(argv), out


def test_exit_zero_and_every_file_written(run):
    status, out = run
    assert status == 0
    for name in TABLES:
        assert (out / f"{name}.md").stat().st_size > 0
        assert (out / f"{name}.csv").stat().st_size > 0
    for name in FIGURES:
        assert (out / "figures" / f"identify_{name}.png").stat().st_size > 1000
    readme = (out / "README.md").read_text(encoding="utf-8")
    for name in FIGURES:  # every figure is shown in the README
        assert f"figures/identify_{name}.png" in readme


def test_tables_parse_and_numbers_are_finite(run):
    _, out = run
    for name in TABLES:
        frame = pd.read_csv(out / f"{name}.csv")
        numbers = frame.select_dtypes("number")
        assert len(frame) > 0 and numbers.shape[1] > 0
        ours = numbers[[c for c in numbers.columns if not c.startswith("paper")]]
        if name == "identify_parameters":  # parameters an estimator does not have (ia2 of OLS) are blank
            ours = ours[[c for c in ours.columns if c.startswith(("ols", "constrained"))]].dropna(how="all")
        assert ours.notna().all().all(), name
        assert all(math.isfinite(v) for v in numbers.to_numpy().ravel() if v == v)
    metrics = pd.read_csv(out / "identify_metrics.csv")
    assert set(metrics["protocol"]) == {"paper", "chronological", "cross_trial"}
    assert set(metrics["model"]) == MODELS | {k + "+gmr" for k in MODELS}


def test_json_follows_the_spec(run):
    _, out = run
    payload = json.loads((out / "identify.json").read_text(encoding="utf-8"))
    for est in ("datasheet", "ols", "constrained"):
        assert {"a1", "a2", "a3", "b1", "b2", "fv1", "fv2", "fc1", "fc2"} <= set(payload["parameters"][est])
    for protocol in ("paper", "chronological", "cross_trial"):
        block = payload["metrics"][protocol]
        for metric in ("rmse", "nmse", "nmse_range"):
            assert set(block[metric]) == MODELS | {k + "+gmr" for k in MODELS}
            assert all(len(v) == 2 and all(math.isfinite(x) for x in v) for v in block[metric].values())
    assert payload["min_mass_eigenvalue"]["constrained"] > 0


def test_bad_problem_is_exit_2(tmp_path, capsys):
    assert main(["identify", "--problem", str(tmp_path / "missing.toml")]) == 2
    assert "not found" in capsys.readouterr().err
