"""The online replay: every model fitted offline on the first part of a trial in time, then the rest replayed
sample by sample in time order — each sample first predicted (one step ahead), then folded in (RR, PBR, CPBR
re-solve exactly on all data seen; DM stays fixed; GMRs follow by the mean-only consistency transform) — beside
the same models frozen; and the batch check: the online parameters against from-scratch solves at random steps.
On an arm whose consistent fit is re-solved at a cadence (`online.Cadence`), also the consistency check: at each
re-solve, how far PBR's exact sign-bounded parameters are from that from-scratch consistent fit.
`ident_opt.report.online` writes it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear
from tqdm import tqdm

from ident_opt.adaptation.estimator import CONSISTENT_EVERY, batch_theta
from ident_opt.adaptation.identifier import OnlineIdentifier
from ident_opt.adaptation.start import Start, model_keys, offline_start, start_identifier
from ident_opt.data.dataset import Dataset, chronological_split, fittable
from ident_opt.data.validate import checked_problem, checked_trial
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import Choice, choose
from ident_opt.fitting.stats import Stats
from ident_opt.metrics import METRICS, all_metrics, coverage
from ident_opt.models.hybrid import features, make_gmr
from ident_opt.problem.spec import Problem

#: Adapted models whose parameters are checked against a batch re-solve (DM never moves).
ADAPTED = ("rr", "pbr", "cpbr")


@dataclass
class Replay:
    """Per model key: the offline start and the online identifier after the replay; per key and `key+gmr`: the
    online (`pred`, `std`) and frozen (`frozen`, `frozen_std`) predictions on the replayed part (N, n) [N m];
    per key: θ after each sample (N, P) and the seconds spent (`seconds`: whole steps; `solve_seconds`: the
    parameter updates alone); the batch check (`batch_check`); the consistency check (`consistency`, None unless a
    model is re-solved at a cadence)."""

    keys: tuple[str, ...]
    train: Dataset
    test: Dataset
    starts: dict[str, Start]
    online: dict[str, OnlineIdentifier]
    pred: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    frozen: dict[str, np.ndarray]
    frozen_std: dict[str, np.ndarray]
    theta: dict[str, np.ndarray]
    seconds: dict[str, float]
    solve_seconds: dict[str, float]
    batch_check: dict
    consistency: dict | None = None
    choice: Choice | None = None  # the fit cpbr starts from and follows

    @property
    def n(self) -> int:
        """Samples replayed."""
        return self.test.n

    def metrics(self, which: str) -> dict[str, dict[str, list[float]]]:
        """metric -> model key (with and without +gmr) -> [joint 1, …, joint n], for "online" or "frozen"."""
        preds = self.pred if which == "online" else self.frozen
        out: dict[str, dict[str, list[float]]] = {m: {} for m in METRICS}
        for key in (k for base in self.keys for k in (base, base + "+gmr")):
            for metric, value in all_metrics(self.test.tau, preds[key]).items():
                out[metric][key] = value
        return out

    def coverage(self, which: str) -> dict[str, list[float]]:
        """`key+gmr` -> the share of replayed torques inside the 95 % interval, per joint."""
        preds, stds = (self.pred, self.std) if which == "online" else (self.frozen, self.frozen_std)
        return {
            k: [float(v) for v in coverage(self.test.tau, preds[k], stds[k])] for k in (b + "+gmr" for b in self.keys)
        }


#: The fewest samples of the offline part (the first part of the trial in time).
MIN_OFFLINE = 20


def online_parts(problem: Problem, trial: Dataset) -> tuple[Dataset, Dataset]:
    """(offline part, online part): the problem's chronological split of `trial` (`[split] train_fraction`)."""
    train_idx, test_idx = chronological_split(trial.n, problem.split.train_fraction)
    train, test = trial.subset(train_idx), trial.subset(test_idx)
    if train.n < MIN_OFFLINE or test.n < 1:
        raise InputError(f"{trial.source}: too few samples for an offline part and an online part ({trial.n})")
    return train, test


