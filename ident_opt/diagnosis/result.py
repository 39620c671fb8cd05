"""The diagnosis's result (`Diagnosis`, its JSON), each fitted model's held-out score (`Fitted`, `versions`), each
candidate's row (`row_of`), and the conclusion drawn from the rounds (`conclude`): the named chain, its gain and the
evidence.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import evidence, scoring
from ident_opt.diagnosis.engine import Parts
from ident_opt.diagnosis.nominal import NominalFit
from ident_opt.diagnosis.split import compared_warnings
from ident_opt.metrics import nmse


@dataclass
class Fitted:
    """One fitted model: the causes it has (in the order named), its fit kind (`baseline`), the candidate
    (None for a nominal model), its held-out MSE [N² m²] and prediction, and its penalised held-out gain over
    the datasheet with every fitted parameter counted (`common`, the one footing all models are ranked on)."""

    causes: tuple
    baseline: str
    cand: Any  # the engine's candidate (None for a nominal model)
    mse: np.ndarray
    pred: np.ndarray
    common: float
    family: Any  # the engine's family (None for a nominal model)
    theta: dict


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
    named: Any  # the extended model's candidate, with its joint standard errors (None: no cause)
    nominal: dict[str, dict]  # "datasheet" / "rigid_fit" -> {"pi": {...}, "nmse": [...]}
    test: Dataset
    predictions: dict[str, np.ndarray]  # held-out torque predictions: "before", "after"
    nmse_raw: list[list[float]] = field(default_factory=list)  # before, after: filtered τ, no rest projection
    nmse_filtered: list[list[float]] = field(default_factory=list)  # before, after: as scored
    causes: list[dict] = field(default_factory=list)  # the chain, in the order named (`docs/effects.md`)
    dropped: list[dict] = field(default_factory=list)  # causes a later one made redundant
    rounds: list[list[dict]] = field(default_factory=list)  # every round's candidates, best first (`ROUND_KEYS`)
    timings: dict[str, float] = field(default_factory=dict)
    joints: list[str] = field(default_factory=list)  # the joints' names, in the order of every per-joint list
    #: what is doubtful about the result (`ident_opt.warnings.ResultWarning`: the trials', the rigid fit's evidence)
    warnings: list = field(default_factory=list)
    margin_variance: float = scoring.MARGIN_VARIANCE  # the least share of the torque variance a cause removes
    partner: float = scoring.PARTNER  # the least share of the refit's gain a cause taken on trial explains
    #: The verdict beside the causes (`verdict`): "causes", "none", "mismatch" or "not_identifiable".
    verdict: str = "none"
    #: What the data can tell (`identifiability.Identifiability.as_json`), the spec's `identifiability`.
    identifiability: dict = field(default_factory=dict)
    #: Where the model or the description is wrong, and where the data cannot tell (`verdict.conclude`).
    mismatch: list[dict] = field(default_factory=list)
    not_identifiable: list[dict] = field(default_factory=list)
    #: Candidates the plausibility rule rejected where they would have been picked (`rounds._pick`), with why.
    rejected: list[dict] = field(default_factory=list)
    #: The rule's facts and thresholds (`plausibility.Facts.describe`), and the confirmation's findings (`confirm`).
    plausibility: dict = field(default_factory=dict)
    confirmation: dict = field(default_factory=dict)
    #: The identified arm that stood in for the datasheet (`nominal.NominalFit`), None: the problem's datasheet.
    nominal_fit: NominalFit | None = None

    def detail_of(self, cause: str) -> dict:
        """What the extended model's joint fit says of `cause` beyond its estimate (e.g. an elastic joint's
        stiffness, link inertia and damping ratio): its entry in the joint fit's `member_details` when several
        causes are named, the fit's own detail when `cause` is the only one; {} when it is not named."""
        if self.named is None:
            return {}
        details = self.named.detail.get("member_details")
        if details is not None:
            return details.get(cause, {})
        return self.named.detail if self.named.cause == cause else {}

    def as_json(self) -> dict:
        """The `--json` payload (`docs/cli.md`), plus extra keys (NaN, e.g. no reversal, as null)."""
        payload = _finite(self._payload())
        if self.nominal_fit is None:
            return payload
        payload = _as_nominal(payload)
        payload["nominal"].update(self.nominal_fit.as_json())
        return payload

    def compared(self) -> str:
        """What was compared with what, in a sentence: where the causes were fitted and scored (`split`), against
        which nominal model, and — when a separate trial was held out without an identified nominal — that a change
        only the held-out trial shows cannot be named this way, and the command that asks for it."""
        against = (
            f"the identified arm in {self.nominal_fit.path} ({self.nominal_fit.estimator} fit) as the nominal model"
            if self.nominal_fit is not None
            else "the problem's datasheet and the rigid fit of the training part as the nominal models"
        )
        out = f"{self.split}; causes are fitted on the training part and scored on the held-out one, against {against}"
        if self.nominal_fit is None and self.split.startswith("train on "):
            out += (
                ". A change only the held-out trial shows (a payload added since) is absent where the causes are "
                "fitted, so it cannot be named this way: to ask what changed in it, identify the first trial "
                "(`ident-opt compare --json FIT`) and diagnose the second with --nominal FIT"
            )
        return out

    @property
    def baseline_name(self) -> str:
        """What the first nominal model is called: "datasheet", or "nominal" when an identified arm stands in."""
        return "datasheet" if self.nominal_fit is None else "nominal"

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
            "joints": self.joints,
            "baseline": self.baseline,
            "nmse_before": self.nmse_before,
            "nmse_after": self.nmse_after,
            "causes": self.causes,
            "candidates": self.candidates,
            "score": "held-out log-likelihood gain over the round's reference model (the best model so far: "
            "in the first round the better nominal model), (n/2) Σ_j ln(MSE_ref,j / MSE_cand,j) − (Δk/2) ln n "
            "with Δk the difference in fitted parameters (a refitted π counts 10); every candidate of a round "
            f"against the same reference. A cause is named when its score > 0 and, on some joint, it removes "
            f">= {scoring.MARGIN:.0%} of the held-out MSE of the same kind of fit without it and "
            f">= {100 * self.margin_variance:g}% of the torque variance, and against the fit of any cause whose "
            "columns it contains (an elastic joint's motor inertia is an armature) too " + scoring.rules_note(),
            "nmse_definition": "MSE ÷ variance of the measured torque (unfiltered, as compare and identify use "
            "it), per joint, on the held-out part; nmse_filtered_*: the scored variant (torque low-passed like "
            "the derivatives, each rest stretch's residual mean removed); nmse_raw_*: filtered, no rest removal",
            "nmse_filtered_before": self.nmse_filtered[0] if self.nmse_filtered else None,
            "nmse_filtered_after": self.nmse_filtered[1] if self.nmse_filtered else None,
            "nmse_raw_before": self.nmse_raw[0] if self.nmse_raw else None,
            "nmse_raw_after": self.nmse_raw[1] if self.nmse_raw else None,
            "dropped": self.dropped,
            "rounds": self.rounds,
            "split": self.split,
            "compared": self.compared(),
            "rate_hz": self.rate_hz,
            "nominal": self.nominal,
            "extended_model": extended,
            "evidence": self.evidence,
            "timings_s": self.timings,
            "warnings": [w.as_dict() for w in self.warnings],
            "verdict": self.verdict,
            "identifiability": self.identifiability,
            "mismatch": self.mismatch,
            "not_identifiable": self.not_identifiable,
            "rejected": self.rejected,
            "plausibility": self.plausibility,
            "confirmation": self.confirmation,
        }


