"""What a fleet run leaves for alerting, beside its reports: `changes.jsonl` (one change per line, the keys of the
JSON's `changes`) and `metrics.prom` (Prometheus' text exposition format, for a node exporter's textfile collector
or any scraper).

Metrics, one sample per robot and tested parameter (labels `robot`, `parameter`), on each robot's latest fitted day:

- `ident_opt_fleet_parameter_latest`: the tested parameter's value (the base parameters in the model's units, the
  torque scales as factors);
- `ident_opt_fleet_parameter_z`: its z against the robot's baseline (`changes.Test`; only for robots with enough
  days to be tested);

and per robot `ident_opt_fleet_changes` (its changes found: 0 or 1) and `ident_opt_fleet_latest_day_seconds` (its
latest fitted day, 00:00 UTC, in Unix seconds). A value that is not finite (a parameter the day does not determine)
has no sample: Prometheus would take NaN for a number, and an alert rule comparing it is silently false.
"""

from __future__ import annotations

import datetime
import json
import math
from pathlib import Path

from ident_opt import outputs
from ident_opt.fleet.result import FleetResult

#: The files written into the output folder.
FILES = ("changes.jsonl", "metrics.prom")
#: Every metric's name starts so (Prometheus' names: [a-zA-Z_:][a-zA-Z0-9_:]*).
PREFIX = "ident_opt_fleet_"
#: (name, help) of each metric, all gauges.
METRICS = (
    ("parameter_latest", "Latest fitted day's value of a tested parameter, per robot."),
    ("parameter_z", "z of a tested parameter's latest value against the robot's baseline days."),
    ("changes", "Changes found for the robot (0 or 1)."),
    ("latest_day_seconds", "The robot's latest fitted day, 00:00 UTC, in Unix seconds."),
)


def _finite(value: object) -> object:
    """`value` with each non-finite number (in dicts and lists too) as None: strict JSON, as the JSON report's."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def changes_lines(result: FleetResult) -> str:
    """`changes.jsonl`: each change's JSON object (the keys of the JSON's `changes`) on its own line, strict JSON
    (a non-finite number as null); empty when nothing changed."""
    return "".join(json.dumps(_finite(c.as_dict()), allow_nan=False) + "\n" for c in result.changes)


def _label(value: str) -> str:
    """A label value escaped as the exposition format asks (backslash, double quote, line feed)."""
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def _sample(metric: str, labels: dict[str, str], value: float) -> str:
    inside = ",".join(f'{key}="{_label(text)}"' for key, text in labels.items())
    return f"{PREFIX}{metric}{{{inside}}} {float(value)!r}"


def _day_seconds(day: str) -> int:
    return int(datetime.datetime.fromisoformat(day).replace(tzinfo=datetime.UTC).timestamp())


def metrics_text(result: FleetResult) -> str:
    """`metrics.prom` (module doc): each metric's `# HELP` and `# TYPE` lines, then its samples."""
    samples: dict[str, list[str]] = {name: [] for name, _ in METRICS}
    changed = {c.robot for c in result.changes}
    for name, r in result.robots.items():
        if not r.days:
            continue
        last = len(r.days) - 1
        for q, parameter in enumerate(result.tested_names):
            labels = {"robot": name, "parameter": parameter}
            value = float(r.tested.values[last, q])
            if math.isfinite(value):
                samples["parameter_latest"].append(_sample("parameter_latest", labels, value))
            z = float(r.test.z[last, q]) if r.test is not None else math.nan
            if math.isfinite(z):
                samples["parameter_z"].append(_sample("parameter_z", labels, z))
        samples["changes"].append(_sample("changes", {"robot": name}, float(name in changed)))
        samples["latest_day_seconds"].append(_sample("latest_day_seconds", {"robot": name}, _day_seconds(r.days[-1])))
    lines = []
    for metric, text in METRICS:
        lines += [f"# HELP {PREFIX}{metric} {text}", f"# TYPE {PREFIX}{metric} gauge", *samples[metric]]
    return "\n".join(lines) + "\n"


def write(result: FleetResult, out: Path) -> list[Path]:
    """Both files into `out`, each atomically (`outputs.write_text`); returns them."""
    return [
        outputs.write_text(out / FILES[0], changes_lines(result)),
        outputs.write_text(out / FILES[1], metrics_text(result)),
    ]
