"""A joint at rest is read with q̇ = 0 (`data.dataset.at_rest`, the loader's last step; docs/data-format.md): on a
simulated arm that rests half the time the fit then reads the true Coulomb friction (it read a third of it when the
estimated velocity's noise stood there), and the fleet's long logs read in pieces hold the same samples at rest
(`fleet.rests`: the speed scale in two counting passes, the mask carried from piece to piece)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import ident_opt as iopt
from ident_opt.data.dataset import at_rest
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fleet import rests
from ident_opt.numerics import signals
from ident_opt.problem.sections import REST_VELOCITY
from ident_opt.simulator.simulate import simulate_trial

ARM4 = Path(__file__).parent / "arms" / "arm4.toml"


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """arm4 (tests/arms/arm4.toml) on a 40 s `tud01` trial at 250 Hz, logged as t, q, τ (no derivatives): the loader
    estimates q̇ and q̈, as for a real log."""
    problem = iopt.load_problem(ARM4)
    trial = simulate_trial(
        problem.robot,
        trajectory="tud01",
        duration=40.0,
        rate_hz=250.0,
        seed=4321,
        limits=problem.limits,
        progress=False,
    )
    path = tmp_path_factory.mktemp("rests") / "trial.csv"
    trial.frame[[c for c in trial.frame.columns if not c.startswith(("dq", "ddq"))]].to_csv(path, index=False)
    (read,), _ = iopt.load_trials(problem, [path])
    return problem, read


def test_a_resting_joint_reads_zero_velocity_and_holding_again_changes_nothing(logged):
    _, d = logged
    rest = d.dq == 0
    assert 0.2 < rest.mean() < 0.9  # this motion rests often: what the rule is for
    again = at_rest(d)
    assert np.array_equal(again.dq, d.dq) and np.array_equal(again.instruments[0], d.instruments[0])
    assert (d.instruments[0][rest] == 0).all()  # the instruments' velocity is held at the same samples
    assert any(n.startswith("velocity read as 0 where a joint rests ([data] rest_velocity = 'auto')") for n in d.notes)


def test_the_fit_reads_the_simulated_coulomb_friction(logged):
    """Least squares' Coulomb levels within 3 % of the arm's (1.0, 1.5, 0.8, 0.15 N·m); with the estimated
    velocities' noise at rest they came out 0.30, 0.42, 0.21, 0.045 (results/slow_samples.md)."""
    problem, d = logged
    robot = problem.robot
    arm = robot.model(None)
    fit = estimators.fit_for(robot, "ols", estimators.statistics(arm, [d], "ols"), arm)
    fc = {p.name: v for p, v in zip(arm.parameters, fit.pi) if p.name.startswith("fc")}
    truth = {"fc_yaw": 1.0, "fc_shoulder": 1.5, "fc_elbow": 0.8, "fc_roll": 0.15}
    assert set(fc) == set(truth)
    for name, value in truth.items():
        assert fc[name] == pytest.approx(value, rel=0.03), (name, fc[name])


def _velocities(rng, n: int, m: int) -> np.ndarray:
    """Velocities with rests (exact zeros and tiny noise), ties and a slow stretch, (n, m) [rad/s]."""
    v = rng.normal(size=(n, m)) * np.repeat(rng.random((n // 50 + 1, m)) < 0.6, 50, axis=0)[:n]
    v[rng.random((n, m)) < 0.05] *= 1e-12
    v[: n // 10] = np.round(v[: n // 10], 1)  # ties
    return v


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_speed_scale_read_in_pieces_is_numpys_quantile(seed):
    rng = np.random.default_rng(seed)
    v = _velocities(rng, 20_000, 3)
    cuts = np.sort(rng.choice(np.arange(1, len(v)), 7, replace=False))
    pieces = np.split(v, cuts)
    scale = rests.SpeedScale(3)
    for p in pieces:
        scale.count(p)
    for p in pieces:
        scale.collect(p)
    np.testing.assert_allclose(scale.value(), np.quantile(np.abs(v), 0.95, axis=0), rtol=1e-14, atol=0)


@pytest.mark.parametrize(("seed", "dt"), [(0, 0.004), (1, 0.001), (2, 0.0002)])
def test_rests_held_in_pieces_are_the_whole_trials(seed, dt):
    """Pieces of any length (some shorter than the rule's look-ahead) give `signals.resting`'s mask of the whole."""
    rng = np.random.default_rng(seed)
    v = _velocities(rng, 6_000, 2)
    cuts = np.unique(np.concatenate([rng.choice(np.arange(1, len(v)), 12, replace=False), [5, 7, 8, 5990, 5995]]))
    pieces = [(p, {"i": np.arange(len(p))}) for p in np.split(v, cuts)]
    parts = list(rests.held(pieces, signals.rest_speed(v), dt))
    mask = np.concatenate([m for _, m in parts])
    assert np.array_equal(mask, signals.resting(v, dt, signals.HOLD_WINDOW_S))
    assert sum(len(a["i"]) for a, _ in parts) == len(v)


def test_the_problems_rest_velocity_decides_for_logged_and_estimated_velocities(logged, tmp_path):
    """ "auto" holds the velocities the loader estimated (above) and keeps logged ones as logged; "zero" holds logged
    ones too, "as_read" holds none; another value is refused, naming the key."""
    problem, estimated = logged
    rest = estimated.dq == 0
    assert estimated.rests_held and rest.any()
    frame = pd.DataFrame({"t": estimated.t})
    for j in range(estimated.q.shape[1]):
        frame[f"q{j + 1}"], frame[f"tau{j + 1}"] = estimated.q[:, j], estimated.tau[:, j]
        frame[f"dq{j + 1}"] = estimated.dq[:, j] + 1e-9  # logged velocities: never exactly 0
        frame[f"ddq{j + 1}"] = estimated.ddq[:, j]
    path = tmp_path / "logged.csv"
    frame.to_csv(path, index=False)
    read = {v: load_dataset(path, replace(problem.data, rest_velocity=v), problem.robot) for v in REST_VELOCITY}
    assert not read["auto"].rests_held and not (read["auto"].dq == 0).any()
    assert not read["as_read"].rests_held and not (read["as_read"].dq == 0).any()
    assert read["zero"].rests_held and np.array_equal(read["zero"].dq == 0, rest)
    text = (ARM4.read_text() + '\n[data]\nrest_velocity = "sometimes"\n').replace(
        'urdf = "arm4.urdf"', f'urdf = "{ARM4.parent / "arm4.urdf"}"'
    )
    (tmp_path / "p.toml").write_text(text)
    with pytest.raises(InputError, match="rest_velocity"):
        iopt.load_problem(tmp_path / "p.toml")
