"""`ident-opt online`: offline fit on the first part of the trial, then exact sequential updates on the rest.

Replay (default): every model (rr, the nominal ones dm, dm_…, pbr, cpbr, each with and without its GMR residual;
`adaptation.identifier.model_keys`) is fitted on the first `[split] train_fraction` of the trial in time; the rest is
replayed sample by sample in time order, each sample first predicted (one step ahead) and then folded in (RR and PBR
re-solve exactly on all data seen, CPBR too where its estimator has an exact online form, else from scratch every
--consistent-every samples; DM stays fixed; GMRs follow by the mean-only consistency transform). Writes the
online-vs-frozen error table, the parameter trajectories (figure), the initial and final parameters, checks the online
parameters against from-scratch batch solves at random steps and, on an n-joint arm, measures how far PBR's exact
sign-bounded parameters are from the consistent re-solves.

Streaming (`--stream`): the same offline fit, then samples from standard input (CSV with a header, or JSON
lines), one JSON line out per sample, each with the contact observer's `tau_ext` and `alarm` (`docs/contacts.md`:
nothing is learnt while an alarm or its settling lasts); see `ident_opt.adaptation.stream`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ident_opt.adaptation.estimator import CONSISTENT_EVERY
from ident_opt.adaptation.replay import online, online_parts
from ident_opt.adaptation.start import serving_identifier
from ident_opt.adaptation.stream import StreamOptions, serve
from ident_opt.commands.common import (
    add_components,
    add_estimator_flag,
    add_problem_arguments,
    add_switches,
    load,
    output_dir,
    write_json,
)
from ident_opt.contact.watch import stream_watch
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import choose
from ident_opt.outputs import shown
from ident_opt.report import online as report
from ident_opt.warnings import ResultWarning

#: Largest accepted --consistent-every.
MAX_EVERY = 10**7


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's, else results/)")
    add_switches(parser, {"--stream": "serve samples from standard input (CSV with header or JSON lines) instead"})
    parser.add_argument(
        "--model",
        default="pbr+gmr",
        help="model served by --stream: rr, dm, dm_physical, pbr or cpbr, optionally +gmr (default pbr+gmr)",
    )
    parser.add_argument(
        "--snapshot-every",
        type=int,
        default=1000,
        metavar="N",
        help="--stream: a parameter snapshot line every N updates (0: none; default 1000)",
    )
    parser.add_argument("--final", metavar="F", help="--stream: also write the final parameters to F (JSON)")
    _contact_flags(parser)
    parser.add_argument(
        "--outlier-k",
        type=float,
        default=10.0,
        metavar="K",
        help="--stream: a sample whose residual is beyond K robust standard deviations updates nothing "
        "(0: no test; default 10)",
    )
    add_switches(
        parser,
        {
            "--no-guard": "--stream: no GMR extrapolation guard (the residual is used even outside its training "
            "support)",
            "--cross-covariance": "also apply the first-order cross-covariance update to the GMRs",
            "--no-progress": "no progress bars",
        },
    )
    parser.add_argument(
        "--consistent-every",
        type=int,
        default=CONSISTENT_EVERY,
        metavar="N",
        help="samples between two from-scratch re-solves of a consistent fit that has no exact online form "
        f"(an n-joint arm's cpbr; default {CONSISTENT_EVERY})",
    )
    parser.add_argument(
        "--checks",
        type=int,
        default=10,
        metavar="K",
        help="random steps at which the online parameters are checked against a batch "
        "re-solve (plus the last step; default 10)",
    )
    add_estimator_flag(parser, "the fit cpbr starts from and follows")
    add_components(parser)


def _contact_flags(parser: argparse.ArgumentParser) -> None:
    """--no-contact and --learning-lag: the stream's contact observer (`docs/contacts.md`)."""
    add_switches(
        parser,
        {"--no-contact": "--stream: no contact observer (lines carry no tau_ext, alarm; every sample is learnt)"},
    )
    parser.add_argument(
        "--learning-lag",
        type=_lag,
        default=0,
        metavar="N",
        help="--stream: learn a sample N samples after it came, so that an alarm drops a push's onset too; 'auto': "
        "the persistence plus three observer time constants (default 0: at once, as the replay)",
    )


