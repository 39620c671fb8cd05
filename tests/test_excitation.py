"""Excitation design (`ident-opt excite`): the Fourier series at rest at both ends, the [limits] section
validated, limits respected on a 1 kHz grid, the optimum better than its random start, bad limits exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_opt.cli import main
from ident_opt.errors import InputError
from ident_opt.excitation import design as excitation
from ident_opt.excitation.setup import make_setup, noise_from_data
from ident_opt.problem import load_problem
from ident_opt.simulator.fourier import Fourier

ROOT = Path(__file__).resolve().parents[1]
#: The robot of the real trials with limits and no data (σ = 1 N m), written to a temporary problem file.
ROBOT = (ROOT / "problems" / "tudor_2dof.toml").read_text().split("[limits]")[0]
LIMITS = """[limits]
position_min = [0.25, -1.40]
position_max = [3.15, 1.40]
velocity = [1.2, 1.4]
acceleration = [5.0, 6.0]
torque = [15.0, 4.0]
"""


def problem_file(tmp_path: Path, limits: str = LIMITS) -> Path:
    path = tmp_path / "p.toml"
    path.write_text(ROBOT + limits)
    return path


def test_fourier_rest_and_derivatives():
    f = Fourier(2, 4, 0.2)
    x = f.random(np.random.default_rng(3), np.array([1.0, 0.0]))
    t = np.linspace(0, 2 * f.period, 4001)
    q, dq, ddq = f.evaluate(x, t)
    for end in (0, -1):  # at rest at the start and after whole periods
        assert np.allclose(dq[end], 0, atol=1e-12) and np.allclose(ddq[end], 0, atol=1e-12)
    h = t[1] - t[0]
    assert np.allclose(np.gradient(q, h, axis=0)[2:-2], dq[2:-2], atol=1e-4)
    assert np.allclose(np.gradient(dq, h, axis=0)[2:-2], ddq[2:-2], atol=1e-3)
    assert np.allclose(q[:-1].mean(0), [1.0, 0.0], atol=1e-9)  # the offsets are the means over whole periods


def test_noise_source_is_shown_relative(physical_problem, exp1, monkeypatch):
    # The committed report names the data as people read it, not by this machine's absolute path.
    monkeypatch.chdir(ROOT)
    _, source = noise_from_data(exp1, physical_problem.robot)
    assert str(ROOT) not in source and "data/merit/exp1.csv" in source


def test_limits_section_parsed(tmp_path):
    limits = load_problem(problem_file(tmp_path)).limits
    assert limits.velocity == (1.2, 1.4) and limits.torque == (15.0, 4.0)
    no_torque = "\n".join(line for line in LIMITS.splitlines() if not line.startswith("torque"))
    assert load_problem(problem_file(tmp_path, no_torque)).limits.torque is None


@pytest.mark.parametrize(
    ("old", "new", "named"),
    [
        ("velocity = [1.2, 1.4]", "velocity = [1.2, -1.4]", "'velocity'"),
        ("velocity = [1.2, 1.4]", "velocity = [1.2]", "'velocity'"),
        ("acceleration = [5.0, 6.0]", "acceleration = [5.0, nan]", "'acceleration'"),
        ("torque = [15.0, 4.0]", 'torque = ["a", 4.0]', "'torque'"),
        ("position_max = [3.15, 1.40]", "position_max = [0.1, 1.40]", "'position_max'"),
        ("velocity = [1.2, 1.4]", "velocity = [1.2, 1.4]\nspeed = 1", "speed"),
        ("velocity = [1.2, 1.4]\n", "", "'velocity'"),
    ],
)
def test_bad_limits_named(tmp_path, old, new, named):
    path = problem_file(tmp_path, LIMITS.replace(old, new))
    with pytest.raises(InputError, match=named) as info:
        load_problem(path)
    assert "[limits]" in str(info.value) and str(path) in str(info.value)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    problem = load_problem(problem_file(tmp_path_factory.mktemp("excite")))
    return make_setup(problem.robot, problem.limits, 10.0, harmonics=3)


def _respects(setup, d) -> None:
    """Every limit on the design's 1 kHz samples over the whole duration."""
    lim = setup.limits
    assert np.all(d.q >= np.array(lim.position_min)) and np.all(d.q <= np.array(lim.position_max))
    assert np.all(np.abs(d.dq) <= np.array(lim.velocity))
    assert np.all(np.abs(d.ddq) <= np.array(lim.acceleration))
    assert np.all(np.abs(d.tau) <= np.array(lim.torque))
    assert np.allclose(d.dq[0], 0, atol=1e-9) and np.allclose(d.ddq[0], 0, atol=1e-9)


