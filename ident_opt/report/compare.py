"""What `ident-opt compare` writes: compare.md (parameters ± SE, consistency, held-out errors, findings, the seed
study), compare_parameters.csv, compare_consistency.csv, compare_metrics.csv, compare_seeds.csv and .png, the
JSON payload (`docs/cli.md`) and the terminal summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.evaluation.compare import PROTOCOLS, Comparison
from ident_opt.metrics import METRICS
from ident_opt.paper.seeds import rmse_table
from ident_opt.report import against as against_report
from ident_opt.report import record, shown, verdicts, write_json
from ident_opt.report.figures import parameters_figure, seed_heatmap
from ident_opt.report.tables import fmt, markdown_table, write_table
from ident_opt.runs import SideBySide
from ident_opt.warnings import markdown_lines

#: The files `write` puts in the output folder, the report first.
FILES = (
    "compare.md",
    "compare_parameters.csv",
    "compare_consistency.csv",
    "compare_metrics.csv",
    "compare_parameters.png",
    "compare_seeds.csv",
    "compare_seeds.png",
)


def write(
    c: Comparison, out: Path, json_path: str | Path | None = None, against: SideBySide | None = None
) -> list[str]:
    """Every file of the comparison into `out` (and the JSON payload to `json_path`); returns their names (the
    seed study's only when the paper's protocol ran; with `against`, another run beside this one:
    `report.against`, and the JSON's `against`)."""
    files = [f for f in FILES if c.seeds is not None or "seeds" not in f]
    files += against_report.write(against, out) if against is not None else []
    figure = seed_heatmap(c.seeds, out / "compare_seeds.png", "ols") if c.seeds is not None else None
    parameters_png(c, out / "compare_parameters.png")
    write_table(parameter_table(c), out / "compare_parameters.csv")
    write_table(consistency_table(c), out / "compare_consistency.csv")
    metrics = pd.concat({m: metrics_table(c, m) for m in METRICS}, names=["metric"])
    write_table(metrics, out / "compare_metrics.csv")
    if c.seeds is not None:
        write_table(rmse_table(c.seeds), out / "compare_seeds.csv")
    outputs.write_text(out / "compare.md", to_markdown(c, figure.name if figure else None))
    verdict = verdicts.fit_verdict(c.choice, c.trust.warnings)
    if against is not None:
        verdict += f"\n\n**Against {against.other.source}:** {against_report.headline(against)}."
    record(out, "compare", "the nominal model against OLS and the consistent fits", files, verdict=verdict)
    extra = {"against": against.as_json()} if against is not None else {}
    write_json(json_path, {**to_json(c), **extra, "files": files})  # "files": in the output folder
    return files


LABELS = {
    "datasheet_paper": "datasheet (paper)",
    "datasheet_physical": "datasheet (physical)",
    "datasheet_urdf": "URDF",
    "ols": "OLS",
    "constrained": "constrained",
    "nlp_physical": "NLP-physical",
    "consistent": "consistent (URDF prior)",
    "iv": "IV",
}


def parameters_png(c: Comparison, path: Path) -> Path:
    """compare_parameters.png: every fit's parameters with ±2 standard errors beside the nominal values
    (`figures.parameters_figure`)."""
    params = c.parameters()
    names = list(c.model.names)
    fits = {}
    for key, fit in c.fits.items():
        se = fit.se_dict()
        values = np.array([params[key].get(n, np.nan) for n in names], dtype=float)
        fits[label(c, key)] = (values, np.array([np.nan if se.get(n) is None else se[n] for n in names], dtype=float))
    nominal = params.get("datasheet")
    nominal_pi = np.array([nominal.get(n, np.nan) for n in names], dtype=float) if nominal else None
    title = f"Parameters ± 2 SE, each fit (recommended: {label(c, c.default)})"
    return parameters_figure(names, fits, nominal_pi, title, path)


def parameter_table(c: Comparison) -> pd.DataFrame:
    """Parameters (rows) × estimators, with standard errors (`<key> se`) for the fits: numbers only."""
    params = c.parameters()
    params.pop("datasheet")
    names = list(dict.fromkeys(n for p in params.values() for n in p))
    cols = {}
    for key, values in params.items():
        cols[key] = [values.get(n, np.nan) for n in names]
        if key in c.fits:
            se = c.fits[key].se_dict()
            cols[f"{key} se"] = [se.get(n, np.nan) for n in names]
    return pd.DataFrame(cols, index=pd.Index(names, name="parameter"))


def consistency_table(c: Comparison, brief: bool = False) -> pd.DataFrame:
    """Per estimator: the arm's consistency margin (`Arm.consistency_measure`: min over q of λ_min(M(q)), or over
    the links' pseudo-inertias) [kg m²], friction ≥ 0, consistent, the active constraints (`brief`: the first
    three and their count)."""

    def active(names: list[str]) -> str:
        if brief and len(names) > 3:
            return " ".join(names[:3]) + f" … ({len(names)} in all)"
        return " ".join(names) or "–"

    rows = {
        key: {
            c.model.consistency_measure: v["min_mass_eigenvalue"],
            "friction ≥ 0": v["friction_nonnegative"],
            "consistent": v["consistent"],
            "active constraints": active(v["active_constraints"]),
        }
        for key, v in c.consistency().items()
    }
    return pd.DataFrame(rows).T.rename_axis("estimator")


def metrics_table(c: Comparison, metric: str = "nmse") -> pd.DataFrame:
    """Held-out `metric` per estimator (rows) × protocol and joint (columns)."""
    rows: dict[str, dict[str, float]] = {}
    for protocol, per_metric in c.metrics.items():
        for key, values in per_metric[metric].items():
            for j, value in enumerate(values):
                rows.setdefault(key, {})[f"{protocol} j{j + 1}"] = value
    return pd.DataFrame(rows).T.rename_axis("estimator")


#: The mark of a value the data do not determine (no standard error), and what it means.
NOT_DETERMINED = "†"
NOT_DETERMINED_NOTE = (
    f"{NOT_DETERMINED} not determined by the data: the fit's own choice (its prior toward the nominal model, a bound, "
    "or 0 for OLS's dependent parameters), so no standard error."
)


def _with_se(c: Comparison) -> pd.DataFrame:
    """The parameter table with "value ± se" strings, for people."""
    table = parameter_table(c)
    out = {}
    for key in [k for k in table.columns if not k.endswith(" se")]:
        se = table.get(f"{key} se")
        silent = set(c.fits[key].details.get("not_determined", [])) if key in c.fits else set()
        cells = []
        for i, (name, v) in enumerate(zip(table.index, table[key])):
            if pd.isna(v):  # a column with a missing standard error is of objects (None), not floats
                cells.append("–")
            elif name in silent:
                cells.append(f"{fmt(v)} {NOT_DETERMINED}")
            elif se is None or pd.isna(se.iloc[i]):
                cells.append(fmt(v))
            else:
                cells.append(f"{fmt(v)} ± {fmt(se.iloc[i], 2)}")
        out[label(c, key)] = cells
    human = pd.DataFrame(out, index=table.index)
    # The consistency column of the issue, as rows under the parameters: one verdict per estimator.
    consistency = c.consistency()
    extra = {
        c.model.consistency_measure: {label(c, k): fmt(v["min_mass_eigenvalue"]) for k, v in consistency.items()},
        "friction ≥ 0": {label(c, k): "yes" if v["friction_nonnegative"] else "NO" for k, v in consistency.items()},
        "physically consistent": {label(c, k): "yes" if v["consistent"] else "NO" for k, v in consistency.items()},
    }
    return pd.concat([human, pd.DataFrame(extra).T.reindex(columns=human.columns)]).rename_axis("parameter")


def findings(c: Comparison) -> list[str]:
    """Plain sentences: consistency of OLS, what the constraints did, their held-out cost or gain."""
    ols, con = c.fits["ols"], c.fits["constrained"]
    lines = []
    base = ols.details.get("base_parameters")
    if base:
        impossible = c.impossible_base_values()
        lines.append(
            f"OLS fits the {len(base)} base parameters (the combinations of the {len(c.model.names)} the data "
            "determine); its standard parameters set the others to 0, so its links are not a physical arm"
            + (
                f", and {len(impossible)} of its base parameters are values no physical arm can have"
                if impossible
                else ""
            )
            + "."
        )
    elif ols.consistent:
        lines.append("OLS is physically consistent on this trial; the constrained fit equals it.")
    else:
        lines.append("OLS is " + "; ".join(w for w in ols.warnings if w.startswith("physically")) + ".")
    if con.active:
        lines.append(
            f"Constrained fit: active constraints {', '.join(con.active)}; "
            f"min eig M(q) = {con.min_mass_eigenvalue:.3g} kg m²."
        )
    for protocol in c.metrics:
        n_ols, n_con = c.metrics[protocol]["nmse"]["ols"], c.metrics[protocol]["nmse"]["constrained"]
        change = [100 * (b - a) / a for a, b in zip(n_ols, n_con)]
        verdict = ", ".join(
            f"joint {j + 1} " + ("costs" if d > 0.05 else "gains" if d < -0.05 else "no change")
            for j, d in enumerate(change)
        )
        lines.append(
            f"{protocol}: held-out nmse OLS {_joined(n_ols)}, constrained {_joined(n_con)} "
            f"({' / '.join(f'{d:+.1f} %' for d in change)}; consistency {verdict})."
        )
    costs = [
        con > ols * 1.0005
        for p in c.metrics
        for ols, con in zip(c.metrics[p]["nmse"]["ols"], c.metrics[p]["nmse"]["constrained"])
    ]
    if not ols.consistent and any(costs):
        lines.append(
            "Where consistency costs held-out accuracy, OLS was using a physically impossible inertia to "
            "absorb something the rigid model lacks (on a real flexible arm: elasticity, friction shape, "
            "delay); `ident-opt diagnose` looks for it. Only the consistent fit has an M(q) that is "
            "invertible at every pose, as forward simulation and model-based control need."
        )
    for w in ols.warnings:
        if not w.startswith("physically"):
            lines.append("OLS: " + w + ".")
    return lines


def _joined(values: list[float]) -> str:
    """Per-joint values as "v1 / v2 / …" (4 significant digits)."""
    return " / ".join(f"{v:.4g}" for v in values)


def label(c: Comparison, key: str) -> str:
    """A column's name for people (the `[reference]`'s own label for "reference")."""
    if key == "reference" and c.reference_label:
        return c.reference_label
    return LABELS.get(key, key)


def sensitivity_table(c: Comparison) -> pd.DataFrame:
    """OLS at ½×, 1× and 2× the derivative cut-off, and IV at 1× (parameters × fits); empty without it."""
    if not c.trust.sensitivity:
        return pd.DataFrame()
    cols = {"OLS ½× cut-off": c.trust.sensitivity[0.5].as_dict(), "OLS": c.fits["ols"].as_dict()}
    cols["OLS 2× cut-off"] = c.trust.sensitivity[2.0].as_dict()
    cols["IV"] = c.fits["iv"].as_dict()
    return pd.DataFrame(cols).rename_axis("parameter")


def warnings_json(c: Comparison) -> list[dict[str, str]]:
    """The `warnings` key: [{"code": …, "message": …}]."""
    return [w.as_dict() for w in c.trust.warnings]


def _trust_section(c: Comparison) -> list[str]:
    """Warnings, the cut-off sensitivity and the fitted direction of gravity, as Markdown lines."""
    parts = ["## The recommended fit", "", f"**{c.choice.estimator}**: {c.choice.why}.", ""]
    parts += ["## Warnings", ""]
    parts += markdown_lines(c.trust.warnings)
    parts.append("")
    if c.trust.cutoffs:
        cut = ", ".join(f"{x:.3g}" for x in c.trust.cutoffs)
        parts += [
            "## Derivative cut-off",
            "",
            f"Cut-off per training trial from its spectrum [Hz]: {cut}"
            + (
                f"; the fits use {c.choice.factor:g}× these (OLS and IV agree up to there)"
                if c.choice.factor != 1
                else ""
            )
            + ". The torque of each fit went through the same zero-phase filter as the angles (parallel filtering); "
            "scores are against the measured torque. OLS with every trial's derivatives at ½× and 2× its cut-off, "
            "beside IV (instruments at ½× the cut-off):",
            "",
            markdown_table(sensitivity_table(c).map(fmt)),
            "",
        ]
    if c.robot_statement:  # a URDF arm: the offsets and signs its data went through
        parts += ["## Robot", "", "```", *c.robot_statement, "```", ""]
    d = c.trust.gravity_direction
    if d:
        parts += [
            "## Angle convention",
            "",
            f"The direction of gravity fitted per joint (OLS with sine gravity columns): δ1 = {d['delta1']:+.3f} "
            f"rad, δ2 = {d['delta2']:+.3f} rad (0 when the data follow ident-opt's convention: q1 from the "
            "horizontal, q2 relative to link 1, counter-clockwise).",
            "",
        ]
    return parts


def _title(c: Comparison) -> str:
    """ "datasheet vs OLS vs constrained vs …": the problem's nominal model, then the fits."""
    keys = [f"datasheet_{c.datasheet}", *[k for k in c.fits if k != "iv"]]
    names = ["datasheet" if k.startswith("datasheet") else label(c, k) for k in keys]
    return "Identification: " + " vs ".join(names)


def _physical_section(c: Comparison) -> list[str]:
    """The NLP-physical fit's physical parameters (the planar arm's), where it ran."""
    physical = c.fits.get("nlp_physical")
    if physical is None or "physical" not in physical.details:
        return []
    theta = pd.DataFrame({"value": physical.details["physical"]}).rename_axis("physical parameter")
    theta["at a physical bound"] = ["yes" if k in physical.details.get("at_bound", []) else "" for k in theta.index]
    return [
        "## NLP-physical: the physical parameters behind its π",
        "",
        "Masses [kg], centres of mass [m], inertias and armature [kg m²], friction [N m s/rad, N m]. "
        "The grouped π do not determine all of them: a weak pull toward the datasheet picks one of "
        "the equivalent sets, so read the individual values with care; π is what the data fix.",
        "",
        markdown_table(theta),
        "",
    ]


def _links_section(c: Comparison) -> list[str]:
    """Link masses against the nominal ones, and the OLS base parameters no consistent arm can have negative
    (arms whose π holds link masses: an n-joint arm)."""
    masses = c.masses()
    if not masses:
        return []
    links = list(next(iter(masses.values()))["links"])
    frame = pd.DataFrame({label(c, k): {**v["links"], "total": v["total"]} for k, v in masses.items()})
    parts = [
        "## Link masses [kg]",
        "",
        markdown_table(frame.reindex([*links, "total"]).rename_axis("link")),
        "",
        "OLS identifies base parameters only: its standard parameters set the dependent ones to 0, so its masses "
        "are not estimates.",
        "",
    ]
    impossible = c.impossible_base_values()
    if impossible:
        parts += [
            "OLS uses values no physical arm can have (what a consistent fit cannot follow): these base parameters "
            "are non-negative for every consistent arm (their coefficients lie in the dual of the pseudo-inertia "
            "and sign cone), yet OLS makes them negative:",
            "",
            markdown_table(pd.DataFrame(impossible).T.rename_axis("base parameter")),
            "",
        ]
    return parts


def _base_section(c: Comparison) -> list[str]:
    """The OLS base parameters with their definitions and standard errors (an arm whose regressor does not
    determine every parameter)."""
    summary = c.fits["ols"].details.get("base_parameters")
    if not summary:
        return []
    frame = pd.DataFrame(summary).T.rename_axis("base parameter")
    frame["definition"] = [f"`{d}`" for d in frame["definition"]]
    return [
        f"## Base parameters (OLS, with standard errors): {len(summary)} of the {len(c.model.names)} parameters",
        "",
        markdown_table(frame),
        "",
    ]


def _within_section(c: Comparison) -> list[str]:
    """Per joint: does OLS beat the nominal model, and is the default fit within 10 % of OLS's RMSE?"""
    rows = {
        joint: {
            "OLS beats the datasheet": "yes" if v["ols_better_than_datasheet"] else "no",
            f"RMSE {label(c, c.default)} / OLS": v["ratio_to_ols"],
            "within 10 %": "yes" if v["within"] else "NO",
        }
        for joint, v in c.within_ols().items()
    }
    return [
        f"## {label(c, c.default)} (the default fit) against OLS, {list(c.metrics)[-1]} protocol",
        "",
        markdown_table(pd.DataFrame(rows).T.rename_axis("joint")),
        "",
    ]


def to_markdown(c: Comparison, figure: str | None = None) -> str:
    """The comparison as a Markdown report (parameters ± SE, consistency, held-out metrics, seed study)."""
    parts = [
        f"# {_title(c)}",
        "",
        f"Identification trial: `{shown(c.sources['train'])}`"
        + (f"; unseen trial: `{shown(c.sources['unseen'])}`" if "unseen" in c.sources else "")
        + f". Joints: {', '.join(c.joints)}. Fitted model: {len(c.model.names)} parameters"
        + (f" ({', '.join(c.model.names)}; β in N·m)" if len(c.model.names) <= 20 else "")
        + ". Standard errors use a per-joint residual variance and assume independent residuals (optimistic on "
        "densely sampled real data).",
        "",
        "## Findings",
        "",
        *[f"- {line}" for line in findings(c)],
        "",
        *_trust_section(c),
        "## Parameters (± standard error)",
        "",
        markdown_table(_with_se(c)),
        "",
        "![Every fit's parameters with ±2 standard errors beside the nominal values](compare_parameters.png)",
        "",
        *([NOT_DETERMINED_NOTE, ""] if any(f.details.get("not_determined") for f in c.fits.values()) else []),
        "## Physical consistency",
        "",
        markdown_table(consistency_table(c)),
        "",
    ]
    for metric in ("nmse", "nmse_range", "rmse"):
        parts += [
            f"## Held-out {metric} per joint",
            "",
            "Protocols: " + "; ".join(f"**{p}** = {PROTOCOLS[p]}" for p in c.metrics) + ".",
            "",
            markdown_table(metrics_table(c, metric)),
            "",
        ]
    parts += _within_section(c) + _physical_section(c) + _links_section(c) + _base_section(c)
    if c.seeds is not None:
        parts += ["## The paper's seed study (shuffled 70/30)", "", markdown_table(rmse_table(c.seeds)), ""]
    if figure:
        parts += [f"![grouped parameters across seeds]({figure})", ""]
    return "\n".join(parts)


#: Above this many parameters the terminal shows the masses, not the parameter table (compare.md has it).
TERMINAL_PARAMETERS = 20


def to_terminal(c: Comparison) -> str:
    """A compact text summary for the terminal: the parameters ± SE (or, for a large arm, its link masses), the
    consistency, the held-out nmse per joint and the findings."""
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        if len(c.model.names) <= TERMINAL_PARAMETERS:
            parameters = "Parameters (± SE):\n" + _with_se(c).to_string()
        else:
            masses = pd.DataFrame({label(c, k): {"total": v["total"], **v["links"]} for k, v in c.masses().items()})
            parameters = f"Link masses [kg] ({len(c.model.names)} parameters: compare.md):\n" + masses.to_string(
                float_format=lambda v: f"{v:.4g}"
            )
        return "\n\n".join(
            [
                parameters,
                "Consistency:\n" + consistency_table(c, brief=True).to_string(),
                "Held-out nmse per joint:\n" + metrics_table(c, "nmse").to_string(float_format=lambda v: f"{v:.4g}"),
                "\n".join(f"- {line}" for line in findings(c)),
                recommended_line(c.choice),
            ]
        )


def recommended_line(choice) -> str:
    """The terminal's line on the recommended fit (`fitting.recommend.Choice`)."""
    return f"Recommended fit: {choice.estimator} — {choice.why}."


def to_json(c: Comparison) -> dict:
    """The `compare --json` payload (`Comparison.as_json`)."""
    return c.as_json()
