"""The four questions in order, on any arm: what the nominal models get wrong, which causes (named round by round),
the extended model, the gain (`docs/effects.md`).

`diagnose_trial` runs them through the arm's engine (`engine.Engine`, picked by `ENGINES` for the robot's kind):
the engine prepares the data and fits the nominal models and every candidate; this module owns the rounds (each
cause named against the best model so far, causes a later one made redundant dropped, a datasheet-side cause taken
on trial until a partner closes the refit's gap), the scoring and the naming rules (`scoring`), and the result
(`result.conclude`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from tqdm import tqdm

from ident_opt.arm.base import Robot
from ident_opt.arm.kinds import ByKind
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import believe, identifiability, plausibility, scoring
from ident_opt.diagnosis.chain.engine import ChainEngine
from ident_opt.diagnosis.engine import Engine, Request
from ident_opt.diagnosis.nominal import NominalFit
from ident_opt.diagnosis.planar.engine import PlanarEngine
from ident_opt.diagnosis.result import Diagnosis, Fitted, conclude, nominal_entries, row_of, versions
from ident_opt.fitting.recommend import checked_choice
from ident_opt.numerics import signals
from ident_opt.outputs import shown

#: Each kind of arm's engine (`arm.kinds.ByKind`): the one place the diagnosis asks which kind it has.
ENGINES = ByKind(planar=PlanarEngine, chain=ChainEngine)

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
    "plausible",
)


def _prune(named: list, chain: list, current: dict, version, var, engine: Engine) -> tuple[list, list, dict, list]:
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
        cand = engine.fit(family, full.baseline)
        test = engine.parts.test
        without = version(cand, full.baseline, cand.predict(test), tuple(f.cause for f, _ in rest), *rest[-1])
        gain = full.common - without.common
        if gain <= 0 or not scoring.clears_margin(without.mse, full.mse, gain, var, engine.margin_variance):
            gone.append({"cause": named[i][0].cause, "dropped_in_round": len(chain) + len(gone), "score": gain})
            named, chain = rest, [c for c in chain if c["cause"] != named[i][0].cause]
            current, full = {full.baseline: without}, without
    return named, chain, current, gone


def _rounds(engine: Engine, current: dict, version, row, var, progress: bool, judge=None) -> tuple:
    """The loop of question 2: name the best cause, extend the model with it, ask again against the extended
    model, until nothing clears the margin (at most `MAX_CAUSES`). Every candidate of a round is scored
    against the same reference (the best model so far). Returns (chain, versions of the final model, the
    first round's candidate rows, dropped causes, every round's rows cut to `ROUND_KEYS`). `engine`: how the arm's
    candidates are built and fitted (`engine.Engine`). `judge(v, row, current, round)`: the plausibility rule
    (`plausibility`, applied where a candidate is picked, `_pick`); None: every candidate that clears is plausible."""
    chain: list[dict] = []
    history: list[list[dict]] = []
    named: list[tuple] = []  # each cause's own family and its θ, in the order named
    candidates: list[dict] = []
    dropped: list[dict] = []
    searched = None  # after the first round: each cause's θ where it is held (`_fit_round`)
    tentative, gap = None, None  # a cause taken on trial (the state before it), and the gap it must close
    bar = tqdm(desc="diagnose: fitting candidates", unit="fit", disable=not progress, leave=False)
    for round_ in range(MAX_CAUSES):
        # The round's reference: the current model with the datasheet's π where it has that version.
        ref = current.get("datasheet") or max(current.values(), key=lambda v: v.common)
        fits = _fit_round(engine, named, ref, version, bar, searched)
        best = _best(fits)
        if searched is None:
            again = engine.search_again
            searched = {
                c: None if again or _promising(v, current[v.baseline]) else (v.theta or None) for c, v in best.items()
            }
        ranked = sorted(best.values(), key=lambda v: v.common, reverse=True)
        rows = [row(v, v.common - ref.common, current, gap) for v in ranked]
        _nested(ranked, rows, var, engine.margin_variance)
        here = None if judge is None else (lambda v, r, c=current, k=round_ + 1: judge(v, r, c, k))
        top, on_trial = _pick(ranked, rows, tentative is not None, here)  # the rule marks the rows it rejects
        judgements = {id(v): r.pop("judgement", None) for v, r in zip(ranked, rows)}  # kept off the JSON rows
        if round_ == 0:
            candidates = rows
        history.append([{k: r[k] for k in ROUND_KEYS} for r in rows])
        if top is None:
            break
        if on_trial:
            tentative = (list(named), list(chain), current, list(dropped))
            gap = (current["datasheet"], current["rigid_fit"])
        else:
            tentative, gap = None, None
        named.append((top.family, top.theta))
        chain.append(
            {
                "cause": top.cand.cause,
                "score": top.common - ref.common,
                "fitted": top,
                "round": round_ + 1,
                "judgement": judgements.get(id(top)),
            }
        )
        current = {v.baseline: v for v in fits if v.family is top.family}
        named, chain, current, gone = _prune(named, chain, current, version, var, engine)
        dropped += gone
    if tentative is not None:  # a cause on trial found no partner: back to the model before the trial
        named, chain, current, dropped = tentative
    bar.close()
    return chain, current, candidates, dropped, history


def _best(fits: list[Fitted]) -> dict[str, Fitted]:
    """Each cause's best-scoring version of a round (cause → fit)."""
    best: dict[str, Fitted] = {}
    for v in fits:
        if v.baseline == "rigid_fit" and v.cand.detail.get("empty", False):
            continue  # screened to no joint (`chain.families`): the refitted π alone, hiding the other version
        if v.cand.cause not in best or v.common > best[v.cand.cause].common:
            best[v.cand.cause] = v
    return best


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


