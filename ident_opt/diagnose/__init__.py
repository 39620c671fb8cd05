"""Diagnosis: what the nominal model gets wrong, which catalogue cause explains it, the extended model and its
held-out gain (`spec/diagnose.md`). Modules: `evidence` (residual features), `candidates` (one fitted
extension per cause), `scoring` (held-out score and the naming rule), `diagnosis` (the four questions in
order), `report` (Markdown, figures, terminal summary), `polish` and `elastic_nlp` (IPOPT refinements of the
searched nonlinear parameters); `linear` and `signals` are shared tools."""

from ident_opt.diagnose.diagnosis import Diagnosis, diagnose

#: The catalogue's cause names (`spec/diagnose.md`), `none` first.
CAUSES = (
    "none",
    "armature",
    "asymmetric_coulomb",
    "stribeck",
    "elasticity",
    "payload",
    "delay",
    "joint_offset",
)

__all__ = ["CAUSES", "Diagnosis", "diagnose"]
