"""The four questions in order: what the nominal models get wrong, which cause, the extended model, the gain.

Split: with a second (unseen) trial, the first trial trains and the second is held out; with one trial,
the first `train_fraction` of it in time trains and the rest is held out (contiguous, so delays and modes
survive the split) — or, when a joint barely moves in that last part and less so in the first, the first part is
held out (`held_out`); a joint the held-out part still barely moves is a warning (`compared_warnings`). Both nominal
models are examined: the datasheet (no fitting) and the best rigid fit of the nominal structure
(`candidates.NOMINAL`, by the recommended fit — the robot's default estimator unless the caller gives one,
`diagnose`'s `rigid_fit` — with joint weights 1/σ_j² from a least-squares pass (`weights_of`), `nominal_fit`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal
from tqdm import tqdm

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.data.dataset import Dataset, chronological_split, refiltered
from ident_opt.data.derivatives import choose_cutoff
from ident_opt.diagnosis import candidates as cands
from ident_opt.diagnosis import evidence, linear, scoring, signals
from ident_opt.errors import InputError
from ident_opt.metrics import nmse
from ident_opt.outputs import shown
from ident_opt.warnings import ResultWarning

#: Fewest held-out / training samples that make a diagnosis meaningful.
MIN_SAMPLES = 200
#: Most causes one diagnosis names (rounds of the loop).
MAX_CAUSES = 4
#: What the JSON's `rounds` keeps of each round's candidate rows (why a cause was, or was not, named).
ROUND_KEYS = (
    "cause",
    "score",
    "baseline",
    "nmse_after_filtered",
    "recovers",
    "clears_margin",
    "needs_partner",
    "shortfall",
)


@dataclass
class Fitted:
    """One fitted model: the causes it has (in the order named), its fit kind (`baseline`), the candidate
    (None for a nominal model), its held-out MSE [N² m²] and prediction, and its penalised held-out gain over
    the datasheet with every fitted parameter counted (`common`, the one footing all models are ranked on)."""

    causes: tuple
    baseline: str
    cand: cands.Candidate | None
    mse: np.ndarray
    pred: np.ndarray
    common: float
    family: cands.Family | None
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
    named: cands.Candidate | None
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
            "rate_hz": self.rate_hz,
            "nominal": self.nominal,
            "extended_model": extended,
            "evidence": self.evidence,
            "timings_s": self.timings,
            "warnings": [w.as_dict() for w in self.warnings],
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
    # a per-joint cause the n-joint screen found on no joint (`arm_fit`) adds nothing: a round's chain refitted
    # against another baseline can still score, and without this the cause would take that score as its own
    # (`unresolved`: the candidate failed its family's own check on the fitted model, `arm_fit.ArmFamily.check`)
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


def _prune(named: list, chain: list, current: dict, ctx, version, var, engine=cands) -> tuple[list, list, dict, list]:
    """Drop earlier causes the newest one made redundant: refit the chain without each (θ held, same fit
    kind as the newest); a cause whose removal does not lose the margin or the score is dropped."""
    gone = []
    if len(named) < 2:
        return named, chain, current, gone
    full = max(current.values(), key=lambda w: w.common)
    for i in range(len(named) - 2, -1, -1):
        rest = [named[k] for k in range(len(named)) if k != i]
        family = engine.compose([(engine.frozen(f, t), t) for f, t in rest[:-1]], engine.frozen(*rest[-1]))
        if full.baseline not in family.baselines:
            continue
        cand = engine.fit(family, full.baseline, ctx)
        without = version(cand, full.baseline, cand.predict(ctx.test), tuple(f.cause for f, _ in rest), *rest[-1])
        gain = full.common - without.common
        if gain <= 0 or not scoring.clears_margin(without.mse, full.mse, gain, var, engine.MARGIN_VARIANCE):
            gone.append({"cause": named[i][0].cause, "dropped_in_round": len(chain) + len(gone), "score": gain})
            named, chain = rest, [c for c in chain if c["cause"] != named[i][0].cause]
            current, full = {full.baseline: without}, without
    return named, chain, current, gone


def _rounds(robot, ctx, current: dict, version, row, var, progress: bool, engine=cands) -> tuple:
    """The loop of question 2: name the best cause, extend the model with it, ask again against the extended
    model, until nothing clears the margin (at most `MAX_CAUSES`). Every candidate of a round is scored
    against the same reference (the best model so far). Returns (chain, versions of the final model, the
    first round's candidate rows, dropped causes, every round's rows cut to `ROUND_KEYS`). `engine`: how candidates
    are built and fitted (`candidates` for the planar arm, `arm_fit.Engine` for n joints)."""
    chain: list[dict] = []
    history: list[list[dict]] = []
    named: list[tuple[cands.Family, dict]] = []  # each cause's own family and its θ, in the order named
    candidates: list[dict] = []
    dropped: list[dict] = []
    searched = None  # after the first round: each cause's θ where it is held (`_fit_round`)
    tentative, gap = None, None  # a cause taken on trial (the state before it), and the gap it must close
    bar = tqdm(desc="diagnose: fitting candidates", unit="fit", disable=not progress, leave=False)
    for round_ in range(MAX_CAUSES):
        # The round's reference: the current model with the datasheet's π where it has that version.
        ref = current.get("datasheet") or max(current.values(), key=lambda v: v.common)
        fits = _fit_round(robot, ctx, named, ref, version, bar, searched, engine)
        best: dict[str, Fitted] = {}
        for v in fits:
            if v.baseline == "rigid_fit" and v.cand.detail.get("empty", False):
                continue  # screened to no joint (`arm_fit`): the refitted π alone, hiding the cause's other version
            if v.cand.cause not in best or v.common > best[v.cand.cause].common:
                best[v.cand.cause] = v
        if searched is None:
            again = engine.SEARCH_AGAIN
            searched = {
                c: None if again or _promising(v, current[v.baseline]) else (v.theta or None) for c, v in best.items()
            }
        ranked = sorted(best.values(), key=lambda v: v.common, reverse=True)
        rows = [row(v, v.common - ref.common, current, gap) for v in ranked]
        _nested(ranked, rows, var, engine.MARGIN_VARIANCE)
        if round_ == 0:
            candidates = rows
        history.append([{k: r[k] for k in ROUND_KEYS} for r in rows])
        top, on_trial = _pick(ranked, rows, tentative is not None)
        if top is None:
            break
        if on_trial:
            tentative = (list(named), list(chain), current, list(dropped))
            gap = (current["datasheet"], current["rigid_fit"])
        else:
            tentative, gap = None, None
        named.append((top.family, top.theta))
        chain.append({"cause": top.cand.cause, "score": top.common - ref.common, "fitted": top, "round": round_ + 1})
        current = {v.baseline: v for v in fits if v.family is top.family}
        named, chain, current, gone = _prune(named, chain, current, ctx, version, var, engine)
        dropped += gone
    if tentative is not None:  # a cause on trial found no partner: back to the model before the trial
        named, chain, current, dropped = tentative
    bar.close()
    return chain, current, candidates, dropped, history


def _nested(ranked: list[Fitted], rows: list[dict], var, floor: float) -> None:
    """A candidate whose columns contain another cause's (`Family.nests`) is named over that cause only if it
    also clears the margin against that cause's own fit on the same baseline, in place on `rows`: its extra
    columns must earn their place, not ride on the gain of the columns it shares (an elastic joint's motor
    inertia reads an armature; the mode beside it may only follow the noise)."""
    fits = {v.cand.cause: v for v in ranked}
    for v, r in zip(ranked, rows):
        for cause in v.family.nests if r["clears_margin"] else ():
            inner = fits.get(cause)
            if inner is None or inner.baseline != v.baseline:
                continue
            why = scoring.shortfall(inner.mse, v.mse, v.common - inner.common, var, True, None, floor)
            if why is not None:
                r["clears_margin"] = r["needs_partner"] = False
                r["shortfall"] = f"against `{cause}`'s fit, whose columns it contains, {why}"
                break


def _pick(ranked: list[Fitted], rows: list[dict], on_trial: bool) -> tuple[Fitted | None, bool]:
    """(The cause this round adds, whether it is taken on trial.)

    The best candidate that clears the margin; while a cause is on trial, only a datasheet-side partner
    counts (the pair must close the refit's gap together). Failing that, two datasheet-side causes (a
    payload and extra rotor inertia, say) can each explain too little of what a refitted π gains to be
    named alone, yet together all of it: the best one that `needs_partner` is taken on trial, and kept only
    if the next round finds a partner that makes the pair recover `scoring.RECOVER` of the same gap."""
    top = next(
        (v for v, r in zip(ranked, rows) if r["clears_margin"] and (not on_trial or v.baseline == "datasheet")),
        None,
    )
    if top is not None or on_trial:
        return top, False
    return next((v for v, r in zip(ranked, rows) if r["needs_partner"]), None), True


def _promising(v: Fitted, without: Fitted) -> bool:
    """Whether a first-round fit is worth refitting in later rounds: it gains (penalised, held out) over the
    same kind of fit without it and removes at least half the naming margin of its MSE on some joint."""
    return v.common > without.common and bool(np.any(without.mse - v.mse >= 0.5 * scoring.MARGIN * without.mse))


def _fit_round(robot, ctx, named: list, ref: Fitted, version, bar, searched: dict | None, engine=cands) -> list[Fitted]:
    """Every cause not yet named, composed with those named, fitted against every baseline it allows.

    After the first round (`searched` given) a cause whose first-round fit was `_promising` (every cause, where
    the engine's `SEARCH_AGAIN` says so) is searched again in full; any other is refitted with its θ held at the
    first-round value (`searched[cause]`): only its linear coefficients move. A cause masked by a larger one in
    the first round (a weak mode under a strong friction asymmetry) thus still gets its chance once the larger
    one is in the model, while the costly searches and polishes run only where they can change the answer."""
    taken = {f.cause for f, _ in named}
    fits = []
    for family in engine.families(robot):
        if family.cause in taken:
            continue
        held = searched.get(family.cause) if searched is not None else None
        own = engine.frozen(family, held) if held is not None else family
        composed = engine.compose(named, own)
        for baseline in composed.baselines:
            cand = engine.fit(composed, baseline, ctx)
            bar.update()
            theta = held if held is not None else engine.theta(family, cand, ctx)
            fits.append(version(cand, baseline, cand.predict(ctx.test), (*ref.causes, family.cause), own, theta))
    return fits


def _forward_after(final: Fitted | None, baseline: str, ds_pi: dict, pi_rigid, test: Dataset, dt: float) -> list:
    """Question 4's motion error of the extended model: its rigid part (π refitted or the datasheet's)
    integrated, the rest of its torque teacher-forced along the measured motion (`evidence.forward_error`).
    Without a cause: the baseline's own error."""
    model = cands.NOMINAL
    if final is None:
        pi = model.vector(ds_pi) if baseline == "datasheet" else pi_rigid
        return evidence.forward_error(model, pi, test, dt)
    pi = model.vector({**ds_pi, **final.cand.parameters})
    rigid = model.predict(pi, test.q, test.dq, test.ddq)
    return evidence.forward_error(model, pi, test, dt, extension=final.pred - rigid)


