"""The front and back of the README `ident-opt identify` writes: how it was made, the reproduction table, the
findings (each computed from this run's numbers) and every figure explained — the paper's narrative where its
protocol ran, a per-joint account for any other arm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ident_opt.evaluation.identify import IdentifyResult
from ident_opt.paper.protocols import ProtocolResult
from ident_opt.paper.published import NMSE_RANGE, NMSE_RANGE_TOLERANCE, RMSE_TOLERANCE
from ident_opt.report import shown
from ident_opt.report.identify_tables import PROTOCOL_TITLES, dm_key, model_name, reproduction_frame
from ident_opt.report.tables import fmt, markdown_table
from ident_opt.shipping.codegen import gmr_inputs
from ident_opt.warnings import markdown_lines


# ---------------------------------------------------------------------------------------------- README
def _v(p: ProtocolResult, key: str, j: int, metric: str = "nmse") -> str:
    return fmt(p.metrics[metric][key][j], 3)


def readme_parts(
    result: IdentifyResult, out: Path, tables: dict[str, Path], made: dict[str, Path], command: str, seconds: float
) -> tuple[str, str]:
    """The README's front (how it was made, the reproduction table, findings, the tables) and back (every
    figure explained); the index of the other reports goes between them (`ident_opt.report.record`)."""
    P = result.protocols
    paper, chrono, cross = P.get("paper"), P.get("chronological"), P.get("cross_trial")
    lines = _readme_intro(result, command, seconds)
    lines += _reproduction(result) if result.paper_robot else []
    rec = result.choice
    lines += ["", "## The recommended fit", "", f"cpbr is **{rec.estimator}**: {rec.why}."]
    lines += ["", "## Warnings", ""]
    lines += markdown_lines(result.warnings)
    lines += ["", "## Findings", ""]
    if paper is not None:
        lines += _findings(result, paper, chrono, cross, "cpbr" in paper.metrics["rmse"])
        sentences = _figure_sentences(paper, cross, result)
    else:
        lines += _arm_findings(result)
        sentences = _arm_figure_sentences(result)
    lines += ["", "## Tables", ""]
    lines += [f"- [{path.name}]({path.name}) (CSV beside it)" for path in tables.values()]
    lines += ["- [identify.json](identify.json): the machine-readable result (`docs/cli.md`)"]
    back = ["", "## Figures", ""]
    for name, (path, sentence) in sentences.items():
        if name in made:
            rel = made[name].relative_to(out) if made[name].is_relative_to(out) else path
            back += [f"### {sentence[0]}", "", f"![{sentence[0]}]({rel})", "", sentence[1], ""]
    return "\n".join(lines), "\n".join(back)


def _readme_intro(result: IdentifyResult, command: str, seconds: float) -> list[str]:
    lines = [
        f"# Results for `{result.problem_name}`",
        "",
        f"Written by `{command}` in {seconds:.0f} s. Identification trial: `{shown(result.trial)}`"
        + (f"; unseen trial: `{shown(result.unseen)}`." if result.unseen else "."),
        "",
        "Protocols (every table says which one it uses):",
        "",
    ]
    if result.robot_statement:  # a URDF arm: the offsets and signs its data went through
        lines[4:4] = ["The robot, and what was applied to its data:", "", "```", *result.robot_statement, "```", ""]
    return [
        *lines,
        *(f"- **{name}**: {p.description}" for name, p in result.protocols.items()),
        "",
        "The paper's protocol shuffles samples before splitting: at 100 Hz every test sample has near-copies "
        "in training, which flatters local models such as GMR. The chronological and cross-trial protocols are "
        'the honest numbers. When the number of GMR components is "auto", it is chosen on held-out training '
        "data that mirror the protocol: a random quarter under the paper's, the latest quarter in time under the "
        "honest ones.",
        "",
        f"GMR: one Gaussian mixture on [{' '.join(gmr_inputs(len(result.joints)))}, "
        f"{' '.join(f'r{j + 1}' for j in range(len(result.joints)))}] (every joint's torque residual in one "
        "mixture), fitted by scikit-learn on standardised columns with `reg_covar` from the problem file "
        f"({result.reg_covar:g}, relative to unit variance), full covariances unless a table says otherwise; "
        "predictions are the conditional mean, intervals use the conditional mixture variance (within- plus "
        "between-component).",
    ]


def _reproduction(result: IdentifyResult) -> list[str]:
    repro = reproduction_frame(result)
    missed = repro[repro["met"] == "NO"]
    return [
        "",
        "## Reproduction of the paper (paper's protocol)",
        "",
        f"Targets: RMSE within {RMSE_TOLERANCE * 100:.0f} % of the paper's seed table, `nmse_range` within "
        f"{NMSE_RANGE_TOLERANCE * 100:.0f} % of its parametric rows. "
        "The paper does not give its GMR settings (components, covariance type, scaling), so its GMR rows "
        "are reported beside ours, not targeted. `nmse_range` is MSE ÷ (max − min)², the paper's nMSE; "
        "`nmse` (÷ variance) is the usual one.",
        "",
        markdown_table(repro),
        "",
        (
            "All reproduction targets are met."
            if missed.empty
            else f"**{len(missed)} target(s) missed:** " + ", ".join(f"{m} {k} J{j}" for m, k, j in missed.index) + "."
        ),
    ]


def _findings(result, paper, chrono, cross, has_c) -> list[str]:
    """Measured statements, each computed from this run's numbers."""
    f = _component_findings(result, paper, chrono, cross)
    if not result.paper_robot:
        f.append(
            f"- The datasheet model of this problem (physical convention), no fitting at all: `nmse` "
            f"{_v(paper, 'dm_physical', 0)} / {_v(paper, 'dm_physical', 1)} (joint 1 / joint 2), against PBR's "
            f"{_v(paper, 'pbr', 0)} / {_v(paper, 'pbr', 1)}."
        )
    else:
        f += _paper_dm_findings(result, paper)
    f += _gmr_findings(paper, chrono, cross)
    if has_c:
        f.append(
            f"- CPBR vs PBR on the paper's protocol: `nmse` {_v(paper, 'cpbr', 0)} / {_v(paper, 'cpbr', 1)} "
            f"vs {_v(paper, 'pbr', 0)} / {_v(paper, 'pbr', 1)}; min eigenvalue of M(q) over q: "
            + ", ".join(f"{k} {v:.3g} kg·m²" for k, v in result.consistency.items())
            + "."
        )
    return f


