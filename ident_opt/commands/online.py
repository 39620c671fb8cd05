"""`ident-opt online`: offline fit on the first part of the trial, then exact sequential updates on the rest.

Replay (default): every model (rr, dm, dm_physical, pbr, cpbr, each with and without its GMR residual) is
fitted on the first `[split] train_fraction` of the trial in time; the rest is replayed sample by sample
in time order, each sample first predicted (one step ahead) and then folded in (RR, PBR, CPBR re-solve
exactly on all data seen; DM stays fixed; GMRs follow by the mean-only consistency transform). Writes
the online-vs-frozen error table, the parameter trajectories (figure), the initial and final parameters,
and checks the online parameters against from-scratch batch solves at random steps.

Streaming (`--stream`): the same offline fit, then samples from standard input (CSV with a header, or JSON
lines), one JSON line out per sample; see `ident_opt.stream`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ident_opt.commands.common import add_problem_arguments, load, output_dir, write_json
from ident_opt.errors import InputError

#: Adapted models whose parameters are checked against a batch re-solve (DM never moves).
ADAPTED = ("rr", "pbr", "cpbr")
#: The adapted gray-box model the JSON's `parameters` describe (the paper's Model 3).
GRAY_BOX = "pbr"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's, else results/)")
    parser.add_argument(
        "--stream",
        action="store_true",
        help="serve samples from standard input (CSV with header or JSON lines) instead",
    )
    parser.add_argument(
        "--model",
        default="pbr+gmr",
        help="model served by --stream: rr, dm, dm_physical, pbr or cpbr, optionally +gmr (default pbr+gmr)",
    )
    parser.add_argument(
        "--snapshot-every",
        type=int,
        default=1000,
        metavar="N",
        help="--stream: a parameter snapshot line every N updates (0: none; default 1000)",
    )
    parser.add_argument("--final", metavar="F", help="--stream: also write the final parameters to F (JSON)")
    parser.add_argument(
        "--cross-covariance", action="store_true", help="also apply the first-order cross-covariance update to the GMRs"
    )
    parser.add_argument(
        "--checks",
        type=int,
        default=10,
        metavar="K",
        help="random steps at which the online parameters are checked against a batch "
        "re-solve (plus the last step; default 10)",
    )
    parser.add_argument(
        "--components", type=int, metavar="K", help="GMR components (default: the problem's [residual] setting)"
    )


def run(args: argparse.Namespace) -> int:
    from ident_opt.data import chronological_split

    if args.snapshot_every < 0:
        raise InputError("--snapshot-every must be ≥ 0")
    if args.checks < 0:
        raise InputError("--checks must be ≥ 0")
    if args.components is not None and args.components < 1:
        raise InputError("--components must be ≥ 1")
    loaded = load(args)
    problem, trial = loaded.problem, loaded.train
    train_idx, test_idx = chronological_split(trial.n, problem.split.train_fraction)
    train, test = trial.subset(train_idx), trial.subset(test_idx)
    if train.n < 20 or test.n < 1:
        raise InputError(f"{trial.source}: too few samples for an offline part and an online part ({trial.n})")
    if args.stream:
        return _stream(args, problem, train)
    out = output_dir(args, problem)
    result = replay(
        problem,
        train,
        test,
        cross_covariance=args.cross_covariance,
        checks=args.checks,
        components=args.components,
        seed=int(problem.split.seeds[0]),
    )
    payload = _payload(result, problem, trial, train, test, args.cross_covariance)
    _write_outputs(result, payload, out)
    write_json(args.json, payload)
    _print_summary(result, payload, out)
    return 0


# ---------------------------------------------------------------------------------------------- replay
def replay(
    problem,
    train,
    test,
    *,
    keys=None,
    cross_covariance: bool = False,
    checks: int = 10,
    components: int | None = None,
    seed: int = 0,
    progress: bool = True,
) -> dict:
    """Offline fits on `train`, then the sample-by-sample replay of `test`. Returns a dict with, per model
    key: online and frozen predictions, std, θ trajectories, initial/final θ, update timings; and the
    batch check."""
    import numpy as np
    from tqdm import tqdm

    from ident_opt.models import make_gmr
    from ident_opt.online import MODEL_KEYS, offline_start, start_identifier

    keys = tuple(keys or MODEL_KEYS)
    starts, online = {}, {}
    for key in tqdm(keys, desc="offline fits (+GMR)", file=sys.stderr, disable=not progress):
        starts[key] = offline_start(key, problem, train)
        # Blocked validation for the number of components: the model will predict later motions.
        gmr = make_gmr(problem.residual, components=components, validation="blocked")
        online[key] = start_identifier(starts[key], train, gmr, cross_covariance=cross_covariance)
    X_test = np.hstack([test.q, test.dq, test.ddq])
    frozen, frozen_std = {}, {}
    for key, ident in online.items():
        base = starts[key].design(test.q, test.dq, test.ddq) @ starts[key].theta0
        mean, cov = ident.gmr0.predict(X_test)
        frozen[key], frozen[key + "+gmr"] = base, base + mean
        frozen_std[key + "+gmr"] = np.sqrt(np.einsum("nii->ni", cov))

    n = test.n
    pred = {k: np.empty((n, 2)) for k in frozen}
    std = {k + "+gmr": np.empty((n, 2)) for k in keys}
    theta = {k: np.empty((n, len(starts[k].theta0))) for k in keys}
    seconds = dict.fromkeys(keys, 0.0)  # whole step: design row, prediction, update
    solve_seconds = dict.fromkeys(keys, 0.0)  # the parameter update alone (statistics + re-solve + transform)
    clock = time.perf_counter
    for i in tqdm(
        range(n), desc="online replay", unit="sample", file=sys.stderr, disable=not progress, mininterval=0.5
    ):
        q, dq, ddq, tau = test.q[i], test.dq[i], test.ddq[i], test.tau[i]
        for key, ident in online.items():
            t0 = clock()
            D = ident.design(q[None], dq[None], ddq[None])[0]  # what `update` does, in two timed halves
            p = ident.predict(q, dq, ddq, D)
            t1 = clock()
            ident.add(D, tau)
            t2 = clock()
            seconds[key] += t2 - t0
            solve_seconds[key] += t2 - t1
            pred[key][i], pred[key + "+gmr"][i], std[key + "+gmr"][i] = p.parametric, p.tau, p.std
            theta[key][i] = ident.theta
    check = batch_check(starts, online, theta, train, test, checks, seed)
    return {
        "keys": keys,
        "starts": starts,
        "online": online,
        "pred": pred,
        "std": std,
        "frozen": frozen,
        "frozen_std": frozen_std,
        "theta": theta,
        "seconds": seconds,
        "solve_seconds": solve_seconds,
        "batch_check": check,
        "n": n,
    }


def batch_check(starts, online, theta, train, test, checks: int, seed: int) -> dict:
    """Largest relative difference |θ_online − θ_batch| / |θ_batch| (per parameter; 0/0 counts as 0) at
    `checks` random steps and the last, against a from-scratch solve on the same prefix (cold-started
    solver on freshly accumulated statistics); for PBR also against the paper's re-solve,
    `scipy.optimize.lsq_linear` (BVLS) on all stacked rows."""
    import numpy as np
    from scipy.optimize import lsq_linear

    from ident_opt.identify.stats import Stats
    from ident_opt.online import batch_theta

    n = test.n
    rng = np.random.default_rng(seed)
    steps = sorted(set(rng.choice(n, min(checks, n), replace=False).tolist()) | {n - 1})
    by_model: dict[str, float] = {}
    paper: float | None = None
    for key in (k for k in ADAPTED if k in starts):
        start, worst = starts[key], 0.0
        D_train = start.design(train.q, train.dq, train.ddq)
        D_test = start.design(test.q, test.dq, test.ddq)
        for i in steps:
            D = np.concatenate([D_train, D_test[: i + 1]])
            tau = np.concatenate([train.tau, test.tau[: i + 1]])
            ref = batch_theta(start.estimator, Stats.from_regressor(D, tau))
            worst = max(worst, _relative(theta[key][i], ref))
            if key == "pbr":
                b = start.estimator.bounds
                bv = lsq_linear(
                    D.reshape(-1, D.shape[2]), tau.reshape(-1), bounds=(b.lower, b.upper), method="bvls", tol=1e-15
                ).x
                paper = max(paper or 0.0, _relative(theta[key][i], bv))
        by_model[key] = worst
    return {
        "max_relative_difference": max(by_model.values()) if by_model else 0.0,
        "steps": [int(train.n + i + 1) for i in steps],  # samples seen at each checked step
        "by_model": by_model,
        "reference": "cold-started solver on from-scratch statistics of the same prefix",
        "pbr_vs_lsq_linear": paper,
    }


def _relative(a, b) -> float:
    import numpy as np

    diff = np.abs(a - b)
    scale = np.abs(b)
    # A parameter at exactly 0 (an active bound) in both counts as equal; else relative to its own size.
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(diff == 0, 0.0, diff / np.maximum(scale, 1e-300))
    return float(rel.max())


# ---------------------------------------------------------------------------------------------- outputs
def _metrics(result, which: str) -> dict:
    from ident_opt.metrics import all_metrics

    preds = result["pred"] if which == "online" else result["frozen"]
    out: dict[str, dict[str, list[float]]] = {"rmse": {}, "nmse": {}, "nmse_range": {}}
    for key in result["keys"]:
        for k in (key, key + "+gmr"):
            for metric, value in all_metrics(result["tau"], preds[k]).items():
                out[metric][k] = value
    return out


def _coverage(result, which: str) -> dict:
    from ident_opt.metrics import coverage

    preds = result["pred"] if which == "online" else result["frozen"]
    stds = result["std"] if which == "online" else result["frozen_std"]
    return {
        k + "+gmr": [float(v) for v in coverage(result["tau"], preds[k + "+gmr"], stds[k + "+gmr"])]
        for k in result["keys"]
    }


def _payload(result, problem, trial, train, test, cross_covariance: bool) -> dict:
    result["tau"] = test.tau
    starts, online = result["starts"], result["online"]
    names = starts[GRAY_BOX].names if GRAY_BOX in starts else ()
    rate = {k: (result["n"] / s if s > 0 else None) for k, s in result["seconds"].items()}
    solve_rate = {k: (result["n"] / s if s > 0 else None) for k, s in result["solve_seconds"].items()}
    return {
        "problem": problem.name,
        "data": _shown(trial.source),
        "protocol": (
            f"offline fit on the first {train.n} samples in time ({problem.split.train_fraction:.0%}), "
            f"online replay of the remaining {test.n}; one-step-ahead predictions"
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
            for k in result["keys"]
        },
        "metrics": {"online": _metrics(result, "online"), "frozen": _metrics(result, "frozen")},
        "coverage": {"online": _coverage(result, "online"), "frozen": _coverage(result, "frozen")},
        "updates_per_second": rate.get(GRAY_BOX),
        "updates_per_second_by_model": rate,
        "parameter_updates_per_second_by_model": solve_rate,
        "update_note": "updates_per_second: the whole step = regressor row, prediction (parametric + GMR with "
        "interval), fold into the statistics, exact re-solve, consistency transform; "
        "parameter_updates_per_second: the last three only",
        # spec/cli.md: the largest relative difference (a number); where and against what, beside it.
        "batch_check": result["batch_check"]["max_relative_difference"],
        "batch_check_detail": result["batch_check"],
        "gmr_components": {k: int(online[k].gmr.n_components_) for k in result["keys"]},
        "cross_covariance": cross_covariance,
        "cpbr_solver": _solver_counts(online.get("cpbr")),
    }


def _shown(source) -> str:
    """A data path as the user would write it: relative to the working folder when inside it."""
    path = Path(str(source)).resolve()
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _solver_counts(ident) -> dict | None:
    if ident is None:
        return None
    solver = ident.estimator.solver
    return {"conic_fallbacks": solver.fallbacks, "inexact": solver.inexact, "updates": ident.n_updates}


def _write_outputs(result, payload, out: Path) -> None:
    import pandas as pd

    from ident_opt.tables import markdown_table, write_table

    rows = []
    for metric in ("nmse", "nmse_range", "rmse"):
        for key in payload["metrics"]["online"][metric]:
            on, fr = payload["metrics"]["online"][metric][key], payload["metrics"]["frozen"][metric][key]
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
    params = []
    for key, p in payload["parameters_by_model"].items():
        for name, a, b in zip(p["names"], p["initial"], p["final"]):
            params.append({"model": key, "parameter": name, "initial": a, "final": b})
    write_table(pd.DataFrame(params).set_index(["model", "parameter"]), out / "online_parameters.csv")
    nmse = table.loc["nmse"]
    text = [
        "# Online adaptation (replay in time order)",
        "",
        payload["protocol"] + ".",
        "",
        "nMSE (÷ variance of the measured torque) per joint, online (exact re-solves after every sample, "
        "GMR kept consistent by the mean-only transform) vs frozen (offline model, never updated):",
        "",
        markdown_table(nmse),
        "",
        f"Updates per second ({GRAY_BOX}+GMR, full step): {payload['updates_per_second']:.0f}; parameter "
        f"update alone: {payload['parameter_updates_per_second_by_model'][GRAY_BOX]:.0f}. "
        f"Batch check: largest relative difference {payload['batch_check']:.2e} "
        f"at {len(payload['batch_check_detail']['steps'])} steps.",
        "",
    ]
    (out / "online.md").write_text("\n".join(text), encoding="utf-8")
    write_json(out / "online.json", payload)
    _figure(result, out / "online_trajectories.png")


def _figure(result, path: Path) -> None:
    """PBR and CPBR parameters over the replay, one panel per parameter, relative to the offline value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    keys = [k for k in ("pbr", "cpbr") if k in result["theta"]]
    if not keys:
        return
    names = result["starts"][keys[0]].names
    cols = 3
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 2.4 * rows), sharex=True)
    t = np.arange(1, result["n"] + 1)
    for p, (ax, name) in enumerate(zip(axes.flat, names)):
        for key in keys:
            ax.plot(t, result["theta"][key][:, p], label=key, lw=1.2)
            ax.axhline(result["starts"][key].theta0[p], color="0.6", lw=0.6, ls=":")
        ax.set_title(name, fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.supxlabel("online samples")
    fig.suptitle("Online parameter trajectories (dotted: offline fit); a kg·m², b N·m, fv N·m·s/rad, fc N·m")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _print_summary(result, payload, out: Path) -> None:
    print(payload["protocol"])
    print(f"{'model':<16}{'online nmse j1':>16}{'j2':>10}{'frozen nmse j1':>16}{'j2':>10}")
    on, fr = payload["metrics"]["online"]["nmse"], payload["metrics"]["frozen"]["nmse"]
    for key in on:
        print(f"{key:<16}{on[key][0]:>16.4f}{on[key][1]:>10.4f}{fr[key][0]:>16.4f}{fr[key][1]:>10.4f}")
    check = payload["batch_check_detail"]
    print(
        f"updates/s ({GRAY_BOX}+gmr, full step): {payload['updates_per_second']:.0f} (parameter update alone: "
        f"{payload['parameter_updates_per_second_by_model'][GRAY_BOX]:.0f}); batch check: max relative "
        f"difference {check['max_relative_difference']:.2e} at {len(check['steps'])} steps"
    )
    print(f"wrote {out / 'online.md'}, online_metrics.csv, online_parameters.csv, online_trajectories.png, online.json")


# ---------------------------------------------------------------------------------------------- stream
def _stream(args, problem, train) -> int:
    from ident_opt.models import make_gmr
    from ident_opt.online import MODEL_KEYS, offline_start, start_identifier
    from ident_opt.stream import serve

    key, _, extra = args.model.partition("+")
    if key not in MODEL_KEYS or extra not in ("", "gmr"):
        raise InputError(f"--model must be one of {', '.join(MODEL_KEYS)}, optionally with +gmr; got {args.model!r}")
    start = offline_start(key, problem, train)
    gmr = make_gmr(problem.residual, components=args.components, validation="blocked") if extra else None
    ident = start_identifier(start, train, gmr, cross_covariance=args.cross_covariance)
    print(
        f"ident-opt online --stream: {args.model} ready (offline fit on {train.n} samples); reading samples",
        file=sys.stderr,
        flush=True,
    )
    serve(
        ident,
        start.names,
        sys.stdin,
        sys.stdout,
        sys.stderr,
        args.snapshot_every,
        on_final=(lambda record: write_json(args.final, record)) if args.final else None,
        current_to_torque=tuple(j.current_to_torque for j in problem.robot.joints),
    )
    return 0