def _pick(ranked: list[Fitted], rows: list[dict], on_trial: bool, judge=None) -> tuple[Fitted | None, bool]:
    """(The cause this round adds, whether it is taken on trial.)

    The best candidate that clears the margin and is plausible (`judge(v, row)`, the plausibility rule, which marks
    a candidate it rejects as not clearing, with its `shortfall`: the loop goes on to the next); while a cause is on
    trial, only a datasheet-side partner counts (the pair must close the refit's gap together). Failing that, two
    datasheet-side causes (a payload and extra rotor inertia, say) can each explain too little of what a refitted π
    gains to be named alone, yet together all of it: the best plausible one that `needs_partner` is taken on trial,
    and kept only if the next round finds a partner that makes the pair recover `scoring.RECOVER` of the same gap."""

    def plausible(v: Fitted, r: dict) -> bool:
        return judge is None or judge(v, r)

    top = next(
        (
            v
            for v, r in zip(ranked, rows)
            if r["clears_margin"] and (not on_trial or v.baseline == "datasheet") and plausible(v, r)
        ),
        None,
    )
    if top is not None or on_trial:
        return top, False
    return next((v for v, r in zip(ranked, rows) if r["needs_partner"] and plausible(v, r)), None), True


def _promising(v: Fitted, without: Fitted) -> bool:
    """Whether a first-round fit is worth refitting in later rounds: it gains (penalised, held out) over the
    same kind of fit without it and removes at least half the naming margin of its MSE on some joint."""
    return v.common > without.common and bool(np.any(without.mse - v.mse >= 0.5 * scoring.MARGIN * without.mse))


def _fit_round(engine: Engine, named: list, ref: Fitted, version, bar, searched: dict | None) -> list[Fitted]:
    """Every cause not yet named, composed with those named, fitted against every baseline it allows.

    After the first round (`searched` given) a cause whose first-round fit was `_promising` (every cause, where
    the engine's `search_again` says so) is searched again in full; any other is refitted with its θ held at the
    first-round value (`searched[cause]`): only its linear coefficients move. A cause masked by a larger one in
    the first round (a weak mode under a strong friction asymmetry) thus still gets its chance once the larger
    one is in the model, while the costly searches and polishes run only where they can change the answer."""
    taken = {f.cause for f, _ in named}
    fits = []
    test = engine.parts.test
    for family in engine.families():
        if family.cause in taken:
            continue
        held = searched.get(family.cause) if searched is not None else None
        own = engine.frozen(family, held) if held is not None else family
        composed = engine.compose(named, own)
        for baseline in composed.baselines:
            cand = engine.fit(composed, baseline)
            bar.update()
            theta = held if held is not None else engine.theta(family, cand)
            fits.append(version(cand, baseline, cand.predict(test), (*ref.causes, family.cause), own, theta))
    return fits


