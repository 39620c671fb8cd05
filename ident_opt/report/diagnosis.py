"""The diagnosis in words and figures: a terminal summary, a Markdown report, two PNG figures.

What each cause's finding says in words is the cause's own (`Effect.sentence`, built with `ident_opt.wording`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ident_opt import outputs, wording
from ident_opt.diagnosis import scoring
from ident_opt.diagnosis.result import Diagnosis
from ident_opt.effects import CATALOGUE
from ident_opt.numerics import signals
from ident_opt.report import record
from ident_opt.report.diagnosis_verdict import cause_lines, identifiability_sentence, verdict_lines, verdict_section
from ident_opt.report.figures import text
from ident_opt.warnings import markdown_lines
from ident_opt.wording import NOT_RESOLVED, num, pair


def joint(d: Diagnosis, j: int) -> str:
    """Joint j (0-based) as the report names it (`wording.joint`)."""
    return wording.joint(d.joints, j)


def _gain(d: Diagnosis) -> str:
    return "; ".join(f"{joint(d, j)} {num(b)} → {num(a)}" for j, (b, a) in enumerate(zip(d.nmse_before, d.nmse_after)))


def cause_sentence(d: Diagnosis) -> str:
    """One or two sentences that say what was found, with its held-out gain."""
    base = "datasheet" if d.baseline == "datasheet" else "best rigid fit"
    gain = f"held-out nMSE {_gain(d)}."
    if d.cause == "none":
        best = d.candidates[0]
        why = f" and is not named: {best['shortfall']}" if best.get("shortfall") else ""
        return (
            f"No catalogue effect beats the nominal models by the stated margin: the best candidate, "
            f"{best['cause']}, scores {best['score']:.1f} against the {best['baseline']} model{why}. "
            f"The {base} model stands (held-out nMSE {pair(d.nmse_before)})."
        )
    return CATALOGUE[d.cause].sentence(d, base, gain)


def chain_sentences(d: Diagnosis) -> list[str]:
    """The chain of causes in sentences, one per round, each with its held-out gain (measured torque)."""
    if not d.causes:
        return []
    out, before, names = [], d.nmse_before, []
    for c in d.causes:
        step = "; ".join(f"{joint(d, j)} {num(b)} → {num(a)}" for j, (b, a) in enumerate(zip(before, c["nmse_after"])))
        given = f"with {', '.join(names)} in the model, " if names else ""
        out.append(
            f"Round {c['round']}: {given}**{c['cause']}** clears the margin (score {c['score']:.1f}, fitted "
            f"against the {c['baseline']} model); estimate `{_rounded(c['estimate'])}`; held-out nMSE {step}."
        )
        if names:  # the first cause's reading is `cause_sentence`; a later one's is said here, in its own words
            base = "datasheet" if c["baseline"] == "datasheet" else "best rigid fit"
            seen = replace(d, cause=c["cause"], estimate=c["estimate"])
            out.append(CATALOGUE[c["cause"]].sentence(seen, base, f"held-out nMSE {step}."))
        before, names = c["nmse_after"], [*names, c["cause"]]
    last = d.rounds[-1] if len(d.rounds) > len(d.causes) and d.rounds[-1] else []
    why = last[0]["shortfall"] if last else None
    closest = f" (the closest, {last[0]['cause']}, is not named: {why})" if why else ""
    out.append(
        f"Round {d.causes[-1]['round'] + 1}: no further candidate clears the margin{closest}; the fully extended "
        f"model ({' + '.join(names)}) has held-out nMSE {pair(d.nmse_after)} against {pair(d.nmse_before)} before."
    )
    for g in d.dropped:
        out.append(
            f"{g['cause']} was dropped: a later cause made it redundant (its gain given the others: {g['score']:.1f})."
        )
    return out


def forward_sentence(d: Diagnosis) -> str:
    """The forward-simulation motion error before (the baseline) and after (the extended model)."""
    fe = d.evidence["forward_error_rad"]
    return (
        f"forward simulation driven by the measured torque (0.5 s windows, RMS angle error at the window's "
        f"end): {pair(fe[d.baseline], 'rad')} with the {d.baseline} model → {pair(fe['after'], 'rad')} with the "
        f"{'extended' if d.causes else 'same'} model"
    )


def rigid_fit_sentence(d: Diagnosis) -> str:
    """Which estimator gave the rigid fit and why (the recommended fit unless --estimator said otherwise)."""
    rigid = d.nominal["rigid_fit"]
    return f"the {rigid['estimator']} fit" + (f" ({rigid['why']})" if rigid.get("why") else "")


def summary(d: Diagnosis) -> str:
    """The terminal summary: the four questions, briefly, then the verdict and what stands behind each cause."""
    nom = d.nominal
    lines = [
        f"diagnosis ({d.split}; {d.rate_hz:.4g} Hz)",
        *(["0. " + identifiability_sentence(d)] if d.identifiability else []),
        "1. nominal models, held-out nMSE per joint: datasheet "
        + pair(nom["datasheet"]["nmse"])
        + ", rigid fit "
        + pair(nom["rigid_fit"]["nmse"]),
        f"2. cause: {d.cause}" + (f" (against the {d.baseline} model)" if d.cause != "none" else ""),
        "   " + cause_sentence(d),
        *("   " + line for line in chain_sentences(d)),
        "3. candidates (score = penalised held-out log-likelihood gain):",
    ]
    for c in d.candidates:
        lines.append(
            f"   {c['cause']:20s} {c['score']:10.1f}  vs {c['baseline']:9s} nMSE after {pair(c['nmse_after'])}"
        )
    lines.append(f"4. held-out nMSE before → after: {_gain(d)}")
    lines.append("   " + forward_sentence(d))
    lines += [f"5. {verdict_lines(d)[0]}", *("   " + line for line in [*cause_lines(d), *verdict_lines(d)[1:]])]
    return "\n".join(lines)


def figures(d: Diagnosis, out: Path) -> list[str]:
    """residual_before_after.png and spectrum_before_after.png in `out`; returns their file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, tau = d.test.t, d.test.tau
    n = tau.shape[1]
    before, after = tau - d.predictions["before"], tau - d.predictions["after"]
    label_after = f"after ({' + '.join(c['cause'] for c in d.causes)})" if d.causes else "after (no extension)"
    rigid = d.nominal.get("rigid_fit", {}).get("estimator")
    label_before = f"before (rigid fit: {rigid})" if d.baseline == "rigid_fit" and rigid else f"before ({d.baseline})"
    fig, axes = plt.subplots(n, 1, figsize=(10, 6 if n == 2 else 1.8 * n + 1), sharex=True)
    for j, ax in enumerate(axes):
        ax.plot(t, before[:, j], lw=0.7, label=label_before)
        ax.plot(t, after[:, j], lw=0.7, label=label_after, alpha=0.8)
        ax.set_ylabel(f"{joint(d, j)} residual [N m]", fontsize=8 if n > 2 else None)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s] (held-out part)")
    fig.suptitle(f"Torque residual τ − τ̂ on held-out data ({text(Path(d.test.source).name)})")
    fig.tight_layout()
    try:
        with outputs.atomic_path(out / "residual_before_after.png") as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)

    dt = 1.0 / d.rate_hz
    if n == 2:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    else:
        rows = -(-n // 2)
        fig, grid = plt.subplots(rows, 2, figsize=(11, 3.2 * rows), squeeze=False)
        axes = grid.ravel()[:n]
        for spare in grid.ravel()[n:]:
            spare.set_visible(False)
    for j, ax in enumerate(axes):
        for r, lab in ((before, label_before), (after, label_after)):
            f, p = signals.spectrum(r[:, j], dt)
            ax.loglog(f[1:], p[1:], lw=0.8, label=lab)  # log frequency: slow drifts and modes both legible
        # Every cause of the chain that has a frequency to show (an elastic mode found in a later round too).
        markers = [CATALOGUE[c["cause"]].spectrum_marker(c["estimate"], j) for c in d.causes if c["cause"] in CATALOGUE]
        for marker in (m for m in markers if m is not None):
            ax.axvline(marker, color="k", ls=":", lw=0.8, label=f"identified mode {marker:.3g} Hz")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"{joint(d, j)} residual PSD [(N m)²/Hz]", fontsize=8 if n > 2 else None)
        ax.legend(fontsize=8)
    fig.suptitle("Residual spectrum on held-out data")
    fig.tight_layout()
    try:
        with outputs.atomic_path(out / "spectrum_before_after.png") as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)
    return ["residual_before_after.png", "spectrum_before_after.png"]


