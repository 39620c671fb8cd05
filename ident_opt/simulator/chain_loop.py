"""The closed loop of an arm with n joints: a digital controller (zero-order hold) on the true plant
(`chain_plant`), integrated with RK4, the way `closed_loop` does it for the planar arm.

Controller, knowing only the datasheet: the nominal model's inverse dynamics at the reference plus a PD on the
encoder (motor-side) angle whose gains are the nominal mass matrix at the reference,
    τ = τ̂(q_r, dq_r, ddq_r; π_datasheet) + M̂(q_r) [ω_c² (q_r − q_enc) + 2 ω_c (dq_r − dq_enc)],
critically damped at `closed_loop.BANDWIDTH_HZ` on every joint whatever the coupling (a diagonal PD tuned on the
diagonal of M drove the Panda's light, strongly coupled wrist unstable at 1 kHz). The torque is constant over each
tick (1 ms at 1 kHz); RK4 takes `substeps` sub-steps per tick, sized from the fastest rate of the loop (the PD
against the true inertia, eig(M(q)⁻¹ M̂(q)) ω_c² and 2 ω_c, over poses spread across the ranges; an elastic
mode's), |λ| h ≤ 0.25. The effects' friction is stiff only near a reversal: a tick takes the fine steps sized for
it only there (`tick`), the coarse ones elsewhere, and matches the fine integration everywhere to a few
hundredths of the torque noise (tests/test_simulate_arm.py).

Speed: one tick is one CasADi function of (x, ref, p, band), its RK4 step looped (`rk4`), not unrolled;
`mapaccum` runs `closed_loop.CHUNK` ticks per call. For a long trial it is generated as C, compiled once per
machine and arm structure (`cbuild.cached_function`, in the user's code cache; seconds of gcc) and loaded back: a
7-joint arm's 60 s at 1 kHz then takes about a second clean, 4–10 s with every effect (benchmarks/bench_simulate.py).
Short trials, or a machine without a C compiler, run CasADi's own virtual machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident_opt.cbuild import cached_function
from ident_opt.errors import InputError
from ident_opt.simulator.chain_dynamics import initial_state, plant_function, state_size
from ident_opt.simulator.chain_plant import ArmPlant, centre, mass_matrix
from ident_opt.simulator.closed_loop import BANDWIDTH_HZ, CHUNK, MAX_SUBSTEPS, Gains
from ident_opt.simulator.integrate import march, rk4_step
from ident_opt.simulator.trajectories import Box, Reference

#: Ticks from which the loop is compiled to C (when it is not compiled yet): below, building costs more than it saves.
COMPILE_TICKS = 20000


@dataclass
class Steps:
    """RK4 sub-steps per tick: `coarse` away from the friction's reversals, `fine` near one (equal without a
    friction effect); `fine_share` the share of a run's ticks that took the fine ones."""

    coarse: int
    fine: int
    fine_share: float = 0.0


def gains(plant: ArmPlant, box: Box, bandwidth_hz: float = BANDWIDTH_HZ) -> Gains:
    """The PD's gains at the centre pose [N m/rad, N m s/rad]: M̂ ω_c² and 2 M̂ ω_c, as the diagonal of M̂ (what
    the truth file reports; the loop multiplies the whole M̂(q_r) at each tick, `controller`)."""
    J = np.diag(mass_matrix(plant.arm, plant.nominal, centre(box)[None, :])[0])
    w = 2 * math.pi * bandwidth_hz
    return Gains(tuple(J * w**2), tuple(2 * J * w))


def controller(plant: ArmPlant, bandwidth_hz: float) -> ca.Function:
    """(ref = [q_r, dq_r, ddq_r], q_enc, dq_enc) -> τ [N m]: the nominal feedforward plus the PD
    M̂(q_r) [ω² e + 2ω ė]."""
    n = plant.n
    ref, q, dq = ca.SX.sym("ref", 3 * n), ca.SX.sym("q", n), ca.SX.sym("dq", n)
    a = ca.SX.sym("a", n)
    nominal = plant.arm.tau_expression(ref[:n], ref[n : 2 * n], a, ca.DM(plant.nominal))
    M = ca.jacobian(nominal, a)
    ff = ca.substitute(nominal, a, ref[2 * n :])
    w = 2 * math.pi * bandwidth_hz
    tau = ff + M @ (w**2 * (ref[:n] - q) + 2 * w * (ref[n : 2 * n] - dq))
    return ca.Function("controller", [ref, q, dq], [tau])


