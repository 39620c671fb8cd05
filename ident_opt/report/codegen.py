"""What `ident-opt codegen` writes: the generated C sources and header, the compiled shared library, the
example `main.c`, a README for embedding (all from `ident_opt.shipping.codegen`), and parameters.json (the parameters
baked in, the estimator, the GMR, the check against Python); with the terminal lines."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ident_opt import outputs
from ident_opt.report import write_json
from ident_opt.shipping import codegen
from ident_opt.shipping.ship import MEASURE, TOLERANCE, Shipped


@dataclass
class Built:
    """The generated CasADi functions and the files written for them."""

    functions: list
    files: list[Path]  # sources, header, library, example, README
    library: Path

    @property
    def names(self) -> list[str]:
        return [f.name() for f in self.functions]


def build(shipped: Shipped, robot, out: Path, compiler: str, forward: bool = True) -> Built:
    """Generate the C code of `shipped` into `out` and compile it (`forward`: also ddq_hat), with the example and
    the README written for `robot` (its joints and angle convention)."""
    functions = codegen.build_functions(shipped.model, shipped.pi, shipped.gmr, forward=forward)
    source, header = codegen.generate_sources(functions, out)
    library = codegen.compile_library(source, out, compiler)
    example = codegen.copy_example(out, shipped.model.n_joints, gmr=shipped.gmr is not None)
    readme = codegen.write_readme(out, functions, robot)
    return Built(functions, [source, header, library, example, readme], library)


def payload(shipped: Shipped, built: Built, errors: dict[str, float], problem, sources: list[str]) -> dict:
    """parameters.json (and the --json payload): the parameters baked in, the model, the GMR, the checks."""
    model, gmr, robot = shipped.model, shipped.gmr, problem.robot
    n = model.n_joints
    out = {
        "estimator": shipped.estimator,
        "estimator_status": shipped.status,
        "model": {"extensions": list(model.extensions), **model.settings()},
        "arm": robot.summary(),
        "joints": list(robot.joint_names),
        "parameters": model.as_dict(shipped.pi),
        "units": {p.name: p.unit for p in model.parameters},
        "gmr": {
            "inputs": list(codegen.gmr_inputs(n)),
            "outputs": [f"r{j + 1}" for j in range(n)],
            "n_components": len(gmr.weights_),
            "weights": gmr.weights_,
            "means": gmr.means_,
            "covariances": gmr.covariances_,
        },
        "problem": problem.name,
        "data": sources,
        "functions": built.names,
        "library": built.library.name,
        "check": {name: {MEASURE[name]: err, "limit": TOLERANCE[name]} for name, err in errors.items()},
    }
    if robot.statement:  # e.g. a two-joint URDF arm: the offsets and signs from its angles to the C code's
        out["robot"] = list(robot.statement)
    return out


def _urdf_angles(statement: list[str]) -> str:
    """The README section of a two-joint URDF arm: its angles are not the C code's; the offsets to apply."""
    return (
        "\n## This robot's angles\n\nThe arm comes from a URDF whose angle zero and axis signs are its own. The C "
        "code takes ident-opt's angles: pass q = sign × q_urdf + offset, and dq, ddq, tau × sign, per joint, as "
        "ident-opt applied them to the data:\n\n```\n" + "\n".join(statement) + "\n```\n"
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
