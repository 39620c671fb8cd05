"""What `ident-opt codegen` writes: the generated C sources and header, the compiled shared library, the
example `main.c`, a README for embedding (all from `ident_opt.shipping.codegen`), and parameters.json (the parameters
baked in, the estimator, the GMR, the check against Python); with the terminal lines."""

from __future__ import annotations

import re
from pathlib import Path

from ident_opt import outputs
from ident_opt.report import write_json
from ident_opt.shipping.codegen import one_line
from ident_opt.shipping.generate import Built
from ident_opt.shipping.ship import MEASURE, TOLERANCE


def _urdf_angles(statement: list[str]) -> str:
    """The README section of a two-joint URDF arm: its angles are not the C code's; the offsets to apply. The
    statement's lines hold the URDF's names: each is kept on its line (`one_line`) inside a fence longer than any
    run of backticks they hold, so no name can close the block."""
    lines = [one_line(line) for line in statement]
    fence = "`" * max(3, 1 + max((len(run) for line in lines for run in re.findall("`+", line)), default=0))
    return (
        "\n## This robot's angles\n\nThe arm comes from a URDF whose angle zero and axis signs are its own. The C "
        "code takes ident-opt's angles: pass q = sign × q_urdf + offset, and dq, ddq, tau × sign, per joint, as "
        f"ident-opt applied them to the data:\n\n{fence}\n" + "\n".join(lines) + f"\n{fence}\n"
    )


def write(data: dict, built: Built, out: Path, json_path: str | Path | None = None) -> str:
    """parameters.json into `out` (and `json_path`); returns the terminal lines: each check, the files."""
    write_json(out / "parameters.json", data)
    write_json(json_path, data)
    if "robot" in data:  # the README says how this robot's own angles become the ones the C code takes
        readme = out / "README.md"
        outputs.write_text(readme, readme.read_text(encoding="utf-8") + _urdf_angles(data["robot"]))
    lines = [
        f"  {name}: compiled vs Python, {MEASURE[name].replace('_', ' ')} {v[MEASURE[name]]:.2e} "
        f"(limit {TOLERANCE[name]:.0e})"
        for name, v in data["check"].items()
    ]
    lines.append(f"  wrote {', '.join(p.name for p in built.files)}, parameters.json")
    return "\n".join(lines)
