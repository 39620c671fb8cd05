"""What joint 2 of the real MERIt trials still lacks: held-out nMSE of joint 2 with candidate torque terms.

    .venv/bin/python benchmarks/merit_joint2.py

An exploration, not a cause of the catalogue: joint 2's torque row of the rigid model (OLS on exp1, scored on
exp2 against the raw measured torque, the same nMSE `compare` and `identify` report), then the same fit with
one family of extra columns at a time. Each family is a hypothesis about the arm:
- `sin/cos q1`: a torque on joint 2 that follows link 1's absolute angle (a cable or hose strung along link 1,
  the drive of joint 2 sitting on a link that bends under gravity, or cross-talk from joint 1's gravity);
- `sin/cos kq2` and `sin/cos k(q1+q2)`: position ripple of joint 2's drive, gravity harmonics of link 2;
- `tau1`: joint 1's measured torque (sensor cross-talk);
- `tanh(dq2/s)`, `dq2|dq2|`: friction shapes.
The rigid model's own gravity on joint 2 depends on q1 + q2 only; a term in q1 alone is outside it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ident_opt.arm.planar import RIGID
from ident_opt.data import load_dataset
from ident_opt.problem import load_problem

ROOT = Path(__file__).resolve().parents[1]


def harmonics(angle: np.ndarray, orders: range) -> np.ndarray:
    """Columns sin(k·angle), cos(k·angle) for k in `orders`."""
    return np.column_stack([f(k * angle) for k in orders for f in (np.sin, np.cos)])


FAMILIES = {
    "rigid model only": lambda d: np.empty((d.n, 0)),
    "sin/cos q1": lambda d: harmonics(d.q[:, 0], range(1, 2)),
    "sin/cos q1, 3 harmonics": lambda d: harmonics(d.q[:, 0], range(1, 4)),
    "sin/cos k q2, k = 1..3": lambda d: harmonics(d.q[:, 1], range(1, 4)),
    "sin/cos k (q1 + q2), k = 2..3": lambda d: harmonics(d.q.sum(1), range(2, 4)),
    "tau1 (cross-talk)": lambda d: d.tau[:, :1],
    "tanh(dq2/s), dq2|dq2|": lambda d: np.column_stack(
        [np.tanh(d.dq[:, 1] / s) for s in (0.01, 0.05, 0.2)] + [d.dq[:, 1] * np.abs(d.dq[:, 1])]
    ),
}


def main() -> None:
    problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    train, test = (load_dataset(p, problem.data, problem.robot) for p in problem.data.trials[:2])
    names = [Path(d.source).name for d in (train, test)]
    print(f"joint 2, OLS on {names[0]}, held out: {names[1]} (nMSE against the raw measured torque)")
    print(f"{'extra columns':32s} {'train':>7s} {'held out':>9s}  extra coefficients")
    for name, extra in FAMILIES.items():
        X, Xt = (np.column_stack([RIGID.regressor(d.q, d.dq, d.ddq)[:, 1, :], extra(d)]) for d in (train, test))
        beta, *_ = np.linalg.lstsq(X, train.tau[:, 1], rcond=None)
        nmse = [np.mean((A @ beta - d.tau[:, 1]) ** 2) / np.var(d.tau[:, 1]) for A, d in ((X, train), (Xt, test))]
        coefficients = np.array2string(beta[len(RIGID.names) :], precision=3, max_line_width=60)
        print(f"{name:32s} {nmse[0]:7.3f} {nmse[1]:9.3f}  {coefficients}")


if __name__ == "__main__":
    main()
