"""The instrumental-variable estimate: exactly OLS when the instruments are the regressor itself, and on a
noisy trial (errors in the regressor) far closer to the truth than OLS at the same cut-off."""

from __future__ import annotations

import numpy as np

from ident_opt.arm.planar import PHYSICAL
from ident_opt.data.loader import load_dataset
from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.iv import InstrumentStats, fit_iv
from ident_opt.problem import DataSpec

from .test_cutoff import trial


def test_iv_with_the_regressor_as_instrument_is_ols(tmp_path):
    path, robot, _ = trial(tmp_path, rate=200.0, noise=1e-4, seed=5)
    d = load_dataset(path, DataSpec(), robot)
    Y = PHYSICAL.regressor(d.q, d.dq, d.ddq)
    iv = InstrumentStats.from_regressors(Y, Y, d.tau)
    ols = fit_ols(iv.stats, PHYSICAL)
    np.testing.assert_allclose(fit_iv(iv, PHYSICAL).pi, ols.pi, rtol=1e-8, atol=1e-12)
    # ... and then the IV sandwich is OLS's sandwich (A = K = G).
    np.testing.assert_allclose(fit_iv(iv, PHYSICAL).se, ols.se, rtol=1e-6)


def test_iv_removes_the_errors_in_variables_bias(tmp_path):
    inertial = [PHYSICAL.names.index(n) for n in ("a1", "a2", "a3", "b1", "b2")]
    worst = {"ols": [], "iv": []}
    for seed in (6, 7, 8):
        path, robot, pi = trial(tmp_path, rate=500.0, noise=1e-3, seed=seed)
        d = load_dataset(path, DataSpec(derivative_cutoff_hz=15.0), robot)
        iv = InstrumentStats.from_data(PHYSICAL, d)
        for name, fit in (("ols", fit_ols(iv.stats, PHYSICAL)), ("iv", fit_iv(iv, PHYSICAL))):
            worst[name].append(np.median(np.abs(fit.pi[inertial] / pi[inertial] - 1)))
    assert np.median(worst["iv"]) < 0.5 * np.median(worst["ols"])
    assert np.median(worst["iv"]) < 0.1
