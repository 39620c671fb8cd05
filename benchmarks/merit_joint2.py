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

Then the rival stories against the sensors no model uses (issue 30): the strain gauge eps31 on link 2 (column 12,
µm/m) reads link 2's bending moment, the torque link 2 actually carries; the gauges on link 1 (eps21, eps22)
read link 1's. A torque that acts on link 2 (a cable or hose pulling it, a mass on it, link 1's bending tilting
it) must show in eps31 in proportion to its size; a torque that stays in the torque channel (a sensor coupling)
must not. A potential energy (a cable loop hanging at the joint) must show on joint 1's row too. The figure
`results/diagnosis/merit_joint2_strain.png` shows joint 2's residual torque and link 2's residual strain (scaled
to N m) against q1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import RIGID
from ident_opt.data.loader import load_dataset
from ident_opt.numerics.derivatives import lowpass
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


def nmse(residual: np.ndarray, y: np.ndarray) -> float:
    """MSE of `residual` ÷ variance of `y`."""
    return float(np.mean(residual**2) / np.var(y))


def ols(columns, y, train, test) -> tuple[np.ndarray, float, float]:
    """β of y(train) ≈ columns(train) β, and the nMSE on train and on test."""
    A, B = columns(train), columns(test)
    beta, *_ = np.linalg.lstsq(A, y(train), rcond=None)
    return beta, nmse(A @ beta - y(train), y(train)), nmse(B @ beta - y(test), y(test))


STRAIN_CUTOFF_HZ = 3.0  # Hz: the gauges' static and slow part (link 1's mode at 3.2 Hz rings above it)


def strain(column: str):
    """A gauge's signal [µm/m], low-passed at `STRAIN_CUTOFF_HZ`."""
    return lambda d: lowpass(d.t, d.extra[column].to_numpy(float), STRAIN_CUTOFF_HZ)


def q1_harmonic(d) -> np.ndarray:
    """sin q1, cos q1."""
    return harmonics(d.q[:, 0], range(1, 2))