def _with_joint_errors(cand: cands.Candidate) -> cands.Candidate:
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


#: A joint is under-compared when the share of its held-out samples in motion is below this fraction of the share of
#: its training samples in motion: what a cause does on it can hardly show in the held-out score.
UNDER_COMPARED = 0.25


def compared(train_dq: np.ndarray, test_dq: np.ndarray) -> np.ndarray:
    """(n,): for each joint, the share of held-out samples in motion over the share of training samples in motion
    (1: the held-out part exercises it as much as the training part). In motion: faster than its stick speed on the
    training part (`signals.stick_speed`), the samples an arm's diagnosis compares."""
    fast = signals.stick_speed(train_dq)
    trained = np.mean(np.abs(train_dq) >= fast, axis=0)
    held = np.mean(np.abs(test_dq) >= fast, axis=0)
    return held / np.maximum(trained, np.finfo(float).tiny)


def split(train: Dataset, test: Dataset | None, train_fraction: float) -> tuple[Dataset, Dataset, str]:
    """(training part, held-out part, description); see the module docstring and `held_out`. The description names
    the trials as every output does (`outputs.shown`: relative to the working folder when inside it), never the
    absolute paths the problem file resolved them to."""
    if test is not None:
        return train, test, f"train on {shown(train.source)}, held out: {shown(test.source)}"
    tr, te, how = held_out(train, train_fraction)
    return train.subset(tr), train.subset(te), how