def _paper_dm_findings(result, paper) -> list[str]:
    """The paper's Model 2 under both conventions, and what a GMR does to it (the paper's robot only)."""
    f = []
    f.append(
        f"- DM (paper's convention) vs DM (physical convention), no fitting at all: `nmse` "
        f"{_v(paper, 'dm', 0)} / {_v(paper, 'dm', 1)} vs {_v(paper, 'dm_physical', 0)} / "
        f"{_v(paper, 'dm_physical', 1)} (joint 1 / joint 2), against PBR's {_v(paper, 'pbr', 0)} / "
        f"{_v(paper, 'pbr', 1)}: reading the datasheet physically removes most of Model 2's joint-1 error."
    )
    f.append(_dm_gmr_finding(result, paper))
    return f


def _gmr_findings(paper, chrono, cross) -> list[str]:
    """What the GMR residual does under each protocol."""
    f = []
    gains = [
        f"{p.metrics['nmse']['pbr+gmr'][1] / p.metrics['nmse']['pbr'][1] - 1:+.0%} under the {name} protocol"
        for name, p in (("paper's", paper), ("chronological", chrono), ("cross-trial", cross))
        if p is not None
    ]
    f.append(
        "- The GMR's joint-2 effect on PBR (`nmse` change): "
        + ", ".join(gains)
        + ": most of the gain on shuffled splits comes from near-copies of the test samples in training."
    )
    for name, p in (("chronological", chrono), ("cross-trial", cross)):
        if p is None:
            continue
        f.append(
            f"- {name.capitalize()}: PBR `nmse` {_v(p, 'pbr', 0)} / {_v(p, 'pbr', 1)} → PBR + GMR "
            f"{_v(p, 'pbr+gmr', 0)} / {_v(p, 'pbr+gmr', 1)}; RR {_v(p, 'rr', 0)} / {_v(p, 'rr', 1)} → "
            f"RR + GMR {_v(p, 'rr+gmr', 0)} / {_v(p, 'rr+gmr', 1)}; 95 % coverage of PBR + GMR "
            f"{p.coverage['pbr+gmr'][0]:.1%} / {p.coverage['pbr+gmr'][1]:.1%} "
            f"(paper's protocol: {paper.coverage['pbr+gmr'][0]:.1%} / {paper.coverage['pbr+gmr'][1]:.1%})."
        )
    return f


