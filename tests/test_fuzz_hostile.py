"""Property-based fuzz (hypothesis) of the paths of issue 52: fleet layouts and the forms of --logs, the kinds of
output path, and the shapes of the Python API's arguments. The contract and the log are `tests.test_fuzz`'s (one JSON
line per case in IDENT_OPT_FUZZ_LOG, summed up by `python -m tests.test_fuzz LOG`), with these properties:

- `fleet-layout` (every case of `test_fuzz_fleet`): a small fleet tree (robots × days of tiny trials of one simulated
  fleet, made once) with hostile entries (links out of the tree and inside it, named pipes, non-UTF-8 and 255-byte
  names, empty and garbage files, a trial whose time step is 1e-300 s, nested folders, a robot with nothing
  readable), --logs as a path, relative, `file://`, `local://`, `simplecache::` or `zip://`, --out and --json
  sometimes inside the logs. What the command runs before any work and on its workers, in-process: the check of
  --out/--json against the logs, `layout.discover`, and per robot `tasks.choose`, `file_stats`, `day_stats`,
  `fit_day`, `baseline` and `scales`: an InputError or results with finite numbers, skip reasons on one short line
  that never quote the file outside the logs, nothing written, the logs unchanged.
- `fleet` (one case in `FULL_EVERY` of the same test): the whole `ident-opt fleet` on that tree (a local Dask cluster
  of one worker process: 5 to 15 s a run, too slow for every case, hence the scan above): exit 0 or 2, no traceback
  (the workers' output included: file descriptors 1 and 2 are captured), strict JSON, the logs unchanged (no new
  entry either), nothing written outside --out and --json, nothing at all on exit 2, the file outside the logs never
  quoted.
- `output-kinds`: check, compare, export, simulate, codegen and diagnose (on the planar arm or a 3-joint URDF arm)
  with one output (a file or a folder) that is new, an existing file or folder, a named pipe, a link to a pipe, to a
  file, to a folder or to nothing, /dev/null (or a link to it), inside a read-only folder, under a file, a name over
  255 bytes, a path over 4096, an input of the run (problem, data, URDF; also through a link), non-UTF-8, empty:
  exit 0 or 2, no traceback, inputs unchanged, a pipe, a device and a link to either still what they were, nothing
  half-written.
- `api`: `ident_opt.trial`, `fit`, `ArmFit.predict`, `load_trials`, `diagnose` and `export` with arguments of the
  wrong shape, rank or type, NaN or inf anywhere, lists, strings, None, dicts, bools, complex and object arrays,
  empty ones, out-of-range fit options and estimators of the wrong type: a value with finite numbers or an
  `ident_opt.errors.InputError` (any other exception fails), the arrays passed in (and the problem) unchanged.

Each case runs under `tests.test_fuzz.HANG_S` (SIGALRM: a hang is reported, not waited for). `make test` runs a small
share of each property (the `share` counts below, fixed cases); `make fuzz` runs IDENT_OPT_FUZZ_EXAMPLES random
cases of each (>= 800).
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import functools
import hashlib
import io
import json
import os
import shutil
import signal
import stat
import sys
import tempfile
import time
import traceback
import warnings
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ident_opt as iopt
from ident_opt import outputs
from ident_opt.cli import main
from ident_opt.errors import InputError
from tests.test_fuzz import CLEAN, FUZZ, HANG_S, PROBLEM, Hang, _alarm, _strict_text, _under, files, violations
from tests.test_fuzz_inputs import ARM3, DRIVES, motion
from tests.test_urdf_arm import TWISTED

ROOT = Path(__file__).resolve().parents[1]
LONG = bool(os.environ.get("IDENT_OPT_FUZZ_EXAMPLES"))
EXAMPLES = int(os.environ.get("IDENT_OPT_FUZZ_EXAMPLES", "0"))
LOG = os.environ.get("IDENT_OPT_FUZZ_LOG")


def share(ci: int) -> settings:
    """The fuzz settings with `ci` cases under `make test`, IDENT_OPT_FUZZ_EXAMPLES under `make fuzz`."""
    return settings(FUZZ, max_examples=EXAMPLES if LONG else ci)


def budget(ci: int, per_case_s: float):
    """pytest's time limit for a property of `ci` cases (or IDENT_OPT_FUZZ_EXAMPLES) at `per_case_s` seconds a case
    on average (the suite's 600 s otherwise stops a long run; each case has its own limit, `HANG_S`)."""
    return pytest.mark.timeout(max(600, int((EXAMPLES if LONG else ci) * per_case_s)))


# ---------------------------------------------------------------------------------------------- the harness
def log(outcome: dict) -> None:
    """One case's outcome into IDENT_OPT_FUZZ_LOG (`tests.test_fuzz.summary` reads it)."""
    if LOG:
        with open(LOG, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(outcome) + "\n")


def shown(arg: object, limit: int = 120) -> str:
    """An argument as the log shows it: at most about `limit` characters."""
    text = str(arg)
    return text if len(text) <= limit else f"{text[: limit - 20]}…({len(text)} chars)"


class Printed:
    """What a case printed: sys.stdout and sys.stderr, and file descriptors 1 and 2 (what the subprocesses it starts
    print: Dask's workers, the C compiler), in `text` after the block."""

    text = ""

    @contextlib.contextmanager
    def capture(self) -> Iterator[None]:
        sys.stdout.flush()
        sys.stderr.flush()
        buffer = io.StringIO()
        saved = [os.dup(1), os.dup(2)]
        with tempfile.TemporaryFile() as sink:
            try:
                os.dup2(sink.fileno(), 1)
                os.dup2(sink.fileno(), 2)
                with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
                    yield
            finally:
                with contextlib.suppress(ValueError, OSError):
                    sys.__stdout__.flush()
                    sys.__stderr__.flush()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                for fd in saved:
                    os.close(fd)
                sink.seek(0)
                self.text = buffer.getvalue() + sink.read().decode("utf-8", "replace")


def guarded(call: Callable[[], object]) -> tuple[object, BaseException | None, list[str], float]:
    """`call()` under the hang limit: (its value, the InputError it raised, the problems: an uncaught exception or a
    hang, its seconds)."""
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_S)
    start = time.monotonic()
    value, error, problems = None, None, []
    try:
        value = call()
    except Hang:
        problems.append(f"hang: still running after {HANG_S} s")
    except InputError as exc:
        error = exc
    except Exception as exc:  # the fuzz's finding: anything but an InputError
        error = exc
        problems.append(f"uncaught {type(exc).__name__}: {shown(exc, 240)} (at {where(exc)})")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return value, error, problems, round(time.monotonic() - start, 3)


def where(exc: BaseException) -> str:
    """Where `exc` was raised: the innermost frame in ident_opt (else the innermost), as file:line in function."""
    frames = traceback.extract_tb(exc.__traceback__)
    own = [f for f in frames if "/ident_opt/" in f.filename] or frames
    if not own:
        return "?"
    frame = own[-1]
    return f"{frame.filename.split('/ident_opt/')[-1]}:{frame.lineno} in {frame.name}"


