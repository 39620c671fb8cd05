"""The bounded online update in generated C, for the Python online path (`OnlineIdentifier.add`).

`attach(identifier, design)` generates `pi_update` (`c_update.generate_pi_update`) with the identifier's current
state (normal equations, θ, active set, bounds) baked in, compiles it into a temporary folder, loads it with ctypes
and makes the identifier's θ a view of the C state, so each `add` is one C call: the rank-J update of the
statistics' square-root factor, the warm-started bounded re-solve (the active-set method of
`fitting.bounded.solve_bounded`, in range-space form on the factor) and the running mean square of the one-step
residual. All or nothing: a refused sample leaves the state as it was. Without a C compiler (or for another
estimator) nothing is attached and the NumPy path is used.
"""

from __future__ import annotations

import ctypes
import shutil
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from ident_opt.adaptation import c_update
from ident_opt.cbuild import compile_shared, find_compiler, generate_sources, library_name
from ident_opt.errors import InputError
from ident_opt.fitting.bounded import KKT_TOL
from ident_opt.models.gmr import conditioning


def load_pi_update(library: Path, n_params: int) -> tuple[ctypes.CDLL, ctypes.Structure]:
    """The compiled `pi_update` library and its state, initialised to the offline start: the C struct of
    pi_update.h {R (2 buffers of P×P), cur, m, order (P), z, h, diag H (P each), θ (P), active-set state (P), n,
    iterations} as ctypes, in one place."""
    P = n_params

    class State(ctypes.Structure):
        _fields_ = [
            ("R", ctypes.c_double * (2 * P * P)),
            ("cur", ctypes.c_int),
            ("m", ctypes.c_int),
            ("order", ctypes.c_int * P),
            ("z", ctypes.c_double * P),
            ("h", ctypes.c_double * P),
            ("hdiag", ctypes.c_double * P),
            ("theta", ctypes.c_double * P),
            ("state", ctypes.c_byte * P),
            ("n", ctypes.c_long),
            ("iterations", ctypes.c_long),
        ]

    lib = ctypes.CDLL(str(Path(library).resolve()))
    state = State()
    lib.pi_update_initial(ctypes.byref(state))
    return lib, state


class Kernel:
    """A loaded `pi_update` library and its state (a ctypes structure the caller owns)."""

    def __init__(self, library: Path, n_params: int, n_joints: int = 2):
        P = n_params
        self.lib, self.state = load_pi_update(library, P)
        self.address = ctypes.addressof(self.state)
        self.rows = self.lib.pi_update_rows
        self.rows.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double]
        self.rows.restype = ctypes.c_int
        self.theta = np.ctypeslib.as_array(self.state.theta)  # a view: the C update writes it in place
        self.D, self.tau = np.zeros((n_joints, P)), np.zeros(n_joints)  # one sample's rows and torques
        self.D_address, self.tau_address = self.D.ctypes.data, self.tau.ctypes.data


def predictor_function(identifier, design) -> ca.Function:
    """pi_step(q, dq, ddq, theta, pvar) -> (Yt, tau, std, logp, parametric): one sample's regressor (as Yᵀ, P×J, i.e.
    Y row-major), the hybrid prediction with its standard deviation and the GMR input log-density, exactly the
    formulas of `OnlineIdentifier.predict` (mean-only consistency transform from θ, extrapolation guard if any),
    as a CasADi expression for code generation. The identifier must have a GMR (without cross-covariance); `design`:
    its `online.ArmDesign` (an arm and the columns of its regressor θ is about)."""
    s = design.arm.symbols
    q, dq, ddq = s["q"], s["dq"], s["ddq"]
    theta, pvar = ca.SX.sym("theta", len(design.names)), ca.SX.sym("pvar", design.n_joints)
    Y = design.expression()
    parametric = ca.mtimes(Y, theta)
    fast, gmr = identifier._fast, identifier.gmr0
    d = gmr.n_inputs
    c = conditioning(gmr.weights_, gmr.means_, gmr.covariances_, d)
    x = ca.vertcat(q, dq, ddq)
    delta = theta - ca.DM(identifier.theta0)
    logs, means = [], []
    for k in range(fast.K):
        dx = x - ca.DM(c.mu_x[k])
        z = ca.mtimes(ca.DM(c.W[k]).T, dx)
        logs.append(c.log_norm[k] - 0.5 * ca.sumsqr(z))
        mu_r = ca.DM(c.mu_r[k]) - ca.mtimes(ca.DM(identifier._design_at_means[k]), delta)
        means.append(mu_r + ca.mtimes(ca.DM(c.A[k]), dx))
    top = logs[0]
    for lk in logs[1:]:
        top = ca.fmax(top, lk)
    e = [ca.exp(lk - top) for lk in logs]
    total = sum(e[1:], e[0])
    mean = sum((ek * mk for ek, mk in zip(e[1:], means[1:])), e[0] * means[0]) / total
    var = (
        sum(
            (ek * (ca.DM(fast.C_diag[k]) + (mk - mean) ** 2) for k, (ek, mk) in enumerate(zip(e, means))),
            ca.DM.zeros(design.n_joints),
        )
        / total
    )
    logp = top + ca.log(total)
    support = identifier.support
    if support is not None:
        w = ca.if_else(logp >= support.threshold, 1.0, ca.exp(-(support.threshold - logp) / support.width))
        shrunk = w * mean
        var = w * (var + mean * mean) + (1 - w) * pvar - shrunk * shrunk
        mean = shrunk
    std = ca.sqrt(ca.fmax(var, 0.0))
    return ca.Function(
        "pi_step",
        [q, dq, ddq, theta, pvar],
        [Y.T, parametric + mean, std, logp, parametric],
        ["q", "dq", "ddq", "theta", "pvar"],
        ["Yt", "tau", "std", "logp", "parametric"],
    )


