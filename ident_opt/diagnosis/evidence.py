"""What the nominal model gets wrong, measured: torque-residual features and short-window motion errors.

Everything here describes a residual r = τ − τ̂ (N m) on one contiguous stretch of data; nothing is fitted.
Velocity thresholds are relative to the joint's own speed scale v_ref (95th percentile of |dq|), so the
same numbers mean the same thing on any arm: at rest |dq| < 1 % v_ref, slow < 10 % v_ref, fast > 30 % v_ref.
"""

from __future__ import annotations

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.data.dataset import Dataset
from ident_opt.numerics import signals

#: Below this frequency [Hz] lies the motion band of point-to-point trials (the real trials' residual
#: power sits mostly there).
LOW_BAND_HZ = 0.6


def _speed_classes(dq: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    v_ref = float(np.quantile(np.abs(dq), 0.95)) or 1.0
    a = np.abs(dq)
    return v_ref, a < 0.01 * v_ref, (a >= 0.01 * v_ref) & (a < 0.1 * v_ref), a > 0.3 * v_ref


def reversal_steps(r: np.ndarray, dq: np.ndarray, dt: float, window_s: float = 0.1) -> dict[str, float]:
    """Mean jump of the residual across velocity reversals [N m], split by direction.

    A reversal is a sign change of dq with real motion (|dq| above 10 % v_ref) within 0.3 s on both sides.
    Symmetric mis-scaled Coulomb friction gives equal and opposite jumps; asymmetric friction unequal ones.
    """
    v_ref = float(np.quantile(np.abs(dq), 0.95)) or 1.0
    w, W = max(1, round(window_s / dt)), max(1, round(0.3 / dt))
    s = np.sign(dq)
    ks = np.flatnonzero((s[1:] * s[:-1]) < 0) + 1
    up, down = [], []
    for k in ks:
        if k < W or k + W > len(dq):
            continue
        if np.max(np.abs(dq[k - W : k])) < 0.1 * v_ref or np.max(np.abs(dq[k : k + W])) < 0.1 * v_ref:
            continue
        step = float(np.mean(r[k : k + w]) - np.mean(r[k - w : k]))
        (up if dq[k] > 0 else down).append(step)
    return {
        "negative_to_positive": float(np.mean(up)) if up else float("nan"),
        "positive_to_negative": float(np.mean(down)) if down else float("nan"),
        "count": len(up) + len(down),
    }


def pose_r2(r: np.ndarray, q: np.ndarray) -> float:
    """Share of the residual's variance explained by gravity-like pose functions (cos/sin of q1, q1 + q2)."""
    q12 = q[:, 0] + q[:, 1]
    A = np.column_stack([np.ones(len(r)), np.cos(q[:, 0]), np.sin(q[:, 0]), np.cos(q12), np.sin(q12)])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    var = float(np.var(r))
    return float(1.0 - np.var(r - A @ coef) / var) if var > 0 else 0.0


def pose_r2_any(r: np.ndarray, q: np.ndarray) -> float:
    """Share of the residual's variance explained by pose functions of an n-joint arm (cos and sin of each joint
    angle): what a rotated gravity or a mis-placed mass leaves."""
    A = np.column_stack([np.ones(len(r)), np.cos(q), np.sin(q)])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    var = float(np.var(r))
    return float(1.0 - np.var(r - A @ coef) / var) if var > 0 else 0.0


def residual_evidence(ds: Dataset, tau_hat: np.ndarray, dt: float, pose=pose_r2) -> dict:
    """Residual features per joint (see the module docstring), plus the torque-channel lag; `pose(r, q)` the share
    of a residual explained by the pose (`pose_r2` for the planar arm, `pose_r2_any` for any)."""
    r = ds.tau - tau_hat
    out: dict = {
        "rms": [],
        "nmse": [],
        "peaks": [],
        "low_band_fraction": [],
        "moving_mean": [],
        "reversal_steps": [],
        "low_speed_excess": [],
        "pose_r2": [],
        "lag_s": [],
    }
    for j in range(r.shape[1]):
        rj, dqj = r[:, j], ds.dq[:, j]
        _, rest, slow, fast = _speed_classes(dqj)
        moving = ~rest
        pos, neg = moving & (dqj > 0), moving & (dqj < 0)
        out["rms"].append(float(np.sqrt(np.mean(rj**2))))
        out["nmse"].append(float(np.mean(rj**2) / np.var(ds.tau[:, j])))
        out["peaks"].append([p.as_dict() for p in signals.peaks(rj, dt)])
        out["low_band_fraction"].append(signals.band_fraction(rj, dt, LOW_BAND_HZ))
        out["moving_mean"].append(
            {
                "positive": float(np.mean(rj[pos])) if pos.any() else float("nan"),
                "negative": float(np.mean(rj[neg])) if neg.any() else float("nan"),
            }
        )
        out["reversal_steps"].append(reversal_steps(rj, dqj, dt))
        signed = rj * np.sign(dqj)
        out["low_speed_excess"].append(
            float(np.mean(signed[slow]) - np.mean(signed[fast])) if slow.any() and fast.any() else float("nan")
        )
        out["pose_r2"].append(pose(rj, ds.q))
        out["lag_s"].append(signals.lag(tau_hat[:, j], ds.tau[:, j], dt))
    out["rest_fraction"] = float(
        np.mean(np.all(np.abs(ds.dq) < 0.01 * np.quantile(np.abs(ds.dq), 0.95, axis=0), axis=1))
    )
    return out


def forward_error(
    model: Arm,
    pi: np.ndarray,
    ds: Dataset,
    dt: float,
    window_s: float = 0.5,
    extension: np.ndarray | None = None,
) -> list[float]:
    """RMS joint-angle error [rad] at the end of short windows of forward simulation driven by the measured
    torque: M(q) q̈ = τ − C(q, q̇)q̇ − G(q) − F(q̇), semi-implicit Euler at the data rate, each window
    restarted from the measured state (so drift does not swamp the comparison). All windows run at once.

    `extension` (N, 2) [N m]: an extended model's torque beyond the rigid model `pi`, evaluated along the
    measured motion (a mode, a delay, friction shapes: teacher-forced, since some depend on the history);
    it is subtracted from the driving torque while the rigid part is integrated."""
    L = max(2, round(window_s / dt))
    starts = np.arange(0, ds.n - L, L)
    if len(starts) == 0:
        return [float("nan")] * ds.q.shape[1]
    q, dq = ds.q[starts].copy(), ds.dq[starts].copy()
    zero = np.zeros_like(q)
    # A joint whose model has no inertia about its axis (a URDF link without it and no rotor: the shipped TX40's
    # last) has nothing to integrate: it follows its measured motion and its error is not reported.
    diagonal = np.abs(np.diagonal(model.mass_matrices(pi, ds.q[starts]), axis1=-2, axis2=-1)).min(axis=0)
    inert = diagonal > 1e-12 * max(float(np.max(diagonal)), np.finfo(float).tiny)
    held = ~inert
    with np.errstate(all="ignore"):
        for step in range(L):
            tau = ds.tau[starts + step] - (extension[starts + step] if extension is not None else 0.0)
            if held.any():
                q[:, held], dq[:, held] = ds.q[starts + step][:, held], ds.dq[starts + step][:, held]
            bias = model.predict(pi, q, dq, zero)
            M = model.mass_matrices(pi, q)
            ddq = ds.ddq[starts + step].copy()
            rhs = tau - bias - np.einsum("wij,wj->wi", M[:, :, held], ddq[:, held])
            ddq[:, inert] = np.linalg.solve(M[:, inert][:, :, inert], rhs[:, inert][..., None])[..., 0]
            dq = dq + dt * ddq
            q = q + dt * dq
        err = q - ds.q[starts + L]
        rms = np.sqrt(np.nanmean(err**2, axis=0))
    return [float(v) if np.isfinite(v) and ok else float("nan") for v, ok in zip(rms, inert)]


#: Where the first modes of flexible-link arms lie [Hz]: the band searched in independent channels.
MODE_BAND_HZ = (1.0, 10.0)


def channel_peaks(ds: Dataset, dt: float) -> dict[str, dict]:
    """Spectra of the file's other numeric channels (e.g. strain gauges): independent evidence of a mode,
    never a model input. Per channel: its most prominent peaks above 0.7 Hz, and the frequency of its
    strongest power within MODE_BAND_HZ (a broad mode on a sloping spectrum is not "prominent" but is still
    the band's maximum). Constant or non-finite channels are skipped."""
    out = {}
    for name in ds.extra.columns:
        x = np.asarray(ds.extra[name], dtype=float)
        if not np.all(np.isfinite(x)) or np.std(x) <= 1e-12 * max(1.0, float(np.max(np.abs(x)))):
            continue
        f, p = signals.spectrum(x, dt, window_s=20.0)
        band = (f >= MODE_BAND_HZ[0]) & (f <= min(MODE_BAND_HZ[1], 0.45 / dt))
        out[str(name)] = {
            "peaks": [pk.as_dict() for pk in signals.peaks(x, dt)],
            "mode_band_max_hz": float(f[band][np.argmax(p[band])]) if band.any() else float("nan"),
        }
    return out
