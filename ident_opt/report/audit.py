"""What `ident-opt audit` writes: paper_audit.md (the paper's π̂ beside the datasheet under both conventions,
the rigid-body parameters behind them, the causes in plain words, the torque error of each datasheet model on
the real trials), paper_audit_parameters.csv, paper_audit_data.csv, figures/paper_audit_torque.png, the JSON
payload and the terminal summary."""

from __future__ import annotations

from pathlib import Path

from ident_opt import outputs
from ident_opt.paper import published as paper
from ident_opt.paper.audit import SHUFFLED, Audit
from ident_opt.report import record, write_json
from ident_opt.report.figures import audit_torque_figure
from ident_opt.report.tables import markdown_table, write_table
from ident_opt.warnings import markdown_lines

#: The causes, in plain words, each with the parameters it moves.
CAUSES = [
    (
        "Actuator mass on the wrong link",
        "The paper lumps joint 1's actuator (1.668 kg) at the distal end of link 1, but joint 1's motor sits on the "
        "fixed base; the motor that rides on link 1 is joint 2's (0.589 kg). This inflates m1 (1.869 vs 0.790 kg) and "
        "so β1 and α1.",
        "a1, b1",
    ),
    (
        "Friction not reflected through the gear ratio",
        "The datasheet's friction is motor-side. At the joint, viscous friction is N² times and Coulomb friction N "
        "times larger (N = 230 and 246): the paper uses the motor-side values, 10⁴–10⁵ too small.",
        "fv1, fv2, fc1, fc2",
    ),
    (
        "Reflected rotor inertia omitted",
        "Each rotor's inertia appears at the joint as N²·J (0.498 and 0.050 kg·m²), larger than the links' own "
        "inertia at joint 1. The paper leaves it out; the physical convention adds it to the diagonal of M "
        "(folded into α1 for joint 1, a separate ia2 for joint 2).",
        "a1 (and a3 through ia2)",
    ),
    (
        "Gravity vector counts β2 cos q1 twice",
        "The printed G1 = (β1 + β2) cos q1 + β2 cos(q1 + q2) has one β2 cos q1 more than the potential energy gives "
        "(G1 = β1 cos q1 + β2 cos(q1 + q2)). Its regressor has the same extra term, so its fitted β̂1 means β1 − β2 "
        "physically: compare β̂1 + β̂2 with a datasheet β1.",
        "b1",
    ),
]


FIGURE = "figures/paper_audit_torque.png"


def write(audit: Audit, out: Path, json_path: str | Path | None = None) -> None:
    """The audit's files into `out`, the JSON payload to `json_path`."""
    write_table(audit.parameters, out / "paper_audit_parameters.csv")
    write_table(audit.data.table, out / "paper_audit_data.csv")
    audit_torque_figure(audit.train, audit.data.predictions, out / FIGURE)
    outputs.write_text(out / "paper_audit.md", markdown(audit))
    files = ("paper_audit.md", "paper_audit_parameters.csv", "paper_audit_data.csv", FIGURE)
    record(out, "audit", "the paper audit: its datasheet model under both conventions", files)
    write_json(json_path, payload(audit))


def markdown(audit: Audit) -> str:
    """paper_audit.md."""
    closer = audit.closer
    lines = [
        "# Paper audit: the datasheet model against the paper's own fit",
        "",
        f"Robot: `{Path(audit.problem_file).name}`; data: `{Path(audit.train.source).name}`"
        + (f" (unseen trial: `{Path(audit.unseen.source).name}`)" if audit.unseen else "")
        + ". Regenerate with `ident-opt audit --problem problems/tudor_2dof_paper.toml`.",
        "",
        "## Parameters",
        "",
        'The paper\'s data-fitted π̂ (its Table "Linear Least Squares Solution") beside the datasheet π computed '
        "under both conventions. The paper fitted π̂ with its printed regressor, whose gravity column counts "
        "β2 cos q1 twice, so its β̂1 means β1 − β2: the `paper_fit_physical` column reads it physically "
        f"(β̂1 + β̂2 = {paper.pi_hat_physical()['b1']:.2f} N·m). Relative differences are to that column. Under "
        "`physical`, `a1` includes the joint-1 armature N²J (it cannot be told apart from a1).",
        "",
        markdown_table(audit.parameters),
        "",
        "The physical datasheet is closer to the fit than the paper's for: "
        + ", ".join(f"`{k}`" for k, v in closer.items() if v)
        + "; not closer for: "
        + (", ".join(f"`{k}`" for k, v in closer.items() if not v) or "none")
        + ".",
        "",
        'Rigid-body parameters behind them (the paper\'s "Dynamic Parameters Used in RBD Model" is the `paper` '
        "column; its printed Ic1 = 3.10e-3 kg·m² is the bar alone, before the actuator and parallel-axis terms):",
        "",
        markdown_table(audit.body.T),
        "",
        "## Causes",
        "",
        *[f"- **{title}** (moves {moved}). {text}" for title, text, moved in CAUSES],
    ]
    return "\n".join(lines + _data_section(audit))


def _data_section(audit: Audit) -> list[str]:
    return [
        "",
        "## On the real trials, no fitting",
        "",
        "Torque error of each datasheet model, next to an OLS fit of the same rigid structure. `nmse` is MSE ÷ "
        "variance of the measured torque (1 = no better than a constant); `nmse_range` is MSE ÷ (max − min)², "
        "the paper's definition. The paper's protocol shuffles the trial, trains on 70 % and tests on 30 % "
        "(the datasheet models use no training data); the cross-trial rows fit OLS on the whole first trial and "
        "test on the second.",
        "",
        markdown_table(audit.data.table),
        "",
        f"![Measured vs datasheet-predicted torque](figures/{Path(FIGURE).name})",
        "",
        "Measured torque (black) against the paper-convention datasheet model (red) and the physical-convention one "
        "(blue), on the whole identification trial: the paper's reading is off by a large, pose-dependent offset "
        "at joint 1; the physical reading follows the measurement without any fitting.",
        "",
        "## Warnings",
        "",
        *markdown_lines(audit.warnings),
        "",
    ]


def payload(audit: Audit) -> dict:
    """The `audit --json` payload: the parameter sets, which are closer, every metric row."""
    return {
        "parameters": {
            "paper_fit": paper.PI_HAT,
            "paper_fit_physical": paper.pi_hat_physical(),
            **{c: audit.parameters[f"datasheet_{c}"].to_dict() for c in ("paper", "physical")},
        },
        "physical_closer": audit.closer,
        "metrics": {f"{m} | {p}": row.to_dict() for (m, p), row in audit.data.table.iterrows()},
        "warnings": [w.as_dict() for w in audit.warnings],
    }


def terminal(audit: Audit, out: Path) -> str:
    """The held-out nmse of every model at joint 1 / joint 2 (paper's protocol), and where the report went."""
    shuffled = audit.data.table.xs(SHUFFLED, level="protocol")
    lines = ["paper audit: held-out nmse (÷ variance) at joint 1 / joint 2, paper protocol"]
    lines += [f"  {name:<22} {row['nmse_j1']:.4f} / {row['nmse_j2']:.4f}" for name, row in shuffled.iterrows()]
    lines.append(f"wrote {out / 'paper_audit.md'}")
    return "\n".join(lines)
