"""Drive gains from a known load (`[data.payloads]`, `ident_opt.fitting.drive_gains`): current-logged simulated
trials whose drives deliver s × the nominal torque constant × gear ratio, one trial carrying a known payload."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

import ident_opt as iopt
from ident_opt.errors import InputError
from ident_opt.fitting import drive_gains
from ident_opt.problem import load_problem
from ident_opt.simulator.simulate import simulate_trial

ROOT = Path(__file__).resolve().parents[1]


def _problem(folder: Path, text: str, scale: list[float], load: str, effect: str, rate: float, exact: bool = False):
    """The problem in `folder` with two current-logged trials of `mixed` motion (40 s at `rate`), the drives' true
    gains `scale` × nominal, the second carrying the payload `effect` and declaring it as `load` in
    [data.payloads]. `exact`: noise-free, the true derivatives logged; else t, q and currents only (the loader
    estimates the derivatives)."""
    (folder / "p.toml").write_text(text, encoding="utf-8")
    problem = load_problem(folder / "p.toml")
    gains = f"torque_scale:scale=[{','.join(str(s) for s in scale)}]"
    for k, effects in enumerate(([gains], [gains, effect])):
        trial = simulate_trial(
            problem.robot,
            trajectory="mixed",
            duration=40.0,
            rate_hz=rate,
            seed=700 + k,
            effects=effects,
            limits=problem.limits,
            output="current",
            noise=not exact,
            exact_derivatives=exact,
            progress=False,
        )
        keep = [c for c in trial.frame.columns if exact or not c.startswith(("dq", "ddq"))]
        trial.frame[keep].to_csv(folder / f"trial{k}.csv", index=False)
    text += f'\n[data]\ntrain = ["trial0.csv", "trial1.csv"]\n\n[data.payloads]\n"trial1.csv" = {{ {load} }}\n'
    (folder / "p.toml").write_text(text, encoding="utf-8")
    return load_problem(folder / "p.toml")


def _identify(problem):
    trains, _ = iopt.load_trials(problem)
    loads = [problem.data.load_of(t.source) for t in trains]
    assert loads[0] is None and loads[1] is not None
    return drive_gains.identify(problem.robot, problem.robot.model(), trains, loads)


def test_a_known_payload_gives_each_drive_its_gain_on_the_planar_arm(tmp_path):
    """The planar arm (tudor_sim), currents with the simulator's noise and quantised angles, derivatives estimated
    from the angles: each gain within 3 % of the truth (measured 0.9 % and 0.2 %), the far one (10 % off) a
    warning, and `compare --json` carries them."""
    text = (ROOT / "problems" / "tudor_sim.toml").read_text(encoding="utf-8")
    text = re.sub(r"\n\[data\][^\[]*", "\n", text)
    truth = [0.9, 1.08]
    problem = _problem(tmp_path, text, truth, "mass = 0.5", "payload:mass=0.5", 100.0)
    g = _identify(problem)
    np.testing.assert_allclose(g.ratio, truth, rtol=0.03)
    assert np.all(np.isfinite(g.se)) and np.all(g.se < 0.02)
    assert [w.code for w in g.warnings] == ["drive_gain"] and g.warnings[0].message.startswith("joint1:")
    k = [j.current_to_torque for j in problem.robot.joints]
    payload = g.as_json()
    np.testing.assert_allclose(payload["gain_n_m_per_a"], np.asarray(g.ratio) * k, rtol=1e-12)
    assert payload["loaded_trials"] == ["trial1.csv"] or payload["loaded_trials"][0].endswith("trial1.csv")

    from ident_opt.cli import main

    out = tmp_path / "compare.json"
    assert main(["compare", "--problem", str(tmp_path / "p.toml"), "--no-progress", "--json", str(out)]) == 0
    result = json.loads(out.read_text(encoding="utf-8"))
    np.testing.assert_allclose(result["drive_gains"]["ratio"], g.ratio, rtol=1e-9)
    assert any(w["code"] == "drive_gain" for w in result["warnings"])


@pytest.mark.parametrize("exact", [True, False], ids=["exact", "noisy"])
def test_the_six_joint_arms_gains(tmp_path, exact):
    """The TX40 with drives (6 joints, a coupled wrist), its drives given a torque constant and gear ratio. Noise-free
    with the true derivatives logged: every gain to 1e-6 (the estimator itself). With the logger's noise and the
    derivatives estimated from the angles: every gain within 3 % (measured 0.01–0.4 %; before each joint's samples
    slower than its stick speed were left out of its equation, joints 1 and 4 were off by 35 % and 5 %:
    `benchmarks/drive_gains.py`)."""
    text = (ROOT / "tests" / "arms" / "tx40_drives.toml").read_text(encoding="utf-8")
    text = text.replace('urdf = "../../', f'urdf = "{ROOT.as_posix()}/')
    text = re.sub(r"(\[robot\.joint_\d\]\n)", r"\1torque_constant = 0.2\ngear_ratio = 40\n", text)
    truth = [0.9, 1.05, 1.1, 0.95, 1.0, 1.04]
    load = "mass = 2.0, com = [0.15, 0.1, 0.1]"
    problem = _problem(tmp_path, text, truth, load, "payload:mass=2.0,com=[0.15,0.1,0.1]", 250.0, exact=exact)
    g = _identify(problem)
    np.testing.assert_allclose(g.ratio, truth, rtol=1e-6 if exact else 0.03)


def test_without_a_known_load_the_scale_is_refused_and_bad_loads_are_named(tmp_path):
    problem = load_problem(ROOT / "problems" / "tudor_sim.toml")
    with pytest.raises(InputError, match="no trial carries a known load"):
        drive_gains.identify(problem.robot, problem.robot.model(), [], [])
    text = re.sub(r"\n\[data\][^\[]*", "\n", (ROOT / "problems" / "tudor_sim.toml").read_text(encoding="utf-8"))
    for bad, match in (
        ('"a.csv" = { mass = -1 }', "mass"),
        ('"a.csv" = { mass = 1, com = [1, 2, 3, 4] }', "com"),
        ('"a.csv" = { mass = 1, colour = 2 }', "colour"),
    ):
        (tmp_path / "p.toml").write_text(text + f"\n[data.payloads]\n{bad}\n", encoding="utf-8")
        with pytest.raises(InputError, match=match):
            load_problem(tmp_path / "p.toml")
