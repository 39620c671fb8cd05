"""Hostile input, third round (issue 32): the paths that came with URDF arms, n joints, ROS 2 bags and several
trials. Each case exits 2 with the culprit named (or does the documented thing), no traceback, no NumPy repr,
nothing written, inputs unchanged, strict JSON.

- every file a run reads is an input (`ident_opt.outputs`): a bag's folder and the files in it, the problem's URDF
  and the meshes it names, the problem file, every trial it lists; no output path (--json, --final, --out,
  codegen --out, export --out, an --out folder's README.md) may land on one;
- an --out folder's README.md is replaced only when ident-opt wrote it; a malformed `.manifest` is named;
- t is converted before it is checked; trials with huge gaps load as segments;
- URDFs are checked once at load (inertials, axes, magnitudes, names, chains); a two-joint URDF that is not planar
  says why; deep TOML and collapsing GMR settings are input errors; bag values, rows and topics are named as the
  user sees them; SIGTERM ends a run with a message; a held-out trial that trains is warned about.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_opt import outputs
from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError, excerpt
from ident_opt.models.gmr import GMR
from ident_opt.problem import load_problem
from tests.test_hostile import exits_2, small_problem, snapshot
from tests.test_rosbag import CSV, STORE, bag_problem, write_bag
from tests.test_urdf_arm import TWISTED

ROOT = Path(__file__).resolve().parents[1]
#: The 3-joint arm's problem (joints a, b, c of `TWISTED`), its trial listed under [data].
ARM3 = 'name = "arm3"\n[robot]\nurdf = "arm.urdf"\njoints = ["a", "b", "c"]\ngravity = 9.81\n'


def _motion(n: int = 400, rate: float = 100.0) -> pd.DataFrame:
    """A smooth motion of the 3 joints (no derivatives: they are estimated) with torques that vary."""
    t = np.arange(n) / rate
    frame = pd.DataFrame({"t": t})
    for j in range(3):
        frame[f"q{j + 1}"] = 0.8 * np.sin((0.7 + 0.45 * j) * t + 0.3 * j)
    for j in range(3):
        frame[f"tau{j + 1}"] = np.cos((1.1 + 0.3 * j) * t) + 0.1 * j
    return frame


@pytest.fixture
def arm3(tmp_path, monkeypatch) -> Path:
    """A folder (the current one) with arm.urdf (`TWISTED`), trial.csv and p.toml listing it."""
    (tmp_path / "arm.urdf").write_text(TWISTED)
    _motion().to_csv(tmp_path / "trial.csv", index=False)
    (tmp_path / "p.toml").write_text(ARM3 + '[data]\ntrials = ["trial.csv"]\n')
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture(scope="module")
def dfki() -> pd.DataFrame:
    return pd.read_csv(CSV).iloc[:600].reset_index(drop=True)


@pytest.fixture
def bag(tmp_path, monkeypatch, dfki) -> Path:
    """A folder (the current one) with a ROS 2 bag `b` of the DFKI trial and `bag.toml` reading it."""
    write_bag(tmp_path / "b", dfki)
    bag_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def unchanged(folder: Path, before: dict, argv: list[str], capsys, *named: str) -> str:
    """`argv` exits 2 naming each of `named` and leaves every file under `folder` as it was."""
    err = exits_2(capsys, argv, *named)
    assert snapshot(folder) == before, err
    return err


# ---------------------------------------------------------------------------------------------- inputs of a run
@pytest.mark.parametrize("target", ["b/metadata.yaml", "b/b.mcap", "b/new.json"])
@pytest.mark.parametrize("flag", ["--json", "--final"])
def test_no_output_lands_in_a_bag(bag, capsys, target, flag):
    before = snapshot(bag)
    command = ["check"] if flag == "--json" else ["online", "--stream"]
    argv = [*command, "--problem", "bag.toml", "--data", "b", flag, target]
    unchanged(bag, before, argv, capsys, target, "input folder b")


def test_a_bag_given_by_its_storage_file_protects_its_folder(bag, capsys):
    before = snapshot(bag)
    unchanged(
        bag, before, ["check", "--problem", "bag.toml", "--data", "b/b.mcap", "--json", "b/metadata.yaml"], capsys
    )


def test_an_out_folder_inside_a_bag_is_refused_before_any_work(bag, capsys):
    before = snapshot(bag)
    unchanged(bag, before, ["compare", "--problem", "bag.toml", "--data", "b", "--out", "b/r", "--no-progress"], capsys)


@pytest.mark.parametrize(
    "argv",
    [
        ["check", "--json", "arm.urdf"],
        ["compare", "--json", "arm.urdf", "--no-progress"],
        ["online", "--stream", "--final", "arm.urdf"],
        ["export", "--format", "urdf", "--out", "arm.urdf"],
        ["check", "--json", "mesh.stl"],
        ["check", "--json", "trial.csv", "--data", "other.csv"],  # listed in [data] though not read this run
    ],
    ids=["check", "compare", "online", "export", "mesh", "listed-trial"],
)
def test_no_output_lands_on_the_urdf_its_meshes_or_a_listed_trial(arm3, capsys, argv):
    (arm3 / "arm.urdf").write_text(
        TWISTED.replace(
            '<link name="l3">', '<link name="l3"><visual><geometry><mesh filename="mesh.stl"/></geometry></visual>'
        )
    )
    (arm3 / "mesh.stl").write_bytes(b"solid x\nendsolid x\n")
    _motion().to_csv(arm3 / "other.csv", index=False)
    before = snapshot(arm3)
    target = argv[argv.index("--json" if "--json" in argv else "--final" if "--final" in argv else "--out") + 1]
    unchanged(arm3, before, [argv[0], "--problem", "p.toml", *argv[1:]], capsys, target, "is also an input")


def test_codegen_out_onto_the_problem_file_is_refused_even_with_force(tmp_path, monkeypatch, capsys):
    small_problem(tmp_path)
    (tmp_path / "p.toml").rename(tmp_path / "README.md")  # codegen writes README.md into --out
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    argv = ["codegen", "--problem", "README.md", "--out", ".", "--force"]
    unchanged(tmp_path, before, argv, capsys, "README.md", "is also an input")


def test_an_out_folder_keeps_a_readme_it_did_not_write(tmp_path, monkeypatch, capsys):
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "README.md").write_text("# my notes\n")
    before = snapshot(tmp_path)
    argv = ["compare", "--problem", "p.toml", "--out", "r", "--no-progress"]
    unchanged(tmp_path, before, argv, capsys, "r/README.md", "not written by ident-opt")


def test_an_out_folder_readme_ident_opt_wrote_is_rebuilt_and_an_edited_one_kept(tmp_path, monkeypatch, capsys):
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    argv = ["compare", "--problem", "p.toml", "--out", "r", "--no-progress"]
    assert main(argv) == 0
    first = (tmp_path / "r" / "README.md").read_text()
    assert main(argv) == 0 and (tmp_path / "r" / "README.md").read_text() == first  # its own: rebuilt
    with open(tmp_path / "r" / "README.md", "a") as fh:
        fh.write("my edit\n")
    capsys.readouterr()
    before = snapshot(tmp_path)
    unchanged(tmp_path, before, argv, capsys, "r/README.md", "edited since")


@pytest.mark.parametrize("target", ["r/README.md", "r/.manifest", "r/.manifest/compare.json"])
def test_a_json_onto_the_out_folders_index_is_refused_before_any_work(tmp_path, monkeypatch, capsys, target):
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    argv = ["compare", "--problem", "p.toml", "--out", "r", "--json", target, "--no-progress"]
    unchanged(tmp_path, before, argv, capsys, target, "keeps its index there")
    assert not (tmp_path / "r").exists()


def test_a_folder_indexed_before_digests_were_kept_is_still_ident_opts(tmp_path, monkeypatch, capsys):
    """results/ of an earlier version: manifests and a README.md but no digest of it: rebuilt, digest kept."""
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    argv = ["compare", "--problem", "p.toml", "--out", "r", "--no-progress"]
    assert main(argv) == 0
    (tmp_path / "r" / ".manifest" / "README.md.sha256").unlink()
    (tmp_path / "r" / "README.md").write_text("# Results\n\nan older index\n")
    assert main(argv) == 0
    assert "older index" not in (tmp_path / "r" / "README.md").read_text()
    assert (tmp_path / "r" / ".manifest" / "README.md.sha256").is_file()


@pytest.mark.parametrize(
    ("make", "named"),
    [
        (lambda r: (r / ".manifest").write_text("not a folder"), ".manifest: exists and is not a folder"),
        (lambda r: _manifest(r, "compare.json", "{not json"), "compare.json: is not JSON"),
        (lambda r: _manifest(r, "audit.json", "[1, 2]"), "audit.json: is not a manifest"),
        (lambda r: _manifest(r, "audit.json", '{"study": "audit", "files": 3}'), "audit.json: is not a manifest"),
        (lambda r: (r / ".manifest" / "x.json").mkdir(parents=True), "x.json: cannot be read"),
    ],
    ids=["file", "not-json", "not-object", "wrong-keys", "folder"],
)
def test_a_malformed_manifest_is_named_and_nothing_written(tmp_path, monkeypatch, capsys, make, named):
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "r").mkdir()
    make(tmp_path / "r")
    before = snapshot(tmp_path)
    argv = ["compare", "--problem", "p.toml", "--out", "r", "--json", "c.json", "--no-progress"]
    unchanged(tmp_path, before, argv, capsys, named)


def _manifest(folder: Path, name: str, text: str) -> None:
    (folder / ".manifest").mkdir(parents=True, exist_ok=True)
    (folder / ".manifest" / name).write_text(text)


def test_an_input_folder_is_refused_as_an_output_through_a_run(tmp_path):
    """The rule itself: an output inside a declared input folder, or an output folder inside one."""
    (tmp_path / "bag").mkdir()
    with pytest.raises(InputError, match="inside the input folder"), outputs.run() as run:
        run.declare_inputs([tmp_path / "bag"])
        outputs.write_text(tmp_path / "bag" / "x.json", "{}")
    with pytest.raises(InputError, match="inside the input folder"), outputs.run() as run:
        run.declare_folder(tmp_path / "bag" / "sub")
        run.declare_inputs([tmp_path / "bag"])
    assert not (tmp_path / "bag" / "x.json").exists() and not (tmp_path / "bag" / "sub").exists()


# ---------------------------------------------------------------------------------------------- t and gaps
def test_t_scaled_by_minus_one_is_refused_alike_by_check_and_compare(tmp_path, monkeypatch, capsys):
    """t mapped with scale = -1 runs backwards: both commands convert it first, then drop every row after the
    first (--drop-invalid) and refuse the trial with the same message."""
    path = small_problem(tmp_path)
    text = path.read_text()
    assert "\nt = 0\n" in text
    path.write_text(text.replace("\nt = 0\n", "\nt = { column = 0, scale = -1 }\n", 1))
    monkeypatch.chdir(tmp_path)
    messages = [
        exits_2(capsys, [c, "--problem", "p.toml", "--drop-invalid", "--allow-implausible", *x], "only 1 valid sample")
        for c, x in (("check", []), ("compare", ["--no-progress"]))
    ]
    same = [m.splitlines()[-1].split(", fewer than")[0] for m in messages]  # each command needs its own count
    assert same[0] == same[1], messages


@pytest.mark.parametrize("gap", [1e5, 1e12])
def test_a_huge_gap_splits_the_trial_into_segments_filtered_alone(tmp_path, gap):
    """A gap of `gap` seconds after 2 s: two segments, each's derivatives what the segment alone gives (nothing
    resampled across the gap)."""
    frame = _motion(n=800)
    before, after = frame.iloc[:200].copy(), frame.iloc[200:].copy()
    after["t"] += gap
    (tmp_path / "arm.urdf").write_text(TWISTED)
    (tmp_path / "p.toml").write_text(ARM3 + "[data]\nderivative_cutoff_hz = 8.0\n")
    problem = load_problem(tmp_path / "p.toml")
    pd.concat([before, after]).to_csv(tmp_path / "gap.csv", index=False)
    before.to_csv(tmp_path / "one.csv", index=False)
    after.to_csv(tmp_path / "two.csv", index=False)
    whole = load_dataset(tmp_path / "gap.csv", problem.data, problem.robot)
    parts = [load_dataset(tmp_path / n, problem.data, problem.robot) for n in ("one.csv", "two.csv")]
    assert any("2 segments" in note for note in whole.notes), whole.notes
    assert np.array_equal(whole.t, np.concatenate([p.t for p in parts]))
    for name in ("q", "dq", "ddq", "tau"):
        assert np.allclose(getattr(whole, name), np.concatenate([getattr(p, name) for p in parts]), atol=1e-9)


def test_a_bag_whose_stamps_jump_a_megasecond_loads_as_two_segments(tmp_path, capsys, dfki):
    jumped = dfki.copy()
    jumped.loc[300:, "time"] += 1e6
    write_bag(tmp_path / "jump", jumped)
    problem = load_problem(bag_problem(tmp_path))
    trial = load_dataset(tmp_path / "jump", problem.data, problem.robot)
    assert any("2 segments" in note for note in trial.notes), trial.notes
    assert trial.t[-1] > 1e6 and np.all(np.diff(trial.t) > 0) and np.isfinite(trial.ddq).all()


# ---------------------------------------------------------------------------------------------- URDF at load
#: Links c1 and c2 hanging from each other by fixed joints (joint a moved onto c1 in the "fixed-cycle" case).
CYCLE = (
    '<link name="c1"/><link name="c2"/><joint name="x1" type="fixed"><parent link="c1"/><child link="c2"/></joint>'
    '<joint name="x2" type="fixed"><parent link="c2"/><child link="c1"/></joint>'
)
#: A hostile edit of `TWISTED`: (text to replace, replacement, words the message must hold).
URDF_CASES = {
    "mass-macro": ('<mass value="2.0"/>', '<mass value="${m}"/>', ("'l1'", "mass value='${m}'")),
    "mass-nan": ('<mass value="2.0"/>', '<mass value="nan"/>', ("'l1'", "'nan'")),
    "inertia-minus-inf": ('ixx="0.02"', 'ixx="-inf"', ("'l1'", "ixx='-inf'")),
    "mass-negative": ('<mass value="1.2"/>', '<mass value="-1.2"/>', ("'l2'", "'-1.2'")),
    "mass-1e30": ('<mass value="0.8"/>', '<mass value="1e30"/>', ("'l4'", "'1e30'")),
    "inertia-negative": ('ixx="0.004" ixy="0"', 'ixx="-0.004" ixy="0"', ("'l2'", "below 0")),
    "inertia-triangle": ('iyy="0.03" iyz="0" izz="0.03"', 'iyy="0.01" iyz="0" izz="0.03"', ("'l2'", "triangle")),
    "axis-zero": ('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>', ("'a'", "non-zero axis")),
    "joint-200-m": ('<origin xyz="0.4 0 0" rpy="0 1.2 0"/>', '<origin xyz="200 0 0" rpy="0 1.2 0"/>', ("'c'", "200")),
    "com-200-m": ('<origin xyz="0.2 0.01 0"/>', '<origin xyz="0.2 200 0"/>', ("'l2'", "200")),
    "joint-named-like-a-link": ('<link name="l1">', '<link name="b">', ("'b'", "name of a <link>")),
    "fixed-cycle": (
        '<parent link="base"/>\n    <child link="l1"/>',
        '<parent link="c1"/>\n    <child link="l1"/>',
        ("cycle", "c1"),
    ),
    "self-loop": (  # urdfdom and Pinocchio recursed on this without end (a segfault, found by make fuzz)
        "</robot>",
        '<joint name="loop" type="fixed"><parent link="l2"/><child link="l2"/></joint></robot>',
        ("'loop'", "the same link 'l2'"),
    ),
    "two-parents": (
        "</robot>",
        '<joint name="again" type="fixed"><parent link="l1"/><child link="l4"/></joint></robot>',
        ("'l4'", "child of two joints"),
    ),
    "unknown-type": ('<joint name="c" type="revolute">', '<joint name="c" type="x">', ("'c'", "not a URDF joint type")),
    "no-limit": (
        '<limit effort="1" lower="-3" upper="3" velocity="1"/></joint>\n  <link name="l4">',
        '</joint>\n  <link name="l4">',
        ("'c'", "needs <limit"),
    ),
    "negative-effort": ('<limit effort="1" lower="-3"', '<limit effort="-1" lower="-3"', ("'a'", "effort='-1'")),
    "lower-above-upper": (
        'lower="-3" upper="3" velocity="1"/></joint>\n  <link name="l1">',
        'lower="3" upper="-3" velocity="1"/></joint>\n  <link name="l1">',
        ("'a'", "above upper"),
    ),
    "all-a-cycle": (
        '<link name="world"/>',
        '<link name="world"/><joint name="back" type="fixed"><parent link="l4"/><child link="world"/></joint>',
        ("cycle",),
    ),
}


@pytest.mark.parametrize("case", sorted(URDF_CASES))
def test_a_bad_urdf_is_refused_at_load_naming_the_element(arm3, capsys, case):
    old, new, named = URDF_CASES[case]
    text = TWISTED.replace(old, new, 1)
    if case == "joint-named-like-a-link":
        text = text.replace('link="l1"', 'link="b"')
    if case == "fixed-cycle":
        text = text.replace("</robot>", CYCLE + "</robot>")
    assert text != TWISTED
    (arm3 / "arm.urdf").write_text(text)
    before = snapshot(arm3)
    unchanged(arm3, before, ["check", "--problem", "p.toml", "--json", "c.json"], capsys, "arm.urdf", *named)


@pytest.mark.parametrize("command", ["codegen", "compare"])
def test_a_negative_mass_stops_codegen_and_compare_before_any_file(arm3, capsys, command):
    (arm3 / "arm.urdf").write_text(TWISTED.replace('<mass value="1.2"/>', '<mass value="-1.2"/>'))
    before = snapshot(arm3)
    argv = [command, "--problem", "p.toml", "--out", "out"] + (["--no-progress"] if command == "compare" else [])
    unchanged(arm3, before, argv, capsys, "'l2'", "mass value='-1.2'")
    assert not (arm3 / "out").exists()


def _planar_case(folder: Path, edit) -> Path:
    """problems/dfki_c0_urdf.toml's robot (planar-form [robot.joint1] tables) on an edited copy of its URDF."""
    text = (ROOT / "problems" / "dfki_c0_urdf.toml").read_text()
    robot = text[: text.index("[data]")]
    urdf, robot = edit((ROOT / "problems" / "dfki_c0.urdf").read_text(), robot)
    (folder / "dfki.urdf").write_text(urdf)
    path = folder / "p.toml"
    path.write_text(robot.replace('urdf = "dfki_c0.urdf"', 'urdf = "dfki.urdf"'))
    return path


