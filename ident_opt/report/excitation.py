"""What `ident-opt excite` writes: the trajectory CSV (t, q, dq, ddq at the controller rate and the datasheet
model's feed-forward torque), a figure beside it (`<stem>.png`) and the JSON of its criteria and limits' margins
(`<stem>.json`, `docs/cli.md`); and the terminal summary. With `--proof`, the simulator study
(`excitation.proof`): results/excitation.md, its CSVs and the designs under results/excitation/."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

matplotlib.use("Agg")  # files only, never a window

import matplotlib.pyplot as plt

from ident_opt import outputs
from ident_opt.columns import joint_columns, kinematic_columns
from ident_opt.errors import InputError
from ident_opt.excitation.design import Design
from ident_opt.excitation.proof import Proof
from ident_opt.excitation.setup import Setup
from ident_opt.report import record, write_json
from ident_opt.report.tables import markdown_table


def paths(out: str | Path) -> tuple[Path, Path, Path]:
    """(CSV, PNG, JSON) of a trajectory written to `out` (*.csv)."""
    out = Path(out)
    if out.suffix.lower() != ".csv":
        raise InputError(f"--out {out}: the trajectory is written as CSV; name it *.csv")
    return out, out.with_suffix(".png"), out.with_suffix(".json")


def frame(d: Design) -> pd.DataFrame:
    """The trajectory as a table (SI units): the data format's t, q, dq, ddq (`columns.kinematic_columns`) and the
    feed-forward torque tau_ff1 … tau_ffn (a command, not a measurement: not named tau)."""
    n = d.q.shape[1]
    names = [*kinematic_columns(n), *joint_columns("tau_ff", n)]
    return pd.DataFrame(np.column_stack([d.t, d.q, d.dq, d.ddq, d.tau]), columns=names)


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
    try:
        with outputs.atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)
    return path


def write(d: Design, setup: Setup, out: str | Path, json_path: str | Path | None = None) -> list[Path]:
    """The CSV, the figure and the JSON (also to `json_path` when given); returns their paths."""
    csv, png, js = paths(out)
    try:
        with outputs.atomic_path(csv) as tmp:
            frame(d).to_csv(tmp, index=False, float_format="%.9g")
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


# ---------------------------------------------------------------------------------------------- the proof
#: How to reproduce the proof (the Makefile's target runs it).
PROOF_COMMAND = "ident-opt excite --problem problems/tudor_2dof.toml --proof 10 --out results/excitation.md"


def proof_paths(report: str | Path) -> tuple[Path, Path, Path, Path]:
    """(report.md, <stem>_identification.csv, <stem>_discrimination.csv, <stem>/ for the designs)."""
    report = Path(report)
    if report.suffix.lower() != ".md":
        raise InputError(f"--out {report}: with --proof, the report is written as Markdown; name it *.md")
    stem = report.with_suffix("")
    return report, Path(f"{stem}_identification.csv"), Path(f"{stem}_discrimination.csv"), stem


def write_proof(p: Proof, report: str | Path) -> list[str]:
    """The report (e.g. results/excitation.md), the CSVs of every trial beside it and the three designs (CSV,
    PNG, JSON each) in the folder of its stem; the manifest for the folder's README.md. Returns the files."""
    md, ident, disc, folder = proof_paths(report)
    out = md.parent
    designs = []
    for name, d in p.designs.items():
        setup = p.setup if name != "discriminate" else p.disc_setup
        designs += [f.relative_to(out).as_posix() for f in write(d, setup, folder / f"{name}.csv")]
    for frame_, path in ((p.identification, ident), (p.discrimination, disc)):
        with outputs.atomic_path(path) as tmp:
            frame_.to_csv(tmp, index=False, float_format="%.6g")
    outputs.write_text(md, proof_markdown(p, folder.name))
    files = [md.name, ident.name, disc.name, *designs]
    title = "excitation design: D-, cond-optimal and discriminating trajectories, proved in the simulator"
    record(out, "excitation", title, files)
    return files


def _designs_section(p: Proof, designs: str) -> list[str]:
    """The title, how to reproduce the proof, and the designs' table with the D-criterion's noise model."""
    return [
        "# Excitation design: proof in the simulator",
        "",
        f"Reproduce: `{PROOF_COMMAND}` (or `make excitation`; {sum(p.seconds.values()) / 60:.0f} min here). "
        f"Duration {p.duration:g} s for every trajectory, the limits of `[limits]` in the problem file, "
        f"{p.seeds} noise seeds each. The designs are in [{designs}/]({designs}/) (CSV at 1 kHz, figure, JSON).",
        "",
        "## The designs",
        "",
        markdown_table(_design_table(p), digits=4),
        "",
        f"Noise model of the D-criterion: {p.setup.noise}, σ = {', '.join(f'{s:.3g}' for s in p.setup.sigma)} N m "
        f"per joint; base parameters: {', '.join(p.setup.base_names)}.",
        "",
    ]