def diagnose_trial(
    robot: Robot,
    trial: Dataset,
    unseen: Dataset | None = None,
    train_fraction: float = 0.7,
    progress: bool = True,
    torque_filter_hz: float | str | None = signals.TORQUE_FILTER_HZ,
    rigid_fit=None,
    others: Sequence[Dataset] = (),
    problem_path: str | None = None,
    nominal_fit: NominalFit | None = None,
) -> Diagnosis:
    """Diagnose `trial` (and `unseen`, if given, as the held-out data) of `robot`'s arm; see the module docstring
    and the engines' (`split.parts` for the split, `split.prepare` for `torque_filter_hz`: the problem's derivative
    cut-off is the natural choice). `rigid_fit`: how the rigid fit's π is identified and why (a
    `fitting.recommend.Choice`: the recommended fit, which `diagnose` passes; None: the robot's default estimator),
    for the nominal rigid fit and every candidate that refits π; anything else is an InputError naming it.

    Before naming anything, what the data can tell (`identifiability`); every candidate picked must pass the
    plausibility rule (`plausibility`, in `_pick`); each named cause is confirmed on the first of `others` (trials
    that neither trained nor selected it) where it still gains (`confirm`); the verdict beside the causes
    (`verdict`) names `problem_path` in the `ident-opt excite` commands it suggests. `nominal_fit`: an identified arm in
    place of the datasheet (`nominal.NominalFit`; the JSON then calls that baseline "nominal")."""
    rigid_fit = checked_choice(rigid_fit, robot, "rigid_fit", "diagnose")
    estimator = robot.default_estimator if rigid_fit is None else rigid_fit.estimator
    t0 = time.perf_counter()
    engine = ENGINES.of(robot)(robot, Request(trial, unseen, train_fraction, torque_filter_hz, estimator, nominal_fit))
    parts, nominal = engine.parts, engine.nominal
    test = parts.test
    entries, nominal_mse = nominal_entries(
        nominal.pi, nominal.pred, test, nominal.rest_test, nominal.model.as_dict, estimator, rigid_fit
    )
    entries["rigid_fit"].update(nominal.extra)
    var = np.var(test.tau, axis=0)
    ident, facts = _what_can_tell(engine, robot, unseen, var)
    t_nominal = time.perf_counter()
    version = versions(test, nominal.rest_test, nominal_mse["datasheet"], nominal.rigid_parameters)
    row = row_of(parts, nominal.rest_test, var, engine.margin_variance, engine.partner)
    current = {b: version(None, b, nominal.pred[b], (), None, {}) for b in nominal.pred}
    rejected: list[dict] = []
    rounds = _rounds(engine, current, version, row, var, progress, believe.judge(engine, facts, rejected))
    t_fit = time.perf_counter()
    result = conclude(
        rounds,
        (entries, nominal.pi, nominal.pred),
        parts,
        nominal.model,
        engine.forward_after,
        {"nominal": t_nominal - t0, "candidates": t_fit - t_nominal, "t0": t0},
        robot.joint_names,
        engine.pose,
        nominal.rest_test,
    )
    _engine_notes(result, engine, nominal_fit)
    t_believe = time.perf_counter()
    believe.complete(result, engine, rounds[0], ident, facts, rejected, others, problem_path)
    result.timings["verdict"] = time.perf_counter() - t_believe
    result.timings["total"] += result.timings["verdict"]
    return result


def _engine_notes(result: Diagnosis, engine: Engine, nominal_fit: NominalFit | None) -> None:
    """What the engine adds to the result (in place): its naming thresholds, its screening, and the identified
    nominal with the datasheet values it kept."""
    result.margin_variance, result.partner = engine.margin_variance, engine.partner
    if nominal_fit is not None:
        result.nominal_fit = nominal_fit
        result.warnings += nominal_fit.warning(engine.kept)
    if (screening := engine.screening()) is not None:
        result.evidence["screening"] = screening


def _what_can_tell(engine: Engine, robot: Robot, unseen: Dataset | None, var: np.ndarray) -> tuple:
    """(what the data can tell, the plausibility rule's facts) before anything is named; the engine leaves out of a
    per-joint candidate the joints whose value the rule rejects."""
    parts = engine.parts
    ident = identifiability.read(
        parts.train, parts.test, engine.nominal.model, _scored_on(parts, unseen), robot.joint_names
    )
    facts = plausibility.facts(engine, ident, var, robot)
    engine.leave_implausible(lambda cause, est, detail: plausibility.failing_joints(cause, est, detail, facts))
    return ident, facts


def _scored_on(parts, unseen: Dataset | None) -> str:
    """The trial the gains are scored on, in words: the unseen trial's name, or the held-out part of the trial."""
    if unseen is not None:
        return shown(unseen.source)
    return f"{shown(parts.train.source)}, its held-out part"
