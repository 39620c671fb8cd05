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
    from ident_opt.data import load_dataset

    return load_dataset(physical_problem.data.trials[0], physical_problem.data, physical_problem.robot)


def kept(frame, data, t: str = "t"):
    """The rows of `frame` (a DataFrame written as a trial, times in column `t` [s]) that the loader kept in `data`:
    estimated derivatives leave out the samples within a filter period of the trial's ends and gaps
    (`derivatives.settled`), so a loaded trial holds a contiguous subset of the file's rows."""
    import numpy as np

    return frame[np.isin(frame[t].to_numpy(), data.t)]
