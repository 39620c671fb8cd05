"""What `ident-opt online` writes for a replay: online.md (online vs frozen nmse, update rate, batch check, and for
an arm whose consistent fit is re-solved at a cadence the distance of the online parameters to it),
online_metrics.csv, online_parameters.csv, online_trajectories.png, online.json (`docs/cli.md`) and the
terminal summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.adaptation.replay import Replay
from ident_opt.report import record, shown, verdicts, write_json
from ident_opt.report.figures import online_trajectories_figure
from ident_opt.report.tables import markdown_table, write_table
from ident_opt.warnings import ResultWarning, markdown_lines

#: The adapted gray-box model the JSON's `parameters` describe (the paper's Model 3).
GRAY_BOX = "pbr"
#: The models whose parameter trajectories are drawn.
DRAWN = ("pbr", "cpbr")
#: At most this many parameters are drawn (those that moved most, relative to their offline value).
MOST_DRAWN = 12
FIGURE = "online_trajectories.png"
FILES = ("online.md", "online_metrics.csv", "online_parameters.csv", FIGURE, "online.json")


def payload(r: Replay, problem, source: str, cross_covariance: bool) -> dict:
    """The `online --json` payload (`docs/cli.md`); `source`: the trial's file."""
    starts, online = r.starts, r.online
    rate = {k: (r.n / s if s > 0 else None) for k, s in r.seconds.items()}
    solve_rate = {k: (r.n / s if s > 0 else None) for k, s in r.solve_seconds.items()}
    return {
        "problem": problem.name,
        "data": shown(source),
        "protocol": (
            f"offline fit on the first {r.train.n} samples in time ({problem.split.train_fraction:.0%}), "
            f"online replay of the remaining {r.test.n}; one-step-ahead predictions"
        ),
        "joints": list(problem.robot.joint_names),
        "parameters": _named(starts.get(GRAY_BOX), online.get(GRAY_BOX), problem.robot),
        "base_parameters": _base(starts.get(GRAY_BOX), online.get(GRAY_BOX)),
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
        "consistency": r.consistency,
        "warnings": _warnings(r),
        **({} if r.choice is None else {"estimator": r.choice.estimator, "estimator_why": r.choice.why}),
    }


def _named(start, ident, robot) -> dict:
    """{"initial", "final"}: the gray-box model's parameters by the arm's names (`docs/cli.md`); on base parameters,
    their standard map (the dependent parameters 0, as `identify --json` gives OLS's), the base values beside it."""
    if start is None:
        return {"initial": {}, "final": {}}
    if start.base is None:
        names = start.names
        return {k: dict(zip(names, map(float, v))) for k, v in (("initial", start.theta0), ("final", ident.theta))}
    names = start.base.standard_names
    return {
        k: dict(zip(names, map(float, start.base.standard(v))))
        for k, v in (("initial", start.theta0), ("final", ident.theta))
    }


def _base(start, ident) -> dict | None:
    """The gray-box model's base parameters (initial, final, each one's definition), when θ is about them."""
    if start is None or start.base is None:
        return None
    return {
        "initial": dict(zip(start.names, map(float, start.theta0))),
        "final": dict(zip(start.names, map(float, ident.theta))),
        "definitions": start.base.definitions(),
        "lower_bounds": {n: 0.0 for n, b in zip(start.names, start.estimator.bounds.lower) if b == 0.0},
    }


def _solver_counts(ident) -> dict | None:
    if ident is None:
        return None
    solver = ident.estimator.solver
    if ident.estimator.kind == "cadence":
        return {
            "re_solves": solver.refreshed,
            "every": solver.every,
            "failed": ident.refresh_failures,
            "seconds": solver.seconds,
            "updates": ident.n_updates,
        }
    return {"conic_fallbacks": solver.fallbacks, "inexact": solver.inexact, "updates": ident.n_updates}


def _warnings(r: Replay) -> list[dict]:
    """What the replay should say beside its numbers (`{code, message}`): failed cadence re-solves."""
    out = []
    for key, ident in r.online.items():
        if ident.refresh_failures:
            out.append(
                {
                    "code": "re_solve_failed",
                    "message": f"{key}: {ident.refresh_failures} from-scratch re-solves failed; its parameters stayed "
                    "at the last one that succeeded",
                }
            )
    return out


def write(r: Replay, data: dict, out: Path, json_path: str | Path | None = None) -> None:
    """Every file of the replay into `out` from its `payload` `data` (also written to `json_path`)."""
    rows = []
    for metric in ("nmse", "nmse_range", "rmse"):
        for key in data["metrics"]["online"][metric]:
            on, fr = data["metrics"]["online"][metric][key], data["metrics"]["frozen"][metric][key]
            row = {"metric": metric, "model": key}
            row.update({f"online_j{j + 1}": v for j, v in enumerate(on)})
            row.update({f"frozen_j{j + 1}": v for j, v in enumerate(fr)})
            rows.append(row)
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
    drawn = [k for k in DRAWN if k in r.theta and r.starts[k].names == r.starts[DRAWN[0]].names]
    if drawn:
        theta0 = {k: r.starts[k].theta0 for k in drawn}
        names, theta = r.starts[drawn[0]].names, {k: r.theta[k] for k in drawn}
        keep = _most_moved(theta[drawn[0]], theta0[drawn[0]])
        title = None
        if keep is not None:
            names = tuple(names[i] for i in keep)
            theta, theta0 = {k: v[:, keep] for k, v in theta.items()}, {k: v[keep] for k, v in theta0.items()}
            title = f"The {len(keep)} parameters that moved most online (relative to their offline value; dotted)"
        online_trajectories_figure(names, theta, theta0, out / FIGURE, title)
    verdict = "\n".join(verdicts.warning_lines([ResultWarning(w["code"], w["message"]) for w in _warnings(r)]))
    record(
        out, "online", "online adaptation: exact re-solves after every sample, online vs frozen", FILES, verdict=verdict
    )
    write_json(json_path, data)