def substeps(plant: ArmPlant, bandwidth_hz: float, box: Box, control: float) -> Steps:
    """RK4 sub-steps per tick of a `control` [Hz] loop, coarse and fine: the fastest closed-loop rate |λ| (the PD
    against the true inertia, √λ ω_c + 2 λ ω_c with λ the largest eigenvalue of M(q)⁻¹ M̂(q) over poses spread
    across the ranges; an elastic mode's, `ElasticJoint`) times the step h ≤ 0.25, and for the fine steps the
    effects' friction at a reversal too (`ArmPlant.friction_rate`). An `InputError` naming the cause when more than
    `MAX_SUBSTEPS` would be needed."""
    poses = np.vstack([centre(box), np.random.default_rng(2).uniform(box.q_min, box.q_max, (16, plant.n))])
    M = mass_matrix(plant.arm, plant.pi, poses) + np.diag(plant.inertia)
    M_hat = mass_matrix(plant.arm, plant.nominal, poses)
    w = 2 * math.pi * bandwidth_hz
    rates = []
    for Mk, Hk in zip(M, M_hat):
        lam = float(np.max(np.abs(np.linalg.eigvals(np.linalg.solve(Mk, Hk)))))
        rates.append(math.sqrt(lam) * w + 2 * lam * w)
    e = plant.elastic
    if e is not None:
        M0 = mass_matrix(plant.arm, plant.nominal, centre(box)[None, :])[0]
        rates.append(e.fastest_rate + 2 * w * M0[e.index, e.index] / e.B)

    def needed(rate: float) -> int:
        k = math.ceil(rate / control / 0.25)
        if not np.isfinite(k) or k > MAX_SUBSTEPS:
            why = (
                f"the elastic joint's mode at {e.frequency_hz:g} Hz"
                if e is not None and e.fastest_rate >= 0.5 * rate
                else "the controller against the arm's smallest inertia"
            )
            raise InputError(
                f"the simulation is too stiff to integrate: {why} needs {k:g} RK4 steps per {1e3 / control:g} ms "
                f"tick (at most {MAX_SUBSTEPS}); use a lower frequency or a faster control rate"
            )
        return max(2, k)

    return Steps(needed(max(rates)), needed(max(*rates, plant.friction_rate)))


def rk4(plant: ArmPlant, steps: int, control: float) -> ca.Function:
    """(x, τ, p) -> x one `control` [Hz] tick later: `steps` RK4 steps of the plant under the held torque τ, as
    one step looped (`fold`), so the generated C holds the plant once, not once per step."""
    f = plant_function(plant)
    x, tau, p = ca.SX.sym("x", f.size1_in(0)), ca.SX.sym("tau", f.size1_in(1)), ca.SX.sym("p", f.size1_in(2))
    h = 1.0 / control / steps
    one = ca.Function("rk4_step", [x, tau, p], [rk4_step(lambda z: f(z, tau, p)[0], x, h)])
    X, T, P = (ca.MX.sym(name, v.sparsity()) for name, v in zip(("x", "tau", "p"), (x, tau, p)))
    return ca.Function(f"rk4_{steps}", [X, T, P], [one.fold(steps)(X, T, P)], ["x", "tau", "p"], ["x_next"])


