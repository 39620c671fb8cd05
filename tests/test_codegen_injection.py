"""Hostile names at `ident-opt codegen`: a URDF's joint and link names are data, never code.

A joint name that closes the C string and the array of pi_update.c's parameter names and adds a constructor ran a
shell command while codegen built and checked the library (exit 0), and shipped inside it. Every name now enters
the generated C as an escaped string literal (`c_update.c_string`) and the README escaped (`codegen.markdown_text`):
codegen succeeds, nothing planted runs (during its own build and check, nor when the libraries are loaded here),
and the names come back byte for byte from parameters.json, from the C example's JSON and from the library itself.
"""

from __future__ import annotations

import ctypes
import json
import shutil
import subprocess
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pandas as pd
import pytest

from ident_opt.adaptation.c_update import c_string
from ident_opt.cli import main
from ident_opt.problem import load_problem
from ident_opt.shipping import codegen

needs_cc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

#: A three-joint arm (as tests/test_urdf_arm.py's TWISTED) with its joints {a} {b} {c} and moving links {l1} {l2}
#: {l4} to fill in, as quoted XML attributes.
URDF = """<?xml version="1.0"?>
<robot name="hostile">
  <link name="world"/>
  <joint name="mount" type="fixed"><origin xyz="0.1 0 0.2" rpy="0.3 0 0"/><parent link="world"/>
    <child link="base"/></joint>
  <link name="base"/>
  <joint name={a} type="revolute"><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><parent link="base"/>
    <child link={l1}/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <link name={l1}><inertial><mass value="2.0"/><origin xyz="0.01 -0.05 0.1" rpy="0.2 0.1 0"/>
    <inertia ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.015" iyz="0.003" izz="0.01"/></inertial></link>
  <joint name={b} type="continuous"><origin xyz="0.05 0.02 0.3" rpy="0.1 -0.4 0.7"/><axis xyz="1 2 -0.5"/>
    <parent link={l1}/><child link={l2}/></joint>
  <link name={l2}><inertial><mass value="1.2"/><origin xyz="0.2 0.01 0"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.03"/></inertial></link>
  <joint name="tool" type="fixed"><origin xyz="0.4 0 0"/><parent link={l2}/><child link="l3"/></joint>
  <link name="l3"><inertial><mass value="0.5"/><origin xyz="0 0 0.02"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
  <joint name={c} type="revolute"><origin xyz="0.4 0 0" rpy="0 1.2 0"/><axis xyz="0 -1 0"/><parent link={l2}/>
    <child link={l4}/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <link name={l4}><inertial><mass value="0.8"/><origin xyz="0 0.1 0.05"/>
    <inertia ixx="0.002" ixy="0.0001" ixz="0" iyy="0.001" iyz="0" izz="0.002"/></inertial></link>
</robot>
"""

#: The review's payload: close the string and the array, add a constructor that runs a shell command, reopen.
ONE_LINE = (
    'j1"}};__attribute__((constructor)) static void p(void){{system("touch {pwned}");}} static const char*x[]={{"'
)
#: The same as a payload that builds (exit 0) and ran on the unescaped code: its newlines (&#10; in the URDF) let
#: it guard its constructor, and name each reopened array by its line, as the name enters the C more than once.
GUARDED = (
    'j1"}};\n#ifndef ONCE\n#define ONCE\n#define CAT2(a,b) a##b\n#define CAT(a,b) CAT2(a,b)\n'
    'int system(const char*);\n__attribute__((constructor)) static void p(void){{system("touch {pwned}");}}\n'
    '#endif\nstatic const char*CAT(x,__LINE__)[]={{"'
)
#: Other names that broke the C or the README: quotes, backslashes, trigraphs, comment ends, format directives, a
#: line splice, line breaks, Markdown and HTML, non-ASCII (a bidirectional override too), a tab, a long name.
OTHERS = {
    "b": "q\"\\ */ /* ??/ ??= ??' %s %n, x\\\r\n#define Y",
    "c": "Gelenk_ä ✓ 😀 \u202e",
    "l1": "*/ x; /* `md` [l](http://x) <b>bold</b> &amp; | ~~s~~",
    "l2": "Glied_ö\t" + "L" * 300,
    "l4": "a\\\nb",
}


def _toml(text: str) -> str:
    """`text` as a TOML basic string."""
    escaped = "".join(
        f"\\u{ord(ch):04x}" if ch in '"\\' or ord(ch) < 0x20 or 0x7F <= ord(ch) < 0xA0 else ch for ch in text
    )
    return f'"{escaped}"'


