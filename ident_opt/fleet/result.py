"""What a fleet run returns: each robot's series (`RobotResult`) and the run's whole answer (`FleetResult`), as
`fleet.run.run_fleet` makes them and `ident_opt.report.fleet` writes them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident_opt.fleet import changes, tasks
from ident_opt.warnings import ResultWarning


@dataclass
class RobotResult:
    """One robot's series: its fitted days, their files and samples, the fit's π and standard errors (D, P), the
    tested parameters (`changes.Tested`) and their test (None with too few days), and the fit its days got with why
    (`tasks.RobotChoice`)."""

    robot: str
    days: list[str]
    files: list[int]
    samples: list[int]
    pi: np.ndarray
    se: np.ndarray
    tested: changes.Tested
    test: changes.Test | None = None
    choice: tasks.RobotChoice | None = None


@dataclass
class FleetResult:
    """A fleet run: the problem and logs, the arm in a line, the fit the robot-days got (`estimator`, `why`: the
    robots' one choice; "per robot" when they differ, each robot's in its `choice`), the model's parameter names
    and the tested ones (with their definitions where they are base parameters), the robots' series, the changes,
    the skipped files, the run's numbers (`fleet`, the contract's keys and more) and the warnings."""

    problem: str
    logs: str
    arm: str
    estimator: str
    why: str
    baseline_days: int
    names: tuple[str, ...]
    tested_names: tuple[str, ...]
    definitions: dict[str, str]
    robots: dict[str, RobotResult]
    changes: list[changes.Change]
    skipped: list[dict]
    fleet: dict
    warnings: list[ResultWarning] = field(default_factory=list)
