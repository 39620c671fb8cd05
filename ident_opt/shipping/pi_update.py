"""The online update on the robot: `pi_update` (statistics update + warm-started bounded least squares) as
generated C, checked against the Python online path and timed from a C loop.

The online PBR of `ident-opt online` (the arm's rigid model, bounded least squares on its parameters, or on its base
parameters for an n-joint arm: `adaptation.identifier.offline_start`) is started from its offline fit on the first
`[split] train_fraction` of the trial; the generated code has that start baked in. Both then fold in the rest of the
trial sample by sample; the parameters after every step are compared (largest relative difference per parameter, 0/0
counting as 0). The example program replays the same samples from a CSV and times its loop (best of `repeats`
runs), and the regressor alone.
"""

from __future__ import annotations

import ctypes
import json
import subprocess
import time
from pathlib import Path

import numpy as np

from ident_opt import outputs
from ident_opt.adaptation import c_update
from ident_opt.adaptation.kernel import load_pi_update, update_state
from ident_opt.adaptation.replay import _relative, _standard_errors
from ident_opt.adaptation.start import offline_start, start_identifier
from ident_opt.data.dataset import Dataset, chronological_split
from ident_opt.fitting.bounded import KKT_TOL


def _torque_relative(D: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """‖D (a − b)‖∞ / ‖D b‖∞: how differently two parameter vectors predict one sample's torques (D (n, P))."""
    scale = np.abs(D @ b).max()
    return float(np.abs(D @ (a - b)).max() / scale) if scale > 0 else 0.0


class CUpdate:
    """The compiled `pi_update` through ctypes (for the checks and the benchmark): P parameters, J joints."""

    def __init__(self, library: Path, n_params: int, n_joints: int = 2):
        P = n_params
        self.J = n_joints
        self.lib, self.state = load_pi_update(library, P)
        self._ref = ctypes.byref(self.state)
        self._buffers = [(ctypes.c_double * n_joints)() for _ in range(4)]
        self._fn = self.lib.pi_update
        self._fn.restype = ctypes.c_int

    def update(self, q, dq, ddq, tau) -> int:
        """Fold one sample in; 0 on success."""
        b = self._buffers
        for buf, values in zip(b, (q, dq, ddq, tau)):
            for j in range(self.J):
                buf[j] = values[j]
        return self._fn(self._ref, b[0], b[1], b[2], b[3])

    @property
    def theta(self) -> np.ndarray:
        """The current parameters."""
        return np.array(self.state.theta[:])


def verify(problem, trial: Dataset, out_dir: Path, compiler: list[str] | None = None, repeats: int = 5) -> dict:
    """Generate, compile, check and time `pi_update` on `trial` (module doc); returns the figures."""
    out_dir = Path(out_dir)
    train_idx, test_idx = chronological_split(trial.n, problem.split.train_fraction)
    train, test = trial.subset(train_idx), trial.subset(test_idx)
    start = offline_start("pbr", problem, train)
    ident = start_identifier(start, train)
    state = update_state(ident)
    design = start.design
    paths = c_update.generate_pi_update(design.arm, state, out_dir, KKT_TOL, design.columns)
    library, example = c_update.compile_pi_update(out_dir, compiler)
    P, J = len(start.names), design.n_joints
    c = CUpdate(library, P, J)
    D = design(test.q, test.dq, test.ddq)
    py, cc, failures = np.empty((test.n, P)), np.empty((test.n, P)), 0
    clock, python_seconds = time.perf_counter, 0.0
    for i in range(test.n):
        t0 = clock()
        ident.add(D[i], test.tau[i])
        python_seconds += clock() - t0
        py[i] = ident.theta
        failures += c.update(test.q[i], test.dq[i], test.ddq[i], test.tau[i]) != 0
        cc[i] = c.theta
    worst = max(_relative(cc[i], py[i]) for i in range(test.n))
    se = _standard_errors(
        np.concatenate([design(train.q, train.dq, train.ddq), D]), np.concatenate([train.tau, test.tau]), py[-1]
    )
    scaled = float(np.max(np.abs(cc - py) / np.maximum(np.abs(py), se)))
    torque = max(_torque_relative(D[i], cc[i], py[i]) for i in range(test.n))
    csv = out_dir / "pi_update_samples.csv"
    rows = np.hstack([test.q, test.dq, test.ddq, test.tau])
    header = ",".join(f"{k}{j + 1}" for k in ("q", "dq", "ddq", "tau") for j in range(J))
    with outputs.atomic_path(csv) as tmp:
        np.savetxt(tmp, rows, delimiter=",", header=header, comments="", fmt="%.17g")
    runs = [_run_example(example, csv) for _ in range(repeats)]
    return {
        "samples": int(test.n),
        "offline_samples": int(train.n),
        "parameters": P,
        "joints": J,
        "max_relative_difference": float(worst),
        "max_difference_vs_size_or_se": scaled,
        "max_torque_relative_difference": float(torque),
        "failures": int(failures),
        "c_ns_per_update": min(r["ns_per_update"] for r in runs),
        "c_ns_per_update_runs": [r["ns_per_update"] for r in runs],
        "c_cpu_ns_per_update": min(r["cpu_ns_per_update"] for r in runs),
        "c_ns_regressor": min(r["ns_regressor"] for r in runs),
        "python_us_per_update": python_seconds / test.n * 1e6,
        "final_python": dict(zip(start.names, map(float, py[-1]))),
        "final_c_example": runs[-1]["parameters"],
        "files": [p.name for p in paths] + [library.name, example.name, csv.name],
    }


def _run_example(example: Path, csv: Path) -> dict:
    # absolute: a bare name (codegen --out .) would be looked up on PATH
    done = subprocess.run(
        [str(example.absolute()), str(csv)], capture_output=True, text=True, errors="replace", check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"{example.name} failed ({done.returncode}): {done.stderr or done.stdout}")
    return json.loads(done.stdout)
