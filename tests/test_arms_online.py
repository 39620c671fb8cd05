"""`online`, its stream and the generated update on an arm of n joints (the 3-joint URDF arm logged with currents,
`tests.test_n_joint_inputs`): the --json contract per joint, PBR's base parameters against a from-scratch re-solve
after every checked step, the sign bounds exact at every sample and the consistent fit re-solved at its cadence, the
compiled update equal to the Python one, the stream on t, q, i only."""

from __future__ import annotations

import io
import json

import numpy as np
import pandas as pd
import pytest

from ident_opt.adaptation.kernel import attach
from ident_opt.adaptation.lines import BadLine, LineParser, Mapping
from ident_opt.adaptation.replay import _standard_errors
from ident_opt.adaptation.start import offline_start, start_identifier
from ident_opt.adaptation.stream import StreamOptions, currents_to_torques, serve
from ident_opt.cli import main
from ident_opt.consistency import necessarily_nonnegative
from ident_opt.data.dataset import chronological_split
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.recommend import choose
from ident_opt.problem import load_problem
from tests.test_n_joint_inputs import arm3, workspace  # noqa: F401  (the fixtures)


@pytest.fixture(scope="module")
def replayed(workspace, tmp_path_factory):  # noqa: F811
    out = tmp_path_factory.mktemp("online3")
    args = ["online", "--problem", str(workspace / "full.toml"), "--out", str(out / "out")]
    args += ["--json", str(out / "o.json"), "--components", "2", "--checks", "3", "--consistent-every", "60"]
    code = main([*args, "--no-progress"])
    return code, json.loads((out / "o.json").read_text()), out / "out"


def test_online_json_on_three_joints(replayed, workspace):  # noqa: F811
    code, js, out = replayed
    assert code == 0
    arm = load_problem(workspace / "full.toml").robot.arm
    assert js["joints"] == ["a", "b", "c"]
    assert list(js["parameters"]["initial"]) == list(arm.names) and list(js["parameters"]["final"]) == list(arm.names)
    base = js["base_parameters"]
    assert set(base["final"]) == set(base["definitions"]) and len(base["final"]) < arm.n_params
    for which in ("online", "frozen"):
        for block in js["metrics"][which].values():
            assert set(block) >= {"rr", "dm", "pbr", "cpbr", "pbr+gmr"}
            assert all(len(v) == 3 and all(np.isfinite(v)) for v in block.values())
    assert all(len(v) == 3 for v in js["coverage"]["online"].values())
    assert js["updates_per_second"] > 0 and js["warnings"] == []
    assert js["batch_check"] <= 1e-9 and js["batch_check_detail"]["pbr_vs_lsq_linear"] <= 1e-8
    assert (out / "online.md").read_text().count("Consistency online") == 1


def test_sign_bounds_exact_and_the_lmis_at_the_cadence(replayed):
    _, js, _ = replayed
    c = js["consistency"]
    assert c["every"] == 60 and c["re_solves"] >= 3 and c["failed_re_solves"] == 0
    assert c["sign_bound_least_slack"] >= 0.0 and c["sign_bounds"]
    assert c["least_lmi_eigenvalue"] >= 0.0  # every re-solve consistent
    assert len(c["at_re_solves"]) == c["re_solves"] - 1  # the offline start is the first re-solve
    assert all(len(r["torque_rms_difference"]) == 3 for r in c["at_re_solves"])
    assert all(min(r["held_torque_rms_difference"]) > 0 for r in c["at_re_solves"])  # the re-solves move cpbr
    cadence = js["batch_check_detail"]["cadence_by_model"]["cpbr"]
    assert cadence["max_torque_rms_difference"] < 1e-6  # the conic solver's tolerance, at its own re-solves


@pytest.fixture(scope="module")
def split(workspace):  # noqa: F811
    problem = load_problem(workspace / "full.toml")
    trial = load_dataset(workspace / "train.csv", problem.data, problem.robot)
    tr, te = chronological_split(trial.n, 0.7)
    return problem, trial.subset(tr), trial.subset(te)


def test_the_start_is_the_recommended_fit_named_with_its_reason(replayed, split):
    _, js, out = replayed
    problem, train, _ = split
    choice = choose(problem, [train], model=problem.robot.model(()))
    assert (js["estimator"], js["estimator_why"]) == (choice.estimator, choice.why)
    assert f"**{choice.estimator}**" in (out / "online.md").read_text()
    cpbr = js["parameters_by_model"]["cpbr"]
    start = offline_start("cpbr", problem, train, choice=choice)
    assert np.allclose(cpbr["initial"], start.theta0, rtol=1e-9, atol=1e-12)