def _component_findings(result, paper, chrono, cross) -> list[str]:
    """The GMR components chosen under each protocol."""
    top = max(result.gmr_candidates, default=None)
    at_top = bool(paper.components) and all(k == top for k in paper.components.values())
    f = [
        f"- GMR components chosen on validation data (first seed; candidates {list(result.gmr_candidates)}): "
        f"{', '.join(f'{k}: {v}' for k, v in paper.components.items())}"
        + (
            " — all the largest candidate: with shuffled samples the validation data have near-copies in "
            "training, so more components always look better."
            if at_top
            else "."
        )
    ]
    for name, p in (("chronological", chrono), ("cross-trial", cross)):
        if p is not None and p.components:
            f.append(
                f"- Components chosen for the {name} protocol: "
                f"{', '.join(f'{k}: {v}' for k, v in p.components.items())}."
            )
    return f


def _dm_gmr_finding(result, paper) -> str:
    """What a GMR does to DM's joint 1, with the GMR variants, beside the paper's row."""
    one, diag = result.variants.get("one_component"), result.variants.get("diagonal_covariance")
    return (
        f"- A full-covariance GMR on DM's residual brings DM's joint-1 `nmse_range` from "
        f"{_v(paper, 'dm', 0, 'nmse_range')} to {_v(paper, 'dm+gmr', 0, 'nmse_range')} (paper: "
        f"{NMSE_RANGE['dm'][0]:#.4g} → {NMSE_RANGE['dm+gmr'][0]:#.4g})"
        + (
            f"; with a single component (a linear correction) already {_v(one[1], 'dm+gmr', 0, 'nmse_range')}"
            if one
            else ""
        )
        + (
            f"; with diagonal covariances {_v(diag[1], 'dm+gmr', 0, 'nmse_range')}, since each component then "
            f"predicts a constant — nearer the paper's {NMSE_RANGE['dm+gmr'][0]:.3g}, whose GMR settings are not "
            "given (for the other GMR rows diagonal covariances move away from the paper's numbers: see the table)"
            if diag
            else ""
        )
        + "."
    )


def _error_sentence(split, j: int, rest_speed: float = 0.05, dm: str = "dm") -> str:
    """The error's size while moving and at rest (both |dq| < `rest_speed` rad/s), without and with GMR."""
    if split is None:
        return ""
    rest = np.all(np.abs(split.test.dq) < rest_speed, axis=1)

    def rms(key: str, mask: np.ndarray) -> str:
        err = split.test.tau[mask, j] - split.predictions[key][mask, j]
        return fmt(float(np.sqrt(np.mean(err**2))), 2) if mask.any() else "–"

    parts = [
        f"{k.upper()} {rms(k, ~rest)} → {rms(k + '+gmr', ~rest)} moving, {rms(k, rest)} → "
        f"{rms(k + '+gmr', rest)} at rest"
        for k in ("rr", dm, "pbr")
    ]
    return (
        f"RMS of the joint-{j + 1} error [N·m] without → with GMR on this split ({rest.mean():.0%} of the "
        f"samples at rest): " + "; ".join(parts) + "."
    )


def _seed_sentence(paper: ProtocolResult, paper_robot: bool = True) -> str:
    """How far the OLS parameters move over the shuffled splits, from this run's per-seed fits."""
    fits = paper.params_per_split.get("pbr", [])
    if len(fits) < 2:
        return "Deviation of each OLS parameter from its mean over the shuffled splits."
    names = list(fits[0])
    arr = np.array([[f[n] for n in names] for f in fits])
    dev = np.max(np.abs(arr / arr.mean(axis=0) - 1), axis=0) * 100
    order = np.argsort(dev)
    worst = ", ".join(f"{names[i]} up to {dev[i]:.0f} %" for i in order[::-1][:2])
    return (
        f"Over the shuffled splits most OLS parameters stay within {np.median(dev):.0f} % of their mean "
        f"(median of the largest deviations); the least determined are {worst}"
        + (" (the paper: α2 and fv2 within 15 %)." if paper_robot else ".")
    )


