"""Shared fixtures: the project's problem files and real trials (all inside the repository)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"


@pytest.fixture(scope="session")
def physical_problem():
    from ident_opt.problem import load_problem

    return load_problem(PROBLEMS / "tudor_2dof.toml")


@pytest.fixture(scope="session")
def paper_problem():
    from ident_opt.problem import load_problem

    return load_problem(PROBLEMS / "tudor_2dof_paper.toml")


@pytest.fixture(scope="session")
def exp1(physical_problem):
    from ident_opt.data.loader import load_dataset

    return load_dataset(physical_problem.data.trials[0], physical_problem.data, physical_problem.robot)


def kept(frame, data, t: str = "t"):
    """The rows of `frame` (a DataFrame written as a trial, times in column `t` [s]) that the loader kept in `data`:
    estimated derivatives leave out the samples within a filter period of the trial's ends and gaps
    (`derivatives.settled`), so a loaded trial holds a contiguous subset of the file's rows."""
    import numpy as np

    return frame[np.isin(frame[t].to_numpy(), data.t)]


def rigid_fit_runs(capsys, base: list[str], out_dir: Path, recommended: str, asked: str) -> dict:
    """Run `ident-opt` with the argv `base` (a `diagnose` call) as is and with `--estimator asked`: each run exits 0,
    its rigid fit is the one expected (`recommended` when none is asked) and named, with its reason, on the terminal,
    in the report and in the JSON (which has its `warnings` list). Returns {None: π, asked: π} of the rigid fits."""
    import json

    from ident_opt.cli import main

    fits = {}
    for choice in (None, asked):
        out = out_dir / f"out_{choice}"
        extra = [] if choice is None else ["--estimator", choice]
        assert main([*base, "--out", str(out), "--json", str(out / "d.json"), *extra]) == 0
        err = capsys.readouterr().err
        payload = json.loads((out / "d.json").read_text())
        rigid = payload["nominal"]["rigid_fit"]
        want = recommended if choice is None else choice
        assert rigid["estimator"] == want and f"rigid fit: the {want} fit" in err
        assert rigid["why"] in (out / "diagnosis.md").read_text() and isinstance(payload["warnings"], list)
        fits[choice] = rigid["pi"]
    return fits
