"""The diagnosis's verdict in words (`ident_opt.diagnosis.verdict`): can these data tell, each named cause's
plausibility and confirmation, the mismatch and not-identifiable entries and the candidates the plausibility rule
rejected — for the terminal summary and the Markdown report (`report.diagnosis`)."""

from __future__ import annotations

import numpy as np

from ident_opt.diagnosis.result import Diagnosis
from ident_opt.wording import num


def _rounded(estimate: dict) -> dict:
    return {k: (np.round(v, 4).tolist() if not isinstance(v, int) else v) for k, v in estimate.items()}


def identifiability_sentence(d: Diagnosis) -> str:
    """Can these data tell? The training motion's independent motions and the held-out part's distance from it."""
    ident = d.identifiability
    if not ident:
        return ""
    n = ident.get("n_joints", len(d.joints))
    motions = f"{ident['independent_motions']} independent motions for {n} joints"
    undetermined = ident.get("undetermined") or []
    left = f" (undetermined: {'; '.join(undetermined)})" if undetermined else ""
    distance = ident.get("held_out_distance_rad")
    held = (
        f"the held-out part ({ident['scored_on']}) is a motion of its own ({num(distance, 'rad')} from the nearest "
        "training stretch)"
        if ident.get("held_out_distinct")
        else f"the held-out part ({ident['scored_on']}) repeats the training motion ({num(distance, 'rad')} from "
        "the nearest training stretch): its gains are unverified"
    )
    return f"The training motion holds {motions}{left}; {held}."


def cause_lines(d: Diagnosis) -> list[str]:
    """Each named cause's plausibility (its four checks) and confirmation on another trial, one line each."""
    out = []
    for c in d.causes:
        checks = c.get("checks")
        if checks is None:
            continue
        failed = [
            name
            for name, ok in (
                ("range", checks["range"]),
                ("search edge", not checks["search_edge"]),
                ("no joint worse", checks["no_joint_worse"]),
                ("forward simulation", checks["forward_simulation"]),
            )
            if not ok
        ]
        plausible = "plausible" if c.get("plausible") else f"IMPLAUSIBLE ({', '.join(failed)})"
        why = (c.get("plausibility") or {}).get("reasons") or []
        confirmed = (
            f"confirmed on {c['confirmed_on']}"
            if c.get("confirmed_on")
            else "unconfirmed (no trial that neither trained nor selected it shows its gain)"
        )
        out.append(
            f"{c['cause']}: {plausible}{': ' + '; '.join(why) if why and not c.get('plausible') else ''}; {confirmed}"
        )
    return out


def verdict_lines(d: Diagnosis) -> list[str]:
    """The verdict, the mismatch and not-identifiable entries and the candidates the plausibility rule rejected."""
    out = [f"verdict: {d.verdict}"]
    for m in d.mismatch:
        rejected = ", ".join(m["explained_by_rejected"]) or "no catalogue cause"
        out.append(
            f"mismatch on {', '.join(m['joint_names'])}: {m['signature']}; explained only by {rejected} (rejected as "
            f"implausible); check {m['check']}"
            if m["explained_by_rejected"]
            else f"mismatch on {', '.join(m['joint_names'])}: {m['signature']}; no catalogue cause explains it; check "
            f"{m['check']}"
        )
    for e in d.not_identifiable:
        rejected = f" (rejected as not identifiable: {', '.join(e['rejected'])})" if e.get("rejected") else ""
        out.append(f"not identifiable: {e['what']}{rejected}; record it: {e['record']}")
    for r in d.rejected:
        what = f"on {', '.join(r['left_out_joints'])}" if r.get("left_out_joints") else f"`{_rounded(r['estimate'])}`"
        out.append(f"rejected in round {r['round']}: {r['cause']} {what}: {'; '.join(r['reasons'])}")
    return out