def strain_tests(train, test, robot) -> list[str]:
    """The rival stories of the q1 torque against the gauges and joint 1's row (module docstring), as lines."""
    rows = lambda d, j: RIGID.regressor(d.q, d.dq, d.ddq)[:, j, :]  # noqa: E731
    tau = lambda j: lambda d: d.tau[:, j]  # noqa: E731
    link_side = lambda d: np.column_stack([rows(d, 1)[:, [1, 2, 4]], np.ones(d.n)])  # noqa: E731 (a2, a3, b2, zero)
    beta_t, *_ = ols(lambda d: np.column_stack([rows(d, 1), q1_harmonic(d)]), tau(1), train, test)
    c_tau = beta_t[-2:]
    eps31 = strain("col12")
    beta_s, s_tr, s_te = ols(link_side, eps31, train, test)
    kappa = beta_s[2] / datasheet_pi(robot, "physical")["b2"]  # µm/m per N m of link 2's gravity moment
    beta_f, f_tr, f_te = ols(lambda d: np.column_stack([link_side(d), q1_harmonic(d)]), eps31, train, test)
    forced = lambda d: eps31(d) - kappa * q1_harmonic(d) @ c_tau  # noqa: E731
    beta_x, *_ = ols(link_side, forced, train, test)
    x_te = nmse(link_side(test) @ beta_x + kappa * q1_harmonic(test) @ c_tau - eps31(test), eps31(test))
    x_tr = nmse(link_side(train) @ beta_x + kappa * q1_harmonic(train) @ c_tau - eps31(train), eps31(train))
    fr = lambda d: np.column_stack([d.dq[:, 1], np.sign(d.dq[:, 1]), d.ddq, np.ones(d.n)])  # noqa: E731
    _, g_tr, g_te = ols(lambda d: np.column_stack([eps31(d), fr(d)]), tau(1), train, test)
    beta_h, h_tr, h_te = ols(lambda d: np.column_stack([eps31(d), fr(d), q1_harmonic(d)]), tau(1), train, test)
    # A potential V = c sin(q1 + q2/2 + ψ) (a cable loop at the joint) puts 2 × joint 2's term on joint 1.
    half = lambda d: harmonics(d.q[:, 0] + d.q[:, 1] / 2, range(1, 2))  # noqa: E731
    beta_2, *_ = ols(lambda d: np.column_stack([rows(d, 1), half(d)]), tau(1), train, test)
    _, r1_tr, r1_te = ols(lambda d: rows(d, 0), tau(0), train, test)
    forced1 = lambda d: d.tau[:, 0] - 2 * half(d) @ beta_2[-2:]  # noqa: E731
    beta_1, *_ = ols(lambda d: rows(d, 0), forced1, train, test)
    p1_te = nmse(rows(test, 0) @ beta_1 + 2 * half(test) @ beta_2[-2:] - test.tau[:, 0], test.tau[:, 0])
    amplitude = float(np.hypot(*c_tau))
    # Where the term lives: joint 2 rests (|dq2| < 0.02 rad/s) or moves (> 0.1 rad/s); one q1 pair per regime.
    regimes = []
    for d in (train, test):
        v = np.abs(d.dq[:, 1])
        masks = (v < 0.02, v > 0.1, (v >= 0.02) & (v <= 0.1))
        X = np.column_stack([rows(d, 1), *(q1_harmonic(d) * m[:, None] for m in masks)])
        beta_r, *_ = np.linalg.lstsq(X, d.tau[:, 1], rcond=None)
        pairs = [np.hypot(*beta_r[9 + 2 * k : 11 + 2 * k]) for k in range(3)]
        regimes.append(
            f"{Path(d.source).name}: rests {masks[0].mean():.0%} of samples, q1 term {pairs[0]:.3f} N m "
            f"at rest, {pairs[1]:.3f} moving, {pairs[2]:.3f} between"
        )
    moving = [np.abs(d.dq[:, 1]) > 0.1 for d in (train, test)]
    on_moving = []
    for d, m in zip((train, test), moving):
        X = np.column_stack([link_side(d), q1_harmonic(d)])[m]
        beta_m, *_ = np.linalg.lstsq(X, eps31(d)[m], rcond=None)
        beta_q, *_ = np.linalg.lstsq(np.column_stack([rows(d, 1), q1_harmonic(d)])[m], d.tau[m, 1], rcond=None)
        on_moving.append(
            f"{Path(d.source).name}: torque {np.hypot(*beta_q[-2:]):.3f} N m, strain "
            f"{np.hypot(*beta_m[-2:]) / kappa:.3f} N m"
        )
    return [
        "",
        f"Rival stories of the q1 torque (amplitude {amplitude:.3f} N m on joint 2) against link 2's gauge eps31 "
        f"(low-passed at {STRAIN_CUTOFF_HZ:g} Hz):",
        f"  eps31 ~ link 2's rigid link-side columns (a2, a3, b2, zero): nMSE {s_tr:.4f} train, {s_te:.4f} held out; "
        f"gain {kappa:.1f} µm/m per N m of link 2's gravity moment",
        f"  + sin/cos q1, free: nMSE {f_tr:.4f} / {f_te:.4f}; its q1 term {np.hypot(*beta_f[-2:]):.2f} µm/m "
        f"= {np.hypot(*beta_f[-2:]) / kappa:.4f} N m",
        "  + the q1 torque forced in (a torque on link 2: cable, mass, link 1's bending): "
        f"nMSE {x_tr:.3f} / {x_te:.3f}",
        f"  -> eps31 carries {np.hypot(*beta_f[-2:]) / kappa / amplitude:.1%} of the q1 torque: "
        "it does not reach link 2",
        "Joint 2's torque with link 2's gauge as its link-side torque (eps31, friction, ddq, zero): "
        f"nMSE {g_tr:.3f} / {g_te:.3f}; + sin/cos q1: {h_tr:.3f} / {h_te:.3f} "
        f"(q1 term {np.hypot(*beta_h[-2:]):.3f} N m beyond what link 2 carries)",
        f"A potential at the joint (cable loop, sin/cos(q1 + q2/2)): joint 1's held-out nMSE {r1_te:.4f} (rigid) -> "
        f"{p1_te:.4f} with the 2 x term it implies there ({r1_tr:.4f} train)",
        "Joint 2's q1 term by regime (one pair each, fitted on each trial alone): " + "; ".join(regimes),
        "Moving samples only (|dq2| > 0.1 rad/s), q1 term of each fit alone: " + "; ".join(on_moving),
    ]


