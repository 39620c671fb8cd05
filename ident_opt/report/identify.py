"""What `ident-opt identify` writes: the tables (`identify_tables`), the figures, the README (`identify_readme`), the
JSON (`docs/cli.md`) and the terminal summary.
"""

from __future__ import annotations

import time
from pathlib import Path

from ident_opt.evaluation.identify import IdentifyResult
from ident_opt.paper.protocols import ProtocolResult
from ident_opt.report import figures, record, shown, verdicts, write_json
from ident_opt.report.identify_readme import readme_parts
from ident_opt.report.identify_tables import figure_models, reproduction_frame, write_tables
from ident_opt.report.tables import fmt


# ---------------------------------------------------------------------------------------------- writer
def figure_count(n_joints: int, paper: bool, unseen: bool) -> int:
    """How many figures `write` draws (one progress tick each) for an arm of `n_joints` joints, with the paper's
    protocol (its seed figure) and a held-out trial or not."""
    return 2 * n_joints + 2 + paper + ((n_joints + 1) if unseen else 0)


def write(
    result: IdentifyResult,
    out: Path,
    json_path: str | Path | None,
    command: str,
    started: float,
    tick=lambda: None,
) -> float:
    """Every figure, table, the README and the JSON into `out`; `command` is the command line that ran, `started`
    its `time.perf_counter()` at the start (the README and the JSON say how long it took, figures included).
    `tick()` after each figure. Returns those seconds."""
    made = draw_figures(result, out / "figures", tick)
    seconds = time.perf_counter() - started
    tables = write_tables(result, out)
    head, tail = readme_parts(result, out, tables, made, command, seconds)
    files = [*(f"{name}.md" for name in tables), *(f"{name}.csv" for name in tables), *made.values()]
    verdict = verdicts.fit_verdict(result.choice, result.warnings)
    record(
        out, "identify", "every model under every protocol", files, readme_head=head, readme_tail=tail, verdict=verdict
    )
    write_json(json_path, json_payload(result, seconds))
    return seconds


def draw_figures(result: IdentifyResult, fig_dir: Path, tick) -> dict[str, Path]:
    """The paper's figures on the first split of its protocol (or, without it, on the chronological split), per
    joint; the seed heatmap; and (cross-trial) the unseen trial's predictions: name -> path."""
    example = example_split(result)
    models = figure_models(result)
    made = {}
    for j in range(len(result.joints)):
        made[f"torque_j{j + 1}"] = figures.torque_figure(example, j, fig_dir / f"identify_torque_j{j + 1}.png", models)
        tick()
        made[f"error_j{j + 1}"] = figures.error_figure(example, j, fig_dir / f"identify_error_j{j + 1}.png", models)
        tick()
    made["parity"] = figures.parity_figure(example, fig_dir / "identify_parity.png", models)
    tick()
    made["interval"] = figures.interval_figure(example, fig_dir / "identify_interval_pbr.png")
    tick()
    if result.seeds is not None:
        made["seeds"] = figures.seed_heatmap(result.seeds, fig_dir / "identify_seeds.png")
        tick()
    cross = result.protocols.get("cross_trial")
    if cross is not None:
        made.update(_cross_trial_figures(result, cross, fig_dir, tick))
    return made


def example_split(result: IdentifyResult):
    """The split the figures show: the paper protocol's first, else the chronological one."""
    return (result.protocols.get("paper") or result.protocols["chronological"]).example


def _cross_trial_figures(result: IdentifyResult, cross: ProtocolResult, fig_dir: Path, tick) -> dict[str, Path]:
    trial, unseen = shown(result.trial), shown(result.unseen)
    models = (("rr", "Model 1: ridge regression (RR)"), ("pbr", "Model 3: physics-based regression (PBR)"))
    if "cpbr" in cross.metrics["rmse"]:
        models += (("cpbr", "Constrained physics-based regression (CPBR)"),)
    made = {}
    for j in range(len(result.joints)):
        made[f"cross_j{j + 1}"] = figures.torque_figure(
            cross.example,
            j,
            fig_dir / f"identify_cross_trial_j{j + 1}.png",
            models,
            title=f"Joint {j + 1} on the unseen trial {figures.text(unseen)} (identified on {figures.text(trial)})",
        )
        tick()
    made["cross_interval"] = figures.interval_figure(
        cross.example,
        fig_dir / "identify_cross_trial_interval_pbr.png",
        title=f"PBR + GMR with 95 % intervals on the unseen trial {figures.text(unseen)}",
    )
    tick()
    return made


