"""`ident-opt compare`: datasheet (both conventions) vs OLS vs physically constrained vs NLP-physical.

Writes to the output folder: compare.md (the report), compare_parameters.csv (values and standard
errors), compare_consistency.csv, compare_metrics.csv (held-out rmse / nmse / nmse_range per joint and
protocol), compare_seeds.csv + compare_seeds.png (the paper's seed study) and, with --json, the
machine-readable result. `--constraints-study N` instead runs the study of where the constraints matter
(N short simulated trials) and writes constraints_study.md and constraints_study.csv.
"""

from __future__ import annotations

import argparse

from ident_opt.commands.common import add_problem_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem/--data/--json plus --out, --margin, --extension and --constraints-study."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's [output] dir)")
    parser.add_argument(
        "--margin",
        type=float,
        default=1e-6,
        metavar="KGM2",
        help="required margin of M(q) ⪰ margin·I in the constrained fit [kg m²] (default 1e-6)",
    )
    parser.add_argument(
        "--weights",
        choices=("ols", "wls"),
        default="ols",
        help="ols: both joints weigh the same; wls: each joint by 1/σ² of its residual (default ols)",
    )
    parser.add_argument(
        "--extension",
        action="append",
        default=[],
        metavar="NAME",
        help="fit an extended model (armature, asymmetric_coulomb, stribeck, offset); repeatable",
    )
    parser.add_argument(
        "--constraints-study",
        type=int,
        metavar="N",
        help="run the constraints study on N short simulated trials instead of the comparison",
    )
    parser.add_argument(
        "--study-source",
        choices=("multisine", "simulator", "both"),
        default="both",
        help="trials of the constraints study: the local rigid multisine generator, the built-in "
        "simulator (short tud01 trials), or both (default)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    """Run the comparison (or the constraints study), print a summary, write the files."""
    import pandas as pd

    from ident_opt import compare
    from ident_opt.commands.common import load, output_dir, write_json
    from ident_opt.errors import InputError
    from ident_opt.identify.seeds import rmse_table, seed_heatmap
    from ident_opt.robot import ArmModel
    from ident_opt.tables import write_table

    if args.margin < 0:
        raise InputError(f"--margin must be ≥ 0 (got {args.margin})")
    try:
        model = ArmModel(tuple(args.extension))
    except ValueError as exc:
        raise InputError(f"--extension: {exc}") from None

    if args.constraints_study is not None:
        if args.constraints_study < 1:
            raise InputError("--constraints-study needs a positive number of trials")
        from ident_opt.problem import load_problem

        problem = load_problem(args.problem)
        out = output_dir(args, problem)
        sources = ("multisine", "simulator") if args.study_source == "both" else (args.study_source,)
        results = [
            compare.constraints_study(
                problem.robot, args.constraints_study, source=source, margin=args.margin, progress=not args.no_progress
            )
            for source in sources
        ]
        rich = None
        if "simulator" in sources:
            rich = compare.rich_agreement(problem.robot, margin=args.margin, progress=not args.no_progress)
            print(
                "[rich trials] "
                + ", ".join(f"{k}: {v:.3g}" if isinstance(v, float) else f"{k}: {v}" for k, v in rich.items())
            )
        (out / "constraints_study.md").write_text(compare.study_markdown(results, rich))
        rows = pd.concat([r.rows.assign(source=r.settings["source"]) for r in results], ignore_index=True)
        write_table(rows.set_index(["source", "trial"]), out / "constraints_study.csv")
        for r in results:
            print(
                f"[{r.settings['source']}] "
                + ", ".join(f"{k}: {v:.3g}" if isinstance(v, float) else f"{k}: {v}" for k, v in r.summary.items())
            )
        print(f"wrote constraints_study.md and constraints_study.csv to {out.resolve()}")
        payload = {
            r.settings["source"]: {
                "summary": r.summary,
                "settings": r.settings,
                "trials": r.rows.to_dict(orient="records"),
            }
            for r in results
        }
        if rich is not None:
            payload["rich_trials"] = rich
        write_json(args.json, payload)
        return 0

    loaded = load(args, min_samples=2 * model.n_params)
    problem = loaded.problem
    out = output_dir(args, problem)
    result = compare.compare_estimators(
        loaded.train,
        problem.robot,
        problem.split,
        loaded.unseen,
        model=model,
        margin=args.margin,
        weights=None if args.weights == "ols" else "wls",
        progress=not args.no_progress,
    )
    figure = seed_heatmap(result.seeds, out / "compare_seeds.png", "ols")
    write_table(compare.parameter_table(result), out / "compare_parameters.csv")
    write_table(compare.consistency_table(result), out / "compare_consistency.csv")
    metrics = pd.concat({m: compare.metrics_table(result, m) for m in compare.METRICS}, names=["metric"])
    write_table(metrics, out / "compare_metrics.csv")
    write_table(rmse_table(result.seeds), out / "compare_seeds.csv")
    (out / "compare.md").write_text(compare.to_markdown(result, figure.name))
    print(compare.to_terminal(result))
    files = [
        "compare.md",
        "compare_parameters.csv",
        "compare_consistency.csv",
        "compare_metrics.csv",
        "compare_seeds.csv",
        "compare_seeds.png",
    ]
    print(f"wrote {', '.join(files)} to {out.resolve()}")
    payload = compare.to_json(result)
    payload["files"] = files  # in the output folder
    write_json(args.json, payload)
    return 0
