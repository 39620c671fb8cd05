"""Side-by-side identification: datasheet (both conventions), OLS, constrained, NLP-physical.

Three jobs, one module:

- `compare_estimators`: the parameter table (values ± SE, physical consistency) and held-out nMSE per
  joint on the paper's shuffled protocol, the chronological split and the unseen trial.
- `constraints_study`: where the constraints matter — many short, poorly exciting rigid trials with a
  known truth; how often OLS is inconsistent and whose parameters are closer to the truth.
- rendering: terminal text, Markdown, CSV and a JSON payload (`spec/cli.md`).

Every estimator is fitted from sufficient statistics of the training samples only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import pandas as pd

from ident_opt.data import Dataset
from ident_opt.datasheet import datasheet_pi
from ident_opt.identify import estimators as registry
from ident_opt.identify.constrained import fit_constrained
from ident_opt.identify.fit import LinearFit, fit_ols
from ident_opt.identify.nlp import fit_physical
from ident_opt.identify.stats import Stats
from ident_opt.metrics import all_metrics
from ident_opt.robot import ArmModel

METRICS = ("rmse", "nmse", "nmse_range")


# ---------------------------------------------------------------------------------------------- estimators
def estimators(
    robot, margin: float = 1e-6, weights: str | None = None
) -> dict[str, Callable[[Stats, ArmModel], LinearFit]]:
    """The fitted estimators by key: statistics + model → LinearFit (`weights`: None or "wls")."""
    return {
        "ols": partial(registry.fit, "ols", weights=weights),
        "constrained": partial(registry.fit, "constrained", margin=margin, weights=weights),
        "nlp_physical": lambda st, m: fit_physical(st, robot, m, weights=weights),
    }


def datasheet_models(robot) -> dict[str, tuple[ArmModel, np.ndarray]]:
    """The datasheet under both conventions, each with the model it is evaluated with.

    The physical convention carries the joint-2 armature (`ia2`); the paper convention is evaluated with
    the paper's printed gravity vector, as its Model 2 was (that is what reproduces its DM row).
    """
    out = {}
    for conv, model in (("paper", ArmModel(gravity="paper")), ("physical", ArmModel(("armature",)))):
        out[f"datasheet_{conv}"] = (model, model.vector(datasheet_pi(robot, conv)))
    return out


# ---------------------------------------------------------------------------------------------- synthetic trials
def multisine_trial(
    model: ArmModel,
    pi_true: np.ndarray,
    *,
    duration: float,
    rate_hz: float = 100.0,
    seed: int = 0,
    amplitude: tuple[float, float] = (0.6, 0.6),
    noise: tuple[float, float] = (0.5, 0.3),
    n_sines: int = 4,
    band_hz: tuple[float, float] = (0.1, 1.0),
) -> Dataset:
    """A rigid trial with known truth: q_j(t) = q0_j + Σ_k A_jk sin(2π f_k t + φ_jk) [rad], exact dq and ddq,
    τ = Y(q, dq, ddq) π_true + N(0, noise_j²) [N m]. Deterministic for a seed. A joint with amplitude 0
    stays still (its friction and inertia columns are then not excited)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate_hz)
    q, dq, ddq = (np.zeros((len(t), 2)) for _ in range(3))
    for j in range(2):
        q[:, j] = rng.uniform(-np.pi / 2, np.pi / 2) if j == 0 else rng.uniform(-2.0, 2.0)
        if amplitude[j] == 0:
            continue
        f = rng.uniform(*band_hz, n_sines)
        a = amplitude[j] * rng.uniform(0.3, 1.0, n_sines) / n_sines
        phi = rng.uniform(0, 2 * np.pi, n_sines)
        arg = 2 * np.pi * f[None, :] * t[:, None] + phi[None, :]
        w = 2 * np.pi * f[None, :]
        q[:, j] += (a * np.sin(arg)).sum(1)
        dq[:, j] = (a * w * np.cos(arg)).sum(1)
        ddq[:, j] = -(a * w**2 * np.sin(arg)).sum(1)
    tau = model.predict(pi_true, q, dq, ddq) + rng.normal(size=(len(t), 2)) * np.asarray(noise)
    return Dataset(f"multisine(seed={seed}, {duration:.2f} s)", t, q, dq, ddq, tau, derivatives="exact")


