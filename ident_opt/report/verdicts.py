"""The verdict of each study, as a few Markdown lines for the top of the folder's `index.html` (`report.html`):
what a person needs first — the recommended fit and why, the warnings, the causes, the fleet's changes, the
alarms. Each writer passes its verdict to `report.record(..., verdict=)`; the README and Markdown do not change.
"""

from __future__ import annotations

from ident_opt.warnings import ResultWarning


def warning_lines(warnings: list[ResultWarning]) -> list[str]:
    """One Markdown item per warning ("- **code**: message"), or one line saying there is none."""
    if not warnings:
        return ["No warnings."]
    return ["**Warnings:**", "", *(f"- **{w.code}**: {w.message}" for w in warnings)]


def recommended(estimator: str, why: str) -> str:
    """The recommended fit and why, as one Markdown line."""
    return f"**Recommended fit: {estimator}** — {why}."


def fit_verdict(choice, warnings: list[ResultWarning]) -> str:
    """`identify` and `compare`: the recommended fit (`fitting.recommend.Choice`, may be None) and the warnings."""
    lines = [recommended(choice.estimator, choice.why), ""] if choice is not None else []
    return "\n".join([*lines, *warning_lines(warnings)])


def fleet_verdict(result) -> str:
    """`fleet` (`FleetResult`): the fit, how many robots changed and each change (robot, cause, joint, since,
    confidence), the warnings."""
    changed = sorted({c.robot for c in result.changes})
    lines = [recommended(result.estimator, result.why), ""]
    lines.append(f"**{len(changed)} of {len(result.robots)} robot(s) changed**" + (":" if changed else "."))
    lines.append("")
    for c in result.changes:
        joint = f" on joint {c.joint}" if c.joint is not None else ""
        lines.append(
            f"- `{c.robot}`: **{c.cause}**{joint} since {c.first_day} ({c.pattern}; z {c.z:+.1f}, explains "
            f"{c.explained:.0%})"
        )
    if result.skipped:
        lines += ["", f"{len(result.skipped)} file(s) skipped (listed in the report)."]
    return "\n".join([*lines, "", *warning_lines(result.warnings)])


def detect_verdict(detection, joint_names: tuple[str, ...] = ()) -> str:
    """`detect` (`contact.detect.Detection`): the fit, the held-out false-alarm rate of the thresholds, each data
    trial's alarms (start–end [s], joint by name, peak [N m]), the warnings."""
    names = list(joint_names) or [f"joint {j + 1}" for j in range(detection.thresholds.n)]
    total = sum(len(t.alarms) for t in detection.trials)
    lines = [recommended(detection.estimator, detection.why), "", f"**{total} alarm(s)** in the data:", ""]
    for trial in detection.trials:
        lines.append(f"- `{trial.source}`: {len(trial.alarms)} alarm(s)")
        for a in trial.alarms:
            joint = names[a.joint - 1] if 1 <= a.joint <= len(names) else f"joint {a.joint}"
            lines.append(f"    - {a.start:.3f}–{a.end:.3f} s, `{joint}`, peak {a.peak:.3g} N m")
    for c in detection.calibration:
        lines += ["", f"Calibration `{c['source']}`: {c['false_alarms_per_minute']:.2f} false alarms/min held out."]
    return "\n".join([*lines, "", *warning_lines(detection.warnings)])
