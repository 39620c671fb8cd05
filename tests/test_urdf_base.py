"""Base parameters of a URDF arm: their number is the numerical rank, they reproduce τ, OLS recovers them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ident_opt.arm.chain import ChainArm
from ident_opt.consistency import necessarily_nonnegative
from ident_opt.fitting.base import base_parameters, fit_base_ols, random_regressor
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem

KUKA = Path(__file__).resolve().parents[1] / "data" / "kuka_lwr4" / "kuka_lwr4.urdf"


@pytest.fixture(scope="module")
def kuka() -> ChainArm:
    return ChainArm(str(KUKA), tuple(f"lwr_{i}_joint" for i in range(7)), offsets=True)


def test_count_is_the_numerical_rank(kuka):
    base = base_parameters(kuka)
    W = random_regressor(kuka, 150, seed=7)  # other states than the ones the base was found on
    assert base.rank == np.linalg.matrix_rank(W) == 69
    assert len(base.names) == base.rank == len(set(base.names))
    # The structure: the first joint (vertical axis) sees only izz of link 1, with its own armature
    assert base.definitions()["izz_lwr_1_link"] == "izz_lwr_1_link + 1·izz_lwr_2_link + 1·ia_lwr_0_joint"
    assert "m_lwr_1_link" not in base.names


def test_base_regressor_reproduces_torques(kuka):
    base = base_parameters(kuka)
    W = random_regressor(kuka, 50, seed=11)
    pi = np.random.default_rng(2).normal(size=kuka.n_params)
    np.testing.assert_allclose(W[:, base.independent] @ base.project(pi), W @ pi, atol=1e-10)
    np.testing.assert_allclose(W @ base.standard(base.project(pi)), W @ pi, atol=1e-10)


def test_ols_on_base_parameters_recovers_them(kuka):
    rng = np.random.default_rng(3)
    q, dq, ddq = (rng.uniform(-2, 2, (400, 7)) for _ in range(3))
    truth = kuka.cad_parameters()
    truth[kuka.n_link_params :] = rng.uniform(0.1, 1.0, kuka.n_params - kuka.n_link_params)
    tau = kuka.predict(truth, q, dq, ddq)
    noisy = tau + 0.01 * rng.standard_normal(tau.shape)
    fit = fit_base_ols(Stats.from_regressor(kuka.regressor(q, dq, ddq), noisy), kuka)
    base = fit.base
    err = np.abs(fit.fit.pi - base.project(truth))
    assert np.all(err < 6 * fit.fit.se + 1e-12)  # within 6 SE of the truth, every one of them
    assert np.all(fit.fit.se > 0) and np.all(fit.fit.se < 0.1)
    summary = fit.summary()
    assert set(summary) == set(base.names) and {"value", "se", "definition"} <= set(summary["izz_lwr_1_link"])


def _random_consistent(arm: ChainArm, rng) -> np.ndarray:
    """π of random point-mass bodies (a density, so every pseudo-inertia ⪰ 0) with positive joint terms."""
    pi = np.zeros(arm.n_params)
    for i in range(arm.n_joints):
        m = rng.uniform(0.1, 2.0, 5)
        r = rng.normal(scale=0.2, size=(5, 3))
        h = m @ r
        inertia = sum(mk * (rk @ rk * np.eye(3) - np.outer(rk, rk)) for mk, rk in zip(m, r))
        pi[10 * i : 10 * i + 10] = [m.sum(), *h, inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2],
                                    inertia[1, 2], inertia[2, 2]]  # fmt: skip
    pi[arm.n_link_params :] = rng.uniform(0.0, 1.0, arm.n_params - arm.n_link_params)
    return pi


def test_necessarily_nonnegative_base_parameters(kuka):
    base = base_parameters(kuka)
    definite = necessarily_nonnegative(kuka, base.K)
    names = dict(zip(base.names, definite))
    assert names["izz_lwr_1_link"] and not names["mx_lwr_7_link"] and not names["off_lwr_0_joint"]
    rng = np.random.default_rng(8)
    values = np.array([base.project(_random_consistent(kuka, rng)) for _ in range(300)])
    assert np.all(values[:, definite] >= -1e-12)
    # and the test is not vacuous: some of the other base parameters do go negative for consistent arms
    assert np.any(values[:, ~definite] < 0)


@pytest.mark.parametrize(("problem", "count"), [("kuka_lwr4", 69), ("franka_panda", 69), ("staubli_tx40", 58)])
def test_count_is_the_numerical_rank_on_the_shipped_robots(problem, count):
    arm = load_problem(Path(__file__).resolve().parents[1] / "problems" / f"{problem}.toml").robot.arm
    W = random_regressor(arm, 150, seed=3)
    assert base_parameters(arm).rank == np.linalg.matrix_rank(W) == count
