"""`simulate` on arms with n joints (`docs/cli.md`, "Any number of joints"; `docs/effects.md`): the true plant's
forward dynamics against Pinocchio's ABA, a clean trial that the nominal model reproduces exactly, references inside
the joint limits, every cause on a chosen joint, and bad input on the new paths (issues 27 and 32): exit 2, the
culprit named, nothing written, strict JSON."""

from __future__ import annotations

import json
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd
import pinocchio as pin
import pytest

from ident_opt.cli import main
from ident_opt.errors import InputError
from ident_opt.problem import load_problem
from ident_opt.simulator import chain_plant as arm_plant
from ident_opt.simulator import simulate_trial
from ident_opt.simulator.chain import box_of
from ident_opt.simulator.chain_dynamics import forward

ROOT = Path(__file__).resolve().parents[1]
ARM4 = ROOT / "tests" / "arms" / "arm4.toml"
PANDA = ROOT / "problems" / "franka_panda.toml"


@pytest.fixture(scope="module")
def arm4():
    return load_problem(ARM4)


@pytest.mark.parametrize("path", [ARM4, PANDA, ROOT / "tests" / "arms" / "tx40_drives.toml"])
def test_forward_dynamics_equal_pinocchio(path):
    """ddq = M⁻¹ (τ − h) from the arm's own CasADi inverse dynamics (the drives' armature included, friction left
    out), against Pinocchio on the same inertials at random states: its ABA with the armature as `model.armature`,
    or, for the TX40's coupled wrist (whose motor's inertia is not diagonal: Cᵀ diag(ia) C), its CRBA and RNEA."""
    robot = load_problem(path).robot
    arm, pi = robot.datasheets()[robot.datasheet]
    n = arm.n_joints
    rigid = np.where([p.kind in ("friction", "other") for p in arm.parameters], 0.0, pi)
    q, dq, tau = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("tau", n)
    f = ca.Function("fd", [q, dq, tau], [forward(arm, ca.DM(rigid), q, dq, tau)])
    model = arm._pinocchio_with(pi)
    data = model.createData()
    armature = np.array([j.rotor_inertia for j in robot.joints])
    C = arm.drive_matrix
    coupled = np.count_nonzero(C - np.diag(np.diag(C)))
    if not coupled:
        model.armature = armature
    rng = np.random.default_rng(7)
    for _ in range(10):
        qk, dqk, tk = rng.normal(size=(3, n))
        if coupled:
            M = pin.crba(model, data, qk)
            M = np.triu(M) + np.triu(M, 1).T + C.T @ np.diag(armature) @ C
            expected = np.linalg.solve(M, tk - pin.rnea(model, data, qk, dqk, np.zeros(n)))
        else:
            expected = pin.aba(model, data, qk, dqk, tk)
        got = np.array(f(qk, dqk, tk)).ravel()
        assert np.max(np.abs(got - expected)) <= 1e-9 * max(1.0, np.max(np.abs(expected)))


