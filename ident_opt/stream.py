"""Streaming mode: the online identifier as a service for a controller process.

Input on a text stream (standard input), one sample per line, either
- CSV with a header line naming the columns (any order, extra columns ignored), or
- JSON lines: one object per line, e.g. {"t": 0.01, "q1": 0.1, "q2": 0.2, "dq1": 0, ..., "tau2": 0.3}.
The format is detected from the first non-empty line ("{" starts JSON). Needed: q1 q2 dq1 dq2 ddq1 ddq2
[rad, rad/s, rad/s²] (no derivative estimation here: the data format's zero-phase filter needs future
samples); tau1 tau2 [N m] — or motor currents i1 i2 [A], converted with the problem's torque constant ×
gear ratio — when present make the sample update the model (without them the line is a pure prediction
request); t [s] is echoed when present.

Output, one JSON line per sample (flushed at once):
    {"n": 17, "t": 0.17, "tau": [τ1, τ2], "lower": [..], "upper": [..], "std": [..], "parametric": [..]}
(the one-step-ahead prediction made before the sample's torque is used, with its 95 % interval), a line
{"snapshot": {"n": ..., "parameters": {...}}} every `snapshot_every` updates, and on end of input,
SIGINT or SIGTERM a last line {"final": {"n": ..., "parameters": {...}}} (also written to `final_path`).
A malformed line gets {"error": ..., "line": k} on the error stream and is skipped; the stream goes on.
"""

from __future__ import annotations

import json
import math
import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

from ident_opt.online import OnlineIdentifier, Prediction

#: Columns every sample needs, and the torque columns that make it an update.
INPUTS = ("q1", "q2", "dq1", "dq2", "ddq1", "ddq2")
TORQUES = ("tau1", "tau2")
CURRENTS = ("i1", "i2")


class BadLine(ValueError):
    """A line that is not a valid sample (reported on the error stream, then skipped)."""


@dataclass
class LineParser:
    """Turns lines into {column: float}; learns the format (and the CSV header) from the first line."""

    format: str | None = None  # "csv" or "json", decided by the first non-empty line
    header: list[str] = field(default_factory=list)
    current_to_torque: tuple[float, float] | None = None  # N m / A per joint, for i1 i2 samples

    def parse(self, line: str) -> dict[str, float] | None:
        """The sample on `line`, or None for a blank line or the CSV header; raises BadLine."""
        text = line.strip()
        if not text:
            return None
        if self.format is None:
            self.format = "json" if text.startswith("{") else "csv"
            if self.format == "csv":
                self.header = [c.strip() for c in text.split(",")]
                missing = [c for c in INPUTS if c not in self.header]
                if missing:
                    self.format = None  # still waiting for a usable header
                    raise BadLine(f"CSV header lacks column(s) {', '.join(missing)}")
                return None
        if self.format == "json":
            try:
                raw = json.loads(text)
            except json.JSONDecodeError as exc:
                raise BadLine(f"not JSON ({exc.msg})") from None
            if not isinstance(raw, dict):
                raise BadLine("a JSON line must be an object")
        else:
            cells = [c.strip() for c in text.split(",")]
            if len(cells) != len(self.header):
                raise BadLine(f"{len(cells)} fields, the header has {len(self.header)}")
            raw = dict(zip(self.header, cells))
        return _sample(raw, self.current_to_torque)


def _sample(raw: dict, current_to_torque: tuple[float, float] | None = None) -> dict[str, float]:
    """The numeric fields of a sample, checked: inputs present, every used value a finite number;
    currents i1 i2 become torques tau1 tau2 [N m]."""
    missing = [c for c in INPUTS if c not in raw]
    if missing:
        raise BadLine(f"missing field(s) {', '.join(missing)}")
    torques = [c for c in TORQUES if c in raw and raw[c] not in ("", None)]
    currents = [c for c in CURRENTS if c in raw and raw[c] not in ("", None)]
    if len(torques) == 1 or len(currents) == 1:
        raise BadLine("give both tau1 and tau2 (or both i1 and i2), or neither")
    if torques and currents:
        raise BadLine("give torques tau1 tau2 or currents i1 i2, not both")
    if currents and current_to_torque is None:
        raise BadLine("currents i1 i2 need the problem's torque constants and gear ratios")
    out = {}
    for name in (*INPUTS, *torques, *currents, *(["t"] if raw.get("t") not in (None, "") else [])):
        value = raw[name]
        if isinstance(value, bool):
            raise BadLine(f"{name} is not a number")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise BadLine(f"{name} is not a number: {value!r}") from None
        if not math.isfinite(number):
            raise BadLine(f"{name} is not finite: {value!r}")
        out[name] = number
    if currents:
        out["tau1"] = out.pop("i1") * current_to_torque[0]
        out["tau2"] = out.pop("i2") * current_to_torque[1]
    return out


