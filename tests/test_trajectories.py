"""The simulator's references: limits, continuity and the `mixed` reference's blocks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ident_opt.simulator import trajectories as tr

DT = 0.001
CENTRE = 0.5 * (tr.Q_MIN + tr.Q_MAX)


def _integrates(r: tr.Reference) -> None:
    """q is the integral of dq, and dq of ddq, step by step on the 1 kHz grid: no jump anywhere. Each step's change
    is compared with the trapezoidal rule over that step; at a kink of ddq (a ramp's start or end, where ddq steps
    by up to A_MAX) the rule misses by up to A_MAX·DT/2, so a step that misses by more than A_MAX·DT is a jump.
    (The integral over the whole trial is not compared: those half-steps add up over a long point-to-point trial,
    to 0.02 rad/s over the 60 ramps of a 46 s tud01.)"""
    step_q = np.diff(r.q, axis=0) - 0.5 * (r.dq[1:] + r.dq[:-1]) * DT
    step_dq = np.diff(r.dq, axis=0) - 0.5 * (r.ddq[1:] + r.ddq[:-1]) * DT
    assert np.max(np.abs(step_q)) < np.max(tr.V_MAX) * DT
    assert np.max(np.abs(step_dq)) <= np.max(tr.A_MAX) * DT


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), duration=st.floats(12.0, 70.0))
def test_every_reference_stays_within_the_limits_and_is_continuous(seed, duration):
    for name in tr.TRAJECTORIES:
        r = tr.reference(name, duration, seed, DT)
        assert np.all(np.isfinite(r.q)) and np.all(np.isfinite(r.dq)) and np.all(np.isfinite(r.ddq))
        assert np.all(r.q >= tr.Q_MIN - 1e-9) and np.all(r.q <= tr.Q_MAX + 1e-9), name
        # `fourier`'s fade-in acts on a deviation that has grown by then: up to 1.26x the speed limit (its
        # docstring); the others stay within it.
        assert np.all(np.abs(r.dq) <= tr.V_MAX * (1.3 if name == "fourier" else 1.0) + 1e-9), name
        assert np.all(np.abs(r.ddq) <= tr.A_MAX + 1e-9), name
        _integrates(r)


@pytest.mark.parametrize("seed", [0, 7, 123])
def test_mixed_alternates_point_to_point_and_smooth_blocks_from_rest_at_the_centre(seed):
    r = tr.reference("mixed", 60.0, seed, DT)
    block = round(tr.MIXED_BLOCK_S / DT)
    for k in range(6):
        edge = k * block
        np.testing.assert_allclose(r.q[edge], CENTRE, atol=1e-9)  # every block starts at rest at the centre
        np.testing.assert_allclose(r.dq[edge], 0.0, atol=1e-9)
        part = slice(edge, edge + block)
        dq, ddq = r.dq[part], r.ddq[part]
        moving = np.abs(dq) > 1e-6
        if k % 2 == 0:  # point-to-point: moves at the velocity plateaus, and rests between them
            assert np.any(np.isclose(np.abs(dq), tr.V_MAX, rtol=1e-6) | (np.abs(dq) > 0.5 * tr.V_MAX))
            assert np.all(np.mean(~moving, axis=0) > 0.2)
        else:  # smooth: moving all the time but at its ends, reversing at low acceleration
            assert np.all(np.mean(moving, axis=0) > 0.9)
            assert np.max(np.abs(ddq)) < 0.7 * np.max(tr.A_MAX)
    np.testing.assert_allclose(r.q[-1], CENTRE, atol=1e-6)  # the last block ends where it started


def test_tud01_with_a_home_returns_there_at_rest():
    home = np.array([1.0, -0.5])
    t = np.arange(round(15.0 / DT)) * DT
    r = tr.tud01(t, np.random.default_rng(4), home=home)
    np.testing.assert_allclose(r.q[0], home)
    np.testing.assert_allclose(r.q[-1], home, atol=1e-9)
    np.testing.assert_allclose(r.dq[-round(0.5 / DT) :], 0.0, atol=1e-12)  # at rest for the last half second
    assert np.max(np.abs(r.q - home)) > 0.3  # and it did move


def test_unknown_reference_is_an_input_error():
    from ident_opt.errors import InputError

    with pytest.raises(InputError, match="mixed"):
        tr.reference("steps", 10.0, 0, DT)


def test_cli_simulates_the_mixed_reference_and_a_problem_file_can_ask_for_it(tmp_path):
    import json
    from pathlib import Path

    import pandas as pd

    from ident_opt.cli import main
    from ident_opt.errors import InputError
    from ident_opt.problem import load_problem

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "trial.csv"
    args = ["simulate", "--problem", str(root / "problems" / "tudor_2dof.toml"), "--out", str(out)]
    assert main([*args, "--trajectory", "mixed", "--duration", "21", "--no-noise"]) == 0
    truth = json.loads(out.with_name("trial.truth.json").read_text())
    assert truth["settings"]["trajectory"] == "mixed"
    q = pd.read_csv(out)[["q1", "q2"]].to_numpy()
    assert np.ptp(q[:1000], axis=0).max() > 0.3 and np.ptp(q[1000:2000], axis=0).max() > 0.3  # both blocks move
    text = (root / "problems" / "tudor_sim.toml").read_text()
    assert 'trajectory = "' in text
    for name, ok in (("mixed", True), ("steps", False)):
        path = tmp_path / f"{name}.toml"
        path.write_text(text.replace('trajectory = "tud01"', f'trajectory = "{name}"'))
        if ok:
            assert load_problem(path).simulate.trajectory == "mixed"
        else:
            with pytest.raises(InputError, match=r"\[simulate\].*mixed"):
                load_problem(path)
