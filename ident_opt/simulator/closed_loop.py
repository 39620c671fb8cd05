"""The closed loop: a digital controller (zero-order hold) on the truth plant, integrated with RK4.

The controller runs at `CONTROL_HZ` = 1 kHz, or at the logging rate when that is faster (`control_hz`), so
that a 2 kHz log is a genuine 2 kHz trial rather than an interpolated 1 kHz one. The gains are the same at
every rate (they are set from the bandwidth, not from the tick), and trials logged at ≤ 1 kHz are unchanged.

Controller (what a real drive does, knowing only the datasheet): inverse-dynamics feedforward of the
nominal model at the reference plus a PD on the encoder angle,
    τ = M̂(q_r) ddq_r + Ĉ(q_r, dq_r) dq_r + Ĝ(q_r) + F̂(dq_r) + Kp (q_r − q_enc) + Kd (dq_r − dq_enc),
with Kp = J ω_c², Kd = 2 J ω_c (critically damped at `BANDWIDTH_HZ` on the nominal diagonal inertia J).
The PD acts on the motor-side angle, so it stays collocated (and passive) with an elastic joint.

Integration: the torque is constant over each tick (1 ms at 1 kHz); the plant is integrated with classical RK4 over
`substeps` sub-steps sized from the fastest mode of the loop (|λ| h ≤ 0.25, well inside RK4's stability
limit of 2.8), so stiff springs and high gains stay stable and accurate. The step is one CasADi function,
run tick after tick by `mapaccum` in chunks (fast: no Python per step).

Background terms (background.py) enter here: their currents are added to the commanded torque (the actual
motor current, held over the tick and logged), their external torques are an extra input per tick, and their
states extend the plant's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi
from ident_opt.errors import InputError
from ident_opt.simulator import background
from ident_opt.simulator.integrate import rk4_step
from ident_opt.simulator.planar_dynamics import TRUTH_MODEL
from ident_opt.simulator.truth import Truth, plant, state_size

CONTROL_HZ = 1000.0  # the controller's rate [Hz] for logging rates up to it
MAX_CONTROL_HZ = 5000.0  # fastest loop [Hz]: memory grows with the tick count (9 floats per tick)
BANDWIDTH_HZ = 6.0  # closed-loop bandwidth of the PD [Hz]
CHUNK = 2000  # ticks per mapaccum call (progress granularity)
#: Most RK4 sub-steps per control tick: beyond it a trial would take the simulator minutes per second (a mode of
#: hundreds of Hz); such a trial is refused, naming why.
MAX_SUBSTEPS = 64
#: Stated tracking limits [rad], max |encoder angle − reference| over a trial: the exact feedforward keeps the
#: clean trial well inside the first; hidden effects are unknown to the controller, only the PD corrects them.
MAX_TRACKING_ERROR = {"clean": 1e-3, "effects": 0.05}


@dataclass(frozen=True)
class Gains:
    """Diagonal PD gains: Kp [N m/rad], Kd [N m s/rad]."""

    kp: tuple[float, float]
    kd: tuple[float, float]


def gains(robot: PlanarRobot, bandwidth_hz: float = BANDWIDTH_HZ) -> Gains:
    """Critically damped PD gains on the nominal (datasheet) diagonal inertia at q2 = 0 [kg m²]."""
    p = datasheet_pi(robot, "physical")
    J = np.array([p["a1"] + 2 * p["a2"], p["a3"] + p["ia2"]])
    w = 2 * math.pi * bandwidth_hz
    return Gains(tuple(J * w**2), tuple(2 * J * w))


def controller(robot: PlanarRobot, g: Gains) -> ca.Function:
    """(ref = [q_r, dq_r, ddq_r], q_enc, dq_enc) -> τ [N m], the nominal feedforward plus PD."""
    ref, q, dq = ca.SX.sym("ref", 6), ca.SX.sym("q", 2), ca.SX.sym("dq", 2)
    pi_nominal = ca.DM(TRUTH_MODEL.vector(datasheet_pi(robot, "physical")))
    ff = TRUTH_MODEL.tau_expression(ref[:2], ref[2:4], ref[4:], pi_nominal)
    tau = ff + ca.DM(g.kp) * (ref[:2] - q) + ca.DM(g.kd) * (ref[2:4] - dq)
    return ca.Function("controller", [ref, q, dq], [tau])


def control_hz(rate_hz: float) -> float:
    """The controller's rate [Hz] for a logging rate [Hz]: 1 kHz, or the logging rate when it is faster."""
    return max(CONTROL_HZ, float(rate_hz))


def substeps(truth: Truth, g: Gains, robot: PlanarRobot, control: float = CONTROL_HZ) -> int:
    """RK4 sub-steps per tick of a `control` [Hz] loop so that the fastest closed-loop rate |λ| satisfies
    |λ| h ≤ 0.25."""
    p = datasheet_pi(robot, "physical")
    J = np.array([p["a1"] + 2 * p["a2"], p["a3"] + p["ia2"]])
    rates = [math.sqrt(max(g.kp[i] / J[i], 0.0)) + g.kd[i] / J[i] for i in range(2)]
    if truth.elastic is not None:
        rates += truth.elastic.rates(g.kd)
    # Joint 1's inertia drops to a1 + 2 a2 cos(1.4) at the trajectories' widest q2; halve for margin.
    rates += background.rates(truth.background, 0.5 * np.array([p["a1"] + 2 * p["a2"] * math.cos(1.4), J[1]]))
    needed = math.ceil(max(rates) / control / 0.25)
    if not math.isfinite(needed) or needed > MAX_SUBSTEPS:
        raise InputError(
            f"the simulation is too stiff to integrate: it needs {needed:g} RK4 steps per {1e3 / control:g} ms tick "
            f"(at most {MAX_SUBSTEPS}); an elastic mode that fast is a rigid joint: use a lower frequency_hz"
        )
    return max(2, needed)


def tick(truth: Truth, robot: PlanarRobot, g: Gains, control: float = CONTROL_HZ) -> ca.Function:
    """One tick of a `control` [Hz] loop: (x, ref) -> (x_next, out) with out = [τ (2), y (7)] at its start.

    ref = [q_r, dq_r, ddq_r, d]: the reference and the background's external torque d [N m] over the tick."""
    nx = state_size(truth)
    bg = truth.background
    f = background.with_background(plant(truth), nx, bg)
    ctrl = controller(robot, g)
    x, ref = ca.SX.sym("x", nx + background.n_states(bg)), ca.SX.sym("ref", 8)
    d = ref[6:]
    _, y = f(x, ca.DM.zeros(2), d)
    tau = ctrl(ref[:6], y[:2], y[2:4])
    r = background.current(bg, robot, y[:2], y[2:4])
    if r is not None:
        tau = tau + r  # the actual motor current: commanded plus the background's (e.g. a ripple)
    _, y = f(x, tau, d)  # y's accelerations are those the dynamics produce under the applied torque
    n = substeps(truth, g, robot, control)
    h = 1.0 / control / n
    xk = x
    for _ in range(n):
        xk = rk4_step(lambda z: f(z, tau, d)[0], xk, h)
    return ca.Function("tick", [x, ref], [xk, ca.vertcat(tau, y)], ["x", "ref"], ["x_next", "out"])
