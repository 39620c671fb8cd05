"""The report of the URDF comparison (`ident_opt.studies.urdf`): compare.md and compare.json in the output
folder, recorded in the folder's index."""

from __future__ import annotations

from pathlib import Path

from ident_opt import outputs
from ident_opt.report import record, write_json

#: Estimator → its column title.
TITLES = {
    "ols": "OLS (base)",
    "constrained": "consistent, no prior",
    "consistent": "consistent (default)",
    "cad": "URDF CAD",
}


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _head(result: dict, title: str) -> list[str]:
    """The title, the arm and its base parameters, the default fit's prior."""
    base, prior, joints = result["base"], result["prior"], result["robot"]["joints"]
    return [
        f"# {result['problem']}: {title}",
        "",
        f"URDF `{Path(result['robot']['urdf']).name}`, {len(joints)} joints, {result['robot']['n_params']} standard "
        f"parameters; {base['count']} base parameters (pivoted QR of the regressor at {base['random_states']} random "
        f"states, rank tolerance {base['rank_tolerance']:g}); condition number of the base regressor on the "
        f"training data {base['condition_number']:.1f}.",
        "",
        f"The default consistent fit: log-det prior toward the URDF's inertials with weight λ = {prior['weight']:g} "
        f"(dimensionless, relative to the measured torque energy); link masses "
        + (f"within ±{prior['mass_range']:.0%} of the URDF's" if prior["mass_range"] else "unbounded")
        + "; centres of mass "
        + (f"within ±{prior['com_box_m']:g} m of the URDF's." if prior["com_box_m"] else "unbounded."),
    ]


def _errors(result: dict, scores: dict, title: str) -> list[str]:
    """Torque error per joint and estimator."""
    joints = result["robot"]["joints"]
    names = [n for n in TITLES if n in scores]
    rows = [[j] + [f"{scores[n]['rmse'][j]:.3f} / {scores[n]['nmse'][j]:.3f}" for n in names] for j in joints]
    return ["", f"## {title}", "", *_table(["joint: RMSE [N m] / nMSE"] + [TITLES[n] for n in names], rows)]


def _impossible(result: dict) -> list[str]:
    """The OLS base parameters no consistent arm can have negative, yet negative."""
    impossible = result.get("ols_impossible_base_values", {})
    if not impossible:
        return []
    rows = [
        [name, f"{v['value']:.4g}", f"{v['se']:.2g}", f"{v['se_below_zero']:.1f}"] for name, v in impossible.items()
    ]
    return [
        "",
        "OLS uses values no physical arm can have (what a consistent fit cannot follow): these base "
        "parameters are non-negative for every consistent arm (their coefficients are in the dual of the "
        "pseudo-inertia and sign cone), yet OLS makes them negative:",
        "",
        *_table(["base parameter", "OLS value", "SE", "SE below 0"], rows),
    ]


def _masses_and_consistency(result: dict) -> list[str]:
    """Masses against the URDF's; each estimator's pseudo-inertia consistency and active constraints."""
    mass, links = result["mass"], result["robot"]["links"]
    cols = ["urdf"] + [n for n in ("ols", "constrained", "consistent") if n in mass]
    rows = [[link] + [f"{mass[c]['links'][link]:.3f}" for c in cols] for link in links]
    rows.append(["**total**"] + [f"**{mass[c]['total']:.2f}**" for c in cols])
    lines = ["", "## Masses [kg]", "", *_table(["link"] + [TITLES.get(c, "URDF") for c in cols], rows)]
    lines += [
        "",
        "OLS identifies base parameters only: its standard parameters set the dependent ones to 0, so its masses "
        "are not estimates.",
        "",
        "## Physical consistency",
        "",
    ]
    cons = result["consistency"]
    rows = [
        [
            TITLES[n],
            "yes" if cons[n]["consistent"] else "no",
            f"{min(cons[n]['pseudo_inertia_min_eigenvalue'].values()):.3g}",
            ", ".join(cons[n]["active_pseudo_inertias"]) or "none",
            ", ".join(cons[n].get("violated_pseudo_inertias", [])) or "none",
        ]
        for n in TITLES
        if n in cons
    ]
    header = ["estimator", "consistent", "min λ(pseudo-inertia) [kg m²]", "active pseudo-inertias", "violated"]
    return lines + _table(header, rows)


def _tail(result: dict) -> list[str]:
    """The base parameters with their definitions, timings, what each estimator is."""
    rows = [
        [name, f"{b['value']:.5g}", f"{b['se']:.2g}", f"`{b['definition']}`"]
        for name, b in result["base_parameters"]["ols"].items()
    ]
    return [
        "",
        "## Base parameters (OLS, with standard errors)",
        "",
        *_table(["base parameter", "value", "SE", "definition"], rows),
        "",
        "Timings [s]: " + ", ".join(f"{k} {v:.3f}" for k, v in result["seconds"].items()) + ".",
        "",
        "Estimators: " + "; ".join(f"**{TITLES[k]}**: {v}" for k, v in result["estimators"].items()) + ".",
    ]


