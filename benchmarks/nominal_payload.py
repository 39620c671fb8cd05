"""`diagnose --nominal` on the simulator (issue 48, point 5): identify arm4 from one trial, export it, then diagnose a
later trial pair with a payload added (and one without) against the exported arm. Prints what was named and the
nominal models' held-out nMSE; `python benchmarks/nominal_payload.py [SEED] [MASS_KG]`."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

import ident_opt as iopt
from ident_opt.diagnosis import diagnose
from ident_opt.problem import load_problem
from ident_opt.simulator.simulate import simulate_trial

ARM4 = Path(__file__).resolve().parents[1] / "tests" / "arms" / "arm4.toml"


def main() -> None:
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1100
    mass = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    problem = load_problem(ARM4)

    def sim(s: int, effects: list[str], trajectory: str, duration: float = 40.0):
        """A trial as a logger without derivatives writes it (t, q, τ), read as `ident-opt` reads files: the loader
        estimates dq and ddq (the simulator's own dq/ddq columns are low-passed estimates beside a raw τ, which a
        fit would take as exact)."""
        trial = simulate_trial(
            problem.robot,
            trajectory=trajectory,
            duration=duration,
            rate_hz=250.0,
            seed=s,
            effects=effects,
            limits=problem.limits,
            progress=False,
        )
        frame = trial.frame[[c for c in trial.frame.columns if not c.startswith(("dq", "ddq"))]]
        path = Path(folder) / f"trial_{s}_{len(effects)}.csv"
        frame.to_csv(path, index=False)
        return iopt.load_trials(problem, [path])[0][0]

    with tempfile.TemporaryDirectory() as folder:
        sidecar = Path(folder) / "arm.urdf.json"
        fit = iopt.fit(problem, [sim(seed, [], "mixed", 60.0), sim(seed + 1, [], "tud01", 60.0)])
        iopt.export(problem, fit, sidecar.with_suffix(""))
        print(
            f"identified from two 60 s trials (`mixed`, `tud01`; seeds {seed}, {seed + 1}): "
            f"the {fit.choice.estimator} fit"
        )
        for label, effects in ((f"payload {mass:g} kg", [f"payload:mass={mass}"]), ("unchanged", [])):
            d = diagnose(problem, [sim(seed + 7, effects, "tud01")], [sim(seed + 8, effects, "mixed")], nominal=sidecar)
            j = d.as_json()
            named = [(c["cause"], c["estimate"]) for c in j["causes"]]
            print(f"{label}: verdict {j['verdict']}, named {named or 'nothing'}")
            if effects and [c for c, _ in named] == ["payload"]:
                print(f"  payload mass {named[0][1]['mass']:.4g} kg: {abs(named[0][1]['mass'] / mass - 1):.1%} off")
            print(
                f"  held-out nMSE: nominal {np.round(j['nominal']['nominal']['nmse'], 4).tolist()}, "
                f"rigid refit {np.round(j['nominal']['rigid_fit']['nmse'], 4).tolist()}"
            )


if __name__ == "__main__":
    main()
