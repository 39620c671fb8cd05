"""`observer_step` in the generated C (`ident_opt.contact.casadi_step`): compiled with gcc, it gives the Python
watch's τ_ext to 1e-9 and the same alarms, sample by sample, on a pushed planar arm and a 7-joint arm; `ident-opt
codegen` exports it beside tau_hat and names it, its thresholds and its state in parameters.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import ident_opt as iopt
from ident_opt.cbuild import compile_library, generate_sources, load_external
from ident_opt.cli import main
from ident_opt.contact.casadi_step import check, for_codegen, observer_step_function, state_size
from ident_opt.simulator.trial import simulate_trial

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("name", "torque"), [("tudor_sim.toml", 6.0), ("kuka_lwr4.toml", 20.0)], ids=["planar", "kuka7"]
)
def test_compiled_step_matches_python(name, torque, tmp_path):
    problem = iopt.load_problem(ROOT / "problems" / name)
    effects = list(problem.simulate.effects) if problem.simulate is not None else []
    train = simulate_trial(problem.robot, duration=15, seed=1, effects=effects, progress=False).dataset()
    push = f"contact:joint=2,torque={torque},start=1.5,duration=0.5,every=3"
    test = simulate_trial(problem.robot, duration=8, seed=2, effects=[*effects, push], progress=False).dataset()
    fit = iopt.fit(problem, [train])
    step, watch, entry = for_codegen(fit.model, fit.pi, [train])
    source, _ = generate_sources([step], tmp_path, "obs")
    compiled = load_external(compile_library(source, tmp_path, name="obs"), "observer_step")
    found = check(compiled, watch, test.q, test.dq, test.tau)
    assert found["max_relative_difference"] <= 1e-9 and found["alarm_mismatches"] == 0
    assert found["alarm_samples"] > 100  # the pushes raise alarms: the alarm logic is exercised, not only τ_ext
    n = problem.robot.n_joints
    assert entry["state_size"] == state_size(n) == sum(b["size"] for b in entry["state_layout"])
    assert step.size1_in(3) == state_size(n) and step.size1_out(0) == n


def test_wrong_alarm_logic_is_caught(tmp_path):
    """The check fails when the C differs: thresholds halved in the compiled step give other alarms."""
    problem = iopt.load_problem(ROOT / "problems" / "tudor_sim.toml")
    train = simulate_trial(problem.robot, duration=10, seed=1, progress=False).dataset()
    fit = iopt.fit(problem, [train])
    _, watch, _ = for_codegen(fit.model, fit.pi, [train])
    th = watch().thresholds
    halved = type(th)(
        th.gain,
        tuple(0.3 * x for x in th.moving),
        tuple(0.3 * x for x in th.resting),
        th.rest_speed,
        th.persistence,
        th.settling,
        th.dt,
    )
    wrong = observer_step_function(fit.model, fit.pi, halved)
    found = check(wrong, watch, train.q[:400], train.dq[:400], train.tau[:400])
    assert found["alarm_mismatches"] > 0


def test_codegen_exports_observer_step(tmp_path):
    out = tmp_path / "cg"
    assert main(["codegen", "--problem", str(ROOT / "problems" / "tudor_2dof.toml"), "--out", str(out)]) == 0
    params = json.loads((out / "parameters.json").read_text())
    assert "observer_step" in params["functions"] and "tau_hat" in params["functions"]
    observer = params["observer"]
    assert observer["inputs"] == ["q", "dq", "tau", "state"] and observer["outputs"] == [
        "tau_ext",
        "state_next",
        "alarm",
    ]
    assert observer["state_size"] == 13 and len(observer["thresholds"]) == 2 and observer["persistence"] >= 2
    assert observer["check"]["max_relative_difference"] <= 1e-9 and observer["check"]["alarm_mismatches"] == 0
    assert params["check"]["observer_step"]["max_relative_error"] <= 1e-9
    assert "int observer_step(" in (out / "ident_opt_model.h").read_text()
    assert "observer_step" in (out / "README.md").read_text()
    assert np.isfinite([t["moving"] for t in observer["thresholds"]]).all()
