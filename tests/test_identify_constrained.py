"""The physically consistent fit: OLS when nothing binds, always consistent, optimal among feasible points."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PlanarArm
from ident_opt.evaluation.constraints import multisine_trial
from ident_opt.fitting import constrained
from ident_opt.fitting.constrained import constraint_slacks, fit_bounded, fit_constrained, solve_constrained
from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.stats import Stats

RIGID = PlanarArm()
ARM = PlanarArm(("armature",))


def _stats(trial, model):
    return Stats.from_data(model, trial.q, trial.dq, trial.ddq, trial.tau)


@pytest.fixture(scope="module")
def truth(physical_problem):
    return ARM.vector(datasheet_pi(physical_problem.robot, "physical"))


def test_equals_ols_when_no_constraint_is_active(truth):
    st = _stats(multisine_trial(ARM, truth, duration=30.0, seed=1), ARM)
    ols = fit_ols(st, ARM)
    assert ols.consistent
    for shortcut, backend in ((True, "clarabel"), (False, "clarabel"), (False, "cvxpy")):
        # shortcut=False: the conic solver itself must land on OLS
        con = fit_constrained(st, ARM, margin=1e-6, shortcut=shortcut, backend=backend)
        assert con.active == []
        np.testing.assert_allclose(con.pi, ols.pi, rtol=1e-8, atol=1e-8)


@pytest.mark.parametrize("seed", range(4))
def test_direct_clarabel_blocks_equal_the_cvxpy_statement(truth, seed):
    """The hand-assembled named blocks and the cvxpy formulation are the same program."""
    amp = (0.8, 0.05) if seed % 2 else (0.05, 0.8)
    st = _stats(multisine_trial(ARM, truth, duration=2.5, seed=700 + seed, amplitude=amp), ARM)
    a = fit_constrained(st, ARM, margin=1e-5, shortcut=False)
    b = fit_constrained(st, ARM, margin=1e-5, shortcut=False, backend="cvxpy")
    assert a.active == b.active
    # Same optimal value (short trials leave flat directions, so compare the objective, not π) ...
    assert st.rss(a.pi).sum() == pytest.approx(st.rss(b.pi).sum(), rel=1e-8)
    # ... and π agrees to a small fraction of its standard error.
    assert np.all(np.abs(a.pi - b.pi) <= 0.01 * a.se + 1e-9)


def test_rich_data_ols_and_constrained_agree_within_standard_errors(truth):
    st = _stats(multisine_trial(ARM, truth, duration=30.0, seed=2), ARM)
    ols, con = fit_ols(st, ARM), fit_constrained(st, ARM, shortcut=False)
    assert np.all(np.abs(con.pi - ols.pi) <= ols.se)


def test_consistent_on_real_data_where_ols_is_not(exp1):
    st = _stats(exp1, RIGID)
    ols = fit_ols(st, RIGID)
    assert ols.as_dict()["a3"] < 0 and not ols.consistent
    margin = 1e-4
    con = fit_constrained(st, RIGID, margin=margin)
    assert con.min_mass_eigenvalue >= margin * (1 - 1e-6)
    assert con.friction_ok and con.consistent
    assert {"mass_pd_q2_0", "mass_pd_q2_pi"} & set(con.active)
    # Optimal among feasible points: no worse than OLS's projection-free alternatives that are feasible.
    datasheet = RIGID.vector(datasheet_pi(exp1_robot(), "physical"))
    assert st.rss(con.pi).sum() <= st.rss(datasheet).sum()
    assert st.rss(con.pi).sum() >= st.rss(ols.pi).sum()


def exp1_robot():
    from pathlib import Path

    from ident_opt.problem import load_problem

    return load_problem(Path(__file__).resolve().parents[1] / "problems" / "tudor_2dof.toml").robot


@pytest.mark.parametrize("seed", range(8))
def test_always_consistent_on_short_poor_trials(truth, seed):
    amp = (0.8, 0.0) if seed % 2 else (0.0, 0.8)
    trial = multisine_trial(ARM, truth, duration=2.0 + 0.4 * seed, seed=500 + seed, amplitude=amp)
    st = _stats(trial, ARM)
    margin = 1e-5
    con = fit_constrained(st, ARM, margin=margin)
    slacks = constraint_slacks(ARM, con.pi, margin)
    assert min(slacks.values()) >= -1e-8, slacks
    # Local optimality: no small feasible move along a random direction lowers the objective.
    rng = np.random.default_rng(seed)
    base = st.rss(con.pi).sum()
    for _ in range(200):
        trial_pi = con.pi + 1e-4 * rng.normal(size=ARM.n_params) * np.maximum(np.abs(con.pi), 1e-2)
        if min(constraint_slacks(ARM, trial_pi, margin).values()) >= 0:
            assert st.rss(trial_pi).sum() >= base * (1 - 1e-9)


def test_prior_and_bounds(truth):
    st = _stats(multisine_trial(ARM, truth, duration=4.0, seed=9, amplitude=(0.8, 0.0)), ARM)
    strong = fit_constrained(st, ARM, prior=truth, prior_weight=1e6)
    np.testing.assert_allclose(strong.pi, truth, rtol=1e-3, atol=1e-6)
    lb = np.full(ARM.n_params, -np.inf)
    ub = np.full(ARM.n_params, np.inf)
    ub[ARM.names.index("b1")] = 3.0  # below the truth 3.72: must bind
    fit = fit_constrained(st, ARM, bounds=(lb, ub))
    assert "upper_b1" in fit.active and fit.as_dict()["b1"] == pytest.approx(3.0, abs=1e-6)
    box = fit_bounded(st, ARM, lb, ub)
    assert box.as_dict()["b1"] <= 3.0 + 1e-7 and box.method == "bounded"
    with pytest.raises(ValueError):
        fit_constrained(st, ARM, prior_weight=1.0)


def test_weighted_constrained_equals_weighted_ols_when_inactive(truth):
    st = _stats(multisine_trial(ARM, truth, duration=30.0, seed=21, noise=(1.0, 0.1)), ARM)
    wls = fit_ols(st, ARM, weights="wls")
    con = fit_constrained(st, ARM, weights="wls", shortcut=False)
    assert con.active == [] and wls.consistent
    np.testing.assert_allclose(con.pi, wls.pi, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(con.weights, wls.weights)


def test_armature_is_kept_nonnegative(truth):
    """Short, noisy, mostly-joint-2 trials push OLS's ia2 (a3 and ia2 share ddq2 on joint 2) below 0 in some
    seeds: the constrained fit must keep it ≥ 0 (its own named constraint)."""
    negatives = 0
    for seed in range(12):
        trial = multisine_trial(ARM, truth, duration=2.0, seed=900 + seed, amplitude=(0.05, 0.8), noise=(1.0, 1.0))
        st = _stats(trial, ARM)
        ols, con = fit_ols(st, ARM), fit_constrained(st, ARM)
        negatives += ols.as_dict()["ia2"] < 0
        assert con.as_dict()["ia2"] >= -1e-9 and con.consistent
        if ols.as_dict()["ia2"] < 0 and ols.min_mass_eigenvalue > 0 and ols.friction_ok:
            assert "armature_ia2" in con.active
    assert negatives > 0  # the test exercises the constraint


def test_bad_arguments_are_named(truth):
    st = _stats(multisine_trial(ARM, truth, duration=3.0, seed=31), ARM)
    with pytest.raises(ValueError, match="shape"):
        fit_constrained(st, ARM, prior=np.ones(3), prior_weight=1.0)
    lb, ub = np.zeros(ARM.n_params), np.ones(ARM.n_params)
    lb[0] = 2.0
    with pytest.raises(ValueError, match="a1"):
        fit_constrained(st, ARM, bounds=(lb, ub))
    with pytest.raises(ValueError, match="backend"):
        fit_constrained(st, ARM, backend="mosek")


def _active_and_inactive(truth):
    """(statistics, model) pairs: a short one-joint trial where OLS is inconsistent, and a rich trial where
    it is consistent (nothing binds)."""
    short = _stats(multisine_trial(ARM, truth, duration=2.0, seed=702, amplitude=(0.05, 0.8)), ARM)
    rich = _stats(multisine_trial(ARM, truth, duration=30.0, seed=1), ARM)
    assert not fit_ols(short, ARM).consistent and fit_ols(rich, ARM).consistent
    return {"active": short, "inactive": rich}


@pytest.mark.parametrize("case", ["active", "inactive"])
@pytest.mark.parametrize(
    "options",
    [{}, {"margin": 1e-3}, {"weights": "wls"}, {"shortcut": False}, {"prior_weight": 1e-6}, {"bounds": "b1<=3"}],
)
def test_solve_constrained_is_fit_constrained_pi(truth, case, options):
    """The lean solve returns the π of the full fit (one implementation), active constraints or not."""
    st = _active_and_inactive(truth)[case]
    options = dict(options)
    if options.pop("bounds", None):
        ub = np.full(ARM.n_params, np.inf)
        ub[ARM.names.index("b1")] = 3.0  # below the truth 3.72
        options["bounds"] = (np.full(ARM.n_params, -np.inf), ub)
    if "prior_weight" in options:
        options["prior"] = truth
    fit = fit_constrained(st, ARM, **options)
    pi = solve_constrained(st, ARM, **options)
    np.testing.assert_allclose(pi, fit.pi, rtol=1e-10, atol=0)
    # The two cases are what they claim: the solver ran with constraints binding, or OLS was returned.
    if case == "active" or "bounds" in options:
        assert fit.active
    elif not options.get("shortcut", True) or options.get("prior_weight"):
        assert fit.active == []
    else:
        assert fit.active == [] and fit.status.startswith("optimal (unconstrained")
        np.testing.assert_array_equal(pi, fit_ols(st, ARM, weights=options.get("weights")).pi)


def test_structure_cache_keeps_models_and_options_apart(truth, exp1):
    """Alternating models (rigid / with armature), margins, sign constraints and bounds through the cached
    structure gives exactly what a fresh cache gives, and each option still has its own effect."""
    arm = _stats(multisine_trial(ARM, truth, duration=2.0, seed=702, amplitude=(0.05, 0.8)), ARM)
    rigid = _stats(exp1, RIGID)
    ub = np.full(ARM.n_params, np.inf)
    ub[ARM.names.index("b1")] = 3.0
    configs = [
        (rigid, RIGID, {"margin": 1e-6}),
        (arm, ARM, {"margin": 1e-6}),
        (rigid, RIGID, {"margin": 1e-3}),
        (arm, ARM, {"margin": 1e-3}),
        (arm, ARM, {"margin": 1e-3, "friction": False}),
        (arm, ARM, {"bounds": (np.full(ARM.n_params, -np.inf), ub)}),
        (arm, ARM, {}),
    ]
    fresh = []
    for st, model, options in configs:
        constrained._structure.cache_clear()
        fresh.append(solve_constrained(st, model, **options))
    for order in (range(len(configs)), reversed(range(len(configs))), [0, 3, 1, 5, 2, 6, 4, 0, 1]):
        for i in order:
            st, model, options = configs[i]
            np.testing.assert_array_equal(solve_constrained(st, model, **options), fresh[i])
    # The options reach the solution: the mass constraint binds at each margin, signs ≥ 0 only when
    # asked for (friction, armature), the bound only when given.
    for i in (0, 1, 2, 3):
        st, model, options = configs[i]
        # binding to the solver's accuracy (tolerance 1e-11 on a problem scaled per sample), far below 1e-3
        assert model.min_mass_eigenvalue(fresh[i]) == pytest.approx(options["margin"], abs=1e-8)
    assert not np.allclose(fresh[1], fresh[3]) and not np.allclose(fresh[0], fresh[2])
    signed = [ARM.names.index(n) for n in constrained.sign_constraints(ARM).values()]
    assert fresh[4][signed].min() < 0 <= fresh[3][signed].min() + 1e-9
    assert fresh[5][ARM.names.index("b1")] == pytest.approx(3.0, abs=1e-6) != fresh[6][ARM.names.index("b1")]
