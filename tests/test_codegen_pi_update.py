"""The generated online update (pi_update): the same parameters as the Python online path at every step of
exp1's online part, all-or-nothing on bad input, and the example program replays a CSV to the same end."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.shipping.codegen import find_compiler
from ident_opt.shipping.pi_update import CUpdate, verify


@pytest.fixture(scope="module")
def shipped(physical_problem, exp1, tmp_path_factory):
    out = tmp_path_factory.mktemp("pi_update")
    return out, verify(physical_problem, exp1, out, find_compiler(), repeats=1)


def test_generated_update_equals_the_python_online_path(shipped):
    _, result = shipped
    assert result["samples"] == 2400 and result["failures"] == 0
    assert result["max_relative_difference"] <= 1e-9
    python, c = result["final_python"], result["final_c_example"]
    assert set(python) == set(c)
    for name, value in python.items():
        assert c[name] == pytest.approx(value, rel=1e-9, abs=1e-12)
    assert result["c_ns_per_update"] > 0


def test_generated_update_is_all_or_nothing(shipped):
    out, _ = shipped
    c = CUpdate(out / "libpi_update.so", 9)
    before, n = c.theta, c.state.n
    assert c.update([0.1, 0.2], [np.nan, 0.0], [0.0, 0.0], [1.0, 1.0]) != 0  # a non-finite input
    assert np.array_equal(c.theta, before) and c.state.n == n
    assert c.update([0.1, 0.2], [0.3, -0.1], [1.0, 0.5], [1.0, 0.2]) == 0
    assert c.state.n == n + 1 and not np.array_equal(c.theta, before)
