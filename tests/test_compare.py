"""`ident-opt compare` end to end on the real trials, its JSON shape, bad input, and the constraints study."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ident_opt import runs
from ident_opt.cli import main
from ident_opt.evaluation.constraints import constraints_study
from ident_opt.report.constraints import study_markdown

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"
PI = ["a1", "a2", "a3", "b1", "b2", "fv1", "fv2", "fc1", "fc2"]


@pytest.fixture(scope="module")
def compare_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("compare")
    status = main(
        [
            "compare",
            "--problem",
            str(PROBLEMS / "tudor_2dof.toml"),
            "--out",
            str(out),
            "--json",
            str(out / "compare.json"),
            "--no-progress",
        ]
    )
    return status, out, json.loads((out / "compare.json").read_text())


def test_compare_writes_its_files(compare_run):
    status, out, _ = compare_run
    assert status == 0
    for name in (
        "compare.md",
        "compare_parameters.csv",
        "compare_consistency.csv",
        "compare_metrics.csv",
        "compare_parameters.png",
        "compare_seeds.csv",
        "compare_seeds.png",
    ):
        assert (out / name).stat().st_size > 0, name
    text = (out / "compare.md").read_text()
    assert "mass_pd_q2_0" in text and "chronological" in text and "cross_trial" in text


def test_compare_json_shape(compare_run):
    _, _, payload = compare_run
    params = payload["parameters"]
    for key in ("datasheet", "ols", "constrained", "nlp_physical", "datasheet_paper", "datasheet_physical"):
        assert set(PI) <= set(params[key]), key
    assert "ia2" in params["datasheet"]  # the physical convention reports the joint-2 armature
    for protocol in ("paper", "chronological", "cross_trial"):
        for metric in ("rmse", "nmse", "nmse_range"):
            for key in ("ols", "constrained", "nlp_physical", "datasheet_physical"):
                values = payload["metrics"][protocol][metric][key]
                assert len(values) == 2 and all(np.isfinite(values))
    assert set(payload["standard_errors"]["ols"]) == set(PI)
    assert len(payload["seed_study"]["parameters"]["ols"]) == 10


def test_compare_on_real_data_ols_inconsistent_constrained_consistent(compare_run):
    _, _, payload = compare_run
    assert payload["parameters"]["ols"]["a3"] < 0
    assert not payload["consistency"]["ols"]["consistent"]
    for key in ("constrained", "nlp_physical"):
        assert payload["consistency"][key]["consistent"], key
    assert payload["consistency"]["constrained"]["active_constraints"]
    # The paper-protocol OLS on exp1, as measured independently: nmse ≈ 0.095 / 0.92.
    assert payload["metrics"]["paper"]["nmse"]["ols"] == pytest.approx([0.095, 0.92], abs=0.01)


@pytest.mark.parametrize(
    "argv",
    [
        ["--data", "/nonexistent/trial.csv"],
        ["--margin", "-1"],
        ["--extension", "magic"],
        ["--constraints-study", "0"],
    ],
)
def test_compare_bad_input_exits_2(argv, tmp_path, capsys):
    status = main(["compare", "--problem", str(PROBLEMS / "tudor_2dof.toml"), "--out", str(tmp_path), *argv])
    assert status == 2
    assert "Traceback" not in capsys.readouterr().err


def test_constraints_study_small(physical_problem):
    result = constraints_study(physical_problem.robot, 8, seed=1, progress=False)
    s = result.summary
    assert s["trials"] == 8 and s["constrained_inconsistent"] == 0
    rows = result.rows
    # With full rank and no active constraint the two fits coincide (rank-deficient data leave free
    # directions, along which the constrained fit may move off OLS's least-norm point at equal RSS).
    same = (rows["active"] == "") & (rows["rank"] == 10)
    assert same.any()
    assert (rows["err_ols"][same] == rows["err_constrained"][same]).all()
    assert (rows["constrained_min_eig"] >= 1e-6 * (1 - 1e-6)).all()
    assert "| OLS physically inconsistent |" in study_markdown(result)


def test_constraints_study_cli(tmp_path):
    status = main(
        [
            "compare",
            "--problem",
            str(PROBLEMS / "tudor_2dof.toml"),
            "--out",
            str(tmp_path),
            "--constraints-study",
            "4",
            "--no-progress",
            "--json",
            str(tmp_path / "s.json"),
        ]
    )
    assert status == 0
    assert (tmp_path / "constraints_study.md").exists()
    payload = json.loads((tmp_path / "s.json").read_text())
    assert payload["multisine"]["summary"]["trials"] == 4 and payload["simulator"]["summary"]["trials"] == 4
    assert payload["simulator"]["summary"]["constrained_inconsistent"] == 0


def test_identify_reports_the_standard_errors_compare_does_on_trials_with_different_cut_offs(tmp_path):
    """Two trials whose spectra give different derivative cut-offs (200 and 500 Hz logs of angles only): identify's
    whole-trial fits (`evaluation.identify.whole_trial_parameters`) carry the same standard errors as compare's for
    every estimator both run. identify used to fit a pool of the trials, which has no single cut-off, so it counted
    every sample as independent and its errors came out √(f_s / 2 f_c) too narrow."""
    from dataclasses import replace

    from ident_opt.data.loader import load_dataset
    from ident_opt.evaluation.compare import compare
    from ident_opt.evaluation.identify import whole_trial_parameters
    from ident_opt.problem import load_problem
    from ident_opt.simulator import simulate_trial

    from .conftest import PROBLEMS

    problem = load_problem(PROBLEMS / "tudor_2dof.toml")
    spec = replace(problem.data, header=True, columns={}, derivative_cutoff_hz="auto")
    trials = []
    for seed, rate in ((81, 200.0), (82, 500.0)):
        sim = simulate_trial(
            problem.robot, trajectory="fourier", duration=20.0, rate_hz=rate, seed=seed, progress=False
        )
        path = tmp_path / f"t{seed}.csv"
        sim.frame.drop(columns=["dq1", "dq2", "ddq1", "ddq2"]).to_csv(path, index=False)
        trials.append(load_dataset(path, spec, problem.robot))
    assert abs(trials[0].cutoff_hz - trials[1].cutoff_hz) > 1.0, "the two trials' cut-offs differ"
    compared = compare(replace(problem, data=spec), trials)
    assert compared.choice.factor == 1.0  # both studies then fit the trials as read
    _, errors, _ = whole_trial_parameters(replace(problem, data=spec), trials, compared.choice)
    for name, se in errors.items():
        theirs = compared.fits[name].se_dict()
        np.testing.assert_allclose([se[k] for k in se], [theirs[k] for k in se], rtol=1e-9, err_msg=name)


# ---------------------------------------------------------------------------------------------- --against
def _doctored(data: dict, tmp_path: Path, shifts: dict[str, float]) -> Path:
    """A copy of a compare JSON whose recommended fit has each parameter of `shifts` moved by that many of its own
    standard errors."""
    other = json.loads(json.dumps(data))
    fit = other["recommended"]
    for name, k in shifts.items():
        other["parameters"][fit][name] += k * other["standard_errors"][fit][name]
    path = tmp_path / "other.json"
    path.write_text(json.dumps(other))
    return path


def test_against_flags_exactly_the_parameters_moved_beyond_their_errors(compare_run, tmp_path):
    """z = d / √(se² + se_other²): moved by 10 of its standard errors, fc1 has z = −10/√2 and is flagged; moved by 2,
    fv2 has z = −2/√2 and is not; the rest are equal (z = 0); the held-out errors are the same run's (ratio 1)."""
    data = compare_run[2]
    this = runs.summarize(data, "this run")
    diff = runs.side_by_side(this, runs.read_run(_doctored(data, tmp_path, {"fc1": 10.0, "fv2": 2.0})))
    z = diff.parameters["z"]
    assert diff.beyond == ["fc1"] and z["fc1"] == pytest.approx(-10 / np.sqrt(2), rel=1e-12)
    assert z["fv2"] == pytest.approx(-2 / np.sqrt(2), rel=1e-12)
    assert (z.drop(["fc1", "fv2"]) == 0).all()
    assert len(diff.errors) and (diff.errors["ratio"] == 1).all()
    assert set(diff.errors["held_out"]) == set(data["metrics"]) & set(runs._side_by_side.PROTOCOLS)