def test_a_singular_nominal_model_is_refused_naming_the_joint(tmp_path, capsys):
    """The TX40's URDF gives its last link no inertia about its axis: without the rotor inertia the shipped problem
    adds (`[robot.joint_6]`), no forward simulation (exit 2)."""
    text = (ROOT / "problems" / "staubli_tx40.toml").read_text()
    assert "[robot.joint_6]" in text, "the shipped problem's rotor, which this test takes away"
    head, tail = text.split("[robot.joint_6]")
    text = head + tail[tail.index("\n[") :]  # the table's lines up to the next table
    problem = tmp_path / "problems" / "tx40.toml"
    problem.parent.mkdir()
    problem.write_text(text.replace('"../', f'"{ROOT}/'))
    out = tmp_path / "out"
    out.mkdir()
    code = main(["simulate", "--problem", str(problem), "--out", str(out / "t.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "singular" in err and "joint_6" in err and "[robot.joint_6] rotor_inertia" in err
    assert not list(out.iterdir())


def test_a_clean_trial_is_the_nominal_model_exactly_and_stays_inside_the_limits(arm4):
    trial = simulate_trial(
        arm4.robot,
        duration=6.0,
        rate_hz=500.0,
        seed=3,
        noise=False,
        exact_derivatives=True,
        limits=arm4.limits,
        progress=False,
    )
    ds = trial.dataset()
    arm, pi = arm4.robot.datasheets()[arm4.robot.datasheet]
    assert ds.q.shape[1] == 4 and "tau4" in trial.frame and "q4_ref" in trial.frame
    np.testing.assert_allclose(arm.predict(pi, ds.q, ds.dq, ds.ddq), ds.tau, atol=1e-8 * np.abs(ds.tau).max())
    limits = arm4.limits
    assert np.all(ds.q >= np.array(limits.position_min)) and np.all(ds.q <= np.array(limits.position_max))
    ref = trial.frame[[f"q{j}_ref" for j in range(1, 5)]].to_numpy()
    dref = np.gradient(ref, ds.t, axis=0)
    assert np.all(np.abs(dref).max(axis=0) <= np.array(limits.velocity) * 1.01)
    assert box_of(arm4.robot, None).q_min[0] > -2.8  # the URDF's <limit> bound the motion without [limits] too


@pytest.mark.parametrize(
    "effect, where",
    [
        ("armature:joint=3,inertia=0.05", ("plant", "extra_inertia", 2, 0.05)),
        ("asymmetric_coulomb:joint=elbow,positive=1.2,negative=0.4", ("plant", "coulomb_positive", 2, 1.2)),
        ("load_friction:joint=[1,4],coefficient=0.2", ("plant", "load_friction", 3, 0.2)),
        ("joint_offset:joint=2,offset=-0.03", ("plant", "encoder_offset", 1, -0.03)),
    ],
)
def test_an_effect_lands_on_the_joint_it_names(arm4, effect, where):
    def plant(effects):
        trial = simulate_trial(
            arm4.robot, duration=1.0, rate_hz=200.0, effects=effects, limits=arm4.limits, progress=False
        )
        return trial.truth[section][key]

    section, key, joint, value = where
    values, clean = plant([effect]), plant([])
    assert values[joint] == pytest.approx(value)
    others = [j for j in range(4) if j != joint and not (key == "load_friction" and j == 0)]
    assert [values[j] for j in others] == pytest.approx([clean[j] for j in others])


def test_an_elastic_joint_and_a_payload_on_the_last_link(arm4):
    trial = simulate_trial(
        arm4.robot,
        duration=2.0,
        rate_hz=250.0,
        effects=["elasticity:joint=3,frequency_hz=6", "payload:mass=0.4,com=[0.0,0.01,0.05]"],
        limits=arm4.limits,
        progress=False,
    )
    truth = trial.truth
    assert truth["effects"]["elasticity"]["joint_name"] == "elbow" and "deflection3" in trial.frame
    arm = arm4.robot.datasheets()[arm4.robot.datasheet][0]
    added = np.array([truth["pi"][name] - truth["pi_datasheet"][name] for name in arm.names])
    assert added[arm.names.index("m_hand")] == pytest.approx(0.4)
    assert np.count_nonzero(np.abs(added) > 1e-12) <= 10  # only the last link's parameters move
    json.dumps(truth, allow_nan=False)


def test_an_elastic_joint_has_the_frequency_of_the_motion_it_ran(arm4):
    """The spring k is set at the centre pose; over a trial the other joints move and the link inertia behind it
    with them. The truth gives the trial's frequency √(k / mean M_link) / 2π and its range, checked here against
    Pinocchio's CRBA on the logged angles (encoder offset added back) with the link-side inertials (no armature)."""
    trial = simulate_trial(
        arm4.robot,
        duration=4.0,
        rate_hz=250.0,
        effects=["elasticity:joint=2,frequency_hz=5", "joint_offset:joint=3,offset=0.05"],
        limits=arm4.limits,
        progress=False,
    )
    el = trial.truth["effects"]["elasticity"]
    arm, pi = arm4.robot.datasheets()[arm4.robot.datasheet]
    model = arm._pinocchio_with(pi)  # inertials only: the rotors' armature is on the motor side of the spring
    data = model.createData()
    q = trial.frame[[f"q{j + 1}" for j in range(4)]].to_numpy() + np.array([0.0, 0.0, 0.05, 0.0])
    M = np.array([pin.crba(model, data, qk)[1, 1] for qk in q[::5]])
    k = el["stiffness"]
    assert el["frequency_trial_hz"] == pytest.approx(np.sqrt(k / M.mean()) / (2 * np.pi), rel=2e-3)
    low, high = el["frequency_range_hz"]
    assert low == pytest.approx(np.sqrt(k / M.max()) / (2 * np.pi), rel=5e-3)
    assert high == pytest.approx(np.sqrt(k / M.min()) / (2 * np.pi), rel=5e-3)
    assert el["frequency_hz"] == 5.0 and low < high


def _simulate(args: list[str], tmp_path: Path, capsys) -> tuple[int, str]:
    out = tmp_path / "t.csv"
    code = main(["simulate", "--problem", str(ARM4), "--out", str(out), "--duration", "1", *args])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if code == 2:
        assert not list(tmp_path.iterdir()), "nothing is written on bad input"
    return code, err


@pytest.mark.parametrize(
    "effect, words",
    [
        ("armature:joint=9", ["joint 9", "does not have", "1 to 4"]),
        ("armature:joint=wrist", ["'wrist'", "does not have", "yaw"]),
        ("elasticity:joint=5", ["joint 5", "does not have"]),
        ("payload:mass=1,com=[5.0,0.0,0.0]", ["beyond the arm's length"]),
        ("armature:inertia=[0.1,0.2]", ["one number or a list of 4"]),
        ("elasticity:kind=link", ["kind=link", "planar"]),
        ("stiction", ["background terms", "planar"]),
        ("elasticity:frequency_hz=1e9", ["frequency_hz", "at most 500"]),
        # the default static level is the datasheet's mean + an excess, below this joint's asymmetric levels
        (
            ["asymmetric_coulomb:joint=2,positive=4.0,negative=2.0", "stribeck:joint=2"],
            ["stribeck", "on shoulder", "below that joint's Coulomb level 3 N m", "give static above 3"],
        ),
    ],
)
def test_bad_effects_on_an_n_joint_arm_exit_2_naming_them(tmp_path, capsys, effect, words):
    effects = [effect] if isinstance(effect, str) else effect
    code, err = _simulate([a for e in effects for a in ("--effect", e)], tmp_path, capsys)
    assert code == 2
    for w in words:
        assert w in err, (w, err)


def test_currents_need_torque_constants(tmp_path, capsys):
    """A URDF arm without [robot.<joint>] drives: --current names the joint's table (was a TypeError)."""
    code = main(["simulate", "--problem", str(PANDA), "--out", str(tmp_path / "t.csv"), "--duration", "1", "--current"])
    err = capsys.readouterr().err
    assert code == 2 and "[robot.panda_joint1]" in err and "torque_constant" in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())


def test_a_trajectory_file_outside_the_joint_range_is_refused(tmp_path, capsys, arm4):
    t = np.arange(0, 2.0, 0.01)
    cols = {"t": t}
    for signal in ("q", "dq", "ddq"):
        for j in range(1, 5):
            cols[f"{signal}{j}"] = np.zeros_like(t)
    cols["q2"] = np.linspace(0, 3.0, len(t))  # beyond the shoulder's 1.2 rad
    path = tmp_path / "traj.csv"
    pd.DataFrame(cols).to_csv(path, index=False)
    code = main(
        [
            "simulate",
            "--problem",
            str(ARM4),
            "--out",
            str(tmp_path / "o.csv"),
            "--duration",
            "1.5",
            "--trajectory-file",
            str(path),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "q2 (shoulder)" in err and "outside" in err
    assert not (tmp_path / "o.csv").exists()


def test_diagnose_refuses_a_joint_that_never_moves(tmp_path, capsys, arm4):
    trial = simulate_trial(arm4.robot, duration=8.0, rate_hz=100.0, seed=1, limits=arm4.limits, progress=False)
    frame = trial.frame.copy()
    frame["q3"] = frame["q3"].iloc[0]
    frame["dq3"] = 0.0
    frame["ddq3"] = 0.0
    path = tmp_path / "still.csv"
    frame.to_csv(path, index=False)
    out = tmp_path / "out"
    code = main(["diagnose", "--problem", str(ARM4), "--data", str(path), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "elbow (q3) never moves" in err and "Traceback" not in err
    assert not out.exists()


def test_input_errors_name_the_key_before_any_work(arm4):
    with pytest.raises(InputError, match=r"load_friction.*at most 0.9"):
        simulate_trial(
            arm4.robot, duration=1.0, effects=["load_friction:coefficient=[1e9,1e9,1e9,1e9]"], progress=False
        )


@pytest.mark.parametrize(
    "trajectory, effects",
    [
        ("fourier", ["stribeck:joint=2", "asymmetric_coulomb:joint=4"]),
        ("tud01", ["load_friction:joint=3", "elasticity:joint=2,frequency_hz=6"]),
    ],
)
def test_fine_steps_only_near_reversals_give_the_fine_integration(arm4, monkeypatch, trajectory, effects):
    """The loop takes the fine RK4 steps only where the effects' friction is stiff or a joint may reverse; every
    tick fine is the reference it must equal (to a small share of the torque noise), and on a reference that keeps
    moving most ticks must be coarse (else the rule does nothing)."""

    def trial():
        return simulate_trial(
            arm4.robot,
            trajectory=trajectory,
            duration=3.0,
            rate_hz=1000.0,
            effects=effects,
            limits=arm4.limits,
            progress=False,
            noise=False,
        )

    adaptive = trial()
    band = arm_plant.ArmPlant.stiff_band
    monkeypatch.setattr(arm_plant.ArmPlant, "stiff_band", lambda self, rate: np.where(band(self, rate) > 0, 1e9, 0))
    fine = trial()
    loop = adaptive.truth["controller"]
    assert loop["rk4_substeps_away_from_reversals"] < loop["rk4_substeps"]
    assert fine.truth["controller"]["fine_tick_share"] == 1.0
    if trajectory == "fourier":
        assert loop["fine_tick_share"] < 0.5
    sigma = np.array(
        simulate_trial(arm4.robot, duration=1.0, limits=arm4.limits, progress=False).truth["measurement"][
            "torque_noise_std"
        ]
    )
    for j in range(4):
        diff = np.abs(adaptive.frame[f"tau{j + 1}"] - fine.frame[f"tau{j + 1}"]).max()
        assert diff < 0.1 * sigma[j], (j, diff, sigma[j])


def test_stribeck_drawn_beside_asymmetric_coulomb_rises_above_its_levels(arm4):
    """Hidden causes drawn together see each other's Coulomb levels: a Stribeck static level drawn after an
    asymmetric Coulomb friction on the same joint lies above that joint's mean level (a positive excess in the
    plant), not merely above the datasheet's."""
    from ident_opt.diagnosis import hidden

    view = hidden.chain_joints(arm4.robot, arm4.limits)
    for seed in range(5):
        keys = hidden.chain_draws(("asymmetric_coulomb", "stribeck"), np.random.default_rng(seed), view, (1,))
        levels = 0.5 * (keys["asymmetric_coulomb"]["positive"][1] + keys["asymmetric_coulomb"]["negative"][1])
        assert keys["stribeck"]["static"][1] > levels
    trial = simulate_trial(arm4.robot, duration=1.0, effects=keys, limits=arm4.limits, progress=False)
    assert trial.truth["effects"]["stribeck"]["static_excess"][1] > 0


def test_a_joint_stribeck_leaves_alone_has_no_excess_beside_asymmetric_coulomb(arm4):
    """Asymmetric Coulomb friction on joint 2, Stribeck friction on joint 3 (`--effect` style, levels from the
    datasheet): joint 2 keeps its per-direction levels and gets no Stribeck excess (it got minus their mean)."""
    effects = ["asymmetric_coulomb:joint=2,positive=4.0,negative=2.0", "stribeck:joint=3"]
    trial = simulate_trial(arm4.robot, duration=1.0, effects=effects, limits=arm4.limits, progress=False)
    excess = trial.truth["effects"]["stribeck"]["static_excess"]
    assert excess[1] == 0.0 and excess[2] > 0 and excess[0] == excess[3] == 0.0
