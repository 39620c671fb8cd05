"""The streaming service's figures (`docs/online.md`), measured on the real trials:

    .venv/bin/python benchmarks/online_service.py [--out results]

1. Causal derivatives: MERIt exp2 streamed as t, q1, q2, i1, i2 only (offline start on exp1's first 70 %) against
   the batch bounded LS on the same statistics with the batch loader's zero-phase derivatives: |Δ| / SE.
2. Extrapolation guard: DFKI double pendulum, trained on trajectory 00, swing-up trajectory 12 replayed online:
   PBR + GMR (guarded, unguarded) against PBR alone per out-of-support stretch; 95 % interval coverage.
3. The generated `pi_update` against the Python online path over exp1's online part, timed from a C loop.
Writes online_service.md and online_service.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from ident_opt.adaptation.estimator import batch_theta
from ident_opt.adaptation.lines import Mapping
from ident_opt.adaptation.start import serving_identifier
from ident_opt.adaptation.stream import StreamOptions, serve
from ident_opt.arm.planar import RIGID
from ident_opt.data.dataset import chronological_split
from ident_opt.data.loader import load_dataset
from ident_opt.fitting.fit import finish
from ident_opt.fitting.stats import Stats
from ident_opt.numerics.derivatives import REST
from ident_opt.problem import load_problem

ROOT = Path(__file__).resolve().parents[1]
Z95 = 1.959963984540054


def derivatives_figures(problem_path: Path) -> dict:
    """Figure 1 (module doc)."""
    problem = load_problem(problem_path)
    exp1 = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    train = exp1.subset(chronological_split(exp1.n, problem.split.train_fraction)[0])
    start, ident = serving_identifier("pbr", problem, train)
    raw = np.loadtxt(problem.data.trials[1], delimiter=",")
    cols = {"t": 0, "q1": 2, "q2": 3, "i1": 8, "i2": 9}
    text = "t,q1,q2,i1,i2\n" + "".join(",".join(repr(float(r[c])) for c in cols.values()) + "\n" for r in raw)
    options = StreamOptions(
        mapping=Mapping.from_spec(problem.data, problem.robot),
        current_to_torque=tuple(j.current_to_torque for j in problem.robot.joints),
        cutoff_hz=float(train.cutoff_hz or problem.data.derivative_cutoff_hz),
    )
    out = io.StringIO()
    final = serve(ident, start.names, io.StringIO(text), out, io.StringIO(), snapshot_every=0, options=options)["final"]
    spec = dataclasses.replace(
        problem.data, columns={k: v for k, v in problem.data.columns.items() if k in cols}, conversions={}
    )
    exp2 = load_dataset(problem.data.trials[1], spec, problem.robot)
    dq = np.where(np.abs(exp2.dq) < REST, 0.0, exp2.dq)
    stats = Stats.from_data(RIGID, train.q, train.dq, train.ddq, train.tau)
    stats = stats + Stats.from_data(RIGID, exp2.q, dq, exp2.ddq, exp2.tau)
    pi = batch_theta(start.estimator, stats)
    se = finish(stats, RIGID, pi, np.ones(2), "bounded").se
    online = np.array([final["parameters"][n] for n in RIGID.names])
    z = np.where(se > 0, np.abs(online - pi) / np.where(se > 0, se, 1.0), 0.0)
    return {
        "stream": final,
        "batch": dict(zip(RIGID.names, map(float, pi))),
        "se": dict(zip(RIGID.names, map(float, se))),
        "z": dict(zip(RIGID.names, map(float, z))),
        "max_z": float(z.max()),
    }


def guard_figures(problem_path: Path) -> dict:
    """Figure 2 (module doc)."""
    problem = load_problem(problem_path)
    train = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    test = load_dataset(problem.data.trials[1], problem.data, problem.robot)
    runs = {}
    for label, model, guard in (("guarded", "pbr+gmr", True), ("unguarded", "pbr+gmr", False), ("pbr", "pbr", False)):
        _, ident = serving_identifier(model, problem, train, guard=guard)
        preds = []
        for i in range(test.n):
            p, D = ident.step(test.q[i], test.dq[i], test.ddq[i])
            preds.append(p)
            ident.add(D.copy(), test.tau[i])
        runs[label] = {
            "tau": np.array([p.tau for p in preds]),
            "std": np.array([p.std for p in preds]),
            "flags": np.array([p.extrapolating for p in preds]),
        }
    flags = runs["guarded"]["flags"]
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(int), 0]))
    stretches = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]) if b - a >= 50]

    def mse(key, a=0, b=None):
        return np.mean((test.tau[a:b] - runs[key]["tau"][a:b]) ** 2, axis=0)

    ratios = [(mse("guarded", a, b) / mse("pbr", a, b)).tolist() for a, b in stretches]
    variance = np.var(test.tau, axis=0)
    return {
        "samples": int(test.n),
        "extrapolating_share": float(flags.mean()),
        "stretches": stretches,
        "mse_ratio_guarded_over_pbr_per_stretch": ratios,
        "worst_ratio": float(max(max(r) for r in ratios)) if ratios else None,
        "nmse": {k: (mse(k) / variance).tolist() for k in runs},
        "coverage_guarded": np.mean(
            np.abs(test.tau - runs["guarded"]["tau"]) <= Z95 * runs["guarded"]["std"], 0
        ).tolist(),
        "coverage_unguarded": np.mean(
            np.abs(test.tau - runs["unguarded"]["tau"]) <= Z95 * runs["unguarded"]["std"], 0
        ).tolist(),
    }


def update_figures(problem_path: Path) -> dict:
    """Figure 3 (module doc)."""
    from ident_opt.shipping.pi_update import verify  # deferred: compiles C

    problem = load_problem(problem_path)
    exp1 = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    with tempfile.TemporaryDirectory(prefix="ident_opt_pi_update_") as folder:
        result = verify(problem, exp1, Path(folder))
    result.pop("files", None)
    return result


def markdown(data: dict) -> str:
    d, g, u = data["derivatives"], data["guard"], data["pi_update"]
    s = d["stream"]
    lines = [
        "# The streaming service (`python benchmarks/online_service.py`)",
        "",
        "## Causal derivatives: MERIt exp2 streamed as `t, q1, q2, i1, i2` only",
        "",
        f"Offline start: exp1's first 70 %. Derivatives: causal FIR, delay {s['derivatives']['delay_samples']} samples "
        f"({s['derivatives']['delay_s']:.2f} s) at {s['derivatives']['cutoff_hz']:g} Hz; {s['updates']} updates, "
        f"{s['outliers']} outliers refused, {s['derivatives']['lost']} samples at the ends without a centred window.",
        "",
        "| parameter | stream | batch | SE | abs(Δ)/SE |",
        "|---|---|---|---|---|",
    ]
    for n in RIGID.names:
        lines.append(f"| {n} | {s['parameters'][n]:.5g} | {d['batch'][n]:.5g} | {d['se'][n]:.2g} | {d['z'][n]:.2f} |")
    lines += [
        "",
        f"Largest |Δ|/SE: **{d['max_z']:.2f}** (target ≤ 1).",
        "",
        "## Extrapolation guard: DFKI double pendulum, trained on trajectory 00, swing-up 12 replayed online",
        "",
        f"{g['extrapolating_share']:.1%} of the held-out samples are outside the GMR's support. nMSE per joint: "
        f"PBR {_pair(g['nmse']['pbr'])}, PBR + GMR guarded {_pair(g['nmse']['guarded'])}, unguarded "
        f"{_pair(g['nmse']['unguarded'])}. Worst MSE ratio guarded / PBR alone over the out-of-support stretches: "
        f"**{g['worst_ratio']:.3f}** (target ≤ 1.10). 95 % interval coverage: guarded "
        f"**{_pair(g['coverage_guarded'])}** (target ≥ 0.90), unguarded {_pair(g['coverage_unguarded'])}.",
        "",
        "## The generated update (`pi_update`) on exp1's online part",
        "",
        f"{u['samples']} samples after {u['offline_samples']} offline: max relative parameter difference to the "
        f"Python online path **{u['max_relative_difference']:.1e}** (target ≤ 1e-9), {u['failures']} failures; "
        f"**{u['c_ns_per_update']:.0f} ns** per update from the C example's loop (best of "
        f"{len(u['c_ns_per_update_runs'])}; target ≤ 2000).",
        "",
    ]
    return "\n".join(lines)


def _pair(v) -> str:
    return " / ".join(f"{x:.3g}" for x in v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    data = {
        "derivatives": derivatives_figures(ROOT / "problems" / "tudor_2dof.toml"),
        "guard": guard_figures(ROOT / "problems" / "dfki_c0.toml"),
        "pi_update": update_figures(ROOT / "problems" / "tudor_2dof.toml"),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "online_service.json").write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    text = markdown(data)
    (out / "online_service.md").write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