def test_compare_against_another_run_end_to_end(compare_run, tmp_path, capsys):
    """The command: the same problem run again against a doctored copy of the first run's JSON writes the side by
    side (fc1 in bold, beyond), says it on the terminal, and adds `against` to its JSON; the fits are deterministic,
    so every other z is 0."""
    other = _doctored(compare_run[2], tmp_path, {"fc1": 10.0})
    out = tmp_path / "b"
    argv = ["compare", "--problem", str(PROBLEMS / "tudor_2dof.toml"), "--out", str(out), "--no-progress"]
    assert main([*argv, "--json", str(tmp_path / "b.json"), "--against", str(other)]) == 0
    data = json.loads((tmp_path / "b.json").read_text())
    assert data["against"]["beyond"] == ["fc1"] and data["against"]["estimator"] == compare_run[2]["recommended"]
    assert {r["parameter"]: r["z"] for r in data["against"]["parameters"]}["fv1"] == 0
    assert "| **fc1** |" in (out / "compare_against.md").read_text()
    page = (out / "index.html").read_text()  # the side by side on the folder's page too, its verdict first
    assert "<strong>fc1</strong>" in page and page.index("moved beyond their errors") < page.index("This run against")
    assert "1 of 9 parameters moved beyond their errors" in capsys.readouterr().out
    assert {"compare_against.md", "compare_against.csv", "compare_against_errors.csv"} <= set(data["files"])


@pytest.mark.parametrize(
    "content, named",
    [("not json", "cannot read the other run"), ('{"parameters": {"ols": {"a1": "x"}}, "recommended": "ols"}', "a1")],
)
def test_a_bad_other_run_is_exit_2_before_any_work(tmp_path, capsys, content, named):
    other = tmp_path / "other.json"
    other.write_text(content)
    argv = ["compare", "--problem", str(PROBLEMS / "tudor_2dof.toml"), "--out", str(tmp_path / "o"), "--no-progress"]
    assert main([*argv, "--against", str(other)]) == 2
    err = capsys.readouterr().err
    assert str(other) in err and named in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_the_other_run_is_an_input_never_overwritten(compare_run, tmp_path, capsys):
    other = tmp_path / "other.json"
    other.write_text(json.dumps(compare_run[2]))
    before = other.read_bytes()
    argv = ["compare", "--problem", str(PROBLEMS / "tudor_2dof.toml"), "--out", str(tmp_path / "o"), "--no-progress"]
    assert main([*argv, "--against", str(other), "--json", str(other)]) == 2
    assert other.read_bytes() == before and "Traceback" not in capsys.readouterr().err
