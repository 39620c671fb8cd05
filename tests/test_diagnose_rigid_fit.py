"""The planar two-link diagnosis fits its rigid model with the recommended fit (issue 29, `docs/cli.md`, "Which fit the
tool stands behind"), like the n-joint one: the nominal rigid fit and every candidate that refits π use one
estimator, and a candidate with no column of its own is that rigid fit exactly.

References are independent of the diagnosis's plumbing: the estimator registry's own statistics of the same samples
(`fitting.estimators.statistics`), and `fitting.recommend.judge` on the training part for the recommendation.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ident_opt.data.loader import load_dataset
from ident_opt.diagnosis.planar import families as cands
from ident_opt.diagnosis.planar.engine import nominal_fit, weights_of
from ident_opt.diagnosis.split import prepare
from ident_opt.effects.families import PlanarFamily
from ident_opt.fitting import estimators
from ident_opt.numerics import signals
from ident_opt.simulator import simulate_trial

from .conftest import rigid_fit_runs


def _angles_only(robot, path, seed: int, trajectory: str = "fourier", duration: float = 20.0):
    """A simulated trial written as t, q, τ only (the loader estimates the derivatives and their instruments)."""
    trial = simulate_trial(robot, trajectory=trajectory, duration=duration, seed=seed, progress=False)
    trial.frame.drop(columns=["dq1", "dq2", "ddq1", "ddq2"]).to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def angles(physical_problem, tmp_path_factory):
    """A smooth trial as the loader reads it and the diagnosis prepares it, without its rest stretches (the samples
    left are compared as they are: no mean to take out, no velocity held at 0)."""
    spec = replace(physical_problem.data, header=True, columns={})
    path = _angles_only(physical_problem.robot, tmp_path_factory.mktemp("rigid") / "t.csv", seed=31)
    ds = prepare(load_dataset(path, spec, physical_problem.robot), "auto")
    return ds.subset(np.nonzero(np.all(signals.rest_runs(ds.dq) < 0, axis=1))[0])


@pytest.mark.parametrize("name", ["ols", "constrained", "robust"])
def test_the_rigid_fit_is_the_estimators_own_fit_and_a_candidate_without_columns_is_it(physical_problem, angles, name):
    """`planar_engine.nominal_fit` equals the registry's fit on statistics built by the registry itself from the same
    samples (instruments included), and a family with no column refitted against it returns the same π to round-off."""
    robot = physical_problem.robot
    train = angles
    rest = signals.rest_runs(train.dq)
    assert np.all(rest < 0) and train.n > 1000, "no rest stretch left"
    weights = weights_of(train)
    ctx = cands.Context(robot, train, train, weights, {}, 1.0 / train.rate_hz, rest, (0.0, 0.0), name)
    pi = nominal_fit(ctx)

    model = cands.NOMINAL
    same = replace(train, tau_filtered=None)  # the registry fits `tau_fit`: here the diagnosis's low-passed τ
    reference = estimators.fit_for(robot, name, estimators.statistics(model, [same], name), model, weights=weights).pi
    np.testing.assert_allclose(pi, reference, rtol=1e-7, atol=1e-9 * np.abs(reference).max())

    bare = cands.fit(PlanarFamily("none", None, None), "rigid_fit", ctx)
    np.testing.assert_allclose(model.vector(bare.parameters), pi, rtol=1e-10, atol=1e-12)
    if name == "robust":  # the instruments are used: the IV fit is not least squares on the same samples
        ols = estimators.fit_for(robot, "ols", estimators.statistics(model, [same], "ols"), model, weights=weights)
        assert not np.allclose(pi, ols.pi, rtol=1e-6)


def test_the_command_uses_the_recommended_fit_on_a_planar_arm(physical_problem, tmp_path, capsys):
    """`diagnose` on a two-link problem: the rigid fit's estimator is `fitting.recommend`'s pick on the training part
    (computed here independently), named with its reason on the terminal and in the report and JSON; --estimator is
    honoured; the physical-parameter NLP, which cannot carry a cause's columns, exits 2 and writes nothing."""
    from ident_opt.cli import main
    from ident_opt.fitting.recommend import judge

    robot = physical_problem.robot
    text = physical_problem.path.read_text()
    problem = tmp_path / "sim.toml"
    problem.write_text(text[: text.index("[data]")])
    path = _angles_only(robot, tmp_path / "trial.csv", seed=32, trajectory="tud01", duration=40.0)
    spec = replace(physical_problem.data, header=True, columns={})
    ds = load_dataset(path, spec, robot)
    head = ds.subset(np.nonzero(ds.t <= ds.t[0] + 0.7 * (ds.t[-1] - ds.t[0]))[0])
    expected = judge(robot, robot.model(), [head], spec.conversions, spec.derivative_cutoff_hz)

    base = ["diagnose", "--problem", str(problem), "--data", str(path), "--no-progress"]
    fits = rigid_fit_runs(capsys, base, tmp_path, expected.estimator, "ols")
    if expected.estimator != "ols":
        assert fits[None] != fits["ols"], "the asked estimator changes the rigid fit"
    assert main([*base, "--out", str(tmp_path / "x"), "--estimator", "nlp_physical"]) == 2
    err = capsys.readouterr().err
    assert "nlp_physical" in err and "Traceback" not in err and not (tmp_path / "x").exists()


def test_report_lists_show_a_level_held_at_its_bound_as_zero():
    """A Coulomb level the consistent fit holds at 0 comes out of the conic solver at ~1e-11 N m: the report's
    per-joint lists show it as 0 beside levels of 1 N m, and keep small numbers that are all of a list."""
    from ident_opt.report.diagnosis import pair

    assert pair([1.0301, 6.12e-11], "N m") == "[1.03, 0] N m"
    assert pair([2e-5, 3e-5]) == "[2e-05, 3e-05]"
    assert pair([float("nan"), 0.5]) == "[—, 0.5]"