def _lag(text: str) -> int | str:
    """--learning-lag: "auto" or a whole number of samples ≥ 0."""
    if text.strip() == "auto":
        return "auto"
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 'auto' or a whole number of samples ≥ 0, got {text!r}")
    return value


def run(args: argparse.Namespace) -> int:
    """Check the flags, load, split in time; serve the stream or replay and write the report."""
    if args.snapshot_every < 0:
        raise InputError("--snapshot-every must be ≥ 0")
    if args.checks < 0:
        raise InputError("--checks must be ≥ 0")
    if not args.outlier_k >= 0:
        raise InputError("--outlier-k must be ≥ 0")
    if args.components is not None and args.components < 1:
        raise InputError("--components must be ≥ 1")
    if not 1 <= args.consistent_every <= MAX_EVERY:
        raise InputError(f"--consistent-every must be an integer in [1, {MAX_EVERY}], got {args.consistent_every}")
    loaded = load(args, "online")
    problem, trial = loaded.problem, loaded.train
    if args.estimator is not None:  # an unknown one fails before any work
        choose(problem, [], model=problem.robot.model(()), estimator=args.estimator, command="online")
    if args.stream:
        return _stream(args, problem, trial)
    out = output_dir(args, problem)
    result = online(
        problem,
        trial,
        estimator=args.estimator,
        cross_covariance=args.cross_covariance,
        checks=args.checks,
        components=args.components,
        every=args.consistent_every,
        progress=not args.no_progress,
    )
    _starts_from(result.choice)
    data = report.payload(result, problem, trial.source, args.cross_covariance)
    data["warnings"] += [w.as_dict() for w in unused_test_data(args)]
    report.write(result, data, out, args.json)
    print(report.terminal(data, out))
    return 0


def _stream(args: argparse.Namespace, problem, trial) -> int:
    """The offline fit of --model on the offline part, then samples from standard input until its end or a
    signal."""
    train, _ = online_parts(problem, trial)
    choice = choose(problem, [train], model=problem.robot.model(()), estimator=args.estimator, command="online")
    _starts_from(choice)
    start, ident = serving_identifier(
        args.model,
        problem,
        train,
        args.components,
        args.cross_covariance,
        guard=not args.no_guard,
        every=args.consistent_every,
        choice=choice,
    )
    options = StreamOptions.for_problem(problem, train, args.outlier_k)
    if not args.no_contact:  # every line: tau_ext and alarm; no learning from a push
        options.watch = stream_watch(problem, [train], choice)
        lag = args.learning_lag
        options.learning_lag = options.watch.thresholds.learning_lag if lag == "auto" else int(lag)
    print(
        f"ident-opt online --stream: {args.model} ready (offline fit on {train.n} samples); reading samples",
        file=sys.stderr,
        flush=True,
    )
    serve(
        ident,
        start.names,
        getattr(sys.stdin, "buffer", sys.stdin),  # bytes: invalid UTF-8 is a reported line, not a crash
        sys.stdout,
        sys.stderr,
        args.snapshot_every,
        on_final=(lambda record: write_json(args.final, record)) if args.final else None,
        options=options,
    )
    return 0


def _starts_from(choice) -> None:
    """The fit cpbr starts from and why, on the terminal."""
    print(f"ident-opt online: cpbr starts from the {choice.estimator} fit ({choice.why})", file=sys.stderr)


def unused_test_data(args: argparse.Namespace) -> list[ResultWarning]:
    """A warning when --test-data is given: the replay streams the later part of its own trial (the problem's
    split) and scores nothing else, so a held-out trial would otherwise be read and silently left unused."""
    given = getattr(args, "test_data", None) or []
    if not given:
        return []
    names = ", ".join(shown(Path(p)) for p in given)
    return [
        ResultWarning(
            "test_data_unused",
            f"--test-data {names}: online replays the later part of the trial it trains on (the problem's "
            "[split]) and scores no held-out trial; to replay that trial, give it with --data",
        )
    ]
