"""The four questions in order: what the nominal models get wrong, which cause, the extended model, the gain.

Split: with a second (unseen) trial, the first trial trains and the second is held out; with one trial,
the first `train_fraction` of it in time trains and the rest is held out (contiguous, so delays and modes
survive the split). Both nominal models are examined: the datasheet (no fitting) and the best rigid fit of
the nominal structure (`candidates.NOMINAL`, weighted least squares with joint weights 1/σ_j² from a first
unweighted pass).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal
from tqdm import tqdm

from ident_opt.data import Dataset, chronological_split
from ident_opt.datasheet import datasheet_pi, rigid_body
from ident_opt.diagnose import candidates as cands
from ident_opt.diagnose import evidence, linear, scoring, signals
from ident_opt.errors import InputError
from ident_opt.metrics import nmse
from ident_opt.problem import Robot

#: A joint moving slower than this fraction of its speed scale (95th percentile of |dq|) is at rest.
REST_FRACTION = 0.01
#: How long [s] a joint must stay slow, before or after a sample, for it to count as at rest.
REST_WINDOW_S = 0.01
#: Fewest held-out / training samples that make a diagnosis meaningful.
MIN_SAMPLES = 200


@dataclass
class Diagnosis:
    """The result: the named cause and its fit, every candidate's score, and the evidence."""

    cause: str
    estimate: dict
    baseline: str
    nmse_before: list[float]
    nmse_after: list[float]
    candidates: list[dict]
    evidence: dict
    split: str
    rate_hz: float
    named: cands.Candidate | None
    nominal: dict[str, dict]  # "datasheet" / "rigid_fit" -> {"pi": {...}, "nmse": [...]}
    test: Dataset
    predictions: dict[str, np.ndarray]  # held-out torque predictions: "before", "after"
    nmse_raw: list[list[float]] = field(default_factory=list)  # before, after: without the rest projection
    timings: dict[str, float] = field(default_factory=dict)

    def as_json(self) -> dict:
        """The `--json` payload (`docs/cli.md`), plus extra keys (NaN, e.g. no reversal, as null)."""
        return _finite(self._payload())

    def _payload(self) -> dict:
        extended = None
        if self.named is not None:
            extended = {
                "parameters": self.named.parameters,
                "standard_errors": self.named.se,
                "detail": self.named.detail,
                "added_parameters": self.named.n_added,
            }
        return {
            "cause": self.cause,
            "estimate": self.estimate,
            "baseline": self.baseline,
            "nmse_before": self.nmse_before,
            "nmse_after": self.nmse_after,
            "candidates": self.candidates,
            "score": "held-out log-likelihood gain over the candidate's baseline minus (k/2) ln n; a cause "
            f"is named when its score > 0 and, on some joint, it removes >= {scoring.MARGIN:.0%} of the "
            f"baseline's held-out MSE and >= {scoring.MARGIN_VARIANCE:.2%} of the torque variance "
            + scoring.rules_note(),
            "nmse_definition": "MSE ÷ variance of the measured torque, per joint, on the held-out part; "
            "within "
            "each stretch where a joint rests, its residual's mean is removed first (stiction "
            "holds a level no model predicts); nmse_raw_before/after: without that",
            "nmse_raw_before": self.nmse_raw[0] if self.nmse_raw else None,
            "nmse_raw_after": self.nmse_raw[1] if self.nmse_raw else None,
            "split": self.split,
            "rate_hz": self.rate_hz,
            "nominal": self.nominal,
            "extended_model": extended,
            "evidence": self.evidence,
            "timings_s": self.timings,
        }


