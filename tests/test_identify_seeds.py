"""The paper's seed study: per-seed fits equal fits on the same split, deviations, RMSE table, figure."""

from __future__ import annotations

import numpy as np

from ident_opt.arm.planar import RIGID
from ident_opt.data.dataset import shuffled_split
from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.stats import Stats
from ident_opt.metrics import rmse
from ident_opt.paper.seeds import deviation_from_mean, rmse_table, seed_study
from ident_opt.problem import SplitSpec
from ident_opt.report.figures import seed_heatmap


def test_seed_study_matches_direct_fits(exp1, tmp_path):
    split = SplitSpec(train_fraction=0.7, seeds=(0, 3, 5))
    study = seed_study(exp1, RIGID, split)
    for s, seed in enumerate(split.seeds):
        train, test = shuffled_split(exp1.n, 0.7, seed)
        st = Stats.from_data(RIGID, exp1.q[train], exp1.dq[train], exp1.ddq[train], exp1.tau[train])
        pi = fit_ols(st, RIGID).pi
        np.testing.assert_allclose(study.pi["ols"][s], pi, rtol=1e-9)
        expected = rmse(exp1.tau[test], RIGID.predict(pi, exp1.q[test], exp1.dq[test], exp1.ddq[test]))
        np.testing.assert_allclose(study.metrics["ols"]["rmse"][s], expected, rtol=1e-9)
    dev = deviation_from_mean(study)
    np.testing.assert_allclose(dev.sum(axis=0), 0.0, atol=1e-8)  # deviations from the mean sum to zero
    table = rmse_table(study)
    assert table.loc["ols", "rmse_j1_mean"] == np.mean(study.metrics["ols"]["rmse"][:, 0])
    path = seed_heatmap(study, tmp_path / "seeds.png")
    assert path.stat().st_size > 1000
