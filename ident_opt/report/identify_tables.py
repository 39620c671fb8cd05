"""The tables `ident-opt identify` writes (Markdown and CSV): metrics per model, protocol and joint, the paper's
reproduction (its robot only) and seed study (its protocol only), the parameters, Model 1's weights, coverage; and
the names the identify report gives models and protocols. Every table names its protocol; the paper's published
numbers (`ident_opt.paper.published`) appear only as reference columns, nothing is fitted or tuned to them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.evaluation.identify import IdentifyResult
from ident_opt.metrics import METRICS
from ident_opt.paper.protocols import ProtocolResult
from ident_opt.paper.published import NMSE_RANGE, NMSE_RANGE_TOLERANCE, PI_HAT, PI_TRUE, RMSE, RMSE_TOLERANCE
from ident_opt.report import figures
from ident_opt.report.tables import markdown_table, write_table

PARAMETER_NOTE = (
    "Units: a [kg·m²], b [N·m], fv [N·m·s/rad], fc [N·m]; `se` = standard errors (assuming independent residuals: "
    "a lower bound on densely sampled trials). The physical datasheet folds joint 1's armature into a1 and "
    "reports joint 2's as ia2. The paper's π̂ was fitted with its printed gravity regressor, so its b1 reads "
    "as b1 − b2 physically (b1 + b2 = 4.00 N·m)."
)


#: The first two sentences of `PARAMETER_NOTE`: what holds for every robot (the rest is about the paper's π̂).
PARAMETER_NOTE_ANY = PARAMETER_NOTE.split(" The paper's π̂")[0]


#: The note of an arm whose parameters are its links' and joints' own (an n-joint arm from a URDF).
ARM_NOTE = (
    "Units: m [kg], mx… [kg·m], ixx… [kg·m²] (about the link frame's origin), fv [N·m·s/rad], fc [N·m], ia [kg·m²], "
    "off [N·m]; `se` = standard errors (assuming independent residuals: a lower bound on densely sampled trials), "
    "empty where the data do not determine the parameter (the fit's prior or its least-norm choice sets it)."
)


MODEL_NAMES = {
    "rr": "RR (ridge, black box)",
    "dm": "DM (datasheet, paper's convention)",
    "dm_physical": "DM (datasheet, physical convention)",
    "pbr": "PBR (OLS rigid body)",
    "cpbr": "CPBR (constrained, consistent)",
}


PROTOCOL_TITLES = {"paper": "Paper's protocol", "chronological": "Chronological split", "cross_trial": "Cross-trial"}


def dm_key(result: IdentifyResult) -> str:
    """The datasheet model the figures and sentences show: the paper's Model 2 for the paper's robot, else the
    problem's own datasheet read physically."""
    return "dm" if result.paper_robot else "dm_physical"


def figure_models(result: IdentifyResult) -> tuple[tuple[str, str], ...]:
    """(key, label) of the models drawn in the paper's figures, with this problem's own datasheet model."""
    if result.paper_robot:
        return figures.PAPER_MODELS
    return tuple(
        (key, "Datasheet model of this problem (DM, physical)") if key == "dm" else (key, label)
        for key, label in figures.PAPER_MODELS
    )


def model_name(key: str) -> str:
    """Readable name of a model key (`pbr+gmr` → "PBR (OLS rigid body) + GMR")."""
    base, _, gmr = key.partition("+")
    return MODEL_NAMES.get(base, base) + (" + GMR" if gmr else "")


# ---------------------------------------------------------------------------------------------- tables
def _per_joint(values) -> dict[str, float]:
    """One value per joint as table columns joint1 … jointn."""
    return {f"joint{j + 1}": v for j, v in enumerate(values)}


def metrics_frame(result: IdentifyResult) -> pd.DataFrame:
    """Long table: protocol, model, metric, one column per joint (coverage and GMR components included)."""
    rows = []
    for name, p in result.protocols.items():
        for metric in (*METRICS, "coverage"):
            values = p.metrics[metric] if metric in METRICS else p.coverage
            for key, v in values.items():
                rows.append({"protocol": name, "model": key, "metric": metric, **_per_joint(v)})
    return pd.DataFrame(rows).set_index(["protocol", "model", "metric"])