def held_out(trial: Dataset, train_fraction: float) -> tuple[np.ndarray, np.ndarray, str]:
    """(training indices, held-out indices, description) of one trial: the last `1 − train_fraction` in time is held
    out, unless a joint is under-compared there (`UNDER_COMPARED`: a point-to-point trial whose last moves leave one
    joint at rest) and less so when the first part is held out instead. Both parts stay contiguous."""
    tr, te = chronological_split(trial.n, train_fraction)
    worst = compared(trial.dq[tr], trial.dq[te]).min()
    if worst < UNDER_COMPARED:
        te_first, tr_last = chronological_split(trial.n, 1.0 - train_fraction)
        if compared(trial.dq[tr_last], trial.dq[te_first]).min() > worst:
            held = f"{1.0 - train_fraction:.0%}"
            return (
                tr_last,
                te_first,
                f"chronological, held out first: the last {train_fraction:.0%} of {shown(trial.source)} trains, "
                f"the first {held} is held out (a joint moves too little in its last {held})",
            )
    return tr, te, f"chronological: first {train_fraction:.0%} of {shown(trial.source)} trains, the rest is held out"


def compared_warnings(train: Dataset, test: Dataset, names: tuple[str, ...]) -> list[ResultWarning]:
    """A warning per joint the held-out part under-compares (`compared`): the diagnosis cannot judge a cause on it."""
    share = compared(train.dq, test.dq)
    low = [j for j in range(len(share)) if share[j] < UNDER_COMPARED]
    if not low:
        return []
    joints = ", ".join(f"{names[j]} (q{j + 1}: {share[j]:.0%})" for j in low)
    return [
        ResultWarning(
            "joint_not_compared",
            f"the held-out part moves {joints} far less than the training part does (share of samples in motion, "
            "held out over training): a cause on such a joint can hardly show in the held-out score, so `none` "
            "there is not evidence of its absence; record a trial that moves every joint throughout, or hold out "
            "another trial",
        )
    ]