def entry_kind(path: str | Path) -> str:
    """What `path` is, not following a link: "missing", "link to X", "fifo", "char device", "socket", "folder",
    or a regular file's SHA-256."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return "missing"
    if stat.S_ISLNK(mode):
        return "link to " + os.readlink(path)
    kinds = ((stat.S_ISFIFO, "fifo"), (stat.S_ISCHR, "char device"), (stat.S_ISSOCK, "socket"), (stat.S_ISDIR, ""))
    for test, kind in kinds:
        if test(mode):
            return kind or "folder"
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        return f"unreadable ({exc.strerror})"


def tree(root: Path) -> dict[str, str]:
    """Every entry under `root` (files, folders, links, pipes; links not followed) → `entry_kind`; {} if missing."""
    out = {}
    for top, folders, names in os.walk(root):
        for name in folders + names:
            path = os.path.join(top, name)
            out[os.path.relpath(path, root)] = entry_kind(path)
    return out


def changed_entries(before: dict[str, str], after: dict[str, str]) -> list[str]:
    """The entries new, gone or different between two `tree`s."""
    return sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))


def run_cli(kind: str, folder: Path, argv: list[str], inputs: tuple[str, ...], **extra) -> dict:
    """`argv` in-process in `folder` with everything printed captured: its outcome and every violation of the
    contract (`tests.test_fuzz.violations`, and `extra_violations`: `trees`, folders that must come out unchanged
    with no new entry either; `specials`, paths whose kind must stay; `allowed`, the only places a write may land;
    `secret`, text that must be neither printed nor written; `watch`, paths whose change of kind is noted, not
    failed: a link to a file or to nothing that an output replaced)."""
    inputs_h = {name: h for name, h in files(folder).items() if any(_under(name, i) for i in inputs)}
    before = files(folder)
    trees = {t: tree(folder / t) for t in extra.get("trees", ())}
    specials = {s: entry_kind(s if os.path.isabs(s) else folder / s) for s in extra.get("specials", ())}
    watched = {s: entry_kind(folder / s) for s in extra.get("watch", ())}
    cwd = Path.cwd()
    os.chdir(folder)
    printed = Printed()
    try:
        with printed.capture():
            status, _, problems, seconds = guarded(lambda: main(argv))
    finally:
        os.chdir(cwd)
    outcome = {"kind": kind, "argv": [shown(a) for a in argv], "status": status, "seconds": seconds}
    lines = printed.text.strip().splitlines()
    outcome["message"] = lines[-1][:200] if lines else ""
    problems += violations(folder, status, before, inputs_h, printed.text, "", None)
    problems += extra_violations(folder, before, trees, specials, printed.text, extra)
    outcome["problems"] = problems
    now = {s: entry_kind(folder / s) for s in watched}
    outcome["notes"] = [f"{s}: {shown(was)} -> {shown(now[s])}" for s, was in watched.items() if now[s] != was]
    log(outcome)
    return outcome


def extra_violations(folder: Path, before: dict, trees: dict, specials: dict, printed: str, extra: dict) -> list[str]:
    """The checks `tests.test_fuzz.violations` does not make (`run_cli`)."""
    found = []
    for name, was in trees.items():
        diff = changed_entries(was, tree(folder / name))
        if diff:
            found.append(f"modified input: {name}: {[shown(d) for d in diff[:3]]}")
    for name, was in specials.items():
        now = entry_kind(name if os.path.isabs(name) else folder / name)
        if now != was:
            found.append(f"special replaced: {shown(name)} was {shown(was)}, now {shown(now)}")
    after = files(folder)
    written = [n for n, h in after.items() if before.get(n) != h and not n.startswith(".cache/")]
    allowed = extra.get("allowed")
    if allowed is not None:
        real = [os.path.realpath(folder / a) for a in allowed]
        outside = [n for n in written if not any(_within(os.path.realpath(folder / n), r) for r in real)]
        if outside:
            found.append(f"wrote outside its outputs: {[shown(n) for n in outside[:3]]}")
    secret = extra.get("secret")
    regular = [folder / n for n in written if not (folder / n).is_symlink() and (folder / n).is_file()]
    if secret and (secret in printed or any(secret.encode() in path.read_bytes() for path in regular)):
        found.append("leak: the file outside the logs is quoted")
    return found


def _within(path: str, top: str) -> bool:
    return path == top or path.startswith(top.rstrip("/") + "/")


# ---------------------------------------------------------------------------------------------- fleet
PLANAR = ROOT / "problems" / "tudor_2dof.toml"
#: What must never leave the file outside the logs (`tests.test_fleet_hostile`'s secret: its first line is wide
#: enough for the planar problem's column indices, so a loader that read it would quote its first cell).
SECRET = "aws_secret_access_key=HUNTER2-do-not-leak"
SECRET_FILE = SECRET + ",0" * 20 + "\n" + ",".join(["1"] * 21) + "\n"
#: The planar problem with its output folder beside it (out/) and its trials named by absolute path.
FLEET_PROBLEM = (
    PLANAR.read_text().replace('"../data/merit/', f'"{ROOT}/data/merit/').replace('dir = "../results"', 'dir = "out"')
)
#: One case in this many runs the whole `ident-opt fleet` (5 to 15 s on a busy machine) after the in-process scan.
FULL_EVERY = 12
ROBOTS = ["R01", "R02", "arm.7", "r-9_x"]
DATES = ["2026-03-01", "2026-03-02", "2026-03-03", "2026-03-04", "2026-03-05"]


@functools.cache
def fleet_problem() -> str:
    """`FLEET_PROBLEM` in a folder of the session (removed at exit), for the in-process scan: the workers' problem
    setup is cached by path (`tasks.setup`), so every case's scan loads it once."""
    folder = Path(tempfile.mkdtemp(prefix="fuzz-fleet-problem-"))
    atexit.register(shutil.rmtree, folder, True)
    (folder / "fp.toml").write_text(FLEET_PROBLEM)
    return str(folder / "fp.toml")


@functools.cache
def trial_pool() -> dict[str, bytes]:
    """The trials a fleet tree is made of, by file name ending → bytes: the simulated fleet's six as CSV
    ("0.csv" … "5.csv"), two as written (Parquet, gzip CSV), and edited ones (`tiny-step`: a time step of 1e-300 s,
    `huge`: torques × 1e300, `nan`: NaN cells, `header`: the header line only)."""
    from ident_opt.fleet.simulated import FleetSpec, simulate_fleet  # here: the fleet's modules stop no other property

    tiny = FleetSpec(robots=2, days=3, seconds=5.0, rate_hz=100.0, seed=7, changed=0.0)
    with tempfile.TemporaryDirectory(prefix="fuzz-fleet-") as tmp:
        simulate_fleet(PLANAR, Path(tmp) / "logs", tiny)
        paths = sorted(p for p in Path(tmp).rglob("log*") if p.is_file())
        frames = [pd.read_parquet(p) if p.suffix == ".parquet" else pd.read_csv(p) for p in paths]
        pool = {f"{k}.csv": f.to_csv(index=False).encode() for k, f in enumerate(frames)}
        pool["x.parquet"] = next(p for p in paths if p.suffix == ".parquet").read_bytes()
        pool["x.csv.gz"] = next(p for p in paths if p.name.endswith(".gz")).read_bytes()
    first = frames[0]
    pool["tiny-step.csv"] = first.assign(t=np.arange(len(first)) * 1e-300).to_csv(index=False).encode()
    pool["huge.csv"] = first.assign(tau1=first["tau1"] * 1e300).to_csv(index=False).encode()
    pool["nan.csv"] = first.assign(q2=first["q2"].where(first.index % 7 != 3)).to_csv(index=False).encode()
    pool["header.csv"] = (",".join(first.columns) + "\n").encode()
    return pool