def _identification_section(p: Proof) -> list[str]:
    """The identification table and each design's improvement over the MERIt-like trajectory."""
    lines = [
        "## Identification (clean rigid truth, the simulator's noise)",
        "",
        "Medians over the seeds. Error: median over the parameters of |π̂ − π|/|π| against the simulator's truth "
        "(the nominal structure, OLS and the physically constrained fit). cond: of the column-equilibrated "
        "regressor of the logged motion; log det: of the base parameters' per-sample information.",
        "",
        markdown_table(p.identification_summary(), digits=4),
        "",
    ]
    lines += [
        f"- {label}: median parameter error {ratio['ols']:.3g}× smaller than the MERIt-like trajectory's (OLS), "
        f"{ratio['constrained']:.3g}× (constrained); with resting velocities read as 0: "
        f"{ratio['ols (rests 0)']:.3g}× (OLS), {ratio['constrained (rests 0)']:.3g}× (constrained)."
        for label, ratio in p.improvement().items()
    ]
    return [
        *lines,
        "",
        "The MERIt-like trajectory rests a large part of the time; at rest the sign of an estimated velocity is noise "
        'and the Coulomb columns carry it, so part of its error is its rests (the columns "rests 0" read resting '
        "velocities as 0, as the diagnosis does) and part its poorer excitation.",
        "",
    ]


def _discrimination_section(p: Proof) -> list[str]:
    """The discrimination table, the discriminating design's margin ratios and the gap it expects on real data."""
    a, b = p.between
    scales = "; ".join(f"{level}: × {', '.join(f'{x:.3g}' for x in scale)}" for level, scale in p.noise_scales.items())
    lines = [
        f"## Discrimination: {a} or {b}",
        "",
        f"Each cause hidden in turn where the data put it (`{p.hidden[a]}`; `{p.hidden[b]}`); a training and a "
        "held-out trial per seed, `diagnose` on them. Margin: the true cause's score minus the other's. Two noise "
        "levels: the simulator's (the sensor noise measured on the real robot at rest), and the real trial's "
        "residual as the diagnosis weighs it (the level the design was planned for: the noise scaled per joint "
        f"until a clean simulated trial shows that residual). Torque noise per joint, × the simulator's: {scales}. "
        "Criterion: the score gap the design's criterion expects on the same logged motion at the real residual "
        "level (what the design maximised, checked against the diagnosis it stands for).",
        "",
        markdown_table(p.discrimination_summary(), digits=4),
        "",
    ]
    for level, ratios in p.gap_ratio().items():
        for cause, ratio in ratios.items():
            lines.append(
                f"- {level} noise, {cause} true: the discriminating design's median margin is {ratio:.3g}× the "
                "MERIt-like one's."
            )
    disc = p.designs["discriminate"].discrimination or {}
    if disc:
        lines += ["", f"Expected gap on the real data (the design's criterion): {disc['summary']}."]
    return lines


def proof_markdown(p: Proof, designs: str = "excitation") -> str:
    """The report: the designs, the identification table, the discrimination table, what was measured."""
    lines = [
        *_designs_section(p, designs),
        *_identification_section(p),
        *_discrimination_section(p),
        "",
        f"Timings: {', '.join(f'{k} {v:.0f} s' for k, v in p.seconds.items())}.",
        "",
    ]
    return "\n".join(lines)


def _design_table(p: Proof) -> pd.DataFrame:
    rows = {}
    for name, d in p.designs.items():
        tight = min(f for m in d.margins.values() for f in m["fraction"])
        rows[name] = {
            "log det": d.criteria.get("log_det"),
            "cond": d.criteria.get("cond"),
            "seconds": d.seconds,
            "starts": len(d.starts),
            "converged": d.converged,
            "tightest margin": f"{tight:.1%}",
        }
    return pd.DataFrame(rows).T.rename_axis("design")


def proof_terminal(p: Proof, report: Path) -> str:
    """A few lines: the improvement factors and the margin ratios."""
    lines = [f"excitation proof ({p.seeds} seeds, {p.duration:g} s) written to {report}"]
    for label, ratio in p.improvement().items():
        lines.append(
            f"  {label}: parameter error {ratio['ols']:.3g}× (OLS), {ratio['constrained']:.3g}× (constrained) smaller"
        )
    for level, ratios in p.gap_ratio().items():
        for cause, ratio in ratios.items():
            lines.append(f"  {level} noise, {cause} true: discrimination margin {ratio:.3g}× the MERIt-like one's")
    return "\n".join(lines)
