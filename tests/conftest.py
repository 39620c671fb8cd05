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
