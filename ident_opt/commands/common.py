"""What every subcommand shares: the standard flags, loading the problem and its trials, writing outputs."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ident_opt import outputs, report
from ident_opt.errors import InputError
from ident_opt.problem import load_problem
from ident_opt.report import write_json  # noqa: F401  (every command's --json goes through it)


def add_problem_arguments(parser: argparse.ArgumentParser, data: bool = True, json_out: bool = True) -> None:
    """--problem, --data, --json and the bad-row flags, named the same in every subcommand."""
    parser.add_argument("--problem", required=True, metavar="P", help="problem file (problems/*.toml)")
    if data:
        parser.add_argument(
            "--data",
            metavar="D",
            action="append",
            help="a training trial, instead of the problem's [data] trials; repeatable (statistics add up)",
        )
        parser.add_argument(
            "--test-data",
            metavar="T",
            action="append",
            help="a held-out trial, instead of the problem's; repeatable (each is scored, and their pool)",
        )
    if json_out:
        parser.add_argument("--json", metavar="F", help="also write a machine-readable result to F")
    add_switches(
        parser,
        {
            "--allow-implausible": "proceed when values look like the wrong unit (e.g. |q| > 100 rad)",
            "--drop-invalid": "skip rows with non-numeric/NaN/inf cells or non-increasing t (the count is reported)",
        },
    )


def add_switches(parser: argparse.ArgumentParser, switches: dict[str, str]) -> None:
    """On/off flags (off unless given), flag -> help, added in this order."""
    for flag, text in switches.items():
        parser.add_argument(flag, action="store_true", help=text)


def add_components(parser: argparse.ArgumentParser) -> None:
    """--components K, the number of GMR components, the same in every subcommand that fits a GMR."""
    parser.add_argument(
        "--components", type=int, metavar="K", help="GMR components (default: the problem's [residual] setting)"
    )


@dataclass
class Loaded:
    """A problem with its trials: `training` (every --data, or the problem's) and `testing` (every --test-data, or
    the problem's). `train`/`unseen` are the first of each (for a command that takes one trial of each); with no
    held-out trial, `unseen` is the second training trial (the legacy reading of a repeated --data)."""

    problem: Any
    training: list = field(default_factory=list)
    testing: list = field(default_factory=list)

    @property
    def trials(self) -> list:
        """Every trial, training first."""
        return [*self.training, *self.testing]

    @property
    def train(self):
        return self.training[0]

    @property
    def unseen(self):
        if self.testing:
            return self.testing[0]
        return self.training[1] if len(self.training) > 1 else None


def problem_for(args: argparse.Namespace, command: str, path_flag: str = "problem"):
    """The problem file named by --problem (or `path_flag`), once `command` is known to serve its arm
    (`Problem.require`: an InputError, exit 2, before any work)."""
    problem = load_problem(getattr(args, path_flag))
    problem.require(command)
    return problem


#: What --estimator's absence means in the commands that fit (`fitting.recommend.choose`).
RECOMMENDED = (
    "the recommended fit, chosen from the data's own evidence: the arm's physically consistent fit, or the robust "
    "one when noise biases it"
)


def add_estimator_flag(parser: argparse.ArgumentParser, what: str, default: str = RECOMMENDED) -> None:
    """--estimator NAME: `what` is fitted with, among the arm's fits (checked by `fitting.recommend.choose`, which
    names the arm's fits when NAME is not one of them); `default` says what the command does without it."""
    parser.add_argument("--estimator", metavar="NAME", help=f"{what}, among the arm's fits (default: {default})")


def add_progress_flag(parser: argparse.ArgumentParser) -> None:
    """--no-progress: no progress bars (for logs and CI)."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def load(
    args: argparse.Namespace, command: str, min_samples: int | None = None, fit: bool = True, problem=None
) -> Loaded:
    """The problem file (`problem` when the command read it already) and its trials (`api.load_trials`: --data and
    --test-data, else the problem's [data] trials or its [simulate] section), once `command` is known to serve its
    arm. `fit`: the trials will be fitted, so a joint whose torque never varies is an error (else a warning)."""
    if problem is None:
        problem = problem_for(args, command)
    else:
        problem.require(command)
    check_trial_names(args)
    from ident_opt import api  # here: the API imports every stage, which a command reading no trials (fleet) skips

    training, testing = api.load_trials(
        problem,
        getattr(args, "data", None),
        getattr(args, "test_data", None),
        allow_implausible=args.allow_implausible,
        drop_invalid=args.drop_invalid,
        min_samples=min_samples,
        fit=fit,
    )
    for trial in [*training, *testing]:
        if trial.dropped_rows:
            print(f"note: {trial.source}: dropped {trial.dropped_rows} invalid row(s)", file=sys.stderr)
    return Loaded(problem, training, testing)


def check_trial_names(args: argparse.Namespace) -> None:
    """InputError naming --data / --test-data when one of their paths cannot exist (a name over NAME_MAX, a path
    over PATH_MAX): said as such, where looking it up would raise ENAMETOOLONG."""
    for flag in ("data", "test_data"):
        for path in getattr(args, flag, None) or []:
            outputs.check_length(path, "--" + flag.replace("_", "-"), reading=True)


def output_dir(args: argparse.Namespace, problem, default: Path | None = None, indexed: bool = True) -> Path:
    """--out, else the problem's [output] dir, else `default` (the project's results/). `indexed`: the reports
    there are indexed in its README.md (`report.record`), whose manifests and README are checked now."""
    out = getattr(args, "out", None)
    path = Path(out) if out else (problem.output_dir or default or Path("results"))
    outputs.check_folder_output(path, "--out")
    if indexed:
        report.check_folder(path)
    outputs.watch_folder(path)  # created here, so a failed run removes it again
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{path}: cannot create the output folder ({exc.strerror})") from None
    if not os.access(path, os.W_OK):
        raise InputError(f"{path}: the output folder is not writable")
    return path
