"""The package's sizes, as the refactors measure them: the largest modules and every function over 60 lines.

python benchmarks/sizes.py [--limit 60] [--top 5]
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "ident_opt"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=60, help="function length to report above (lines)")
    parser.add_argument("--top", type=int, default=5, help="largest modules to list")
    args = parser.parse_args()
    modules, long = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        rel = path.relative_to(PACKAGE.parent)
        modules.append((text.count("\n"), rel))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > args.limit:
                    long.append((lines, f"{rel}:{node.lineno} {node.name}"))
    print(f"{len(modules)} modules; largest:")
    for lines, rel in sorted(modules, reverse=True)[: args.top]:
        print(f"  {lines:5d}  {rel}")
    print(f"{len(long)} function(s) over {args.limit} lines")
    for lines, where in sorted(long, reverse=True):
        print(f"  {lines:5d}  {where}")


if __name__ == "__main__":
    main()