def at_rest(trial: Dataset) -> Dataset:
    """The trial with the velocity of a joint at rest read as exactly 0.

    Coulomb friction at rest is set-valued (stiction holds whatever the controller pushes, up to the
    breakaway level), and the sign of an estimated velocity at rest is noise: a rigid model's fc·sgn(dq)
    there is a random ±fc that no cause explains. A joint is at rest at a sample (`signals.resting`) when |dq| is
    below REST_FRACTION of its speed scale (95th percentile of |dq|) there and stays below it for REST_WINDOW_S
    before or after (so the filter ringing just before a start or after a stop counts as rest, but a smooth
    velocity reversal, slow only for an instant, does not). Every model (nominal and candidates) sees the
    same velocities, so scores compare like with like; the rest samples stay in (ringing and gravity live
    there too).
    """
    dq = np.where(signals.resting(trial.dq, float(np.median(np.diff(trial.t)))), 0.0, trial.dq)
    return replace(trial, dq=dq)


def weights_of(ds: Dataset) -> np.ndarray:
    """1/σ_j² [1/(N m)²] per joint, σ_j² the residual variance of the nominal structure's least-squares fit, on the
    same objective as every candidate (rest stretches compared about their mean)."""
    rest = signals.rest_runs(ds.dq)
    Y = signals.demean_runs(cands.NOMINAL.regressor(ds.q, ds.dq, ds.ddq), rest)
    tau = signals.demean_runs(ds.tau, rest)
    first = linear.solve(np.zeros((ds.n, 2)), Y, tau, np.ones(2), with_se=False)
    return 1.0 / np.maximum(first.rss / ds.n, 1e-12 * np.maximum(np.var(ds.tau, axis=0), 1e-30))