def _row(
    v: Fitted,
    score: float,
    current: dict,
    raw_tau: np.ndarray,
    test: Dataset,
    rest,
    var,
    dt: float,
    gap,
    floor: float,
    partner: float = scoring.PARTNER,
) -> dict:
    """A candidate's JSON row: its score against the round's reference, held-out nMSE, estimate, and whether
    it may be named: resolved, clearing the margin against the same kind of fit without it
    (`current[baseline]`), and, when it holds the datasheet's π while a refitted π does better, explaining
    at least `scoring.RECOVER` of the refit's log-gain (`recovers`). `gap`: (datasheet, rigid_fit) versions
    the share is measured between (default: the current model's), for a cause that completes a partner's.
    `needs_partner`: clears the margin but explains less than `RECOVER` alone, and at least `partner` (the
    engine's floor, `_rounds`)."""
    c = v.cand
    without = current.get(v.baseline) or max(current.values(), key=lambda w: w.common)
    # a per-joint cause the n-joint screen found on no joint (`chain.families`) adds nothing: a round's chain refitted
    # against another baseline can still score, and without this the cause would take that score as its own
    # (`unresolved`: the candidate failed its family's own check on the fitted model, `chain.families.ArmFamily.check`)
    ok = scoring.resolved(c.cause, c.estimate, dt) and not c.detail.get("empty") and not c.detail.get("unresolved")
    share = None
    if gap is not None and v.baseline == "datasheet":
        share = scoring.recovered(gap[0].mse, v.mse, gap[1].mse)
    elif _refit_better(v, current):
        share = scoring.recovered(without.mse, v.mse, current["rigid_fit"].mse)
    margin = ok and scoring.clears_margin(without.mse, v.mse, score, var, floor)
    why = scoring.shortfall(without.mse, v.mse, score, var, ok, share, floor)
    if why is not None and not ok and isinstance(c.detail.get("unresolved"), str):
        why = f"{why}: {c.detail['unresolved']}"  # the rule's own words (a static level, a delay read like with like)
    return {
        "cause": c.cause,
        "score": score,
        "score_vs_datasheet": v.common,
        "nmse_after": nmse(raw_tau, v.pred).tolist(),
        "nmse_after_filtered": scoring.nmse(test.tau, v.pred, rest),
        "baseline": v.baseline,
        "estimate": c.estimate,
        "added_parameters": c.n_added,
        "resolved": ok,
        "recovers": share,
        "clears_margin": why is None,
        "shortfall": why,
        "needs_partner": bool(margin and share is not None and partner <= share < scoring.RECOVER),
        "plausible": None,  # the plausibility rule's answer where it was asked (`rounds._pick`), else None
        **({"polish": c.detail["polish"]} if "polish" in c.detail else {}),
    }