def online(
    problem: Problem,
    trial: Dataset,
    *,
    estimator: str | None = None,
    cross_covariance: bool = False,
    checks: int = 10,
    components: int | None = None,
    every: int = CONSISTENT_EVERY,
    progress: bool = True,
) -> Replay:
    """`online`'s stage function (what `ident-opt online` runs): `trial` split in time (`online_parts`), the fit
    cpbr starts from and follows chosen on the offline part (the recommended fit, or `estimator`), then `replay`
    with the problem's first seed for the batch checks. A trial not of the arm's joints, or not finite, is an
    InputError naming it."""
    checked_problem(problem, "online").require("online")
    trial = checked_trial(problem.robot, trial, "online: trial")
    fittable(trial)
    train, test = online_parts(problem, trial)
    choice = choose(problem, [train], model=problem.robot.model(()), estimator=estimator, command="online")
    return replay(
        problem,
        train,
        test,
        cross_covariance=cross_covariance,
        checks=checks,
        components=components,
        seed=int(problem.split.seeds[0]),
        progress=progress,
        every=every,
        choice=choice,
    )


def replay(
    problem: Problem,
    train: Dataset,
    test: Dataset,
    *,
    keys=None,
    cross_covariance: bool = False,
    checks: int = 10,
    components: int | None = None,
    seed: int = 0,
    progress: bool = True,
    every: int = CONSISTENT_EVERY,
    choice: Choice | None = None,
) -> Replay:
    """Offline fits on `train`, then the sample-by-sample replay of `test` (module doc); `checks` random steps
    (and the last) are checked against a batch re-solve. `components`: the GMRs' K (else the problem's); `every`:
    samples between a cadence estimator's re-solves; `choice`: the fit cpbr is (`fitting.recommend.Choice`)."""
    keys = tuple(keys or model_keys(problem.robot))
    starts, online = {}, {}
    for key in tqdm(keys, desc="offline fits (+GMR)", disable=not progress):
        starts[key] = offline_start(key, problem, train, every=every, choice=choice)
        # Blocked validation for the number of components: the model will predict later motions.
        gmr = make_gmr(problem.residual, components=components, validation="blocked")
        online[key] = start_identifier(starts[key], train, gmr, cross_covariance=cross_covariance)
    frozen, frozen_std = _frozen(starts, online, test)
    pred, std, theta, seconds, solve_seconds = _replay(keys, starts, online, test, progress)
    check = batch_check(starts, theta, train, test, checks, seed)
    return Replay(
        keys,
        train,
        test,
        starts,
        online,
        pred,
        std,
        frozen,
        frozen_std,
        theta,
        seconds,
        solve_seconds,
        check,
        consistency_check(starts, online, theta, train, test),
        choice,
    )


def _frozen(starts: dict[str, Start], online: dict[str, OnlineIdentifier], test: Dataset) -> tuple[dict, dict]:
    """The offline models' predictions on the whole replayed part (never updated), with the GMRs' std."""
    frozen, frozen_std = {}, {}
    for key, ident in online.items():
        base = starts[key].design(test.q, test.dq, test.ddq) @ starts[key].theta0
        mean, cov = ident.gmr0.predict(features(test))
        frozen[key], frozen[key + "+gmr"] = base, base + mean
        frozen_std[key + "+gmr"] = np.sqrt(np.einsum("nii->ni", cov))
    return frozen, frozen_std


def _replay(keys, starts, online, test: Dataset, progress: bool):
    """Each sample of `test` in time order: predict it with every model, then fold it in (timed)."""
    n, J = test.n, test.q.shape[1]
    pred = {k: np.empty((n, J)) for base in keys for k in (base, base + "+gmr")}
    std = {k + "+gmr": np.empty((n, J)) for k in keys}
    theta = {k: np.empty((n, len(starts[k].theta0))) for k in keys}
    seconds = dict.fromkeys(keys, 0.0)  # whole step: design row, prediction, update
    solve_seconds = dict.fromkeys(keys, 0.0)  # the parameter update alone (statistics + re-solve + transform)
    clock = time.perf_counter
    for i in tqdm(range(n), desc="online replay", unit="sample", disable=not progress, mininterval=0.5):
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
    return pred, std, theta, seconds, solve_seconds


