"""Hostile input to the Python API (issue 52, point 5): the API validates like the command line. Shapes, finiteness,
column counts, option ranges and types are checked at the door, each an `InputError` naming the argument; nothing
is truncated or broadcast; the API's writers obey the command line's output rules. Tiny trials with exact
derivatives keep every fit fast."""

from __future__ import annotations

import os
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import ident_opt as iopt
from ident_opt.cli import main
from ident_opt.diagnosis import diagnose_trial

from .conftest import PROBLEMS

N, RATE = 300, 100.0  # samples, Hz


def _motion(n_joints: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], q [rad], dq [rad/s], ddq [rad/s²]) of three sines per joint, with exact derivatives."""
    t = np.arange(N) / RATE
    q, dq, ddq = (np.zeros((N, n_joints)) for _ in range(3))
    for j in range(n_joints):
        for k, (f, a) in enumerate(((0.7 + 0.2 * j, 0.5), (1.3 + 0.4 * j, 0.3), (2.9 - 0.6 * j, 0.1))):
            w = 2 * np.pi * f
            q[:, j] += a * np.sin(w * t + k)
            dq[:, j] += a * w * np.cos(w * t + k)
            ddq[:, j] -= a * w * w * np.sin(w * t + k)
    q[:, 0] += 1.5
    return t, q, dq, ddq


@pytest.fixture(scope="module")
def planar():
    return iopt.load_problem(PROBLEMS / "tudor_2dof.toml")


@pytest.fixture(scope="module")
def good(planar):
    """A tiny trial of the planar arm: the datasheet's torques along a multisine, a little noise, exact derivatives."""
    t, q, dq, ddq = _motion()
    arm, pi = planar.robot.datasheets()["physical"]
    tau = arm.predict(pi, q, dq, ddq) + np.random.default_rng(0).normal(0.0, 0.01, (N, 2))
    return iopt.trial(planar, t, q, tau, dq=dq, ddq=ddq, source="tiny")


@pytest.fixture(scope="module")
def fitted(planar, good):
    return iopt.fit(planar, [good])


# ---------------------------------------------------------------------------------------------- trials at the door
def test_a_torque_shorter_than_q_is_refused_naming_tau(planar, good):
    short = replace(good, tau=good.tau[:-5])
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.tau must be an array of shape \(300, 2\).*\(295, 2\)"):
        iopt.fit(planar, [short])
    with pytest.raises(iopt.InputError, match=r"tiny: tau must be an array of shape \(300, 2\)"):
        iopt.trial(planar, good.t, good.q, good.tau[:-5], dq=good.dq, ddq=good.ddq, source="tiny")


def test_nan_in_q_is_refused_naming_the_cell(planar, good):
    q = good.q.copy()
    q[3, 1] = np.nan
    with pytest.raises(iopt.InputError, match=r"fit: trials\[0\]\.q\[3, 1\] is nan: every value must be a finite"):
        iopt.fit(planar, [replace(good, q=q)])
    with pytest.raises(iopt.InputError, match=r"tiny: q\[3, 1\] is nan"):
        iopt.trial(planar, good.t, q, good.tau, dq=good.dq, ddq=good.ddq, source="tiny")


def test_inf_in_tau_is_refused_before_the_solver(planar, good):
    tau = good.tau.copy()
    tau[7, 0] = np.inf
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.tau\[7, 0\] is inf"):
        iopt.fit(planar, [replace(good, tau=tau)], estimator="constrained")


def test_trials_of_another_arm_are_refused(planar, good):
    t, q, dq, ddq = _motion(7)
    seven = iopt.Dataset("seven", t, q, dq, ddq, np.ones((N, 7)))
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.q must be an array of shape \(300, 2\).*got \(300, 7\)"):
        iopt.fit(planar, [seven])
    with pytest.raises(iopt.InputError, match=r"compare: testing\[0\]\.q must be an array of shape"):
        iopt.compare(planar, [good], [seven])


