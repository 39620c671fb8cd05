"""Problem files (`problems/*.toml`): which robot, which data, and how to identify it.

The `[robot]` section is a contract, documented in `docs/problem-files.md` (datasheet values as printed:
motor-side friction and rotor inertia, everything else joint-side, SI units; or a URDF). The other sections
are documented there too; every key has a default, and an unknown key is an error so that a typo never falls
back silently to a default. Paths are relative to the problem file.

`load_problem` reads and checks a file; the parsed sections are the dataclasses of `ident_opt.problem.spec`.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import replace
from pathlib import Path

from ident_opt import outputs
from ident_opt.errors import InputError
from ident_opt.problem.robot import parse_planar
from ident_opt.problem.sections import (
    parse_data,
    parse_limits,
    parse_reference,
    parse_residual,
    parse_simulate,
    parse_split,
    relative,
)
from ident_opt.problem.spec import DataSpec, Limits, Problem, Reference, ResidualSpec, SimulateSpec, SplitSpec
from ident_opt.problem.table import LIMITS, Table
from ident_opt.problem.urdf import parse_urdf_robot

#: The largest problem file read [bytes]: the shipped ones are a few kB; a larger file is a wrong path (a log, an
#: image), read whole otherwise.
MAX_PROBLEM_BYTES = 10_000_000

__all__ = [
    "DataSpec",
    "Limits",
    "Problem",
    "Reference",
    "ResidualSpec",
    "SimulateSpec",
    "SplitSpec",
    "load_problem",
]


def load_problem(path: str | Path) -> Problem:
    """Read and validate a problem file; raise `InputError` naming the file and key on any fault."""
    path = Path(path)
    try:
        raw = tomllib.loads(read_problem_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not a valid TOML file ({exc})") from None
    except RecursionError:  # tomllib parses nested arrays and tables recursively
        raise InputError(f"{path}: not a problem file: arrays or tables nested too deeply to read") from None
    outputs.declare_inputs([path])  # before anything it names: an output onto this file is refused first
    top = Table(raw, "", path)
    base = path.resolve().parent
    name = top.take("name", str)
    robot = _robot(top.table("robot"))  # first: the sections below depend on the arm (its joints, its model)
    sections = {  # each section fills the `Problem` field of its name, read in this order
        "data": parse_data(top.table("data", required=False), base, robot.n_joints),
        "split": parse_split(top.table("split", required=False)),
        "residual": parse_residual(top.table("residual", required=False)),
    }
    optional = {  # the sections a file may leave out (their field is then None)
        "simulate": parse_simulate,
        "limits": lambda table: parse_limits(table, robot),
        "reference": lambda table: parse_reference(table, robot, base),
    }
    for key, parse in optional.items():
        sections[key] = parse(top.table(key)) if key in top.raw else None
    output = top.table("output", required=False)
    out_dir = output.take("dir", str, None)
    output.done()
    top.done()
    problem = Problem(
        name=name, path=path, robot=robot, output_dir=relative(base, out_dir) if out_dir else None, **sections
    )
    listed = [*problem.data.trials, *problem.data.train, *problem.data.test]
    for trial in listed:  # a name no file can have: the file's fault, said now (a look-up would raise)
        outputs.check_length(trial, f"{outputs.abbreviated(path)}: [data]", reading=True)
    outputs.declare_inputs(listed)  # every trial listed
    return problem


def read_problem_text(path: Path) -> str:
    """The text of the problem file `path`; an InputError naming it when it is missing, not a regular file (a folder,
    a pipe: opening one would block), too large to be a problem file (`MAX_PROBLEM_BYTES`), unreadable (its
    permissions, an I/O error) or not UTF-8."""
    outputs.check_length(path, reading=True)  # os.stat of a name too long raises, it does not say "missing"
    shown = outputs.abbreviated(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"{shown}: problem file not found") from None
    except OSError as exc:  # a folder on the way that cannot be searched, a loop of links
        raise InputError(f"{shown}: cannot read the problem file ({exc.strerror})") from None
    kind = outputs.mode_kind(mode)
    if kind is not None:
        raise InputError(f"{shown}: is {kind}, not a problem file; give the path of a .toml file")
    try:
        with open(path, "rb") as file:
            data = file.read(MAX_PROBLEM_BYTES + 1)
    except OSError as exc:  # PermissionError (mode 000 and not root), EIO
        raise InputError(f"{shown}: cannot read the problem file ({exc.strerror or type(exc).__name__})") from None
    if len(data) > MAX_PROBLEM_BYTES:
        raise InputError(f"{shown}: larger than {MAX_PROBLEM_BYTES // 1_000_000} MB, which no problem file is")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{shown}: not a valid TOML file (not UTF-8 text: byte {data[exc.start]:#04x} at offset {exc.start})"
        ) from None


def _robot(table: Table):
    """The arm the `[robot]` table describes: from a URDF when it names one, else the planar two-link arm; with
    `rated_payload` [kg], the most it is specified to carry (the diagnosis's plausibility of a payload), on any arm."""
    rated = table.positive("rated_payload", high=LIMITS["mass"]) if "rated_payload" in table.raw else None
    robot = parse_urdf_robot(table, table.path.resolve().parent) if "urdf" in table.raw else parse_planar(table)
    return robot if rated is None else replace(robot, rated_payload=rated)
