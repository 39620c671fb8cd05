"""`diagnose --nominal FIT`: an identified arm (an `export` sidecar or a `compare --json`) stands in for the
datasheet, nothing of it lost on the way (inertials, friction, armature, constant offsets), and the JSON calls that
baseline "nominal" and names the file and the fit (`docs/effects.md`, "What changed since a model")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import ident_opt as iopt
from ident_opt.diagnosis import read_nominal
from ident_opt.diagnosis.chain.engine import ChainEngine
from ident_opt.diagnosis.engine import Request
from ident_opt.errors import InputError
from ident_opt.problem import load_problem
from ident_opt.simulator.simulate import simulate_trial

ARM4 = Path(__file__).parent / "arms" / "arm4.toml"


@pytest.fixture(scope="module")
def arm4(tmp_path_factory):
    """arm4's problem, two simulated trials of distinct motions (20 s at 250 Hz) and the consistent fit of the first
    exported as URDF and MJCF, each with its sidecar."""
    folder = tmp_path_factory.mktemp("nominal")
    problem = load_problem(ARM4)

    def trial(seed: int, trajectory: str):
        return simulate_trial(
            problem.robot,
            trajectory=trajectory,
            duration=20.0,
            rate_hz=250.0,
            seed=seed,
            limits=problem.limits,
            progress=False,
        ).dataset()

    first, second = trial(1200, "mixed"), trial(1201, "tud01")
    fit = iopt.fit(problem, [first])
    iopt.export(problem, fit, folder / "arm.urdf")
    iopt.export(problem, fit, folder / "arm.xml")
    return problem, first, second, fit, folder


@pytest.mark.parametrize("sidecar", ["arm.urdf.json", "arm.xml.json"])
def test_an_exported_sidecar_gives_back_every_fitted_value(arm4, sidecar):
    """URDF and MJCF sidecars both carry the fit: read back, the diagnosis's nominal π is the fit's π exactly (no
    datasheet value kept), inertials, friction and armature alike."""
    problem, first, _, fit, folder = arm4
    nominal = read_nominal(folder / sidecar)
    assert nominal.estimator == fit.choice.estimator
    engine = ChainEngine(problem.robot, Request(first, None, 0.7, "auto", "consistent", nominal))
    assert engine.kept == []
    np.testing.assert_array_equal(engine.nominal.pi["datasheet"], fit.pi)
    plain = ChainEngine(problem.robot, Request(first, None, 0.7, "auto", "consistent"))
    _, pi_ds = problem.robot.datasheets()[problem.robot.datasheet]
    np.testing.assert_array_equal(plain.nominal.pi["datasheet"], pi_ds)
    assert not np.allclose(fit.pi, pi_ds)  # the test would not tell them apart otherwise


def test_a_compare_json_gives_its_recommended_fit_or_the_one_asked(arm4, tmp_path):
    """A compare JSON's parameters per fit: its `recommended` by default, another by name, an unknown name refused
    naming what the file has."""
    _, _, _, fit, _ = arm4
    values = dict(zip(fit.model.names, fit.pi.tolist()))
    other = {k: 2 * v for k, v in values.items()}
    path = tmp_path / "compare.json"
    path.write_text(
        json.dumps(
            {
                "recommended": "consistent",
                "fits": {"consistent": {}, "ols": {}},
                "parameters": {"datasheet": other, "consistent": values, "ols": other},
            }
        )
    )
    assert read_nominal(path).parameters == values and read_nominal(path).estimator == "consistent"
    assert read_nominal(path, "ols").parameters == other
    with pytest.raises(InputError, match=r"no fit 'iv' in it; it has consistent, ols"):
        read_nominal(path, "iv")


def test_bad_nominal_files_are_named(arm4, tmp_path):
    problem, first, _, _, folder = arm4
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    with pytest.raises(InputError, match=r"broken\.json: cannot read the identified arm"):
        read_nominal(broken)
    record = json.loads((folder / "arm.urdf.json").read_text())
    record["parameters"]["fv_yaw"]["value"] = float("nan")
    nan = tmp_path / "nan.json"
    nan.write_text(json.dumps(record))
    with pytest.raises(InputError, match="parameter fv_yaw = nan is not a finite number"):
        read_nominal(nan)
    record = json.loads((folder / "arm.urdf.json").read_text())
    record["parameters"]["b1s"] = {"value": 0.1}
    extra = tmp_path / "extra.json"
    extra.write_text(json.dumps(record))
    with pytest.raises(InputError, match=r"1 parameter\(s\) the diagnosis's nominal model does not \(b1s\)"):
        ChainEngine(problem.robot, Request(first, None, 0.7, "auto", "consistent", read_nominal(extra)))
    with pytest.raises(InputError, match="the sidecar holds the consistent fit, not ols"):
        read_nominal(folder / "arm.urdf.json", "ols")


def test_the_json_calls_the_identified_arm_nominal_and_says_what_was_compared(arm4):
    """A diagnosis with --nominal: no "datasheet" baseline anywhere in its JSON, `nominal` names the file and the
    fit, its nMSE is the identified arm's on the held-out trial, and `compared` says what was compared."""
    from ident_opt.diagnosis import diagnose

    problem, first, second, fit, folder = arm4
    d = diagnose(problem, [second], [first], nominal=folder / "arm.urdf.json")
    payload = d.as_json()
    text = json.dumps(payload)
    assert '"datasheet"' not in text
    assert payload["nominal"]["estimator"] == fit.choice.estimator
    assert payload["nominal"]["file"].endswith("arm.urdf.json")
    assert set(payload["nominal"]) >= {"nominal", "rigid_fit"}
    assert all(r["baseline"] in ("nominal", "rigid_fit") for rows in payload["rounds"] for r in rows)
    assert "the identified arm in" in payload["compared"] and "arm.urdf.json" in payload["compared"]
    plain = diagnose(problem, [second], [first]).as_json()
    assert plain["nominal"]["datasheet"]["nmse"] != payload["nominal"]["nominal"]["nmse"]
    assert plain["nominal"]["rigid_fit"]["nmse"] == payload["nominal"]["rigid_fit"]["nmse"]
    assert "--nominal FIT" in plain["compared"]  # a separate held-out trial without a nominal: said how to ask