def verdict_section(d: Diagnosis) -> list[str]:
    """The verdict first: can these data tell, each named cause's plausibility and confirmation, where the model or
    the description is wrong (mismatch) and what the data lack (not identifiable), and the rejected candidates."""
    lines = ["## Verdict", "", f"**{d.verdict}**. {VERDICT_MEANING.get(d.verdict, '')}", ""]
    if d.identifiability:
        lines += [f"Can these data tell? {identifiability_sentence(d)}", ""]
    lines += _causes_table(d)
    for m in d.mismatch:
        rejected = ", ".join(f"`{c}`" for c in m["explained_by_rejected"])
        lines += [
            f"- **mismatch** on {', '.join(m['joint_names'])} (held-out nMSE after "
            f"{', '.join(num(v) for v in m['nmse_after'])}): {m['signature']}. "
            + (
                f"Only {rejected} would explain it, and it is not plausible. "
                if m["explained_by_rejected"]
                else "No catalogue cause explains it. "
            )
            + f"Check {m['check']}."
        ]
    for e in d.not_identifiable:
        rejected = f" Rejected as not identifiable: {', '.join(e['rejected'])}." if e.get("rejected") else ""
        beyond = (
            f" The residual beyond noise there ({', '.join(e['residual_beyond_noise'])}): {e['signature']}."
            if e.get("residual_beyond_noise")
            else ""
        )
        lines += [f"- **not identifiable**: {e['what']}.{rejected}{beyond} Record it: `{e['record']}`"]
    if d.mismatch or d.not_identifiable:
        lines.append("")
    lines += _rejected_lines(d)
    return lines


def _causes_table(d: Diagnosis) -> list[str]:
    """Each named cause's plausibility checks and confirmation, as a table."""
    if not d.causes:
        return []
    lines = ["| cause | plausible | range | search edge | no joint worse | forward simulation | confirmed on |"]
    lines += ["|---|---|---|---|---|---|---|"]
    for c in d.causes:
        k = c.get("checks") or {}
        yes = {True: "yes", False: "no", None: "—"}
        lines.append(
            f"| {c['cause']} | {yes[c.get('plausible')]} | {yes[k.get('range')]} | "
            f"{'at an edge' if k.get('search_edge') else 'inside'} | {yes[k.get('no_joint_worse')]} | "
            f"{yes[k.get('forward_simulation')]} | {c.get('confirmed_on') or 'unconfirmed'} |"
        )
    lines.append("")
    unconfirmed = [c["cause"] for c in d.causes if not c.get("confirmed_on")]
    if unconfirmed:
        lines += [
            f"Unconfirmed: {', '.join(unconfirmed)} — no trial that neither trained nor selected the cause shows "
            "its gain (none was given, or it does not gain there; `confirmation` in the JSON).",
            "",
        ]
    return lines


def _rejected_lines(d: Diagnosis) -> list[str]:
    """The candidates the plausibility rule rejected where they would have been named, with why."""
    if not d.rejected:
        return []
    lines = ["Candidates the plausibility rule rejected where they would have been named:", ""]
    for r in d.rejected:
        if r.get("left_out_joints"):
            lines.append(
                f"- round {r['round']}: **{r['cause']}** on {', '.join(r['left_out_joints'])} (left out of the "
                f"candidate, fitted again without): {'; '.join(r['reasons'])}"
            )
            continue
        lines.append(
            f"- round {r['round']}: **{r['cause']}** (score {r['score']:.1f}, against the {r['baseline']} model, "
            f"estimate `{_rounded(r['estimate'])}`): {'; '.join(r['reasons'])}"
        )
    lines.append("")
    return lines


#: What each verdict means, in a sentence.
VERDICT_MEANING = {
    "causes": "At least one plausible cause is named (below); any mismatch or missing motion listed here concerns "
    "what it leaves.",
    "none": "Nothing beyond noise remains that a cause would explain: the nominal model stands.",
    "mismatch": "A residual clearly beyond noise remains that no plausible catalogue cause explains: the model or the "
    "description (a URDF frame, a torque channel, a missing body) is wrong there.",
    "not_identifiable": "The trials cannot tell: they lack the motion that would separate the causes (below, with the "
    "command that records it).",
}