def batch_check(starts: dict[str, Start], theta: dict, train: Dataset, test: Dataset, checks: int, seed: int) -> dict:
    """Largest relative difference |θ_online − θ_batch| / |θ_batch| (per parameter; 0/0 counts as 0) at
    `checks` random steps and the last, against a from-scratch solve on the same prefix (cold-started
    solver on freshly accumulated statistics); for PBR also against the paper's re-solve,
    `scipy.optimize.lsq_linear` (BVLS) on all stacked rows. A model re-solved at a cadence (`online.Cadence`) is
    checked at its re-solves (its θ is held in between), apart: `cadence_by_model` (the conic solver's tolerance,
    not the update's exactness, sets that difference; also as the RMS difference of the two fits' torques over the
    prefix ÷ their RMS)."""
    n = test.n
    rng = np.random.default_rng(seed)
    steps = sorted(set(rng.choice(n, min(checks, n), replace=False).tolist()) | {n - 1})
    by_model: dict[str, float] = {}
    cadence: dict[str, dict] = {}
    paper: float | None = None
    for key in (k for k in ADAPTED if k in starts):
        start, worst = starts[key], 0.0
        D_train = start.design(train.q, train.dq, train.ddq)
        D_test = start.design(test.q, test.dq, test.ddq)
        every = getattr(start.estimator.solver, "every", None) if start.estimator.kind == "cadence" else None
        at = _refreshes(n, every)[-checks:] if every else steps
        torque = 0.0
        for i in at:
            D = np.concatenate([D_train, D_test[: i + 1]])
            tau = np.concatenate([train.tau, test.tau[: i + 1]])
            ref = batch_theta(start.estimator, Stats.from_regressor(D, tau), rows=(D, tau))
            worst = max(worst, _relative(theta[key][i], ref))
            torque = max(torque, _torque_gap(D, theta[key][i], ref))
            if key == "pbr":
                b = start.estimator.bounds
                bv = lsq_linear(
                    D.reshape(-1, D.shape[2]), tau.reshape(-1), bounds=(b.lower, b.upper), method="bvls", tol=1e-15
                ).x
                paper = max(paper or 0.0, _relative(theta[key][i], bv))
        if every:
            cadence[key] = {
                "max_relative_difference": worst,
                "max_torque_rms_difference": torque,
                "steps": [int(train.n + i + 1) for i in at],
            }
        else:
            by_model[key] = worst
    return {
        "max_relative_difference": max(by_model.values()) if by_model else 0.0,
        "steps": [int(train.n + i + 1) for i in steps],  # samples seen at each checked step
        "by_model": by_model,
        "reference": "cold-started solver on from-scratch statistics of the same prefix",
        "pbr_vs_lsq_linear": paper,
        "cadence_by_model": cadence,
    }


def _refreshes(n: int, every: int) -> list[int]:
    """The replayed samples (0-based) after which a cadence estimator re-solved (every `every` updates)."""
    return [i for i in range(n) if (i + 1) % every == 0]