# ---------------------------------------------------------------------------------------------- JSON
def json_payload(result: IdentifyResult, seconds: float = float("nan")) -> dict:
    """The JSON of `docs/cli.md`: parameters (datasheet/ols/constrained, plus extras) and metrics."""
    metrics = {name: p.as_json() for name, p in result.protocols.items()}
    payload = {
        "problem": result.problem_name,
        "trials": {"identification": shown(result.trial), "unseen": shown(result.unseen) if result.unseen else None},
        "parameters": result.parameters,
        "ridge": result.ridge,
        "standard_errors": result.standard_errors,
        "min_mass_eigenvalue": result.consistency,
        "metrics": metrics,
        "protocols": {name: p.description for name, p in result.protocols.items()},
        "seconds": seconds,
    }
    payload["joints"] = list(result.joints)
    payload["warnings"] = [w.as_dict() for w in result.warnings]
    payload["recommended"] = result.choice.estimator
    payload["recommended_why"] = result.choice.why
    payload["metrics_by_test_trial"] = {shown(k): v for k, v in result.by_test_trial.items()}
    if result.robot_statement:  # what the tool applied to read the robot (a URDF's angle offsets, notes)
        payload["robot"] = list(result.robot_statement)
    if result.variants:
        payload["gmr_variants"] = {
            name: {"label": label, "paper": v.as_json()} for name, (label, v) in result.variants.items()
        }
    return payload


# ---------------------------------------------------------------------------------------------- terminal
def _terminal_reproduction(result: IdentifyResult) -> list[str]:
    """The reproduction rows for the terminal (the paper's robot only; the GMR variants stay in the tables)."""
    lines = ["", "Reproduction (paper's protocol: shuffled 70/30, mean over seeds)   ours    paper   diff   target"]
    for (metric, key, joint), row in reproduction_frame(result).iterrows():
        if "(" in metric:
            continue
        lines.append(
            f"  {metric:<12} {key:<8} J{joint}  {fmt(row['ours'], 4):>28} {fmt(row['paper'], 4):>8} "
            f"{row['difference']:>7} {row['met']:>8}"
        )
    return lines


def terminal(result: IdentifyResult, out: Path, json_path: str | Path | None, seconds: float) -> str:
    """The reproduction rows, nmse per model and protocol, PBR + GMR's coverage, and where the files went."""
    lines = [
        f"ident-opt identify: {result.problem_name} on {shown(result.trial)}"
        + (f" (unseen: {shown(result.unseen)})" if result.unseen else ""),
    ]
    lines += _terminal_reproduction(result) if result.paper_robot else []
    keys = list(next(iter(result.protocols.values())).metrics["nmse"])
    cells = {
        key: [" / ".join(fmt(v, 3) for v in p.metrics["nmse"][key]) for p in result.protocols.values()] for key in keys
    }
    width = 2 + max(len(c) for row in cells.values() for c in [*row, *result.protocols])
    lines += ["", f"nmse (÷ variance) J1 … J{len(result.joints)} per protocol:"]
    lines.append("  " + f"{'model':<16}" + "".join(f"{name:>{width}}" for name in result.protocols))
    lines += [f"  {key:<16}" + "".join(f"{c:>{width}}" for c in row) for key, row in cells.items()]
    cov = {name: p.coverage.get("pbr+gmr") for name, p in result.protocols.items()}
    lines += [
        "",
        "95 % coverage of PBR + GMR: "
        + ", ".join(f"{name} {' / '.join(f'{c:.1%}' for c in v)}" for name, v in cov.items() if v),
    ]
    rec = result.choice
    lines += [
        "",
        f"Recommended fit (cpbr): {rec.estimator} — {rec.why}.",
        "",
        f"wrote {out}/README.md, identify_*.md/.csv, figures/identify_*.png"
        + (f" and {json_path}" if json_path else "")
        + f" in {seconds:.1f} s",
    ]
    return "\n".join(lines)
