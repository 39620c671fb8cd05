"""The fit the tool stands behind (`fitting.recommend`) and the instrumental-variable machinery under it: the
two-stage statistics against 2SLS computed from the samples, the robust fit against them where no constraint binds,
the recommendation on trials whose truth is known (the cut-off study's plant, seeds the study does not use), and
advice that never asks for what the run already did."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ident_opt.data.loader import load_dataset
from ident_opt.evaluation.cutoff_plant import Condition, simulate
from ident_opt.evaluation.cutoff_study import _error, truth
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.recommend import choose
from ident_opt.problem import DataSpec, load_problem

from .conftest import PROBLEMS


@pytest.fixture(scope="module")
def dfki():
    return load_problem(PROBLEMS / "dfki_c0.toml")


def simulated(tmp_path, problem, kind: str, rate: float, noise: float, seed: int, setting="auto", rests="auto"):
    """One trial of the study's plant (seeds ≥ 50: never the study's), read back by the loader (`rests`: its
    `[data] rest_velocity`)."""
    arm, pi = truth(problem.robot)
    path = tmp_path / f"{kind}_{seed}.csv"
    simulate(arm, pi, Condition(kind, rate, noise), seed, duration=15.0).to_csv(path, index=False)
    return load_dataset(path, DataSpec(derivative_cutoff_hz=setting, rest_velocity=rests), problem.robot), arm, pi


def test_two_stage_statistics_are_2sls(tmp_path, dfki):
    """OLS on `InstrumentStats.two_stage()` equals two-stage least squares computed from the samples: each joint's
    torque equation projected onto its own instruments, stacked, solved."""
    d, arm, _ = simulated(tmp_path, dfki, "driven", 250.0, 3.0, seed=51)
    Y = arm.regressor(d.q, d.dq, d.ddq)
    Z = arm.regressor(d.q, *d.instruments)
    iv = InstrumentStats.from_regressors(Y, Z, d.tau_fit)
    rows, rhs = [], []
    for j in range(arm.n_joints):
        Zj, Yj, tj = Z[:, j], Y[:, j], d.tau_fit[:, j]
        keep = np.abs(Zj).sum(axis=0) > 0
        coef = np.linalg.lstsq(Zj[:, keep], np.column_stack([Yj, tj]), rcond=None)[0]
        projected = Zj[:, keep] @ coef
        rows.append(projected[:, :-1])
        rhs.append(projected[:, -1])
    direct = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    np.testing.assert_allclose(fit_ols(iv.two_stage(), arm).pi, direct, rtol=1e-6, atol=1e-9)


def test_robust_is_2sls_where_no_constraint_binds(tmp_path, dfki):
    d, arm, _ = simulated(tmp_path, dfki, "swing_up", 250.0, 1.0, seed=52)
    stats = estimators.statistics(arm, [d])
    robust = estimators.fit_for(dfki.robot, "robust", stats, arm)
    assert robust.method == "robust" and robust.active == []
    two_sls = fit_ols(stats.two_stage(), arm)
    np.testing.assert_allclose(robust.pi, two_sls.pi, rtol=1e-5, atol=1e-7)
    # its standard errors are the 2SLS ones, from the residuals of the measured torque: wider than OLS's
    ols = estimators.fit("ols", stats, arm)
    assert np.all(robust.se >= 0.999 * ols.se)


def test_correlated_residuals_widen_the_standard_errors(tmp_path, dfki):
    """A trial low-passed at f_c carries about n · 2 f_c / f_s independent residuals: SEs grow by √(f_s / 2 f_c)."""
    d, arm, _ = simulated(tmp_path, dfki, "driven", 500.0, 1.0, seed=53)
    stats = estimators.statistics(arm, [d], "ols")
    assert stats.effective == pytest.approx(d.n * 2 * d.cutoff_hz / d.rate_hz)
    plain = estimators.fit("ols", type(stats)(stats.G, stats.b, stats.s, stats.n), arm)
    widened = estimators.fit("ols", stats, arm)
    np.testing.assert_allclose(widened.se / plain.se, np.sqrt(d.rate_hz / (2 * d.cutoff_hz)), rtol=1e-9)


def test_noise_in_the_regressor_makes_the_robust_fit_the_recommended_one(tmp_path, dfki):
    """A passively swinging joint at three times the noise: the cut-off its spectrum supports still lets noise bias
    least squares; the run sees it (OLS against IV) and recommends the robust fit, which is closer to the truth."""
    d, arm, pi = simulated(tmp_path, dfki, "passive", 500.0, 3.0, seed=54)
    found = choose(dfki, [d], model=arm)
    fit = found.fit(dfki.robot, arm, [d])
    assert found.estimator == "robust"
    consistent = estimators.fit_for(dfki.robot, "constrained", estimators.statistics(arm, [d], "constrained"), arm)
    assert _error(arm, fit.pi, pi) < 0.7 * _error(arm, consistent.pi, pi)


def test_a_clean_trial_keeps_the_consistent_fit_and_raises_the_cutoff(tmp_path, dfki):
    d, arm, pi = simulated(tmp_path, dfki, "swing_up", 500.0, 0.5, seed=55)
    found = choose(dfki, [d], model=arm)
    fit = found.fit(dfki.robot, arm, [d])
    assert found.estimator == dfki.robot.default_estimator
    assert found.factor > 1 and found.at_cutoff([d])[0].cutoff_hz > d.cutoff_hz
    assert _error(arm, fit.pi, pi) < 0.01


def test_advice_never_asks_for_what_the_run_did(tmp_path, dfki, capsys):
    """With "auto" no warning advises setting it to "auto"; with a fixed cut-off above what the data support the
    advice gives the supported one."""
    from ident_opt.cli import main

    simulated(tmp_path, dfki, "passive", 500.0, 3.0, seed=56)
    csv = next(tmp_path.glob("passive_56.csv"))
    robot = (PROBLEMS / "dfki_c0.toml").read_text().split("# Angles are 0 when")[0]
    messages = {}
    for setting in ('"auto"', "40.0"):
        problem = tmp_path / f"p{len(messages)}.toml"
        problem.write_text(robot + f"[data]\ntrials = [{json.dumps(str(csv))}]\nderivative_cutoff_hz = {setting}\n")
        out = tmp_path / f"c{len(messages)}.json"
        argv = [
            "compare",
            "--problem",
            str(problem),
            "--json",
            str(out),
            "--out",
            str(tmp_path / "out"),
            "--no-progress",
        ]
        assert main(argv) == 0
        result = json.loads(out.read_text())
        assert result["recommended"] in ("robust", "constrained") and result["recommended_why"]
        assert all(set(w) == {"code", "message"} for w in result["warnings"])
        messages[setting] = " ".join(w["message"] for w in result["warnings"])
    capsys.readouterr()
    assert '"auto"' not in messages['"auto"']
    assert 'derivative_cutoff_hz = "auto"' in messages["40.0"]


def test_the_robust_fits_errors_cover_what_its_probes_move_it_by(tmp_path, dfki):
    """With probes, the robust fit's standard errors are √(se_2SLS² + Σ b_k²), b_k how far the same fit moves when
    the trial is read with its instruments, and with its whole derivatives, at half their cut-off — computed here
    from the two reads built by hand; without probes they are the 2SLS errors alone."""
    from dataclasses import replace

    from ident_opt.data.dataset import refiltered
    from ident_opt.numerics.derivatives import instrument_derivatives

    d, arm, _ = simulated(tmp_path, dfki, "passive", 250.0, 0.5, seed=61)
    robot = dfki.robot
    plain = estimators.fit_for(robot, "robust", estimators.statistics(arm, [d], "robust"), arm)
    probed = estimators.fit_for(robot, "robust", estimators.statistics(arm, [d], "robust", probes=True), arm)
    reads = (
        replace(d, instruments=instrument_derivatives(d.t, d.q, 0.5 * d.cutoff_hz)),
        refiltered(d, 0.5 * d.cutoff_hz),
    )
    moved = [
        estimators.fit_for(robot, "robust", estimators.statistics(arm, [r], "robust"), arm).pi - plain.pi for r in reads
    ]
    np.testing.assert_allclose(probed.pi, plain.pi, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(probed.details["se_noise"], plain.se, rtol=1e-12)
    expected = np.sqrt(plain.se**2 + sum(m**2 for m in moved))
    np.testing.assert_allclose(probed.se, expected, rtol=1e-9)
    assert np.all(probed.se >= plain.se) and np.any(probed.se > 1.5 * plain.se)


@pytest.mark.parametrize("rests", ["as_read", "auto"])
def test_the_recommended_robust_fit_covers_the_truth_where_2sls_errors_do_not(tmp_path, dfki, rests):
    """On trials of the study's plant where the robust fit is recommended (a passive joint at 100 and 250 Hz, steps:
    conditions where the 2SLS errors are too narrow; seeds 71–74, never the study's nor used to choose the probes),
    the recommended fit's judged parameters lie within two of its standard errors in at least 85 % of cases. With
    the estimated velocities read as they are at rest ("as_read"), far more often than within two of the 2SLS
    errors; with them held at 0 (the loader's default for estimated velocities) the bias those errors miss is mostly
    gone (2SLS covers 0.875, the recommended fit 0.9): not less often."""
    from dataclasses import replace

    from ident_opt.fitting.trust import JUDGED_KINDS

    problem = replace(dfki, data=DataSpec(derivative_cutoff_hz="auto", rest_velocity=rests))
    covered = {"2sls": [], "recommended": []}
    for kind, rate, noise in (("passive", 100.0, 0.5), ("passive", 250.0, 0.5), ("steps", 250.0, 1.0)):
        for seed in (71, 72, 73, 74):
            d, arm, pi = simulated(tmp_path, dfki, kind, rate, noise, seed, rests=rests)
            found = choose(problem, [d], model=arm)
            fit = found.fit(dfki.robot, arm, [d])
            if found.estimator != "robust":
                continue
            judged = [i for i, p in enumerate(arm.parameters) if p.kind in JUDGED_KINDS]
            err = np.abs(fit.pi[judged] - pi[judged])
            covered["2sls"] += list(err <= 2 * fit.details["se_noise"][judged])
            covered["recommended"] += list(err <= 2 * fit.se[judged])
    assert len(covered["recommended"]) >= 30, "the robust fit is recommended on most of these trials"
    share = {k: float(np.mean(v)) for k, v in covered.items()}
    assert share["recommended"] >= 0.85, share
    assert share["recommended"] >= share["2sls"] + (0.1 if rests == "as_read" else 0.0), share
