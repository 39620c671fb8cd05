"""Plants the diagnosis was not tuned on: a distributed flexible link, a non-linear elastic joint, other loggers.

The catalogue's own elastic plants (`effects/elasticity.py`) are a two-mass joint with a linear spring and a
link cut once into two rigid halves: one mode each. A real flexible link has distributed mass and several
modes; a real gear's spring hardens, or has a play. These mechanisms replace the rigid arm in
`simulate_trial(..., mechanism=...)` the way the catalogue's do, so that the diagnosis can be tested on them:

- `Beam`: link j as an Euler–Bernoulli beam by the assumed-modes method. Its deflection is
  w(x, t) = Σ_i φ_i(x) δ_i(t) with the clamped–free eigenfunctions φ_i (tip value 1, so δ_i is mode i's tip
  deflection [m]); its mass is spread along it (`POINTS` masses, the bar's), the next joint's actuator (link 1)
  or the payload (link 2) rides at its tip, whose slope w'(L) tilts the next link. Stiffness EI ∫ φ_i''² dx,
  with EI set so that the first mode, joints held at q2 = 0, lies at `frequency_hz`; modal damping ζ on every
  mode (D = M Φ diag(2 ζ ω) Φᵀ M at that pose, Φ mass-normalised). The joints are rigid and logged.
- `NonlinearJoint`: the catalogue's two-mass elastic joint with a non-linear spring k·s(e): `hardening`
  (tangent stiffness k (1 + (e/e_h)²)) or `backlash` (a smooth play, k (e − b tanh(e/b))). e_h and b are given
  relative to e_g, the largest static deflection gravity causes over the workspace (`size`).
- `derived`: a simulated trial as another logger would hand it over: derivatives from a Savitzky–Golay filter
  of another window, or no derivatives at all (the loader estimates them), or currents instead of torques.

Nothing here is a cause of the catalogue: the truth is still `elasticity` (joint, frequency), which is what
the diagnosis must name.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import casadi as ca
import numpy as np
from scipy import signal

from ident_opt.arm.datasheet import bar_inertia, cylinder_inertia
from ident_opt.effects.elasticity import Q2_RANGE
from ident_opt.simulator import planar_dynamics as sim
from ident_opt.simulator.elastic import Elastic

#: Clamped–free beam eigenvalues β_i L of the first modes.
BETA_L = (1.8751040687, 4.6940911330, 7.8547574382, 10.9955407349)
#: Point masses a beam's distributed mass is spread over (midpoints of equal pieces).
POINTS = 16


def _shape(i: int, length: float):
    """φ_i, φ_i' and φ_i'' of the clamped–free beam's mode i as functions of x [m], scaled to φ_i(L) = 1."""
    b = BETA_L[i] / length
    s = (math.cosh(BETA_L[i]) + math.cos(BETA_L[i])) / (math.sinh(BETA_L[i]) + math.sin(BETA_L[i]))

    def raw(x, d):
        cosh, cos, sinh, sin = (
            (np.cosh, np.cos, np.sinh, np.sin)
            if isinstance(x, np.ndarray)
            else (
                math.cosh,
                math.cos,
                math.sinh,
                math.sin,
            )
        )
        bx = b * x
        if d == 0:
            return cosh(bx) - cos(bx) - s * (sinh(bx) - sin(bx))
        if d == 1:
            return b * (sinh(bx) + sin(bx) - s * (cosh(bx) - cos(bx)))
        return b * b * (cosh(bx) + cos(bx) - s * (sinh(bx) + sin(bx)))

    tip = raw(length, 0)
    return tuple(lambda x, d=d: raw(x, d) / tip for d in (0, 1, 2))


def beam_lagrangian(robot, j: int, modes: int, armature, points: int = POINTS):
    """CasADi (z, dz, M(z), h(z, dz), K̂, tip slope) of the arm with link j (0-based) an assumed-modes beam.

    z = [q1, q2, δ_1 … δ_m]; M ddz + h = Q (h: Coriolis, centrifugal and gravity; no spring); the elastic
    energy is ½ EI δᵀ K̂ δ (K̂ = diag ∫ φ_i''² dx, EI set by the caller); `tip slope` w'(L) [rad]. The beam's mass
    is `points` equal pieces, each a point mass at its middle with its own inertia (the rigid bar's exactly)."""
    n = 2 + modes
    z, dz = ca.SX.sym("z", n), ca.SX.sym("dz", n)
    g = robot.gravity
    links = (robot.link1, robot.link2)
    rider = robot.joint2
    tips = (
        [(rider.actuator_mass, cylinder_inertia(rider.actuator_mass, rider.motor_diameter))],
        [(robot.payload_mass, 0.0)] if robot.payload_mass > 0 else [],
    )
    bodies = []  # (mass, inertia, position (2), angle) of every body
    origin, angle, slope_tip = ca.DM.zeros(2), 0, 0
    K = np.zeros(modes)
    for i, link in enumerate(links):
        angle = angle + z[i]
        L = link.length
        R = ca.vertcat(ca.horzcat(ca.cos(angle), -ca.sin(angle)), ca.horzcat(ca.sin(angle), ca.cos(angle)))
        if i == j:
            shapes = [_shape(k, L) for k in range(modes)]

            def w(x, d=0, shapes=shapes):
                return sum(shapes[k][d](x) * z[2 + k] for k in range(modes))

            piece = link.mass / points
            for x in (np.arange(points) + 0.5) * L / points:
                bodies.append((piece, piece * (L / points) ** 2 / 12, origin + R @ ca.vertcat(x, w(x)), angle))
            grid = np.linspace(0.0, L, 801)
            K = np.array([np.trapezoid(shapes[k][2](grid) ** 2, grid) for k in range(modes)])
            end, tilt = origin + R @ ca.vertcat(L, w(L)), w(L, 1)
            slope_tip = tilt
        else:
            bodies.append((link.mass, bar_inertia(link), origin + R @ ca.vertcat(L / 2, 0), angle))
            end, tilt = origin + R @ ca.vertcat(L, 0), 0
        bodies += [(m, inertia, end, angle + tilt) for m, inertia in tips[i]]
        origin, angle = end, angle + tilt
    T = 0.5 * armature[0] * dz[0] ** 2 + 0.5 * armature[1] * dz[1] ** 2
    V = 0
    for m, inertia, p, a in bodies:
        v = ca.jtimes(p, z, dz)
        omega = ca.jtimes(a, z, dz) if isinstance(a, ca.SX) else 0
        T += 0.5 * m * ca.dot(v, v) + 0.5 * inertia * omega**2
        V += m * g * p[1]
    dT = ca.gradient(T, dz)
    M = ca.jacobian(dT, dz)
    h = ca.jacobian(dT, z) @ dz - ca.gradient(T, z) + ca.gradient(V, z)
    return z, dz, M, h, K, slope_tip


@dataclass(frozen=True)
class Beam:
    """Link `index` (0-based) as an assumed-modes beam (see the module docstring). Quacks like `Elastic` for
    the simulator (`state_size`, `plant`, `initial_state`, `rates`, `deflection_column`) and the truth file
    (`k`, `d`, `B`, `J_link`: the first mode's modal stiffness, damper and mass)."""

    index: int
    modes: int
    EI: float  # N m²
    damping: float
    frequency_hz: float  # first mode, joints held at q2 = 0
    mode_frequencies_hz: tuple[float, ...]
    frequency_range_hz: tuple[float, float]  # first mode over q2 in Q2_RANGE
    D: np.ndarray  # modal damping matrix [N s/m]
    k: float
    d: float
    B: float
    J_link: float
    fastest_rate: float
    kind: str = "beam"
    points: int = POINTS

    @property
    def state_size(self) -> int:
        """[q (2), δ (m), dq (2), dδ (m)]."""
        return 2 * (2 + self.modes)

    @property
    def deflection_column(self) -> str:
        """The logged column of the tip slope w'(L) [rad]."""
        return f"deflection{self.index + 1}"

    def rates(self, kd) -> list[float]:
        """The fastest closed-loop rate [1/s] (the stiffest mode with free joints, and the PD on the rotor)."""
        return [self.fastest_rate + kd[self.index] / self.B]

    def _terms(self, truth):
        z, dz, M, h, K, slope = beam_lagrangian(truth.robot, self.index, self.modes, truth.armature, self.points)
        return z, dz, M, h, ca.DM(np.diag(self.EI * K)), slope

    def plant(self, truth) -> ca.Function:
        """(x, τ) -> (ẋ, y) as `simulator.truth.plant`: the joints' encoders and the tip slope."""
        m = self.modes
        x, tau = ca.SX.sym("x", 2 * (2 + m)), ca.SX.sym("tau", 2)
        z, dz, M, h, K, slope = self._terms(truth)
        model, pi = truth.model, truth.pi
        friction_pi = sim.friction_only(model, pi, 0) + sim.friction_only(model, pi, 1)
        F = model.tau_expression(z[:2], dz[:2], ca.DM.zeros(2), ca.DM(friction_pi))
        B = ca.DM(truth.armature)

        def solve(extra):
            return ca.solve(M, ca.vertcat(tau - F - extra, -K @ z[2:] - ca.DM(self.D) @ dz[2:]) - h)

        def load(a):
            return (ca.mtimes(M, a) + h)[:2] - B * a[:2]

        ddz = sim.with_load_friction(truth, dz[:2], solve, load)
        motion = ca.Function("motion", [z, dz, tau], [ddz, slope])
        ddz_x, tip = motion(x[: 2 + m], x[2 + m :], tau)
        xdot = ca.vertcat(x[2 + m :], ddz_x)
        y = ca.vertcat(x[:2] - ca.DM(truth.offset), x[2 + m : 4 + m], ddz_x[:2], tip)
        return ca.Function("plant", [x, tau], [xdot, y], ["x", "tau"], ["xdot", "y"])

    def initial_state(self, truth, q: np.ndarray) -> np.ndarray:
        """At rest with joint angles `q` [rad], the beam at its static deflection under gravity: K δ = −∂V/∂δ."""
        z, dz, _, h, K, _ = self._terms(truth)
        dV = ca.Function("dV", [z], [ca.substitute(h, dz, ca.DM.zeros(dz.shape[0]))[2:]])
        Kinv = np.linalg.inv(np.array(K))
        delta = np.zeros(self.modes)
        for _ in range(30):
            delta = -Kinv @ np.array(dV(np.concatenate([q, delta]))).ravel()
        return np.concatenate([q, delta, np.zeros(2 + self.modes)])


def beam(truth, j: int, f: float, zeta: float, modes: int = 3, points: int = POINTS) -> Beam:
    """Link j (0-based) as an assumed-modes beam whose first mode (joints held, q2 = 0) is at f [Hz], every
    mode damped at ratio ζ, on the true plant `truth` (its robot and rotor inertias); `points`: pieces of its mass."""
    z, _, M, _, K, _ = beam_lagrangian(truth.robot, j, modes, truth.armature, points)
    Mf = ca.Function("M", [z], [M])

    def held(q2: float, EI: float = 1.0):  # modes with the joints held: K v = ω² M_δδ v
        Md = np.array(Mf(np.r_[0.0, q2, np.zeros(modes)]))[2:, 2:]
        w2, V = _generalised_eig(EI * np.diag(K), Md)
        return w2, V, Md

    w2, _, _ = held(0.0)
    EI = (2 * math.pi * f) ** 2 / w2[0]
    w2, V, Md = held(0.0, EI)
    w = np.sqrt(w2)
    D = Md @ V @ np.diag(2 * zeta * w) @ V.T @ Md
    band = [math.sqrt(held(q2, EI)[0][0]) / (2 * math.pi) for q2 in Q2_RANGE]
    fastest = 0.0
    for q2 in (0.0, 0.7, 1.4):  # free joints: the largest rate of M⁻¹ diag(0, 0, K)
        Mi = np.linalg.inv(np.array(Mf(np.r_[0.0, q2, np.zeros(modes)])))
        Kfull = np.zeros_like(Mi)
        Kfull[2:, 2:] = EI * np.diag(K)
        fastest = max(fastest, math.sqrt(max(np.linalg.eigvals(Mi @ Kfull).real)))
    fastest *= 1 + 2 * zeta
    m1 = 1.0  # V mass-normalised: the first mode's modal mass is 1 in its own units
    return Beam(
        j,
        modes,
        EI,
        zeta,
        f,
        tuple(float(v) / (2 * math.pi) for v in w),
        (min(band), max(band)),
        D,
        float(w2[0] * m1),
        float(2 * zeta * w[0] * m1),
        float(truth.armature[j]),
        m1,
        fastest,
        points=points,
    )


def _generalised_eig(K: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ω², V of K v = ω² M v, ascending, V mass-normalised (Vᵀ M V = I)."""
    L = np.linalg.cholesky(M)
    Li = np.linalg.inv(L)
    w2, U = np.linalg.eigh(Li @ K @ Li.T)
    return w2, Li.T @ U


@dataclass(frozen=True)
class NonlinearJoint(Elastic):
    """The catalogue's two-mass elastic joint with a non-linear spring k·s(e) (module docstring): `shape`
    "hardening" (tangent k (1 + (e/a)²)) or "backlash" (k (e − a tanh(e/a))), a [rad]."""

    shape: str = "hardening"
    a: float = 1.0

    def spring(self, e, de):
        """The spring and damper torque [N m] at deflection e [rad] and its rate de [rad/s]."""
        tanh = ca.tanh if isinstance(e, ca.SX | ca.MX) else np.tanh
        s = e + e**3 / (3 * self.a**2) if self.shape == "hardening" else e - self.a * tanh(e / self.a)
        return self.k * s + self.d * de

    def static_deflection(self, torque: float) -> float:
        """The deflection e [rad] with spring torque k s(e) = `torque` [N m] (s is monotonic: bisection)."""
        lo, hi = -1.0, 1.0
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.spring(mid, 0.0) < torque else (lo, mid)
        return 0.5 * (lo + hi)

    def rates(self, kd) -> list[float]:
        # A hardening spring stiffens: allow a tangent 4 × k (deflections to √3 a) in the RK4 step.
        grow = 2.0 if self.shape == "hardening" else 1.0
        return [grow * self.fastest_rate + kd[self.index] / self.B]


def gravity_deflection(truth, j: int, k: float) -> float:
    """e_g [rad]: the largest static deflection of joint j (0-based) under gravity over the workspace."""
    G = sim.TRUTH_MODEL.function("G")
    pi = sim.TRUTH_MODEL.vector(truth.pi_rigid)
    torques = [
        abs(float(G([q1, q2], [0, 0], [0, 0], pi)[j])) for q1 in np.linspace(0, math.pi, 13) for q2 in (-1.4, 0, 1.4)
    ]
    return max(torques) / k


def nonlinear_joint(truth, shape: str, size: float) -> NonlinearJoint:
    """The truth's elastic joint (`truth.elastic`, a catalogue `Elastic` of kind joint) with a non-linear spring:
    `shape` "hardening" (tangent stiffness k (1 + size) at e_g) or "backlash" (play half-width size × e_g)."""
    e = truth.elastic
    e_g = gravity_deflection(truth, e.index, e.k)
    a = e_g / math.sqrt(size) if shape == "hardening" else size * e_g
    fields = {f: getattr(e, f) for f in e.__dataclass_fields__}
    return NonlinearJoint(**fields, shape=shape, a=a)


def effective_frequency_hz(mech: NonlinearJoint, deflection: np.ndarray) -> float:
    """The mode's frequency [Hz] at the spring's mean tangent stiffness over the logged deflections [rad]."""
    e = ca.SX.sym("e")
    tangent = ca.Function("kt", [e], [ca.jacobian(mech.spring(e, 0.0), e)])
    kt = float(np.mean(np.array(tangent(deflection.reshape(1, -1))).ravel()))
    return mech.frequency_hz * math.sqrt(kt / mech.k)


# ---------------------------------------------------------------------------------------------- loggers
#: How a logger hands the trial over: Savitzky–Golay derivatives (window in samples, polynomial order 3),
#: no derivatives (the loader estimates them), or currents and no derivatives.
PIPELINES = ("savgol11", "savgol15", "savgol21", "no_derivatives", "currents")


def savgol(t: np.ndarray, q: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """dq [rad/s], ddq [rad/s²] of angles q (N, n) sampled every dt, by a cubic Savitzky–Golay filter."""
    dt = float(np.median(np.diff(t)))
    return tuple(signal.savgol_filter(q, window, 3, deriv=d, delta=dt, axis=0) for d in (1, 2))


def derived(trial, pipeline: str, robot):
    """`trial` (a `SimTrial`) as the `pipeline` logger hands it over, as a `Dataset` read the way the CLI reads
    it (derivatives missing: the loader estimates them at the "auto" cut-off and leaves out the edges)."""
    from ident_opt.data.loader import load_dataset
    from ident_opt.problem.spec import DataSpec

    ds = trial.dataset()
    if pipeline.startswith("savgol"):
        dq, ddq = savgol(ds.t, ds.q, int(pipeline.removeprefix("savgol")))
        return replace(ds, dq=dq, ddq=ddq, derivatives=f"given ({pipeline})")
    frame = trial.frame.drop(columns=[c for c in trial.frame.columns if c.startswith(("dq", "ddq"))])
    if pipeline == "currents":
        gains = np.array([j.current_to_torque for j in robot.joints])
        for k in range(2):
            frame[f"i{k + 1}"] = frame.pop(f"tau{k + 1}") / gains[k]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trial.csv"
        frame.to_csv(path, index=False)
        return load_dataset(path, DataSpec(trials=(path,)), robot)