def prediction_record(n: int, sample: dict[str, float], p: Prediction) -> dict:
    """The output line for one sample (n = updates so far, t echoed when given)."""
    record: dict = {"n": n}
    if "t" in sample:
        record["t"] = sample["t"]
    record.update(
        tau=p.tau.tolist(),
        lower=p.lower.tolist(),
        upper=p.upper.tolist(),
        std=p.std.tolist(),
        parametric=p.parametric.tolist(),
    )
    return record


class _Stop(Exception):
    """SIGTERM or SIGINT while waiting for input."""


def serve(
    identifier: OnlineIdentifier,
    names: tuple[str, ...],
    instream: TextIO,
    outstream: TextIO,
    errstream: TextIO,
    snapshot_every: int = 1000,
    on_final: Callable[[dict], None] | None = None,
    current_to_torque: tuple[float, float] | None = None,
) -> dict:
    """Run the stream until end of input, SIGINT or SIGTERM; returns (and writes) the final record.

    names: the parameter names of `identifier` (for the snapshots); on_final: called with the final
    record (e.g. to write it to a file) after it has been printed; current_to_torque: N m / A per joint
    (torque constant × gear ratio) for samples that give motor currents.
    """
    parser = LineParser(current_to_torque=current_to_torque)
    state = {"reading": False, "stop": False}

    def on_term(signum, frame):
        # SIGTERM/SIGINT: interrupt a blocking read at once; during an update, finish it and stop after it
        # (never half a step: the statistics and θ always describe the same samples).
        state["stop"] = True
        if state["reading"]:
            raise _Stop

    previous = {sig: _install(sig, on_term) for sig in (signal.SIGTERM, signal.SIGINT)}
    lineno = 0
    try:
        while not state["stop"]:
            state["reading"] = True
            try:
                line = instream.readline()
            finally:
                state["reading"] = False
            if not line:
                break
            lineno += 1
            try:
                sample = parser.parse(line)
            except BadLine as exc:
                _emit(errstream, {"error": str(exc), "line": lineno})
                continue
            if sample is None:
                continue
            q = np.array([sample["q1"], sample["q2"]])
            dq = np.array([sample["dq1"], sample["dq2"]])
            ddq = np.array([sample["ddq1"], sample["ddq2"]])
            if "tau1" in sample:
                p = identifier.update(q, dq, ddq, np.array([sample["tau1"], sample["tau2"]]))
            else:
                p = identifier.predict(q, dq, ddq)
            _emit(outstream, prediction_record(identifier.n_updates, sample, p))
            if "tau1" in sample and snapshot_every and identifier.n_updates % snapshot_every == 0:
                _emit(outstream, {"snapshot": _parameters(identifier, names)})
    except (KeyboardInterrupt, _Stop):
        pass
    finally:
        for sig, handler in previous.items():
            _install(sig, signal.SIG_DFL if handler is None else handler)
    final = {"final": _parameters(identifier, names)}
    _emit(outstream, final)
    if on_final is not None:
        on_final(final)
    return final


def _parameters(identifier: OnlineIdentifier, names: tuple[str, ...]) -> dict:
    return {"n": identifier.n_updates, "parameters": dict(zip(names, map(float, identifier.theta)))}


def _emit(stream: TextIO, record: dict) -> None:
    stream.write(json.dumps(record) + "\n")
    stream.flush()


def _install(signum, handler):
    """signal.signal where allowed (only the main thread may); returns the previous handler."""
    try:
        return signal.signal(signum, handler)
    except (ValueError, TypeError):  # not the main thread, or no previous Python-level handler
        return None