def relative_error(pi_hat: np.ndarray, pi_true: np.ndarray) -> float:
    """RMS over parameters of (π̂_p − π_p)/|π_p|: a unit-free parameter error."""
    return float(np.sqrt(np.mean(((pi_hat - pi_true) / np.abs(pi_true)) ** 2)))


@dataclass
class StudyResult:
    """Per-trial results of `constraints_study` and its summary."""

    rows: pd.DataFrame
    settings: dict = field(default_factory=dict)

    @property
    def summary(self) -> dict:
        """Inconsistency rate of OLS, the constrained fit's, win rate and median error ratio."""
        r = self.rows
        differ = r["err_constrained"] != r["err_ols"]
        ratio = r["err_constrained"] / r["err_ols"]
        return {
            "trials": len(r),
            "ols_inconsistent": int((~r["ols_consistent"]).sum()),
            "constrained_inconsistent": int((~r["constrained_consistent"]).sum()),
            "fits_differ": int(differ.sum()),
            "constrained_wins": int((r["err_constrained"] < r["err_ols"]).sum()),
            "win_rate_where_differ": float((r["err_constrained"] < r["err_ols"])[differ].mean())
            if differ.any()
            else float("nan"),
            "median_error_ols": float(r["err_ols"].median()),
            "median_error_constrained": float(r["err_constrained"].median()),
            "median_error_ratio": float(ratio.median()),
            "median_error_ratio_where_differ": float(ratio[differ].median()) if differ.any() else float("nan"),
            "median_error_ols_excited": float(r["err_ols_excited"].median()),
            "median_error_constrained_excited": float(r["err_constrained_excited"].median()),
        }


STUDY_SOURCES = {
    "multisine": "a local rigid generator: one joint moves (multisine, alternating), the other is held still or "
    "moves ±0.05 rad; exact dq, ddq; Gaussian torque noise",
    "simulator": "the built-in simulator (`ident_opt.simulate`, no hidden effect): the first seconds of a "
    "tud01 point-to-point trial under closed-loop control, with its measurement noise, "
    "quantisation and estimated derivatives",
}