def _evidence_table(d: Diagnosis) -> list[str]:
    n = len(d.nmse_before)
    short = {"datasheet": "datasheet", "rigid_fit": "rigid fit"}
    heads = [f"{short[b]} {f'j{j + 1}' if n == 2 else joint(d, j)}" for b in short for j in range(n)]
    rows = ["| evidence (held-out) | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]

    def row(name, fn):
        vals = [fn(d.evidence[b], j) for b in ("datasheet", "rigid_fit") for j in range(n)]
        rows.append(f"| {name} | " + " | ".join(vals) + " |")

    row("residual RMS [N m]", lambda e, j: num(e["rms"][j]))
    row("nMSE of the raw residual (rest levels included)", lambda e, j: num(e["nmse"][j]))
    row(
        "strongest residual peak [Hz] (ζ)",
        lambda e, j: (
            f"{num(e['peaks'][j][0]['frequency_hz'])} ({num(e['peaks'][j][0]['damping'], digits=2)})"
            if e["peaks"][j]
            else "—"
        ),
    )
    row(f"power share below {0.6} Hz", lambda e, j: num(e["low_band_fraction"][j]))
    row(
        "mean residual moving +/− [N m]",
        lambda e, j: f"{num(e['moving_mean'][j]['positive'])} / {num(e['moving_mean'][j]['negative'])}",
    )
    row("reversal jump −→+ / +→− [N m]", lambda e, j: _either_way(e["reversal_steps"][j]))
    row("low-speed excess [N m]", lambda e, j: num(e["low_speed_excess"][j]))
    row("pose-explained share (gravity-like)", lambda e, j: num(e["pose_r2"][j]))
    row("lag of measured vs predicted [ms]", lambda e, j: num(1e3 * e["lag_s"][j]))
    fe = d.evidence["forward_error_rad"]
    rows.append(
        "| forward simulation, 0.5 s windows, RMS angle error [rad] | "
        + " | ".join(num(fe[b][j]) for b in ("datasheet", "rigid_fit") for j in range(n))
        + " |"
    )
    return rows


def _either_way(steps: dict) -> str:
    """A reversal-jump cell: "up / down" [N m], one `NOT_RESOLVED` cell when neither direction reverses."""
    up, down = steps["negative_to_positive"], steps["positive_to_negative"]
    if not (np.isfinite(up) or np.isfinite(down)):
        return NOT_RESOLVED
    return f"{num(up)} / {num(down)}"


def channels_paragraph(d: Diagnosis) -> list[str]:
    """What the file's other channels (e.g. strain gauges) say, as independent evidence of a mode."""
    ch = d.evidence.get("other_channels") or {}
    if not ch:
        return []
    lines = [
        "## Independent channels",
        "",
        "Other numeric columns of the data file, never model inputs (on the MERIt trials col10–col13 are the "
        "links' strain gauges): the strongest power in the 1–10 Hz band of first link modes, and the most "
        "prominent peaks above 0.7 Hz.",
        "",
        "| channel | strongest in 1–10 Hz | prominent peaks [Hz] |",
        "|---|---|---|",
    ]
    for name, info in ch.items():
        peaks = ", ".join(f"{num(p['frequency_hz'])} ({num(p['prominence_db'], digits=2)} dB)" for p in info["peaks"])
        lines.append(f"| `{name}` | {num(info['mode_band_max_hz'])} Hz | {peaks or '—'} |")
    for effect in CATALOGUE.values():
        lines += effect.channel_lines(d, ch)
    return [*lines, ""]


def also_clear(d: Diagnosis) -> list[str]:
    """Runner-up candidates that would also clear the naming margin (a second effect may be present)."""
    chained = {c["cause"] for c in d.causes}
    others = [c for c in d.candidates if c["cause"] not in chained and c.get("clears_margin")]
    if not others:
        return []
    return [
        "Other candidates that also clear the margin on their own (effects need not come alone): "
        + "; ".join(
            f"{c['cause']} against the {c['baseline']} model (score {c['score']:.1f}, estimate "
            f"`{_rounded(c['estimate'])}`, held-out nMSE after {pair(c['nmse_after'])})"
            for c in others
        )
        + ".",
        "",
    ]


def _rounded(estimate: dict) -> dict:
    return {k: (np.round(v, 4).tolist() if not isinstance(v, int) else v) for k, v in estimate.items()}


def _preamble(d: Diagnosis) -> list[str]:
    """The title, what the data are and how the residual is measured, and the warnings."""
    return [
        "# Diagnosis",
        "",
        f"Data: {d.split} ({d.rate_hz:.4g} Hz). All numbers are on the held-out part. The torque is "
        "low-passed by the same zero-phase filter the derivatives are estimated with, and where a joint "
        "rests its residual is compared about its mean over the rest (stiction holds a level no model "
        "predicts); `nmse_raw_*` in the JSON are without that.",
        "",
        f"Compared: {d.compared()}.",
        "",
        "## Warnings",
        "",
        *markdown_lines(d.warnings),
        "",
    ]


def _nominal_section(d: Diagnosis) -> list[str]:
    """Section 1: the nominal models' held-out nMSE, the rigid fit's estimator and the evidence table."""
    nom = d.nominal
    return [
        "## 1. What the nominal models get wrong",
        "",
        f"Held-out nMSE (MSE ÷ variance) per joint: datasheet {pair(nom['datasheet']['nmse'])}, "
        "best rigid fit "
        f"{pair(nom['rigid_fit']['nmse'])}.",
        *(["", f"The rigid fit: {rigid_fit_sentence(d)}."] if "estimator" in nom["rigid_fit"] else []),
        "",
        *_evidence_table(d),
        "",
    ]


def _scoring_paragraph(d: Diagnosis) -> str:
    """How every catalogue effect is fitted and scored, and when a cause is named."""
    return (
        "Every catalogue effect was fitted on the training part (with the datasheet's π held, and/or with π "
        "refitted) and scored on the held-out part against the same reference for all: score = (n/2) Σ_j "
        "ln(MSE_ref,j / MSE_cand,j) − (Δk/2) ln n, the reference being the current model with the datasheet's π "
        "(first round: the datasheet) and Δk the parameters fitted beyond it (a refitted π counts all "
        f"{d.nominal['rigid_fit'].get('rank', 10)}). A "
        "cause is named when its score is positive and, on some joint, it removes at least 5 % of the held-out "
        f"MSE of the same kind of fit without it and at least {100 * d.margin_variance:g} % of the torque's "
        "variance, and against the fit of any cause whose columns it contains (an elastic joint's motor inertia is "
        f"an armature) too; a cause holding the datasheet's π must also explain {scoring.RECOVER:.0%} of what a "
        "refitted π gains over it"
        + "".join(f"; {rule} ({reason})" for rule, reason in scoring.rules())
        + ". The best such cause is added to the model and the question is asked again (a datasheet-side cause that"
        + (f" explains {d.partner:.0%} to" if d.partner > 0 else " explains less than")
        + f" {scoring.RECOVER:.0%} of the refit's gain is tried with a partner, kept"
        f" only if the pair explains {scoring.RECOVER:.0%})."
    )


def _cause_section(d: Diagnosis) -> list[str]:
    """Section 2: the cause named, how causes are scored, every candidate, the chain and other clear candidates."""
    lines = [
        "## 2. The cause",
        "",
        f"**{d.cause}**"
        + (f" (found against the {d.baseline} model)" if d.cause != "none" else "")
        + ". "
        + cause_sentence(d),
        "",
        _scoring_paragraph(d),
        "",
        "| cause | score | baseline | added parameters | held-out nMSE after | estimate |",
        "|---|---|---|---|---|---|",
    ]
    for c in d.candidates:
        lines.append(
            f"| {c['cause']} | {c['score']:.1f} | {c['baseline']} | {c['added_parameters']} | "
            f"{pair(c['nmse_after'])} | `{_rounded(c['estimate'])}` |"
        )
    chain = chain_sentences(d)
    if chain:
        lines += ["", "### The chain of causes", "", *chain]
    return [*lines, "", *also_clear(d)]


def _extended_section(d: Diagnosis) -> list[str]:
    """Section 3: the extended model's parameters with their standard errors, or that the nominal model is kept."""
    lines = ["## 3. The extended model", ""]
    if d.named is None:
        return [*lines, "No extension: the nominal model is kept.", ""]
    lines += ["| parameter | value | standard error |", "|---|---|---|"]
    for name, value in d.named.parameters.items():
        se = d.named.se.get(name)
        shown = f"{se:.2g}" if se is not None else "(searched)"
        lines.append(f"| {name} | {value:.5g} | {shown} |")
    return [
        *lines,
        "",
        "Standard errors: every coefficient and every searched parameter together (Gauss–Newton at the "
        "optimum, on the training part), with the residuals' correlation over time counted (Newey–West). "
        "They measure what the noise leaves uncertain, not a bias from something the model lacks.",
        "",
    ]


def _gain_section(d: Diagnosis, figure_files: list[str]) -> list[str]:
    """Section 4: the held-out gain in torque and in motion, and the figures."""
    return [
        "## 4. The gain",
        "",
        f"Held-out nMSE (measured torque) before → after: {_gain(d)}.",
        "",
        f"Motion: {forward_sentence(d)}. The extended model's rigid part is integrated; the rest of its torque "
        "(a mode, a delay, a friction shape) is evaluated along the measured motion, since some of it depends "
        "on the history.",
        "",
        *(f"![{f}]({f})" for f in figure_files),
        "",
    ]


def markdown(d: Diagnosis, figure_files: list[str]) -> str:
    """The Markdown report."""
    lines = [
        *_preamble(d),
        *verdict_section(d),
        *_nominal_section(d),
        *_cause_section(d),
        *_extended_section(d),
        *_gain_section(d, figure_files),
        *channels_paragraph(d),
    ]
    return "\n".join(lines)


def write(d: Diagnosis, out: Path) -> list[str]:
    """Write the figures and `diagnosis.md` to `out`; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    files = figures(d, out)
    outputs.write_text(out / "diagnosis.md", markdown(d, files))
    record(
        out,
        "diagnosis",
        "what the rigid model gets wrong, why, and the held-out gain of the fix",
        ["diagnosis.md", *files],
        verdict="\n".join(verdict_section(d)[2:]),  # without its "## Verdict" heading: the page has one
    )
    return [*files, "diagnosis.md"]
