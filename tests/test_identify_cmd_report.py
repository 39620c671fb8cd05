"""The reproduction table judges targets by the stated tolerances, from the numbers it is given."""

from __future__ import annotations

import pytest

from ident_opt.evaluation.identify import IdentifyResult
from ident_opt.paper.protocols import ProtocolResult
from ident_opt.paper.published import NMSE_RANGE as PAPER_NMSE_RANGE
from ident_opt.paper.published import RMSE as PAPER_RMSE
from ident_opt.report.identify_tables import reproduction_frame


def _result(scale_rmse: float, scale_nmse: float) -> IdentifyResult:
    keys = list(PAPER_NMSE_RANGE)
    rmse = {
        k: [PAPER_RMSE[k][0][0] * scale_rmse, PAPER_RMSE[k][1][0] * scale_rmse] if k in PAPER_RMSE else [1.0, 1.0]
        for k in keys
    }
    nmse_range = {k: [v * scale_nmse for v in PAPER_NMSE_RANGE[k]] for k in keys}
    metrics = {"rmse": rmse, "nmse": {k: [0.1, 0.1] for k in keys}, "nmse_range": nmse_range}
    paper = ProtocolResult("paper", "test", metrics, {}, {})
    return IdentifyResult("t", "a.csv", None, {"paper": paper}, {}, {}, {})


@pytest.mark.parametrize("rmse, nmse, expect", [(1.09, 0.76, "yes"), (1.11, 1.0, "NO"), (1.0, 1.26, "NO")])
def test_targets_follow_the_tolerances(rmse, nmse, expect):
    frame = reproduction_frame(_result(rmse, nmse)).reset_index()
    targeted = frame[frame["target"] != "–"]
    assert set(targeted["metric"]) == {"RMSE [N·m]", "nmse_range"}
    if expect == "yes":
        assert (targeted["met"] == "yes").all()
    else:
        assert (targeted["met"] == "NO").any()
    # the GMR rows are reported, never judged
    assert set(frame[frame["model"].str.endswith("+gmr")]["met"]) == {"reported"}
