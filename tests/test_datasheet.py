"""Datasheet → π under both conventions, against the paper's tables and independent hand arithmetic."""

from __future__ import annotations

import pytest

from ident_opt.arm.datasheet import datasheet_pi, rigid_body
from ident_opt.paper import published as paper


def rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def test_paper_convention_reproduces_dynamic_parameter_table(paper_problem):
    body = rigid_body(paper_problem.robot, "paper")
    # The paper's "Dynamic Parameters Used in RBD Model" (rounded there to 3-4 digits).
    for value, printed in (
        (body.m1, 1.869),
        (body.m2, 0.192),
        (body.lc1, 0.407),
        (body.lc2, 0.205),
        (body.Ic2, 2.69e-3),
        (body.fv[0], 1.86e-5),
        (body.fv[1], 2.45e-6),
        (body.fc[0], 2.25e-3),
        (body.fc[1], 1.95e-3),
    ):
        assert rel(value, printed) < 0.01


def test_paper_convention_reproduces_pi_true_column(paper_problem):
    pi = datasheet_pi(paper_problem.robot, "paper")
    for name, value in paper.PI_TRUE.items():
        assert rel(pi[name], value) < 0.01, name
    assert "ia2" not in pi


def test_physical_convention_against_hand_arithmetic(physical_problem):
    # Independent arithmetic from the datasheet numbers (not via the package's helpers).
    g, rho, w, h = 9.81, 7800.0, 0.015, 0.004
    l1, l2 = 0.430, 0.410
    ml1, ml2 = rho * l1 * w * h, rho * l2 * w * h
    ma2, r2 = 0.5885, 0.015  # joint 2's actuator rides on link 1
    m1 = ml1 + ma2
    lc1 = (ml1 * l1 / 2 + ma2 * l1) / m1
    Ic1 = ml1 * (h**2 + l1**2) / 12 + ml1 * (lc1 - l1 / 2) ** 2 + ma2 * r2**2 / 2 + ma2 * (l1 - lc1) ** 2
    m2, lc2 = ml2, l2 / 2
    Ic2 = ml2 * (h**2 + l2**2) / 12
    expected = {
        "a1": Ic1 + Ic2 + m1 * lc1**2 + m2 * (l1**2 + lc2**2) + 230**2 * 9.41e-6,
        "a2": m2 * l1 * lc2,
        "a3": Ic2 + m2 * lc2**2,
        "b1": (m1 * lc1 + m2 * l1) * g,
        "b2": m2 * lc2 * g,
        "fv1": 230**2 * 1.86e-5,
        "fv2": 246**2 * (2.60e-6 + 2.30e-6) / 2,
        "fc1": 230 * (3.34e-3 + 1.15e-3) / 2,
        "fc2": 246 * (1.49e-3 + 2.40e-3) / 2,
        "ia2": 246**2 * 8.20e-7,
    }
    pi = datasheet_pi(physical_problem.robot, "physical")
    assert set(pi) == set(expected)
    for name, value in expected.items():
        assert rel(pi[name], value) < 1e-12, name
    # The printed values (5 significant digits).
    printed = {
        "a1": 0.66530,
        "a2": 0.016914,
        "a3": 0.010752,
        "b1": 3.7163,
        "b2": 0.38588,
        "fv1": 0.98394,
        "fv2": 0.14826,
        "fc1": 0.51635,
        "fc2": 0.47847,
        "ia2": 0.049623,
    }
    for name, value in printed.items():
        assert rel(pi[name], value) < 1e-4, name
    body = rigid_body(physical_problem.robot, "physical")
    assert rel(pi["a1"] - body.armature[0], 0.16751) < 1e-4
    assert rel(body.armature[0], 0.49779) < 1e-4


def test_convention_key_of_the_problem_is_the_default(physical_problem, paper_problem):
    assert datasheet_pi(physical_problem.robot) == datasheet_pi(physical_problem.robot, "physical")
    assert datasheet_pi(paper_problem.robot) == datasheet_pi(paper_problem.robot, "paper")
    with pytest.raises(ValueError):
        rigid_body(paper_problem.robot, "metric")


def test_payload_moves_only_link2_parameters(physical_problem):
    from dataclasses import replace

    base = datasheet_pi(physical_problem.robot)
    loaded = datasheet_pi(replace(physical_problem.robot, payload_mass=0.5))
    # A 0.5 kg point mass at the tip of link 2 (l2 = 0.41 m): exact increments.
    assert loaded["b2"] - base["b2"] == pytest.approx(0.5 * 0.41 * 9.81, rel=1e-12)
    assert loaded["a3"] - base["a3"] == pytest.approx(0.5 * 0.41**2, rel=1e-12)
    assert loaded["a2"] - base["a2"] == pytest.approx(0.5 * 0.43 * 0.41, rel=1e-12)
    assert loaded["fv1"] == base["fv1"] and loaded["ia2"] == base["ia2"]
