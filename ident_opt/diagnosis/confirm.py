"""Confirmation across trials (`docs/effects.md`, "Confirmation"): a named cause must still gain on a trial that
neither trained it nor selected it (the held-out part did), when there is one.

Each cause of the chain is judged as it was named: the model extended with it and every cause before it against the
model before it (the previous cause's, or the nominal model the first was found against), both as fitted on the
training part, on the other trial read as the held-out part is (`Engine.other`: filtered, decimated and labelled
alike). It is confirmed there when it passes the naming rule on that trial: a penalised log-likelihood gain > 0 and,
on some joint, the margin of the MSE and of the torque variance (`scoring.clears_margin`). A trial whose joint
paths repeat the training motion (`identifiability.REPEAT_RAD`) confirms nothing and is skipped, said so.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import identifiability, scoring
from ident_opt.errors import InputError
from ident_opt.outputs import shown

#: Most other trials a chain is confirmed on (the first distinct ones, in the problem's order).
MOST_TRIALS = 3


def _k(v, rigid_parameters: int) -> int:
    """The fitted parameters of a model version (`result.Fitted`), a refitted π's counted."""
    own = v.cand.n_added if v is not None and v.cand is not None else 0
    return own + (rigid_parameters if v is not None and v.baseline == "rigid_fit" else 0)


def confirm(engine, chain: list[dict], others: Sequence[Dataset], baseline: str) -> tuple[list[str | None], dict]:
    """(confirmed_on per cause of `chain` — the first other trial it gains on, or None —, what was found: per trial its
    distance from the training motion, whether it was used, each cause's score there, or why it was skipped).
    `chain`: the rounds' chain entries (each with its `fitted` version); `baseline`: the nominal model the first cause
    was found against."""
    confirmed: list[str | None] = [None] * len(chain)
    found: dict = {"trials": []}
    if not chain or not others:
        return confirmed, found
    train = engine.parts.train
    rigid = engine.nominal.rigid_parameters
    used = 0
    for trial in others:
        name = shown(trial.source)
        distance = identifiability.held_out_distance(trial, train)
        entry = {"trial": name, "distance_rad": distance}
        if distance <= identifiability.REPEAT_RAD:
            entry["skipped"] = "its joint paths repeat the training motion"
            found["trials"].append(entry)
            continue
        if used >= MOST_TRIALS:
            break
        used += 1
        try:
            ds, _, labels = engine.other(trial)
        except (ValueError, InputError) as exc:  # a trial the engine cannot read as held out is said, not fatal
            entry["skipped"] = f"it cannot be read as a held-out part ({exc})"
            found["trials"].append(entry)
            continue
        var = np.var(ds.tau, axis=0)
        before_pred = engine.nominal_prediction(baseline, ds)
        before, k_before = scoring.mse(ds.tau, before_pred, labels), rigid if baseline == "rigid_fit" else 0
        scores = []
        for i, c in enumerate(chain):
            v = c["fitted"]
            after = scoring.mse(ds.tau, v.cand.predict(ds), labels)
            k_after = _k(v, rigid)
            gain = scoring.score(before, after, ds.n, k_after - k_before)
            ok = scoring.clears_margin(before, after, gain, var, engine.margin_variance)
            scores.append({"cause": c["cause"], "score": gain, "gains": bool(ok), "nmse_after": (after / var).tolist()})
            if ok and confirmed[i] is None:
                confirmed[i] = name
            before, k_before = after, k_after
        entry["causes"] = scores
        entry["nmse_before"] = (scoring.mse(ds.tau, before_pred, labels) / var).tolist()
        found["trials"].append(entry)
    return confirmed, found