@pytest.mark.parametrize(
    ("edit", "why"),
    [
        (lambda u, r: (u, r.replace("gravity = 9.81", "gravity = [-9.81, 0, 0]")), "gravity is along the joint axes"),
        (lambda u, r: (u.replace('<origin xyz="0 0 -0.2"', '<origin xyz="0 0.05 -0.2"', 1), r), "off the line"),
        (lambda u, r: (u.replace('<axis xyz="1 0 0"/>', '<axis xyz="0 0 0"/>', 1), r), "non-zero axis"),
    ],
    ids=["gravity-along-axes", "com-off-line", "zero-axis"],
)
def test_a_two_joint_urdf_that_is_not_planar_says_why(tmp_path, capsys, edit, why):
    path = _planar_case(tmp_path, edit)
    err = exits_2(capsys, ["check", "--problem", str(path)], why)
    assert "unknown key" not in err


# ---------------------------------------------------------------------------------------------- problem files
@pytest.mark.parametrize("nested", ["[" * 5000 + "]" * 5000, "{ a = " * 5000 + "1" + " }" * 5000])
def test_a_problem_nested_5000_deep_is_refused(tmp_path, capsys, nested):
    (tmp_path / "p.toml").write_text(f'name = "x"\nv = {nested}\n')
    exits_2(capsys, ["check", "--problem", str(tmp_path / "p.toml")], "p.toml", "nested too deeply")


