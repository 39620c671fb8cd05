"""What `ident-opt online` writes for a replay: online.md (online vs frozen nmse, update rate, batch check),
online_metrics.csv, online_parameters.csv, online_trajectories.png, online.json (`docs/cli.md`) and the
terminal summary."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ident_opt import outputs
from ident_opt.report import record, shown, write_json
from ident_opt.report.figures import online_trajectories_figure
from ident_opt.report.tables import markdown_table, write_table
from ident_opt.studies.online_replay import Replay

#: The adapted gray-box model the JSON's `parameters` describe (the paper's Model 3).
GRAY_BOX = "pbr"
#: The models whose parameter trajectories are drawn.
DRAWN = ("pbr", "cpbr")
FIGURE = "online_trajectories.png"
FILES = ("online.md", "online_metrics.csv", "online_parameters.csv", FIGURE, "online.json")


def payload(r: Replay, problem, source: str, cross_covariance: bool) -> dict:
    """The `online --json` payload (`docs/cli.md`); `source`: the trial's file."""
    starts, online = r.starts, r.online
    names = starts[GRAY_BOX].names if GRAY_BOX in starts else ()
    rate = {k: (r.n / s if s > 0 else None) for k, s in r.seconds.items()}
    solve_rate = {k: (r.n / s if s > 0 else None) for k, s in r.solve_seconds.items()}
    return {
        "problem": problem.name,
        "data": shown(source),
        "protocol": (
            f"offline fit on the first {r.train.n} samples in time ({problem.split.train_fraction:.0%}), "
            f"online replay of the remaining {r.test.n}; one-step-ahead predictions"
        ),
        "parameters": {
            "initial": dict(zip(names, map(float, starts[GRAY_BOX].theta0))) if names else {},
            "final": dict(zip(names, map(float, online[GRAY_BOX].theta))) if names else {},
        },
        "parameters_by_model": {
            k: {
                "names": list(starts[k].names),
                "initial": [float(v) for v in starts[k].theta0],
                "final": [float(v) for v in online[k].theta],
            }
            for k in r.keys
        },
        "metrics": {"online": r.metrics("online"), "frozen": r.metrics("frozen")},
        "coverage": {"online": r.coverage("online"), "frozen": r.coverage("frozen")},
        "updates_per_second": rate.get(GRAY_BOX),
        "updates_per_second_by_model": rate,
        "parameter_updates_per_second_by_model": solve_rate,
        "update_note": "updates_per_second: the whole step = regressor row, prediction (parametric + GMR with "
        "interval), fold into the statistics, exact re-solve, consistency transform; "
        "parameter_updates_per_second: the last three only",
        # docs/cli.md: the largest relative difference (a number); where and against what, beside it.
        "batch_check": r.batch_check["max_relative_difference"],
        "batch_check_detail": r.batch_check,
        "gmr_components": {k: int(online[k].gmr.n_components_) for k in r.keys},
        "cross_covariance": cross_covariance,
        "cpbr_solver": _solver_counts(online.get("cpbr")),
    }


def _solver_counts(ident) -> dict | None:
    if ident is None:
        return None
    solver = ident.estimator.solver
    return {"conic_fallbacks": solver.fallbacks, "inexact": solver.inexact, "updates": ident.n_updates}


def write(r: Replay, data: dict, out: Path, json_path: str | Path | None = None) -> None:
    """Every file of the replay into `out` from its `payload` `data` (also written to `json_path`)."""
    rows = []
    for metric in ("nmse", "nmse_range", "rmse"):
        for key in data["metrics"]["online"][metric]:
            on, fr = data["metrics"]["online"][metric][key], data["metrics"]["frozen"][metric][key]
            rows.append(
                {
                    "metric": metric,
                    "model": key,
                    "online_j1": on[0],
                    "online_j2": on[1],
                    "frozen_j1": fr[0],
                    "frozen_j2": fr[1],
                }
            )
    table = pd.DataFrame(rows).set_index(["metric", "model"])
    write_table(table, out / "online_metrics.csv")
    params = [
        {"model": key, "parameter": name, "initial": a, "final": b}
        for key, p in data["parameters_by_model"].items()
        for name, a, b in zip(p["names"], p["initial"], p["final"])
    ]
    write_table(pd.DataFrame(params).set_index(["model", "parameter"]), out / "online_parameters.csv")
    outputs.write_text(out / "online.md", markdown(data, table.loc["nmse"]))
    write_json(out / "online.json", data)
    drawn = [k for k in DRAWN if k in r.theta]
    if drawn:
        theta0 = {k: r.starts[k].theta0 for k in drawn}
        online_trajectories_figure(r.starts[drawn[0]].names, {k: r.theta[k] for k in drawn}, theta0, out / FIGURE)
    record(out, "online", "online adaptation: exact re-solves after every sample, online vs frozen", FILES)
    write_json(json_path, data)


def markdown(data: dict, nmse: pd.DataFrame) -> str:
    """online.md: the protocol, online vs frozen nmse, the update rate and the batch check."""
    return "\n".join(
        [
            "# Online adaptation (replay in time order)",
            "",
            data["protocol"] + ".",
            "",
            "nMSE (÷ variance of the measured torque) per joint, online (exact re-solves after every sample, "
            "GMR kept consistent by the mean-only transform) vs frozen (offline model, never updated):",
            "",
            markdown_table(nmse),
            "",
            f"Updates per second ({GRAY_BOX}+GMR, full step): {data['updates_per_second']:.0f}; parameter "
            f"update alone: {data['parameter_updates_per_second_by_model'][GRAY_BOX]:.0f}. "
            f"Batch check: largest relative difference {data['batch_check']:.2e} "
            f"at {len(data['batch_check_detail']['steps'])} steps.",
            "",
        ]
    )


def terminal(data: dict, out: Path) -> str:
    """nmse online vs frozen per model, the update rate, the batch check, the files."""
    on, fr = data["metrics"]["online"]["nmse"], data["metrics"]["frozen"]["nmse"]
    check = data["batch_check_detail"]
    return "\n".join(
        [
            data["protocol"],
            f"{'model':<16}{'online nmse j1':>16}{'j2':>10}{'frozen nmse j1':>16}{'j2':>10}",
            *(f"{key:<16}{on[key][0]:>16.4f}{on[key][1]:>10.4f}{fr[key][0]:>16.4f}{fr[key][1]:>10.4f}" for key in on),
            f"updates/s ({GRAY_BOX}+gmr, full step): {data['updates_per_second']:.0f} (parameter update alone: "
            f"{data['parameter_updates_per_second_by_model'][GRAY_BOX]:.0f}); batch check: max relative "
            f"difference {check['max_relative_difference']:.2e} at {len(check['steps'])} steps",
            f"wrote {out / FILES[0]}, {', '.join(FILES[1:])}",
        ]
    )
