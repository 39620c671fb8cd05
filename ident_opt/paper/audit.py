"""The paper audit: its datasheet model (Model 2) against its own least-squares fit, and why they differ.

The paper's datasheet π is far from its data-fitted π̂ (β1 8.23 vs 3.64 N·m, friction off by 10⁴).
Computing the same datasheet with the ``physical`` convention — the right actuator on link 1, friction
and rotor inertia reflected through the gear ratio — lands close to the fit. This study shows it from
the paper's published numbers (`ident_opt.paper.published`), and on the real trials without any fitting;
`ident_opt.report.audit` writes it, with the causes in plain words.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.arm.planar import PI_NAMES, RIGID, PlanarArm
from ident_opt.data.dataset import Dataset, shuffled_split
from ident_opt.data.loader import held_out_overlap
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.metrics import all_metrics
from ident_opt.models.hybrid import datasheet_model
from ident_opt.paper import published as paper
from ident_opt.problem.spec import SplitSpec

#: The metrics of the audit's tables, in their column order.
METRICS = ("nmse", "nmse_range", "rmse")
#: The protocols of the audit's data table.
SHUFFLED, CROSS_TRIAL = "paper (shuffled 70/30, mean of seeds)", "cross-trial (unseen trial)"


def parameter_table(robot: PlanarRobot) -> pd.DataFrame:
    """Published π̂ beside the datasheet π under both conventions, with relative differences to π̂."""
    fit = paper.pi_hat_physical()
    sheet = datasheet_pi(robot, "paper")
    physical = datasheet_pi(robot, "physical")
    rows = []
    for name in PI_NAMES:
        rows.append(
            {
                "parameter": name,
                "paper_fit": paper.PI_HAT[name],
                "paper_fit_physical": fit[name],
                "paper_printed_true": paper.PI_TRUE[name],
                "datasheet_paper": sheet[name],
                "datasheet_physical": physical[name],
                "rel_diff_paper": (sheet[name] - fit[name]) / fit[name],
                "rel_diff_physical": (physical[name] - fit[name]) / fit[name],
            }
        )
    return pd.DataFrame(rows).set_index("parameter")


@dataclass
class DataAudit:
    """Held-out torque error of the datasheet models (no fitting) and of an OLS fit, per joint."""

    table: pd.DataFrame  # rows: model, columns: metric_joint
    predictions: dict[str, np.ndarray]  # model -> (N, 2) on the whole identification trial


def datasheet_models(robot: PlanarRobot) -> dict[str, tuple[PlanarArm, np.ndarray]]:
    """The datasheet models the audit compares: name -> (model, π). Besides the two datasheet models of
    `models.datasheet_model`, the paper's π with the correct gravity vector."""
    sheet, physical = datasheet_model(robot, "paper"), datasheet_model(robot, "physical")
    return {
        "dm_paper (printed G)": (sheet.arm, sheet.pi),
        "dm_paper (correct G)": (RIGID, RIGID.vector(datasheet_pi(robot, "paper"))),
        "dm_physical": (physical.arm, physical.pi),
    }


def audit_data(robot: PlanarRobot, train: Dataset, unseen: Dataset | None, split: SplitSpec) -> DataAudit:
    """The paper's protocol (shuffled 70/30 over its seeds) for every model, plus the unseen trial; the
    OLS fit of the rigid model on the same training samples beside them."""
    models = datasheet_models(robot)
    per_seed: dict[str, list[dict[str, list[float]]]] = {}
    for seed in split.seeds:
        tr, te = shuffled_split(train.n, split.train_fraction, seed)
        for name, scores in _scores({**models, "ols (fitted)": _ols(train.subset(tr))}, train.subset(te)).items():
            per_seed.setdefault(name, []).append(scores)
    rows = {
        (name, SHUFFLED): _row(np.mean([[r[m] for m in METRICS] for r in runs], axis=0))
        for name, runs in per_seed.items()
    }
    if unseen is not None:
        for name, scores in _scores({**models, "ols (fitted)": _ols(train)}, unseen).items():
            rows[(name, CROSS_TRIAL)] = _row([scores[m] for m in METRICS])
    table = pd.DataFrame.from_dict(rows, orient="index")
    table.index.names = ["model", "protocol"]
    predictions = {name: model.predict(pi, train.q, train.dq, train.ddq) for name, (model, pi) in models.items()}
    return DataAudit(table, predictions)


