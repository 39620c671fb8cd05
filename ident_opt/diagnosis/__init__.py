"""Diagnosis: what the nominal model gets wrong, which catalogue cause explains it, the extended model and its
held-out gain (`docs/effects.md`). Modules: `evidence` (residual features), `candidates` (fitting each cause's
model families, declared by the cause's own module in `ident_opt.effects`), `scoring` (held-out score and the
naming rule), `diagnosis` (the four questions in order), `report` (Markdown, figures, terminal summary),
`hidden` (hidden-effect trials for tests and benchmarks); `linear`, `signals` and `elastic_nlp` (the IPOPT
polish of a lightly damped mode) are shared tools."""

from ident_opt.diagnosis.loop import Diagnosis, diagnose
from ident_opt.effects import CATALOGUE

#: The catalogue's cause names, `none` first.
CAUSES = ("none", *CATALOGUE)

__all__ = ["CAUSES", "Diagnosis", "diagnose"]
