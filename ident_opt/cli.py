"""The `ident-opt` command line: one subcommand per job, each in `ident_opt/commands/<name>.py`.

Exit status: 0 success, 2 bad input or usage (a one-paragraph message, no traceback), 1 anything else.
Each command module is thin: arguments, then `run()` = load, call the stage function the API exports (`ident_opt`),
call its report writer (`ident_opt.report`), return the exit status. Only the command being run is imported (its flags
are added to the parser then): `ident-opt --help` lists the commands without importing any of them.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import signal
import sys
import threading
from collections.abc import Iterable, Iterator

from ident_opt import __version__, outputs
from ident_opt.arguments import validate_numbers
from ident_opt.errors import InputError

#: Flags (by dest) that name input files, and output files; `--out` is a file for these subcommands, else a folder.
INPUT_FLAGS = (
    *("problem", "data", "test_data", "calibrate", "parameters", "real", "trajectory_file"),
    *("nominal", "against"),  # diagnose's identified arm, compare's other run
)
OUTPUT_FLAGS = ("json", "final")
FILE_OUT = ("simulate", "excite", "export")

#: What `ident-opt --help` says first.
DESCRIPTION = (
    "Identify the dynamics of robot arms from measured data (any number of joints), find what the model still gets "
    "wrong, and ship the result: generated C for the controller, a URDF or MJCF for other tools.\n\n"
    "Start with `ident-opt check --problem P` on a new robot's logs, then `compare` (which fit to trust), "
    "`identify` (every model, tables and figures) and `codegen` or `export`. `ident-opt COMMAND --help` documents "
    "each command; docs/ has the problem file, data format and JSON contracts."
)
#: subcommand -> one-line help. Each lives in ident_opt.commands.<name> with add_arguments() and run().
COMMANDS = {
    "identify": "identify every model on the problem's data; write tables and figures",
    "compare": "constrained vs OLS vs datasheet parameters, with standard errors and consistency checks",
    "diagnose": "what the model gets wrong, why, the extended model and its held-out gain",
    "simulate": "write a measured-style trial from the built-in simulator (optional hidden effects)",
    "codegen": "generate, compile and check C code for embedded torque prediction",
    "online": "offline fit, then exact sequential updates on the rest of the trial (or a stream)",
    "check": "validate a problem file and its data; summarise each trial",
    "audit": "the paper audit: its datasheet model under both conventions against its own fit",
    "excite": "design the trajectory to run next: a Fourier excitation optimised by IPOPT within [limits]",
    "calibrate": "how close the simulator's default trial is to a real one (residual size, spectrum, strain)",
    "export": "write the identified arm as a robot description: URDF (with a JSON sidecar) or MuJoCo MJCF",
    "fleet": "every robot of a fleet identified every day on Dask, and what changed (wear, payload, drive), named",
    "detect": "contacts and collisions: an external-torque observer with calibrated thresholds, its alarms per trial",
}


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors go through the same exit-2 path as bad input."""

    def error(self, message: str):
        self.print_usage(sys.stderr)
        raise InputError(f"{self.prog}: {message}")


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser: every subcommand by name and help; the flags of those in `commands` (None: all), whose
    modules (`ident_opt.commands.<name>`) are imported to add them."""
    parser = _Parser(prog="ident-opt", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, summary in COMMANDS.items():
        p = sub.add_parser(
            name, help=summary, description=summary, formatter_class=argparse.RawDescriptionHelpFormatter
        )
        if commands is None or name in commands:
            module = _module(name)
            p.description = (module.__doc__ or summary).strip()
            module.add_arguments(p)
            validate_numbers(name, p)
    return parser


def check_outputs(args: argparse.Namespace) -> None:
    """Before any work: every output path usable, none of them an input file (`outputs`)."""
    for dest in INPUT_FLAGS:
        value = getattr(args, dest, None)
        outputs.declare_inputs([value] if isinstance(value, str) else value or [])
    for dest in (*OUTPUT_FLAGS, "out"):
        value = getattr(args, dest, None)
        if isinstance(value, str) and not value.strip():
            raise InputError(f"--{dest}: an empty path; give a file or folder name")
    for dest in OUTPUT_FLAGS:
        if getattr(args, dest, None):
            outputs.check_file_output(getattr(args, dest), "--" + dest)
    out = getattr(args, "out", None)
    if out and args.command in FILE_OUT:
        outputs.check_file_output(out, "--out")
    elif out:
        outputs.check_folder_output(out, "--out")


def _module(name: str):
    return importlib.import_module(f"ident_opt.commands.{name}")


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: handled as an interrupt (the run's outputs rolled back), reported as termination."""


def _terminate(signum, frame) -> None:
    raise Terminated


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises `Terminated` in the main thread while a command runs (start-up included), so that the run
    ends with a message and rolls back what it wrote; the previous handler is put back after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status (SIGTERM: 143, Ctrl-C: 130)."""
    for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 is printed with "?", not a traceback
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")
    try:
        with _sigterm_as_interrupt():
            argv = sys.argv[1:] if argv is None else list(argv)
            parser = build_parser(argv[:1])  # the command comes first: only its module is imported
            args = parser.parse_args(argv)
            if args.command is None:
                parser.print_help()
                return 2
            with outputs.run():
                check_outputs(args)
                return int(_module(args.command).run(args) or 0)
    except InputError as exc:
        print(f"ident-opt: error: {exc}", file=sys.stderr)
        return 2
    except Terminated:
        print("ident-opt: terminated (SIGTERM); nothing it was writing was left behind", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print("ident-opt: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
