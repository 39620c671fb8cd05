"""What makes a diagnosis believable on a real robot (`docs/effects.md`, "Believable on real robots"), around the
rounds (`rounds.diagnose_trial`): the plausibility rule applied where a candidate is picked (`judge`, handed to
`rounds._rounds`), and, once the rounds are done, each named cause's plausibility in the final model, its
confirmation on another trial, the verdict and its warnings (`complete`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import confirm, identifiability, plausibility, verdict
from ident_opt.diagnosis.engine import Engine
from ident_opt.diagnosis.result import Diagnosis, Fitted
from ident_opt.numerics import signals
from ident_opt.warnings import ResultWarning

#: The checks of a joint the plausibility rule took out of a per-joint candidate: its value out of range.
LEFT_OUT_CHECKS = {"range": False, "search_edge": False, "no_joint_worse": True, "forward_simulation": True}


def judge(engine: Engine, facts: plausibility.Facts, rejected: list[dict]):
    """`judge(v, row, current, round) -> bool` for `rounds._rounds`: the plausibility rule (`plausibility.judge`) on a
    fitted candidate `v` against the same kind of fit without it (`current`), with the forward simulation of both
    (`Engine.forward_after`, each run once); it writes its answer into the candidate's row, marks a rejected one as
    not clearing (its `shortfall` says why) and lists it in `rejected`."""
    forwards: dict[int, tuple] = {}

    def forward(v: Fitted) -> list:
        if id(v) not in forwards:
            forwards[id(v)] = (v, engine.forward_after(v if v.cand is not None else None, v.baseline))
        return forwards[id(v)][1]

    test, rest = engine.parts.test, engine.nominal.rest_test
    dt = float(np.median(np.diff(test.t)))

    def judge(v: Fitted, r: dict, current: dict, round_: int) -> bool:
        without = current.get(v.baseline) or max(current.values(), key=lambda w: w.common)
        scatter = plausibility.paired_scatter(
            signals.demean_runs(test.tau - without.pred, rest), signals.demean_runs(test.tau - v.pred, rest), dt
        )
        j = plausibility.judge(
            v.cand.cause,
            v.cand.estimate,
            v.cand.detail,
            without.mse,
            v.mse,
            (forward(without), forward(v)),
            facts,
            scatter,
        )
        names = facts.joints
        r.update(
            plausible=j["plausible"],
            checks=j["checks"],
            identifiable=j["identifiable"],
            judgement=j,
            plausibility={
                "reasons": j["reasons"],
                "gains_on": [names[k] for k in j["gains_on"]],
                "worse_on": [names[k] for k in j["worse_on"]],
                "forward": j["forward"],
            },
        )
        left_out = v.cand.detail.get("implausible_joints") or {}
        if left_out:  # joints the rule took out of the candidate before this fit (`chain.families.fit`)
            rejected.append(_left_out(v, round_, left_out, names))
        if not j["plausible"]:
            r["clears_margin"] = r["needs_partner"] = False
            r["shortfall"] = plausibility.shortfall(j)
            rejected.append(_rejected(v, r, j, round_, names))
        return j["plausible"]

    return judge


def _left_out(v: Fitted, round_: int, left_out: dict, names: tuple[str, ...]) -> dict:
    """The `rejected` entry of the joints the rule took out of a per-joint candidate (`left_out`: joint name → why)."""
    return {
        "cause": v.cand.cause,
        "round": round_,
        "baseline": v.baseline,
        "estimate": None,
        "score": None,
        "nmse_after": None,
        "checks": {**LEFT_OUT_CHECKS},
        "identifiable": True,
        "reasons": [why for whys in left_out.values() for why in whys],
        "gains_on": [names.index(name) for name in left_out],
        "gains_on_joints": list(left_out),
        "left_out_joints": list(left_out),
    }


def _rejected(v: Fitted, r: dict, j: dict, round_: int, names: tuple[str, ...]) -> dict:
    """The `rejected` entry of a candidate `v` (its row `r`) the plausibility rule's judgement `j` turned down."""
    return {
        "cause": v.cand.cause,
        "round": round_,
        "baseline": v.baseline,
        "estimate": v.cand.estimate,
        "score": r["score"],
        "nmse_after": r["nmse_after"],
        "checks": j["checks"],
        "identifiable": j["identifiable"],
        "reasons": j["reasons"],
        "gains_on": j["gains_on"],
        "gains_on_joints": [names[k] for k in j["gains_on"]],
    }