def tick(
    plant: ArmPlant, bandwidth_hz: float, box: Box, control: float, disturbed: bool = False
) -> tuple[ca.Function, Steps]:
    """One tick of a `control` [Hz] loop: (x, ref, p, band) -> (x_next, out), out = [τ (n), y (3n + 1), fine] at
    its start, and its sub-steps. `disturbed`: ref = [q_r, dq_r, ddq_r, d] carries an external torque d [N m] over
    the tick (a contact, `effects.background.contact`), applied with the drive's τ (the logged τ is the drive's).

    The effects' friction is stiff only near a reversal (its sign is regularised over ε ≪ the cruise speed,
    `ArmPlant.regularisation`), so a tick takes the fine steps (sized for it) only when some joint's rate dq is
    inside its `band` (`ArmPlant.stiff_band` at the coarse steps' rate) or could reach it within the tick, and
    when some joint's rate could change sign within it (|dq| < 2 |ddq| Δt: the arm's own Coulomb friction is a
    sharp sign, whose crossing a coarse step smears); the coarse steps (sized for the rest of the loop) otherwise.
    `fine` = 1 marks the first. Without an effect's friction every tick takes the same steps."""
    n = plant.n
    f = plant_function(plant)
    ctrl = controller(plant, bandwidth_hz)
    steps = substeps(plant, bandwidth_hz, box, control)
    x, ref = ca.MX.sym("x", state_size(plant)), ca.MX.sym("ref", (4 if disturbed else 3) * n)
    p, band = ca.MX.sym("p", f.size1_in(2)), ca.MX.sym("band", n)
    d = ref[3 * n :] if disturbed else ca.DM.zeros(n)
    _, y = f(x, d, p)
    tau = ctrl(ref[: 3 * n] if disturbed else ref, y[:n], y[n : 2 * n])
    applied = tau + d if disturbed else tau
    _, y = f(x, applied, p)  # y's accelerations are those the dynamics produce under the applied torque
    if steps.fine == steps.coarse:
        fine = ca.MX(0)
        x_next = rk4(plant, steps.fine, control)(x, applied, p)
    else:
        speed, change = ca.fabs(y[n : 2 * n]), 2.0 / control * ca.fabs(y[2 * n : 3 * n])
        fine = ca.logic_or(ca.mmax(ca.logic_and(band > 0, speed < band + change)), ca.mmax(speed < change))
        switch = ca.Function.conditional(
            "substeps", [rk4(plant, steps.coarse, control)], rk4(plant, steps.fine, control)
        )
        x_next = switch(fine, x, applied, p)
    out = ca.vertcat(tau, y, fine)
    return ca.Function(
        "arm_tick", [x, ref, p, band], [x_next, out], ["x", "ref", "p", "band"], ["x_next", "out"]
    ), steps


def chunked(step: ca.Function, plant: ArmPlant, ticks: int) -> ca.Function:
    """`step` accumulated over `CHUNK` ticks, compiled to C when the trial is long or it is compiled already
    (cached per machine, `cbuild.cached_function`); CasADi's virtual machine otherwise, or without a compiler."""
    accumulated = step.mapaccum(CHUNK)
    try:
        compiled = cached_function(accumulated, "simulate", build=ticks >= COMPILE_TICKS)
    except (InputError, OSError):
        compiled = None
    return accumulated if compiled is None else compiled


def follow(
    plant: ArmPlant,
    ref: Reference,
    box: Box,
    control: float,
    bandwidth_hz: float,
    progress: bool,
    disturbance: np.ndarray | None = None,
) -> tuple[np.ndarray, Gains, Steps]:
    """The loop along `ref` (sampled at the control rate `control` [Hz]): (out (N, 4n + 1): τ, q_enc, dq_enc, ddq_enc,
    deflection at each tick; the gains; the RK4 sub-steps per tick and the share of ticks that took the fine ones);
    an InputError when it diverges. `disturbance` (N, n) [N m]: an external torque at each tick (None: none)."""
    g = gains(plant, box, bandwidth_hz)
    step, steps = tick(plant, bandwidth_hz, box, control, disturbed=disturbance is not None)
    p = ca.DM(plant.parameters())
    band = ca.DM(plant.stiff_band(0.25 * control * steps.coarse))
    x = ca.DM(initial_state(plant, ref.q[0]))
    columns = [ref.q, ref.dq, ref.ddq] + ([] if disturbance is None else [disturbance])
    refs = np.hstack(columns).T
    out = march(chunked(step, plant, refs.shape[1]), x, refs, (p, band), CHUNK, progress)
    if not np.all(np.isfinite(out)):
        raise InputError(
            "the simulation diverged (non-finite angles or torques): the hidden effects "
            f"({', '.join(plant.effects) or 'none'}) or the trajectory are beyond what the arm can follow"
        )
    steps.fine_share = float(out[-1].mean()) if out.size else 0.0
    return out[:-1].T, g, steps
