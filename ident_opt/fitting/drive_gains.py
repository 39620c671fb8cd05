"""Drive gains from a known load (`[data.payloads]`, `docs/problem-files.md`, "Payloads and drive gains").

A drive logged as current is turned into joint torque by a gain, current × torque constant × gear ratio; the true
gain differs from that product by a factor s_j per joint (a torque constant off its datasheet value, a gear's
efficiency). Without a known load, s and the dynamics share a scale: s τ_log = Y π is solved by (c s, c π) for any
c, and s cannot be told. A trial with a known load m at c on the last link adds a known torque Y Δπ(m, c)
(`Robot.payload`), which fixes the scale. With w_j = 1/s_j, per joint j and sample k of trial t,

    τ_log[k, j] = w_j Y_j[k] (π + Δπ_t) + e[k, j]      (Δπ_t = 0 without a load),

the logged torque — the noisy signal — on the left: written the other way round (s τ_log = Y π) the noise would sit
in a regressor and bias s toward 0 (5 % on a simulated planar arm at the default noise). The problem is bilinear in
(π, w): a few sweeps of alternating least squares (π given w, then each w_j given π, from s = 1), then Gauss–Newton,
on sufficient statistics accumulated in chunks of samples (memory flat in the trials' length), the joints weighted
by the inverse of their residual variance. Standard errors from the Gauss–Newton normal matrix at the solution
(white residuals: the filtered torque's correlation makes them optimistic), s_j's by the delta method. s_j more
than `TOLERANCE` from 1 and more than two standard errors is a warning; a joint whose w_j the trials do not
determine has no estimate. τ is the fit's torque (`Dataset.tau_fit`: low-passed like the derivatives), as every
fit takes it.

Each joint's samples slower than its stick speed (`signals.stick_speed`: 2 % of its 95th-percentile speed, the
n-joint diagnosis's rule) are left out of that joint's equation: there its friction is whatever stiction holds and
the Coulomb column, sign(q̇) of an estimated velocity, is noise. Left in, they bias the friction, and through it the
gain: on the simulated TX40 with the logger's noise (33–43 % of its samples that slow) joint 1's gain was off by
35 % and joint 4's by 5 %, and are within 0.4 % without them (`benchmarks/drive_gains.py`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ident_opt.arm.base import Arm, Robot
from ident_opt.data.dataset import Dataset
from ident_opt.errors import InputError
from ident_opt.numerics import signals
from ident_opt.outputs import shown
from ident_opt.problem.spec import KnownLoad
from ident_opt.warnings import ResultWarning

#: A drive whose gain leaves the nominal one by more than this share (and two standard errors) is a warning.
TOLERANCE = 0.10
#: Samples per chunk of the normal equations.
CHUNK = 4096
#: A direction of the weighted normal matrix below this share of its largest eigenvalue is undetermined.
RANK_TOL = 1e-10


@dataclass(frozen=True)
class DriveGains:
    """Each joint's drive gain as a factor on the nominal one (`ratio`, true joint torque over logged), its standard
    error (NaN: not determined), the nominal gain [N m/A] (None: the problem gives no torque constant and gear
    ratio: a torque-logged joint), the trials with a known load, and what to warn about."""

    joints: tuple[str, ...]
    ratio: np.ndarray
    se: np.ndarray
    nominal: tuple[float | None, ...]
    loaded: tuple[str, ...]
    warnings: list[ResultWarning] = field(default_factory=list)

    def as_json(self) -> dict:
        """The `compare --json` key `drive_gains`."""
        determined = np.isfinite(self.se)
        return {
            "joints": list(self.joints),
            "ratio": [float(r) if ok else None for r, ok in zip(self.ratio, determined)],
            "standard_error": [float(e) if ok else None for e, ok in zip(self.se, determined)],
            "gain_n_m_per_a": [
                float(r * k) if ok and k is not None else None for r, k, ok in zip(self.ratio, self.nominal, determined)
            ],
            "nominal_n_m_per_a": list(self.nominal),
            "loaded_trials": list(self.loaded),
            "definition": "ratio: the joint torque the drive delivers over the torque logged (current × torque "
            "constant × gear ratio, or the logged torque); identified with the dynamics from the trials with a "
            "known load ([data.payloads]), which fix the scale the two otherwise share",
        }


#: Alternating least squares: at most this many sweeps, stopping when no w_j moves by more than `STEP` (relative).
SWEEPS, STEP = 200, 1e-10


@dataclass
class _Stats:
    """Per joint j, over every sample: Z_jᵀZ_j, Z_jᵀr_j, Z_jᵀt_j, r_jᵀr_j, r_jᵀt_j, t_jᵀt_j, with Z_j = Y_j,
    r_j = Y_j Δπ (the known load's torque) and t_j = τ_log,j; and the sample count."""

    ZZ: np.ndarray
    Zr: np.ndarray
    Zt: np.ndarray
    rr: np.ndarray
    rt: np.ndarray
    tt: np.ndarray
    count: int = 0


def _statistics(model: Arm, robot: Robot, trials: Sequence[Dataset], loads: Sequence[KnownLoad | None]) -> _Stats:
    """`_Stats` of `trials`, accumulated in chunks of `CHUNK` samples."""
    n, P = robot.n_joints, model.n_params
    st = _Stats(np.zeros((n, P, P)), np.zeros((n, P)), np.zeros((n, P)), np.zeros(n), np.zeros(n), np.zeros(n))
    for trial, load in zip(trials, loads):
        delta = np.zeros(P)
        if load is not None:
            try:
                delta = robot.payload(model, load.mass, load.com)
            except ValueError as exc:
                raise InputError(f"[data.payloads] {shown(trial.source)}: {exc}") from None
        below = signals.stick_speed(trial.dq)
        for start in range(0, trial.n, CHUNK):
            part = trial.subset(np.arange(start, min(start + CHUNK, trial.n)))
            moving = (np.abs(part.dq) >= below).astype(float)  # (N, n): a slow sample leaves its joint's equation
            Z = model.regressor(part.q, part.dq, part.ddq) * moving[:, :, None]  # (N, n, P)
            r, t = Z @ delta, part.tau_fit * moving
            st.ZZ += np.einsum("kjp,kjq->jpq", Z, Z)
            st.Zr += np.einsum("kjp,kj->jp", Z, r)
            st.Zt += np.einsum("kjp,kj->jp", Z, t)
            st.rr += np.einsum("kj,kj->j", r, r)
            st.rt += np.einsum("kj,kj->j", r, t)
            st.tt += np.einsum("kj,kj->j", t, t)
            st.count += len(t)
    return st


def _pinv(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the pseudo-inverse of the symmetric H, column-scaled, directions below `RANK_TOL` dropped; the mask of the
    unknowns no dropped direction reaches)."""
    scale = np.sqrt(np.maximum(np.diag(H), np.finfo(float).tiny))
    vals, vecs = np.linalg.eigh(H / np.outer(scale, scale))
    keep = vals > RANK_TOL * vals.max()
    inv = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    determined = np.sum(vecs[:, ~keep] ** 2, axis=1) < 1e-6  # numerically 0 in noise-free data
    return inv / np.outer(scale, scale), determined


def _sse(st: _Stats, pi: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per joint Σ_k (t − w (Z π + r))², from the statistics."""
    aa = np.einsum("p,jpq,q->j", pi, st.ZZ, pi) + 2 * st.Zr @ pi + st.rr
    at = st.Zt @ pi + st.rt
    return st.tt - 2 * w * at + w**2 * aa


def _alternate(st: _Stats, weight: np.ndarray, w: np.ndarray, sweeps: int = SWEEPS) -> tuple[np.ndarray, np.ndarray]:
    """(π, w) by alternating least squares from `w`, the joints weighted by `weight`."""
    pi = np.zeros(st.ZZ.shape[1])
    for _ in range(sweeps):
        H = np.einsum("j,jpq->pq", weight * w**2, st.ZZ)
        g = np.einsum("j,jp->p", weight * w, st.Zt - w[:, None] * st.Zr)
        inv, _ = _pinv(H)
        pi = inv @ g
        aa = np.einsum("p,jpq,q->j", pi, st.ZZ, pi) + 2 * st.Zr @ pi + st.rr
        new = (st.Zt @ pi + st.rt) / np.maximum(aa, np.finfo(float).tiny)
        done = np.max(np.abs(new - w) / np.maximum(np.abs(w), np.finfo(float).tiny)) < STEP
        w = new
        if done:
            break
    return pi, w


def _normal_matrix(st: _Stats, weight: np.ndarray, pi: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The weighted Gauss–Newton normal matrix JᵀWJ of (π, w) at (π, w), from the statistics."""
    n, P = len(w), len(pi)
    H = np.zeros((P + n, P + n))
    H[:P, :P] = np.einsum("j,jpq->pq", weight * w**2, st.ZZ)
    cross = np.einsum("jpq,q->jp", st.ZZ, pi) + st.Zr  # Z_jᵀ (Z_j π + r_j)
    H[:P, P:] = (weight * w)[None, :] * cross.T
    H[P:, :P] = H[:P, P:].T
    H[P:, P:] = np.diag(weight * (np.einsum("p,jpq,q->j", pi, st.ZZ, pi) + 2 * st.Zr @ pi + st.rr))
    return H


def _gauss_newton(st: _Stats, weight: np.ndarray, pi: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(π, w) polished by Gauss–Newton steps on the bilinear problem (the alternation's zig-zag converges slowly
    where π and w trade off)."""
    P = len(pi)
    for _ in range(SWEEPS):
        aa = np.einsum("p,jpq,q->j", pi, st.ZZ, pi) + 2 * st.Zr @ pi + st.rr
        at = st.Zt @ pi + st.rt
        b_pi = np.einsum("j,jp->p", weight * w, st.Zt - w[:, None] * (np.einsum("jpq,q->jp", st.ZZ, pi) + st.Zr))
        b = np.concatenate([b_pi, weight * (at - w * aa)])
        inv, _ = _pinv(_normal_matrix(st, weight, pi, w))
        step = inv @ b
        pi, w = pi + step[:P], w + step[P:]
        if np.max(np.abs(step[P:]) / np.maximum(np.abs(w), np.finfo(float).tiny)) < STEP:
            break
    return pi, w


def _covariance(st: _Stats, weight: np.ndarray, pi: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the covariance of w, the mask of determined w_j) from the weighted Gauss–Newton normal matrix of (π, w)."""
    cov, determined = _pinv(_normal_matrix(st, weight, pi, w))
    P = len(pi)
    return np.diag(cov)[P:], determined[P:]


def identify(robot: Robot, model: Arm, trials: Sequence[Dataset], loads: Sequence[KnownLoad | None]) -> DriveGains:
    """The drive gains (module doc) from `trials`, `loads[k]` the known load of trial k (None: none); at least one
    trial must carry a load (else the scale is not determined: an InputError says so)."""
    if not any(load is not None for load in loads):
        raise InputError(
            "drive gains: no trial carries a known load ([data.payloads]); without one the drives' gains and the "
            "dynamics share a scale the data cannot split"
        )
    n, P = robot.n_joints, model.n_params
    st = _statistics(model, robot, trials, loads)
    pi, w = _gauss_newton(st, np.ones(n), *_alternate(st, np.ones(n), np.ones(n), sweeps=5))
    # A residual variance floor of 1e-12 of the torque's mean square: exact (noise-free) data keep finite weights.
    floor = 1e-12 * np.maximum(st.tt / max(st.count, 1), np.finfo(float).tiny)
    sigma2 = np.maximum(_sse(st, pi, w) / max(st.count - (P + n) / n, 1), floor)
    pi, w = _gauss_newton(st, 1.0 / sigma2, pi, w)  # the joints weighted by their residual variance
    var_w, determined = _covariance(st, 1.0 / sigma2, pi, w)
    s = 1.0 / w
    se = np.where(determined, np.sqrt(np.maximum(var_w, 0.0)) / w**2, np.nan)  # delta method: |ds/dw| = 1/w²
    nominal = tuple(j.current_to_torque for j in robot.joints)
    loaded = tuple(shown(t.source) for t, load in zip(trials, loads) if load is not None)
    gains = DriveGains(tuple(robot.joint_names), s, se, nominal, loaded)
    gains.warnings.extend(_warnings(gains))
    return gains


def _warnings(g: DriveGains) -> list[ResultWarning]:
    """A drive whose gain is far from its nominal one; a joint whose gain the trials do not determine."""
    out = []
    for name, r, e, k in zip(g.joints, g.ratio, g.se, g.nominal):
        if not np.isfinite(e):
            out.append(
                ResultWarning(
                    "drive_gain_undetermined",
                    f"{name}: the trials do not determine its drive gain "
                    "(the joint does not move enough under the known load)",
                )
            )
        elif abs(r - 1.0) > TOLERANCE and abs(r - 1.0) > 2 * e:
            nominal = f"torque constant × gear ratio ({k:.4g} N m/A)" if k is not None else "the logged torque"
            out.append(
                ResultWarning(
                    "drive_gain",
                    f"{name}: the drive delivers {r:.3g} ± {e:.2g} × {nominal}, more than {TOLERANCE:.0%} off: check "
                    "the torque constant, the gear ratio and the current channel's scale",
                )
            )
    return out
