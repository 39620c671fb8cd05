"""Property-based fuzz (hypothesis) of hostile input: random mutations of a real data file (15 s of exp1) and of
a problem file (tudor_2dof.toml), and random command-line numbers, through `check` and `compare` in-process, and
random lines through `online --stream`. Every case must exit 0 or 2 with no traceback, write strict JSON only
(no NaN or Infinity), leave its inputs unchanged and leave nothing half-written (on exit 2: no new or changed
file at all; never a temporary file).

The CI share is small (80 cases per test, 30 for the stream, whose every case makes an offline fit); `make fuzz`
sets IDENT_OPT_FUZZ_EXAMPLES for the long run and IDENT_OPT_FUZZ_LOG to a file where each case appends one JSON
line (its outcome), which `python -m tests.test_fuzz LOG` sums up.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import signal
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ident_opt.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = int(os.environ.get("IDENT_OPT_FUZZ_EXAMPLES", "80"))
LOG = os.environ.get("IDENT_OPT_FUZZ_LOG")
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    derandomize=not os.environ.get("IDENT_OPT_FUZZ_EXAMPLES"),  # CI: the same cases every run
    suppress_health_check=list(HealthCheck),
)

ROWS = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[1500:3000]
PROBLEM = (
    (ROOT / "problems" / "tudor_2dof.toml")
    .read_text()
    .replace('"../data/merit/exp1.csv", "../data/merit/exp2.csv"', '"d.csv"')
    .replace("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", "seeds = [0]")
    .replace('components = "auto"', "components = 2")
    .replace('dir = "../results"', 'dir = "out"')
)
#: The problem file's numeric lines (key = value), the targets of its mutations.
KEYS = [line.split("=")[0].strip() for line in PROBLEM.splitlines() if "=" in line and not line.startswith("#")]

HOSTILE_CELLS = [
    "", " ", "nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e309", "0", "-0", "1e-320", "abc", "1,5", "0x10",
    "9" * 400, "\u00e9", "None", "true", '"1"', "1e150", "-1e150",
]  # fmt: skip
HOSTILE_VALUES = [
    "nan", "inf", "-inf", "0", "-1", "1e300", "-1e300", "1e-300", "0.5", "4294967296", "-4294967297",
    '"x"', "true", "[]", "[1e300, 1e300]", "[nan, 1]", "{}", "{ positive = -1, negative = 1 }", "[[1]]",
    '"../data/merit/exp1.csv"', "99999999999999999999999", "[0, 0, 0]", "1e5", "2", '"auto"',
    "1", "0.3", "0.9", "10", "100", "1e-3", "[0.5, 0.5]", "[1, 2]",
]  # fmt: skip
FACTORS = [0.0, -1.0, 1e-6, 1e6, 1e150, 1e-150, 3.0]


class Mutated(bytes):
    """A mutated file's bytes, shown (in a failing example) as the mutations that made it."""

    log: str = ""

    def __repr__(self) -> str:
        return f"Mutated({self.log})"


ONE_LINE = st.text(max_size=40).filter(lambda s: "\n" not in s and "\r" not in s)


@st.composite
def data_text(draw) -> Mutated:
    """exp1's 15 s with 1 to 4 random mutations: cells, columns, rows, garbage, truncation."""
    rows = [r.split(",") for r in ROWS]
    log = []
    for _ in range(draw(st.integers(1, 4))):
        if not rows:
            break
        op = draw(st.sampled_from(["cell", "scale", "constant", "rows", "ragged", "garbage", "truncate", "swap"]))
        i, j = draw(st.integers(0, len(rows) - 1)), draw(st.integers(0, 16))
        arg = None
        if op == "cell" and j < len(rows[i]):
            rows[i][j] = arg = draw(st.sampled_from(HOSTILE_CELLS) | ONE_LINE.filter(lambda s: "," not in s))
        elif op == "scale":
            arg = draw(st.sampled_from(FACTORS))
            rows = [[_scaled(c, arg) if k == j else c for k, c in enumerate(r)] for r in rows]
        elif op == "constant":
            rows = [[("0" if k == j else c) for k, c in enumerate(r)] for r in rows]
        elif op == "rows":
            arg = draw(st.integers(1, 1500))
            del rows[i : i + arg]
        elif op == "ragged":
            arg = draw(st.booleans())
            rows[i] = rows[i][:j] if arg else [*rows[i], "1"]
        elif op == "garbage":
            arg = draw(ONE_LINE)
            rows.insert(i, [arg])
        elif op == "truncate":
            arg = draw(st.integers(0, 40))
            rows = rows[:arg]
        elif op == "swap" and len(rows) > i + 1:
            rows[i], rows[i + 1] = rows[i + 1], rows[i]
        log.append(f"{op}(row={i}, col={j}, {arg!r})")
    text = "\n".join(",".join(r) for r in rows) + "\n"
    out = Mutated(text.encode("utf-8", "replace"))
    out.log = "; ".join(log)
    return out