VALID = [f"{k}.csv" for k in range(6)] + ["x.parquet", "x.csv.gz"]
#: Hostile entries of a fleet tree (`HOSTILE`), those that make the layout an error (exit 2) listed once, the
#: others several times.
ENTRIES = [
    "link-file-out", "link-day-out", "link-robot-out", "link-inside", "link-dangling", "link-loop", "fifo",
    "non-utf8-file", "long-file", "empty", "garbage", "garbage-gz", "garbage-parquet", "tiny-step", "huge", "nan",
    "header", "nested", "unreadable-robot", "hidden", "other-type", "long-robot",
]  # fmt: skip
FATAL = ["fifo-root", "file-root", "non-utf8-robot", "non-utf8-day", "bad-day", "nested-robot"]
#: --logs, given the absolute path of the logs (`{a}`) and of the case's folder (`{f}`); the case runs in `{f}`.
FORMS = {
    "path": "{a}",
    "relative": "logs",
    "dot-slash": "./logs/",
    "file://": "file://{a}",
    "file://relative": "file://logs",
    "file:": "file:{a}",
    "local://": "local://{a}",
    "simplecache::": "simplecache::file://{a}",
    "alias": "{f}/alias",
    "zip://": "zip://logs::file://{f}/logs.zip",
}
#: --out and --json (`_target`): outside the logs (None: the problem's out/, or no JSON) three times as often as inside
#: them (or onto an input).
OUTS = [None, "out", "rep", "{f}/abs-rep"] * 3 + ["logs", "logs/robot={robot}", "logs/new", "alias/rep", "logs/{day}"]
JSONS = [None, "f.json", "out/f.json", "{f}/abs.json"] * 3 + ["logs/f.json", "logs/{trial}", "alias/f.json"]
JSONS += ["logs.zip", "fp.toml"]


@st.composite
def fleet_case(draw) -> dict:
    """A fleet tree (robots → days → trials from `trial_pool`), its hostile entries (each placed by a number), the
    garbage bytes, the --logs form, --out, --json, the estimator and whether the whole command runs too."""
    robots = draw(st.lists(st.sampled_from(ROBOTS), min_size=1, max_size=3, unique=True))
    layout_ = {
        robot: {
            day: draw(st.lists(st.sampled_from(VALID), min_size=1, max_size=2))
            for day in draw(st.lists(st.sampled_from(DATES), min_size=1, max_size=3, unique=True))
        }
        for robot in robots
    }
    entries = st.sampled_from(ENTRIES * 4 + FATAL)
    return {
        "tree": layout_,
        "hostile": draw(st.lists(st.tuples(entries, st.integers(0, 99)), max_size=4)),
        "garbage": draw(st.binary(max_size=64)),
        "form": draw(st.sampled_from(list(FORMS))),
        "out": draw(st.sampled_from(OUTS)),
        "json": draw(st.sampled_from(JSONS)),
        "estimator": draw(st.sampled_from([None, None, None, "ols", "constrained"])),
        "full": draw(st.integers(0, 2**20)) % FULL_EVERY == 1,  # hypothesis favours a small range's ends
    }


def build_fleet(folder: Path, case: dict) -> None:
    """The case's fleet under `folder`/logs, the problem fp.toml, secret.csv (outside the logs), `alias` (a link to
    the logs), what the hostile entries need outside the logs (elsewhere/), and logs.zip for the zip form."""
    pool = trial_pool()
    logs = folder / "logs"
    for robot, days in case["tree"].items():
        for day, names in days.items():
            where = logs / f"robot={robot}" / f"day={day}"
            where.mkdir(parents=True)
            for k, name in enumerate(names):
                (where / f"log{k}{name[name.index('.') :]}").write_bytes(pool[name])
    (folder / "secret.csv").write_text(SECRET_FILE)
    (folder / "fp.toml").write_text(FLEET_PROBLEM)
    (folder / "alias").symlink_to("logs", target_is_directory=True)
    elsewhere = folder / "elsewhere" / "robot=R09" / "day=2026-03-01"
    elsewhere.mkdir(parents=True)
    (elsewhere / "log0.csv").write_bytes(pool["0.csv"])
    (elsewhere / "leak.csv").write_text(SECRET_FILE)
    days = sorted(p for p in logs.glob("robot=*/day=*"))
    for entry, at in case["hostile"]:
        with contextlib.suppress(FileExistsError):  # the same entry twice in one place
            HOSTILE[entry](folder, days[at % len(days)], case["garbage"])
    if case["form"] == "zip://":
        with zipfile.ZipFile(folder / "logs.zip", "w") as archive:
            for path in sorted(logs.rglob("*")):
                name = str(path.relative_to(folder))
                if path.is_file() and not path.is_symlink() and name.isprintable() and name.isascii():
                    archive.write(path, name)


def _garbage(name: str) -> Callable:
    return lambda folder, day, garbage: (day / name).write_bytes(garbage or b"\x00\xff")


def _pooled(name: str, pooled: str) -> Callable:
    return lambda folder, day, garbage: (day / name).write_bytes(trial_pool()[pooled])


def _mkdir_with_trial(path: Path) -> None:
    path.mkdir(parents=True, exist_ok=True)
    (path / "log0.csv").write_bytes(trial_pool()["0.csv"])


def _unreadable_robot(robot: Path, garbage: bytes) -> None:
    """A robot whose one day holds nothing the loader can read (garbage, an empty file, a header only)."""
    day = robot / "day=2026-03-02"
    day.mkdir(parents=True, exist_ok=True)
    (day / "junk.csv").write_bytes(garbage or b"\x00")
    (day / "empty.csv").write_bytes(b"")
    (day / "header.csv").write_bytes(trial_pool()["header.csv"])


HOSTILE: dict[str, Callable[[Path, Path, bytes], object]] = {
    "link-file-out": lambda folder, day, garbage: (day / "leak.csv").symlink_to(folder / "secret.csv"),
    "link-day-out": lambda folder, day, garbage: (day.parent / "day=2026-04-01").symlink_to(
        folder / "elsewhere" / "robot=R09" / "day=2026-03-01", target_is_directory=True
    ),
    "link-robot-out": lambda folder, day, garbage: (folder / "logs" / "robot=R09").symlink_to(
        folder / "elsewhere" / "robot=R09", target_is_directory=True
    ),
    "link-inside": lambda folder, day, garbage: (day / "dup.csv").symlink_to(next(day.iterdir()).name),
    "link-dangling": lambda folder, day, garbage: (day / "gone.csv").symlink_to("nowhere.csv"),
    "link-loop": lambda folder, day, garbage: (day / "loop.csv").symlink_to("loop.csv"),
    "fifo": lambda folder, day, garbage: os.mkfifo(day / "pipe.csv"),
    "non-utf8-file": lambda folder, day, garbage: (day / os.fsdecode(b"\xff\xfe.csv")).write_bytes(
        trial_pool()["1.csv"]
    ),
    "long-file": lambda folder, day, garbage: (day / ("x" * 251 + ".csv")).write_bytes(trial_pool()["2.csv"]),
    "empty": lambda folder, day, garbage: (day / "empty.csv").write_bytes(b""),
    "garbage": _garbage("junk.csv"),
    "garbage-gz": _garbage("junk.csv.gz"),
    "garbage-parquet": _garbage("junk.parquet"),
    "tiny-step": _pooled("tiny.csv", "tiny-step.csv"),
    "huge": _pooled("huge.csv", "huge.csv"),
    "nan": _pooled("nan.csv", "nan.csv"),
    "header": _pooled("header.csv", "header.csv"),
    "nested": lambda folder, day, garbage: _mkdir_with_trial(day / "sub"),
    "unreadable-robot": lambda folder, day, garbage: _unreadable_robot(folder / "logs" / "robot=R07", garbage),
    "hidden": lambda folder, day, garbage: [
        (day / ".hidden.csv").write_bytes(garbage),
        (folder / "logs" / "_SUCCESS").write_bytes(b""),
    ],
    "other-type": lambda folder, day, garbage: (day / "notes.txt").write_text("not a trial\n"),
    "long-robot": lambda folder, day, garbage: _mkdir_with_trial(
        folder / "logs" / ("robot=" + "R" * 249) / "day=2026-03-01"
    ),
    "fifo-root": lambda folder, day, garbage: os.mkfifo(folder / "logs" / "pipe"),
    "file-root": lambda folder, day, garbage: (folder / "logs" / "README.csv").write_text("x\n"),
    "non-utf8-robot": lambda folder, day, garbage: _mkdir_with_trial(
        folder / "logs" / os.fsdecode(b"robot=\xffR") / "day=2026-03-01"
    ),
    "non-utf8-day": lambda folder, day, garbage: _mkdir_with_trial(day.parent / os.fsdecode(b"day=\xff")),
    "bad-day": lambda folder, day, garbage: _mkdir_with_trial(day.parent / "day=2026-02-30"),
    "nested-robot": lambda folder, day, garbage: _mkdir_with_trial(day.parent / "extra"),
}


