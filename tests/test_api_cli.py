"""The Python API says what the command line says (issue 47): every stage function takes the problem first, the
commands call the same functions, and both give the same JSON on real arms (the MERIt trials and the KUKA LWR4+);
the one fit a run stands behind is decided once, so `export` and `codegen` write exactly the π `compare` reports as
recommended; trials come from arrays through the pipeline files go through; a fit predicts; `dir(ident_opt)` shows
only public names."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import ident_opt as iopt
from ident_opt.cli import main
from ident_opt.report import write_json

from .conftest import PROBLEMS, ROOT

#: Keys whose values are wall-clock measurements or the paths of the files written, not results.
VOLATILE = ("timings_s", "files", "updates_per_second", "seconds")


def _plain(payload: dict, tmp_path, name: str) -> dict:
    """`payload` as the commands write it (strict JSON: NumPy values plain, non-finite numbers null)."""
    path = tmp_path / f"{name}.json"
    write_json(path, payload)
    return json.loads(path.read_text())


def _same(a, b, where: str = "") -> None:
    """Equal JSON, to the last digit, but for wall-clock timings and the paths of files written."""
    if isinstance(a, dict):
        keys = {k for k in {*a, *b} if k not in VOLATILE and not k.endswith("_seconds")}
        assert keys <= set(a) and keys <= set(b), (where, sorted(keys - set(a)), sorted(keys - set(b)))
        for k in keys:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    else:
        assert a == b, (where, a, b)


def _head(source, target, seconds: float) -> str:
    """The first `seconds` of a recording (a CSV, gzipped or not, with a header and t in its first column), written
    as it is: a shorter trial in the recording's own format."""
    frame = pd.read_csv(source)
    frame = frame[frame.iloc[:, 0] <= frame.iloc[0, 0] + seconds]
    frame.to_csv(target, index=False, float_format="%.17g")
    return str(target)


@pytest.fixture(scope="module")
def kuka_trials(tmp_path_factory):
    """The KUKA's training and held-out recordings cut to 20 s each (the diagnosis of a whole minute takes 90 s)."""
    folder = tmp_path_factory.mktemp("kuka")
    data = ROOT / "data" / "kuka_lwr4"
    return (
        _head(data / "measurements_3.csv.gz", folder / "train.csv", 20.0),
        _head(data / "measurements_2.csv.gz", folder / "test.csv", 20.0),
    )


def _cases(kuka_trials) -> dict[str, tuple]:
    return {
        "merit": ("tudor_2dof.toml", [str(ROOT / "data/merit/exp1.csv")], [str(ROOT / "data/merit/exp2.csv")]),
        "kuka": ("kuka_lwr4.toml", [kuka_trials[0]], [kuka_trials[1]]),
    }


@pytest.mark.parametrize("arm", ["merit", "kuka"])
def test_compare_diagnose_and_export_give_the_commands_json(arm, kuka_trials, tmp_path):
    name, data, test = _cases(kuka_trials)[arm]
    problem = iopt.load_problem(PROBLEMS / name)
    training, testing = iopt.load_trials(problem, data, test)
    flags = ["--problem", str(PROBLEMS / name)]
    flags += [word for d in data for word in ("--data", d)] + [word for t in test for word in ("--test-data", t)]

    assert main(["compare", *flags, "--out", str(tmp_path / "c"), "--json", str(tmp_path / "c.json")]) == 0
    api = iopt.compare(problem, training, testing)
    _same(json.loads((tmp_path / "c.json").read_text()), _plain(api.as_json(), tmp_path, "compare"))

    assert (
        main(["diagnose", *flags, "--no-progress", "--out", str(tmp_path / "d"), "--json", str(tmp_path / "d.json")])
        == 0
    )
    found = iopt.diagnose(problem, training, testing)
    _same(json.loads((tmp_path / "d.json").read_text()), _plain(found.as_json(), tmp_path, "diagnose"))

    cli, api = tmp_path / "cli" / "arm.urdf", tmp_path / "api" / "arm.urdf"
    assert main(["export", *flags, "--format", "urdf", "--out", str(cli), "--json", str(tmp_path / "e.json")]) == 0
    exported = iopt.export(problem, iopt.fit(problem, training), api)
    _same(json.loads((tmp_path / "e.json").read_text()), _plain(exported.as_json(), tmp_path, "export"))
    assert json.loads(api.with_suffix(".urdf.json").read_text()) == json.loads(
        cli.with_suffix(".urdf.json").read_text()
    )
    assert api.read_text() == cli.read_text()


