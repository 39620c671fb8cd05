"""The context every candidate of an arm with n joints is fitted in (`ArmContext`): the robot and its model, the
training and held-out parts, joint weights, the datasheet's π, rest labels, the estimator π is refitted with, and
the views and columns the candidates share (remembered per data view)."""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy import sparse
from scipy.signal import butter, filtfilt

from ident_opt.arm.base import Arm, Robot
from ident_opt.cbuild import CompiledRows
from ident_opt.data.dataset import Dataset
from ident_opt.effects.families import (
    per_joint_columns,
    step,
    view_key,
)
from ident_opt.errors import InputError
from ident_opt.fitting.base import base_parameters
from ident_opt.fitting.estimators import INSTRUMENTED, fit_for
from ident_opt.fitting.iv import InstrumentStats, instrument_kinematics
from ident_opt.fitting.stats import Stats
from ident_opt.numerics import least_squares as linear
from ident_opt.numerics import signals

#: Samples the nonlinear searches read (strided, never below `SEARCH_HZ` [Hz]: the torque filter's default cut-off
#: with room to spare, and a Stribeck hump crossed in tens of milliseconds still falls on samples).
SEARCH_SAMPLES, SEARCH_HZ = 4000, 100.0
#: Eigenvalues of the rigid columns' Gram matrix below this share of the largest are directions the data do not
#: determine (`ArmContext.basis`): singular values below 1e-5 of the largest.
RANK_TOL = 1e-10


#: A link whose inertia about its joint's axis is below this share of the largest link's carries none
#: (`elastic_joints`).
MASSLESS = 1e-9