def _target(template: str | None, case: dict, folder: Path) -> str | None:
    """An --out or --json template (`OUTS`, `JSONS`) for the case's tree."""
    if template is None:
        return None
    robot = next(iter(case["tree"]))
    day = next(iter(case["tree"][robot]))
    first = case["tree"][robot][day][0]
    trial = f"robot={robot}/day={day}/log0{first[first.index('.') :]}"
    return template.format(f=folder, robot=robot, day=f"robot={robot}/day={day}", trial=trial)


def scan(folder: Path, logs: str, out: str | None, json_path: str | None, estimator: str | None) -> dict:
    """What `ident-opt fleet` runs before any work and on its workers, in-process (`fleet-layout`): the --out/--json
    check, the layout, and per robot its choice of fit, each file's statistics, each day's sum and fit, the baseline
    and the scales. Returns what it found, for `scan_violations`."""
    from ident_opt.commands import fleet as fleet_command
    from ident_opt.fleet import layout, tasks

    with outputs.run():
        fleet_command._outside(SimpleNamespace(logs=logs, out=out, json=json_path), None)
    found = layout.discover(logs)
    job = tasks.Job(fleet_problem(), estimator=estimator)
    got = {"layout": found, "choices": [], "files": [], "fits": [], "scales": []}
    for robot in found.robots:
        days = [found.files_of(robot, day) for day in found.days(robot)]
        choice = tasks.choose(job, robot, *days[:8])
        got["choices"].append(choice)
        sums = []
        for files_ in days:
            stats = [tasks.file_stats(job, f, choice) for f in files_]
            got["files"] += stats
            sums.append(tasks.day_stats(*stats))
            got["fits"].append(tasks.fit_day(job, sums[-1], choice))
        base = tasks.baseline(job, *sums, count=5)
        got["scales"] += [tasks.scales(job, day, base) for day in sums]
    return got


def scan_violations(got: dict, folder: Path) -> list[str]:
    """What a finished scan broke: a trial outside the logs or through a link, a reason not on one short line or
    quoting the file outside the logs, a number that is not finite."""
    from ident_opt.fleet import layout, tasks

    found = []
    root = os.path.realpath(folder / "logs")
    for f in got["layout"].files:
        local = layout._local(f.url)
        if local is not None and (not _within(os.path.realpath(local), root) or layout.linked(f)):
            found.append(f"read outside the logs: {shown(f.url)}")
    reasons = [s["reason"] for s in got["layout"].skipped] + [f.reason for f in got["files"] if f.stats is None]
    said = [str(w) for w in got["layout"].warnings] + [n for fit in got["fits"] for n in fit.notes]
    for reason in reasons + said:
        if SECRET in reason:
            found.append("leak: the file outside the logs is quoted")
        if "\n" in reason.strip() or (reason in reasons and len(reason) > tasks.REASON_CHARS):
            found.append(f"reason not one short line: {shown(reason)}")
    numbers = [a for f in got["files"] if f.stats is not None for a in (f.stats.G, f.stats.b, f.stats.s)]
    numbers += [fit.pi for fit in got["fits"] if fit.pi is not None]
    numbers += [fit.tested for fit in got["fits"] if fit.tested is not None]
    numbers += [s.scale for s in got["scales"] if s is not None]
    if any(not np.isfinite(np.asarray(a, dtype=float)).all() for a in numbers):
        found.append("NaN or inf in a result")
    return found


def run_scan(folder: Path, case: dict, logs: str, out: str | None, json_path: str | None) -> dict:
    """`scan` in `folder` under the hang limit; logged as `fleet-layout` with its violations (`scan_violations`,
    and: nothing written anywhere in the case's folder)."""
    before = tree(folder)
    cwd = Path.cwd()
    os.chdir(folder)
    printed = Printed()
    try:
        with printed.capture():
            got, error, problems, seconds = guarded(lambda: scan(folder, logs, out, json_path, case["estimator"]))
    finally:
        os.chdir(cwd)
    status = 0 if got is not None else 2 if isinstance(error, InputError) else None
    argv = ["fleet-layout", "--logs", logs, "--out", str(out), "--json", str(json_path)]
    outcome = {"kind": "fleet-layout", "argv": [shown(a) for a in argv], "status": status, "seconds": seconds}
    outcome["message"] = shown(error) if error is not None else ""
    if got is not None:
        problems += scan_violations(got, folder)
    diff = changed_entries(before, tree(folder))
    if diff:
        problems.append(f"modified input: {[shown(d) for d in diff[:3]]}")
    if SECRET in printed.text or (error is not None and SECRET in str(error)):
        problems.append("leak: the file outside the logs is quoted")
    outcome["problems"] = problems
    outcome["case"] = shown({k: v for k, v in case.items() if k != "garbage"}, 1000)
    log(outcome)
    return outcome


def run_fleet_command(folder: Path, case: dict, logs: str, out: str | None, json_path: str | None) -> dict:
    """The whole `ident-opt fleet` (one local worker) on the case's tree (`fleet`)."""
    argv = ["fleet", "--problem", "fp.toml", "--logs", logs, "--workers", "1", "--no-progress"]
    argv += ["--out", out] if out else []
    argv += ["--json", json_path] if json_path else []
    argv += ["--estimator", case["estimator"]] if case["estimator"] else []
    allowed = [out or "out", *([json_path] if json_path else [])]
    # The run's inputs: the logs it reads. Read from logs.zip, the folder the archive was made from is scaffolding
    # the run never opens (a report written there is the user's choice, as anywhere else).
    logs_read = ("logs.zip",) if case["form"] == "zip://" else ("logs",)
    inputs = (*logs_read, "fp.toml", "secret.csv", "elsewhere")
    specials = [str(p.relative_to(folder)) for p in _specials(folder)]
    return run_cli(
        "fleet", folder, argv, inputs, trees=("logs", "elsewhere"), specials=specials, allowed=allowed, secret=SECRET
    )


def _specials(folder: Path) -> list[Path]:
    """The named pipes and links under `folder`/logs."""
    return [p for p in (folder / "logs").rglob("*") if p.is_symlink() or stat.S_ISFIFO(os.lstat(p).st_mode)]


def fleet_outcomes(case: dict) -> list[dict]:
    """The outcomes of a `fleet_case`: the in-process scan's, and the whole command's when the case says so."""
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        build_fleet(folder, case)
        logs = FORMS[case["form"]].format(a=folder / "logs", f=folder)
        out, json_path = _target(case["out"], case, folder), _target(case["json"], case, folder)
        outcomes = [run_scan(folder, case, logs, out, json_path)]
        if case["full"]:
            outcomes.append(run_fleet_command(folder, case, logs, out, json_path))
    return outcomes


