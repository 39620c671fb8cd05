"""Property-based fuzz (hypothesis) of the input paths of issue 32: mutated URDFs, n-joint columns, ROS 2 bags,
trials with gaps, and output paths aimed at every input of a run. Same contract and log as `tests.test_fuzz`
(`run_case`): exit 0 or 2, no traceback or NumPy repr, strict JSON, inputs unchanged (a bag: every file in its
folder), nothing half-written, no case past `HANG_S`.

`make test` runs a small share of each property (the `CI` counts below, fixed cases); `make fuzz` runs
IDENT_OPT_FUZZ_EXAMPLES random cases of each (>= 800). Most cases run `check` (every path up to the fit); one in
`COMPARE_EVERY` runs `compare` too (the fits).
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin

from tests.test_fuzz import FUZZ, ONE_LINE, _scaled, run_case
from tests.test_rosbag import CSV, JOINT_STATE, STORE
from tests.test_urdf_arm import TWISTED

ROOT = Path(__file__).resolve().parents[1]
LONG = bool(os.environ.get("IDENT_OPT_FUZZ_EXAMPLES"))
EXAMPLES = int(os.environ.get("IDENT_OPT_FUZZ_EXAMPLES", "0"))


def share(ci: int) -> settings:
    """The fuzz settings with `ci` cases under `make test`, IDENT_OPT_FUZZ_EXAMPLES under `make fuzz`."""
    return settings(FUZZ, max_examples=EXAMPLES if LONG else ci)


#: One case in this many runs `compare` rather than `check`.
COMPARE_EVERY = 8
COMMAND = st.integers(0, COMPARE_EVERY - 1).map(lambda k: "compare" if k == 0 else "check")


def argv_for(command: str, problem: str = "p.toml", *extra: str) -> list[str]:
    """`check` or `compare` on `problem` writing c.json (compare: no progress bars, no report folder)."""
    tail = ["--no-progress"] if command == "compare" else []
    return [command, "--problem", problem, "--json", "c.json", *tail, *extra]


# ---------------------------------------------------------------------------------------------- the arms
ARM3 = 'name = "arm3"\n[robot]\nurdf = "arm.urdf"\njoints = ["a", "b", "c"]\ngravity = 9.81\n'
DRIVES = "".join(
    f"[robot.{j}]\ntorque_constant = {kt}\ngear_ratio = {r}\n" for j, kt, r in (("a", 0.05, 100), ("b", 0.04, 120))
)
DFKI_URDF = (ROOT / "problems" / "dfki_c0.urdf").read_text()
_dfki_toml = (ROOT / "problems" / "dfki_c0_urdf.toml").read_text()
DFKI_PROBLEM = (
    _dfki_toml[: _dfki_toml.index("[data]")].replace('urdf = "dfki_c0.urdf"', 'urdf = "arm.urdf"')
    + '[data]\ntrials = ["d.csv"]\n[data.columns]\nt = "time"\nq1 = "pos_meas1"\nq2 = "pos_meas2"\n'
    + 'tau1 = "tau_meas1"\ntau2 = "tau_meas2"\n'
)
DFKI_FRAME = pd.read_csv(CSV).iloc[:400].reset_index(drop=True)
DFKI_CSV = DFKI_FRAME.to_csv(index=False)


def motion(n: int = 400, rate: float = 100.0, joints: int = 3) -> pd.DataFrame:
    """A smooth motion of `joints` joints (t, q_j, tau_j; derivatives left to the loader)."""
    t = np.arange(n) / rate
    frame = pd.DataFrame({"t": t})
    for j in range(joints):
        frame[f"q{j + 1}"] = 0.8 * np.sin((0.7 + 0.45 * j) * t + 0.3 * j)
    for j in range(joints):
        frame[f"tau{j + 1}"] = np.cos((1.1 + 0.3 * j) * t) + 0.1 * j
    return frame


MOTION = motion()
ARM3_CSV = MOTION.to_csv(index=False)


def workspace(folder: Path, urdf: str, problem: str, data: str) -> None:
    (folder / "arm.urdf").write_text(urdf, encoding="utf-8", errors="surrogatepass")
    (folder / "p.toml").write_text(problem, encoding="utf-8", errors="surrogatepass")
    (folder / "d.csv").write_text(data, encoding="utf-8", errors="surrogatepass")


# ---------------------------------------------------------------------------------------------- URDF
HOSTILE_NUMBERS = [
    "nan", "inf", "-inf", "-1", "0", "1e30", "-1e30", "200", "-200", "1e-300", "${m}", "", " ", "1 2", "0 0 0",
    "1e308 0 0", "a b c", "1 0 0 0", "0.5", "1e4", "1e5", "-0", "0x10", "1e400", "NaN NaN NaN", "0 0 1e-320",
]  # fmt: skip
TYPES = ["fixed", "prismatic", "floating", "planar", "continuous", "revolute", "x", ""]
ATTRIBUTE = re.compile(r'(\w+)="([^"]*)"')
ELEMENT = re.compile(r"<(inertial|mass|inertia|axis|origin|limit|parent|child|dynamics)\b[^>]*?(/>|>.*?</\1>)", re.S)


@st.composite
def urdf_text(draw) -> tuple[str, str, str]:
    """(URDF, problem, data): the 3-joint arm or the DFKI pendulum (planar form) with 1 to 3 mutations."""
    planar = draw(st.booleans())
    text, problem, data = (DFKI_URDF, DFKI_PROBLEM, DFKI_CSV) if planar else (TWISTED, ARM3 + DRIVES, ARM3_CSV)
    if not planar:
        problem += '[data]\ntrials = ["d.csv"]\n'
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["value", "value", "value", "drop", "name", "type", "cycle", "mesh", "cut"]))
        attributes = list(ATTRIBUTE.finditer(text))
        if op == "value" and attributes:
            m = draw(st.sampled_from(attributes))
            value = draw(st.sampled_from(HOSTILE_NUMBERS) | ONE_LINE.filter(lambda s: '"' not in s and "<" not in s))
            text = text[: m.start(2)] + value.replace("&", "&amp;") + text[m.end(2) :]
        elif op == "drop":
            elements = list(ELEMENT.finditer(text))
            if elements:
                m = draw(st.sampled_from(elements))
                text = text[: m.start()] + text[m.end() :]
        elif op == "name" and re.search(r'name="', text):
            names = re.findall(r'name="([^"]*)"', text)
            old, new = draw(st.sampled_from(names)), draw(st.sampled_from(names))
            text = text.replace(f'name="{old}"', f'name="{new}"', 1)
        elif op == "type" and re.search(r'type="', text):
            types = list(re.finditer(r'type="([^"]*)"', text))
            m = draw(st.sampled_from(types))
            text = text[: m.start(1)] + draw(st.sampled_from(TYPES)) + text[m.end(1) :]
        elif op == "cycle" and re.search(r'<link name="', text):
            links = re.findall(r'<link name="([^"]*)"', text)
            a, b = draw(st.sampled_from(links)), draw(st.sampled_from(links))
            joint = f'<joint name="cyc{len(text)}" type="fixed"><parent link="{a}"/><child link="{b}"/></joint>'
            text = text.replace("</robot>", joint + "</robot>")
        elif op == "mesh":
            mesh = draw(st.sampled_from(["d.csv", "p.toml", "arm.urdf", "missing.stl", "/etc/hostname", "../x"]))
            text = text.replace(
                "<inertial>", f'<visual><geometry><mesh filename="{mesh}"/></geometry></visual><inertial>', 1
            )
        elif op == "cut":
            text = text[: draw(st.integers(0, len(text)))]
    return text, problem, data


@share(24)
@given(case=urdf_text(), command=COMMAND)
def test_fuzz_urdf(case, command):
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        workspace(folder, *case)
        outcome = run_case("urdf", folder, argv_for(command), inputs=("arm.urdf", "p.toml", "d.csv"))
    assert not outcome["problems"], outcome


# ---------------------------------------------------------------------------------------------- n-joint columns
EXTRA_COLUMNS = ["q4", "tau4", "dq4", "i5", "q10", "ddq3", "tau0", "q-1", " q1", "Q1", "i1", "i2", "i3", "dq1", "x"]
HOSTILE_CELLS = ["", "nan", "inf", "-inf", "1e308", "-1e308", "abc", "1e-320", "0x10", "9" * 400]
MAPPINGS = [
    "",
    "",
    "",
    "",
    "",
    "",
    "",
    "",  # most cases: the standard names, read as they are
    "[data.columns]\ni2 = false\n",
    "[data.columns]\ntau1 = false\n",
    '[data.columns]\ntau1 = { column = "i1", scale = 5.0 }\ni1 = false\n',
    '[data.columns]\nq4 = "q1"\n',
    '[data.columns]\nq1 = { column = "q1", scale = 0.0174533 }\n',
    '[data.columns]\nt = { column = "t", scale = 1e-3 }\n',
    "[data.columns]\nq3 = 2\n",
]


@st.composite
def n_joint_case(draw) -> tuple[str, str]:
    """(problem, data) of the 3-joint arm or part of it (1, 2 or 3 joints named): drives for some joints, a column
    mapping, and 0 to 4 column edits of a trial of that many joints."""
    joints = draw(st.sampled_from([("a", "b", "c")] * 3 + [("a", "b"), ("b", "c"), ("a",)]))
    frame = motion(n=draw(st.sampled_from([50, 400])), joints=len(joints))
    if draw(st.booleans()):  # logged as currents
        frame = frame.rename(columns={f"tau{j + 1}": f"i{j + 1}" for j in range(len(joints))})
    header = list(frame.columns)  # edited by position: a renamed column may repeat another's name
    cells = [[repr(float(v)) for v in frame[c]] for c in header]
    for _ in range(draw(st.integers(0, 4))):
        op = draw(st.sampled_from(["add", "drop", "rename", "constant", "cell", "scale", "swap"]))
        i = draw(st.integers(0, len(header) - 1)) if header else 0
        if op == "add" and header:
            header.append(draw(st.sampled_from(EXTRA_COLUMNS)))
            cells.append(list(cells[i]))
        elif op == "drop" and len(header) > 1:
            del header[i], cells[i]
        elif op == "rename" and header:
            header[i] = draw(st.sampled_from(EXTRA_COLUMNS + header))
        elif op == "constant" and header:
            cells[i] = [draw(st.sampled_from(["0", "0.5", "1e300"]))] * len(cells[i])
        elif op == "cell" and header:
            cells[i][draw(st.integers(0, len(cells[i]) - 1))] = draw(st.sampled_from(HOSTILE_CELLS))
        elif op == "scale" and header:
            factor = draw(st.sampled_from([0.0, -1.0, 1e6, 1e-9]))
            cells[i] = [_scaled(c, factor) for c in cells[i]]
        elif op == "swap" and header:
            k = draw(st.integers(0, len(header) - 1))
            cells[i], cells[k] = cells[k], cells[i]
    names = "[" + ", ".join(f'"{j}"' for j in joints) + "]"
    problem = ARM3.replace('["a", "b", "c"]', names) + 'form = "n-joint"\n' * (len(joints) == 2)
    problem += "".join(
        f"[robot.{j}]\ntorque_constant = 0.05\ngear_ratio = 100\n" for j in joints if draw(st.booleans())
    )
    problem += '[data]\ntrials = ["d.csv"]\n' + draw(st.sampled_from(MAPPINGS))
    rows = [",".join(header)] + [",".join(row) for row in zip(*cells)]
    return problem, "\n".join(rows) + "\n"


@share(16)
@given(case=n_joint_case(), command=COMMAND)
def test_fuzz_n_joint_columns(case, command):
    problem, data = case
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        workspace(folder, TWISTED, problem, data)
        outcome = run_case("n-joint", folder, argv_for(command), inputs=("arm.urdf", "p.toml", "d.csv"))
    assert not outcome["problems"], outcome


# ---------------------------------------------------------------------------------------------- ROS 2 bags
BAG_PROBLEM = (
    (ROOT / "problems" / "dfki_c0.toml").read_text(encoding="utf-8").split("# Angles are 0")[0]
    + '[data]\nros_joints = ["shoulder", "elbow"]\n\n[data.columns]\n'
    + 'q1 = { column = "q1", offset = -1.5707963267948966 }\nq2 = "q2"\ntau1 = "tau1"\ntau2 = "tau2"\n'
)
BAG_VALUES = [np.inf, -np.inf, np.nan, 1e308, -1e308, 0.0, 1e-320]
STAMP_EDITS = ["zero", "repeat", "back", "jump_1e6", "jump_1e12", "jump_1e-9"]


@st.composite
def bag_case(draw) -> dict:
    """How to write the bag: message edits (values, names, stamps, lengths), topic, type, storage, and an edit of
    its files after writing."""
    n = draw(st.sampled_from([5, 60, 300]))
    edits = []
    for _ in range(draw(st.integers(0, 3))):
        k = draw(st.integers(0, n - 1))
        op = draw(st.sampled_from(["value", "value", "names", "stamp", "short"]))
        arg = None
        if op == "value":
            arg = (draw(st.sampled_from(["position", "velocity", "effort"])), draw(st.integers(0, 2)))
            arg = (*arg, draw(st.sampled_from(BAG_VALUES)))
        elif op == "names":
            arg = draw(st.sampled_from([["rail", "shoulder"], ["elbow", "shoulder", "rail"], ["x", "y", "z"], []]))
        elif op == "stamp":
            arg = draw(st.sampled_from(STAMP_EDITS))
        else:
            arg = draw(st.sampled_from(["position", "velocity", "effort"]))
        edits.append((op, k, arg))
    return {
        "n": n,
        "edits": edits,
        "topic": draw(st.sampled_from(["/joint_states"] * 4 + ["/other"])),
        "float64": draw(st.integers(0, 9)) == 0,
        "storage": draw(st.sampled_from([StoragePlugin.MCAP, StoragePlugin.SQLITE3])),
        "after": draw(
            st.sampled_from([None] * 6 + ["metadata-garbage", "metadata-cut", "storage-cut", "storage-gone"])
        ),
        "velocity": draw(st.booleans()),
    }


def write_case_bag(folder: Path, case: dict) -> None:
    """The bag of `case` (`bag_case`) in `folder`: JointState messages of the DFKI trial, edited."""
    header, stamp_type = STORE.types["std_msgs/msg/Header"], STORE.types["builtin_interfaces/msg/Time"]
    edits: dict[int, list] = {}
    for op, k, arg in case["edits"]:
        edits.setdefault(k, []).append((op, arg))
    with Writer(folder, version=9, storage_plugin=case["storage"]) as writer:
        if case["float64"]:
            value = STORE.types["std_msgs/msg/Float64"]
            connection = writer.add_connection(case["topic"], value.__msgtype__, typestore=STORE)
            for k in range(case["n"]):
                writer.write(connection, 10**9 + k * 10**7, STORE.serialize_cdr(value(data=1.0), value.__msgtype__))
            return
        connection = writer.add_connection(case["topic"], JOINT_STATE.__msgtype__, typestore=STORE)
        t_prev = None
        for k, row in enumerate(DFKI_FRAME.iloc[: case["n"]].itertuples()):
            t = 100.0 + row.time
            fields = {
                "position": np.array([0.0, row.pos_meas1, row.pos_meas2]),
                "velocity": np.array([0.0, row.vel_meas1, row.vel_meas2]) if case["velocity"] else np.array([]),
                "effort": np.array([0.0, row.tau_meas1, row.tau_meas2]),
            }
            names = ["rail", "shoulder", "elbow"]
            for op, arg in edits.get(k, []):
                if op == "value" and len(fields[arg[0]]) > arg[1]:
                    fields[arg[0]][arg[1]] = arg[2]
                elif op == "names":
                    names = arg
                elif op == "stamp":
                    t = _stamp(arg, t, t_prev)
                elif op == "short":
                    fields[arg] = fields[arg][:1]
            t_prev = t
            sec = int(t)
            msg = JOINT_STATE(
                header=header(stamp=stamp_type(sec=sec, nanosec=min(round((t - sec) * 1e9), 999_999_999)), frame_id=""),
                name=names,
                **fields,
            )
            writer.write(connection, round(t * 1e9), STORE.serialize_cdr(msg, JOINT_STATE.__msgtype__))


def _stamp(edit: str, t: float, previous: float | None) -> float:
    """A message's stamp [s] after `edit` (`STAMP_EDITS`), within what a ROS Time (uint32 s) can hold."""
    previous = t if previous is None else previous
    return {
        "zero": 0.0,
        "repeat": previous,
        "back": max(previous - 5.0, 0.0),
        "jump_1e6": t + 1e6,
        "jump_1e12": min(t + 1e12, 2.1e9),  # a ROS Time holds int32 seconds
        "jump_1e-9": previous + 1e-9,
    }[edit]


