"""`diagnose --nominal` answers "what changed since this model?" (issue 48, point 5; docs/effects.md, "What changed
since a model"): arm4 identified from two logged trials and exported; a later pair of trials with a payload added
names the payload alone, its mass within 10 %, and a pair without it names nothing. Seeds and mass not those of
`benchmarks/nominal_payload.py`."""

from __future__ import annotations

from pathlib import Path

import pytest

import ident_opt as iopt
from ident_opt.diagnosis import diagnose
from ident_opt.simulator.simulate import simulate_trial

ARM4 = Path(__file__).parent / "arms" / "arm4.toml"
MASS = 0.8


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """(problem, a function simulating a logged trial (t, q, τ) read as files are read, the export's sidecar)."""
    folder = tmp_path_factory.mktemp("nominal_payload")
    problem = iopt.load_problem(ARM4)

    def logged(seed: int, trajectory: str, effects: list[str], duration: float = 40.0):
        trial = simulate_trial(
            problem.robot,
            trajectory=trajectory,
            duration=duration,
            rate_hz=250.0,
            seed=seed,
            effects=effects,
            limits=problem.limits,
            progress=False,
        )
        path = folder / f"trial_{seed}.csv"
        trial.frame[[c for c in trial.frame.columns if not c.startswith(("dq", "ddq"))]].to_csv(path, index=False)
        return iopt.load_trials(problem, [path])[0][0]

    fit = iopt.fit(problem, [logged(5100, "mixed", []), logged(5101, "tud01", [])])
    sidecar = folder / "arm.urdf.json"
    iopt.export(problem, fit, sidecar.with_suffix(""))
    return problem, logged, sidecar


def test_a_payload_added_since_the_exported_arm_is_named_alone(identified):
    problem, logged, sidecar = identified
    effects = [f"payload:mass={MASS}"]
    found = diagnose(problem, [logged(5107, "tud01", effects)], [logged(5108, "mixed", effects)], nominal=sidecar)
    j = found.as_json()
    assert j["verdict"] == "causes"
    assert [c["cause"] for c in j["causes"]] == ["payload"]
    assert j["causes"][0]["estimate"]["mass"] == pytest.approx(MASS, rel=0.10)


def test_the_same_arm_later_names_nothing(identified):
    problem, logged, sidecar = identified
    found = diagnose(problem, [logged(5117, "tud01", [])], [logged(5118, "mixed", [])], nominal=sidecar)
    assert found.as_json()["causes"] == []