def nominal_fit(ctx: cands.Context) -> np.ndarray:
    """π̂ of the nominal structure by the context's estimator on the training part (`Context.rigid`): what every
    candidate that refits π reduces to without a column of its own."""
    tr, model = ctx.train, cands.NOMINAL
    at = ctx.instrumented
    Z = model.regressor(at.q, at.dq, at.ddq) if at is not None else None
    return ctx.rigid(model, model.regressor(tr.q, tr.dq, tr.ddq), tr.tau, Z)


def logged_bandwidth(trial: Dataset) -> tuple[Dataset, float | None]:
    """(The trial, the torque's cut-off [Hz]) for derivatives as logged, under "auto".

    The logger's filter is unknown; its bandwidth is read from the logged accelerations
    (`signals.matched_cutoff`). Where it is narrower than what the angles support (`derivatives.choose_cutoff`,
    the rule the loader uses for a file without derivatives), the derivatives are estimated again from the
    angles at that cut-off (`data.refiltered`): a narrow logger filter (a Savitzky–Golay filter of 21 samples at
    100 Hz passes 4.7 Hz) smears Coulomb steps and modes that the data hold. Assumption: the angles are logged
    at the full rate and resolution, so they carry the motion's whole band. The trial keeps every sample (the
    held-out part is aligned with the raw torque's)."""
    matched = signals.matched_cutoff(trial.t, trial.q, trial.ddq)
    if matched is None:
        return trial, None
    supported = choose_cutoff(trial.t, trial.q)
    if matched >= supported:
        return trial, matched
    return refiltered(trial, supported), supported


def prepare(trial: Dataset, torque_filter_hz: float | str | None) -> Dataset:
    """`at_rest`, then the torque low-passed by the zero-phase filter the derivatives are estimated with
    (4th-order Butterworth at `torque_filter_hz`, forward-backward; "auto": the cut-off the trial's derivatives
    were estimated with, `Dataset.cutoff_hz`, or for derivatives as logged the bandwidth of the logger's own
    filter, with the derivatives estimated again where that filter is narrower than the data, `logged_bandwidth`;
    None: no filter).

    Estimated accelerations are a smoothed version of the true ones (a step in acceleration becomes a ramp
    over tens of ms); the measured torque steps. Filtering τ the same way puts both sides of τ = Y π in the
    same bandwidth, so the smoothing mismatch at every start and stop does not pose as a delay or a mode,
    and noise above the cut-off goes too. Modes and delays inside the band are untouched (the filter is
    zero-phase and linear).
    """
    if torque_filter_hz == "auto":  # the problem's `derivative_cutoff_hz = "auto"`: the one this trial was read with
        trial, torque_filter_hz = (trial, trial.cutoff_hz) if trial.cutoff_hz is not None else logged_bandwidth(trial)
    trial = at_rest(trial)
    if torque_filter_hz is None:
        return trial
    dt = float(np.median(np.diff(trial.t)))
    if torque_filter_hz >= 0.45 / dt or trial.n <= 30:
        return trial
    b, a = signal.butter(4, torque_filter_hz * 2 * dt)
    return replace(trial, tau=signal.filtfilt(b, a, trial.tau, axis=0))


