"""Nonlinear fits: the generic expression fitter, and physical parameters consistent by construction."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PlanarArm
from ident_opt.evaluation.constraints import multisine_trial
from ident_opt.fitting.nlp import fit_physical
from ident_opt.fitting.stats import Stats
from ident_opt.numerics.nlp import fit_expression

ARM = PlanarArm(("armature",))


def test_fit_expression_recovers_a_stribeck_velocity():
    rng = np.random.default_rng(0)
    dq = rng.uniform(-0.3, 0.3, 400)
    fs_true, vs_true = 0.4, 0.05
    y = fs_true * np.sign(dq) * np.exp(-((dq / vs_true) ** 2)) + 0.001 * rng.normal(size=dq.size)
    v, theta = ca.SX.sym("dq"), ca.SX.sym("theta", 2)
    expr = theta[0] * ca.sign(v) * ca.exp(-((v / theta[1]) ** 2))
    fit = fit_expression(expr, theta, [v], [dq], y, x0=[0.1, 0.2], lb=[0.0, 1e-3], ub=[10.0, 1.0], names=["fs", "vs"])
    assert fit.success
    assert fit.as_dict()["vs"] == pytest.approx(vs_true, rel=0.02)
    assert fit.as_dict()["fs"] == pytest.approx(fs_true, rel=0.02)


def test_fit_expression_respects_bounds_and_shapes():
    x = np.linspace(0, 1, 50)
    s, theta = ca.SX.sym("x"), ca.SX.sym("theta")
    fit = fit_expression(theta * s, theta, [s], [x], 2.0 * x, x0=[0.5], lb=[0.0], ub=[1.5])
    assert fit.values[0] == pytest.approx(1.5, abs=1e-6)
    with pytest.raises(ValueError):
        fit_expression(theta * s, theta, [s], [x], np.zeros((50, 2)), x0=[0.5])


def test_physical_fit_is_consistent_and_matches_the_truth_on_clean_data(physical_problem):
    robot = physical_problem.robot
    truth = ARM.vector(datasheet_pi(robot, "physical"))
    trial = multisine_trial(ARM, truth, duration=20.0, seed=11, noise=(0.0, 0.0))
    st = Stats.from_data(ARM, trial.q, trial.dq, trial.ddq, trial.tau)
    # Start far from the truth: the datasheet is the start, so perturb the data's truth instead.
    fit = fit_physical(st, robot, ARM)
    assert fit.method == "nlp_physical" and fit.consistent
    np.testing.assert_allclose(fit.pi, truth, rtol=1e-4, atol=1e-6)
    phys = fit.details["physical"]
    assert phys["m1"] > 0 and phys["m2"] > 0 and 0 <= phys["lc2"] <= robot.link2.length


def test_physical_fit_on_data_from_another_arm(physical_problem):
    """Truth = a heavier arm than the datasheet (so the start is wrong): π is still recovered."""
    robot = physical_problem.robot
    truth = ARM.vector(datasheet_pi(robot, "physical")) * np.array([1.3, 1.2, 1.2, 1.25, 1.2, 0.7, 1.5, 1.2, 0.8, 1.1])
    trial = multisine_trial(ARM, truth, duration=20.0, seed=12, noise=(0.0, 0.0))
    fit = fit_physical(trial, robot, ARM)  # a Dataset works too
    np.testing.assert_allclose(fit.pi, truth, rtol=1e-3, atol=1e-5)
    assert fit.min_mass_eigenvalue > 0