def _problem(folder: Path, names: dict[str, str]) -> Path:
    """A three-joint URDF problem in `folder` with the names `names` (joints a, b, c; links l1, l2, l4) and one
    trial of 400 samples."""
    every = {"a": "a", "b": "b", "c": "c", "l1": "l1", "l2": "l2", "l4": "l4", **names}
    attributes = {k: quoteattr(v, {"\n": "&#10;", "\r": "&#13;", "\t": "&#9;"}) for k, v in every.items()}
    (folder / "arm.urdf").write_text(URDF.format(**attributes), encoding="utf-8")
    joints = ", ".join(_toml(every[k]) for k in "abc")
    path = folder / "arm.toml"
    path.write_text(
        f'name = "hostile"\n[robot]\nurdf = "arm.urdf"\njoints = [{joints}]\ngravity = 9.81\n'
        '[data]\ntrials = ["trial.csv"]\n',
        encoding="utf-8",
    )
    arm = load_problem(path).robot.arm
    t = np.arange(400) * 0.01
    frame = pd.DataFrame({"t": t})
    for s, scale in (("q", 1.0), ("dq", 1.0), ("ddq", 3.0)):
        for j in range(3):
            frame[f"{s}{j + 1}"] = scale * np.sin(0.3 * (j + 1) * (2 + j) * t + s.count("d"))
    q, dq, ddq = (frame[[f"{s}{j}" for j in (1, 2, 3)]].to_numpy() for s in ("q", "dq", "ddq"))
    truth = arm.cad_parameters()
    truth[arm.n_link_params :] = 0.2
    tau = arm.predict(truth, q, dq, ddq) + 0.01 * np.random.default_rng(0).standard_normal((400, 3))
    for j in range(3):
        frame[f"tau{j + 1}"] = tau[:, j]
    frame.to_csv(folder / "trial.csv", index=False)
    return path


@needs_cc
@pytest.mark.parametrize("case", ["guarded", "hostile"])
def test_hostile_names_are_data_not_code(tmp_path, case):
    pwned = tmp_path / "PWNED"
    names = {"a": GUARDED.format(pwned=pwned)} if case == "guarded" else {"a": ONE_LINE.format(pwned=pwned), **OTHERS}
    problem = _problem(tmp_path, names)
    robot = load_problem(problem).robot
    joints, parameters = list(robot.joint_names), list(robot.arm.names)
    assert joints[0] == names["a"]  # the URDF and problem file carry the names as they are
    out = tmp_path / "c"
    argv = ["codegen", "--problem", str(problem), "--out", str(out), "--estimator", "consistent"]
    code = main([*argv, "--allow-implausible"])
    assert not pwned.exists(), "a joint name ran as code during codegen's build and check"
    assert code == 0

    # Loading the shipped libraries runs nothing planted either; the names are in pi_update's library, byte exact.
    ctypes.CDLL(str(out / codegen.library_name()))
    library = ctypes.CDLL(str(out / "libpi_update.so"))
    saved = json.loads((out / "parameters.json").read_text(encoding="utf-8"))
    online = saved["pi_update"]
    in_c = list((ctypes.c_char_p * online["parameters"]).in_dll(library, "PI_UPDATE_NAMES"))
    assert in_c == [name.encode() for name in online["final_python"]]
    assert not pwned.exists(), "a joint name ran as code when the library was loaded"

    # parameters.json and the C example's JSON report the names as they are.
    assert saved["joints"] == joints and list(saved["parameters"]) == parameters
    for key, name in names.items():
        assert (f"fv_{name}" if key in "abc" else f"m_{name}") in parameters
    assert list(online["final_c_example"]) == list(online["final_python"])

    # Every generated C file is plain ASCII and builds warning-free in ISO C (trigraphs on); main.c runs.
    sources = sorted(out.glob("*.[ch]"))
    assert all(path.read_bytes().isascii() for path in sources)
    update = (out / "pi_update.c").read_text(encoding="ascii")
    assert all(c_string(name) in update for name in online["final_python"])  # each name as one escaped literal
    strict = ["gcc", "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wtrigraphs", "-Werror", "-c"]
    subprocess.run([*strict, "pi_update.c", "-o", str(tmp_path / "u.o")], cwd=out, check=True, capture_output=True)
    build = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "main.c", "-L.", "-lident_opt_model"]
    subprocess.run([*build, "-Wl,-rpath,.", "-o", "example", "-lm"], cwd=out, check=True, capture_output=True)
    subprocess.run(["./example"], cwd=out, check=True, capture_output=True)
    assert not pwned.exists()

    # The README shows the names escaped, each on the line it belongs to: no heading or block of theirs. (Its
    # section on a URDF's angles, which `report.codegen` appends, is not `codegen.write_readme`'s: left out here.)
    readme = (out / "README.md").read_text(encoding="utf-8").split("\n## This robot's angles")[0]
    template = (codegen.FILES / "README.md").read_text(encoding="utf-8")
    assert [line for line in readme.splitlines() if line.startswith("#")][1:] == [
        line for line in template.splitlines() if line.startswith("#")
    ][1:]
    assert "\n#define" not in readme and "\n#ifndef" not in readme and "<b>" not in readme
    written = next(line for line in readme.splitlines() if line.startswith("Written by"))
    assert written.count(", ") >= 2 and all(codegen.markdown_text(j) in written for j in joints)