@budget(6, 2.5)
@share(6)
@given(case=fleet_case())
def test_fuzz_fleet(case):
    for outcome in fleet_outcomes(case):
        assert not outcome["problems"], outcome


# ---------------------------------------------------------------------------------------------- output kinds
#: The two workspaces: (problem, its data, its URDF or None).
SPACES = {"planar": ("p.toml", "d.csv", None), "arm3": ("a.toml", "d3.csv", "arm.urdf")}
#: A command: its arguments besides --problem, and its outputs (flag, a file's ending or "/" for a folder), the
#: required one first.
COMMANDS = {
    "check": ([], [("--json", ".json")]),
    "compare": (["--no-progress"], [("--json", ".json"), ("--out", "/")]),
    "export-urdf": (["--format", "urdf"], [("--out", ".urdf")]),
    "export-mjcf": (["--format", "mjcf"], [("--out", ".xml")]),
    "simulate": (["--duration", "1"], [("--out", ".csv")]),
    "codegen": ([], [("--out", "/"), ("--json", ".json")]),
    "diagnose": ([], [("--json", ".json"), ("--out", "/")]),
}
REQUIRED = {"export-urdf", "export-mjcf", "simulate", "codegen"}
#: How often each command is drawn: a codegen (a C build) and a diagnosis take seconds, the others a fraction of one.
WEIGHTS = ["check"] * 8 + ["compare"] * 3 + ["export-urdf"] * 4 + ["export-mjcf"] * 3 + ["simulate"] * 4
WEIGHTS += ["codegen", "diagnose"]
#: The kinds of output path: the path (`{s}`: the output's ending, empty for a folder; `{p}`, `{d}`, `{u}`: the
#: workspace's problem, data and URDF).
PATHS = {
    "new": "new{s}",
    "new-in-new-folder": "nf/sub/new{s}",
    "existing": "old{s}",
    "folder": "adir",
    "cwd": ".",
    "fifo": "pipe{s}",
    "link-to-fifo": "lpipe{s}",
    "link-to-file": "lfile{s}",
    "link-to-folder": "ldir",
    "dangling-link": "dangling{s}",
    "dev-null": "/dev/null",
    "link-to-dev-null": "lnull{s}",
    "read-only-folder": "ro/new{s}",
    "under-a-file": "afile/new{s}",
    "long-name": "x" * 300 + "{s}",
    "long-path": "/".join(["d" * 200] * 21) + "/new{s}",
    "problem": "{p}",
    "data": "{d}",
    "urdf": "{u}",
    "data-dot-slash": "./{d}",
    "link-to-data": "l{d}",
    "non-utf8": os.fsdecode(b"\xff\xfe") + "{s}",
    "non-utf8-folder": os.fsdecode(b"\xfe") + "/new{s}",
    "empty": "",
}
ENDINGS = (".json", ".urdf", ".xml", ".csv", "")


def output_workspace(folder: Path) -> list[str]:
    """Both workspaces and what the kinds of path (`PATHS`) name, for every ending; returns the pipes and links whose
    kind must stay."""
    (folder / "p.toml").write_text(PROBLEM)
    (folder / "d.csv").write_bytes(CLEAN)
    (folder / "arm.urdf").write_text(TWISTED)
    (folder / "a.toml").write_text(ARM3 + DRIVES + '[data]\ntrials = ["d3.csv"]\n')
    (folder / "d3.csv").write_text(motion(n=400).to_csv(index=False))
    (folder / "adir").mkdir()
    (folder / "adir" / "mine.txt").write_text("the user's\n")
    (folder / "ldir").symlink_to("adir", target_is_directory=True)
    (folder / "ro").mkdir(mode=0o555)
    (folder / "afile").write_text("a file\n")
    (folder / "ld.csv").symlink_to("d.csv")
    (folder / "ld3.csv").symlink_to("d3.csv")
    specials = ["ldir", "ld.csv", "ld3.csv", "/dev/null"]
    for s in ENDINGS:
        (folder / f"old{s}").write_text("old\n")
        os.mkfifo(folder / f"pipe{s}")
        (folder / f"lpipe{s}").symlink_to(f"pipe{s}")
        (folder / f"lfile{s}").symlink_to(f"old{s}")
        (folder / f"dangling{s}").symlink_to(f"missing/target{s}")
        (folder / f"lnull{s}").symlink_to("/dev/null")
        specials += [f"pipe{s}", f"lpipe{s}", f"lnull{s}"]
    return specials


@st.composite
def output_kind_case(draw) -> dict:
    """A command on one of the workspaces, the output that gets a kind of path, the kind, and whether the command's
    other outputs are given (beside, in safe/)."""
    command = draw(st.sampled_from(WEIGHTS))
    space = draw(st.sampled_from(["planar", "arm3", "arm3", "arm3"] if command == "diagnose" else list(SPACES)))
    outs = COMMANDS[command][1]
    return {
        "command": command,
        "space": space,
        "output": draw(st.integers(0, len(outs) - 1)),
        "kind": draw(st.sampled_from(list(PATHS))),
        "others": draw(st.booleans()),
    }


def output_argv(case: dict) -> list[str]:
    """The case's command line (`output_kind_case`)."""
    problem, data, urdf = SPACES[case["space"]]
    extra, outs = COMMANDS[case["command"]]
    argv = [case["command"].split("-")[0], "--problem", problem, *extra]
    for k, (flag, ending) in enumerate(outs):
        s = "" if ending == "/" else ending
        if k == case["output"]:
            argv += [flag, PATHS[case["kind"]].format(s=s, p=problem, d=data, u=urdf or "arm.urdf")]
        elif (case["command"] in REQUIRED and k == 0) or case["others"]:
            argv += [flag, f"safe/other{s}"]
    return argv


def output_outcome(case: dict) -> dict:
    """The outcome of an `output_kind_case`."""
    argv = output_argv(case)
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        try:
            specials = output_workspace(folder)
            inputs = (*(p for p in SPACES[case["space"]] if p), "adir", "afile")
            watch = [f"{link}{s}" for link in ("lfile", "dangling") for s in ENDINGS]
            return run_cli("output-kinds", folder, argv, inputs, specials=specials, watch=watch)
        finally:
            (folder / "ro").chmod(0o755)


@budget(24, 3.0)
@share(24)
@given(case=output_kind_case())
def test_fuzz_output_kinds(case):
    outcome = output_outcome(case)
    assert not outcome["problems"], outcome


# ---------------------------------------------------------------------------------------------- the API
@dataclasses.dataclass
class Arm:
    """One arm of the API's world: its problem, a trial of it (and that trial's arrays), and its constrained fit."""

    problem: object
    trial: iopt.Dataset
    arrays: dict[str, np.ndarray]
    fit: object


@functools.cache
def world() -> dict:
    """The API's world, made once: a folder (removed at exit) with the planar problem (p.toml on d.csv) and the 3-joint
    URDF arm (a.toml, arm.urdf, d3.csv), hostile files (junk.csv, empty.csv, pipe.csv a named pipe, sub/), and per
    arm its `Arm`."""
    folder = Path(tempfile.mkdtemp(prefix="fuzz-api-"))
    atexit.register(shutil.rmtree, folder, True)
    (folder / "p.toml").write_text(PROBLEM)
    (folder / "d.csv").write_bytes(CLEAN)
    (folder / "arm.urdf").write_text(TWISTED)
    (folder / "a.toml").write_text(ARM3 + DRIVES + '[data]\ntrials = ["d3.csv"]\n')
    (folder / "d3.csv").write_text(motion(n=600).to_csv(index=False))
    (folder / "junk.csv").write_bytes(b"\x00\xff garbage,\n1,2\n")
    (folder / "empty.csv").write_bytes(b"")
    os.mkfifo(folder / "pipe.csv")
    (folder / "sub").mkdir()
    arms = {}
    for name, toml in (("planar", "p.toml"), ("arm3", "a.toml")):
        problem = iopt.load_problem(folder / toml)
        (trial,), _ = iopt.load_trials(problem, [folder / SPACES[name][1]])
        arrays = {k: getattr(trial, k).copy() for k in ("t", "q", "dq", "ddq", "tau")}
        arms[name] = Arm(problem, trial, arrays, iopt.fit(problem, [trial], estimator="constrained"))
    return {"folder": folder, "arms": arms}


