"""`observer_step` as one CasADi Function, for the generated C (`ident-opt codegen`): the momentum observer
(`contact.observer`) and its alarm (`contact.alarm`) one sample at a time, π and the thresholds baked in.

    observer_step(q, dq, tau, state) -> (tau_ext, state_next, alarm)

q, dq, τ (n) [rad, rad/s, N m]; τ_ext (n) [N m]; alarm 0/1; the state (`state_size(n)` = 4n + 5 doubles, all zero
before the first sample) is laid out as `STATE_LAYOUT` says: the previous sample's momentum p and u = τ − β, the
residual r = τ_ext, each joint's peak in the last alarm, then started, count, below, alarm, hold [s]. The sample step
Δt is the calibration's (`Thresholds.dt`): the samples must come at that rate. Each line mirrors the Python
(`MomentumObserver`, `Detector.step`), which the codegen check compares it with (to 1e-9).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import casadi as ca
import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.contact.dynamics import Momentum, momentum_expressions
from ident_opt.contact.thresholds import Thresholds
from ident_opt.contact.watch import ContactWatch, watch_with

#: The state's blocks, in order: (name, size in joints or 1, meaning).
STATE_LAYOUT = (
    ("p", "n", "the previous sample's momentum M(q) dq [N m s]"),
    ("u", "n", "the previous sample's τ − β [N m]"),
    ("tau_ext", "n", "the residual r, the estimate of τ_ext [N m]"),
    ("peak", "n", "each joint's τ_ext of largest size while it exceeded in the last alarm [N m] (0: it did not)"),
    ("started", "1", "0 before the first sample, then 1"),
    ("count", "1", "excesses in a row while not in alarm"),
    ("below", "1", "samples in a row without an excess while in alarm"),
    ("alarm", "1", "1 while in alarm"),
    ("hold", "1", "settling left after a release [s]"),
)


def state_size(n: int) -> int:
    """Doubles in the observer's state for an arm of n joints (`STATE_LAYOUT`)."""
    return 4 * n + 5


def _alarm_step(r: ca.SX, dq: ca.SX, z: ca.SX, th: Thresholds) -> tuple[ca.SX, ca.SX]:
    """(the detector's new state [peak (n), count, below, alarm, hold], the excess mask) from the old one `z` (same
    layout) at τ_ext r and dq: `contact.alarm.Detector.step`, as expressions."""
    n = th.n
    peak, count, below, alarm, hold = z[:n], z[n], z[n + 1], z[n + 2], z[n + 3]
    limit = ca.if_else(ca.fabs(dq) <= ca.DM(th.rest_speed), ca.DM(th.resting), ca.DM(th.moving))
    over = ca.fabs(r) > limit
    same = ca.sign(r) == ca.sign(peak)
    allowed = ca.logic_or(ca.logic_or(peak == 0, same), ca.fabs(r) > ca.fabs(peak))
    over = ca.logic_and(over, ca.logic_or(hold <= 0, allowed))
    any_over = ca.mmax(over)
    persistence = float(th.persistence)
    # in alarm: the peaks grow, a run without excess of `persistence` samples releases it into the settling
    peak_in = ca.if_else(ca.logic_and(over, ca.fabs(r) > ca.fabs(peak)), r, peak)
    below_in = ca.if_else(any_over, 0.0, below + 1.0)
    release = below_in >= persistence
    in_alarm = ca.vertcat(
        peak_in,
        count,
        ca.if_else(release, 0.0, below_in),
        ca.if_else(release, 0.0, 1.0),
        ca.if_else(release, th.settling, hold),
    )
    # quiet: the settling runs down, `persistence` excesses in a row raise the alarm
    count_q = ca.if_else(any_over, count + 1.0, 0.0)
    rise = count_q >= persistence
    quiet = ca.vertcat(
        ca.if_else(rise, ca.if_else(over, r, 0.0), peak),
        ca.if_else(rise, 0.0, count_q),
        ca.if_else(rise, 0.0, below),
        ca.if_else(rise, 1.0, 0.0),
        ca.fmax(0.0, hold - th.dt),
    )
    return ca.if_else(alarm > 0.5, in_alarm, quiet), over