def _refit_better(v: Fitted, current: dict) -> bool:
    """Whether `v` holds the datasheet's π while the current model with π refitted scores higher."""
    return (
        v.baseline == "datasheet"
        and "rigid_fit" in current
        and "datasheet" in current
        and current["rigid_fit"].common > current["datasheet"].common
    )


def _with_joint_errors(cand):
    """The reported model with the standard errors of β and θ together, residual correlation counted
    (`candidates.joint_errors`), instead of the searches' conditional ones."""
    return replace(cand, se=cand.errors()) if cand.errors is not None else cand


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


def nominal_entries(
    nominal_pi: dict,
    nominal_pred: dict,
    test: Dataset,
    rest_test: np.ndarray,
    as_dict: Callable[[np.ndarray], dict],
    estimator: str,
    rigid_fit,
) -> tuple[dict, dict]:
    """The nominal models' JSON entries (π by name, held-out nMSE filtered and raw; the rigid fit's estimator and
    why) and their held-out MSE [N² m²] (`scoring.mse`), from their π and held-out predictions by baseline
    ("datasheet", "rigid_fit"). `as_dict`: π (P,) -> {name: value} of the nominal model."""
    mse = {b: scoring.mse(test.tau, p, rest_test) for b, p in nominal_pred.items()}
    entries = {
        b: {
            "pi": as_dict(nominal_pi[b]),
            "nmse": scoring.nmse(test.tau, nominal_pred[b], rest_test),
            "nmse_raw": nmse(test.tau, nominal_pred[b]).tolist(),
        }
        for b in nominal_pi
    }
    entries["rigid_fit"]["estimator"] = estimator
    entries["rigid_fit"]["why"] = "the robot's default estimator" if rigid_fit is None else rigid_fit.why
    return entries, mse


def versions(
    test: Dataset, rest_test: np.ndarray, datasheet_mse: np.ndarray, rigid_parameters: int
) -> Callable[..., Fitted]:
    """`version(cand, baseline, pred, causes, family, theta) -> Fitted`: a model's held-out MSE and its penalised
    gain over the datasheet (`scoring.score`), counting the candidate's added parameters and, on the rigid fit's
    baseline, the `rigid_parameters` its refitted π has."""

    def version(cand, baseline: str, pred: np.ndarray, causes: tuple, family, theta: dict) -> Fitted:
        after = scoring.mse(test.tau, pred, rest_test)
        k = (cand.n_added if cand is not None else 0) + (rigid_parameters if baseline == "rigid_fit" else 0)
        common = scoring.score(datasheet_mse, after, test.n, k)
        return Fitted(causes, baseline, cand, after, pred, common, family, theta)

    return version


def _final_model(chain: list[dict], current: dict, nominal_pred: dict) -> tuple[Fitted, str, np.ndarray]:
    """The final model (the best current one on the common footing), the baseline the report compares against (the
    first cause's when a chain is named, else the final model's) and the held-out prediction after."""
    final = max(current.values(), key=lambda v: v.common)
    if chain:
        baseline = chain[0]["fitted"].baseline
        after_pred = final.pred
    else:
        baseline = final.baseline
        after_pred = nominal_pred[baseline]
    return final, baseline, after_pred


def _chain_entries(chain: list[dict], final: Fitted, parts: Parts, rest_test: np.ndarray) -> list[dict]:
    """The named chain's JSON entries in the order named: each cause's estimate in the final model (its members),
    score, held-out nMSE after it (raw and as scored), baseline, round and estimate when it was added."""
    members = final.cand.detail.get("members", {}) if final.cand is not None else {}
    if final.cand is not None and not members:
        members = {final.cand.cause: final.cand.estimate}
    return [
        {
            "cause": c["cause"],
            "estimate": members.get(c["cause"], c["fitted"].cand.estimate),
            "score": c["score"],
            "nmse_after": nmse(parts.raw_test.tau, c["fitted"].pred).tolist(),
            "nmse_after_filtered": scoring.nmse(parts.test.tau, c["fitted"].pred, rest_test),
            "baseline": c["fitted"].baseline,
            "round": c["round"],
            "estimate_when_added": c["fitted"].cand.estimate,
        }
        for c in chain
    ]