def test_extra_columns_of_q_are_refused_not_truncated(planar, good, fitted):
    wide = np.column_stack([good.q, good.q])  # 4 columns on a 2-joint arm
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.q must be an array of shape \(300, 2\).*got \(300, 4\)"):
        iopt.fit(planar, [replace(good, q=wide)])
    with pytest.raises(iopt.InputError, match=r"predict: trial\.q must be an array of shape \(N, 2\).*got \(300, 3\)"):
        fitted.predict(replace(good, q=wide[:, :3]))
    with pytest.raises(iopt.InputError, match=r"predict: trial must be a trial"):
        fitted.predict(good.q)
    assert fitted.predict(good).shape == (N, 2)


def test_empty_or_missing_trials_are_refused(planar, good):
    with pytest.raises(iopt.InputError, match=r"fit: trials is empty: give at least one trial"):
        iopt.fit(planar, [])
    with pytest.raises(iopt.InputError, match=r"compare: training is empty"):
        iopt.compare(planar, [])
    with pytest.raises(iopt.InputError, match=r"diagnose: training is empty"):
        iopt.diagnose(planar, [])
    with pytest.raises(iopt.InputError, match=r"check: training is empty"):
        iopt.check(planar, [])
    with pytest.raises(iopt.InputError, match=r"fit: trials must be a list of trials.*'exp1.csv'"):
        iopt.fit(planar, "exp1.csv")
    with pytest.raises(iopt.InputError, match=r"fit: trials\[0\] must be a trial.*ndarray"):
        iopt.fit(planar, [good.q])
    with pytest.raises(iopt.InputError, match=r"fit: problem must be a parsed problem file"):
        iopt.fit("problems/tudor_2dof.toml", [good])


# ---------------------------------------------------------------------------------------------- fit options
@pytest.mark.parametrize("margin", [np.nan, -1.0, np.inf, "1e-6", True])
def test_a_bad_margin_is_refused_naming_it(planar, good, margin):
    with pytest.raises(iopt.InputError, match=r"fit: margin must be a number in \[0, 1\] kg m²"):
        iopt.fit(planar, [good], estimator="constrained", margin=margin)


def test_fit_options_are_checked_by_name_type_and_range(planar, good):
    with pytest.raises(iopt.InputError, match=r"the constrained fit takes no option 'margn'; its options: margin, "):
        iopt.fit(planar, [good], estimator="constrained", margn=1e-3)
    with pytest.raises(iopt.InputError, match=r"the ols fit takes no option 'margin'; its options: weights"):
        iopt.fit(planar, [good], estimator="ols", margin=1e-3)
    with pytest.raises(iopt.InputError, match=r"fit: weights\[1\] is nan"):
        iopt.fit(planar, [good], estimator="ols", weights=[1.0, np.nan])
    with pytest.raises(iopt.InputError, match=r"fit: weights must be an array of shape \(2,\)"):
        iopt.fit(planar, [good], estimator="ols", weights=[1.0, 1.0, 1.0])
    with pytest.raises(iopt.InputError, match=r"fit: estimator must be None .* got int 3"):
        iopt.fit(planar, [good], estimator=3)
    with pytest.raises(iopt.InputError, match=r"compare: margin must be a number in \[0, 1\]"):
        iopt.compare(planar, [good], margin=np.nan)
    fit = iopt.fit(planar, [good], estimator="constrained", margin=1e-4, weights="wls")
    assert fit.consistent and np.isfinite(fit.pi).all()


def test_diagnose_names_a_rigid_fit_that_is_not_a_choice(planar, good, fitted):
    with pytest.raises(iopt.InputError, match=r"diagnose: rigid_fit must be None or a Choice.*estimator='consistent'"):
        iopt.diagnose(planar, [good], rigid_fit="consistent")
    with pytest.raises(iopt.InputError, match=r"rigid_fit must be None or a Choice"):
        diagnose_trial(planar.robot, good, rigid_fit="consistent")
    with pytest.raises(iopt.InputError, match=r"give estimator .* or rigid_fit .*, not both"):
        iopt.diagnose(planar, [good], estimator="ols", rigid_fit=fitted.choice)


# ---------------------------------------------------------------------------------------------- files in, files out
def _urdf_problem(folder: Path) -> iopt.Problem:
    """The DFKI pendulum from its URDF (a planar arm), copied into `folder` with a problem file of its own."""
    shutil.copy(PROBLEMS / "dfki_c0.urdf", folder / "arm.urdf")
    (folder / "p.toml").write_text(
        'name = "u"\n[robot]\nurdf = "arm.urdf"\njoints = ["Joint1", "Joint2"]\ngravity = 9.81\n', encoding="utf-8"
    )
    return iopt.load_problem(folder / "p.toml")