def _figure_sentences(paper, cross, result: IdentifyResult) -> dict[str, tuple[str, tuple[str, str]]]:
    """figure name -> (default relative path, (title, one sentence on what it shows))."""
    m = paper.metrics["nmse"]
    dm = dm_key(result)
    s = _time_figure_sentences(m, paper, dm)
    s.update(
        {
            "parity": (
                "figures/identify_parity.png",
                (
                    "Parity plots, 2 × 3 (paper's protocol)",
                    "Points on the diagonal are perfect predictions: with GMR, joint 1's nmse is at most "
                    f"{fmt(max(m[k + '+gmr'][0] for k in ('rr', dm, 'pbr')), 2)} for the three models, joint 2's "
                    f"at least {fmt(min(m[k + '+gmr'][1] for k in ('rr', dm, 'pbr')), 2)} (a visibly wider "
                    "cloud).",
                ),
            ),
            "interval": (
                "figures/identify_interval_pbr.png",
                (
                    "PBR + GMR with 95 % intervals (paper's protocol)",
                    f"The interval covers {paper.coverage['pbr+gmr'][0]:.0%} / "
                    f"{paper.coverage['pbr+gmr'][1]:.0%} of held-out joint-1 / joint-2 torques.",
                ),
            ),
            "seeds": (
                "figures/identify_seeds.png",
                (
                    "Grouped parameters over the paper's 10 seeds"
                    if result.paper_robot
                    else f"Grouped parameters over the {len(paper.rmse_per_split.get('pbr', []))} seeds of the "
                    "paper's protocol",
                    _seed_sentence(paper, result.paper_robot),
                ),
            ),
        }
    )
    if cross is not None:
        s.update(_cross_figure_sentences(m, cross, shown(result.trial), shown(result.unseen)))
    return s


def _time_figure_sentences(m: dict, paper: ProtocolResult, dm: str = "dm") -> dict[str, tuple[str, tuple[str, str]]]:
    """The torque and error figures over time: name -> (default relative path, (title, sentence))."""
    return {
        "torque_j1": (
            "figures/identify_torque_j1.png",
            (
                "Joint 1 torque predictions (paper's protocol)",
                f"RR and PBR follow the measured joint-1 torque closely (nmse {fmt(m['rr'][0], 2)}, "
                f"{fmt(m['pbr'][0], 2)}) while "
                + (
                    f"the paper's datasheet model is offset (nmse {fmt(m['dm'][0], 2)}) until the GMR removes it."
                    if dm == "dm"
                    else f"the datasheet model has nmse {fmt(m[dm][0], 2)} (with GMR {fmt(m[dm + '+gmr'][0], 2)})."
                ),
            ),
        ),
        "torque_j2": (
            "figures/identify_torque_j2.png",
            (
                "Joint 2 torque predictions (paper's protocol)",
                f"No rigid model explains joint 2 (nmse {fmt(m['pbr'][1], 2)} for PBR); GMR recovers part "
                f"of it on shuffled splits (PBR + GMR {fmt(m['pbr+gmr'][1], 2)}).",
            ),
        ),
        "error_j1": (
            "figures/identify_error_j1.png",
            ("Joint 1 torque error over time (paper's protocol)", _error_sentence(paper.example, 0, dm=dm)),
        ),
        "error_j2": (
            "figures/identify_error_j2.png",
            ("Joint 2 torque error over time (paper's protocol)", _error_sentence(paper.example, 1, dm=dm)),
        ),
    }


def _cross_figure_sentences(
    m: dict, cross: ProtocolResult, trial: str = "exp1", unseen: str = "exp2"
) -> dict[str, tuple[str, tuple[str, str]]]:
    """The cross-trial figures: name -> (default relative path, (title, sentence)); `m`: the paper's nmse."""
    s = {}
    mc = cross.metrics["nmse"]
    s["cross_j1"] = (
        "figures/identify_cross_trial_j1.png",
        (
            "Joint 1 on the unseen trial (cross-trial)",
            f"Identified on {trial}, predicted on {unseen}: PBR nmse {fmt(mc['pbr'][0], 2)}, "
            f"PBR + GMR {fmt(mc['pbr+gmr'][0], 2)}.",
        ),
    )
    s["cross_j2"] = (
        "figures/identify_cross_trial_j2.png",
        (
            "Joint 2 on the unseen trial (cross-trial)",
            f"Joint 2 on a new trial: PBR nmse {fmt(mc['pbr'][1], 2)} → PBR + GMR "
            f"{fmt(mc['pbr+gmr'][1], 2)}, against {fmt(m['pbr'][1], 2)} → {fmt(m['pbr+gmr'][1], 2)} "
            "on the paper's shuffled splits.",
        ),
    )
    s["cross_interval"] = (
        "figures/identify_cross_trial_interval_pbr.png",
        (
            "PBR + GMR with 95 % intervals on the unseen trial (cross-trial)",
            f"On the unseen trial the interval covers {cross.coverage['pbr+gmr'][0]:.0%} / "
            f"{cross.coverage['pbr+gmr'][1]:.0%} of the torques.",
        ),
    )
    return s