def _scaled(cell: str, factor: float) -> str:
    try:
        return f"{float(cell) * factor:.6g}"
    except ValueError:
        return cell


@st.composite
def problem_text(draw) -> str:
    """tudor_2dof.toml (on d.csv, one seed) with 1 to 3 random mutations of its key = value lines."""
    lines = PROBLEM.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["value", "value", "value", "drop", "duplicate", "truncate", "garbage"]))
        numbered = [k for k, line in enumerate(lines) if "=" in line and not line.lstrip().startswith("#")]
        if not numbered:
            break
        k = draw(st.sampled_from(numbered))
        key = lines[k].split("=")[0].strip()
        if op == "value":
            lines[k] = f"{key} = {draw(st.sampled_from(HOSTILE_VALUES))}"
        elif op == "drop":
            del lines[k]
        elif op == "duplicate":
            lines.insert(k, lines[k])
        elif op == "truncate":
            lines = lines[:k]
        else:
            lines.insert(k, draw(st.text(max_size=30).filter(lambda s: "\n" not in s and "\r" not in s)))
    return "\n".join(lines) + "\n"


def files(folder: Path) -> dict[str, str]:
    """Every file under `folder` by relative path -> SHA-256 of its bytes and its mode (a link: where it points)."""
    return {
        str(p.relative_to(folder)): (
            "link to " + os.readlink(p)
            if p.is_symlink()
            else hashlib.sha256(p.read_bytes()).hexdigest() + oct(p.stat().st_mode)
        )
        for p in sorted(folder.rglob("*"))
        if p.is_file() or p.is_symlink()
    }


#: A case running longer than this [s] is a hang (each case is a few seconds at most on a busy machine).
HANG_S = int(os.environ.get("IDENT_OPT_FUZZ_HANG_S", "120"))


class Hang(BaseException):
    """A case ran past `HANG_S` (a BaseException: no handler of the tool's catches it)."""


def _alarm(signum, frame):
    raise Hang


def run_case(
    kind: str,
    folder: Path,
    argv: list[str],
    stdin: bytes | None = None,
    inputs: Iterable[str] = ("d.csv", "p.toml"),
) -> dict:
    """Run `argv` in `folder` (in-process); return its outcome and every violation of the contract. `inputs`:
    the files (relative to `folder`; a folder stands for every file in it) that must come out unchanged."""
    inputs = {name: h for name, h in files(folder).items() if any(_under(name, i) for i in inputs)}
    before = files(folder)
    out, err = io.StringIO(), io.StringIO()
    cwd, stdin_was = Path.cwd(), sys.stdin
    os.chdir(folder)
    outcome = {"kind": kind, "argv": argv, "problems": []}
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_S)
    started = time.monotonic()
    try:
        if stdin is not None:
            sys.stdin = io.TextIOWrapper(io.BytesIO(stdin), encoding="utf-8", errors="replace")
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main(argv)
    except Hang:
        status = None
        outcome["problems"].append(f"hang: still running after {HANG_S} s")
    except Exception as exc:  # the fuzz's first finding: an uncaught exception
        status = None
        outcome["problems"].append(f"uncaught {type(exc).__name__}: {exc}"[:300])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
        os.chdir(cwd)
        sys.stdin = stdin_was
    outcome["status"] = status
    outcome["seconds"] = round(time.monotonic() - started, 3)
    outcome["message"] = err.getvalue().strip().splitlines()[-1][:200] if err.getvalue().strip() else ""
    outcome["problems"] += violations(folder, status, before, inputs, err.getvalue(), out.getvalue(), stdin)
    if LOG:
        with open(LOG, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(outcome) + "\n")
    return outcome


def _under(name: str, top: str) -> bool:
    """Whether the relative path `name` is `top` or lies inside the folder `top`."""
    return name == top or name.startswith(top.rstrip("/") + "/")


