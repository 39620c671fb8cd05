"""The bounded online update in generated C, for the Python online path (`OnlineIdentifier.add`).

`attach(identifier)` generates `pi_update` (`codegen.generate_pi_update`) with the identifier's current state
(normal equations, θ, active set, bounds) baked in, compiles it into a temporary folder, loads it with ctypes and
makes the identifier's H, h and θ views of the C state, so each `add` is one C call: the rank-J statistics update,
the warm-started bounded re-solve (the same active-set method as `identify.bounded.solve_bounded`) and the running
mean square of the one-step residual. All or nothing: a refused sample leaves the state as it was. Without a C
compiler (or for another estimator) nothing is attached and the NumPy path is used.
"""

from __future__ import annotations

import ctypes
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ident_opt import codegen
from ident_opt.errors import InputError
from ident_opt.identify.bounded import KKT_TOL


class Kernel:
    """A loaded `pi_update` library and its state (a ctypes structure the caller owns)."""

    def __init__(self, library: Path, n_params: int, n_joints: int = 2):
        P = n_params

        class State(ctypes.Structure):
            _fields_ = [
                ("H", ctypes.c_double * (P * P)),
                ("h", ctypes.c_double * P),
                ("theta", ctypes.c_double * P),
                ("state", ctypes.c_byte * P),
                ("n", ctypes.c_long),
                ("iterations", ctypes.c_long),
            ]

        self.lib = ctypes.CDLL(str(Path(library).resolve()))
        self.state = State()
        self.lib.pi_update_initial(ctypes.byref(self.state))
        self.address = ctypes.addressof(self.state)
        self.rows = self.lib.pi_update_rows
        self.rows.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double]
        self.rows.restype = ctypes.c_int
        self.H = np.ctypeslib.as_array(self.state.H).reshape(P, P)  # views: the C update writes them in place
        self.h = np.ctypeslib.as_array(self.state.h)
        self.theta = np.ctypeslib.as_array(self.state.theta)
        self.D, self.tau = np.zeros((n_joints, P)), np.zeros(n_joints)  # one sample's rows and torques
        self.D_address, self.tau_address = self.D.ctypes.data, self.tau.ctypes.data


def attach(identifier, model, compiler: list[str] | None = None) -> bool:
    """Give a bounded `OnlineIdentifier` (on `model`'s regressor) the generated C update; False (and nothing
    changed) when the estimator is not bounded or no C compiler is available."""
    if identifier.estimator.kind != "bounded" or identifier._solve is None:
        return False
    try:
        compiler = list(compiler or codegen.find_compiler())
    except InputError:
        return False
    solver = identifier._solve.__self__
    bounds = identifier.estimator.bounds
    start = codegen.UpdateState(
        identifier._H.copy(),
        identifier._h.copy(),
        identifier.theta.copy(),
        solver.last.state.copy() if solver.last is not None else np.zeros(model.n_params, dtype=np.int8),
        identifier.n_updates,
        bounds.lower,
        bounds.upper,
    )
    folder = Path(tempfile.mkdtemp(prefix="ident_opt_update_"))
    try:
        codegen.generate_pi_update(model, start, folder, KKT_TOL)
        sources = [str(folder / f"{codegen.UPDATE}.c"), str(folder / f"{codegen.UPDATE}_casadi.c")]
        library = codegen.compile_shared(sources, folder / codegen.library_name(codegen.UPDATE), compiler)
        kernel = Kernel(library, model.n_params, model.n_joints)  # loaded: the file may go
    except InputError:
        return False
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    identifier.use_kernel(kernel)
    return True