def _study_trial(
    source: str,
    robot,
    model: ArmModel,
    pi_sheet: np.ndarray,
    i: int,
    duration: float,
    seed: int,
    noise: tuple[float, float],
    rate_hz: float,
) -> tuple[Dataset, np.ndarray, dict]:
    """Trial i of the constraints study: (data, true π, description columns)."""
    if source == "simulator":
        from ident_opt.simulate import simulate_trial

        sim = simulate_trial(
            robot, trajectory="tud01", duration=duration, rate_hz=rate_hz, seed=seed * 100003 + i, progress=False
        )
        data = sim.dataset()
        moved = np.ptp(data.q, axis=0) > 0.05
        return (
            data,
            model.vector(sim.truth["pi"]),
            {"moving_joints": "".join(str(j + 1) for j in range(2) if moved[j]) or "none"},
        )
    moving = i % 2
    small = 0.0 if (i // 2) % 2 == 0 else 0.05
    amp = (0.8, small) if moving == 0 else (small, 0.8)
    data = multisine_trial(
        model, pi_sheet, duration=duration, rate_hz=rate_hz, seed=seed * 100003 + i, amplitude=amp, noise=noise
    )
    return data, pi_sheet, {"moving_joints": str(moving + 1), "other_amplitude": small}


def constraints_study(
    robot,
    n_trials: int = 50,
    *,
    source: str = "multisine",
    seed: int = 0,
    durations: tuple[float, float] = (2.0, 5.0),
    noise: tuple[float, float] = (0.5, 0.3),
    rate_hz: float = 100.0,
    margin: float = 1e-6,
    progress: bool = True,
) -> StudyResult:
    """OLS vs constrained on `n_trials` short, poorly exciting trials with known truth.

    `source`: "multisine" or "simulator" (see `STUDY_SOURCES`). Truth: the physical-convention datasheet
    π with joint-2 armature; the fitted model is `ArmModel(("armature",))`, which contains the truth.
    Trial i lasts a duration uniform in `durations` [s]; `noise` [N m] is the multisine source's.
    """
    from tqdm import tqdm

    if source not in STUDY_SOURCES:
        raise ValueError(f"source must be one of {sorted(STUDY_SOURCES)}, not {source!r}")
    model = ArmModel(("armature",))
    pi_sheet = model.vector(datasheet_pi(robot, "physical"))
    rng = np.random.default_rng(seed)
    rows = []
    for i in tqdm(range(n_trials), desc=f"constraints study ({source})", disable=not progress):
        duration = float(rng.uniform(*durations))
        trial, pi_true, described = _study_trial(source, robot, model, pi_sheet, i, duration, seed, noise, rate_hz)
        st = Stats.from_data(model, trial.q, trial.dq, trial.ddq, trial.tau)
        ols = fit_ols(st, model)
        con = fit_constrained(st, model, margin=margin)
        excited = np.array([name not in ols.unexcited for name in model.names])
        rows.append(
            {
                "trial": i,
                "duration_s": duration,
                **described,
                "rank": ols.rank,
                "ols_consistent": ols.consistent,
                "ols_min_eig": ols.min_mass_eigenvalue,
                "constrained_consistent": bool(con.min_mass_eigenvalue >= margin * (1 - 1e-6) and con.consistent),
                "constrained_min_eig": con.min_mass_eigenvalue,
                "active": " ".join(con.active),
                "err_ols": relative_error(ols.pi, pi_true),
                "err_constrained": relative_error(con.pi, pi_true),
                # the same over the parameters whose columns the trial excites at all
                "err_ols_excited": relative_error(ols.pi[excited], pi_true[excited]),
                "err_constrained_excited": relative_error(con.pi[excited], pi_true[excited]),
            }
        )
    settings = {
        "n_trials": n_trials,
        "source": source,
        "seed": seed,
        "durations_s": list(durations),
        "noise_nm": list(noise) if source == "multisine" else "the simulator's",
        "rate_hz": rate_hz,
        "margin": margin,
        "model": list(model.names),
        "truth": "physical-convention datasheet π with joint-2 armature",
    }
    return StudyResult(pd.DataFrame(rows), settings)


def rich_agreement(
    robot, n_trials: int = 10, *, duration: float = 30.0, seed: int = 0, margin: float = 1e-6, progress: bool = True
) -> dict:
    """On exciting simulated trials (the simulator's `fourier` reference, both joints, `duration` s): is
    OLS consistent, how far is the constrained fit from it in OLS standard errors, and how often is the
    truth within ±2 SE. Returns a summary dict."""
    from tqdm import tqdm

    from ident_opt.simulate import simulate_trial

    model = ArmModel(("armature",))
    distance, inside, consistent = [], [], 0
    for i in tqdm(range(n_trials), desc="rich trials", disable=not progress):
        sim = simulate_trial(robot, trajectory="fourier", duration=duration, seed=seed * 100003 + i, progress=False)
        data = sim.dataset()
        st = Stats.from_data(model, data.q, data.dq, data.ddq, data.tau)
        ols, con = fit_ols(st, model), fit_constrained(st, model, margin=margin)
        consistent += ols.consistent
        distance.append(float(np.max(np.abs(con.pi - ols.pi) / ols.se)))
        inside.append(np.abs(ols.pi - model.vector(sim.truth["pi"])) <= 2 * ols.se)
    return {
        "trials": n_trials,
        "duration_s": duration,
        "ols_consistent": int(consistent),
        "max_constrained_minus_ols_in_se": float(max(distance)),
        "truth_within_2se": float(np.mean(inside)),
    }


def study_markdown(results: StudyResult | list[StudyResult], rich: dict | None = None) -> str:
    """`results/constraints_study.md`: what was run, the summary in numbers per trial source, per-trial tables."""
    from ident_opt.tables import markdown_table

    results = [results] if isinstance(results, StudyResult) else list(results)
    cfg = results[0].settings
    lines = [
        "# Where the physical-consistency constraints matter",
        "",
        f"Short trials ({cfg['durations_s'][0]:g}–{cfg['durations_s'][1]:g} s at {cfg['rate_hz']:g} Hz) with a "
        f"known truth ({cfg['truth']}); fitted model: {', '.join(cfg['model'])}. OLS vs constrained = "
        f"M(q) ⪰ {cfg['margin']:g}·I ∀q, friction ≥ 0 and armature ≥ 0 (from the sufficient statistics; Clarabel). "
        "Parameter error = RMS over parameters of (π̂ − π)/|π|. Trial sources:",
        "",
        *[
            f"- **{r.settings['source']}**: {STUDY_SOURCES[r.settings['source']]}"
            + (
                f" (σ = {r.settings['noise_nm'][0]:g} / {r.settings['noise_nm'][1]:g} N·m)"
                if r.settings["source"] == "multisine"
                else ""
            )
            + "."
            for r in results
        ],
        "",
        "| quantity | " + " | ".join(r.settings["source"] for r in results) + " |",
        "|---|" + "---|" * len(results),
    ]
    rows = [
        ("trials", lambda s: f"{s['trials']}"),
        ("OLS physically inconsistent", lambda s: f"{s['ols_inconsistent']} / {s['trials']}"),
        ("constrained inconsistent", lambda s: f"{s['constrained_inconsistent']} / {s['trials']}"),
        ("trials where the two fits differ", lambda s: f"{s['fits_differ']}"),
        ("constrained closer to the truth", lambda s: f"{s['constrained_wins']} / {s['trials']}"),
        ("win rate where the fits differ", lambda s: f"{s['win_rate_where_differ']:.2f}"),
        ("median parameter error, OLS", lambda s: f"{s['median_error_ols']:.3g}"),
        ("median parameter error, constrained", lambda s: f"{s['median_error_constrained']:.3g}"),
        ("median error ratio constrained / OLS, all trials", lambda s: f"{s['median_error_ratio']:.3g}"),
        ("median error ratio where the fits differ", lambda s: f"{s['median_error_ratio_where_differ']:.3g}"),
        (
            "median error over excited parameters, OLS / constrained",
            lambda s: f"{s['median_error_ols_excited']:.3g} / {s['median_error_constrained_excited']:.3g}",
        ),
    ]
    for label, cell in rows:
        lines.append(f"| {label} | " + " | ".join(cell(r.summary) for r in results) + " |")
    lines += [
        "",
        "Reading: short trials leave some columns unexcited (e.g. a still joint's friction) and others barely "
        "excited; OLS then trades physically impossible inertias for a slightly smaller training residual. "
        "The constrained fit cannot. Where the fits differ but no constraint is listed as active, the data "
        "leave a direction free (rank-deficient) and the two solvers pick different points of equal residual.",
        "",
    ]
    if rich is not None:
        lines += [
            "## On trials that excite everything",
            "",
            f"{rich['trials']} simulated trials of {rich['duration_s']:g} s on the simulator's `fourier` reference "
            f"(both joints move): OLS is consistent in {rich['ols_consistent']} / {rich['trials']}; the largest "
            f"difference between the constrained fit and OLS is {rich['max_constrained_minus_ols_in_se']:.3g} OLS "
            f"standard errors; the truth lies within ±2 SE for {100 * rich['truth_within_2se']:.0f} % of the "
            "parameters. The constraints cost nothing where the data are good.",
            "",
        ]
    for r in results:
        lines += [f"## Per trial: {r.settings['source']}", "", markdown_table(r.rows.set_index("trial"), digits=3), ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- comparison
PROTOCOLS = {
    "paper": "shuffled 70/30, mean over the paper's seeds (flattering: test samples have near-copies in training)",
    "chronological": "first 70 % of the trial in time trains, the rest tests (honest within one trial)",
    "cross_trial": "identify on the whole first trial, test on the second, unseen trial",
}


@dataclass
class Comparison:
    """Everything `ident-opt compare` reports. `fits` are on the whole identification trial; `metrics` is
    {protocol: {metric: {estimator: [joint 1, joint 2]}}}; `seeds` is the paper's seed study."""

    model: ArmModel
    fits: dict[str, LinearFit]
    datasheets: dict[str, tuple[ArmModel, np.ndarray]]
    metrics: dict[str, dict[str, dict[str, list[float]]]]
    seeds: object
    convention: str
    sources: dict[str, str] = field(default_factory=dict)

    def parameters(self) -> dict[str, dict[str, float]]:
        """π by estimator: "datasheet" (the problem's convention), both datasheets, and every fit."""
        out = {key: model.as_dict(pi) for key, (model, pi) in self.datasheets.items()}
        out = {"datasheet": out[f"datasheet_{self.convention}"], **out}
        out.update({key: fit.as_dict() for key, fit in self.fits.items()})
        return out

    def consistency(self) -> dict[str, dict]:
        """Physical consistency of each parameter set: M(q) margin [kg m²], friction signs, verdict (which
        also requires armature ≥ 0)."""
        out = {}
        for key, (model, pi) in self.datasheets.items():
            values = model.as_dict(pi)
            friction = all(v >= 0 for n, v in values.items() if n.startswith("f"))
            armature = all(v >= 0 for n, v in values.items() if n.startswith("ia"))
            eig = model.min_mass_eigenvalue(pi)
            out[key] = {
                "min_mass_eigenvalue": eig,
                "friction_nonnegative": friction,
                "consistent": bool(eig > 0 and friction and armature),
                "active_constraints": [],
            }
        for key, fit in self.fits.items():
            out[key] = {
                "min_mass_eigenvalue": fit.min_mass_eigenvalue,
                "friction_nonnegative": fit.friction_ok,
                "consistent": fit.consistent,
                "active_constraints": fit.active,
            }
        return out


def _scores(datasets: list[tuple[Dataset, np.ndarray]], model: ArmModel, pi: np.ndarray) -> dict[str, list]:
    """Metrics of a fixed π on (dataset, test index) pairs, averaged over the pairs."""
    per = [all_metrics(d.tau[idx], model.predict(pi, d.q[idx], d.dq[idx], d.ddq[idx])) for d, idx in datasets]
    return {m: [float(np.mean([p[m][j] for p in per])) for j in range(2)] for m in METRICS}


def compare_estimators(
    train: Dataset,
    robot,
    split,
    unseen: Dataset | None = None,
    *,
    model: ArmModel | None = None,
    margin: float = 1e-6,
    weights: str | None = None,
    progress: bool = True,
) -> Comparison:
    """Fit every estimator, score it on the paper's shuffled protocol, the chronological split and (when
    `unseen` is given) the unseen trial; score both datasheets on the same test samples. `weights`:
    None (plain least squares) or "wls" (joints weighted by 1/σ_j², estimated per fit)."""
    from ident_opt.data import chronological_split, shuffled_split
    from ident_opt.identify.seeds import seed_study, split_fits

    model = model or ArmModel()
    fitters = estimators(robot, margin, weights)
    whole = Stats.from_data(model, train.q, train.dq, train.ddq, train.tau)
    fits = {key: fn(whole, model) for key, fn in fitters.items()}
    seeds = seed_study(train, model, split, fitters, progress=progress)
    metrics: dict[str, dict[str, dict[str, list[float]]]] = {p: {m: {} for m in METRICS} for p in PROTOCOLS}
    for m in METRICS:
        metrics["paper"][m].update(seeds.mean(m))
    chrono = chronological_split(train.n, split.train_fraction)
    chrono_res = split_fits(train, model, [chrono], fitters)
    for m in METRICS:
        metrics["chronological"][m].update(chrono_res.mean(m))
    test_sets = {
        "paper": [(train, shuffled_split(train.n, split.train_fraction, s)[1]) for s in split.seeds],
        "chronological": [(train, chrono[1])],
    }
    if unseen is not None:
        for key, fit in fits.items():
            Y = model.regressor(unseen.q, unseen.dq, unseen.ddq)
            for m, v in all_metrics(unseen.tau, Y @ fit.pi).items():
                metrics["cross_trial"][m][key] = v
        test_sets["cross_trial"] = [(unseen, np.arange(unseen.n))]
    else:
        metrics.pop("cross_trial")
    sheets = datasheet_models(robot)
    for protocol, pairs in test_sets.items():
        for key, (sheet_model, pi) in sheets.items():
            for m, v in _scores(pairs, sheet_model, pi).items():
                metrics[protocol][m][key] = v
    sources = {"train": _shown(train.source), **({"unseen": _shown(unseen.source)} if unseen is not None else {})}
    return Comparison(model, fits, sheets, metrics, seeds, robot.convention, sources)


def _shown(path: str) -> str:
    """A data path as people read it: relative to the working folder when inside it."""
    import os
    from pathlib import Path

    resolved = Path(path).resolve()
    try:
        return os.path.relpath(resolved) if resolved.is_relative_to(Path.cwd()) else str(resolved)
    except ValueError:
        return str(resolved)


# ---------------------------------------------------------------------------------------------- rendering
LABELS = {
    "datasheet_paper": "datasheet (paper)",
    "datasheet_physical": "datasheet (physical)",
    "ols": "OLS",
    "constrained": "constrained",
    "nlp_physical": "NLP-physical",
}


def parameter_table(c: Comparison) -> pd.DataFrame:
    """Parameters (rows) × estimators, with standard errors (`<key> se`) for the fits: numbers only."""
    params = c.parameters()
    params.pop("datasheet")
    names = list(dict.fromkeys(n for p in params.values() for n in p))
    cols = {}
    for key, values in params.items():
        cols[key] = [values.get(n, np.nan) for n in names]
        if key in c.fits:
            se = c.fits[key].se_dict()
            cols[f"{key} se"] = [se.get(n, np.nan) for n in names]
    return pd.DataFrame(cols, index=pd.Index(names, name="parameter"))


def consistency_table(c: Comparison) -> pd.DataFrame:
    """Per estimator: min over q of λ_min(M(q)) [kg m²], friction ≥ 0, consistent, active constraints."""
    rows = {
        key: {
            "min eig M(q) [kg m²]": v["min_mass_eigenvalue"],
            "friction ≥ 0": v["friction_nonnegative"],
            "consistent": v["consistent"],
            "active constraints": " ".join(v["active_constraints"]) or "–",
        }
        for key, v in c.consistency().items()
    }
    return pd.DataFrame(rows).T.rename_axis("estimator")


def metrics_table(c: Comparison, metric: str = "nmse") -> pd.DataFrame:
    """Held-out `metric` per estimator (rows) × protocol and joint (columns)."""
    rows: dict[str, dict[str, float]] = {}
    for protocol, per_metric in c.metrics.items():
        for key, values in per_metric[metric].items():
            for j in range(2):
                rows.setdefault(key, {})[f"{protocol} j{j + 1}"] = values[j]
    return pd.DataFrame(rows).T.rename_axis("estimator")


def _with_se(c: Comparison) -> pd.DataFrame:
    """The parameter table with "value ± se" strings, for people."""
    from ident_opt.tables import fmt

    table = parameter_table(c)
    out = {}
    for key in [k for k in table.columns if not k.endswith(" se")]:
        se = table.get(f"{key} se")
        cells = []
        for i, v in enumerate(table[key]):
            if np.isnan(v):
                cells.append("–")
            elif se is None or np.isnan(se.iloc[i]):
                cells.append(fmt(v))
            else:
                cells.append(f"{fmt(v)} ± {fmt(se.iloc[i], 2)}")
        out[LABELS.get(key, key)] = cells
    human = pd.DataFrame(out, index=table.index)
    # The consistency column of the issue, as rows under the parameters: one verdict per estimator.
    consistency = c.consistency()
    extra = {
        "min eig M(q) [kg m²]": {LABELS.get(k, k): fmt(v["min_mass_eigenvalue"]) for k, v in consistency.items()},
        "friction ≥ 0": {
            LABELS.get(k, k): "yes" if v["friction_nonnegative"] else "NO" for k, v in consistency.items()
        },
        "physically consistent": {LABELS.get(k, k): "yes" if v["consistent"] else "NO" for k, v in consistency.items()},
    }
    return pd.concat([human, pd.DataFrame(extra).T.reindex(columns=human.columns)]).rename_axis("parameter")


def findings(c: Comparison) -> list[str]:
    """Plain sentences: consistency of OLS, what the constraints did, their held-out cost or gain."""
    ols, con = c.fits["ols"], c.fits["constrained"]
    lines = []
    if ols.consistent:
        lines.append("OLS is physically consistent on this trial; the constrained fit equals it.")
    else:
        lines.append("OLS is " + "; ".join(w for w in ols.warnings if w.startswith("physically")) + ".")
    if con.active:
        lines.append(
            f"Constrained fit: active constraints {', '.join(con.active)}; "
            f"min eig M(q) = {con.min_mass_eigenvalue:.3g} kg m²."
        )
    for protocol in c.metrics:
        n_ols, n_con = c.metrics[protocol]["nmse"]["ols"], c.metrics[protocol]["nmse"]["constrained"]
        change = [100 * (b - a) / a for a, b in zip(n_ols, n_con)]
        verdict = ", ".join(
            f"joint {j + 1} " + ("costs" if d > 0.05 else "gains" if d < -0.05 else "no change")
            for j, d in enumerate(change)
        )
        lines.append(
            f"{protocol}: held-out nmse OLS {n_ols[0]:.4g} / {n_ols[1]:.4g}, constrained {n_con[0]:.4g} / "
            f"{n_con[1]:.4g} ({change[0]:+.1f} % / {change[1]:+.1f} %; consistency {verdict})."
        )
    costs = [
        c.metrics[p]["nmse"]["constrained"][j] > c.metrics[p]["nmse"]["ols"][j] * 1.0005
        for p in c.metrics
        for j in range(2)
    ]
    if not ols.consistent and any(costs):
        lines.append(
            "Where consistency costs held-out accuracy, OLS was using a physically impossible inertia to "
            "absorb something the rigid model lacks (on a real flexible arm: elasticity, friction shape, "
            "delay); `ident-opt diagnose` looks for it. Only the consistent fit has an M(q) that is "
            "invertible at every pose, as forward simulation and model-based control need."
        )
    for w in ols.warnings:
        if not w.startswith("physically"):
            lines.append("OLS: " + w + ".")
    return lines


def to_markdown(c: Comparison, figure: str | None = None) -> str:
    """The comparison as a Markdown report (parameters ± SE, consistency, held-out metrics, seed study)."""
    from ident_opt.identify.seeds import rmse_table
    from ident_opt.tables import markdown_table

    parts = [
        "# Identification: datasheet vs OLS vs constrained vs NLP-physical",
        "",
        f"Identification trial: `{c.sources.get('train')}`"
        + (f"; unseen trial: `{c.sources['unseen']}`" if "unseen" in c.sources else "")
        + f". Fitted model: {', '.join(c.model.names)} (β in N·m). Standard errors use a per-joint residual "
        "variance and assume independent residuals (optimistic on densely sampled real data).",
        "",
        "## Findings",
        "",
        *[f"- {line}" for line in findings(c)],
        "",
        "## Parameters (± standard error)",
        "",
        markdown_table(_with_se(c)),
        "",
        "## Physical consistency",
        "",
        markdown_table(consistency_table(c)),
        "",
    ]
    for metric in ("nmse", "nmse_range", "rmse"):
        parts += [
            f"## Held-out {metric} per joint",
            "",
            "Protocols: " + "; ".join(f"**{p}** = {PROTOCOLS[p]}" for p in c.metrics) + ".",
            "",
            markdown_table(metrics_table(c, metric)),
            "",
        ]
    physical = c.fits.get("nlp_physical")
    if physical is not None and "physical" in physical.details:
        theta = pd.DataFrame({"value": physical.details["physical"]}).rename_axis("physical parameter")
        theta["at a physical bound"] = ["yes" if k in physical.details.get("at_bound", []) else "" for k in theta.index]
        parts += [
            "## NLP-physical: the physical parameters behind its π",
            "",
            "Masses [kg], centres of mass [m], inertias and armature [kg m²], friction [N m s/rad, N m]. "
            "The grouped π do not determine all of them: a weak pull toward the datasheet picks one of "
            "the equivalent sets, so read the individual values with care; π is what the data fix.",
            "",
            markdown_table(theta),
            "",
        ]
    parts += ["## The paper's seed study (shuffled 70/30)", "", markdown_table(rmse_table(c.seeds)), ""]
    if figure:
        parts += [f"![grouped parameters across seeds]({figure})", ""]
    return "\n".join(parts)


def to_terminal(c: Comparison) -> str:
    """A compact text summary for the terminal."""
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        return "\n\n".join(
            [
                "Parameters (± SE):\n" + _with_se(c).to_string(),
                "Consistency:\n" + consistency_table(c).to_string(),
                "Held-out nmse per joint:\n" + metrics_table(c, "nmse").to_string(float_format=lambda v: f"{v:.4g}"),
                "\n".join(f"- {line}" for line in findings(c)),
            ]
        )


def to_json(c: Comparison) -> dict:
    """The `compare --json` payload (`spec/cli.md`): parameters, standard errors, consistency, metrics."""
    from ident_opt.identify.seeds import deviation_from_mean

    return {
        "parameters": c.parameters(),
        "standard_errors": {key: fit.se_dict() for key, fit in c.fits.items()},
        "consistency": c.consistency(),
        "metrics": c.metrics,
        "protocols": {p: PROTOCOLS[p] for p in c.metrics},
        "fits": {key: fit.summary() for key, fit in c.fits.items()},
        "physical_parameters": c.fits["nlp_physical"].details.get("physical", {}) if "nlp_physical" in c.fits else {},
        "seed_study": {
            "seeds": c.seeds.labels,
            "parameters": {key: v.tolist() for key, v in c.seeds.pi.items()},
            "deviation_from_mean_percent": {
                key: deviation_from_mean(c.seeds, key).to_numpy().tolist() for key in c.seeds.pi
            },
            "rmse_mean": c.seeds.mean("rmse"),
            "rmse_std": c.seeds.std("rmse"),
        },
        "model": list(c.model.names),
        "sources": c.sources,
    }