def test_residual_settings_that_collapse_the_gmr_name_the_keys():
    """components = 50 on 100 samples with reg_covar = 1e-300 (each within its range): an input error naming
    [residual] and its keys, not scikit-learn's ValueError."""
    rng = np.random.default_rng(0)
    X, R = rng.standard_normal((400, 6)), rng.standard_normal((400, 2))
    with pytest.raises(InputError, match=r"\[residual\].*50 components.*100 training samples.*reg_covar"):
        GMR(n_components=50, reg_covar=1e-300, max_train_samples=100).fit(X, R)


@pytest.mark.parametrize(
    "reference",
    ["[reference.parameters]\nnowhere = 1.0", 'urdf = "arm.urdf"', "[reference.parameters]\n"],
    ids=["unknown-name", "urdf-on-planar", "empty"],
)
def test_check_refuses_the_reference_compare_refuses(tmp_path, monkeypatch, capsys, reference):
    path = small_problem(tmp_path)
    path.write_text(path.read_text() + f'\n[reference]\nlabel = "x"\n{reference}\n')
    (tmp_path / "arm.urdf").write_text(TWISTED)
    monkeypatch.chdir(tmp_path)
    messages = [
        exits_2(capsys, [c, "--problem", "p.toml", *x], "[reference")
        for c, x in (("check", []), ("compare", ["--no-progress"]))
    ]
    assert messages[0] == messages[1]