def markdown(result: dict) -> str:
    """compare.md: split, base parameters, held-out errors per joint, the 10 % check, masses, consistency."""
    protocol = result["split"]["protocol"]
    split = result["split"]
    lines = _head(result, "OLS, consistent and CAD parameters of an arm from a URDF")
    lines += [
        "",
        f"Split `{protocol}`: trained on {', '.join(Path(t).name for t in split['train'])} "
        f"({split['train_samples']} samples), tested on {', '.join(Path(t).name for t in split['test'])} "
        f"({split['test_samples']} samples).",
    ]
    lines += _errors(result, result["metrics"][protocol], "Held-out torque error per joint")
    lines += ["", "## Consistent fit against OLS (within 10 % of OLS's RMSE where OLS beats the CAD prior)", ""]
    rows = [
        [j, "yes" if c["ols_better_than_cad"] else "no", f"{c['ratio_to_ols']:.3f}", "yes" if c["within"] else "NO"]
        for j, c in result["within_10_percent_of_ols"].items()
    ]
    lines += _table(["joint", "OLS beats CAD", "RMSE consistent / OLS", "within 10 %"], rows)
    lines += _impossible(result) + _masses_and_consistency(result) + _tail(result)
    return "\n".join(lines) + "\n"


def identify_markdown(result: dict) -> str:
    """identify.md: every estimator on all the trials, the consistent fit's parameters with SEs, masses."""
    lines = _head(result, "identified parameters of an arm from a URDF")
    lines += ["", f"Trials: {', '.join(Path(t).name for t in result['trials'])} ({result['samples']} samples)."]
    lines += _errors(result, result["metrics"]["fit"], "Torque error per joint on the identification data")
    lines += _impossible(result) + _masses_and_consistency(result)
    params, se = result["parameters"], result["se"]["consistent"]
    rows = [
        [name, f"{params['consistent'][name]:.5g}", f"{se[name]:.2g}", f"{params['cad'][name]:.5g}"]
        for name in params["consistent"]
    ]
    lines += ["", "## Standard parameters of the default consistent fit", ""]
    lines += _table(["parameter", "consistent", "SE", "URDF CAD"], rows) + _tail(result)
    return "\n".join(lines) + "\n"


def write(result: dict, out_dir: Path, json_path: str | Path | None = None) -> Path:
    """compare.md and compare.json in `out_dir` (and `json_path` if given); returns the report's path."""
    title = f"{result['problem']}: OLS, consistent and CAD fits of a URDF arm"
    return _write(result, out_dir, json_path, "compare", markdown(result), title)


def write_identify(result: dict, out_dir: Path, json_path: str | Path | None = None) -> Path:
    """identify.md and identify.json in `out_dir` (and `json_path` if given); returns the report's path."""
    title = f"{result['problem']}: identified parameters of a URDF arm"
    return _write(result, out_dir, json_path, "identify", identify_markdown(result), title)


def _write(result: dict, out_dir: Path, json_path: str | Path | None, stem: str, text: str, title: str) -> Path:
    """`stem`.md (`text`) and `stem`.json in `out_dir` (and `json_path` if given), recorded as urdf_`stem`."""
    out_dir.mkdir(parents=True, exist_ok=True)
    report = out_dir / f"{stem}.md"
    outputs.write_text(report, text)
    write_json(out_dir / f"{stem}.json", result)
    if json_path:
        write_json(json_path, result)
    record(out_dir, f"urdf_{stem}", title, [report])
    return report


def terminal(result: dict) -> str:
    """A short summary: held-out RMSE per joint and estimator, masses, the 10 % check."""
    protocol = result["split"]["protocol"]
    scores = result["metrics"][protocol]
    lines = [
        f"{result['problem']}: {result['base']['count']} base parameters, condition number "
        f"{result['base']['condition_number']:.1f}; held-out ({protocol}) RMSE [N m] per joint:"
    ]
    for name in TITLES:
        if name in scores:
            values = " ".join(f"{v:7.3f}" for v in scores[name]["rmse"].values())
            mass = result["mass"].get(name, result["mass"]["urdf"] if name == "cad" else None)
            total = f"  total mass {mass['total']:.2f} kg" if mass and name != "ols" else ""
            lines.append(f"  {TITLES[name]:22s} {values}{total}")
    failed = [j for j, c in result["within_10_percent_of_ols"].items() if c["ols_better_than_cad"] and not c["within"]]
    lines.append(
        "consistent fit within 10 % of OLS on every joint where OLS beats the CAD prior"
        if not failed
        else f"consistent fit NOT within 10 % of OLS on {', '.join(failed)} (see compare.md)"
    )
    return "\n".join(lines)