def protocol_frame(p: ProtocolResult) -> pd.DataFrame:
    """One protocol, one row per model: every metric per joint, 95 % coverage and GMR components."""
    rows = []
    for key in p.metrics["rmse"]:
        row = {"model": key}
        n = len(p.metrics["rmse"][key])
        for metric in METRICS:
            row.update({f"{metric} J{j + 1}": v for j, v in enumerate(p.metrics[metric][key])})
        row.update({f"coverage95 J{j + 1}": v for j, v in enumerate(p.coverage.get(key, [np.nan] * n))})
        row["K"] = p.components.get(key, "")
        rows.append(row)
    return pd.DataFrame(rows).set_index("model")


def reproduction_frame(result: IdentifyResult) -> pd.DataFrame:
    """Ours (paper's protocol) beside the paper, with the relative difference and whether a target is met."""
    paper = result.protocols["paper"]
    rows = []
    for key, (ref1, ref2) in RMSE.items():
        for j, (mean, _) in enumerate((ref1, ref2)):
            ours = paper.metrics["rmse"][key][j]
            rows.append(_repro_row("RMSE [N·m]", key, j, ours, mean, RMSE_TOLERANCE))
    for key, ref in NMSE_RANGE.items():
        for j in range(2):
            ours = paper.metrics["nmse_range"][key][j]
            tol = None if key.endswith("+gmr") else NMSE_RANGE_TOLERANCE
            rows.append(_repro_row("nmse_range", key, j, ours, ref[j], tol))
            if key.endswith("+gmr"):
                for label, variant in result.variants.values():
                    value = variant.metrics["nmse_range"][key][j]
                    rows.append(_repro_row(f"nmse_range ({label})", key, j, value, ref[j], None))
    return pd.DataFrame(rows).set_index(["metric", "model", "joint"])


def _repro_row(metric: str, key: str, j: int, ours: float, paper: float, tol: float | None) -> dict:
    rel = ours / paper - 1
    target = "–" if tol is None else f"±{tol:.0%}"
    met = "reported" if tol is None else ("yes" if abs(rel) <= tol else "NO")
    return {
        "metric": metric,
        "model": key,
        "joint": j + 1,
        "ours": ours,
        "paper": paper,
        "difference": f"{rel:+.1%}",
        "target": target,
        "met": met,
    }


def seeds_frame(result: IdentifyResult) -> pd.DataFrame:
    """Test RMSE over the paper's seeds (mean, std with ddof = 1) per model and joint, the paper's beside."""
    per = result.protocols["paper"].rmse_per_split
    rows = []
    for key, values in per.items():
        arr = np.asarray(values)
        for j in range(arr.shape[1]):
            ref = RMSE.get(key) if result.paper_robot else None
            rows.append(
                {
                    "model": key,
                    "joint": j + 1,
                    "mean RMSE [N·m]": arr[:, j].mean(),
                    "std RMSE [N·m]": arr[:, j].std(ddof=1) if len(arr) > 1 else 0.0,
                    "paper mean": ref[j][0] if ref else np.nan,
                    "paper std": ref[j][1] if ref else np.nan,
                }
            )
    frame = pd.DataFrame(rows).set_index(["model", "joint"])
    return frame if result.paper_robot else frame.drop(columns=["paper mean", "paper std"])


def parameters_frame(result: IdentifyResult) -> pd.DataFrame:
    """π by estimator (fitted on the whole first trial), with standard errors and the paper's columns."""
    names = list(dict.fromkeys(n for d in result.parameters.values() for n in d))
    frame = pd.DataFrame(index=pd.Index(names, name="parameter"))
    physical_first = "datasheet_paper" in result.parameters
    labels = {
        "datasheet": f"datasheet ({'physical' if physical_first else 'paper'})",
        "datasheet_paper": "datasheet (paper)",
        "datasheet_physical": "datasheet (physical)",
    }
    for est, values in result.parameters.items():
        frame[labels.get(est, est)] = [values.get(n, np.nan) for n in names]
        if est in result.standard_errors:
            frame[f"{est} se"] = [result.standard_errors[est].get(n, np.nan) for n in names]
    if result.paper_robot:  # the paper's published parameters are about its robot only
        frame["paper π_True"] = [PI_TRUE.get(n, np.nan) for n in names]
        frame["paper π̂"] = [PI_HAT.get(n, np.nan) for n in names]
    return frame