#: Edits of an array argument (`edited`), each with two numbers that place it.
EDITS = [
    "nan", "inf", "-inf", "huge", "transpose", "drop-column", "add-column", "drop-rows", "add-row", "ndim3",
    "scalar", "empty", "empty-rows", "complex", "object", "object-str", "bool", "int", "list", "ragged-list",
    "string", "none", "dict", "float32", "strided", "t-constant", "t-reversed", "t-tiny-step", "t-repeat",
    "1e-320",
]  # fmt: skip
EDIT_LISTS = st.one_of(
    st.just(()),
    st.lists(st.tuples(st.sampled_from(EDITS), st.integers(0, 10**6), st.integers(0, 10**6)), max_size=3).map(tuple),
)


def edited(a: np.ndarray, edits: tuple) -> object:
    """A copy of the array `a` after `edits`; an edit that does not apply to what it has become leaves it as it is."""
    a = a.copy()
    for name, i, j in edits:
        if not isinstance(a, np.ndarray):
            break
        with warnings.catch_warnings(), contextlib.suppress(TypeError, ValueError):  # e.g. "int" of a complex array
            warnings.simplefilter("ignore")
            a = _edit(a.copy(), name, i, j)
    return a


def _edit(a: np.ndarray, name: str, i: int, j: int) -> object:
    """`a` after the edit `name` (`EDITS`), placed by `i` and `j`."""
    at = (i % a.shape[0], j % a.shape[1]) if a.ndim == 2 and a.size else (i % a.size,) if a.size else None
    if name in ("nan", "inf", "-inf", "huge", "1e-320") and at is not None and a.dtype.kind == "f":
        value = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf, "huge": 1e308, "1e-320": 1e-320}[name]
        a[at if a.ndim == 2 else np.unravel_index(at[0], a.shape)] = value
        return a
    table = {
        "transpose": lambda: a.T,
        "drop-column": lambda: a[:, :-1] if a.ndim == 2 else a[:-1],
        "add-column": lambda: np.column_stack([a, a[:, :1] if a.ndim == 2 else a]),
        "drop-rows": lambda: a[: i % (len(a) + 1)] if a.ndim else a,
        "add-row": lambda: np.concatenate([a, a[-1:]]) if a.ndim and len(a) else a,
        "ndim3": lambda: a[..., None],
        "scalar": lambda: a.flat[0] if a.size else 1.0,
        "empty": lambda: np.array([]),
        "empty-rows": lambda: a[:0],
        "complex": lambda: a.astype(complex) + 1j * (np.arange(a.size).reshape(a.shape) == (i % max(a.size, 1))),
        "object": lambda: a.astype(object),
        "object-str": lambda: _with_string(a.astype(object), at),
        "bool": lambda: a > 0,
        "int": lambda: a.astype(np.int64) if np.isfinite(a).all() else a,
        "list": lambda: a.tolist(),
        "ragged-list": lambda: _ragged(a.tolist()),
        "string": lambda: "q",
        "none": lambda: None,
        "dict": lambda: {"values": a},
        "float32": lambda: a.astype(np.float32),
        "strided": lambda: np.repeat(a, 2, axis=0)[::2],
        "t-constant": lambda: np.zeros_like(a),
        "t-reversed": lambda: a[::-1].copy(),
        "t-tiny-step": lambda: np.arange(a.size, dtype=float).reshape(a.shape) * 1e-300,
        "t-repeat": lambda: np.concatenate([a[:1], a[:-1]]) if a.ndim and len(a) else a,
    }
    return table[name]() if name in table else a


def _with_string(a: np.ndarray, at: tuple | None) -> np.ndarray:
    """The object array `a` with a number written as a string at `at`."""
    if at is not None:
        a[at if a.ndim == 2 else np.unravel_index(at[0], a.shape)] = "1.5"
    return a


