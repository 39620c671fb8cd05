"""Streaming mode: the online identifier as a service for a controller process (docs/online.md).

Input on standard input, one sample per line: CSV with a header line (any order, extra columns ignored), CSV
without a header when the problem's `[data] header = false` maps column indices, or JSON lines. The first
non-empty line decides. The problem's `[data.columns]` mapping and its `{column, scale, offset}` conversions
apply by the batch loader's rules (`columns.locate`). Each sample needs q1 … qn [rad] (n the arm's joints);
dq1 … dqn, ddq1 … ddqn [rad/s, rad/s²] when given, else estimated causally from q and t
(`numerics.causal.CausalDerivatives`: a linear-phase FIR whose delay is stated, the torque delayed to match);
tau1 … taun [N m] or motor currents i1 … in [A] make the sample an update.

Guards (nothing on the input kills the stream): lines that are not UTF-8, not parseable, with numbers that
overflow, missing fields or values outside the batch loader's plausibility limits (`data.PLAUSIBLE`) are
reported on the error stream as {"error", "kind", "line"} and skipped; a sample whose one-step residual is
beyond `outlier_k` robust standard deviations is answered but updates nothing (counted); a failed update
changes nothing. With a contact watch (`StreamOptions.watch`, `ident_opt.contact.watch`), every line carries the
external-torque estimate `tau_ext` [N m] and `alarm`; while an alarm or its settling lasts, a sample updates
nothing (neither θ nor the GMR residual; counted as `contact`); with `learning_lag` > 0 a sample is learnt that many
samples after it came (an alarm drops those still waiting: a push's onset, before its alarm, is not learnt). Output is
strict JSON (no NaN or Infinity). A header or mapping error is an `InputError` (exit status 2, one message),
raised before any output.
"""

from __future__ import annotations

import json
import math
import signal
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TextIO

import numpy as np

from ident_opt.adaptation.identifier import OnlineIdentifier, Prediction
from ident_opt.adaptation.lines import BadLine, LineParser, Mapping
from ident_opt.data.checks import PLAUSIBLE
from ident_opt.data.dataset import Dataset
from ident_opt.data.loader import _current_to_torque as current_to_torque  # the batch loader's rule and message
from ident_opt.errors import InputError
from ident_opt.numerics.causal import CausalDerivatives, NonIncreasingTime, RateError
from ident_opt.numerics.derivatives import resolve_cutoff

if TYPE_CHECKING:
    from ident_opt.contact.watch import ContactWatch

#: Default robust outlier threshold: residuals beyond this many robust standard deviations update nothing.
OUTLIER_K = 10.0
#: Memory (samples) of the robust residual scale; an outlier moves it by 1/`OUTLIER_MEMORY` of its clipped square.
OUTLIER_MEMORY = 500.0


#: Where a sample keeps its input line number (for errors found later, in the causal derivatives' window).
LINE = "_line"


# ---------------------------------------------------------------------------------------------- the service
def prediction_record(
    n: int, sample: dict[str, float], p: Prediction, contact: tuple[np.ndarray, bool] | None = None
) -> dict:
    """The output line for one sample (n = updates so far, t echoed when given; with a contact watch, `contact` =
    (τ_ext [N m], alarm))."""
    record: dict = {"n": n}
    if "t" in sample:
        record["t"] = sample["t"]
    record.update(
        tau=p.tau.tolist(),
        lower=p.lower.tolist(),
        upper=p.upper.tolist(),
        std=p.std.tolist(),
        parametric=p.parametric.tolist(),
        extrapolating=bool(p.extrapolating),
    )
    if contact is not None:
        record.update(tau_ext=contact[0].tolist(), alarm=bool(contact[1]))
    return record


@dataclass
class Counts:
    """What the stream did, for the final line."""

    lines: int = 0  # input lines read
    samples: int = 0  # complete samples (angles and derivatives) predicted
    updates: int = 0  # samples with a torque folded into θ
    predictions: int = 0  # samples without a torque: predicted only
    outliers: int = 0  # samples whose torque failed the residual test: predicted, not learnt from
    contact: int = 0  # samples with a torque during a contact alarm or its settling: predicted, not learnt from
    alarms: int = 0  # contact alarms raised
    extrapolating: int = 0  # samples outside the GMR residual's training region
    skipped: dict[str, int] = field(default_factory=dict)  # lines not used, by kind (`BadLine.kind`)

    def skip(self, kind: str) -> None:
        self.skipped[kind] = self.skipped.get(kind, 0) + 1