def rigid_pi(d) -> np.ndarray:
    """π of the rigid model by OLS on both joints' rows of trial `d` (joint velocities at rest read as 0)."""
    Y = RIGID.regressor(d.q, d.dq, d.ddq)
    return np.linalg.lstsq(np.vstack([Y[:, 0], Y[:, 1]]), np.concatenate([d.tau[:, 0], d.tau[:, 1]]), rcond=None)[0]


def crosstalk_steps(d, c_tau1: float) -> str:
    """Cross-talk from drive 1 into drive 2's channel puts c × each step of joint 1's torque into joint 2's, at zero
    lag. Joint 1's reversals while joint 2 rests (±0.3 s) step joint 1's torque by its Coulomb level: the step of
    joint 2's torque there (mean over 0.05–0.25 s after minus before) against c × joint 1's."""
    s = np.sign(d.dq[:, 0])
    events = []
    for k in np.flatnonzero(s[1:] * s[:-1] < 0) + 1:
        if 40 < k < d.n - 40 and np.all(np.abs(d.dq[k - 30 : k + 30, 1]) < 0.02):
            step = [d.tau[k + 5 : k + 25, j].mean() - d.tau[k - 25 : k - 5, j].mean() for j in (0, 1)]
            events.append(step)
    e = np.array(events)
    big = np.abs(e[:, 0]) > 2.0
    slope = float(e[:, 0] @ e[:, 1] / (e[:, 0] @ e[:, 0]))
    return (
        f"{Path(d.source).name}: {len(e)} reversals of joint 1 while joint 2 rests; joint 2's torque steps by "
        f"{slope:.4f} x joint 1's (the cross-talk fitted above: {c_tau1:.3f}); steps of joint 1 beyond 2 N m: "
        + ", ".join(f"{a:.2f} -> {b:.3f}" for a, b in e[big])
        + " N m"
    )