def violations(folder, status, before, inputs, err, out, stdin) -> list[str]:
    """What a finished case broke: exit status, traceback, reprs, NaN in JSON, inputs, half-written outputs."""
    found = []
    if status not in (0, 2, None):
        found.append(f"exit status {status}")
    if "Traceback" in err or "np.float64(" in err or "array(" in err:
        found.append("traceback or repr in the message: " + err[-300:])
    after = files(folder)
    changed = [name for name, h in inputs.items() if after.get(name) != h]
    if changed:
        found.append(f"modified input: {changed[:3]}")
    if any(".tmp" in name or name.endswith(".bak") for name in after):
        found.append("temporary file left")
    new = {name: h for name, h in after.items() if not name.startswith(".cache/")}  # the compiled-code cache stays
    if status == 2 and new != {name: h for name, h in before.items() if not name.startswith(".cache/")}:
        found.append(f"partial output: {sorted(set(new.items()) - set(before.items()))[:3]}")
    for name in after:  # the JSON this case wrote (a file it did not touch is not its output)
        if name.endswith(".json") and after[name] != before.get(name) and not _strict(folder / name):
            found.append(f"NaN or invalid JSON in {name}")
    if stdin is not None:
        for line in out.splitlines():
            if line.strip() and not _strict_text(line):
                found.append(f"NaN or invalid JSON line on stdout: {line[:100]}")
                break
    return found


def _strict_text(text: str) -> bool:
    def refuse(token):
        raise ValueError(token)

    try:
        json.loads(text, parse_constant=refuse)
    except ValueError:
        return False
    return True


def _strict(path: Path) -> bool:
    return _strict_text(path.read_text(encoding="utf-8", errors="replace"))


def _case(kind: str, data: bytes, problem: str, argv: list[str], stdin: bytes | None = None) -> dict:
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        (folder / "d.csv").write_bytes(data)
        (folder / "p.toml").write_text(problem, encoding="utf-8", errors="surrogatepass")
        return run_case(kind, folder, argv, stdin)


FLAGS = st.lists(st.sampled_from(["--allow-implausible", "--drop-invalid"]), unique=True)
CLEAN = "\n".join(ROWS).encode() + b"\n"


@FUZZ
@given(data=data_text(), flags=FLAGS)
def test_fuzz_check_on_mutated_data(data, flags):
    outcome = _case("check-data", data, PROBLEM, ["check", "--problem", "p.toml", "--json", "c.json", *flags])
    assert not outcome["problems"], outcome


@FUZZ
@given(problem=problem_text())
def test_fuzz_check_on_mutated_problem(problem):
    outcome = _case("check-problem", CLEAN, problem, ["check", "--problem", "p.toml", "--json", "c.json"])
    assert not outcome["problems"], outcome


@FUZZ
@given(
    data=st.one_of(st.just(CLEAN), data_text()),
    problem=st.one_of(st.just(PROBLEM), problem_text()),
    flags=FLAGS,
    margin=st.sampled_from([None, None, None, "1e-6", "0", "0.5", "nan", "inf", "-1", "1e400", "x"]),
)
def test_fuzz_compare(data, problem, flags, margin):
    extra = ["--margin", margin] if margin is not None else []
    argv = ["compare", "--problem", "p.toml", "--json", "r.json", "--no-progress", *flags, *extra]
    outcome = _case("compare", data, problem, argv)
    assert not outcome["problems"], outcome


@FUZZ
@given(
    text=st.sampled_from(["nan", "inf", "-1", "1e400", "", "0x1", "1_0", "99999999999999999999", "1.5", " 3 ", "é"]),
    flag=st.sampled_from(
        [
            ["compare", "--margin"],
            ["compare", "--constraints-study"],
            ["online", "--components"],
            ["online", "--checks"],
            ["online", "--snapshot-every"],
            ["codegen", "--out", "cg", "--components"],
            ["simulate", "--out", "s.csv", "--seed"],
            ["simulate", "--out", "s.csv", "--duration"],
            ["simulate", "--out", "s.csv", "--rate"],
        ]
    ),
)
def test_fuzz_command_line_numbers(text, flag):
    command, *rest = flag
    argv = [command, "--problem", "p.toml", *rest, text, "--json", "r.json"]
    if command == "simulate" and text.strip() in ("1", "3", "1.5", "1_0"):
        return  # a valid value would run the simulator (slow); only the refusals are fuzzed here
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        (folder / "d.csv").write_bytes(CLEAN)
        (folder / "p.toml").write_text(PROBLEM)
        parsed_ok = _parses(argv)
        if parsed_ok:
            return  # accepted values run whole commands: covered by the other tests
        outcome = run_case("cli-number", folder, argv)
    assert outcome["status"] == 2 and not outcome["problems"], outcome


def _parses(argv: list[str]) -> bool:
    from ident_opt.cli import build_parser
    from ident_opt.errors import InputError

    try:
        with contextlib.redirect_stderr(io.StringIO()):
            build_parser().parse_args(argv)
    except InputError:
        return False
    return True