@pytest.mark.parametrize("name", ["tudor_2dof.toml", "dfki_c0.toml", "kuka_lwr4.toml"])
def test_export_and_codegen_write_the_fit_compare_recommends(name, tmp_path):
    """The three commands on the problem's own trials: the π of `export`'s sidecar and of `codegen`'s
    parameters.json are the π `compare --json` reports for its `recommended` fit, to 1e-12."""
    problem = ["--problem", str(PROBLEMS / name)]
    assert (
        main(["compare", *problem, "--no-progress", "--out", str(tmp_path / "c"), "--json", str(tmp_path / "c.json")])
        == 0
    )
    compared = json.loads((tmp_path / "c.json").read_text())
    recommended = compared["parameters"][compared["recommended"]]
    assert main(["export", *problem, "--format", "urdf", "--out", str(tmp_path / "arm.urdf")]) == 0
    sidecar = json.loads((tmp_path / "arm.urdf.json").read_text())
    assert sidecar["estimator"] == compared["recommended"]
    exported = {k: v["value"] for k, v in sidecar["parameters"].items()}
    assert main(["codegen", *problem, "--out", str(tmp_path / "c_code"), "--components", "1", "--no-update"]) == 0
    generated = json.loads((tmp_path / "c_code" / "parameters.json").read_text())
    assert generated["estimator"] == compared["recommended"]
    names = sorted(recommended)
    want = np.array([recommended[k] for k in names])
    scale = np.abs(want).max()
    for got in (exported, generated["parameters"]):
        assert sorted(got) == names
        np.testing.assert_allclose([got[k] for k in names], want, rtol=1e-12, atol=1e-12 * scale)


def test_the_commands_call_the_api_functions():
    """Each command reaches its stage through the very function `ident_opt` exports (no second path)."""
    from ident_opt.commands import compare, diagnose, export, identify, simulate

    assert compare.compare.compare is iopt.compare
    assert diagnose.diagnose is iopt.diagnose
    assert export.export is iopt.export
    assert identify.identify is iopt.identify
    assert simulate.simulate is iopt.simulate


def test_a_trial_from_arrays_is_the_trial_from_its_file(tmp_path):
    """t, q and τ as arrays go through the loader's own pipeline: the same derivatives, cut-off and edge trimming as
    the same columns read from a file, and the same fit; bad shapes are an InputError naming the array."""
    problem = iopt.load_problem(PROBLEMS / "dfki_c0.toml")
    (from_file,), _ = iopt.load_trials(problem, [ROOT / "data/dfki/trajectory_00.csv.gz"], [])
    with gzip.open(ROOT / "data/dfki/trajectory_00.csv.gz", "rt") as f:
        raw = pd.read_csv(f)
    spec = problem.data
    column = {k: spec.columns[k] for k in ("t", "q1", "q2", "tau1", "tau2")}

    def values(key: str) -> np.ndarray:
        scale, offset = spec.conversions.get(key, (1.0, 0.0))
        return scale * raw[column[key]].to_numpy(dtype=float) + offset

    q = np.column_stack([values("q1"), values("q2")])
    tau = np.column_stack([values("tau1"), values("tau2")])
    from_arrays = iopt.trial(problem, values("t"), q, tau, source="trajectory_00")
    assert from_arrays.cutoff_hz == from_file.cutoff_hz and from_arrays.n == from_file.n
    for key in ("t", "q", "dq", "ddq", "tau", "tau_fit"):
        np.testing.assert_array_equal(getattr(from_arrays, key), getattr(from_file, key), err_msg=key)
    a, b = iopt.fit(problem, [from_arrays]), iopt.fit(problem, [from_file])
    assert a.choice.estimator == b.choice.estimator
    np.testing.assert_array_equal(a.pi, b.pi)
    np.testing.assert_allclose(a.predict(from_file), problem.robot.model().predict(a.pi, *_kinematics(from_file)))
    with pytest.raises(iopt.InputError, match="trajectory_00: q must be an array of shape"):
        iopt.trial(problem, values("t"), q[:, :1], tau, source="trajectory_00")
    with pytest.raises(iopt.InputError, match=r"tau.*or the motor currents"):
        iopt.trial(problem, values("t"), q, source="trajectory_00")


def _kinematics(trial):
    return trial.q, trial.dq, trial.ddq


def test_dir_shows_only_the_public_names():
    """After a run has imported every subpackage, `dir(ident_opt)` still lists the API and nothing else; importing
    under the documented alias shadows nothing of the standard library."""
    code = (
        "import ident_opt as iopt, ident_opt.cli, ident_opt.commands.compare, ident_opt.simulator.trial\n"
        "import io, sys\n"
        "print(sorted(dir(iopt)) == sorted(iopt.__all__), io is sys.modules['io'],\n"
        "      'iopt' not in sys.stdlib_module_names)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "True", "True"]