def test_export_refuses_the_runs_inputs_and_a_missing_fit(tmp_path, planar, good):
    problem = _urdf_problem(tmp_path)
    trial = iopt.trial(problem, good.t, good.q, good.tau, dq=good.dq, ddq=good.ddq, source="tiny")
    fit = iopt.fit(problem, [trial])
    urdf, toml = tmp_path / "arm.urdf", tmp_path / "p.toml"
    before = urdf.read_bytes(), toml.read_bytes()
    with pytest.raises(iopt.InputError, match=r"export: fit must be a fit of the problem's arm.*NoneType"):
        iopt.export(problem, None, tmp_path / "out.urdf")
    with pytest.raises(iopt.InputError, match=r"this output is also an input"):
        iopt.export(problem, fit, urdf)
    with pytest.raises(iopt.InputError, match=r"this output is also an input"):
        iopt.export(problem, fit, os.path.relpath(toml), "urdf")
    link = tmp_path / "link.urdf"
    link.symlink_to(urdf)
    with pytest.raises(iopt.InputError, match=r"this output is also an input"):
        iopt.export(problem, fit, link)
    assert (urdf.read_bytes(), toml.read_bytes()) == before
    (tmp_path / "folder.urdf").mkdir()
    with pytest.raises(iopt.InputError, match=r"export: path .*folder.urdf: is a folder"):
        iopt.export(problem, fit, tmp_path / "folder.urdf")
    os.mkfifo(tmp_path / "pipe.urdf")
    with pytest.raises(iopt.InputError, match=r"named pipe"):
        iopt.export(problem, fit, tmp_path / "pipe.urdf")
    with pytest.raises(iopt.InputError, match=r"export: path: an empty path"):
        iopt.export(problem, fit, " ")
    with pytest.raises(iopt.InputError, match=r"export: fit.pi must be 9 finite values"):
        iopt.export(problem, replace(fit, pi=np.full_like(fit.pi, np.nan)), tmp_path / "x.urdf")
    made = iopt.export(problem, fit, tmp_path / "out.urdf")
    assert [p.name for p in made.files] == ["out.urdf", "out.urdf.json"]


def test_codegen_refuses_an_input_as_its_folder_before_any_work(tmp_path, planar, good):
    with pytest.raises(iopt.InputError, match=r"codegen: training is empty"):
        iopt.codegen(planar, [], tmp_path / "c")
    with pytest.raises(iopt.InputError, match=r"codegen: out .*tudor_2dof.toml: exists and is not a folder"):
        iopt.codegen(planar, [good], planar.path)
    assert not (tmp_path / "c").exists()


def _csv(path: Path, t: np.ndarray | None = None) -> Path:
    """A tiny trial file of the planar arm (angles, torques; derivatives left to the loader)."""
    times, q, _, _ = _motion()
    frame = pd.DataFrame({"t": times if t is None else t, "q1": q[:, 0], "q2": q[:, 1]})
    frame["tau1"], frame["tau2"] = np.sin(times), np.cos(2 * times)
    frame.to_csv(path, index=False)
    return path


def test_load_trials_takes_one_path_as_one_file(tmp_path, planar):
    path = _csv(tmp_path / "log.csv")
    training, testing = iopt.load_trials(planar, data=str(path), test=path)
    assert [d.source for d in training] == [str(path)] and [d.source for d in testing] == [str(path)]
    with pytest.raises(iopt.InputError, match=r"load_trials: data must be a path or a list of paths, got 3"):
        iopt.load_trials(planar, data=3)
    with pytest.raises(iopt.InputError, match=r"load_trials: test\[1\] must be the path of a trial file, got None"):
        iopt.load_trials(planar, data=[path], test=[path, None])


