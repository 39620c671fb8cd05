"""`ident-opt export`: the identified arm written as a robot description other tools load, from a fit that knows its
arm (`fitting.recommend.ArmFit`, what `ident_opt.fit` returns: by default the recommended fit, the one `compare`
reports), realised exactly as rigid bodies (`ident_opt.arm.realise`), with what the data did not determine named."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ident_opt.arm.bodies import RobotDescription
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import ArmFit
from ident_opt.problem.spec import Problem
from ident_opt.shipping.mjcf import write_mjcf
from ident_opt.shipping.urdf import identified, write_urdf

#: The formats, and the file ending each expects.
FORMATS = {"urdf": ".urdf", "mjcf": ".xml"}


@dataclass
class Exported:
    """The identified arm as written: the fit, the rigid bodies that realise π, the sidecar record (every identified
    value with its standard error, the problem, the trials, the model), the format, the files written and the notes
    (what the data did not determine, how a grouped π was realised)."""

    fit: ArmFit
    description: RobotDescription
    record: dict
    format: str
    files: list[Path] = field(default_factory=list)

    @property
    def notes(self) -> list[str]:
        return list(self.description.notes)

    def as_json(self) -> dict:
        """The `export --json` payload: the sidecar record, the format, the files and the notes."""
        return {**self.record, "format": self.format, "files": [str(p) for p in self.files], "notes": self.notes}


def export_format(path: str | Path, format: str | None = None) -> str:
    """The format of a description written to `path`: `format` when given, else read from the file's ending
    (*.urdf: URDF; *.xml, *.mjcf: MuJoCo MJCF); an InputError otherwise."""
    if format is not None:
        if not isinstance(format, str) or format not in FORMATS:
            raise InputError(f"export: the format must be one of {', '.join(FORMATS)}, got {format!r}")
        return format
    suffix = Path(path).suffix.lower()
    if suffix == ".urdf":
        return "urdf"
    if suffix in (".xml", ".mjcf"):
        return "mjcf"
    raise InputError(f"{path}: name it *.urdf (URDF) or *.xml / *.mjcf (MuJoCo MJCF)")


def massless(problem: Problem, fit: ArmFit, undetermined: list[str]) -> None:
    """InputError when `fit` gives a link a mass ≤ 0 kg, which no rigid body has and no robot description can
    say: naming the fit and the link, why (a mass the data do not determine, which least squares leaves at 0; or a
    negative one, which an unconstrained fit can give) and the physically consistent fit to export instead."""
    masses = fit.model.link_masses(fit.pi)
    bad = [(link, m) for link, m in masses.items() if not m > 0]
    if not bad:
        return
    link, mass = bad[0]
    name = fit.choice.estimator if fit.choice is not None else fit.method
    why = (
        "the joint torques do not determine it, and least squares leaves such a parameter at 0"
        if f"m_{link}" in undetermined and mass == 0
        else "nothing in that fit keeps a mass positive"
    )
    more = f" (and {len(bad) - 1} more link(s))" if len(bad) > 1 else ""
    consistent = problem.robot.default_estimator
    raise InputError(
        f"export: the {name} fit gave link {link!r} a mass of {mass:.6g} kg{more}, which no rigid body has ({why}), "
        f"so no robot description can hold it; export a physically consistent fit: --estimator {consistent}, or "
        "no --estimator for the recommended fit"
    )


def export(problem: Problem, fit: ArmFit, path: str | Path, format: str | None = None) -> Exported:
    """`ident-opt export`: write the arm of `problem` with the parameters of `fit` (`ident_opt.fit`) to `path` as a
    URDF with its JSON sidecar `path.json` (`format` "urdf", or a path ending in .urdf) or a MuJoCo MJCF ("mjcf",
    .xml, .mjcf). A π no physical robot has (e.g. an OLS fit's negative mass) raises `InputError` naming the link."""
    problem.require("export")
    fmt = export_format(path, format)
    model = fit.model
    undetermined = fit.details.get("not_determined", [])
    massless(problem, fit, undetermined)  # the fit's fault, said as such (not the URDF's, which realises it)
    description = problem.robot.bodies(model, fit.pi, undetermined=undetermined)
    record = {
        **identified(model.names, fit.pi, fit.se, fit.choice.estimator if fit.choice is not None else fit.method),
        "problem": problem.name,
        "trials": list(fit.trials),
        "model": {"extensions": list(model.extensions), **model.settings()},
        "not_determined": undetermined,
    }
    if fmt == "urdf":
        files = list(write_urdf(description, path, record))
    else:
        files = write_mjcf(description, path, record)
    return Exported(fit, description, record, fmt, files)