def _ols(data: Dataset) -> tuple[PlanarArm, np.ndarray]:
    """The rigid model fitted by OLS on `data` (π only)."""
    return RIGID, solve_ols(Stats.from_data(RIGID, data.q, data.dq, data.ddq, data.tau))


def _scores(models: dict[str, tuple[PlanarArm, np.ndarray]], test: Dataset) -> dict[str, dict[str, list[float]]]:
    """Every model's metrics (per joint) on `test`."""
    return {
        name: all_metrics(test.tau, model.predict(pi, test.q, test.dq, test.ddq))
        for name, (model, pi) in models.items()
    }


def _row(values) -> dict[str, float]:
    """metric × joint values (len(METRICS), 2) as the table's columns `<metric>_j1`, `<metric>_j2`."""
    return {f"{m}_j{j + 1}": float(values[i][j]) for i, m in enumerate(METRICS) for j in range(2)}


def physical_is_closer(robot: PlanarRobot, table: pd.DataFrame | None = None) -> dict[str, bool]:
    """For each parameter: is the physical datasheet closer to the paper's π̂ (read physically) than the paper's?
    (`table`: the robot's `parameter_table`, if already computed.)"""
    table = parameter_table(robot) if table is None else table
    return {name: abs(r.rel_diff_physical) < abs(r.rel_diff_paper) for name, r in table.iterrows()}


def rigid_body_table(robot: PlanarRobot) -> pd.DataFrame:
    """Masses, centres of mass and inertias under both conventions (the paper's 'Dynamic Parameters' table)."""
    rows = {}
    for convention in ("paper", "physical"):
        body = rigid_body(robot, convention)
        rows[convention] = {
            "m1 [kg]": body.m1,
            "m2 [kg]": body.m2,
            "lc1 [m]": body.lc1,
            "lc2 [m]": body.lc2,
            "Ic1 [kg m²]": body.Ic1,
            "Ic2 [kg m²]": body.Ic2,
            "armature1 [kg m²]": body.armature[0],
            "armature2 [kg m²]": body.armature[1],
            "fv1 [N m s/rad]": body.fv[0],
            "fv2 [N m s/rad]": body.fv[1],
            "fc1 [N m]": body.fc[0],
            "fc2 [N m]": body.fc[1],
        }
    return pd.DataFrame(rows)


@dataclass
class Audit:
    """Everything the audit report shows: the published π̂ beside both datasheet readings (`parameter_table`),
    the rigid-body parameters behind them, the data audit and which parameters the physical reading gets
    closer; with the problem file and the trials it ran on, and what is doubtful about them (`warnings`:
    `ident_opt.warnings.ResultWarning`s, e.g. an unseen trial that is the identification trial)."""

    parameters: pd.DataFrame
    body: pd.DataFrame
    data: DataAudit
    closer: dict[str, bool]
    problem_file: str
    train: Dataset
    unseen: Dataset | None
    warnings: list = field(default_factory=list)


def audit(problem, training: list[Dataset], testing: list[Dataset] = ()) -> Audit:
    """`ident-opt audit`: the paper audit of `problem`'s robot on its identification trial (the first of `training`)
    and its unseen trial (the first of `testing`, else the second of `training`), if any. A held-out trial that is a
    training trial is a warning."""
    checked_problem(problem, "audit").require("audit")
    training = checked_trials(problem, training, "audit", "training", fit=True)
    testing = checked_trials(problem, testing, "audit", "testing", required=False)
    robot = problem.robot
    train = training[0]
    unseen = testing[0] if testing else (training[1] if len(training) > 1 else None)
    parameters = parameter_table(robot)
    found = Audit(
        parameters,
        rigid_body_table(robot),
        audit_data(robot, train, unseen, problem.split),
        physical_is_closer(robot, parameters),
        str(problem.path),
        train,
        unseen,
    )
    found.warnings = held_out_overlap(training, testing)  # an unseen trial that is the identification trial
    return found