def observer_step_function(arm: Arm, pi: np.ndarray, thresholds: Thresholds) -> ca.Function:
    """`observer_step` of `arm` at parameters π (P,) with `thresholds` baked in (module doc)."""
    n, dt = arm.n_joints, thresholds.dt
    q, dq, tau, state = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("tau", n), ca.SX.sym("state", state_size(n))
    p, beta = momentum_expressions(arm, q, dq, ca.DM(np.asarray(pi, dtype=float)))
    u = tau - beta
    p_prev, u_prev, r_prev = state[:n], state[n : 2 * n], state[2 * n : 3 * n]
    started = state[4 * n]
    gamma = ca.DM([1.0 - math.exp(-k * dt) for k in thresholds.gain])
    m = (p - p_prev - 0.5 * dt * (u_prev + u)) / dt  # the torque that moved the momentum beyond τ − β
    r = ca.if_else(started > 0.5, r_prev + gamma * (m - r_prev), ca.DM.zeros(n))
    detector, _ = _alarm_step(r, dq, ca.vertcat(state[3 * n : 4 * n], state[4 * n + 1 :]), thresholds)
    peak, rest = detector[:n], detector[n:]
    state_next = ca.vertcat(p, u, r, peak, 1.0, rest)
    return ca.Function(
        "observer_step",
        [q, dq, tau, state],
        [r, state_next, rest[2]],
        ["q", "dq", "tau", "state"],
        ["tau_ext", "state_next", "alarm"],
    )


def run_compiled(step: ca.Function, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(τ_ext (N, n), alarm (N,)) of a (compiled or symbolic) `observer_step` over N samples from a zero state."""
    n = q.shape[1]
    state = np.zeros(state_size(n))
    r, alarm = np.zeros_like(q), np.zeros(len(q), dtype=bool)
    for k in range(len(q)):
        out, state, a = step(q[k], dq[k], tau[k], state)
        r[k], state, alarm[k] = np.asarray(out).ravel(), np.asarray(state).ravel(), float(a) > 0.5
    return r, alarm


def check(step: ca.Function, watch_factory, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> dict:
    """The compiled `step` against the Python watch (`watch_factory()`, a fresh `ContactWatch`, stepped without
    times: at the calibration's Δt) over the samples: the largest difference of τ_ext relative to the largest
    |τ_ext| (at least 1 N m), and the samples whose alarm differs."""
    r_c, alarm_c = run_compiled(step, q, dq, tau)
    watch = watch_factory()
    r_py, alarm_py = np.zeros_like(r_c), np.zeros(len(q), dtype=bool)
    for k in range(len(q)):
        r_py[k], alarm_py[k] = watch.step(None, q[k], dq[k], tau[k])
    scale = max(1.0, float(np.abs(r_py).max()))
    return {
        "samples": len(q),
        "max_relative_difference": float(np.abs(r_c - r_py).max() / scale),
        "alarm_mismatches": int((alarm_c != alarm_py).sum()),
        "alarm_samples": int(alarm_py.sum()),
    }


def for_codegen(model: Arm, pi: np.ndarray, trials) -> tuple[ca.Function, Callable[[], ContactWatch], dict]:
    """What `ident-opt codegen` ships of the observer for `model` at π on the training `trials` (collision-free:
    the identification's own): `observer_step` with thresholds calibrated on them, the Python watch it is checked
    against, and its entry of parameters.json (the thresholds, the state's layout)."""
    momentum = Momentum(model, np.asarray(pi, dtype=float))
    watch = watch_with(momentum, trials)
    th = watch.thresholds
    n = model.n_joints
    entry = {
        "function": "observer_step",
        "inputs": ["q", "dq", "tau", "state"],
        "outputs": ["tau_ext", "state_next", "alarm"],
        "state_size": state_size(n),
        "state_layout": [
            {"name": name, "size": n if size == "n" else 1, "meaning": meaning} for name, size, meaning in STATE_LAYOUT
        ],
        "dt": th.dt,
        "thresholds": th.as_json(),
        "persistence": th.persistence,
        "settling_s": th.settling,
        "margin": th.margin,
    }
    return observer_step_function(model, pi, th), lambda: ContactWatch(momentum, th), entry