def currents_to_torques(robot) -> tuple[tuple[float, ...] | None, str]:
    """(joint-side torque per ampere [N m/A] per joint, or None when a joint lacks its torque constant or gear ratio;
    and then why, naming the joints' tables), the batch loader's rule and message."""
    try:
        return tuple(float(k) for k in current_to_torque(robot, "stream")), ""
    except InputError as exc:
        return None, str(exc).removeprefix("stream: the file logs motor currents, but ")


@dataclass
class StreamOptions:
    """How `serve` reads and guards: the column `mapping`, `current_to_torque` [N m/A per joint] (None: currents
    are refused, `currents_refused` says why), `cutoff_hz` of the causal derivative filter (used when dq/ddq are
    not given), `outlier_k` (0: no residual test), `snapshot_every` updates, the contact `watch` (None: none)."""

    mapping: Mapping = field(default_factory=Mapping)
    current_to_torque: tuple[float, ...] | None = None
    currents_refused: str = ""
    cutoff_hz: float = 15.0
    outlier_k: float = OUTLIER_K
    snapshot_every: int = 1000
    watch: ContactWatch | None = None
    #: With a watch: samples a sample waits before it is learnt (0: at once; `Thresholds.learning_lag` is long
    #: enough that a push's onset, before its alarm, is never learnt, at the price of θ lagging the stream).
    learning_lag: int = 0

    @classmethod
    def for_problem(cls, problem, train: Dataset, outlier_k: float = OUTLIER_K) -> StreamOptions:
        """How a stream of `problem`'s data is read: its `[data]` columns and the robot's angle convention, its
        drives' currents, and the causal filter's cut-off, decided here once: the training trial's own (the one its
        derivatives were estimated at), or for logged derivatives the problem's setting (a number, or "auto": read
        from the training trial's angles, `derivatives.resolve_cutoff`)."""
        cutoff = train.cutoff_hz or resolve_cutoff(problem.data.derivative_cutoff_hz, train.t, train.q)[0]
        scale, refused = currents_to_torques(problem.robot)
        return cls(Mapping.from_spec(problem.data, problem.robot), scale, refused, float(cutoff), outlier_k)


class _Stop(Exception):
    """SIGTERM or SIGINT while waiting for input."""