@dataclass
class ArmContext:
    """What every candidate needs: the robot and its model, the training and held-out parts, joint weights 1/σ_j²,
    the datasheet's π (P,), the sample step dt [s], rest-stretch labels, the estimator π is refitted with, the
    rigid model's rank, per-joint evidence, and caches."""

    robot: Robot
    arm: Arm
    train: Dataset
    test: Dataset
    weights: np.ndarray
    datasheet: np.ndarray
    dt: float
    rest: np.ndarray
    estimator: str
    filter_hz: float | None = None  # the torque's zero-phase low-pass [Hz] (`split.prepare`), None: none
    rank: int = 0
    evidence: dict = field(default_factory=dict)
    pi_rigid: np.ndarray | None = None
    #: `failing(cause, estimate, detail) -> {joint: [why]}`: the plausibility rule's per-joint range failures
    #: (`plausibility.failing_joints`), set by the rounds once the facts are read; None: none asked (`families.fit`).
    failing: object = None
    _cache: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        """The number of joints."""
        return self.arm.n_joints

    @property
    def independent(self) -> np.ndarray:
        """The columns of Y that span its column space on any motion: the base parameters' (`fitting.base`)."""
        if "independent" not in self._cache:
            self._cache["independent"] = np.sort(base_parameters(self.arm).independent)
        return self._cache["independent"]

    @property
    def stick_speed(self) -> np.ndarray:
        """(n,) [rad/s]: below this speed a joint's samples are left out of every fit and score (`labels`):
        `signals.STICK_SPEEDS` × its rest speed on the training part."""
        if ("stick_speed",) not in self._cache:
            self._cache[("stick_speed",)] = signals.stick_speed(self.train.dq)
        return self._cache[("stick_speed",)]

    def labels(self, ds: Dataset) -> np.ndarray:
        """Labels of `ds` (`signals.rest_runs`) that leave each joint's samples slower than `stick_speed` out of
        every comparison (stiction may hold them), and those where a coupled drive (a wrist's motor turning two
        joints) is slower than its own stick speed on every row it reaches: its friction is set-valued there whatever
        its joints do (on a clean simulated TX40, joint 5's residual is 0.39 N m RMS there, 0.03 elsewhere).
        Remembered."""
        key = ("labels", *view_key(ds))
        if key not in self._cache:
            labels = signals.rest_runs(ds.dq, self.stick_speed)
            if self.coupled:
                C = self.arm.drive_matrix
                v, below = ds.dq @ C.T, signals.stick_speed(self.train.dq @ C.T)
                for m in self.coupled:
                    slow = np.abs(v[:, m]) < below[m]
                    for j in np.flatnonzero(C[m]):
                        new = slow & (labels[:, j] < 0)  # moving on joint j, held by the drive: a stretch of its own
                        labels[new, j] = labels[:, j].max() + 1 + np.arange(int(new.sum()))
            self._cache[key] = labels
        return self._cache[key]

    def regressor(self, ds: Dataset, delta: np.ndarray | None = None) -> np.ndarray:
        """Y (N, n, P) of `ds` at the angles q + δ (δ None: as logged), a coupled drive's Coulomb column 0 where the
        drive rests (`drive_rest`), remembered for the last few."""
        key = ("Y", *view_key(ds), None if delta is None else np.asarray(delta).tobytes())
        if key not in self._cache:
            q = ds.q if delta is None else ds.q + delta
            self._trim("Y")
            self._cache[key] = self.drive_rest(self.arm.regressor(q, ds.dq, ds.ddq), ds)
        return self._cache[key]

    def drive_rest(self, Y: np.ndarray, ds: Dataset) -> np.ndarray:
        """Y (N, n, P) with the Coulomb column of each coupled drive (a row of `Arm.drive_matrix` other than its own
        joint's, a coupled wrist's motor) set to 0 where that drive rests (`signals.resting` on its velocity
        v_m = C[m] · dq): the joints' rule (`data.dataset.at_rest`) for a drive whose joints move while it stands still,
        as a wrist's motor does when its joints counter-rotate. Its friction is set-valued there, and
        sgn(v_m) of a velocity of a few 1e-4 rad/s (the encoders' noise) a random ±fc on every row it reaches."""
        v = self.drive_velocity(ds)
        coupled = self.coupled
        if not coupled:
            return Y
        terms = self.coulomb_terms()
        Y = np.array(Y, copy=True)
        for m in coupled:
            Y[np.ix_(v[:, m] == 0, np.arange(self.n), terms[m])] = 0.0
        return Y

    @property
    def coupled(self) -> list[int]:
        """The drives (0-based) that turn more than their own joint (`Arm.drive_matrix`: a coupled wrist's motor)."""
        C = self.arm.drive_matrix
        return [m for m in range(self.n) if np.count_nonzero(C[m]) > 1]

    def drive_velocity(self, ds: Dataset) -> np.ndarray:
        """v = dq Cᵀ (N, n) [rad/s]: each drive's joint-side velocity along `ds`, a coupled drive's exactly 0 where it
        rests (`signals.resting`; a drive of its own joint rests with it, `data.dataset.at_rest`), remembered per
        view."""
        key = ("v", *view_key(ds))
        if key not in self._cache:
            v = ds.dq @ self.arm.drive_matrix.T
            coupled = self.coupled
            if coupled and ds.n > 1:
                rest = np.zeros_like(v, dtype=bool)
                rest[:, coupled] = signals.resting(v[:, coupled], step(ds))
                v = np.where(rest, 0.0, v)
            self._cache[key] = v
        return self._cache[key]

    def drive_columns(self, values: np.ndarray, joints: tuple[int, ...], prefix: str) -> tuple[np.ndarray, list[str]]:
        """(X (N, n, k), names): one column per drive m of `joints`, `values[:, m]` × C[m, i] on each row i it
        reaches (`Arm.drive_matrix`; on row m alone for a drive of its own joint: `per_joint_columns`), named
        `<prefix><m + 1>`. A drive's friction, reaching every joint its motor turns."""
        X, names = per_joint_columns(values, joints, prefix)
        C = self.arm.drive_matrix
        for k, m in enumerate(joints):
            X[:, :, k] = values[:, m][:, None] * C[m][None, :]
        return X, names

    def basis(self, ds: Dataset, delta: np.ndarray | None = None) -> np.ndarray:
        """Q (N n, r): an orthonormal basis (`orthonormal`) of the weighted, rest-demeaned rigid columns (`rows`),
        remembered (the one at the logged angles kept for good)."""
        kind = "Q" if delta is not None else "Q0"
        key = (kind, *view_key(ds), None if delta is None else np.asarray(delta).tobytes())
        if key not in self._cache:
            # the base parameters' columns span the same space as all of Y's (`fitting.base`), at a third of the cost
            A = self.rows(self.regressor(ds, delta)[:, :, self.independent], ds)
            if kind == "Q":
                self._trim("Q")
            self._cache[key] = orthonormal(A)
        return self._cache[key]

    def inertial_basis(self, ds: Dataset) -> np.ndarray:
        """Q (N n, r): `basis` of the rigid body's inertial columns alone (the base parameters that are neither
        friction nor offsets), at the logged angles, remembered."""
        key = ("Qinertial", *view_key(ds))
        if key not in self._cache:
            kinds = [p.kind for p in self.arm.parameters]
            inertial = [i for i in self.independent if kinds[i] not in ("friction", "other")]
            self._cache[key] = orthonormal(self.rows(self.regressor(ds)[:, :, inertial], ds))
        return self._cache[key]

    def demean(self, X: np.ndarray, ds: Dataset) -> np.ndarray:
        """X (N, n, ...) with each joint's rest-stretch means removed (`signals.demean_runs` on `ds`'s stretches),
        by two sparse products per joint (stretch means, back to the samples), remembered per view."""
        key = ("demean", *view_key(ds))
        if key not in self._cache:
            labels = self.labels(ds)
            operators = []
            for j in range(labels.shape[1]):
                rest = np.nonzero(labels[:, j] >= 0)[0]
                if not len(rest):
                    operators.append(None)
                    continue
                lab = labels[rest, j]
                counts = np.bincount(lab)
                mean = sparse.csr_matrix((1.0 / counts[lab], (lab, rest)), shape=(len(counts), len(labels)))
                back = sparse.csr_matrix((np.ones(len(rest)), (rest, lab)), shape=(len(labels), len(counts)))
                operators.append((mean, back))
            self._cache[key] = operators
        out = np.array(X, dtype=float, copy=True)
        shape = out.shape
        for j, op in enumerate(self._cache[key]):
            if op is None:
                continue
            block = out[:, j].reshape(shape[0], -1)
            out[:, j] = (block - op[1] @ (op[0] @ block)).reshape((shape[0], *shape[2:]))
        return out

    def rows(self, X: np.ndarray, ds: Dataset) -> np.ndarray:
        """X (N, n, k) rest-demeaned (`demean`) and weighted by √w_j, stacked to (N n, k): what every fit
        minimises over."""
        if X.shape[2] == 0:
            return np.zeros((X.shape[0] * X.shape[1], 0))
        A = self.demean(X, ds) * np.sqrt(self.weights)[None, :, None]
        return A.reshape(-1, X.shape[2])

    @property
    def search_view(self) -> Dataset:
        """The training part as the nonlinear searches read it: every k-th sample, at most `SEARCH_SAMPLES` and at
        least `SEARCH_HZ` (the final fit reads every sample)."""
        if "search" not in self._cache:
            tr = self.train
            k = max(1, min(-(-tr.n // SEARCH_SAMPLES), int(1.0 / (self.dt * SEARCH_HZ))))
            self._cache["search"] = tr if k == 1 else tr.subset(np.arange(0, tr.n, k))
        return self._cache["search"]

    @property
    def correlation(self) -> float:
        """√(2 τ): how much wider a coefficient's standard error is than least squares says, the residuals being
        correlated over τ samples (the lag where the rigid fit's training residual's autocorrelation, joints
        averaged, falls below 1/e; `linear.hac_lag`'s). The offsets' screen uses it (`offset_search`;
        the linear causes' screens read `linear.sandwich`)."""
        if "correlation" not in self._cache:
            tr = self.train
            r = self.demean(tr.tau - self.regressor(tr) @ self.pi_rigid, tr)
            self._cache["correlation"] = float(np.sqrt(2.0 * max(linear.hac_lag(r) / 3.0, 0.5)))
        return self._cache["correlation"]

    def reweight(self, weights: np.ndarray) -> None:
        """New joint weights (the bases, which depend on them, are forgotten)."""
        self.weights = np.asarray(weights, dtype=float)
        self._cache = {key: value for key, value in self._cache.items() if key[0] not in ("Q", "Q0")}

    def _trim(self, kind: str, keep: int = 6) -> None:
        mine = [k for k in self._cache if k[0] == kind]
        for k in mine[: max(0, len(mine) - keep + 1)]:
            del self._cache[k]

    def rigid(self, Y: np.ndarray, target: np.ndarray, ds: Dataset) -> np.ndarray:
        """π (P,) of the diagnosis's estimator (`estimator`: the recommended fit unless --estimator says otherwise;
        `fit_for`) on τ = `target` (N, n) [N m] with regressor Y along `ds`, rest stretches compared about their
        means, joints weighted by `weights`: the one place the diagnosis fits π. (The statistics are built per
        joint by matrix products, the Gram part remembered per regressor; an instrumented estimator's instruments
        Z are the regressor at `ds`'s instrument kinematics, `iv.instrument_kinematics`.)"""
        key = ("gram", id(Y), Y.shape)
        instrumented = self.estimator in INSTRUMENTED
        if key not in self._cache:
            self._trim("gram", 3)
            Yd = self.demean(Y, ds)
            G = np.stack([Yd[:, j, :].T @ Yd[:, j, :] for j in range(self.n)])
            Zd = A = K = None
            if instrumented:
                Z = self.drive_rest(self.arm.regressor(ds.q, *instrument_kinematics(ds, self.filter_hz)), ds)
                Zd = self.demean(Z, ds)
                A = np.stack([Zd[:, j, :].T @ Yd[:, j, :] for j in range(self.n)])
                K = np.stack([Zd[:, j, :].T @ Zd[:, j, :] for j in range(self.n)])
            self._cache[key] = (Yd, G, Y, Zd, A, K)
        Yd, G, _, Zd, A, K = self._cache[key]
        t = self.demean(target, ds)
        b = np.stack([Yd[:, j, :].T @ t[:, j] for j in range(self.n)])
        stats = Stats(G, b, np.einsum("kj,kj->j", t, t), len(t))
        if instrumented:
            stats = InstrumentStats(A, np.stack([Zd[:, j, :].T @ t[:, j] for j in range(self.n)]), K, stats)
        return fit_for(self.robot, self.estimator, stats, self.arm, weights=self.weights).pi

    def link_torque(self, ds: Dataset) -> np.ndarray:
        """τ_load (N, n) [N m]: the datasheet's link-side rigid torque at the measured motion (the joint terms —
        friction, armature, offsets — removed), remembered."""
        key = ("load", *view_key(ds))
        if key not in self._cache:
            self._cache[key] = self.regressor(ds) @ link_side(self.arm, self.datasheet)
        return self._cache[key]

    def inertia_column(self, ds: Dataset, joint: int) -> np.ndarray:
        """M_link(q)[:, j] (N, n) [kg m²]: joint j's column of the datasheet's link-side mass matrix along `ds`."""
        key = ("M", *view_key(ds), joint)
        if key not in self._cache:
            pi = link_side(self.arm, self.datasheet)
            unit = np.zeros_like(ds.ddq)
            unit[:, joint] = 1.0
            zero = np.zeros_like(ds.ddq)
            self._cache[key] = self.arm.predict(pi, ds.q, zero, unit) - self.arm.predict(pi, ds.q, zero, zero)
        return self._cache[key]

    def lowpass(self, x: np.ndarray, ds: Dataset) -> np.ndarray:
        """x (N, ...) along `ds` through the zero-phase low-pass the measured torque went through (`split.prepare`):
        a column that jumps within a few samples (a friction hump at a reversal) compared like with like."""
        if not self.filter_hz or self.filter_hz >= 0.45 / step(ds) or ds.n <= 30:
            return x
        b, a = butter(4, self.filter_hz * 2 * step(ds))
        return filtfilt(b, a, x, axis=0)

    def stiffness_column(self, ds: Dataset, joint: int) -> np.ndarray:
        """∂τ_link/∂q_j (N, n) [N m/rad]: how the datasheet's link-side torque along `ds` changes with joint j's
        angle (gravity's stiffness and the motion's), remembered."""
        key = ("K", *view_key(ds), joint)
        if key not in self._cache:
            J = self.torque_jacobian(ds, np.zeros(self.n), link_side(self.arm, self.datasheet))
            for j in range(self.n):
                self._cache[("K", *view_key(ds), j)] = np.ascontiguousarray(J[:, :, j])
        return self._cache[key]

    def coulomb_terms(self) -> list[list[int]]:
        """For each joint j, the Coulomb level of its drive: the parameters whose column is sgn(v_j) C[j, i] on each
        row i (v = C dq, C the arm's `drive_matrix`; sgn(dq_j) on row j alone where the drive turns its joint only),
        read from the regressor at random states (no parameter name is matched)."""
        if "coulomb" not in self._cache:
            rng = np.random.default_rng(0)
            q, dq, ddq = rng.normal(size=(3, 16, self.n))
            Y = self.arm.regressor(q, dq, ddq)
            C = self.arm.drive_matrix
            v = dq @ C.T
            found = []
            for j in range(self.n):
                target = np.sign(v[:, j])[:, None] * C[j][None, :]
                found.append([p for p in range(Y.shape[2]) if np.allclose(Y[:, :, p], target, atol=1e-12)])
            self._cache["coulomb"] = found
        return self._cache["coulomb"]

    def torque_jacobian(self, ds: Dataset, delta: np.ndarray, pi: np.ndarray) -> np.ndarray:
        """∂τ/∂q (N, n, n) [N m/rad] of the model at π along `ds` at the angles q + δ: row i, column j is ∂τ_i/∂q_j."""
        f = self._jacobian_function()
        x = np.hstack([ds.q + delta, ds.dq, ds.ddq, np.tile(pi, (ds.n, 1))])
        return f(x)

    def _jacobian_function(self):
        if "dtau_dq" not in self._cache:
            n, P = self.n, self.arm.n_params
            q, dq, ddq, pi = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("ddq", n), ca.SX.sym("pi", P)
            J = ca.jacobian(self.arm.tau_expression(q, dq, ddq, pi), q)
            fn = ca.Function("torque_jacobian", [ca.vertcat(q, dq, ddq, pi)], [ca.densify(J).T])
            try:
                compiled = CompiledRows(fn, "diagnosis")
            except (InputError, OSError):
                compiled = None
            self._cache["dtau_dq"] = compiled or (lambda X, fn=fn: _mapped(fn, X))
        return self._cache["dtau_dq"]


def _mapped(fn: ca.Function, X: np.ndarray) -> np.ndarray:
    """`fn` (one sample's x to a dense (r, c) output) on every row of X (N, k) by CasADi's map: (N, c, r)."""
    out = np.asarray(fn.map(len(X))(X.T))
    r, c = fn.size1_out(0), fn.size2_out(0)
    return out.reshape(r, len(X), c).transpose(1, 2, 0)


def link_side(arm: Arm, pi: np.ndarray) -> np.ndarray:
    """π with the joint terms (friction, armature, offsets) zeroed: the link-side rigid body."""
    return np.where([p.kind in ("friction", "armature", "other") for p in arm.parameters], 0.0, pi)


def advanced(x: np.ndarray, seconds: float, dt: float) -> np.ndarray:
    """x(t + d) on the same grid (linear interpolation; the last samples repeat x[-1]): a channel lagging by d,
    read back in time with the encoders."""
    return signals.delayed(x[::-1], seconds, dt)[::-1]


def orthonormal(A: np.ndarray) -> np.ndarray:
    """Q (rows, r): an orthonormal basis of A's columns. From the Gram matrix AᵀA = V Λ Vᵀ: Q = A V Λ^(−1/2) on the
    eigenvalues above `RANK_TOL` × the largest (a hundred times cheaper than an SVD of A, and as exact for the
    directions it keeps)."""
    lam, V = np.linalg.eigh(A.T @ A)
    keep = lam > RANK_TOL * max(lam[-1], np.finfo(float).tiny)
    return (A @ V[:, keep]) / np.sqrt(lam[keep])