def complete(
    d: Diagnosis,
    engine: Engine,
    chain: list[dict],
    ident: identifiability.Identifiability,
    facts: plausibility.Facts,
    rejected: list[dict],
    others: Sequence[Dataset],
    problem_path: str | None,
) -> None:
    """Complete `d` (in place) with what the data can tell, each named cause's plausibility in the final model and its
    confirmation on another trial, the candidates rejected, the verdict and its warnings."""
    confirmed, found = confirm.confirm(engine, chain, others, d.baseline)
    for c, entry, on in zip(d.causes, chain, confirmed):
        judged = entry.get("judgement") or {}
        in_range, at_edge = plausibility.ranges(c["cause"], c["estimate"], d.detail_of(c["cause"]), facts)
        checks = {
            "range": not in_range,
            "search_edge": bool(at_edge),
            "no_joint_worse": judged.get("checks", {}).get("no_joint_worse", True),
            "forward_simulation": judged.get("checks", {}).get("forward_simulation", True),
        }
        c["plausible"] = bool(checks["range"] and not checks["search_edge"] and checks["no_joint_worse"])
        c["plausible"] = c["plausible"] and bool(checks["forward_simulation"])
        c["checks"] = checks
        c["confirmed_on"] = on
        reasons = [*in_range, *at_edge] + [r for r in judged.get("reasons", []) if r not in in_range + at_edge]
        c["plausibility"] = {"reasons": reasons, "identifiable": judged.get("identifiable", True)}
    d.identifiability = ident.as_json()
    d.rejected = rejected
    d.plausibility = {"facts": facts.describe(), "rule": plausibility.__doc__.split("\n\n", 1)[1].strip()}
    d.confirmation = found
    test = engine.parts.test
    dt = float(np.median(np.diff(test.t)))
    residual = signals.demean_runs(test.tau - d.predictions["after"], engine.nominal.rest_test)  # as scored
    residual = residual - residual.mean(axis=0)
    noise = verdict.noise_nmse(residual, test.tau, dt, engine.filter_hz)
    left_nmse = verdict.residual_nmse(residual, test.tau)
    d.verdict, d.mismatch, d.not_identifiable, left = verdict.conclude(
        d.causes,
        rejected,
        ident,
        d.nmse_after,
        (left_nmse, noise),
        d.evidence["after"],
        tuple(d.joints),
        problem_path,
        engine.filter_hz,
        len(d.rounds),
    )
    d.evidence["noise_nmse"] = noise.tolist()
    d.evidence["residual_nmse"] = left_nmse.tolist()
    d.evidence["beyond_noise"] = [d.joints[j] for j in left]
    d.warnings += warnings(d, ident)


def warnings(d: Diagnosis, ident: identifiability.Identifiability) -> list[ResultWarning]:
    """What the verdict adds to the warnings: gains measured on a repeat of the training motion, too few independent
    motions, a named cause implausible in the final model or unconfirmed where another trial was there to confirm it."""
    out = []
    if not ident.held_out_distinct:
        out.append(
            ResultWarning(
                "gains_unverified",
                f"the held-out part ({ident.scored_on}) repeats the training motion (median distance "
                f"{ident.held_out_distance_rad:.3g} rad from the nearest training stretch, within "
                f"{identifiability.REPEAT_RAD:g}) and no distinct trial was given: every gain below is measured on "
                "the motion that trained it and is unverified; record a distinct trial (`ident-opt excite`) and give "
                "it as --test-data",
            )
        )
    if not ident.full_rank:
        out.append(
            ResultWarning(
                "few_independent_motions",
                f"the training motion holds {ident.independent_motions} independent motions for {ident.n_joints} "
                f"joints: {'; '.join(ident.undetermined())}. A cause on those joints is not identifiable from it",
            )
        )
    for c in d.causes:
        if not c.get("plausible", True):
            out.append(
                ResultWarning(
                    "implausible_cause",
                    f"{c['cause']} is named, yet in the final model it fails its plausibility: "
                    + "; ".join(c["plausibility"]["reasons"]),
                )
            )
    tried = [t for t in d.confirmation.get("trials", []) if "causes" in t]
    unconfirmed = [c["cause"] for c in d.causes if c.get("confirmed_on") is None]
    if unconfirmed and d.causes:
        where = (
            f"on {', '.join(t['trial'] for t in tried)}, which neither trained nor selected it"
            if tried
            else "no other trial distinct from the training motion was given"
        )
        out.append(
            ResultWarning(
                "unconfirmed",
                f"{', '.join(unconfirmed)}: the gain is not confirmed ({where}); a cause is confirmed when it still "
                "gains on a trial that neither trained nor selected it",
            )
        )
    return out