class Service:
    """One stream's state: parser, causal derivatives, robust residual scale, counts."""

    def __init__(self, identifier: OnlineIdentifier, names: tuple[str, ...], options: StreamOptions):
        self.ident, self.names, self.options = identifier, names, options
        self.parser = LineParser(
            current_to_torque=options.current_to_torque,
            mapping=options.mapping,
            currents_refused=options.currents_refused,
        )
        self.derivatives = CausalDerivatives(options.cutoff_hz)
        self.counts = Counts()
        self.scale2: np.ndarray | None = None  # robust residual variance per joint [N² m²]
        self.errors: list[dict] = []  # error records about earlier lines (times found stray later), to report
        #: (design row, τ) of samples that passed every test, learnt `StreamOptions.learning_lag` samples later
        self.pending: deque[tuple[np.ndarray, np.ndarray]] = deque()

    def line(self, raw: str | bytes, lineno: int) -> list[dict]:
        """The output records for one input line; raises BadLine or InputError."""
        if isinstance(raw, bytes):
            try:
                raw = raw.decode("utf-8")
            except UnicodeDecodeError:
                raise BadLine("not valid UTF-8", "encoding") from None
        sample = self.parser.parse(raw)
        if sample is None:
            return []
        self.counts.samples += 1
        names = self.parser.mapping.names
        if names["dq"][0] not in sample or names["ddq"][0] not in sample:
            if "t" not in sample:
                raise BadLine("t is needed to estimate dq and ddq (the sample gives neither both)")
            sample[LINE] = lineno
            try:
                sample = self.derivatives.push(sample)
            except NonIncreasingTime as exc:
                raise BadLine(str(exc), "time") from None
            except RateError as exc:
                raise InputError(f"stream: {exc}") from None
            finally:
                self._stray_times()
            if sample is None:
                return []
            for name in (*names["dq"], *names["ddq"]):
                kind = name.rstrip("0123456789")
                if not abs(sample[name]) <= PLAUSIBLE[kind]:
                    raise BadLine(f"estimated {name} = {sample[name]:.6g} is implausible", "implausible")
        return self.step(sample)

    def _stray_times(self) -> None:
        """Samples the causal derivatives left out after seeing later ones (a time that jumps ahead): their errors."""
        for sample, why in self.derivatives.rejected:
            self.counts.skip("time")
            self.errors.append({"error": why, "kind": "time", "line": sample.get(LINE)})
        self.derivatives.rejected.clear()

    def step(self, sample: dict[str, float]) -> list[dict]:
        """Predict one complete sample and, when it has a torque that passes the residual test, fold it in."""
        names = self.parser.mapping.names
        q, dq, ddq = (np.array([sample[n] for n in names[s]]) for s in ("q", "dq", "ddq"))
        p, D = self.ident.step(q, dq, ddq)
        if not (np.isfinite(p.tau).all() and np.isfinite(p.std).all()):
            raise BadLine("the prediction is not finite for this sample", "numeric")
        self.counts.extrapolating += bool(p.extrapolating)
        out = []
        watch = self.options.watch
        contact = None if watch is None else (watch.tau_ext.copy(), watch.alarm)
        if names["tau"][0] in sample:
            tau = np.array([sample[n] for n in names["tau"]])
            if watch is not None:
                contact = self._watch(watch, sample.get("t"), q, dq, tau)
                if watch.quiet:  # a push, or the settling after one: nothing is learnt from it
                    return [prediction_record(self.ident.n_updates, sample, p, contact)]
            if self._outlier(tau - p.parametric):
                self.counts.outliers += 1
                record = prediction_record(self.ident.n_updates, sample, p, contact)
                record["outlier"] = True
                return [record]
            self.pending.append((D, tau))
            folded = len(self.pending) > (0 if watch is None else self.options.learning_lag)
            if folded:
                self._fold(*self.pending.popleft())
            out.append(prediction_record(self.ident.n_updates, sample, p, contact))
            every = self.options.snapshot_every
            if folded and every and self.ident.n_updates % every == 0:
                out.append({"snapshot": self.parameters()})
        else:
            self.counts.predictions += 1
            out.append(prediction_record(self.ident.n_updates, sample, p, contact))
        return out

    def _watch(self, watch: ContactWatch, t: float | None, q, dq, tau) -> tuple[np.ndarray, bool]:
        """The contact watch's step: (τ_ext, alarm). An alarm also drops the samples still waiting to be learnt
        (`StreamOptions.learning_lag`): a push's onset, before the alarm, is not learnt either."""
        raised = not watch.alarm
        contact = watch.step(t, q, dq, tau)
        self.counts.alarms += bool(raised and contact[1])
        if watch.quiet:
            self.counts.contact += 1 + len(self.pending)
            self.pending.clear()
        return contact

    def _fold(self, D: np.ndarray, tau: np.ndarray) -> None:
        """Fold one sample into θ (and the GMR residual)."""
        try:
            self.ident.add(D, tau)
        except (FloatingPointError, RuntimeError, np.linalg.LinAlgError, ValueError) as exc:
            raise BadLine(f"update failed, sample not used ({type(exc).__name__}: {exc})", "numeric") from None
        self.counts.updates += 1

    def flush(self) -> None:
        """At the end of the stream: the samples still waiting (no alarm came) are learnt."""
        while self.pending:
            self._fold(*self.pending.popleft())

    def _outlier(self, r: np.ndarray) -> bool:
        """Robust residual test on the parametric model's one-step residual r = τ − Dθ [N m]: |r_j| > k·s_j for a
        joint j, with s² a winsorised running mean square of past residuals (each clipped at (k s)², so one
        spike barely moves it and a lasting change is accepted after a few samples), started at the offline
        fit's residual mean square. The GMR is left out: where it extrapolates, its error is not the sample's."""
        k = self.options.outlier_k
        if not k:
            return False
        if self.scale2 is None:
            self.scale2 = np.maximum(self.ident.parametric_var.copy(), 1e-12)
        r2 = r * r
        outlier = bool(np.any(r2 > k * k * self.scale2))
        self.scale2 += (np.minimum(r2, k * k * self.scale2) - self.scale2) / OUTLIER_MEMORY
        return outlier

    def parameters(self) -> dict:
        """{"n", "parameters"} of the current θ."""
        return {"n": self.ident.n_updates, "parameters": dict(zip(self.names, map(float, self.ident.theta)))}

    def final(self) -> dict:
        """The final record."""
        c = self.counts
        estimated = self.derivatives.dt is not None
        return {
            "final": {
                **self.parameters(),
                "lines": c.lines,
                "samples": c.samples,
                "updates": c.updates,
                "predictions": c.predictions,
                "outliers": c.outliers,
                **({"contact": c.contact, "alarms": c.alarms} if self.options.watch is not None else {}),
                "extrapolating": c.extrapolating,
                "skipped": dict(c.skipped),
                "derivatives": {
                    "estimated": estimated,
                    "delay_samples": self.derivatives.delay if estimated else 0,
                    "delay_s": self.derivatives.delay_seconds() if estimated else 0.0,
                    "cutoff_hz": self.derivatives.cutoff_hz if estimated else None,
                    "lost": self.derivatives.lost,
                    "restarts": self.derivatives.restarts,
                },
            }
        }