def _finite(value):
    """A JSON-safe copy: NumPy scalars as Python numbers, NaN and ±inf as None (strict JSON has neither)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def split(train: Dataset, test: Dataset | None, train_fraction: float) -> tuple[Dataset, Dataset, str]:
    """(training part, held-out part, description); see the module docstring."""
    if test is not None:
        return train, test, f"train on {train.source}, held out: {test.source}"
    tr, te = chronological_split(train.n, train_fraction)
    return (
        train.subset(tr),
        train.subset(te),
        f"chronological: first {train_fraction:.0%} of {train.source} trains, the rest is held out",
    )


def at_rest(trial: Dataset) -> Dataset:
    """The trial with the velocity of a joint at rest read as exactly 0.

    Coulomb friction at rest is set-valued (stiction holds whatever the controller pushes, up to the
    breakaway level), and the sign of an estimated velocity at rest is noise: a rigid model's fc·sgn(dq)
    there is a random ±fc that no cause explains. A joint is at rest at a sample when |dq| is below
    REST_FRACTION of its speed scale (95th percentile of |dq|) there and stays below it for REST_WINDOW_S
    before or after (so the filter ringing just before a start or after a stop counts as rest, but a smooth
    velocity reversal, slow only for an instant, does not). Every model (nominal and candidates) sees the
    same velocities, so scores compare like with like; the rest samples stay in (ringing and gravity live
    there too).
    """
    v_ref = np.quantile(np.abs(trial.dq), 0.95, axis=0)
    dt = float(np.median(np.diff(trial.t)))
    w = max(1, round(REST_WINDOW_S / dt))
    slow = np.abs(trial.dq) < REST_FRACTION * v_ref
    padded = np.pad(slow, ((w, w), (0, 0)), mode="edge").astype(float)
    windows = np.lib.stride_tricks.sliding_window_view(padded, w + 1, axis=0)  # (N + w, 2, w + 1)
    quiet = windows.min(axis=-1) > 0  # slow throughout the w + 1 samples starting at each index
    before, after = quiet[: trial.n], quiet[w : w + trial.n]
    dq = np.where(slow & (before | after), 0.0, trial.dq)
    return replace(trial, dq=dq)


def rigid_fit(ds: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """(π̂ of the nominal structure, joint weights 1/σ_j²): OLS, then WLS with the OLS residual variances,
    on the same objective as every candidate (rest stretches compared about their mean)."""
    rest = signals.rest_runs(ds.dq)
    Y = signals.demean_runs(cands.NOMINAL.regressor(ds.q, ds.dq, ds.ddq), rest)
    tau = signals.demean_runs(ds.tau, rest)
    zero = np.zeros((ds.n, 2))
    first = linear.solve(zero, Y, tau, np.ones(2))
    var = np.maximum(first.rss / ds.n, 1e-12 * np.maximum(np.var(ds.tau, axis=0), 1e-30))
    weights = 1.0 / var
    return linear.solve(zero, Y, tau, weights).beta, weights


def prepare(trial: Dataset, torque_filter_hz: float | None) -> Dataset:
    """`at_rest`, then the torque low-passed by the zero-phase filter the derivatives are estimated with
    (4th-order Butterworth at `torque_filter_hz`, forward-backward; None: no filter).

    Estimated accelerations are a smoothed version of the true ones (a step in acceleration becomes a ramp
    over tens of ms); the measured torque steps. Filtering τ the same way puts both sides of τ = Y π in the
    same bandwidth, so the smoothing mismatch at every start and stop does not pose as a delay or a mode,
    and noise above the cut-off goes too. Modes and delays inside the band are untouched (the filter is
    zero-phase and linear).
    """
    trial = at_rest(trial)
    if torque_filter_hz is None:
        return trial
    dt = float(np.median(np.diff(trial.t)))
    if torque_filter_hz >= 0.45 / dt or trial.n <= 30:
        return trial
    b, a = signal.butter(4, torque_filter_hz * 2 * dt)
    return replace(trial, tau=signal.filtfilt(b, a, trial.tau, axis=0))


def diagnose(
    robot: Robot,
    trial: Dataset,
    unseen: Dataset | None = None,
    train_fraction: float = 0.7,
    progress: bool = True,
    torque_filter_hz: float | None = 15.0,
) -> Diagnosis:
    """Diagnose `trial` (and `unseen`, if given, as the held-out data); see the module docstring.
    `torque_filter_hz`: see `prepare` (the problem's derivative cut-off is the natural choice)."""
    t0 = time.perf_counter()
    trial = prepare(trial, torque_filter_hz)
    unseen = prepare(unseen, torque_filter_hz) if unseen is not None else None
    train, test, how = split(trial, unseen, train_fraction)
    if train.n < MIN_SAMPLES or test.n < MIN_SAMPLES:
        raise InputError(
            f"{trial.source}: too little data to diagnose ({train.n} training and {test.n} held-out "
            f"samples; at least {MIN_SAMPLES} each)"
        )
    for ds in (train, test):
        if np.any(np.var(ds.tau, axis=0) <= 0):
            raise InputError(f"{ds.source}: a torque channel is constant; nothing to diagnose")
    dt = float(np.median(np.diff(trial.t)))
    ds_pi = datasheet_pi(robot, "physical")
    pi_rigid, weights = rigid_fit(train)
    rest_test = signals.rest_runs(test.dq)
    ctx = cands.Context(
        robot,
        train,
        test,
        weights,
        ds_pi,
        dt,
        signals.rest_runs(train.dq),
        rigid_body(robot, "physical").armature,
    )

    nominal_pred = {
        "datasheet": cands.NOMINAL.predict(cands.NOMINAL.vector(ds_pi), test.q, test.dq, test.ddq),
        "rigid_fit": cands.NOMINAL.predict(pi_rigid, test.q, test.dq, test.ddq),
    }
    nominal_mse = {b: scoring.mse(test.tau, p, rest_test) for b, p in nominal_pred.items()}
    nominal = {
        "datasheet": {
            "pi": cands.NOMINAL.as_dict(cands.NOMINAL.vector(ds_pi)),
            "nmse": scoring.nmse(test.tau, nominal_pred["datasheet"], rest_test),
            "nmse_raw": nmse(test.tau, nominal_pred["datasheet"]).tolist(),
        },
        "rigid_fit": {
            "pi": cands.NOMINAL.as_dict(pi_rigid),
            "nmse": scoring.nmse(test.tau, nominal_pred["rigid_fit"], rest_test),
            "nmse_raw": nmse(test.tau, nominal_pred["rigid_fit"]).tolist(),
        },
    }
    t_nominal = time.perf_counter()

    jobs = [(f, b) for f in cands.families(robot) for b in f.baselines]
    fitted: list[tuple[cands.Candidate, float, np.ndarray, np.ndarray]] = []
    for family, baseline in tqdm(
        jobs, desc="diagnose: fitting candidates", unit="fit", disable=not progress, leave=False
    ):
        cand = cands.fit(family, baseline, ctx)
        pred = cand.predict(test)
        after = scoring.mse(test.tau, pred, rest_test)
        fitted.append((cand, scoring.score(nominal_mse[baseline], after, test.n, cand.n_added), after, pred))
    t_fit = time.perf_counter()

    # One version per cause: the datasheet-based or the refitted extension, whichever is better on a common
    # footing (its gain over the datasheet, every fitted parameter penalised: the refit's π counts too).
    def common(item) -> float:
        refit = len(cands.NOMINAL.names) if item[0].baseline == "rigid_fit" else 0
        return scoring.score(nominal_mse["datasheet"], item[2], test.n, item[0].n_added + refit)

    best: dict[str, tuple] = {}
    for item in fitted:
        if item[0].cause not in best or common(item) > common(best[item[0].cause]):
            best[item[0].cause] = item
    ranked = sorted(best.values(), key=lambda it: it[1], reverse=True)
    candidates = [
        {
            "cause": c.cause,
            "score": s,
            "score_vs_datasheet": common((c, s, after, pred)),
            "nmse_after": scoring.nmse(test.tau, pred, rest_test),
            "baseline": c.baseline,
            "estimate": c.estimate,
            "added_parameters": c.n_added,
            "resolved": scoring.resolved(c.cause, c.estimate, dt),
            "clears_margin": scoring.resolved(c.cause, c.estimate, dt)
            and scoring.clears_margin(nominal_mse[c.baseline], after, s, np.var(test.tau, axis=0)),
            # The IPOPT polish (elasticity, joint offsets): estimates before/after it, whether it was kept.
            **({"polish": c.detail["polish"]} if "polish" in c.detail else {}),
        }
        for c, s, after, pred in ranked
    ]
    nameable = [it for it in ranked if scoring.resolved(it[0].cause, it[0].estimate, dt)]
    top = nameable[0] if nameable else None
    if top is not None and scoring.clears_margin(
        nominal_mse[top[0].baseline], top[2], top[1], np.var(test.tau, axis=0)
    ):
        named, after_pred = top[0], top[3]
        cause, estimate, baseline = named.cause, named.estimate, named.baseline
    else:
        baseline = min(nominal_mse, key=lambda b: float(np.sum(nominal_mse[b] / np.var(test.tau, axis=0))))
        named, cause, estimate, after_pred = None, "none", {}, nominal_pred[baseline]
    before_pred = nominal_pred[baseline]

    ev = {b: evidence.residual_evidence(test, p, dt) for b, p in nominal_pred.items()}
    ev["forward_error_rad"] = {
        "datasheet": evidence.forward_error(cands.NOMINAL, cands.NOMINAL.vector(ds_pi), test, dt),
        "rigid_fit": evidence.forward_error(cands.NOMINAL, pi_rigid, test, dt),
    }
    ev["after"] = evidence.residual_evidence(test, after_pred, dt)
    ev["other_channels"] = evidence.channel_peaks(test if unseen is None else trial, dt)
    t_end = time.perf_counter()
    return Diagnosis(
        cause=cause,
        estimate=estimate,
        baseline=baseline,
        nmse_before=scoring.nmse(test.tau, before_pred, rest_test),
        nmse_after=scoring.nmse(test.tau, after_pred, rest_test),
        nmse_raw=[nmse(test.tau, before_pred).tolist(), nmse(test.tau, after_pred).tolist()],
        candidates=candidates,
        evidence=ev,
        split=how,
        rate_hz=1.0 / dt,
        named=named,
        nominal=nominal,
        test=test,
        predictions={"before": before_pred, "after": after_pred},
        timings={
            "nominal": t_nominal - t0,
            "candidates": t_fit - t_nominal,
            "evidence": t_end - t_fit,
            "total": t_end - t0,
        },
    )