#: [rad/s] A joint whose speed never exceeds this is still: its derivatives re-estimated from a constant angle are
#: round-off, not motion.
STILL_SPEED = 1e-9


def parts(
    trial: Dataset, unseen: Dataset | None, train_fraction: float, torque_filter_hz, names: tuple[str, ...]
) -> tuple[Dataset, Dataset, Dataset, str]:
    """(training part, held-out part, the held-out part's measured torque as logged, the split in words): `prepare`d
    and `split`; an InputError when there is too little data, a torque channel is constant, or a joint never
    moves in the training part (named: nothing about it can be fitted, and its rows would be one rest stretch)."""
    prepared = prepare(trial, torque_filter_hz)
    if unseen is not None:
        train, test, how = split(prepared, prepare(unseen, torque_filter_hz), train_fraction)
        raw_test = unseen  # the measured torque, as compare and identify see it
    else:  # one choice of samples (from the trial as logged, as `fitting.recommend.for_diagnosis` makes it)
        tr, te, how = held_out(trial, train_fraction)
        train, test, raw_test = prepared.subset(tr), prepared.subset(te), trial.subset(te)
    if train.n < MIN_SAMPLES or test.n < MIN_SAMPLES:
        raise InputError(
            f"{trial.source}: too little data to diagnose ({train.n} training and {test.n} held-out "
            f"samples; at least {MIN_SAMPLES} each)"
        )
    for ds, part in ((train, "training"), (test, "held-out")):
        if np.any(np.var(ds.tau, axis=0) <= 0):
            raise InputError(f"{ds.source}: a torque channel is constant; nothing to diagnose")
        still = (
            [j for j in range(ds.dq.shape[1]) if np.max(np.abs(ds.dq[:, j])) < STILL_SPEED]
            if part == "training"
            else []
        )
        if still:
            joints = ", ".join(f"{names[j]} (q{j + 1})" for j in still)
            raise InputError(
                f"{ds.source}: joint{'s' if len(still) > 1 else ''} {joints} never move{'' if len(still) > 1 else 's'} "
                f"in the {part} part; the diagnosis needs every joint in motion (move it, or leave it out of the "
                "problem)"
            )
    return train, test, raw_test, how


#: The estimators that refit the grouped π of any model the candidates build (extensions and columns included).
REFITS = ("ols", "constrained", "robust")


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


def diagnose(
    robot: PlanarRobot,
    trial: Dataset,
    unseen: Dataset | None = None,
    train_fraction: float = 0.7,
    progress: bool = True,
    torque_filter_hz: float | str | None = signals.TORQUE_FILTER_HZ,
    rigid_fit=None,
) -> Diagnosis:
    """Diagnose `trial` (and `unseen`, if given, as the held-out data); see the module docstring.
    `torque_filter_hz`: see `prepare` (the problem's derivative cut-off is the natural choice). `rigid_fit`: how the
    rigid fit's π is identified and why (a `fitting.recommend.Recommendation`: the recommended fit, which the command
    gives; None: the robot's default estimator), for the nominal rigid fit and every candidate that refits π."""
    estimator = robot.default_estimator if rigid_fit is None else rigid_fit.estimator
    if estimator not in REFITS:  # e.g. nlp_physical: π from the rigid arm's physical parameters alone
        raise InputError(
            f"diagnose: the rigid fit {estimator!r} cannot carry a cause's parameters beside the grouped π, as the "
            f"planar diagnosis refits them together; use one of {', '.join(REFITS)}"
        )
    t0 = time.perf_counter()
    train, test, raw_test, how = parts(trial, unseen, train_fraction, torque_filter_hz, robot.joint_names)
    dt = float(np.median(np.diff(train.t)))
    ds_pi = datasheet_pi(robot, "physical")
    weights = weights_of(train)
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
        estimator,
    )
    pi_rigid = nominal_fit(ctx)

    model = cands.NOMINAL
    nominal_pi = {"datasheet": model.vector(ds_pi), "rigid_fit": pi_rigid}
    nominal_pred = {b: model.predict(pi, test.q, test.dq, test.ddq) for b, pi in nominal_pi.items()}
    nominal, nominal_mse = nominal_entries(
        nominal_pi, nominal_pred, test, rest_test, model.as_dict, estimator, rigid_fit
    )
    t_nominal = time.perf_counter()

    var = np.var(test.tau, axis=0)
    version = versions(test, rest_test, nominal_mse["datasheet"], len(cands.NOMINAL.names))

    def row(v: Fitted, score: float, current: dict, gap=None) -> dict:
        return _row(v, score, current, raw_test.tau, test, rest_test, var, dt, gap, cands.MARGIN_VARIANCE)

    current = {b: version(None, b, nominal_pred[b], (), None, {}) for b in nominal_pred}
    rounds = _rounds(robot, ctx, current, version, row, var, progress)
    t_fit = time.perf_counter()

    def forward_after(final: Fitted | None, baseline: str) -> list:
        return _forward_after(final, baseline, ds_pi, pi_rigid, test, dt)

    return conclude(
        rounds,
        (nominal, nominal_pi, nominal_pred),
        (train, test, raw_test, how, trial if unseen is not None else None),
        model,
        forward_after,
        {"nominal": t_nominal - t0, "candidates": t_fit - t_nominal, "t0": t0},
        robot.joint_names,
    )