def test_d_optimal_beats_its_start_within_limits(setup):
    d = excitation.design(setup, "d", starts=1, seed=1, rate=1000.0, progress=False)
    assert np.allclose(np.diff(d.t), 1e-3) and d.t[-1] > 9.99
    _respects(setup, d)
    assert d.criteria["log_det"] > d.start_criteria["log_det"] + 1.0  # e = 2.7 times the information volume
    assert d.criteria["rank"] == len(setup.arm.names)
    assert all(min(m["margin"]) >= 0 for m in d.margins.values())
    # The tightest limit is close: the optimum uses the room it has.
    assert min(min(m["fraction"]) for m in d.margins.values()) < 0.05


def test_cond_optimal_beats_its_start(setup):
    d = excitation.design(setup, "cond", starts=1, seed=2, rate=1000.0, progress=False, max_iter=60)
    _respects(setup, d)
    assert d.criteria["cond"] < 0.8 * d.start_criteria["cond"]


def test_tight_torque_limit_still_respected(tmp_path):
    # A torque limit that binds (joint 1 needs about 4 N m against gravity near the horizontal).
    problem = load_problem(problem_file(tmp_path, LIMITS.replace("[15.0, 4.0]", "[5.0, 1.0]")))
    s = make_setup(problem.robot, problem.limits, 10.0, harmonics=3)
    d = excitation.design(s, "d", starts=1, rate=1000.0, progress=False, max_iter=80)
    _respects(s, d)
    assert min(d.margins["torque"]["fraction"]) < 0.05


def test_infeasible_torque_limit_exits_2(tmp_path, capsys):
    # Joint 1 within 0.25..1.0 rad of the horizontal: gravity needs at least 1.6 N m there at rest.
    limits = LIMITS.replace("[15.0, 4.0]", "[1.0, 4.0]").replace("[3.15, 1.40]", "[1.0, 1.40]")
    path = problem_file(tmp_path, limits)
    status = main(["excite", "--problem", str(path), "--out", str(tmp_path / "t.csv")])
    err = capsys.readouterr().err
    assert status == 2 and "'torque'" in err and "[limits]" in err and "joint 1" in err
    assert not (tmp_path / "t.csv").exists()


def test_missing_limits_exit_2(tmp_path, capsys):
    path = tmp_path / "p.toml"
    path.write_text(ROBOT)
    assert main(["excite", "--problem", str(path), "--out", str(tmp_path / "t.csv")]) == 2
    assert "[limits]" in capsys.readouterr().err


def test_command_writes_trajectory_figure_and_json(tmp_path):
    out = tmp_path / "traj.csv"
    args = ["excite", "--problem", str(problem_file(tmp_path)), "--out", str(out), "--duration", "10"]
    assert main([*args, "--harmonics", "3", "--starts", "1", "--rate", "200", "--no-progress"]) == 0
    frame = pd.read_csv(out)
    assert list(frame.columns) == ["t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau_ff1", "tau_ff2"]
    assert len(frame) == 2000 and out.with_suffix(".png").stat().st_size > 0
    payload = json.loads(out.with_suffix(".json").read_text())
    assert {"log_det", "cond"} <= set(payload["criteria"]) and payload["noise"]["sigma"] == [1.0, 1.0]
    assert set(payload["margins"]) == {"position", "velocity", "acceleration", "torque"}


# ---------------------------------------------------------------------------------------------- discrimination
def test_between_is_checked(tmp_path, capsys):
    args = ["excite", "--problem", str(problem_file(tmp_path)), "--out", str(tmp_path / "t.csv")]
    assert main([*args, "--criterion", "discriminate", "--between", "elasticity,gravity_wave"]) == 2
    assert "gravity_wave" in capsys.readouterr().err
    assert main([*args, "--criterion", "discriminate", "--between", "elasticity"]) == 2
    assert main([*args, "--criterion", "discriminate"]) == 2  # --between missing
    # No data to fit the causes on: said so.
    assert main([*args, "--criterion", "discriminate", "--between", "asymmetric_coulomb,elasticity"]) == 2
    assert "needs data" in capsys.readouterr().err


