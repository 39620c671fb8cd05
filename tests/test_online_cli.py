"""`ident-opt online`: the --json contract of docs/cli.md, the outputs, bad usage → exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ident_opt.cli import main

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "tudor_2dof.toml"
PI = ["a1", "a2", "a3", "b1", "b2", "fv1", "fv2", "fc1", "fc2"]
KEYS = ["rr", "rr+gmr", "dm", "dm+gmr", "pbr", "pbr+gmr", "cpbr", "cpbr+gmr"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("online_cli")
    data = tmp / "exp1_small.csv"
    data.write_text("\n".join((ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[:3000]) + "\n")
    held = tmp / "exp2_small.csv"  # given with --test-data, which online does not score: a warning says so
    held.write_text("\n".join((ROOT / "data" / "merit" / "exp2.csv").read_text().splitlines()[:1500]) + "\n")
    out = tmp / "out"
    code = main(
        [
            "online",
            "--problem",
            str(PROBLEM),
            "--data",
            str(data),
            "--test-data",
            str(held),
            "--out",
            str(out),
            "--json",
            str(tmp / "o.json"),
            "--components",
            "2",
            "--checks",
            "4",
        ]
    )
    return code, json.loads((tmp / "o.json").read_text()), out


def test_json_contract(run):
    code, js, _ = run
    assert code == 0
    assert list(js["parameters"]["initial"]) == PI and list(js["parameters"]["final"]) == PI
    for which in ("online", "frozen"):
        for metric in ("rmse", "nmse", "nmse_range"):
            block = js["metrics"][which][metric]
            assert set(KEYS) <= set(block)
            assert all(len(v) == 2 and all(np.isfinite(v)) for v in block.values())
    assert js["updates_per_second"] > 0
    assert isinstance(js["batch_check"], float) and js["batch_check"] <= 1e-9
    check = js["batch_check_detail"]
    assert check["max_relative_difference"] == js["batch_check"] and len(check["steps"]) == 5
    assert check["pbr_vs_lsq_linear"] <= 1e-9
    assert set(check["by_model"]) == {"rr", "pbr", "cpbr"}


def test_a_held_out_trial_it_does_not_score_is_a_warning(run):
    """online replays its own trial's later part: a --test-data trial is named as unused in the JSON warnings
    and in online.md, not read and silently dropped."""
    _, js, out = run
    codes = [w["code"] for w in js["warnings"]]
    assert codes.count("test_data_unused") == 1
    message = next(w["message"] for w in js["warnings"] if w["code"] == "test_data_unused")
    assert "exp2_small.csv" in message and "--data" in message
    assert "test_data_unused" in (out / "online.md").read_text()


def test_online_differs_from_frozen_only_where_models_adapt(run):
    _, js, _ = run
    on, fr = js["metrics"]["online"]["nmse"], js["metrics"]["frozen"]["nmse"]
    # DM is fixed, and so is its GMR (batch vs one-sample evaluation: rounding only).
    np.testing.assert_allclose(on["dm"], fr["dm"], rtol=1e-12)
    np.testing.assert_allclose(on["dm+gmr"], fr["dm+gmr"], rtol=1e-12)
    assert on["pbr"] != fr["pbr"] and on["rr"] != fr["rr"]
    assert js["parameters"]["initial"] != js["parameters"]["final"]


def test_outputs_written(run):
    _, _, out = run
    for name in ("online.md", "online_metrics.csv", "online_parameters.csv", "online_trajectories.png", "online.json"):
        assert (out / name).stat().st_size > 0
    assert "| model |" in (out / "online.md").read_text() or "model" in (out / "online.md").read_text()


@pytest.mark.parametrize(
    "argv",
    [
        ["--snapshot-every", "-1"],
        ["--stream", "--model", "gp"],
        ["--checks", "-2"],
        ["--stream", "--model", "pbr+nn"],
        ["--consistent-every", "0"],
    ],
)
def test_bad_usage_exit_2(argv, capsys):
    assert main(["online", "--problem", str(PROBLEM), *argv]) == 2
    assert "error" in capsys.readouterr().err
