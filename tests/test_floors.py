"""The package's floors (`docs/architecture.md`, "Floors"): each package imports only from the floors below it —
module imports, imports inside functions and string tables of module names alike — and the one switch between the
kinds of arm is `arm.kinds.ByKind`: nothing else reads `Robot.kind`."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import ident_opt

PACKAGE = Path(ident_opt.__file__).parent
DOC = PACKAGE.parent / "docs" / "architecture.md"
#: A string that is a whole module name of the package: a table that imports by name (`importlib`).
MODULE_NAME = re.compile(r"ident_opt(\.\w+)+")


def floors() -> dict[str, int]:
    """Unit (a top-level module or subpackage of `ident_opt`, or the package itself) → its floor, from the doc."""
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index("## Floors") :]
    out = {}
    for floor, cell in re.findall(r"^\| (\d+) \| (.+?) \|$", section, re.M):
        for name in re.findall(r"`([\w_]+)`", cell):
            out[name] = int(floor)
    return out


def unit(module: str) -> str:
    """The unit of a dotted module name of the package (`ident_opt.diagnosis.rounds` → `diagnosis`)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "ident_opt"


def _runtime_nodes(tree: ast.AST):
    """Every node but those under `if TYPE_CHECKING:`."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        yield node
        yield from _runtime_nodes(node)


def references(path: Path, module: str) -> set[str]:
    """The package's modules `path` reaches: its imports anywhere in the file, and its string constants that are
    whole module names."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = set()
    for node in _runtime_nodes(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("ident_opt")}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            if base == "ident_opt":
                out |= {f"ident_opt.{a.name}" for a in node.names}
            elif base.startswith("ident_opt"):
                out.add(base)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and MODULE_NAME.fullmatch(node.value):
            out.add(node.value)
    return out


def modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def test_every_unit_has_a_floor():
    known = floors()
    units = {unit(m) for m in modules()}
    assert units <= set(known), sorted(units - set(known))


def test_every_import_points_down():
    known = floors()
    wrong = []
    for module, path in modules().items():
        here = unit(module)
        for target in references(path, module):
            there = unit(target)
            if there in ("__version__",) or there == here:
                continue
            if known[there] >= known[here]:
                wrong.append(f"{module} (floor {known[here]}) -> {target} (floor {known[there]})")
    assert wrong == []


def test_the_checker_sees_strings_and_function_imports(tmp_path):
    """A string table and an import inside a function count, an import for the type checker does not."""
    path = tmp_path / "probe.py"
    path.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from ident_opt.report import x\n"
        "TABLE = {'a': 'ident_opt.diagnosis.rounds', 'b': 'see ident_opt.report for more'}\n"
        "def f():\n    from ident_opt.simulator import trial\n"
    )
    assert references(path, "ident_opt.effects.probe") == {"ident_opt.diagnosis.rounds", "ident_opt.simulator"}


def test_only_the_factory_asks_which_kind_of_arm():
    """`Robot.kind` is read by `arm.kinds` alone (and set by the two robots); no `engine ==` anywhere."""
    readers = []
    for module, path in modules().items():
        text = path.read_text(encoding="utf-8")
        if module in ("ident_opt.arm.kinds",):
            continue
        for line in text.splitlines():
            code = line.split("#")[0]
            if re.search(r"\brobot\.kind\b|\bengine\s*==", code):
                readers.append(f"{module}: {line.strip()}")
    assert readers == []


def test_no_module_but_the_console_script_has_an_entry_point_or_knows_the_repository():
    """Scripts live in `benchmarks/`: inside the package only `cli.py` (the console script) has a `main()` or a
    `__main__` block, and no module computes the repository's root from its own path (`Path(__file__)` two folders up or
    more)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and node.name == "main" and rel != "cli.py":
                found.append(f"{rel}: def main")
            if isinstance(node, ast.If) and "__main__" in ast.unparse(node.test) and rel != "cli.py":
                found.append(f"{rel}: __main__ block")
            if isinstance(node, ast.Attribute) and node.attr in ("parent", "parents"):
                inner = ast.unparse(node.value)  # `.parents[k]`, or `.parent` of a `.parent`: above the package
                if "__file__" in inner and (node.attr == "parents" or ".parent" in inner):
                    found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    assert not found, "\n".join(found)