def test_discrimination_design_beats_its_start_within_limits(physical_problem, exp1):
    from ident_opt.excitation import discrimination

    s = make_setup(physical_problem.robot, physical_problem.limits, 8.0, harmonics=8, base_hz=0.5)
    d = discrimination.design(
        s, physical_problem.robot, exp1, "asymmetric_coulomb,elasticity", starts=1, seed=1, progress=False, max_iter=25
    )
    _respects(s, d)
    gaps = d.criteria
    assert gaps["discrimination"] == min(gaps["gap_asymmetric_coulomb_true"], gaps["gap_elasticity_true"])
    assert gaps["discrimination"] > 1.1 * d.start_criteria["discrimination"]
    # Fast motion separates an elastic mode at ~3 Hz from asymmetric friction far better than the first 8 s of
    # the data (mostly a rest): the design's gap is the larger.
    assert d.discrimination["ratio_same_duration"] > 2
    assert d.discrimination["candidates"]["elasticity"]["theta"]["frequency_hz"] == pytest.approx(3.1, abs=0.3)


def test_proof_report_and_index(setup, tmp_path):
    from ident_opt.excitation import proof as proof
    from ident_opt.report import excitation as report

    d = excitation.design(setup, "d", starts=1, seed=1, rate=100.0, progress=False, max_iter=20)
    ident = pd.DataFrame(
        [
            {"trajectory": label, "seed": s, "cond": 3.0, "log_det": 1.0, **{f"error_{k}": e * (1 + s) for k in KINDS}}
            for label, e in zip(proof.IDENTIFICATION, (0.01, 0.02, 0.1, 0.03))
            for s in range(2)
        ]
    )
    disc = pd.DataFrame(
        [
            {
                "noise": n,
                "true cause": c,
                "trajectory": t,
                "seed": 0,
                "margin": m * k,
                "named right": True,
                "criterion": m,
            }
            for n, k in (("simulator", 1.0), ("real residual", 0.1))
            for c, r in (("asymmetric_coulomb", 1.0), ("elasticity", 2.0))
            for t, m in ((proof.BASELINE, 100.0), ("discriminating design", 300.0 * r))
        ]
    )
    p = proof.Proof(
        20.0,
        2,
        ("asymmetric_coulomb", "elasticity"),
        {"asymmetric_coulomb": "asymmetric_coulomb", "elasticity": "elasticity"},
        {"d": d, "cond": d, "discriminate": d},
        setup,
        setup,
        ident,
        disc,
    )
    assert p.improvement()["D-optimal design"]["ols"] == pytest.approx(10.0)
    ratios = {"asymmetric_coulomb": pytest.approx(3.0), "elasticity": pytest.approx(6.0)}
    assert p.gap_ratio() == {"simulator": ratios, "real residual": ratios}
    files = report.write_proof(p, tmp_path / "excitation.md")
    assert "excitation/d.csv" in files and (tmp_path / "excitation_identification.csv").exists()
    text = (tmp_path / "excitation.md").read_text()
    assert "10× smaller" in text and "real residual noise, elasticity true" in text and "6× the MERIt-like" in text
    assert "excitation.md" in (tmp_path / "README.md").read_text()


KINDS = ("ols", "constrained", "ols (rests 0)", "constrained (rests 0)")


def test_simulator_follows_a_designed_trajectory(setup, tmp_path, capsys):
    from ident_opt.report import excitation as report

    d = excitation.design(setup, "d", starts=1, seed=1, rate=1000.0, progress=False, max_iter=20)
    traj = tmp_path / "traj.csv"
    report.write(d, setup, traj)
    problem = problem_file(tmp_path)
    run = tmp_path / "run.csv"
    args = ["simulate", "--problem", str(problem), "--trajectory-file", str(traj), "--no-noise", "--out", str(run)]
    assert main([*args, "--duration", "10"]) == 0
    logged = pd.read_csv(run)
    reference = np.column_stack([np.interp(logged["t"], d.t, d.q[:, j]) for j in range(2)])
    assert np.abs(logged[["q1", "q2"]].to_numpy() - reference).max() < 0.02  # tracking error of the 1 kHz loop
    assert main([*args, "--duration", "30"]) == 2  # the file covers 10 s only
    assert "covers" in capsys.readouterr().err
    pd.read_csv(traj).drop(columns=["ddq2"]).to_csv(traj, index=False)
    assert main([*args, "--duration", "10"]) == 2
    assert "ddq2" in capsys.readouterr().err