def ridge_frame(result: IdentifyResult) -> pd.DataFrame:
    """Model 1's weights per joint (units: N·m per rad, rad/s, rad/s²), intercept [N·m] and CV penalty."""
    r = result.ridge
    rows = [{"term": f, **_per_joint(v)} for f, v in r["coef"].items()]
    rows.append({"term": "intercept", **_per_joint(r["intercept"])})
    rows.append({"term": "alpha (LOO-CV)", **_per_joint(r["alpha"])})
    return pd.DataFrame(rows).set_index("term")


def coverage_frame(result: IdentifyResult) -> pd.DataFrame:
    """95 % interval coverage of every `+gmr` model on held-out data, per protocol and joint."""
    rows = [
        {"protocol": name, "model": key, **_per_joint(v)}
        for name, p in result.protocols.items()
        for key, v in p.coverage.items()
    ]
    return pd.DataFrame(rows).set_index(["protocol", "model"])


def write_tables(result: IdentifyResult, out: Path) -> dict[str, Path]:
    """Every table as CSV (full precision) and Markdown; returns name -> Markdown path. The reproduction table is
    the paper's robot's, the seed table the paper's protocol's: written where they apply."""
    frames = {}
    if result.paper_robot:
        frames["identify_reproduction"] = (
            reproduction_frame(result),
            "Reproduction of the paper (paper's protocol)",
            "",
        )
    if "paper" in result.protocols:
        frames["identify_seeds"] = (
            seeds_frame(result),
            "Test RMSE over the paper's seeds (paper's protocol)",
            "Mean and standard deviation (ddof = 1) of the test RMSE over the shuffled splits.",
        )
    frames["identify_parameters"] = (
        parameters_frame(result),
        "Parameters (identified on the whole first trial)",
        (PARAMETER_NOTE if result.paper_robot else PARAMETER_NOTE_ANY if result.paper_views else ARM_NOTE)
        + f" {result.consistency_note} (> 0: physically "
        "consistent): " + ", ".join(f"{k} {v:.3g} kg·m²" for k, v in result.consistency.items()) + ".",
    )
    frames["identify_ridge"] = (
        ridge_frame(result),
        "Ridge regression (Model 1) on the whole first trial",
        "τ̂_j = Σ w_j · feature + intercept_j; the penalty alpha is chosen per joint by efficient "
        "leave-one-out cross-validation among 10⁻⁴ … 10⁴ (features unscaled).",
    )
    frames["identify_coverage"] = (
        coverage_frame(result),
        "95 % interval coverage on held-out data",
        "Fraction of held-out torques inside the GMR's 95 % predictive interval "
        "(mixture variance, including the spread between components); 0.95 is ideal.",
    )
    written = {}
    for name, (frame, title, note) in frames.items():
        write_table(frame, out / f"{name}.csv")
        text = f"# {title}\n\n{markdown_table(frame)}\n" + (f"\n{note}\n" if note else "")
        outputs.write_text(out / f"{name}.md", text)
        written[name] = out / f"{name}.md"
    write_table(metrics_frame(result), out / "identify_metrics.csv")
    parts = [
        "# Metrics per model and protocol\n",
        "`nmse` = MSE ÷ variance of the measured torque; `nmse_range` = MSE ÷ (max − min)² (the paper's); "
        "coverage95 = fraction of test torques inside the 95 % GMR predictive interval; K = GMR components.\n",
    ]
    for name, p in result.protocols.items():
        parts.append(f"## {PROTOCOL_TITLES.get(name, name)}: {p.description}\n\n{markdown_table(protocol_frame(p))}\n")
    for label, variant in result.variants.values():
        parts.append(
            f"## Paper's protocol, GMR variant ({label}): {variant.description}\n\n"
            f"{markdown_table(protocol_frame(variant))}\n"
        )
    outputs.write_text(out / "identify_metrics.md", "\n".join(parts))
    written["identify_metrics"] = out / "identify_metrics.md"
    return written
