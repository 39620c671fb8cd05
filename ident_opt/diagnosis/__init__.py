"""Diagnosis: what the nominal model gets wrong, which catalogue cause explains it, the extended model and its
held-out gain (`docs/effects.md`).

One loop (`rounds.diagnose_trial`: the four questions, the rounds, the naming rules) talks to a declared engine
(`engine.Engine`) of the robot's kind: `planar.PlanarEngine` (grouped π, flexible links) or `chain.ChainEngine`
(an arm of n joints from a URDF), each with its candidate families (the causes' own, declared in
`ident_opt.effects`). `split` prepares the training and held-out parts, `evidence` reads the residual's features,
`scoring` holds the held-out score and the naming rule, `result` the `Diagnosis` and its JSON, `hidden` the
hidden-effect trials of the tests and benchmarks. The report is `ident_opt.report.diagnosis`."""

from __future__ import annotations

from collections.abc import Sequence

from ident_opt.data.dataset import Dataset
from ident_opt.data.loader import held_out_overlap
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.diagnosis.result import Diagnosis
from ident_opt.diagnosis.rounds import diagnose_trial
from ident_opt.diagnosis.split import split
from ident_opt.effects import CATALOGUE
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import Choice, checked_choice, choose
from ident_opt.problem.spec import Problem

#: The catalogue's cause names, `none` first.
CAUSES = ("none", *CATALOGUE)

__all__ = ["CAUSES", "Diagnosis", "diagnose", "diagnose_trial", "rigid_choice"]


def diagnose(
    problem: Problem,
    training: Sequence[Dataset],
    testing: Sequence[Dataset] = (),
    *,
    estimator: str | None = None,
    rigid_fit: Choice | None = None,
    progress: bool = False,
) -> Diagnosis:
    """`ident-opt diagnose`: the first of `training` trains; the first of `testing` (else the second of `training`)
    is held out, or without one the last part of the training trial in time (the problem's `[split]
    train_fraction`). The rigid fit is the recommended fit on the training part (`rigid_choice`) unless `estimator`
    (a fit's name) or `rigid_fit` (a `Choice` made already, e.g. `comparison.choice`) says otherwise; the torque is
    low-passed like the derivatives (the problem's `derivative_cutoff_hz`). Warnings: the trials' own (a held-out
    trial that trains), the evidence behind the rigid fit's, the diagnosis's. Bad arguments (trials not of the
    arm's joints or not finite, a rigid fit that is not a `Choice`) raise an InputError naming them."""
    checked_problem(problem, "diagnose").require("diagnose")
    training = checked_trials(problem, training, "diagnose", "training", fit=True)
    testing = checked_trials(problem, testing, "diagnose", "testing", required=False)
    rigid_fit = checked_choice(rigid_fit, problem.robot, "rigid_fit", "diagnose")
    if rigid_fit is not None and estimator is not None:
        raise InputError("diagnose: give estimator (a fit's name) or rigid_fit (a Choice), not both")
    train = training[0]
    unseen = testing[0] if testing else (training[1] if len(training) > 1 else None)
    choice = rigid_fit if rigid_fit is not None else rigid_choice(problem, train, unseen, estimator)
    result = diagnose_trial(
        problem.robot,
        train,
        unseen,
        train_fraction=problem.split.train_fraction,
        progress=progress,
        torque_filter_hz=problem.data.derivative_cutoff_hz,
        rigid_fit=choice,
    )
    result.warnings = [*held_out_overlap(training, testing), *choice.warnings, *result.warnings]
    return result


def rigid_choice(
    problem: Problem, trial: Dataset, unseen: Dataset | None = None, estimator: str | None = None
) -> Choice:
    """The rigid fit's choice (`fitting.recommend.choose`) on the part of the data the diagnosis trains on: all of
    `trial` when a held-out `unseen` trial is given, else its first `train_fraction` in time (`split.split`)."""
    train = split(trial, unseen, problem.split.train_fraction)[0]
    return choose(problem, [train], estimator=estimator, command="diagnose")