def test_rated_payload_is_read_on_every_arm_and_bounds_the_payload(tmp_path):
    """`[robot] rated_payload` on a planar and on an n-joint problem: kept on the robot, the plausibility rule's
    bound (a payload above it fails its range); out of range or not a number: an InputError naming the key."""
    from ident_opt.diagnosis import plausibility

    root = Path(__file__).resolve().parents[1]
    for source in (root / "problems" / "tudor_2dof.toml", ARM4):
        text = source.read_text(encoding="utf-8").replace("[robot]\n", "[robot]\nrated_payload = 1.5\n", 1)
        copy = source.parent / f"_rated_{source.name}"
        try:
            copy.write_text(text, encoding="utf-8")
            robot = load_problem(copy).robot
            assert robot.rated_payload == 1.5
            copy.write_text(text.replace("rated_payload = 1.5", "rated_payload = -1"), encoding="utf-8")
            with pytest.raises(InputError, match="rated_payload"):
                load_problem(copy)
        finally:
            copy.unlink(missing_ok=True)
    n = 4
    facts = plausibility.Facts(("a", "b", "c", "d"), np.ones(n), np.ones(n), 1.5, 0.2, True, (), np.ones(n), 0.01, 10)
    estimate = {"mass": 1.4, "com": [0.0, 0.0, 0.05]}
    assert plausibility.ranges("payload", estimate, {}, facts) == ([], [])
    heavy, _ = plausibility.ranges("payload", {**estimate, "mass": 1.6}, {}, facts)
    assert len(heavy) == 1 and "1.5" in heavy[0], heavy