class Predictor:
    """The generated `pi_step` (`predictor_function`) bound to a kernel's θ and an identifier's residual variance:
    `__call__(q, dq, ddq)` fills `Yt` (one sample's regressor, row-major), `tau`, `std`, `logp`, `parametric`."""

    def __init__(self, lib: ctypes.CDLL, kernel: Kernel, pvar: np.ndarray):
        self.fn = lib.pi_step
        self.fn.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        self.fn.restype = ctypes.c_int
        P, J = kernel.theta.size, kernel.tau.size
        self.x = np.zeros(3 * J)
        self.Yt, self.tau, self.std, self.logp, self.par = kernel.D, np.zeros(J), np.zeros(J), np.zeros(1), np.zeros(J)
        self.J = J
        ins = [self.x.ctypes.data + 8 * J * i for i in range(3)] + [kernel.theta.ctypes.data, pvar.ctypes.data]
        outs = [a.ctypes.data for a in (self.Yt, self.tau, self.std, self.logp, self.par)]
        self._keep = [np.array(ins, dtype=np.uintp), np.array(outs, dtype=np.uintp)]
        sizes = (ctypes.c_longlong * 4)()
        lib.pi_step_work(
            ctypes.byref(sizes, 0), ctypes.byref(sizes, 8), ctypes.byref(sizes, 16), ctypes.byref(sizes, 24)
        )
        self.iw = np.zeros(max(int(sizes[2]), 1), dtype=np.int64)
        self.w = np.zeros(max(int(sizes[3]), 1))
        self.args = (self._keep[0].ctypes.data, self._keep[1].ctypes.data, self.iw.ctypes.data, self.w.ctypes.data, 0)
        self.assert_P = P

    def __call__(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> int:
        J = self.J
        self.x[:J], self.x[J : 2 * J], self.x[2 * J :] = q, dq, ddq
        return self.fn(*self.args)


def update_state(ident) -> c_update.UpdateState:
    """The state of a bounded online identifier (NumPy path), for `c_update.generate_pi_update`: its normal
    equations, or its square-root factor (a ``factor`` estimator)."""
    bounds = ident.estimator.bounds
    common = {"theta": ident.theta.copy(), "n": ident.stats.n, "lower": bounds.lower, "upper": bounds.upper}
    factor = ident._factor
    if factor is not None:  # R, z and diag H as the factor keeps them; no H
        return c_update.UpdateState(
            H=None,
            h=factor.h.copy(),
            state=factor.last.state.copy(),
            R=factor.R.copy(),
            z=factor.z.copy(),
            hdiag=factor.hdiag.copy(),
            **common,
        )
    solver = ident._solve.__self__  # WarmBoundedLS: its last active set
    return c_update.UpdateState(H=ident._H.copy(), h=ident._h.copy(), state=solver.last.state.copy(), **common)


def attach(identifier, design, compiler: list[str] | None = None) -> bool:
    """Give a bounded `OnlineIdentifier` (on `design`, an `online.ArmDesign`: columns of an arm's regressor) the
    generated C update; False (and nothing changed) when the estimator is not bounded or no C compiler is
    available."""
    if identifier.estimator.kind not in ("bounded", "factor"):
        return False
    try:
        compiler = list(compiler or find_compiler())
    except InputError:
        return False
    start = update_state(identifier)
    folder = Path(tempfile.mkdtemp(prefix="ident_opt_update_"))
    try:
        c_update.generate_pi_update(design.arm, start, folder, KKT_TOL, design.columns)
        sources = [str(folder / f"{c_update.UPDATE}.c"), str(folder / f"{c_update.UPDATE}_casadi.c")]
        predicts = identifier._fast is not None
        if predicts:
            step_c, _ = generate_sources([predictor_function(identifier, design)], folder, name="pi_step")
            sources.append(str(step_c))
        library = compile_shared(sources, folder / library_name(c_update.UPDATE), compiler, c_update.UPDATE_CFLAGS)
        kernel = Kernel(library, len(design.names), design.n_joints)  # loaded: the file may go
    except InputError:
        return False
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    identifier.use_kernel(kernel)
    if predicts:
        identifier.use_predictor(Predictor(kernel.lib, kernel, identifier.parametric_var))
    return True
