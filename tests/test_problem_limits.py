"""Hostile problem-file values (the fuzz issue's reproducers 1, 2, 3, 5, 9, 13, 18, 19): every number is
validated at load — finite, in a sane range for its unit, an integer where an integer is meant — and the
message names the file and key with a short excerpt of the value, exit status 2 through the CLI."""

from __future__ import annotations

import pytest

from ident_opt.cli import main
from ident_opt.errors import InputError
from ident_opt.problem import load_problem

from .test_problem import edit

REPRODUCERS = [
    # (old text, new text, key named)
    ("max_train_samples = 20000", "max_train_samples = inf", "max_train_samples"),  # 1: OverflowError before
    ("max_train_samples = 20000", "max_train_samples = 0.5", "max_train_samples"),  # 13: truncated to 0 before
    ("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", "seeds = [-1]", "seeds"),  # 2: sklearn error before
    ("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", "seeds = [4294967296]", "seeds"),
    ("train_fraction = 0.7", "train_fraction = 1e-6", "train_fraction"),  # 3: empty training set before
    ("train_fraction = 0.7", "train_fraction = 0.9999999", "train_fraction"),  # 3: empty test set before
    ("gear_ratio = 230.0", "gear_ratio = inf", "gear_ratio"),  # 5: RuntimeError in the constrained fit before
    ("gear_ratio = 230.0", "gear_ratio = 1e300", "gear_ratio"),
    ("length = 0.430", "length = inf", "length"),
    ("length = 0.430", "length = 1e300", "length"),  # 5: OverflowError in bar_inertia before
    ("torque_constant = 4.48e-2", "torque_constant = 1e30", "torque_constant"),
    ("density = 7800.0", "density = inf", "density"),  # 9: NaN in compare.json before
    ("gravity = 9.81", "gravity = 1e300", "gravity"),
    ("mass = 0.0", "mass = 1e300", "mass"),
    ("candidates = [1, 2, 3, 4, 6, 8, 10]", "candidates = [100000]", "candidates"),  # 13
    ("density = 7800.0", "density = nan", "density"),
]


@pytest.mark.parametrize(("old", "new", "key"), REPRODUCERS, ids=[r[1] for r in REPRODUCERS])
def test_hostile_number_is_refused_at_load_naming_file_and_key(tmp_path, capsys, old, new, key):
    path = edit(tmp_path, old, new)
    with pytest.raises(InputError) as err:
        load_problem(path)
    message = str(err.value)
    assert str(path) in message and f"'{key}'" in message
    assert main(["check", "--problem", str(path)]) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out


def test_huge_list_is_not_echoed_whole(tmp_path):
    # 18: a 200,000-entry array used to be echoed in a 1.49 MB error line.
    path = edit(tmp_path, "density = 7800.0", "density = [" + ", ".join(map(str, range(200_000))) + "]")
    with pytest.raises(InputError) as err:
        load_problem(path)
    assert "'density'" in str(err.value) and len(str(err.value)) < 400


def test_unbounded_seed_list_is_refused(tmp_path):
    # 19: 100,000 seeds ran compare for minutes.
    seeds = "seeds = [" + ", ".join(map(str, range(100_000))) + "]"
    path = edit(tmp_path, "seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", seeds)
    with pytest.raises(InputError) as err:
        load_problem(path)
    assert "'seeds'" in str(err.value) and "1 to 100" in str(err.value) and len(str(err.value)) < 400


def test_sane_values_at_the_limits_still_load(tmp_path):
    path = edit(tmp_path, "train_fraction = 0.7", "train_fraction = 0.95")
    assert load_problem(path).split.train_fraction == 0.95
