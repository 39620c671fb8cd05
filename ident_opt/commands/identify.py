"""`ident-opt identify`: every model (RR, DM in both conventions, PBR, CPBR, each ± GMR) on the problem's
trials under three protocols — the paper's shuffled 70/30 over its seeds, a chronological split, and
cross-trial (identify on the first trial, test on the second) — with the paper's tables and figures.

Writes to --out (default: the problem's [output] dir, else results/): identify_*.md/.csv tables,
figures/identify_*.png, README.md; with --json the result of `spec/cli.md`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ident_opt.commands.common import add_problem_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem, --data, --json, --out, plus --no-variants."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's [output] dir)")
    parser.add_argument(
        "--no-variants",
        action="store_true",
        help="skip the GMR variants of the paper's protocol (diagonal covariances; one component)",
    )


def run(args: argparse.Namespace) -> int:
    """Identify, evaluate, write tables/figures/README/JSON, print a summary."""
    from tqdm import tqdm

    from ident_opt import figures, report
    from ident_opt.commands.common import load, output_dir, write_json
    from ident_opt.protocols import chronological_protocol, cross_trial_protocol, paper_protocol

    start = time.perf_counter()
    loaded = load(args, min_samples=50)
    problem, trial, unseen = loaded.problem, loaded.train, loaded.unseen
    out = output_dir(args, problem)
    fig_dir = out / "figures"
    constrained = True
    seeds = len(problem.split.seeds)
    n_figs = 7 + (3 if unseen is not None else 0)
    total = seeds * (1 if args.no_variants else 3) + 2 + (unseen is not None) + n_figs
    with tqdm(total=total, desc="identify", unit="step", file=sys.stderr, leave=False) as bar:

        def tick() -> None:
            bar.update()

        bar.set_postfix_str("paper's protocol")
        protocols = {"paper": paper_protocol(trial, problem, constrained=constrained, progress=tick)}
        variants = {}
        if not args.no_variants:
            bar.set_postfix_str("paper's protocol, diagonal GMM")
            diag = paper_protocol(trial, problem, constrained=constrained, covariance="diag", progress=tick)
            diag.description += ", diagonal-covariance GMMs"
            bar.set_postfix_str("paper's protocol, one component")
            ones = {key: 1 for key in protocols["paper"].components}
            one = paper_protocol(trial, problem, constrained=constrained, components=ones, progress=tick)
            one.description += ", one full-covariance component"
            variants = {"diagonal_covariance": ("diag GMM", diag), "one_component": ("K = 1", one)}
        bar.set_postfix_str("chronological")
        protocols["chronological"] = chronological_protocol(trial, problem, constrained=constrained, progress=tick)
        if unseen is not None:
            bar.set_postfix_str("cross-trial")
            protocols["cross_trial"] = cross_trial_protocol(
                trial, unseen, problem, constrained=constrained, progress=tick
            )
        bar.set_postfix_str("parameters")
        params, ses, eig = _parameters(problem, trial, constrained)
        ridge = _ridge(trial)
        tick()
        result = report.IdentifyResult(
            problem.name,
            _rel(trial.source),
            _rel(unseen.source) if unseen else None,
            protocols,
            params,
            ses,
            eig,
            variants,
            gmr_candidates=tuple(problem.residual.candidates),
            command=_command(args),
            ridge=ridge,
            reg_covar=problem.residual.reg_covar,
        )
        bar.set_postfix_str("figures")
        result.figures = _figures(figures, result, trial, problem, fig_dir, tick)
        result.seconds = time.perf_counter() - start
        tables = report.write_tables(result, out)
        report.write_readme(result, out, tables)
    write_json(args.json, report.json_payload(result))
    _summary(result, out, args.json)
    return 0


def _command(args: argparse.Namespace) -> str:
    """The command line, rebuilt from the parsed flags (for the README)."""
    parts = ["ident-opt identify", f"--problem {args.problem}"]
    parts += [f"--data {d}" for d in (args.data or [])]
    parts += [f"--out {args.out}"] if args.out else []
    parts += [f"--json {args.json}"] if args.json else []
    parts += ["--no-variants"] if args.no_variants else []
    return " ".join(parts)


def _rel(path: str) -> str:
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def _parameters(problem, trial, constrained: bool):
    """π on the whole first trial: datasheet (both conventions), OLS and constrained, with SEs."""
    import numpy as np

    from ident_opt.datasheet import datasheet_pi
    from ident_opt.models import RigidModel
    from ident_opt.robot import RIGID, ArmModel

    conv = problem.robot.convention
    other = "paper" if conv == "physical" else "physical"
    params = {"datasheet": datasheet_pi(problem.robot, conv), f"datasheet_{other}": datasheet_pi(problem.robot, other)}
    ses, eig = {}, {}
    for est in ("ols", "constrained") if constrained else ("ols",):
        fitted = RigidModel(est, RIGID, estimator=est).fit(trial)
        params[est] = fitted.params()
        if hasattr(fitted.fit_, "se"):
            ses[est] = fitted.fit_.se_dict()
        eig[est] = RIGID.min_mass_eigenvalue(fitted.pi)
    arm = ArmModel(("armature",)) if conv == "physical" else RIGID
    eig["datasheet"] = arm.min_mass_eigenvalue(arm.vector(params["datasheet"]))
    return params, ses, {k: float(np.round(v, 12)) for k, v in eig.items()}


def _ridge(trial) -> dict:
    """Model 1 fitted on the whole first trial: penalty (chosen by leave-one-out CV), weights, intercept."""
    from ident_opt.models import RidgeModel

    rr = RidgeModel().fit(trial)
    features = ("q1", "q2", "dq1", "dq2", "ddq1", "ddq2")
    return {
        "alpha": rr.alpha_.tolist(),
        "intercept": rr.intercept_.tolist(),
        "coef": {f: rr.coef_[:, i].tolist() for i, f in enumerate(features)},
    }


def _figures(figures, result, trial, problem, fig_dir: Path, tick) -> dict[str, Path]:
    example = result.protocols["paper"].example
    made = {}
    for j in (0, 1):
        made[f"torque_j{j + 1}"] = figures.torque_figure(example, j, fig_dir / f"identify_torque_j{j + 1}.png")
        tick()
        made[f"error_j{j + 1}"] = figures.error_figure(example, j, fig_dir / f"identify_error_j{j + 1}.png")
        tick()
    made["parity"] = figures.parity_figure(example, fig_dir / "identify_parity.png")
    tick()
    made["interval"] = figures.interval_figure(example, fig_dir / "identify_interval_pbr.png")
    tick()
    made["seeds"] = figures.seed_figure(trial, problem, fig_dir / "identify_seeds.png")
    tick()
    cross = result.protocols.get("cross_trial")
    if cross is not None:
        models = (
            (
                ("rr", "Model 1: ridge regression (RR)"),
                ("pbr", "Model 3: physics-based regression (PBR)"),
                ("cpbr", "Constrained physics-based regression (CPBR)"),
            )
            if "cpbr" in cross.metrics["rmse"]
            else (("rr", "Model 1: ridge regression (RR)"), ("pbr", "Model 3: physics-based regression (PBR)"))
        )
        for j in (0, 1):
            made[f"cross_j{j + 1}"] = figures.torque_figure(
                cross.example,
                j,
                fig_dir / f"identify_cross_trial_j{j + 1}.png",
                models,
                title=f"Joint {j + 1} on the unseen trial {result.unseen} (identified on {result.trial})",
            )
            tick()
        made["cross_interval"] = figures.interval_figure(
            cross.example,
            fig_dir / "identify_cross_trial_interval_pbr.png",
            title=f"PBR + GMR with 95 % intervals on the unseen trial {result.unseen}",
        )
        tick()
    return made


def _summary(result, out: Path, json_path) -> None:
    from ident_opt.report import reproduction_frame
    from ident_opt.tables import fmt

    print(
        f"ident-opt identify: {result.problem_name} on {result.trial}"
        + (f" (unseen: {result.unseen})" if result.unseen else "")
    )
    repro = reproduction_frame(result)
    print("\nReproduction (paper's protocol: shuffled 70/30, mean over seeds)   ours    paper   diff   target")
    for (metric, key, joint), row in repro.iterrows():
        if "(" in metric:  # the GMR variants: in the tables, not the terminal
            continue
        print(
            f"  {metric:<12} {key:<8} J{joint}  {fmt(row['ours'], 4):>28} {fmt(row['paper'], 4):>8} "
            f"{row['difference']:>7} {row['met']:>8}"
        )
    print("\nnmse (÷ variance) J1 / J2 per protocol:")
    keys = list(result.protocols["paper"].metrics["nmse"])
    print("  " + f"{'model':<16}" + "".join(f"{name:>24}" for name in result.protocols))
    for key in keys:
        cells = "".join(
            f"{fmt(p.metrics['nmse'][key][0], 3) + ' / ' + fmt(p.metrics['nmse'][key][1], 3):>24}"
            for p in result.protocols.values()
        )
        print(f"  {key:<16}{cells}")
    cov = {n: p.coverage.get("pbr+gmr") for n, p in result.protocols.items()}
    print("\n95 % coverage of PBR + GMR: " + ", ".join(f"{n} {v[0]:.1%} / {v[1]:.1%}" for n, v in cov.items() if v))
    print(
        f"\nwrote {out}/README.md, identify_*.md/.csv, figures/identify_*.png"
        + (f" and {json_path}" if json_path else "")
        + f" in {result.seconds:.1f} s"
    )