def _after(folder: Path, edit: str | None) -> None:
    """Damage the written bag's files (`bag_case`'s "after")."""
    storage = next((p for p in folder.iterdir() if p.suffix in (".mcap", ".db3")), None)
    if edit == "metadata-garbage":
        (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: [garbage")
    elif edit == "metadata-cut":
        text = (folder / "metadata.yaml").read_text()
        (folder / "metadata.yaml").write_text(text[: len(text) // 2])
    elif edit == "storage-cut" and storage is not None:
        data = storage.read_bytes()
        storage.write_bytes(data[: len(data) // 3])
    elif edit == "storage-gone" and storage is not None:
        storage.unlink()


@share(12)
@given(case=bag_case(), command=COMMAND)
def test_fuzz_rosbag(case, command):
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        try:
            write_case_bag(folder / "b", case)
        except (ValueError, OverflowError, TypeError, struct.error):  # the writer refuses the message: no bag
            return
        _after(folder / "b", case["after"])
        (folder / "bag.toml").write_text(BAG_PROBLEM)
        argv = argv_for(command, "bag.toml", "--data", "b")
        outcome = run_case("rosbag", folder, argv, inputs=("b", "bag.toml"))
    assert not outcome["problems"], outcome


# ---------------------------------------------------------------------------------------------- trial gaps
GAPS = [1e-9, 1e-3, 0.05, 1.0, 1e3, 1e5, 1e6, 1e12, 1e15, 1e300, 0.0, -1.0]


@st.composite
def gap_case(draw) -> tuple[str, str, list[str]]:
    """(problem, data, flags): the 3-joint trial (derivatives estimated) with 1 to 3 gaps of hostile sizes."""
    frame = motion(n=draw(st.sampled_from([120, 600])), rate=draw(st.sampled_from([100.0, 1000.0])))
    t = frame["t"].to_numpy().copy()
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(1, len(t) - 1))
        t[at:] = t[at:] + draw(st.sampled_from(GAPS))
    if draw(st.integers(0, 4)) == 0:  # jitter too
        t = t + draw(st.sampled_from([1e-6, 1e-4])) * np.sin(np.arange(len(t)))
    frame["t"] = t
    cutoff = draw(st.sampled_from(['"auto"', "5.0", "20.0", "49.0", "1e-3"]))
    problem = ARM3 + f'[data]\ntrials = ["d.csv"]\nderivative_cutoff_hz = {cutoff}\n'
    flags = draw(st.lists(st.sampled_from(["--drop-invalid", "--allow-implausible"]), unique=True))
    return problem, frame.to_csv(index=False, float_format="%.17g"), flags


@share(12)
@given(case=gap_case(), command=COMMAND)
def test_fuzz_trial_gaps(case, command):
    problem, data, flags = case
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        workspace(folder, TWISTED, problem, data)
        outcome = run_case("gaps", folder, argv_for(command, "p.toml", *flags), inputs=("arm.urdf", "p.toml", "d.csv"))
    assert not outcome["problems"], outcome


# ---------------------------------------------------------------------------------------------- output paths
#: The inputs of a run on each problem of the output workspace (the 3-joint arm's lists two trials; the bag's).
INPUTS = {"p.toml": ("arm.urdf", "mesh.stl", "p.toml", "d.csv", "t2.csv"), "bag.toml": ("bag.toml", "b")}
FILE_TARGETS = [
    "arm.urdf", "mesh.stl", "p.toml", "d.csv", "t2.csv", "./d.csv", "sub/../t2.csv", "b/metadata.yaml", "b/b.mcap",
    "b/new.json", "b", "bag.toml", "r/README.md", "r/.manifest", "r", "new.json", "sub/new.json", "link_urdf",
    "linkdir/x.json", "r/compare.md", "",
]  # fmt: skip
FOLDER_TARGETS = ["r", "b", "b/sub", ".", "new_dir", "arm.urdf", "r/.manifest", "linkdir", "linkdir/sub"]
OUT_STATES = ["empty", "none", "user-readme", "manifest-file", "manifest-garbage", "manifest-folder", "readme-dir"]
WITH_MESH = TWISTED.replace(
    "<inertial>", '<visual><geometry><mesh filename="mesh.stl"/></geometry></visual><inertial>', 1
)


def output_workspace(folder: Path, state: str) -> list[str]:
    """The 3-joint arm (URDF with a mesh, two listed trials), a bag and its problem, links to inputs, and the
    output folder r in `state`; returns what must stay unchanged besides the run's inputs (a README.md of the
    user's, unless the case names it as its output file)."""
    workspace(folder, WITH_MESH, ARM3 + DRIVES + '[data]\ntrials = ["d.csv", "t2.csv"]\n', ARM3_CSV)
    (folder / "mesh.stl").write_bytes(b"solid x\nendsolid x\n")
    (folder / "t2.csv").write_text(motion(n=300).to_csv(index=False))
    write_case_bag(folder / "b", {"n": 300, "edits": [], "topic": "/joint_states", "float64": False,
                                  "storage": StoragePlugin.MCAP, "velocity": True})  # fmt: skip
    (folder / "bag.toml").write_text(BAG_PROBLEM)
    (folder / "link_urdf").symlink_to("arm.urdf")
    (folder / "linkdir").symlink_to("b")
    keep = []
    out = folder / "r"
    if state != "none":
        out.mkdir()
    if state == "user-readme":
        (out / "README.md").write_text("# my notes\n")
        keep.append("r/README.md")
    elif state == "manifest-file":
        (out / ".manifest").write_text("x")
    elif state == "manifest-garbage":
        (out / ".manifest").mkdir()
        (out / ".manifest" / "compare.json").write_text("{garbage")
    elif state == "manifest-folder":
        (out / ".manifest" / "audit.json").mkdir(parents=True)
    elif state == "readme-dir":
        (out / "README.md").mkdir()
    return keep


@st.composite
def output_case(draw) -> tuple[str, list[str]]:
    """(state of r, argv): a command on one of the two problems with its outputs aimed anywhere."""
    command = draw(st.sampled_from(["check", "check", "check", "export", "export", "compare"]))  # compare: slow
    on_bag = draw(st.booleans()) and command != "export"
    argv = [command, "--problem", "bag.toml" if on_bag else "p.toml"] + (["--data", "b"] * on_bag)
    if command == "export":  # it writes XML: aimed at .xml names where the others write .json
        target = draw(st.sampled_from(FILE_TARGETS)).replace(".json", ".xml")
        argv += ["--out", target, "--format", draw(st.sampled_from(["urdf", "mjcf"]))]
    else:
        argv += ["--json", draw(st.sampled_from(FILE_TARGETS))]
    if command == "compare":
        argv += ["--no-progress", "--out", draw(st.sampled_from(FOLDER_TARGETS))]
    return draw(st.sampled_from(OUT_STATES)), argv


@share(10)
@given(case=output_case())
def test_fuzz_output_paths(case):
    state, argv = case
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        folder = Path(tmp)
        keep = output_workspace(folder, state)
        keep = [k for k in keep if k not in argv] + list(INPUTS[argv[2]])  # the user's README named as the output
        outcome = run_case("outputs", folder, argv, inputs=keep)
    assert not outcome["problems"], outcome