def _ragged(rows: list) -> list:
    """Nested lists with one row a value short."""
    if rows and isinstance(rows[0], list) and rows[0]:
        rows[len(rows) // 2] = rows[len(rows) // 2][:-1]
    return rows


ARMS = st.sampled_from(["planar", "arm3"])
ESTIMATORS = ["ols", "constrained", "robust", "nlp_physical", "consistent", "nope", "", "OLS", 1, True, ["ols"],
              b"ols", {"ols": 1}, 1.5, np.str_("ols"), None]  # fmt: skip
#: The trials argument of fit and diagnose (`trials_of`).
TRIALS = ["valid", "valid", "two", "bare", "tuple", "empty", "none", "string", "dict", "list-none", "list-int",
          "other-arm", "mutated", "mutated", "mutated", "mixed", "array", "generator"]  # fmt: skip
FIELDS = ["t", "q", "dq", "ddq", "tau", "tau", "q", "tau_filtered", "instruments", "source", "notes"]
OPTIONS = ["weights", "margin", "prior", "prior_weight", "bounds", "friction", "mass", "shortcut", "backend",
           "mass_range", "com_box", "options", "unknown"]  # fmt: skip
VALUES = ["wls", "ols", "x", "nan", "-1", "0", "1e-6", "1e300", "inf", "list3", "ones-P", "ones-P+1", "ones-n",
          "none", "true", "cvxpy", "clarabel", "dict", "complex", "nan-array", "-inf"]  # fmt: skip


def option_value(key: str, arm: Arm) -> object:
    """A fit option's value from its key (`VALUES`)."""
    P, n = arm.fit.model.n_params, arm.fit.model.n_joints
    numbers = {"nan": np.nan, "-1": -1, "0": 0, "1e-6": 1e-6, "1e300": 1e300, "inf": np.inf, "-inf": -np.inf}
    if key in numbers:
        return numbers[key]
    arrays = {"ones-P": np.ones(P), "ones-P+1": np.ones(P + 1), "ones-n": np.ones(n), "nan-array": np.full(P, np.nan)}
    if key in arrays:
        return arrays[key]
    return {"list3": [1, 2, 3], "none": None, "true": True, "dict": {}, "complex": 1j}.get(key, key)


def mutated(arm: Arm, field: str, edits: tuple) -> iopt.Dataset:
    """The arm's trial with one field replaced: an array edited (`edited`), the instruments' pair edited, or a
    hostile source or notes."""
    trial = arm.trial
    if field == "instruments":
        dq, ddq = trial.instruments or (trial.dq, trial.ddq)
        return dataclasses.replace(trial, instruments=(edited(dq, edits), ddq) if edits else (dq, ddq[:5]))
    if field in ("source", "notes"):
        return dataclasses.replace(trial, **{field: None if edits else 7})
    base = getattr(trial, field)
    base = trial.tau if base is None else base
    return dataclasses.replace(trial, **{field: edited(base, edits or (("nan", 3, 1),))})


def trials_of(kind: str, arm: Arm, other: Arm, mutation: tuple) -> object:
    """The trials argument of `kind` (`TRIALS`)."""
    trial = arm.trial
    table = {
        "valid": lambda: [trial],
        "two": lambda: [trial, trial],
        "bare": lambda: trial,
        "tuple": lambda: (trial,),
        "empty": lambda: [],
        "none": lambda: None,
        "string": lambda: "d.csv",
        "dict": lambda: {"train": trial},
        "list-none": lambda: [None],
        "list-int": lambda: [1, 2],
        "other-arm": lambda: [other.trial],
        "mutated": lambda: [mutated(arm, *mutation)],
        "mutated-bare": lambda: mutated(arm, *mutation),
        "mixed": lambda: [trial, mutated(arm, *mutation)],
        "array": lambda: arm.arrays["q"].copy(),
        "generator": lambda: (d for d in [trial]),
    }
    return table[kind]()


ONE_EDIT = st.tuples(st.sampled_from(EDITS), st.integers(0, 10**6), st.integers(0, 10**6)).map(lambda e: (e,))
EDITED = st.one_of(ONE_EDIT, ONE_EDIT, EDIT_LISTS.filter(bool))
MUTATION = st.tuples(st.sampled_from(FIELDS), EDITED)
OPTION_LISTS = st.lists(st.tuples(st.sampled_from(OPTIONS), st.sampled_from(VALUES)), min_size=1, max_size=2)


def arguments(target: str) -> dict[str, tuple[object, st.SearchStrategy]]:
    """Each argument of `target` (`api_case`): its valid key and the strategy of its hostile ones."""
    fitted = {
        "trials": ("valid", st.sampled_from(TRIALS)),
        "mutation": (("t", ()), MUTATION),
        "estimator": (None, st.sampled_from(ESTIMATORS)),
    }
    return {
        "trial": {
            "t": ((), EDITED),
            "q": ((), EDITED),
            "tau": ((), EDITED),
            "given": ("tau", st.sampled_from(["current", "both", "neither", "dq", "dq+ddq"])),
            "allow": (False, st.sampled_from([True, None, "yes", 1])),
            "source": ("arrays", st.sampled_from(["", "x" * 500, None, 7, os.fsdecode(b"\xff")])),
        },
        "fit": {**fitted, "options": ((), OPTION_LISTS.map(tuple))},
        "diagnose": {**fitted, "testing": ("default", st.sampled_from(["valid", "mutated", "none", "string"]))},
        "predict": {"trials": ("bare", st.sampled_from(TRIALS)), "mutation": (("t", ()), MUTATION)},
        "load_trials": {
            "data": ("own", st.sampled_from(DATA)),
            "test": ("none", st.sampled_from(DATA)),
            "min_samples": (None, st.sampled_from([0, 1, -1, 10**9, np.nan, np.inf, "10", True, 2.5])),
            "fit": (True, st.sampled_from([False, None, "no", 1])),
            "flags": ((False, False), st.sampled_from([(True, False), (False, True), ("yes", None)])),
        },
        "export": {
            "fit": ("valid", st.sampled_from(EXPORT_FITS)),
            "path": ("x.urdf", st.sampled_from(EXPORT_PATHS)),
            "format": (None, st.sampled_from(["urdf", "mjcf", "URDF", "x", 1, ["urdf"], b"urdf"])),
        },
    }[target]


@st.composite
def api_case(draw) -> dict:
    """The function called, on which arm, and the keys of its arguments (`api_call` builds them): most cases make one
    argument hostile (the `focus`) and keep the others valid, so that each reaches its own check; one in eight makes
    them all hostile at once."""
    target = draw(st.sampled_from(["trial"] * 4 + ["fit"] * 3 + ["predict"] * 2 + ["load_trials"] * 2 +
                                  ["export"] * 2 + ["diagnose"]))  # fmt: skip
    args = arguments(target)
    focus = draw(st.sampled_from([*args, *args, "problem", "all"]))
    case = {"target": target, "arm": draw(ARMS), "focus": focus}
    case["problem"] = draw(st.sampled_from(["none", "path", "dict"])) if focus in ("problem", "all") else "own"
    for name, (valid, hostile) in args.items():
        case[name] = draw(hostile) if focus in (name, "all") else valid
    if focus == "mutation":  # a mutated trial among the trials
        case["trials"] = draw(st.sampled_from(["mutated-bare"] if target == "predict" else ["mutated", "mixed"]))
    if target == "diagnose" and case["arm"] == "planar" and draw(st.integers(0, 3)) > 0:
        case["arm"] = "arm3"  # a planar diagnosis takes seconds
    return case


#: load_trials' data and test arguments (`data_of`).
DATA = [
    "none", "own", "own", "empty-list", "missing", "junk", "empty-file", "folder", "own-string", "own-path",
    "other-arm", "int", "dict", "bytes", "list-none", "dev-null", "fifo", "long-name", "non-utf8", "url", "blank",
    "two", "bare-path", "generator",
]  # fmt: skip
EXPORT_FITS = ["other-arm", "none", "string", "dict", "ols", "no-model", "nan-pi", "short-pi", "no-choice"]
EXPORT_PATHS = ["x.urdf", "x.xml", "x.mjcf", "path-urdf", "none", "int", "bytes", "x.txt", "", "sub/dir/x.urdf",
                "long-name", "non-utf8", "fifo", "dev-null", "folder", "link-to-fifo"]  # fmt: skip


def data_of(key: str, own: str, other: str) -> object:
    """A load_trials data or test argument (`DATA`): `own` and `other`, the absolute paths of the arm's data and of
    the other arm's."""
    w = world()["folder"]
    table = {
        "none": None,
        "own": [own],
        "empty-list": [],
        "missing": [str(w / "missing.csv")],
        "junk": [str(w / "junk.csv")],
        "empty-file": [str(w / "empty.csv")],
        "folder": [str(w / "sub")],
        "own-string": own,
        "own-path": [Path(own)],
        "other-arm": [other],
        "int": [1],
        "dict": {own: 1},
        "bytes": own.encode(),
        "list-none": [None],
        "dev-null": ["/dev/null"],
        "fifo": [str(w / "pipe.csv")],
        "long-name": [str(w / ("x" * 300 + ".csv"))],
        "non-utf8": [str(w / os.fsdecode(b"\xff.csv"))],
        "url": [f"file://{own}"],
        "blank": [""],
        "two": [own, own],
        "bare-path": Path(own),
        "generator": (p for p in [own]),
    }
    return table[key]


def export_path(key: str, here: Path) -> object:
    """An export path (`EXPORT_PATHS`) in the case's folder `here` (where a pipe, a link to it and a folder are)."""
    os.mkfifo(here / "pipe.urdf")
    (here / "lpipe.urdf").symlink_to("pipe.urdf")
    (here / "adir").mkdir()
    table = {
        "path-urdf": Path("x.urdf"),
        "none": None,
        "int": 1,
        "bytes": b"x.urdf",
        "long-name": "x" * 300 + ".urdf",
        "non-utf8": os.fsdecode(b"\xff") + ".urdf",
        "fifo": "pipe.urdf",
        "dev-null": "/dev/null",
        "folder": "adir",
        "link-to-fifo": "lpipe.urdf",
    }
    return table.get(key, key)


def export_fit(key: str, arm: Arm, other: Arm) -> object:
    """An export's fit argument (`api_case`)."""
    fit = arm.fit
    table = {
        "valid": lambda: fit,
        "other-arm": lambda: other.fit,
        "none": lambda: None,
        "string": lambda: "fit",
        "dict": lambda: fit.as_dict(),
        "ols": lambda: iopt.fit(arm.problem, [arm.trial], estimator="ols"),
        "no-model": lambda: dataclasses.replace(fit, model=None),
        "nan-pi": lambda: dataclasses.replace(fit, pi=np.where(np.arange(len(fit.pi)) == 1, np.nan, fit.pi)),
        "short-pi": lambda: dataclasses.replace(fit, pi=fit.pi[:-1]),
        "no-choice": lambda: dataclasses.replace(fit, choice=None),
    }
    return table[key]()


def api_call(case: dict, here: Path) -> tuple[Callable[[], object], list]:
    """The call of `case` (`api_case`) and the arguments it passes (whose arrays must come out unchanged)."""
    arms = world()["arms"]
    arm, other = arms[case["arm"]], arms["arm3" if case["arm"] == "planar" else "planar"]
    target = case["target"]
    problem = {"own": arm.problem, "none": None, "path": str(arm.problem.path), "dict": {"name": "x"}}[case["problem"]]
    if target == "trial":
        return _trial_call(case, arm, problem)
    if target == "fit":
        trials = trials_of(case["trials"], arm, other, case["mutation"])
        options = {name: option_value(value, arm) for name, value in case["options"]}
        return lambda: iopt.fit(problem, trials, case["estimator"], **options), [trials, options]
    if target == "diagnose":
        trials = trials_of(case["trials"], arm, other, case["mutation"])
        testing = {"default": (), "valid": [arm.trial], "mutated": [mutated(arm, *case["mutation"])]}.get(
            case["testing"], None if case["testing"] == "none" else "x"
        )
        return lambda: iopt.diagnose(problem, trials, testing, estimator=case["estimator"]), [trials, testing]
    if target == "predict":
        trial = trials_of(case["trials"], arm, other, case["mutation"])
        return lambda: arm.fit.predict(trial), [trial]
    if target == "load_trials":
        own = str(world()["folder"] / SPACES[case["arm"]][1])
        theirs = str(world()["folder"] / SPACES["arm3" if case["arm"] == "planar" else "planar"][1])
        data, test = data_of(case["data"], own, theirs), data_of(case["test"], own, theirs)
        allow, drop = case["flags"]
        options = {"min_samples": case["min_samples"], "fit": case["fit"]}
        call = lambda: iopt.load_trials(  # noqa: E731
            problem, data, test, allow_implausible=allow, drop_invalid=drop, **options
        )
        return call, [data, test]
    fit, path = export_fit(case["fit"], arm, other), export_path(case["path"], here)
    return lambda: iopt.export(problem, fit, path, case["format"]), [fit]


def _trial_call(case: dict, arm: Arm, problem: object) -> tuple[Callable[[], object], list]:
    a = arm.arrays
    t, q, tau = edited(a["t"], case["t"]), edited(a["q"], case["q"]), edited(a["tau"], case["tau"])
    given_ = case["given"]
    kwargs = {"source": case["source"], "allow_implausible": case["allow"]}
    if given_ == "current":
        kwargs["current"], tau = tau, None
    elif given_ == "both":
        kwargs["current"] = a["tau"].copy()
    elif given_ == "neither":
        tau = None
    elif given_.startswith("dq"):
        kwargs["dq"] = edited(a["dq"], case["q"])
        if given_ == "dq+ddq":
            kwargs["ddq"] = a["ddq"].copy()
    return lambda: iopt.trial(problem, t, q, tau, **kwargs), [t, q, tau, kwargs]


def fingerprint(value: object, depth: int = 0) -> object:
    """What `value` holds (arrays by dtype, shape and bytes; lists, tuples, dicts and trials by their items), to tell
    whether a call changed an argument."""
    if depth > 4:
        return type(value).__name__
    if isinstance(value, np.ndarray):
        body = repr(value.tolist()) if value.dtype.kind == "O" else value.tobytes()
        return (str(value.dtype), value.shape, body)
    if isinstance(value, list | tuple):
        return (type(value).__name__, [fingerprint(v, depth + 1) for v in value])
    if isinstance(value, dict):
        return ("dict", sorted((repr(k), fingerprint(v, depth + 1)) for k, v in value.items()))
    if isinstance(value, iopt.Dataset):
        return ("Dataset", [fingerprint(getattr(value, f.name), depth + 1) for f in dataclasses.fields(value)])
    if isinstance(value, pd.DataFrame):
        return ("frame", value.to_json())
    if dataclasses.is_dataclass(value):
        return (type(value).__name__, repr(value)[:2000])
    return repr(value)


def finite(value: object, target: str, arm: Arm) -> list[str]:
    """Whether a returned value has finite numbers only (`api_case`'s targets)."""
    bad = []
    if target == "trial":
        bad += _trial_finite(value, arm)
    elif target == "fit":
        if not np.isfinite(value.pi).all() or np.isinf(value.se).any():
            bad.append("pi or se not finite")
        bad += [] if np.isfinite(value.predict(arm.trial)).all() else ["its prediction not finite"]
    elif target == "predict":
        n = arm.fit.model.n_joints
        if not (isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[1] == n and np.isfinite(value).all()):
            bad.append(f"prediction of shape {getattr(value, 'shape', None)} or not finite")
    elif target == "load_trials":
        for trial in [*value[0], *value[1]]:
            bad += _trial_finite(trial, arm)
    elif not _strict_text(json.dumps(value.as_json(), default=str)):
        bad.append("NaN or inf in as_json()")
    return [f"NaN or inf in the result: {b}" for b in bad]


def result_problems(value: object, target: str, arm: Arm) -> list[str]:
    """`finite` under the hang limit; an exception while checking (a fit that cannot predict) is a problem too."""
    found, error, problems, _ = guarded(lambda: finite(value, target, arm))
    if isinstance(error, InputError):
        problems.append(f"NaN or inf in the result: checking it raised InputError: {error}"[:300])
    return problems + (found or [])


def world_fifo() -> Path:
    """The named pipe of the API's world."""
    return world()["folder"] / "pipe.csv"


def _trial_finite(trial: object, arm: Arm) -> list[str]:
    """What is wrong with a returned trial: not a `Dataset`, or a value of t, q, dq, ddq or tau not finite."""
    if not isinstance(trial, iopt.Dataset):
        return [f"not a Dataset but {type(trial).__name__}"]
    arrays = [trial.t, trial.q, trial.dq, trial.ddq, trial.tau]
    if not all(np.isfinite(np.asarray(a, dtype=float)).all() for a in arrays):
        return ["a trial's t, q, dq, ddq or tau"]
    return []


def api_outcome(case: dict) -> dict:
    """The outcome of an `api_case`."""
    arm = world()["arms"][case["arm"]]
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        here = Path(tmp)
        cwd = Path.cwd()
        os.chdir(here)
        try:
            call, passed = api_call(case, here)
            before = [fingerprint(passed), repr(arm.problem)]
            specials = {str(p): entry_kind(p) for p in ("pipe.urdf", "lpipe.urdf", "/dev/null", world_fifo())}
            with Printed().capture():
                value, error, problems, seconds = guarded(call)
            status = 0 if error is None and not problems else 2 if isinstance(error, InputError) else None
            if status == 0:
                problems += result_problems(value, case["target"], arm)
            if [fingerprint(passed), repr(arm.problem)] != before:
                problems.append("modified input: an argument (or the problem) changed")
            problems += [f"special replaced: {p}" for p, k in specials.items() if entry_kind(p) != k]
        finally:
            os.chdir(cwd)
    outcome = {"kind": "api", "argv": [case["target"], shown(case)], "status": status, "seconds": seconds}
    outcome["case"] = shown(case, 1000)
    outcome.update(message=shown(error) if error is not None else "", problems=problems)
    log(outcome)
    return outcome


@budget(80, 1.5)
@share(80)
@given(case=api_case())
def test_fuzz_api(case):
    outcome = api_outcome(case)
    assert not outcome["problems"], outcome
