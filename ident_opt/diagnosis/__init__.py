"""Diagnosis: what the nominal model gets wrong, which catalogue cause explains it, the extended model and its
held-out gain (`docs/effects.md`). Modules: `evidence` (residual features), `candidates` (fitting each cause's
model families, declared by the cause's own module in `ident_opt.effects`), `scoring` (held-out score and the
naming rule), `diagnosis` (the four questions in order), `report` (Markdown, figures, terminal summary),
`hidden` (hidden-effect trials for tests and benchmarks); `linear`, `signals` and `elastic_nlp` (the IPOPT
polish of a lightly damped mode) are shared tools."""

from ident_opt.diagnosis import arm_diagnosis, loop
from ident_opt.diagnosis.loop import Diagnosis
from ident_opt.diagnosis.signals import TORQUE_FILTER_HZ
from ident_opt.effects import CATALOGUE

#: The catalogue's cause names, `none` first.
CAUSES = ("none", *CATALOGUE)

__all__ = ["CAUSES", "Diagnosis", "diagnose"]


def diagnose(
    robot,
    trial,
    unseen=None,
    train_fraction: float = 0.7,
    progress: bool = True,
    torque_filter_hz: float | str | None = TORQUE_FILTER_HZ,
    rigid_fit=None,
) -> Diagnosis:
    """Diagnose `trial` (and `unseen`, if given, as the held-out data) of `robot`'s arm: the planar two-link arm's
    diagnosis (`loop.diagnose`) or any arm's (`arm_diagnosis.diagnose`), as the robot says (`Robot.engine`).
    `rigid_fit`: the estimator π is fitted with and why (a `fitting.recommend.Recommendation`: the recommended fit,
    which the command passes; None: the robot's default estimator)."""
    if robot.engine == "planar":
        return loop.diagnose(robot, trial, unseen, train_fraction, progress, torque_filter_hz, rigid_fit)
    return arm_diagnosis.diagnose(robot, trial, unseen, train_fraction, progress, torque_filter_hz, rigid_fit)