#: Strings whose bytes must come back from the C literal exactly: every byte, trigraphs, quotes, backslashes, line
#: breaks, a line splice, an escape followed by digits (a hex escape would swallow them), non-ASCII, a lone surrogate.
NASTY = [
    bytes(range(256)),
    bytes(range(255, -1, -1)),
    "".join(map(chr, range(256))),
    "??/",
    "??=??(??)??'??<??!??>??-???/",
    '"',
    "\\",
    "\n",
    "a\\\nb",
    "\x0012\x01789\x7fff\x80" + "0" * 3,
    '"};int x;/*',
    "*/ // \r\n",
    "Gelenk_ä ✓ 😀 \u202e\ufeff",
    "\ud800",
    "",
    "%s%n",
]


@needs_cc
def test_c_string_is_a_literal_of_exactly_the_bytes(tmp_path):
    """The escaped literals, printed by a C program built in ISO C (trigraphs on), are the strings' bytes."""
    compiler = codegen.find_compiler()
    expected = [s.encode("utf-8", "surrogatepass") if isinstance(s, str) else s for s in NASTY]
    literals = [c_string(s) for s in NASTY]
    for literal in literals:
        assert literal.isascii() and literal.isprintable() and "??" not in literal
    table = ",\n".join(f"  {{{literal}, sizeof {literal} - 1}}" for literal in literals)
    program = (
        "#include <stdio.h>\n"
        "static const struct { const char *s; unsigned long n; } T[] = {\n" + table + "\n};\n"
        "int main(void) {\n"
        "  for (unsigned long i = 0; i < sizeof T / sizeof T[0]; ++i) {\n"
        '    printf("%lu:", T[i].n);\n'
        "    fwrite(T[i].s, 1, T[i].n, stdout);\n"
        "  }\n"
        "  return 0;\n"
        "}\n"
    )
    (tmp_path / "t.c").write_text(program, encoding="ascii")
    flags = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wtrigraphs", "-Werror"]
    subprocess.run([*compiler, *flags, "t.c", "-o", "t"], cwd=tmp_path, check=True, capture_output=True)
    got = subprocess.run([str(tmp_path / "t")], check=True, capture_output=True).stdout
    assert got == b"".join(str(len(e)).encode() + b":" + e for e in expected)


def test_markdown_keeps_names_on_their_line():
    assert codegen.markdown_text("panda_joint1") == "panda_joint1"  # ordinary names unchanged
    assert codegen.markdown_text("a\n# b <i>") == "a\\\\u000a\\# b \\<i\\>"
    assert codegen.markdown_code("7-joint arm") == "`7-joint arm`"
    assert codegen.markdown_code("a`b\u2028") == "``a`b\\u2028``"
    assert codegen.markdown_code("`x`") == "`` `x` ``"


def test_export_comment_and_readme_angles_cannot_be_closed_by_a_name():
    # An XML comment may not hold "--" (a name with "--->" would close it and inject XML), and the README's
    # angle block must not be closed by a name holding a newline and a fence.
    import xml.etree.ElementTree as ET

    from ident_opt.report.codegen import _urdf_angles
    from ident_opt.shipping.urdf import comment

    root = ET.Element("robot")
    root.append(comment(["joint a--->b<evil/>", "x---y-", "----"]))
    text = ET.tostring(root, encoding="unicode")
    inner = text[text.index("<!--") + 4 : text.rindex("-->")]
    assert "--" not in inner and "<evil/>" in inner  # the name is kept, as comment text
    assert [e.tag for e in ET.fromstring(text)] == []  # nothing but the comment: no element injected

    section = _urdf_angles(["q1 = sign × q_urdf(j1\n```\n# injected\n````) + 0.1"])
    fence = section.split("\n\n")[-1].split("\n")[0]
    assert set(fence) == {"`"} and section.rstrip("\n").endswith(fence)
    body = section.rstrip("\n")[: -len(fence)].split(fence + "\n", 1)[1]
    assert "\n# injected" not in body and fence not in body
