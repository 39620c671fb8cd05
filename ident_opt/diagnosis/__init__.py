"""Diagnosis: what the nominal model gets wrong, which catalogue cause explains it, the extended model and its
held-out gain (`docs/effects.md`).

One loop (`rounds.diagnose_trial`: the four questions, the rounds, the naming rules) talks to a declared engine
(`engine.Engine`) of the robot's kind: `planar.PlanarEngine` (grouped π, flexible links) or `chain.ChainEngine`
(an arm of n joints from a URDF), each with its candidate families (the causes' own, declared in
`ident_opt.effects`). `split` prepares the training and held-out parts, `evidence` reads the residual's features,
`scoring` holds the held-out score and the naming rule, `result` the `Diagnosis` and its JSON, `hidden` the
hidden-effect trials of the tests and benchmarks. Believable on real robots (`docs/effects.md`): `identifiability` (can
these data tell), `plausibility` (the one rule every candidate picked must pass), `confirm` (a named cause gains on a
trial that neither trained nor selected it), `verdict` (causes, none, mismatch, not_identifiable), `believe` (where
the loop applies them). The report is `ident_opt.report.diagnosis`."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from ident_opt.data.dataset import Dataset
from ident_opt.data.loader import held_out_overlap
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.diagnosis import identifiability
from ident_opt.diagnosis.nominal import NominalFit, read_nominal
from ident_opt.diagnosis.result import Diagnosis
from ident_opt.diagnosis.rounds import diagnose_trial
from ident_opt.diagnosis.split import held_out, split
from ident_opt.effects import CATALOGUE
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import Choice, checked_choice, choose
from ident_opt.outputs import shown
from ident_opt.problem.spec import Problem
from ident_opt.warnings import ResultWarning

#: The catalogue's cause names, `none` first.
CAUSES = ("none", *CATALOGUE)

__all__ = [
    "CAUSES",
    "Diagnosis",
    "NominalFit",
    "diagnose",
    "diagnose_trial",
    "read_nominal",
    "rigid_choice",
    "scored_trial",
]


def _path(value: object, argument: str) -> Path:
    """`value` as a path, else an InputError naming `argument`."""
    if not isinstance(value, str | os.PathLike) or not str(value):
        raise InputError(f"diagnose: {argument} must be a path to a compare JSON or an export sidecar, got {value!r}")
    return Path(value)


def diagnose(
    problem: Problem,
    training: Sequence[Dataset],
    testing: Sequence[Dataset] = (),
    *,
    estimator: str | None = None,
    rigid_fit: Choice | None = None,
    nominal: str | os.PathLike | NominalFit | None = None,
    progress: bool = False,
) -> Diagnosis:
    """`ident-opt diagnose`: the first of `training` trains; the first of `testing` (else the second of `training`)
    is held out, or without one the last part of the training trial in time (the problem's `[split]
    train_fraction`). The rigid fit is the recommended fit on the training part (`rigid_choice`) unless `estimator`
    (a fit's name) or `rigid_fit` (a `Choice` made already, e.g. `comparison.choice`) says otherwise; the torque is
    low-passed like the derivatives (the problem's `derivative_cutoff_hz`). Warnings: the trials' own (a held-out
    trial that trains), the evidence behind the rigid fit's, the diagnosis's. Bad arguments (trials not of the
    arm's joints or not finite, a rigid fit that is not a `Choice`) raise an InputError naming them.

    `nominal`: an identified arm in place of the problem's datasheet (a `compare --json` or an `export` sidecar, or
    a `NominalFit` read already; `estimator` picks the compare JSON's fit, default its recommended): "what changed
    since this model?" (`nominal.read_nominal`); the JSON then calls that baseline "nominal"."""
    checked_problem(problem, "diagnose").require("diagnose")
    training = checked_trials(problem, training, "diagnose", "training", fit=True)
    testing = checked_trials(problem, testing, "diagnose", "testing", required=False)
    rigid_fit = checked_choice(rigid_fit, problem.robot, "rigid_fit", "diagnose")
    if rigid_fit is not None and estimator is not None:
        raise InputError("diagnose: give estimator (a fit's name) or rigid_fit (a Choice), not both")
    if nominal is not None and not isinstance(nominal, NominalFit):
        nominal = read_nominal(_path(nominal, "nominal"), estimator)
    train = training[0]
    others = [t for t in [*testing, *training[1:]] if t is not train]
    unseen, others, switched = scored_trial(problem, train, others)
    choice = rigid_fit if rigid_fit is not None else rigid_choice(problem, train, unseen, estimator)
    result = diagnose_trial(
        problem.robot,
        train,
        unseen,
        train_fraction=problem.split.train_fraction,
        progress=progress,
        torque_filter_hz=problem.data.derivative_cutoff_hz,
        rigid_fit=choice,
        others=others,
        problem_path=shown(problem.path) if getattr(problem, "path", None) else None,
        nominal_fit=nominal,
    )
    result.warnings = [*held_out_overlap(training, testing), *choice.warnings, *switched, *result.warnings]
    return result


def scored_trial(
    problem: Problem, train: Dataset, others: Sequence[Dataset]
) -> tuple[Dataset | None, list[Dataset], list[ResultWarning]]:
    """(the held-out trial, the other trials left to confirm the causes on, a warning when the first was passed
    over): the first of `others` (None: the last part of `train` in time), unless its joint paths — or the held-out
    part's — repeat the training motion (`identifiability.held_out_distance` within `REPEAT_RAD`) while another of
    `others` is a motion of its own: the gains are then scored on that one (the first such), and said so."""
    default = others[0] if others else None
    if default is None:
        idx_train, idx_test, _ = held_out(train, problem.split.train_fraction)
        part, fitted = train.subset(idx_test), train.subset(idx_train)
    else:
        part, fitted = default, train
    distance = identifiability.held_out_distance(part, fitted)
    if distance > identifiability.REPEAT_RAD:
        return default, list(others[1:]), []
    for k, t in enumerate(others):
        if t is default:
            continue
        d = identifiability.held_out_distance(t, train)
        if d > identifiability.REPEAT_RAD:
            rest = [o for i, o in enumerate(others) if i != k]
            was = shown(default.source) if default is not None else f"the held-out part of {shown(train.source)}"
            return (
                t,
                rest,
                [
                    ResultWarning(
                        "held_out_repeats_training",
                        f"{was} repeats the training motion (median distance {distance:.3g} rad from the nearest "
                        f"training stretch, within {identifiability.REPEAT_RAD:g}): its gains would be measured on "
                        f"the motion that trained them, so the gains are scored on {shown(t.source)} instead "
                        f"({d:.3g} rad from it)",
                    )
                ],
            )
    return default, list(others[1:]), []


def rigid_choice(
    problem: Problem, trial: Dataset, unseen: Dataset | None = None, estimator: str | None = None
) -> Choice:
    """The rigid fit's choice (`fitting.recommend.choose`) on the part of the data the diagnosis trains on: all of
    `trial` when a held-out `unseen` trial is given, else its first `train_fraction` in time (`split.split`)."""
    train = split(trial, unseen, problem.split.train_fraction)[0]
    return choose(problem, [train], estimator=estimator, command="diagnose")