# ---------------------------------------------------------------------------------------------- n joints
def test_n_joint_constant_torque_is_refused_by_compare_and_warned_by_check(arm3, capsys):
    frame = _motion()
    frame["tau2"] = 0.5
    frame.to_csv(arm3 / "trial.csv", index=False)
    exits_2(capsys, ["compare", "--problem", "p.toml", "--no-progress"], "joint 2 is constant")
    assert main(["check", "--problem", "p.toml"]) == 0
    assert "warning: " in capsys.readouterr().err


def test_columns_of_more_joints_than_the_problem_names_are_refused(arm3, capsys):
    frame = _motion()
    frame["q4"], frame["tau4"] = frame["q1"], frame["tau1"]
    frame.to_csv(arm3 / "trial.csv", index=False)
    exits_2(capsys, ["check", "--problem", "p.toml"], "trial.csv", "q4, tau4", "3 joints")


# ---------------------------------------------------------------------------------------------- bag messages
@pytest.mark.parametrize(
    ("column", "value", "named"),
    [
        ("pos_meas1", np.inf, "column 'q1' has the value inf at message 6 of topic '/joint_states'"),
        ("pos_meas2", -np.inf, "column 'q2' has the value -inf at message 6 of topic '/joint_states'"),
        ("tau_meas2", np.nan, "column 'tau2' has the value nan at message 6 of topic '/joint_states'"),
    ],
)
def test_a_bad_bag_value_is_named_as_a_value_at_its_message(tmp_path, capsys, dfki, column, value, named):
    frame = dfki.copy()
    frame.loc[5, column] = value
    write_bag(tmp_path / "b", frame)
    err = exits_2(capsys, ["check", "--problem", str(bag_problem(tmp_path)), "--data", str(tmp_path / "b")], named)
    assert "empty cell" not in err and "data row" not in err