def test_a_robust_start_keeps_its_instruments_at_the_cadence(split):
    problem, train, test = split
    start = offline_start("cpbr", problem, train, every=40, choice=choose(problem, [train], estimator="robust"))
    fit = estimators.fit_for(
        problem.robot, "robust", estimators.statistics(problem.robot.arm, [train], "robust"), problem.robot.arm
    )
    assert np.allclose(start.theta0, start.base.project(fit.pi), rtol=1e-9, atol=1e-12)  # the start: the robust fit
    ident = start_identifier(start, train)
    D = start.design(test.q[:80], test.dq[:80], test.ddq[:80])
    for k in range(80):
        ident.add(D[k], test.tau[k])
    assert ident.estimator.solver.refreshed == 3 and ident.refresh_failures == 0
    # at its re-solve (80 samples in), the robust fit on the training instruments plus the online rows as their own
    online = estimators.statistics(problem.robot.arm, [train], "robust") + InstrumentStats.from_regressors(
        *(problem.robot.arm.regressor(test.q[:80], test.dq[:80], test.ddq[:80]),) * 2, test.tau[:80]
    )
    again = start.base.project(estimators.fit_for(problem.robot, "robust", online, problem.robot.arm).pi)
    gap = np.sqrt(np.mean((D @ (ident.theta - again)) ** 2)) / np.sqrt(np.mean(test.tau[:80] ** 2))
    assert gap < 1e-6  # the conic solver's tolerance (as at the consistent fit's own re-solves)
    plain = start.base.project(
        estimators.fit_for(problem.robot, problem.robot.default_estimator, online.stats, problem.robot.arm).pi
    )
    apart = np.sqrt(np.mean((D @ (plain - again)) ** 2)) / np.sqrt(np.mean(test.tau[:80] ** 2))
    assert apart > 100 * gap  # the instruments matter: without them the re-solve lands elsewhere


def test_an_unknown_estimator_exits_2_writing_nothing(workspace, tmp_path, capsys):  # noqa: F811
    args = ["online", "--problem", str(workspace / "full.toml"), "--out", str(tmp_path / "o"), "--estimator", "nope"]
    assert main([*args, "--no-progress"]) == 2
    assert "--estimator nope" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_sign_bounds_are_those_no_consistent_arm_breaks(split):
    problem, train, _ = split
    start = offline_start("pbr", problem, train)
    lower = start.estimator.bounds.lower
    definite = necessarily_nonnegative(problem.robot.arm, start.base.K)
    assert np.array_equal(lower == 0.0, definite) and np.all(np.isinf(lower[~definite]))
    assert any(name.startswith("fv_") for name, b in zip(start.names, lower) if b == 0.0)


def test_compiled_update_equals_python_on_three_joints(split):
    problem, train, test = split
    start = offline_start("pbr", problem, train)
    python, compiled = start_identifier(start, train), start_identifier(start, train)
    assert attach(compiled, start.design)
    D = start.design(test.q, test.dq, test.ddq)
    for i in range(test.n):
        python.add(D[i], test.tau[i])
        compiled.add(D[i], test.tau[i])
        prefix = np.concatenate([start.design(train.q, train.dq, train.ddq), D[: i + 1]])
        tau = np.concatenate([train.tau, test.tau[: i + 1]])
        scale = np.maximum(np.abs(python.theta), _standard_errors(prefix, tau, python.theta))
        assert np.all(np.abs(compiled.theta - python.theta) <= 1e-9 * scale), i


def test_stream_on_t_q_i_only_updates_every_completed_sample(split, workspace):  # noqa: F811
    problem, train, _ = split
    raw = pd.read_csv(workspace / "test.csv")
    lines = [",".join(["t", "q1", "q2", "q3", "i1", "i2", "i3"])]
    lines += [",".join(repr(float(v)) for v in row) for row in raw[["t", "q1", "q2", "q3", "i1", "i2", "i3"]].values]
    start = offline_start("pbr", problem, train)
    ident = start_identifier(start, train)
    scale, refused = currents_to_torques(problem.robot)
    options = StreamOptions(Mapping.from_spec(problem.data, problem.robot), scale, refused, cutoff_hz=5.0)
    out, err = io.StringIO(), io.StringIO()
    final = serve(ident, start.names, io.StringIO("\n".join(lines) + "\n"), out, err, 0, options=options)
    final = final["final"]
    assert err.getvalue() == "" and final["derivatives"]["estimated"] and final["updates"] > 300
    assert final["updates"] + final["outliers"] + final["derivatives"]["lost"] == len(raw)
    records = [json.loads(x) for x in out.getvalue().splitlines() if '"n"' in x and "final" not in x]
    assert all(len(r["tau"]) == 3 and len(r["std"]) == 3 for r in records)
    assert list(final["parameters"]) == list(start.names)


def test_stream_header_without_an_angle_of_the_arm_exits_2(split):
    problem, _, _ = split
    parser = LineParser(mapping=Mapping.from_spec(problem.data, problem.robot))
    with pytest.raises(InputError, match="q3"):
        parser.parse("t,q1,q2,tau1,tau2,tau3")
    with pytest.raises(BadLine, match="every joint"):  # torques of two joints of three
        good = LineParser(mapping=Mapping.from_spec(problem.data, problem.robot))
        good.parse("t,q1,q2,q3,tau1,tau2")
        good.parse("0.1,0.1,0.2,0.3,1.0,2.0")
