"""What `ident-opt excite` writes: the trajectory CSV (t, q, dq, ddq at the controller rate and the datasheet
model's feed-forward torque), a figure beside it (`<stem>.png`) and the JSON of its criteria and limits' margins
(`<stem>.json`, `docs/cli.md`); and the terminal summary."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

matplotlib.use("Agg")  # files only, never a window

import matplotlib.pyplot as plt

from ident_opt.errors import InputError
from ident_opt.report import write_json
from ident_opt.studies.excitation import Design, Setup

#: Column names of the trajectory file (the data format's names; the torque is a feed-forward, not a measurement).
COLUMNS = ("t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau_ff1", "tau_ff2")


def paths(out: str | Path) -> tuple[Path, Path, Path]:
    """(CSV, PNG, JSON) of a trajectory written to `out` (*.csv)."""
    out = Path(out)
    if out.suffix.lower() != ".csv":
        raise InputError(f"--out {out}: the trajectory is written as CSV; name it *.csv")
    return out, out.with_suffix(".png"), out.with_suffix(".json")


def frame(d: Design) -> pd.DataFrame:
    """The trajectory as a table in `COLUMNS` (SI units)."""
    return pd.DataFrame(np.column_stack([d.t, d.q, d.dq, d.ddq, d.tau]), columns=list(COLUMNS))


def to_json(d: Design, setup: Setup) -> dict:
    """The design's JSON payload: criteria (and those of its random start), margins, noise model, settings."""
    f = setup.fourier
    return {
        "criterion": d.criterion,
        "criteria": d.criteria,
        "start_criteria": d.start_criteria,
        "margins": d.margins,
        "converged": d.converged,
        "status": d.status,
        "warnings": d.warnings,
        "seconds": d.seconds,
        "starts": d.starts,
        "model": list(setup.arm.names),
        "base_parameters": setup.base_names,
        "noise": {"sigma": setup.sigma.tolist(), "unit": "N m", "source": setup.noise},
        "limits": {k: list(v) if v is not None else None for k, v in vars(setup.limits).items()},
        "fourier": {
            "harmonics": f.harmonics,
            "base_hz": f.base_hz,
            "duration": setup.duration,
            "coefficients": {
                f"joint{j + 1}": {
                    "offset": float(d.x[f.joint_slice(j)][0]),
                    "a": d.x[f.joint_slice(j)][1 : 1 + f.harmonics].tolist(),
                    "b": d.x[f.joint_slice(j)][1 + f.harmonics :].tolist(),
                }
                for j in range(f.n_joints)
            },
        },
        "rate_hz": float(1.0 / (d.t[1] - d.t[0])) if len(d.t) > 1 else None,
        "discrimination": d.discrimination,
    }


def figure(d: Design, setup: Setup, path: Path) -> Path:
    """q, dq, ddq and τ_ff per joint over time, with the limits dashed."""
    lim = setup.limits
    rows = [
        ("q [rad]", d.q, (lim.position_min, lim.position_max)),
        ("dq [rad/s]", d.dq, (tuple(-v for v in lim.velocity), lim.velocity)),
        ("ddq [rad/s²]", d.ddq, (tuple(-a for a in lim.acceleration), lim.acceleration)),
        ("τ_ff [N·m]", d.tau, (tuple(-x for x in lim.torque), lim.torque) if lim.torque else None),
    ]
    fig, axes = plt.subplots(len(rows), 1, figsize=(10, 9), sharex=True)
    for ax, (label, values, bounds) in zip(axes, rows):
        for j in range(values.shape[1]):
            line = ax.plot(d.t, values[:, j], lw=1.0, label=f"joint {j + 1}")[0]
            if bounds is not None:
                for b in bounds:
                    ax.axhline(b[j], color=line.get_color(), ls="--", lw=0.7)
        ax.set_ylabel(label)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    crit = d.criteria
    fig.suptitle(
        f"{d.criterion} design: log det F = {crit.get('log_det', float('nan')):.3g}, "
        f"cond = {crit.get('cond', float('nan')):.3g} (limits dashed)"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write(d: Design, setup: Setup, out: str | Path, json_path: str | Path | None = None) -> list[Path]:
    """The CSV, the figure and the JSON (also to `json_path` when given); returns their paths."""
    csv, png, js = paths(out)
    try:
        csv.parent.mkdir(parents=True, exist_ok=True)
        frame(d).to_csv(csv, index=False, float_format="%.9g")
    except OSError as exc:
        raise InputError(f"{csv}: cannot write the trajectory ({exc.strerror})") from None
    figure(d, setup, png)
    payload = {**to_json(d, setup), "files": [str(csv), str(png), str(js)]}
    write_json(js, payload)
    write_json(json_path, payload)
    return [csv, png, js]


def terminal(d: Design) -> str:
    """A few lines: criteria against the random start, the tightest margin, convergence."""
    c, s = d.criteria, d.start_criteria
    tight = min(((k, j, f) for k, m in d.margins.items() for j, f in enumerate(m["fraction"])), key=lambda x: x[2])
    lines = [
        f"{d.criterion} design in {d.seconds:.1f} s ({len(d.starts)} starts, kept: {d.status})",
        f"  log det F = {c.get('log_det', float('nan')):.4g} (its random start {s.get('log_det', float('nan')):.4g}); "
        f"cond = {c.get('cond', float('nan')):.4g} (start {s.get('cond', float('nan')):.4g})",
        f"  tightest limit: {tight[0]} joint {tight[1] + 1}, {tight[2]:.1%} of the limit left (1 kHz grid)",
    ]
    if d.discrimination:
        lines.append("  " + d.discrimination.get("summary", ""))
    lines += [f"  warning: {w}" for w in d.warnings]
    return "\n".join(lines)
