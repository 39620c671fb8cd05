"""`ident-opt export` end to end on the shipped arms: the command fits the arm, writes a URDF (with its sidecar) or
an MJCF, and Pinocchio and MuJoCo reproduce the fit's torques from the files to 1e-9 relative; the default fit's
links are physically possible; bad input exits 2 naming the culprit and writes nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ident_opt.cli import main
from tests.conftest import PROBLEMS
from tests.test_export import TOLERANCE, _mujoco_torques, _pinocchio_torques, _robot, _strict_json, _worst

#: (problem, trials (None: the problem's)) exported by the CLI; the KUKA on one recording keeps it quick.
CASES = {
    "kuka_lwr4": [PROBLEMS.parent / "data" / "kuka_lwr4" / "measurements_3.csv.gz"],
    "franka_panda": None,
    "staubli_tx40": None,
    "tudor_2dof": None,
    "dfki_c0": [PROBLEMS.parent / "data" / "dfki" / "trajectory_00.csv.gz"],
}


def _export(tmp_path, name: str, fmt: str, *extra: str) -> tuple[int, str]:
    """Run `ident-opt export` on a shipped problem; (exit status, the output file)."""
    out = tmp_path / f"{name}.{'urdf' if fmt == 'urdf' else 'xml'}"
    data = [arg for path in CASES[name] or [] for arg in ("--data", str(path))]
    argv = ["export", "--problem", str(PROBLEMS / f"{name}.toml"), *data, "--format", fmt, "--out", str(out), *extra]
    return main(argv), str(out)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Each case exported as a URDF (with its sidecar) and as an MJCF: name -> (urdf, mjcf, sidecar record)."""
    out = {}
    for name in CASES:
        folder = tmp_path_factory.mktemp(name)
        status_urdf, urdf = _export(folder, name, "urdf")
        status_mjcf, mjcf = _export(folder, name, "mjcf")
        assert status_urdf == status_mjcf == 0
        out[name] = (urdf, mjcf, _strict_json(open(f"{urdf}.json", encoding="utf-8").read()))
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_the_exported_files_reproduce_the_fit(name, exported):
    urdf, mjcf, record = exported[name]
    robot = _robot(name)
    model = robot.model()
    pi = model.vector({k: v["value"] for k, v in record["parameters"].items()})
    # the recommended fit: the arm's consistent one, or the robust one where the data show noise biasing it
    assert record["estimator"] in (robot.default_estimator, "robust") and set(record["parameters"]) == set(model.names)
    rng = np.random.default_rng(1)
    n = model.n_joints
    joints = record["robot"]["joints"]  # within each joint's range: MuJoCo's limit constraints act beyond it
    low = [j["lower"] if j.get("lower") is not None else -1.5 for j in joints]
    high = [j["upper"] if j.get("upper") is not None else 1.5 for j in joints]
    q = rng.uniform(low, high, (40, n))
    dq = rng.uniform(0.3, 2.0, (40, n)) * rng.choice([-1.0, 1.0], (40, n))
    ddq = rng.uniform(-3.0, 3.0, (40, n))
    if robot.column_map:
        pytest.skip("a URDF planar arm is written in its own angles: test_export checks that mapping")
    expected = model.predict(pi, q, dq, ddq)
    assert _worst(_pinocchio_torques(urdf, record, q, dq, ddq), expected) <= TOLERANCE
    assert _worst(_mujoco_torques(mjcf, record, q, dq, ddq), expected) <= TOLERANCE


@pytest.mark.parametrize("name", list(CASES))
def test_the_default_fit_exports_a_physically_possible_arm(name, exported):
    record = exported[name][2]
    for body in record["robot"]["bodies"]:
        moments = np.linalg.eigvalsh(np.array(body["inertia"]))
        assert body["mass"] > 0 and moments.min() >= -1e-12
        assert moments.max() <= moments.sum() - moments.max() + 1e-9  # the triangle inequality of a body
    assert all(j["damping"] >= 0 and j["friction"] >= 0 and j["armature"] >= 0 for j in record["robot"]["joints"])


def test_what_the_data_did_not_determine_has_no_standard_error(exported):
    record = exported["kuka_lwr4"][2]
    silent = set(record["not_determined"])
    assert silent and all(record["parameters"][name]["standard_error"] is None for name in silent)
    assert any(v["standard_error"] is not None for name, v in record["parameters"].items() if name not in silent)


def test_an_impossible_fit_is_refused_naming_the_link(tmp_path, capsys):
    """OLS on the base parameters sets the dependent standard parameters to 0: links of zero mass, no body."""
    status, _ = _export(tmp_path, "kuka_lwr4", "mjcf", "--estimator", "ols")
    err = capsys.readouterr().err
    assert status == 2 and "link" in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--estimator", "nlp_physical"], ["nlp_physical", "consistent"]),
        (["--estimator", "nope"], ["nope"]),
    ],
)
def test_bad_estimators_are_refused(tmp_path, capsys, extra, words):
    status, _ = _export(tmp_path, "kuka_lwr4", "urdf", *extra)
    err = capsys.readouterr().err
    assert status == 2 and all(w in err for w in words)
    assert not list(tmp_path.iterdir())


def test_export_never_overwrites_an_input(tmp_path, capsys):
    problem = PROBLEMS / "tudor_2dof.toml"
    before = problem.read_bytes()
    argv = ["export", "--problem", str(problem), "--format", "urdf", "--out", str(problem)]
    assert main(argv) == 2 and problem.read_bytes() == before
    assert "input" in capsys.readouterr().err


def test_json_names_the_files(tmp_path):
    out = tmp_path / "r.json"
    status, urdf = _export(tmp_path, "tudor_2dof", "urdf", "--json", str(out))
    result = json.loads(out.read_text())
    assert status == 0 and result["files"] == [urdf, f"{urdf}.json"] and result["notes"]
