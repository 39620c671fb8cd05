"""The information an excitation gives, and its cheap evaluation inside IPOPT: the base parameters' information matrix
along a trajectory (`information`, `criteria`, `criterion_value`: D-optimal, condition number), evaluated per sample in
NumPy and handed to CasADi as callbacks with their Jacobians (`SampleFunctions`, `NumpyFunction`,
`information_callback`, `torque_callback`)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ident_opt.cbuild import CompiledRows
from ident_opt.errors import InputError
from ident_opt.excitation.setup import COND_POWER, OBJECTIVE_HZ, STILL, TINY, Setup, _grid
from ident_opt.fitting.fit import base_combinations

# ---------------------------------------------------------------------------------------------- criteria
#: Samples per block of the regressor in `information`.
BLOCK = 4096


def information(setup: Setup, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, H): F = (1/N) Σ Y_Bᵀ W Y_B of the base columns (own units, W = 1/σ²) and H = Σ_j Y_jᵀY_j (all columns).
    Summed over blocks of `BLOCK` samples: the regressor is N × n × P doubles (5 kB a sample on a 7-joint arm), and
    the criteria of a design are read on its whole output grid (hours at kHz rates)."""
    base, P = list(setup.base), setup.arm.n_params
    F, H = np.zeros((len(base), len(base))), np.zeros((P, P))
    for k in range(0, len(q), BLOCK):
        block = slice(k, k + BLOCK)
        Y = setup.arm.regressor(q[block], dq[block], ddq[block])
        Yb = Y[:, :, base] / setup.sigma[None, :, None]
        F += np.einsum("njp,njr->pr", Yb, Yb)
        H += np.einsum("njp,njr->pr", Y, Y)
    return F / len(q), H


