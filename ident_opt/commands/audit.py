"""The paper audit: the paper's datasheet model (Model 2) beside its own least-squares fit, the
datasheet read under both conventions, the causes named in plain words, and the torque error of
each datasheet model on the real trials without any fitting.

Writes `paper_audit.md`, `paper_audit_parameters.csv`, `paper_audit_data.csv` and
`figures/paper_audit_torque.png` into --out (default: the problem's [output] dir, else results/).
"""

from __future__ import annotations

import argparse

from ident_opt.commands.common import add_problem_arguments, load, output_dir, write_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: results/)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ident_opt import audit
    from ident_opt.tables import markdown_table, write_table

    loaded = load(args)
    problem = loaded.problem
    out = output_dir(args, problem, Path("results"))
    robot = problem.robot
    params = audit.parameter_table(robot)
    body = audit.rigid_body_table(robot)
    data = audit.audit_data(robot, loaded.train, loaded.unseen, problem.split)
    closer = audit.physical_is_closer(robot)

    write_table(params, out / "paper_audit_parameters.csv")
    write_table(data.table, out / "paper_audit_data.csv")
    figure = out / "figures" / "paper_audit_torque.png"
    _figure(loaded.train, data.predictions, figure)

    fit = audit.fit_read_physically(audit.PAPER_FIT)
    lines = [
        "# Paper audit: the datasheet model against the paper's own fit",
        "",
        f"Robot: `{problem.path.name}`; data: `{Path(loaded.train.source).name}`"
        + (f" (unseen trial: `{Path(loaded.unseen.source).name}`)" if loaded.unseen else "")
        + ". Regenerate with `ident-opt audit --problem problems/tudor_2dof_paper.toml`.",
        "",
        "## Parameters",
        "",
        'The paper\'s data-fitted π̂ (its Table "Linear Least Squares Solution") beside the datasheet π computed '
        "under both conventions. The paper fitted π̂ with its printed regressor, whose gravity column counts "
        "β2 cos q1 twice, so its β̂1 means β1 − β2: the `paper_fit_physical` column reads it physically "
        f"(β̂1 + β̂2 = {fit['b1']:.2f} N·m). Relative differences are to that column. Under `physical`, `a1` "
        "includes the joint-1 armature N²J (it cannot be told apart from a1).",
        "",
        markdown_table(params),
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
        markdown_table(body.T),
        "",
        "## Causes",
        "",
    ]
    for title, text, moved in audit.CAUSES:
        lines += [f"- **{title}** (moves {moved}). {text}"]
    lines += [
        "",
        "## On the real trials, no fitting",
        "",
        "Torque error of each datasheet model, next to an OLS fit of the same rigid structure. `nmse` is MSE ÷ "
        "variance of the measured torque (1 = no better than a constant); `nmse_range` is MSE ÷ (max − min)², "
        "the paper's definition. The paper's protocol shuffles the trial, trains on 70 % and tests on 30 % "
        "(the datasheet models use no training data); the cross-trial rows fit OLS on the whole first trial and "
        "test on the second.",
        "",
        markdown_table(data.table),
        "",
        f"![Measured vs datasheet-predicted torque](figures/{figure.name})",
        "",
        "Measured torque (black) against the paper-convention datasheet model (red) and the physical-convention one "
        "(blue), on the whole identification trial: the paper's reading is off by a large, pose-dependent offset "
        "at joint 1; the physical reading follows the measurement without any fitting.",
        "",
    ]
    (out / "paper_audit.md").write_text("\n".join(lines), encoding="utf-8")

    paper = data.table.xs("paper (shuffled 70/30, mean of seeds)", level="protocol")
    print("paper audit: held-out nmse (÷ variance) at joint 1 / joint 2, paper protocol")
    for name, row in paper.iterrows():
        print(f"  {name:<22} {row['nmse_j1']:.4f} / {row['nmse_j2']:.4f}")
    print(f"wrote {out / 'paper_audit.md'}")
    write_json(
        args.json,
        {
            "parameters": {
                "paper_fit": audit.PAPER_FIT,
                "paper_fit_physical": fit,
                **{c: params[f"datasheet_{c}"].to_dict() for c in ("paper", "physical")},
            },
            "physical_closer": closer,
            "metrics": {f"{m} | {p}": row.to_dict() for (m, p), row in data.table.iterrows()},
        },
    )
    return 0


def _figure(trial, predictions: dict, path) -> None:
    """Measured vs predicted torque over time, both joints, both datasheet conventions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for j, ax in enumerate(axes):
        ax.plot(trial.t, trial.tau[:, j], color="black", lw=1.0, label="measured")
        ax.plot(
            trial.t,
            predictions["dm_paper (printed G)"][:, j],
            color="tab:red",
            lw=1.0,
            label="datasheet, paper convention",
        )
        ax.plot(
            trial.t, predictions["dm_physical"][:, j], color="tab:blue", lw=1.0, label="datasheet, physical convention"
        )
        ax.set_ylabel(f"joint {j + 1} torque [N·m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle("Datasheet models without fitting vs measured torque")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