def test_a_step_of_1e300_seconds_is_refused_by_the_loader(tmp_path, planar, good, capsys):
    t = np.arange(N) / RATE
    t[1] = 1e-300
    path = _csv(tmp_path / "close.csv", t)
    problem = tmp_path / "p.toml"
    shutil.copy(PROBLEMS / "tudor_2dof.toml", problem)
    text = problem.read_text(encoding="utf-8")
    problem.write_text(text[: text.index("# The real MERIt")], encoding="utf-8")  # no [data]: --data decides
    for extra in ([], ["--allow-implausible"]):
        assert main(["check", "--problem", str(problem), "--data", str(path), *extra]) == 2
        err = capsys.readouterr().err
        assert f"{path}: column 't' steps by only 1e-300 s at data row 2 (line 3 of the file)" in err
        assert "Traceback" not in err
    with pytest.raises(iopt.InputError, match=r"close: column 't' steps by only 1e-300 s at data row 2"):
        iopt.trial(planar, t, good.q, good.tau, source="close")
    with pytest.raises(iopt.InputError, match=r"trials\[0\]: column 't' steps by only 1e-300 s"):
        iopt.fit(planar, [replace(good, t=t)])


def test_the_constraints_study_refuses_an_n_joint_arm(tmp_path, capsys):
    argv = ["compare", "--problem", str(PROBLEMS / "kuka_lwr4.toml"), "--constraints-study", "1"]
    assert main([*argv, "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--constraints-study is a study of the planar two-link arm" in err and "7-joint" in err
    assert "Traceback" not in err and not (tmp_path / "out").exists()


def test_a_simulated_trial_is_never_written_over_its_problems_files(tmp_path):
    """`iopt.simulate(problem).write(path)` outside a command: before, it replaced the problem's own trial file when
    told to (the command refuses); now the trial knows the files it was made from and keeps the command's rules."""
    problem = _urdf_problem(tmp_path)
    log = iopt.simulate(problem, duration=1.0, seed=1).write(tmp_path / "log.csv")  # not an input yet: written
    toml = tmp_path / "p.toml"
    toml.write_text(toml.read_text(encoding="utf-8") + '[data]\ntrain = ["log.csv"]\n', encoding="utf-8")
    problem = iopt.load_problem(toml)
    trial = iopt.simulate(problem, duration=1.0, seed=2)
    assert {log.resolve(), toml.resolve(), (tmp_path / "arm.urdf").resolve()} <= {p.resolve() for p in trial.inputs}
    before = log.read_bytes(), (tmp_path / "log.truth.json").read_bytes()
    with pytest.raises(iopt.InputError, match=r"this output is also an input"):
        trial.write(log)
    assert (log.read_bytes(), (tmp_path / "log.truth.json").read_bytes()) == before
    assert trial.write(tmp_path / "other.csv").is_file()


# ---------------------------------------------------------------------------------------------- found by make fuzz
def test_fuzz_findings_on_the_api_are_input_errors(tmp_path, planar, good):
    """Each was a raw exception before (`make fuzz`, test_fuzz_hostile.py::test_fuzz_api): a list as export's format
    (TypeError), a data path too long for any file system (OSError), prior_weight without a prior (the solver's
    ValueError), and a trial edited in code with a 1e-300 s step (LinAlgError) or a value of 1e308 (LinAlgError)."""
    fit = iopt.fit(planar, [good])
    with pytest.raises(iopt.InputError, match=r"format must be one of"):
        iopt.export(planar, fit, tmp_path / "x.urdf", ["urdf"])
    with pytest.raises(iopt.InputError, match=r"cannot be read"):
        iopt.load_trials(planar, [str(tmp_path / ("x" * 300 + ".csv"))])
    with pytest.raises(iopt.InputError, match=r"prior_weight > 0 pulls π towards a prior"):
        iopt.fit(planar, [good], "constrained", prior_weight=1e-6)
    tiny = replace(good, t=np.arange(len(good.t)) * 1e-300)
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.t steps by 1e-300 s"):
        iopt.fit(planar, [tiny])
    huge = good.dq.copy()
    huge[5, 1] = 1e308
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.instruments\[0\] reaches 1e\+308"):
        iopt.fit(planar, [replace(good, instruments=(huge, good.ddq))])
    with pytest.raises(iopt.InputError, match=r"trials\[0\]\.tau reaches 1e\+308"):
        iopt.fit(planar, [replace(good, tau=np.where(np.arange(len(good.t))[:, None] == 7, 1e308, good.tau))])