def approach_levels(d, pi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per rest stretch of joint 2 (at least 0.3 s): the sign of joint 2's velocity just before it stopped, and the
    stretch's mean residual of the rigid fit `pi`."""
    from ident_opt.numerics import signals

    r = d.tau[:, 1] - np.einsum("np,p->n", RIGID.regressor(d.q, d.dq, d.ddq)[:, 1, :], pi)
    labels = signals.rest_runs(d.dq)[:, 1]
    sign, level = [], []
    for k in np.unique(labels[labels >= 0]):
        idx = np.flatnonzero(labels == k)
        if len(idx) >= 30 and idx[0] >= 20:
            sign.append(np.sign(d.raw_dq2[idx[0] - 20 : idx[0]].mean()))
            level.append(r[idx].mean())
    return np.array(sign), np.array(level)


def channel_stories(train, test, c_tau1: float) -> list[str]:
    """The two stories left for the torque on joint 2 that follows joint 1's angle (issue 48, point 7), told apart on
    the samples each predicts, and the constant offset per trial."""
    from dataclasses import replace

    from ident_opt.diagnosis.split import at_rest

    views = [replace(at_rest(d), extra=d.extra) for d in (train, test)]
    for v, d in zip(views, (train, test)):
        v.raw_dq2 = d.dq[:, 1]
    lines = ["", "Cross-talk from drive 1's current into drive 2's channel (zero-lag steps at joint 1's reversals):"]
    lines += ["  " + crosstalk_steps(d, c_tau1) for d in (train, test)]
    lines.append("A rest level set by the direction joint 2 approached from (level = a x sign + c per rest stretch):")
    fits = [(approach_levels(v, rigid_pi(views[0]))) for v in views]
    for name, other in ((0, 1), (1, 0)):
        A = np.column_stack([fits[name][0], np.ones(len(fits[name][0]))])
        beta, *_ = np.linalg.lstsq(A, fits[name][1], rcond=None)
        B = np.column_stack([fits[other][0], np.ones(len(fits[other][0]))])
        r2 = 1 - np.var(fits[other][1] - B @ beta) / np.var(fits[other][1])
        lines.append(
            f"  fitted on {Path(views[name].source).name} ({len(A)} stretches): a {beta[0]:.3f}, c {beta[1]:.3f} N m; "
            f"R² on {Path(views[other].source).name}: {r2:.2f}"
        )
    lines.append(
        "A constant offset of each torque channel (the rigid fit of each trial alone with a constant per joint):"
    )
    for v in views:
        Y = RIGID.regressor(v.q, v.dq, v.ddq)
        A = np.concatenate([Y, np.broadcast_to(np.eye(2), (v.n, 2, 2))], axis=2)
        A2, b2 = np.vstack([A[:, 0], A[:, 1]]), np.concatenate([v.tau[:, 0], v.tau[:, 1]])
        beta, *_ = np.linalg.lstsq(A2, b2, rcond=None)
        res = A2 @ beta - b2
        se = np.sqrt(np.diag(res @ res / (len(b2) - A2.shape[1]) * np.linalg.inv(A2.T @ A2)))
        lines.append(
            f"  {Path(v.source).name}: b = {beta[-2]:.3f} ± {se[-2]:.3f}, {beta[-1]:.3f} ± {se[-1]:.3f} N m "
            "(white-noise standard errors)"
        )
    return lines


def figure(train, robot, path: Path) -> None:
    """Joint 2's torque and link 2's strain (in N m), each minus the rigid part of a fit with sin/cos q1 beside
    it (the q1 term plus the residual), binned against q1, with the q1 term fitted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Y = RIGID.regressor(train.q, train.dq, train.ddq)
    H = q1_harmonic(train)
    eps = strain("col12")(train)
    S = np.column_stack([Y[:, 1, [1, 2, 4]], np.ones(train.n)])
    beta_s, *_ = np.linalg.lstsq(S, eps, rcond=None)
    kappa = beta_s[2] / datasheet_pi(robot, "physical")["b2"]
    edges = np.linspace(train.q[:, 0].min(), train.q[:, 0].max(), 25)
    mid = 0.5 * (edges[1:] + edges[:-1])
    which = np.digitize(train.q[:, 0], edges[1:-1])
    grid = np.column_stack([np.sin(mid), np.cos(mid)])
    fig, ax = plt.subplots(figsize=(7, 4))
    for rigid, y, scale, label in (
        (Y[:, 1, :], train.tau[:, 1], 1.0, "joint 2's torque (current)"),
        (S, eps, kappa, "link 2's strain eps31, as N m"),
    ):
        beta, *_ = np.linalg.lstsq(np.column_stack([rigid, H]), y, rcond=None)
        partial = (y - rigid @ beta[: rigid.shape[1]]) / scale
        offset = np.mean(partial)
        line = ax.plot(mid, [partial[which == k].mean() - offset for k in range(len(mid))], "o", label=label)[0]
        ax.plot(mid, (grid @ beta[-2:]) / scale - np.mean(H @ beta[-2:]) / scale, "-", color=line.get_color())
    ax.set(
        xlabel="q1 [rad]",
        ylabel="q1 term + residual [N m], bin mean",
        title="MERIt exp1: the q1 torque is in joint 2's current, not in link 2",
    )
    ax.axhline(0, color="k", lw=0.5)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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
    print("\n".join(strain_tests(train, test, problem.robot)))
    X = np.column_stack([RIGID.regressor(train.q, train.dq, train.ddq)[:, 1, :], train.tau[:, :1]])
    c_tau1 = float(np.linalg.lstsq(X, train.tau[:, 1], rcond=None)[0][-1])
    print("\n".join(channel_stories(train, test, c_tau1)))
    raw = problem.data.trials[0].parent / "exp1.csv"
    still = np.loadtxt(raw, delimiter=",", usecols=(1, 7))
    print(
        f"TUDOR's first drive (it never moves: {np.ptp(still[:, 0]):.1e} rad) reads {still[:, 1].mean():.4f} A "
        f"± {still[:, 1].std():.4f} A on exp1: the logger's current channels carry zero offsets of that size"
    )
    figure(train, problem.robot, ROOT / "results" / "diagnosis" / "merit_joint2_strain.png")


if __name__ == "__main__":
    main()