def consistency_check(
    starts: dict[str, Start], online: dict[str, OnlineIdentifier], theta: dict, train: Dataset, test: Dataset
) -> dict | None:
    """How far PBR's exact, sign-bounded online parameters are from the from-scratch consistent fit (CPBR re-solved
    at a cadence) at each of its re-solves: per joint, the RMS difference of their torques over every sample seen
    [N m] and that ÷ the consistent fit's own residual RMS, and the same for CPBR as held until then (the previous
    re-solve's parameters: how stale the cadence lets it get); the parameters' difference in PBR's standard errors
    (`_standard_errors`: median, largest); the sign bounds' least slack over every replayed sample (≥ 0: they held
    exactly); the LMIs' least eigenvalue at the re-solves [kg m²] (`Arm.min_mass_eigenvalue`). None unless CPBR is
    re-solved at a cadence and PBR is on the same base parameters."""
    pbr, cpbr = starts.get("pbr"), starts.get("cpbr")
    if pbr is None or cpbr is None or cpbr.estimator.kind != "cadence" or pbr.names != cpbr.names:
        return None
    cadence = online["cpbr"].estimator.solver
    D_train, D_test = pbr.design(train.q, train.dq, train.ddq), pbr.design(test.q, test.dq, test.ddq)
    rows = []
    for i in _refreshes(test.n, cadence.every):
        D = np.concatenate([D_train, D_test[: i + 1]])
        tau = np.concatenate([train.tau, test.tau[: i + 1]])
        gap = theta["pbr"][i] - theta["cpbr"][i]
        delta = np.sqrt(np.mean((D @ gap) ** 2, axis=0))
        residual = np.sqrt(np.mean((tau - D @ theta["cpbr"][i]) ** 2, axis=0))
        in_se = np.abs(gap) / _standard_errors(D, tau, theta["pbr"][i])
        # CPBR as held until this re-solve (the previous one's parameters) against the re-solve: its staleness.
        held = np.sqrt(np.mean((D @ (theta["cpbr"][i - 1] - theta["cpbr"][i])) ** 2, axis=0)) if i > 0 else delta * 0
        rows.append(
            {
                "samples_seen": int(train.n + i + 1),
                "torque_rms_difference": delta.tolist(),
                "relative_to_residual": (delta / np.maximum(residual, 1e-300)).tolist(),
                "parameter_difference_in_se": {"median": float(np.median(in_se)), "max": float(in_se.max())},
                "held_torque_rms_difference": held.tolist(),
                "held_relative_to_residual": (held / np.maximum(residual, 1e-300)).tolist(),
            }
        )
    lower = pbr.estimator.bounds.lower
    bounded = np.isfinite(lower)
    slack = float((theta["pbr"][:, bounded] - lower[bounded]).min()) if bounded.any() else None
    return {
        "every": cadence.every,
        "estimator": cadence.name,
        "re_solves": cadence.refreshed,
        "re_solve_seconds": cadence.seconds,
        "failed_re_solves": online["cpbr"].refresh_failures,
        "at_re_solves": rows,
        "sign_bounds": [pbr.names[i] for i in np.flatnonzero(bounded)],
        "sign_bound_least_slack": slack,
        "least_lmi_eigenvalue": min(cadence.least_eigenvalues) if cadence.least_eigenvalues else None,
    }


def _torque_gap(D: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """RMS of D (a − b) ÷ RMS of D b over the rows D (N, n, P): how differently two parameter vectors predict."""
    return float(np.sqrt(np.mean((D @ (a - b)) ** 2) / max(np.mean((D @ b) ** 2), 1e-300)))


def _standard_errors(D: np.ndarray, tau: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Least squares' standard errors of θ on the design D (N, n, P) with torques τ (N, n): √(σ² (ΣDᵀD)⁻¹_pp), σ²
    the residual variance pooled over the joints (a scale for parameter differences, not a fit's own SEs)."""
    A = D.reshape(-1, D.shape[2])
    r = tau.reshape(-1) - A @ theta
    sigma2 = float(r @ r) / max(A.shape[0] - A.shape[1], 1)
    return np.sqrt(sigma2 * np.diag(np.linalg.inv(A.T @ A)))


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    diff = np.abs(a - b)
    scale = np.abs(b)
    # A parameter at exactly 0 (an active bound) in both counts as equal; else relative to its own size.
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(diff == 0, 0.0, diff / np.maximum(scale, 1e-300))
    return float(rel.max())