def _evidence(
    parts: Parts,
    nominals: tuple,
    model,
    after_pred: np.ndarray,
    after_forward_error: Callable[[], Any],
    dt: float,
    pose,
) -> dict:
    """The held-out evidence: each nominal model's and the extended model's (`after_pred`) residual evidence, their
    forward-simulation errors (the extended model's from `after_forward_error()`) and the other channels' peaks."""
    _, nominal_pi, nominal_pred = nominals
    test, trial = parts.test, parts.source
    ev = {b: evidence.residual_evidence(test, p, dt, pose) for b, p in nominal_pred.items()}
    ev["forward_error_rad"] = {b: evidence.forward_error(model, pi, test, dt) for b, pi in nominal_pi.items()}
    ev["after"] = evidence.residual_evidence(test, after_pred, dt, pose)
    ev["forward_error_rad"]["after"] = after_forward_error()
    ev["other_channels"] = evidence.channel_peaks(test if trial is None else trial, dt)
    return ev


def conclude(
    rounds, nominals, parts: Parts, model, forward_after, timings: dict, joints, pose, rest_test: np.ndarray
) -> Diagnosis:
    """The `Diagnosis` from the loop's `rounds` (`rounds._rounds`' result), the nominal models (their JSON entries, π
    and held-out predictions by baseline), the data (`Parts`), the nominal `model`, `forward_after(final, baseline)`
    (question 4's motion error), the stages' timings so far, the joints' names, the pose evidence (`Engine.pose`)
    and the held-out part's labels the engine scored with: the named chain, its gain and the evidence."""
    chain, current, candidates, dropped, history = rounds
    nominal, _, nominal_pred = nominals
    train, test, raw_test, how = parts.train, parts.test, parts.raw_test, parts.how
    dt = float(np.median(np.diff(train.t)))
    final, baseline, after_pred = _final_model(chain, current, nominal_pred)
    causes = _chain_entries(chain, final, parts, rest_test)
    cause = causes[0]["cause"] if causes else "none"
    estimate = causes[0]["estimate"] if causes else {}
    before_pred = nominal_pred[baseline]
    named_cand = _with_joint_errors(final.cand) if chain else None

    ev = _evidence(
        parts, nominals, model, after_pred, lambda: forward_after(final if chain else None, baseline), dt, pose
    )
    t_end = time.perf_counter()
    t0, t_fit = timings.pop("t0"), timings["nominal"] + timings["candidates"]
    return Diagnosis(
        cause=cause,
        estimate=estimate,
        baseline=baseline,
        nmse_before=nmse(raw_test.tau, before_pred).tolist(),
        nmse_after=nmse(raw_test.tau, after_pred).tolist(),
        nmse_raw=[nmse(test.tau, before_pred).tolist(), nmse(test.tau, after_pred).tolist()],
        nmse_filtered=[scoring.nmse(test.tau, before_pred, rest_test), scoring.nmse(test.tau, after_pred, rest_test)],
        causes=causes,
        dropped=dropped,
        rounds=history,
        candidates=candidates,
        evidence=ev,
        split=how,
        rate_hz=1.0 / dt,
        named=named_cand,
        nominal=nominal,
        test=test,
        predictions={"before": before_pred, "after": after_pred},
        timings={**timings, "evidence": t_end - t0 - t_fit, "total": t_end - t0},
        joints=list(joints),
        warnings=compared_warnings(train, test, joints),
    )


def row_of(parts: Parts, rest_test: np.ndarray, var: np.ndarray, floor: float, partner: float) -> Callable[..., dict]:
    """`row(v, score, current, gap=None) -> dict`: a candidate's JSON row (`_row`) on the held-out part of `parts`,
    with the engine's naming floor (`floor`, the least share of the torque variance) and partner share."""
    dt = float(np.median(np.diff(parts.train.t)))

    def row(v: Fitted, score: float, current: dict, gap=None) -> dict:
        return _row(v, score, current, parts.raw_test.tau, parts.test, rest_test, var, dt, gap, floor, partner)

    return row


def _as_nominal(value: Any, key: str | None = None) -> Any:
    """The JSON with the datasheet baseline called "nominal" (an identified arm stood in for it): every dict key
    "datasheet" and every `baseline` value "datasheet"."""
    if isinstance(value, dict):
        return {("nominal" if k == "datasheet" else k): _as_nominal(v, k) for k, v in value.items()}
    if isinstance(value, list):
        return [_as_nominal(v, key) for v in value]
    if key == "baseline" and value == "datasheet":
        return "nominal"
    return value