def _most_moved(theta, theta0):
    """Indices of the `MOST_DRAWN` parameters that moved most relative to their offline value, in their order; None
    when there are no more than that."""
    if theta.shape[1] <= MOST_DRAWN:
        return None
    moved = np.abs(theta - theta0).max(axis=0) / np.maximum(np.abs(theta0), 1e-12 * np.abs(theta0).max())
    return sorted(np.argsort(moved)[-MOST_DRAWN:].tolist())


def markdown(data: dict, nmse: pd.DataFrame) -> str:
    """online.md: the protocol, online vs frozen nmse, the update rate and the batch check."""
    return "\n".join(
        [
            "# Online adaptation (replay in time order)",
            "",
            data["protocol"] + ".",
            "",
            *(
                [f"cpbr starts from the **{data['estimator']}** fit: {data['estimator_why']}.", ""]
                if "estimator" in data
                else []
            ),
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
            *_consistency_lines(data),
            "## Warnings",
            "",
            *markdown_lines([ResultWarning(**w) for w in data.get("warnings", [])]),
            "",
        ]
    )


def _consistency_lines(data: dict) -> list[str]:
    """online.md's consistency section: what is exact online, and the distance to the consistent re-solves."""
    c = data.get("consistency")
    if not c:
        return []
    lines = [
        "## Consistency online",
        "",
        f"Exact after every sample (pbr): the lower bound 0 on the {len(c['sign_bounds'])} base parameters that are "
        "non-negative for every consistent arm (friction, armature and the combinations of link parameters whose "
        "coefficients lie in the dual of the pseudo-inertia cone); least slack over the replay "
        f"{_number(c['sign_bound_least_slack'])}. The per-link pseudo-inertia LMIs hold exactly at the cadence: "
        f"cpbr is the {c['estimator']} fit re-solved from scratch on the exact statistics every {c['every']} "
        f"samples ({c['re_solves']} re-solves, {c['re_solve_seconds']:.1f} s in all, {c['failed_re_solves']} "
        "failed), held in between.",
        "",
    ]
    if c["at_re_solves"]:
        lines += [
            "Distance of pbr's online parameters to the consistent re-solve at each re-solve: RMS of the difference "
            "of their torques over every sample seen, per joint [N m] (÷ the consistent fit's residual RMS); and "
            "cpbr as held until then (the previous re-solve) against the new one:",
            "",
            "| samples seen | torque RMS difference [N m] | ÷ residual RMS | parameters: median, largest \\|Δ\\|/SE | "
            "cpbr held: torque RMS difference [N m] | ÷ residual RMS |",
            "|---|---|---|---|---|---|",
        ]
        for row in c["at_re_solves"]:
            se = row["parameter_difference_in_se"]
            lines.append(
                f"| {row['samples_seen']} | {_list(row['torque_rms_difference'])} | "
                f"{_list(row['relative_to_residual'])} | {se['median']:.3g}, {se['max']:.3g} | "
                f"{_list(row['held_torque_rms_difference'])} | {_list(row['held_relative_to_residual'])} |"
            )
        lines.append("")
    return lines


def _list(values) -> str:
    return " / ".join(f"{v:.3g}" for v in values)


def _number(value) -> str:
    return "–" if value is None else f"{value:.3g}"


def terminal(data: dict, out: Path) -> str:
    """nmse online vs frozen per model, the update rate, the batch check, the files."""
    on, fr = data["metrics"]["online"]["nmse"], data["metrics"]["frozen"]["nmse"]
    check = data["batch_check_detail"]
    joints = "/".join(f"j{j + 1}" for j in range(len(next(iter(on.values())))))
    return "\n".join(
        [
            data["protocol"],
            f"{'model':<16}online nmse {joints}   |   frozen nmse {joints}",
            *(f"{key:<16}{_row(on[key])}   |   {_row(fr[key])}" for key in on),
            f"updates/s ({GRAY_BOX}+gmr, full step): {data['updates_per_second']:.0f} (parameter update alone: "
            f"{data['parameter_updates_per_second_by_model'][GRAY_BOX]:.0f}); batch check: max relative "
            f"difference {check['max_relative_difference']:.2e} at {len(check['steps'])} steps",
            *(f"warning: {w['message']}" for w in data.get("warnings", [])),
            f"wrote {out / FILES[0]}, {', '.join(FILES[1:])}",
        ]
    )


def _row(values) -> str:
    return " ".join(f"{v:.4f}" for v in values)
