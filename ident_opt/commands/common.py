"""What every subcommand shares: the standard flags, loading the problem and its trials, writing outputs."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ident_opt import outputs, report
from ident_opt import simulator as simulate
from ident_opt.arm.base import ALL_COMMANDS
from ident_opt.data.dataset import fittable, load_dataset
from ident_opt.errors import InputError
from ident_opt.problem import load_problem
from ident_opt.report import write_json  # noqa: F401  (every command's --json goes through it)
from ident_opt.warnings import ResultWarning


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
    """A problem with its trials: `training` (every --data, or the problem's) and `testing` (every --test-data,
    or the problem's); `trials` is both, in that order. `train`/`unseen` are the first of each (for a command
    that takes one trial of each); with no held-out trial, `unseen` is the second training trial (the legacy
    reading of a repeated --data). `warnings`: what is doubtful about the trials themselves (a held-out trial that
    is a training trial, `held_out_overlap`): a command that scores held-out trials makes them part of its result
    (terminal, report, JSON `warnings`)."""

    problem: Any
    trials: list
    training: list = field(default_factory=list)
    testing: list = field(default_factory=list)
    warnings: list[ResultWarning] = field(default_factory=list)

    def __post_init__(self):
        if not self.training and not self.testing:  # built from one list: the first trains, the second is unseen
            self.training, self.testing = self.trials[:1], self.trials[1:2]

    @property
    def train(self):
        return self.training[0]

    @property
    def unseen(self):
        if self.testing:
            return self.testing[0]
        return self.training[1] if len(self.training) > 1 else None


def require(command: str, problem) -> None:
    """InputError (exit 2) when `command` does not serve the problem's arm (`Robot.serves`), before any work."""
    robot = problem.robot
    if command not in robot.serves:
        serving = ", ".join(c for c in ALL_COMMANDS if c in robot.serves)
        raise InputError(
            f"{command} supports two-joint problems only; {problem.path} describes {robot.described_as} "
            f"(the commands for this arm: {serving})"
        )


def load(
    args: argparse.Namespace, command: str, min_samples: int | None = None, fit: bool = True, problem=None
) -> Loaded:
    """The problem file (`problem` when the command read it already) and its data (from --data, the problem's
    [data] trials, or its [simulate] section), once `command` is known to serve its arm. `fit`: the trials will be
    fitted, so a joint whose torque never varies is an error (else a warning). The trials' own warnings are in
    `Loaded.warnings`, not printed: the command prints them with its result (and writes them in its report and
    JSON)."""
    problem = problem or load_problem(args.problem)
    require(command, problem)
    train, test = _trial_paths(args, problem)
    paths, n_train = train + test, len(train) or 1
    if not paths and problem.simulate is not None:
        paths = simulate.problem_trials(problem)  # generated on first use, cached
    if not paths:
        raise InputError(f"{problem.path}: no data: give --data D or list trials under [data] in the problem file")
    kwargs = {"allow_implausible": args.allow_implausible, "drop_invalid": args.drop_invalid}
    if min_samples is not None:
        kwargs["min_samples"] = min_samples
    outputs.declare_inputs(paths)
    trials = [load_dataset(p, problem.data, problem.robot, **kwargs) for p in paths]
    for trial in trials:
        if trial.dropped_rows:
            print(f"note: {trial.source}: dropped {trial.dropped_rows} invalid row(s)", file=sys.stderr)
        fittable(trial, fit)
    return Loaded(problem, trials, trials[:n_train], trials[n_train:], held_out_overlap(train, test))


def _trial_paths(args: argparse.Namespace, problem) -> tuple[list[Path], list[Path]]:
    """(training, held-out) files: every --data trains and every --test-data is held out; without --data the
    problem's [data] decides (`train`/`test`, or `trials`: the first trains, the second is held out)."""
    data = [Path(p) for p in (getattr(args, "data", None) or [])]
    test = [Path(p) for p in (getattr(args, "test_data", None) or [])]
    if data:
        return data, test
    return list(problem.data.training), test or list(problem.data.testing)


def held_out_overlap(train: list[Path], test: list[Path]) -> list[ResultWarning]:
    """A warning per held-out trial that is also a training trial (the same file, or a copy of the same bytes):
    its scores are then not held out."""
    found = []
    for held in test:
        same = next((t for t in train if _same_trial(t, held)), None)
        if same is not None:
            found.append(
                ResultWarning(
                    "held_out_is_training",
                    f"{held} (held out) is the training trial {same}: its scores measure the fit on its own data, "
                    "not on unseen data; hold out another trial",
                )
            )
    return found


def _same_trial(a: Path, b: Path) -> bool:
    """Whether two trial paths are one file (also through links) or two files with the same bytes."""
    try:
        if os.path.samefile(a, b):
            return True
        if a.is_file() and b.is_file() and a.stat().st_size == b.stat().st_size:
            return a.read_bytes() == b.read_bytes()
    except OSError:
        pass
    return False


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