def test_a_topic_of_another_message_type_is_named_with_its_type(tmp_path, capsys):
    from rosbags.rosbag2 import Writer

    value = STORE.types["std_msgs/msg/Float64"]
    with Writer(tmp_path / "b", version=9) as writer:
        connection = writer.add_connection("/joint_states", value.__msgtype__, typestore=STORE)
        for k in range(5):
            writer.write(connection, 10**9 + k * 10**7, STORE.serialize_cdr(value(data=1.0), value.__msgtype__))
    argv = ["check", "--problem", str(bag_problem(tmp_path)), "--data", str(tmp_path / "b")]
    exits_2(capsys, argv, "std_msgs/msg/Float64", "not sensor_msgs/msg/JointState")


@pytest.mark.parametrize(
    ("value", "shown"),
    [(np.float64("inf"), "inf"), (np.float32(1.5), "1.5"), (np.array([1.0, np.nan]), "[1.0, nan]"), ("x", "'x'")],
)
def test_messages_show_values_as_python_writes_them(value, shown):
    assert excerpt(value) == shown


# ---------------------------------------------------------------------------------------------- also noticed
def test_sigterm_ends_a_run_with_a_message_and_rolls_it_back(tmp_path, monkeypatch, capsys):
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    import ident_opt.commands.check as check

    def slow_start(args):
        outputs.write_text("half.json", "{}")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(30)  # the handler interrupts this

    monkeypatch.setattr(check, "run", slow_start)
    started = time.monotonic()
    assert main(["check", "--problem", "p.toml"]) == 128 + signal.SIGTERM
    assert time.monotonic() - started < 20
    assert "terminated (SIGTERM)" in capsys.readouterr().err
    assert not (tmp_path / "half.json").exists()
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL or callable(signal.getsignal(signal.SIGTERM))


