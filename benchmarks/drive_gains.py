"""Drive gains from a known load on simulated current-logged trials (issue 48, point 6): the planar arm
(tudor_sim) and the 6-joint TX40 with drives, two 40 s `mixed` trials each, the second with a known payload; the
drives' true gains s × nominal. Prints the estimate, its standard error and its error per joint, with the logger's
noise and derivatives estimated from the angles, and noise-free with the true derivatives.
`python benchmarks/drive_gains.py`."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np

import ident_opt as iopt
from ident_opt.fitting import drive_gains
from ident_opt.problem import load_problem
from ident_opt.simulator.simulate import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "planar (tudor_sim)": (
        "problems/tudor_sim.toml",
        [0.9, 1.08],
        "mass = 0.5",
        "payload:mass=0.5",
        100.0,
        lambda text: text,
    ),
    "TX40 with drives (6 joints)": (
        "tests/arms/tx40_drives.toml",
        [0.9, 1.05, 1.1, 0.95, 1.0, 1.04],
        "mass = 2.0, com = [0.15, 0.1, 0.1]",
        "payload:mass=2.0,com=[0.15,0.1,0.1]",
        250.0,
        lambda text: re.sub(r"(\[robot\.joint_\d\]\n)", r"\1torque_constant = 0.2\ngear_ratio = 40\n", text).replace(
            'urdf = "../../', f'urdf = "{ROOT.as_posix()}/'
        ),
    ),
}


def run(source: str, truth, load: str, effect: str, rate: float, edit, exact: bool, folder: Path) -> np.ndarray:
    text = edit(re.sub(r"\n\[data\][^\[]*", "\n", (ROOT / source).read_text(encoding="utf-8")))
    (folder / "p.toml").write_text(text, encoding="utf-8")
    problem = load_problem(folder / "p.toml")
    gains = f"torque_scale:scale=[{','.join(map(str, truth))}]"
    for k, effects in enumerate(([gains], [gains, effect])):
        trial = simulate_trial(
            problem.robot,
            trajectory="mixed",
            duration=40.0,
            rate_hz=rate,
            seed=700 + k,
            effects=effects,
            limits=problem.limits,
            output="current",
            noise=not exact,
            exact_derivatives=exact,
            progress=False,
        )
        keep = [c for c in trial.frame.columns if exact or not c.startswith(("dq", "ddq"))]
        trial.frame[keep].to_csv(folder / f"trial{k}.csv", index=False)
    text += f'\n[data]\ntrain = ["trial0.csv", "trial1.csv"]\n\n[data.payloads]\n"trial1.csv" = {{ {load} }}\n'
    (folder / "p.toml").write_text(text, encoding="utf-8")
    problem = load_problem(folder / "p.toml")
    trains, _ = iopt.load_trials(problem)
    g = drive_gains.identify(
        problem.robot, problem.robot.model(), trains, [problem.data.load_of(t.source) for t in trains]
    )
    return g


def main() -> None:
    for name, (source, truth, load, effect, rate, edit) in CASES.items():
        for exact in (False, True):
            with tempfile.TemporaryDirectory() as folder:
                g = run(source, truth, load, effect, rate, edit, exact, Path(folder))
            error = np.asarray(g.ratio) / np.asarray(truth) - 1
            how = "noise-free, true derivatives" if exact else "logger noise, derivatives from the angles"
            print(f"{name}, {how}:")
            print(f"  ratio {np.round(g.ratio, 4).tolist()} ± {np.round(g.se, 4).tolist()}")
            print(f"  error {np.round(100 * error, 2).tolist()} %  (truth {truth})")


if __name__ == "__main__":
    main()