def conclude(
    rounds, nominals, data, model, forward_after, timings: dict, joints, pose=evidence.pose_r2, rest_test=None
) -> Diagnosis:
    """The `Diagnosis` from the loop's `rounds` (`_rounds`' result), the nominal models (their JSON entries, π and
    held-out predictions by baseline), the data (training, held-out and measured held-out parts, the split, the
    unseen trial's source trial or None), the nominal `model`, `forward_after(final, baseline)` (question 4's motion
    error), the stages' timings so far and the joints' names: the named chain, its gain and the evidence.
    `rest_test`: the held-out part's labels the engine scored with (None: its rest stretches, `signals.rest_runs`)."""
    chain, current, candidates, dropped, history = rounds
    nominal, nominal_pi, nominal_pred = nominals
    train, test, raw_test, how, trial = data
    dt = float(np.median(np.diff(train.t)))
    rest_test = signals.rest_runs(test.dq) if rest_test is None else rest_test
    final = max(current.values(), key=lambda v: v.common)
    if chain:
        baseline = chain[0]["fitted"].baseline
        after_pred = final.pred
    else:
        baseline = final.baseline
        after_pred = nominal_pred[baseline]
    members = final.cand.detail.get("members", {}) if final.cand is not None else {}
    if final.cand is not None and not members:
        members = {final.cand.cause: final.cand.estimate}
    causes = [
        {
            "cause": c["cause"],
            "estimate": members.get(c["cause"], c["fitted"].cand.estimate),
            "score": c["score"],
            "nmse_after": nmse(raw_test.tau, c["fitted"].pred).tolist(),
            "nmse_after_filtered": scoring.nmse(test.tau, c["fitted"].pred, rest_test),
            "baseline": c["fitted"].baseline,
            "round": c["round"],
            "estimate_when_added": c["fitted"].cand.estimate,
        }
        for c in chain
    ]
    cause = causes[0]["cause"] if causes else "none"
    estimate = causes[0]["estimate"] if causes else {}
    before_pred = nominal_pred[baseline]
    named_cand = _with_joint_errors(final.cand) if chain else None

    ev = {b: evidence.residual_evidence(test, p, dt, pose) for b, p in nominal_pred.items()}
    ev["forward_error_rad"] = {b: evidence.forward_error(model, pi, test, dt) for b, pi in nominal_pi.items()}
    ev["after"] = evidence.residual_evidence(test, after_pred, dt, pose)
    ev["forward_error_rad"]["after"] = forward_after(final if chain else None, baseline)
    ev["other_channels"] = evidence.channel_peaks(test if trial is None else trial, dt)
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