def test_held_out_trial_equal_to_the_training_trial_is_warned_about(tmp_path, monkeypatch, capsys):
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "copy.csv").write_bytes((tmp_path / "small.csv").read_bytes())
    for held in ("small.csv", "./small.csv", "copy.csv"):
        assert main(["check", "--problem", "p.toml", "--data", "small.csv", "--test-data", held]) == 0
        err = capsys.readouterr().err
        assert "warning [held_out_is_training]" in err and str(Path(held)) in err, err
    assert main(["check", "--problem", "p.toml", "--data", "small.csv"]) == 0
    assert "held_out_is_training" not in capsys.readouterr().err


#: The commands that score held-out trials, each with its flags beyond --problem/--data/--test-data/--json and the
#: report that must carry the warning (relative to the working folder).
SCORING = {
    "identify": (["--out", "out", "--no-variants"], "out/README.md"),
    "compare": (["--out", "out", "--no-progress"], "out/compare.md"),
    "diagnose": (["--out", "out", "--no-progress"], "out/diagnosis.md"),
    "audit": (["--out", "out"], "out/paper_audit.md"),
}


@pytest.mark.parametrize("command", list(SCORING))
def test_a_held_out_trial_that_trains_is_a_warning_of_the_result(command, tmp_path, monkeypatch, capsys):
    """The warning is part of the result wherever a held-out score is written: terminal, report and JSON
    `warnings` (it was printed on the terminal only)."""
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    flags, report = SCORING[command]
    base = [command, "--problem", "p.toml", "--data", "small.csv", *flags, "--json", "r.json"]
    assert main([*base, "--test-data", "./small.csv"]) == 0
    assert "warning [held_out_is_training]" in capsys.readouterr().err
    codes = [w["code"] for w in json.loads(Path("r.json").read_text())["warnings"]]
    assert codes.count("held_out_is_training") == 1, codes
    text = Path(report).read_text()
    assert "held_out_is_training" in text and "small.csv (held out) is the training trial" in text