@st.composite
def stream_line(draw) -> str:
    """A line of the stream: a row of exp1 (the problem maps its columns by index), perhaps with a hostile field,
    cut short or lengthened, a JSON object, or random text."""
    kind = draw(st.sampled_from(["row", "row", "row", "field", "short", "long", "json", "text"]))
    cells = draw(st.sampled_from(ROWS[:300])).split(",")
    if kind == "field":
        cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(HOSTILE_CELLS))
    elif kind == "short":
        cells = cells[: draw(st.integers(0, len(cells) - 1))]
    elif kind == "long":
        cells += ["1"] * draw(st.integers(1, 5))
    elif kind == "json":
        return json.dumps({f"c{k}": v for k, v in enumerate(cells)})
    elif kind == "text":
        return draw(ONE_LINE)
    return ",".join(cells)


@settings(FUZZ, max_examples=EXAMPLES if os.environ.get("IDENT_OPT_FUZZ_EXAMPLES") else 30)  # CI: its offline fit
@given(lines=st.lists(stream_line(), min_size=1, max_size=60))
def test_fuzz_stream(lines):
    stdin = ("\n".join(lines) + "\n").encode("utf-8", "replace")
    argv = ["online", "--problem", "p.toml", "--stream", "--model", "pbr", "--final", "f.json", "--components", "2"]
    outcome = _case("stream", CLEAN, PROBLEM, argv, stdin)
    assert not outcome["problems"], outcome


def summary(log: str) -> str:
    """The fuzz log summed up: cases by kind and status, and each kind of violation."""
    cases = [json.loads(line) for line in Path(log).read_text().splitlines() if line.strip()]
    counts = Counter()
    for case in cases:
        for problem in case["problems"]:
            counts[problem.split(":")[0].split(" in ")[0]] += 1
    by_kind = Counter((c["kind"], c["status"]) for c in cases)
    per_kind = Counter(c["kind"] for c in cases)
    lines = [f"{len(cases)} cases; per property: " + ", ".join(f"{k} {n}" for k, n in sorted(per_kind.items()))]
    lines += [f"  {kind}: exit {status}: {n}" for (kind, status), n in sorted(by_kind.items(), key=str)]
    slowest = max(cases, key=lambda c: c.get("seconds", 0.0), default={})
    if slowest:
        lines.append(
            f"slowest case: {slowest.get('seconds', 0.0):.1f} s ({slowest['kind']}: {' '.join(slowest['argv'])})"
        )
    lines.append(
        "uncaught exceptions: {}, NaN/invalid JSON: {}, modified inputs: {}, partial outputs: {}, "
        "temporary files: {}, tracebacks/reprs: {}, hangs: {}".format(
            sum(n for k, n in counts.items() if k.startswith("uncaught")),
            sum(n for k, n in counts.items() if k.startswith("NaN")),
            counts["modified input"],
            counts["partial output"],
            counts["temporary file left"],
            counts["traceback or repr"],
            counts["hang"],
        )
    )
    lines.append(", ".join(f"{label}: {counts[key]}" for key, label in HOSTILE_KINDS.items()))
    known = ("uncaught", "NaN", "modified input", "partial output", "temporary file left", "traceback or repr", "hang")
    others = {k: n for k, n in counts.items() if not k.startswith(known) and k not in HOSTILE_KINDS}
    if others:
        lines.append("other violations: " + ", ".join(f"{k}: {n}" for k, n in sorted(others.items())))
    noted = sum(1 for c in cases if c.get("notes"))
    if noted:
        lines.append(f"noted, not failed: {noted} cases replaced a link to a file (or to nothing) with their output")
    return "\n".join(lines)


#: The violations `tests.test_fuzz_hostile` adds (the problem's prefix → how the summary names it).
HOSTILE_KINDS = {
    "special replaced": "specials replaced",
    "wrote outside its outputs": "writes outside the outputs",
    "leak": "leaks of the file outside the logs",
    "read outside the logs": "reads outside the logs",
    "reason not one short line": "long skip reasons",
}


if __name__ == "__main__":
    print(summary(sys.argv[1]))


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_strict_json_check_catches_nan(tmp_path, bad):
    """The fuzz's own JSON check refuses what it must (so a NaN cannot slip through unnoticed)."""
    (tmp_path / "x.json").write_text(f'{{"a": {bad.replace("inf", "Infinity").replace("nan", "NaN")}}}')
    assert not _strict(tmp_path / "x.json")
    assert _strict_text('{"a": null}')
