"""The Python API (`docs/api.md`): every public name of `ident_opt` resolves, and the worked example of the docs runs
as written (paths made absolute, files written into a temporary folder) and gives what it prints."""

from __future__ import annotations

import contextlib
import io
import re

import ident_opt
from tests.conftest import PROBLEMS

ROOT = PROBLEMS.parent
DOC = ROOT / "docs" / "api.md"


def test_every_public_name_resolves():
    for name in ident_opt.__all__:
        assert getattr(ident_opt, name) is not None, name
    assert set(ident_opt.__all__) <= set(dir(ident_opt))


def test_the_worked_example_runs(tmp_path, monkeypatch):
    code = re.search(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)[1]
    for folder in ("problems/", "data/"):
        code = code.replace(f'"{folder}', f'"{ROOT.as_posix()}/{folder}')
    monkeypatch.chdir(tmp_path)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, str(DOC), "exec"), {})
    lines = printed.getvalue().splitlines()
    assert lines[0].startswith("7-joint arm from the URDF") and lines[1] == "consistent True"
    assert (tmp_path / "kuka_identified.urdf").is_file() and (tmp_path / "kuka_identified.urdf.json").is_file()
    assert (tmp_path / "kuka_identified.xml").is_file()