def serve(
    identifier: OnlineIdentifier,
    names: tuple[str, ...],
    instream: TextIO,
    outstream: TextIO,
    errstream: TextIO,
    snapshot_every: int = 1000,
    on_final: Callable[[dict], None] | None = None,
    current_to_torque: tuple[float, ...] | None = None,
    options: StreamOptions | None = None,
) -> dict:
    """Run the stream until end of input, SIGINT or SIGTERM; returns (and writes) the final record.

    names: the parameter names of `identifier` (for the snapshots); instream: text or binary (bytes are
    decoded as strict UTF-8 per line); on_final: called with the final record (e.g. to write it to a file)
    after it has been printed; current_to_torque: N m / A per joint for samples that give motor currents
    (overrides `options`). A header or mapping error raises `InputError` before any output.
    """
    options = options or StreamOptions()
    options.snapshot_every = snapshot_every
    if current_to_torque is not None:
        options.current_to_torque = current_to_torque
    service = Service(identifier, names, options)
    state = {"reading": False, "stop": False}

    def on_term(signum, frame):
        # SIGTERM/SIGINT: interrupt a blocking read at once; during an update, finish it and stop after it
        # (never half a step: the statistics and θ always describe the same samples).
        state["stop"] = True
        if state["reading"]:
            raise _Stop

    previous = {sig: _install(sig, on_term) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        _loop(service, instream, outstream, errstream, state)
    except (KeyboardInterrupt, _Stop):
        pass
    finally:
        for sig, handler in previous.items():
            _install(sig, signal.SIG_DFL if handler is None else handler)
    try:
        service.flush()
    except BadLine as exc:
        service.counts.skip(exc.kind)
        _emit(errstream, {"error": str(exc), "kind": exc.kind, "line": None})
    final = service.final()
    _emit(outstream, final)
    if on_final is not None:
        on_final(final)
    return final


def _loop(service: Service, instream, outstream: TextIO, errstream: TextIO, state: dict) -> None:
    lineno = 0
    while not state["stop"]:
        state["reading"] = True
        try:
            line = instream.readline()
        except UnicodeDecodeError:  # a text stream with strict decoding: report and go on
            line = b"\xff"
        finally:
            state["reading"] = False
        if not line:
            break
        lineno += 1
        service.counts.lines += 1
        try:
            records = service.line(line, lineno)
        except InputError:
            raise
        except BadLine as exc:
            service.counts.skip(exc.kind)
            records, errors = [], [{"error": str(exc), "kind": exc.kind, "line": lineno}]
        except Exception as exc:  # the stream never dies on input: report, skip, go on
            service.counts.skip("internal")
            records, errors = [], [{"error": f"{type(exc).__name__}: {exc}", "kind": "internal", "line": lineno}]
        else:
            errors = []
        for error in [*service.errors, *errors]:
            _emit(errstream, error)
        service.errors.clear()
        for record in records:
            _emit(outstream, record)


def _emit(stream: TextIO, record: dict) -> None:
    """One strict-JSON line (no NaN or Infinity: a non-finite value becomes null), flushed."""
    try:
        text = json.dumps(record, allow_nan=False)
    except ValueError:
        text = json.dumps(_finite(record), allow_nan=False)
    stream.write(text + "\n")
    stream.flush()


def _finite(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _install(signum, handler):
    """signal.signal where allowed (only the main thread may); returns the previous handler."""
    try:
        return signal.signal(signum, handler)
    except (ValueError, TypeError):  # not the main thread, or no previous Python-level handler
        return None