def criteria(setup: Setup, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict:
    """log det F (base parameters, per sample, noise-weighted), cond of the column-equilibrated regressor and
    its rank (as `LinearFit.cond` / `.rank`)."""
    F, H = information(setup, q, dq, ddq)
    sign, logdet = np.linalg.slogdet(F)
    rank, cond, _, _ = base_combinations(H, setup.arm.names)
    return {"log_det": float(logdet) if sign > 0 else float("-inf"), "cond": float(cond), "rank": int(rank)}


class SampleFunctions:
    """Per-sample functions of a setup's arms, compiled to C once per machine (`cbuild.CompiledRows`, cached by
    their source's hash; CasADi's own evaluation where no C compiler works), each mapped over many samples at once:
    the states s = [q; dq; ddq] (3n) in, one small matrix out.

    - `columns(S)`: Y_B (N, n, r) of the model's base columns, scaled by `Setup.scale`;
    - `pullback(S, M)`: ∂/∂s Σ_jp M_jp Y_B,jp(s) (N, 3n), the gradient of an information criterion through Y_B;
    - `torques(S)`, `torque_jacobian(S)`: the nominal model's τ (N, n) and ∂τ/∂s (N, n, 3n)."""

    def __init__(self, setup: Setup):
        arm, nominal = setup.arm, setup.torque_model
        s = arm.symbols
        state = ca.vertcat(s["q"], s["dq"], s["ddq"])
        Yb = s["Y"][:, list(setup.base)] @ ca.diag(ca.DM(setup.scale))
        n, r = Yb.shape
        M = ca.SX.sym("M", n, r)
        self.n, self.r = n, r
        self._columns = _rows(ca.Function("excite_columns", [state], [ca.densify(Yb).T]))
        pull = ca.gradient(ca.sum1(ca.sum2(M * Yb)), state)
        self._pull = _rows(ca.Function("excite_pullback", [ca.vertcat(state, ca.vec(M))], [ca.densify(pull)]))
        t = nominal.symbols
        nominal_state = ca.vertcat(t["q"], t["dq"], t["ddq"])
        tau = nominal.tau_expression(t["q"], t["dq"], t["ddq"], ca.DM(setup.pi_datasheet))
        self._tau = _rows(ca.Function("excite_torques", [nominal_state], [ca.densify(tau)]))
        dtau = ca.densify(ca.jacobian(tau, nominal_state).T)  # dense: the compiled rows are read as full matrices
        self._dtau = _rows(ca.Function("excite_torque_jacobian", [nominal_state], [dtau]))

    def columns(self, S: np.ndarray) -> np.ndarray:
        """Y_B (N, n, r) at states S (N, 3n), the base columns scaled."""
        return self._columns(_at_rest(S, self.n))

    def pullback(self, S: np.ndarray, M: np.ndarray) -> np.ndarray:
        """∂/∂s Σ_jp M_jp Y_B,jp(s) (N, 3n) at states S (N, 3n) for weights M (N, n, r)."""
        flat = np.swapaxes(M, 1, 2).reshape(len(S), -1)  # CasADi's vec: column-major
        return self._pull(np.hstack([_at_rest(S, self.n), flat]))[:, 0, :]

    def torques(self, S: np.ndarray) -> np.ndarray:
        """The nominal model's τ (N, n) [N m] at states S (N, 3n)."""
        return self._tau(_at_rest(S, self.n))[:, 0, :]

    def torque_jacobian(self, S: np.ndarray) -> np.ndarray:
        """∂τ/∂s (N, n, 3n) at states S (N, 3n)."""
        return self._dtau(_at_rest(S, self.n))


def _at_rest(S: np.ndarray, n: int) -> np.ndarray:
    """S with speeds below `STILL` set to 0: the series is at rest at its ends up to the rest constraints' round-off,
    where the Coulomb terms' sign (in the torques and in the regressor) would otherwise follow that round-off from one
    iterate to the next, and IPOPT see a constraint or the objective jump."""
    S = S.copy()
    speeds = S[:, n : 2 * n]
    speeds[np.abs(speeds) < STILL] = 0.0
    return S


def _rows(function: ca.Function):
    """`function` (one sample's input column → one dense output) over many samples: X (N, k) → (N, c, r), each
    output transposed (`cbuild.CompiledRows`); CasADi's evaluation when it cannot be compiled."""
    try:
        return CompiledRows(function, "excitation")
    except (InputError, OSError):
        mapped = {}

        def evaluate(X: np.ndarray) -> np.ndarray:
            f = mapped.setdefault(len(X), function.map(len(X)))
            out = np.asarray(f(np.asarray(X, dtype=float).T))  # (r, c·N): sample k in columns k·c … k·c + c − 1
            r, c = function.size1_out(0), function.size2_out(0)
            return out.reshape(r, len(X), c).transpose(1, 2, 0)

        return evaluate


def criterion_value(criterion: str, Fw: np.ndarray, Fu: np.ndarray) -> tuple[float, np.ndarray]:
    """(value to minimise, its gradient with respect to F (r, r)) of "d": −log det Fw (Fw = Σ Y_Bᵀ W Y_B / N), or of
    "cond": the smooth surrogate ½ log(λ_max/λ_min) ≈ (log tr G^p + log tr G^-p)/(2p) of the equilibrated
    G = E Fu E, E = diag(Fu)^-½, p = `COND_POWER` (its gradient with respect to Fu)."""
    if criterion == "d":
        lam, V = np.linalg.eigh(Fw)
        lam = np.maximum(lam, TINY * max(lam.max(), TINY))
        return -float(np.log(lam).sum()), -(V / lam) @ V.T
    e = 1.0 / np.sqrt(np.maximum(np.diag(Fu), TINY))
    G = Fu * np.outer(e, e)
    lam, V = np.linalg.eigh(G)
    lam = np.maximum(lam, TINY * max(lam.max(), TINY))
    p = COND_POWER
    up, down = (lam / lam.max()) ** p, (lam.min() / lam) ** p  # scaled: the logs take the scales back
    value = (np.log(up.sum()) + p * np.log(lam.max()) + np.log(down.sum()) - p * np.log(lam.min())) / (2 * p)
    dphi = (V * ((up / lam) / up.sum() - (down / lam) / down.sum())) @ V.T / 2  # ∂value/∂G
    # G_kl = Fu_kl e_k e_l with e = Fu_kk^-½: back to Fu
    dF = dphi * np.outer(e, e)
    dF[np.diag_indices_from(dF)] -= e**2 * np.einsum("kl,kl->k", dphi, G)
    return float(value), dF


# ---------------------------------------------------------------------------------------------- numeric callbacks
class NumpyFunction(ca.Callback):
    """x (size) → y (m): a NumPy function `value(x)` as a CasADi function, with `jacobian(x)` (m, size) its
    Jacobian (exact here, so IPOPT calls compiled C through NumPy instead of CasADi's expression interpreter; the
    discrimination design's, central differences with its rivals held)."""

    def __init__(self, name: str, size: int, m: int, value, jacobian, opts: dict | None = None):
        ca.Callback.__init__(self)
        self._size, self._m, self._value, self._jac = size, m, value, jacobian
        self.construct(name, opts or {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._size, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._m, 1)

    def eval(self, arg):
        return [ca.DM(self._value(np.array(arg[0]).ravel()))]

    def has_jacobian(self) -> bool:
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jacobian = _Jacobian(name, self._size, self._m, self._jac, opts)  # kept: CasADi holds no Python ref
        return self._jacobian


class _Jacobian(ca.Callback):
    """(x, y) → ∂y/∂x (m, size) for `NumpyFunction`."""

    def __init__(self, name: str, size: int, m: int, jacobian, opts: dict):
        ca.Callback.__init__(self)
        self._size, self._m, self._jac = size, m, jacobian
        self.construct(name, opts)

    def get_n_in(self) -> int:
        return 2

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._size, 1) if i == 0 else ca.Sparsity.dense(self._m, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._m, self._size)

    def eval(self, arg):
        return [ca.DM(self._jac(np.array(arg[0]).ravel()))]


class _Trajectory:
    """The states along the series at fixed times, and the chain rule back to its coefficients x."""

    def __init__(self, setup: Setup, t: np.ndarray):
        self.f = setup.fourier
        self.B = self.f.basis(t)  # (Bq, Bv, Ba), each (N, 2H + 1)

    def states(self, x: np.ndarray) -> np.ndarray:
        """S (N, 3n) = [q dq ddq] at the times."""
        return np.hstack(self.f.evaluate(x, None, self.B))

    def back(self, V: np.ndarray) -> np.ndarray:
        """Σ_k (∂s_k/∂x)ᵀ v_k for V (N, 3n) (a gradient with respect to the states): (size,)."""
        n = self.f.n_joints
        out = np.zeros(self.f.size)
        for j in range(n):
            sl = self.f.joint_slice(j)
            out[sl] = sum(B.T @ V[:, i * n + j] for i, B in enumerate(self.B))
        return out

    def jacobian(self, D: np.ndarray) -> np.ndarray:
        """(N·m, size) of outputs y_k (m per sample, in sample order) with ∂y_k/∂s_k = D[k] (N, m, 3n)."""
        N, m, _ = D.shape
        n = self.f.n_joints
        out = np.zeros((N, m, self.f.size))
        for j in range(n):
            sl = self.f.joint_slice(j)
            for i, B in enumerate(self.B):
                out[:, :, sl] += D[:, :, i * n + j, None] * B[:, None, :]
        return out.reshape(N * m, self.f.size)


def information_callback(setup: Setup, criterion: str, functions: SampleFunctions | None = None) -> NumpyFunction:
    """x → the NLP objective of `criterion` ("d": −log det F; "cond": the surrogate of log cond) on the
    objective grid (`OBJECTIVE_HZ` over a period), with its exact gradient (`criterion_value`, the pullback)."""
    functions = functions or SampleFunctions(setup)
    path = _Trajectory(setup, _grid(setup, OBJECTIVE_HZ))
    w = 1.0 / setup.sigma**2

    def parts(x):
        S = path.states(x)
        Y = functions.columns(S)  # (N, n, r)
        N = len(S)
        A = Y.reshape(-1, Y.shape[2])
        Fu = A.T @ A / N
        Fw = (A * np.repeat(w[None, :], N, axis=0).reshape(-1, 1)).T @ A / N
        return S, Y, Fw, Fu

    def value(x):
        _, _, Fw, Fu = parts(x)
        return [criterion_value(criterion, Fw, Fu)[0]]

    def gradient(x):
        S, Y, Fw, Fu = parts(x)
        _, dF = criterion_value(criterion, Fw, Fu)
        scale = w[None, :, None] if criterion == "d" else 1.0
        M = (2.0 / len(S)) * scale * (Y @ dF)  # ∂value/∂Y_B per sample (dF symmetric)
        return path.back(functions.pullback(S, M))[None, :]

    return NumpyFunction(f"excite_{criterion}", setup.fourier.size, 1, value, gradient)


def torque_callback(setup: Setup, t: np.ndarray, functions: SampleFunctions | None = None) -> NumpyFunction:
    """x → the nominal model's τ at times t (N·n, sample by sample), with its exact Jacobian."""
    functions = functions or SampleFunctions(setup)
    path = _Trajectory(setup, t)
    n = setup.fourier.n_joints
    return NumpyFunction(
        "excite_torques",
        setup.fourier.size,
        len(t) * n,
        lambda x: functions.torques(path.states(x)).ravel(),
        lambda x: path.jacobian(functions.torque_jacobian(path.states(x))),
    )