def test_strict_json_of_a_check_on_a_bag(bag, capsys):
    assert main(["check", "--problem", "bag.toml", "--data", "b", "--json", "c.json"]) == 0
    json.loads((bag / "c.json").read_text(), parse_constant=lambda token: pytest.fail(f"non-strict JSON: {token}"))


# ---------------------------------------------------------------------------------------------- fuzz findings
@pytest.mark.parametrize("ratio", [1e-2, 1e-4, 1e-5])
def test_the_zero_phase_filter_is_exact_far_below_nyquist(ratio):
    """A cut-off at `ratio` of Nyquist over 4 of its periods: a sine at a tenth of it passes unchanged (as
    (b, a) the filter gave 1e37 at 2e-5, then a traceback; found by make fuzz)."""
    from ident_opt.numerics.derivatives import lowpass

    fs, n = 1000.0, round(8 / ratio)
    cutoff = ratio * fs / 2
    t = np.arange(n) / fs
    x = np.sin(2 * np.pi * 0.1 * cutoff * t)[:, None]
    y = lowpass(t, x, cutoff)
    assert np.isfinite(y).all() and np.abs(y - x)[n // 4 : -n // 4].max() < 1e-4


def test_a_cut_off_far_below_the_trial_is_an_input_error_not_a_traceback(arm3, capsys):
    frame = _motion(n=120, rate=1000.0)
    frame["t"] += 1e-6 * np.sin(np.arange(120))  # jitter: the segment is resampled too
    frame.to_csv(arm3 / "trial.csv", index=False, float_format="%.17g")
    (arm3 / "p.toml").write_text(ARM3 + '[data]\ntrials = ["trial.csv"]\nderivative_cutoff_hz = 1e-3\n')
    exits_2(capsys, ["compare", "--problem", "p.toml", "--json", "c.json", "--no-progress"], "trial.csv", "1/0.001 Hz")
    assert not (arm3 / "c.json").exists()


@pytest.mark.parametrize("flag", [["--json", ""], ["--out", " "]])
def test_an_empty_output_path_is_refused_before_any_work(arm3, capsys, flag):
    before = snapshot(arm3)
    argv = (
        ["export", "--problem", "p.toml", "--format", "urdf", *flag]
        if flag[0] == "--out"
        else ["check", "--problem", "p.toml", *flag]
    )
    unchanged(arm3, before, argv, capsys, flag[0], "empty path")