# ---------------------------------------------------------------------------------------------- any arm
def _joined(p: ProtocolResult, key: str, metric: str = "nmse") -> str:
    """A model's metric on every joint, "v1 / v2 / …" (3 significant digits)."""
    return " / ".join(fmt(v, 3) for v in p.metrics[metric][key])


def _arm_findings(result: IdentifyResult) -> list[str]:
    """Measured statements for an arm the paper's views do not apply to: per protocol, every model's `nmse` per
    joint, what the GMR residual does, its intervals' coverage; the fits' consistency margins."""
    joints = " / ".join(result.joints)
    f = [f"- `nmse` per joint ({joints}) on held-out data; `nmse_range` and RMSE are in the tables."]
    for name, p in result.protocols.items():
        title = PROTOCOL_TITLES.get(name, name)
        models = [k for k in p.metrics["nmse"] if "+" not in k]
        f.append(f"- {title}: " + "; ".join(f"{model_name(k)} {_joined(p, k)}" for k in models) + ".")
        gmr = [k for k in ("pbr", "cpbr") if f"{k}+gmr" in p.metrics["nmse"]]
        f.append(
            f"- {title}, with the GMR residual: "
            + "; ".join(f"{model_name(k + '+gmr')} {_joined(p, k + '+gmr')}" for k in gmr)
            + f"; 95 % coverage of PBR + GMR {' / '.join(f'{c:.1%}' for c in p.coverage.get('pbr+gmr', []))}"
            + (f"; GMR components {', '.join(f'{k}: {v}' for k, v in p.components.items())}." if p.components else ".")
        )
    f.append(
        f"- Consistency ({result.consistency_note}, > 0: physically consistent) of the whole-trial fits: "
        + ", ".join(f"{k} {v:.3g} kg·m²" for k, v in result.consistency.items())
        + "."
    )
    return f


def _arm_figure_sentences(result: IdentifyResult) -> dict[str, tuple[str, tuple[str, str]]]:
    """Every figure of an arm the paper's views do not apply to: name -> (default path, (title, sentence))."""
    chrono, cross = result.protocols["chronological"], result.protocols.get("cross_trial")
    m = chrono.metrics["nmse"]
    s = {}
    for j, joint in enumerate(result.joints):
        s[f"torque_j{j + 1}"] = (
            f"figures/identify_torque_j{j + 1}.png",
            (
                f"Joint {j + 1} ({joint}) torque predictions (chronological split)",
                f"nmse: RR {fmt(m['rr'][j], 2)}, DM {fmt(m['dm'][j], 2)}, PBR {fmt(m['pbr'][j], 2)}; with GMR "
                f"{fmt(m['rr+gmr'][j], 2)}, {fmt(m['dm+gmr'][j], 2)}, {fmt(m['pbr+gmr'][j], 2)}.",
            ),
        )
        s[f"error_j{j + 1}"] = (
            f"figures/identify_error_j{j + 1}.png",
            (
                f"Joint {j + 1} ({joint}) torque error over time (chronological split)",
                _error_sentence(chrono.example, j),
            ),
        )
    s["parity"] = (
        "figures/identify_parity.png",
        ("Parity plots (chronological split)", "Points on the diagonal are perfect predictions, one row per joint."),
    )
    s["interval"] = (
        "figures/identify_interval_pbr.png",
        (
            "PBR + GMR with 95 % intervals (chronological split)",
            f"The interval covers {' / '.join(f'{c:.0%}' for c in chrono.coverage['pbr+gmr'])} of the held-out "
            "torques, joint by joint.",
        ),
    )
    if cross is not None:
        mc = cross.metrics["nmse"]
        for j, joint in enumerate(result.joints):
            s[f"cross_j{j + 1}"] = (
                f"figures/identify_cross_trial_j{j + 1}.png",
                (
                    f"Joint {j + 1} ({joint}) on the unseen trial (cross-trial)",
                    f"PBR nmse {fmt(mc['pbr'][j], 2)}, PBR + GMR {fmt(mc['pbr+gmr'][j], 2)}.",
                ),
            )
        s["cross_interval"] = (
            "figures/identify_cross_trial_interval_pbr.png",
            (
                "PBR + GMR with 95 % intervals on the unseen trial (cross-trial)",
                f"On the unseen trial the interval covers "
                f"{' / '.join(f'{c:.0%}' for c in cross.coverage['pbr+gmr'])} of the torques.",
            ),
        )
    return s
