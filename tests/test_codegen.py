"""Generated C (ident_opt.shipping.codegen): compiled once per module with gcc, called through ctypes, compared
with the Python model (NumPy regressor + GMR) on thousands of random states."""

from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.special import logsumexp
from scipy.stats import multivariate_normal

from ident_opt.arm.planar import PlanarArm
from ident_opt.errors import InputError
from ident_opt.models.gmr import GMR
from ident_opt.problem import load_problem
from ident_opt.shipping import codegen

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

MODEL = PlanarArm(extensions=("armature", "asymmetric_coulomb"))
#: A physically plausible π for MODEL (a [kg m²], b [N m], friction ≥ 0), distinct per-direction Coulomb.
PI = MODEL.vector(
    {
        "a1": 0.81,
        "a2": 0.013,
        "a3": 0.011,
        "b1": 3.76,
        "b2": 0.30,
        "fv1": 1.56,
        "fv2": 0.015,
        "ia2": 0.004,
        "fc1p": 0.58,
        "fc1n": 0.41,
        "fc2p": 0.38,
        "fc2n": 0.52,
    }
)
N = 5000


def _states(rng: np.random.Generator, n: int = N) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random states; a tenth with dq exactly 0 on one joint, where the friction terms switch."""
    q = rng.uniform(-np.pi, np.pi, (n, 2))
    dq = rng.normal(0.0, 1.5, (n, 2))
    ddq = rng.normal(0.0, 4.0, (n, 2))
    dq[: n // 10, rng.integers(0, 2)] = 0.0
    return q, dq, ddq


@pytest.fixture(scope="module")
def gmr() -> GMR:
    """A K = 4 GMR fitted on a smooth synthetic residual of x = [q dq ddq]."""
    rng = np.random.default_rng(1)
    X = np.hstack(_states(rng, 1500))
    R = np.column_stack([0.3 * np.sin(X[:, 0]) + 0.05 * X[:, 2], 0.2 * np.cos(X[:, 1]) * X[:, 3]])
    return GMR(n_components=4).fit(X, R + 0.01 * rng.normal(size=R.shape))


@pytest.fixture(scope="module")
def built(tmp_path_factory, gmr):
    """Generate and compile once: (folder, library path, ctypes handle)."""
    out = tmp_path_factory.mktemp("codegen")
    functions = codegen.build_functions(MODEL, PI, gmr)
    source, _ = codegen.generate_sources(functions, out)
    lib = codegen.compile_library(source, out, [shutil.which("gcc")])
    codegen.copy_example(out, MODEL.n_joints)
    codegen.write_readme(out, functions, load_problem(ROOT / "problems" / "tudor_2dof.toml").robot)
    return out, lib, ctypes.CDLL(str(lib))


class CFunction:
    """One CasADi-convention entry point called through ctypes, work arrays sized by <name>_work."""

    def __init__(self, handle: ctypes.CDLL, name: str):
        assert handle.ident_opt_model_casadi_int_size() == ctypes.sizeof(ctypes.c_longlong)
        assert handle.ident_opt_model_casadi_real_size() == ctypes.sizeof(ctypes.c_double)
        sizes = [ctypes.c_longlong() for _ in range(4)]
        assert getattr(handle, f"{name}_work")(*(ctypes.byref(s) for s in sizes)) == 0
        n_arg, n_res, n_iw, n_w = (s.value for s in sizes)
        self.f = getattr(handle, name)
        self.f.restype = ctypes.c_int
        self.inputs = [(ctypes.c_double * 2)() for _ in range(3)]
        self.output = (ctypes.c_double * 2)()
        self.arg = (ctypes.POINTER(ctypes.c_double) * max(n_arg, 1))(
            *(ctypes.cast(a, ctypes.POINTER(ctypes.c_double)) for a in self.inputs)
        )
        self.res = (ctypes.POINTER(ctypes.c_double) * max(n_res, 1))(
            ctypes.cast(self.output, ctypes.POINTER(ctypes.c_double))
        )
        self.iw = (ctypes.c_longlong * max(n_iw, 1))()
        self.w = (ctypes.c_double * max(n_w, 1))()
        getattr(handle, f"{name}_incref")()
        self.mem = getattr(handle, f"{name}_checkout")()

    def __call__(self, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Inputs (N, 2) each → output (N, 2), one C call per row."""
        out = np.empty((len(a), 2))
        for k in range(len(a)):
            for buf, value in zip(self.inputs, (a[k], b[k], c[k])):
                buf[0], buf[1] = value
            assert self.f(self.arg, self.res, self.iw, self.w, self.mem) == 0
            out[k] = self.output[0], self.output[1]
        return out


def test_tau_hat_matches_python_model_with_extensions(built):
    q, dq, ddq = _states(np.random.default_rng(2))
    got = CFunction(built[2], "tau_hat")(q, dq, ddq)
    assert codegen.relative_error(got, MODEL.predict(PI, q, dq, ddq)) <= 1e-12


def test_asymmetric_coulomb_reaches_the_c_code(built):
    """Opposite velocities at the same pose: friction differs by (fc1p − fc1n) + 2 fv1 |dq1| at joint 1."""
    f = CFunction(built[2], "tau_hat")
    q, ddq = np.zeros((1, 2)), np.zeros((1, 2))
    up, down = f(q, np.array([[0.5, 0.0]]), ddq), f(q, np.array([[-0.5, 0.0]]), ddq)
    fc1p, fc1n, fv1 = (PI[MODEL.names.index(n)] for n in ("fc1p", "fc1n", "fv1"))
    assert up[0, 0] - down[0, 0] == pytest.approx(fc1p + fc1n + 2 * fv1 * 0.5, rel=1e-13)


def test_tau_hat_gmr_matches_python_model_plus_gmr(built, gmr):
    q, dq, ddq = _states(np.random.default_rng(3))
    got = CFunction(built[2], "tau_hat_gmr")(q, dq, ddq)
    ref = MODEL.predict(PI, q, dq, ddq) + gmr.predict_mean(np.hstack([q, dq, ddq]))
    assert codegen.relative_error(got, ref) <= 1e-10


def _direct_gmr_mean(gmr: GMR, X: np.ndarray) -> np.ndarray:
    """E[r | x] straight from the definition (scipy densities in log form, normalised by logsumexp)."""
    d = gmr.n_inputs
    logs, means = [], []
    for w, mu, S in zip(gmr.weights_, gmr.means_, gmr.covariances_):
        logs.append(np.log(w) + multivariate_normal(mu[:d], S[:d, :d]).logpdf(X))
        means.append(mu[d:] + (X - mu[:d]) @ np.linalg.solve(S[:d, :d], S[:d, d:]))
    logs = np.array(logs)
    h = np.exp(logs - logsumexp(logs, axis=0))
    return np.einsum("kn,kno->no", h, np.array(means))


def test_gmr_term_is_finite_and_right_far_from_the_data(built, gmr):
    """Where every Gaussian density underflows to 0 in double precision, the log-sum-exp keeps it exact."""
    q, dq, ddq = _states(np.random.default_rng(4), 500)
    q, dq, ddq = 40 * q, 40 * dq, 40 * ddq
    X = np.hstack([q, dq, ddq])
    assert np.all(multivariate_normal(gmr.means_[0, :6], gmr.covariances_[0, :6, :6]).pdf(X[:50]) == 0)
    got = CFunction(built[2], "tau_hat_gmr")(q, dq, ddq) - MODEL.predict(PI, q, dq, ddq)
    assert np.isfinite(got).all()
    ref = _direct_gmr_mean(gmr, X)
    assert np.max(np.abs(got - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_ddq_hat_inverts_the_model(built):
    q, dq, ddq = _states(np.random.default_rng(5))
    tau = MODEL.predict(PI, q, dq, ddq)
    got = CFunction(built[2], "ddq_hat")(q, dq, tau)
    assert codegen.forward_backward_error(MODEL, PI, q, dq, tau, got) <= 1e-13
    M = MODEL.mass_matrix(PI, q[:, 1])
    assert np.max(np.linalg.cond(M)) < 1e4  # well-conditioned here, so the forward error is small too
    assert codegen.relative_error(got, ddq) <= 1e-10


def test_standard_casadi_entry_points(built):
    handle = built[2]
    for name, inputs in (("tau_hat", "q dq ddq"), ("tau_hat_gmr", "q dq ddq"), ("ddq_hat", "q dq tau")):
        getattr(handle, f"{name}_n_in").restype = ctypes.c_longlong
        getattr(handle, f"{name}_name_in").restype = ctypes.c_char_p
        getattr(handle, f"{name}_name_out").restype = ctypes.c_char_p
        getattr(handle, f"{name}_sparsity_in").restype = ctypes.POINTER(ctypes.c_longlong)
        assert getattr(handle, f"{name}_n_in")() == 3
        names = [getattr(handle, f"{name}_name_in")(ctypes.c_longlong(i)).decode() for i in range(3)]
        assert names == inputs.split()
        assert getattr(handle, f"{name}_name_out")(ctypes.c_longlong(0)).decode() in ("tau", "ddq")
        sp = getattr(handle, f"{name}_sparsity_in")(ctypes.c_longlong(0))
        assert (sp[0], sp[1]) == (2, 1)  # a dense 2×1 column
        for entry in ("incref", "decref", "checkout", "release", "work", "work_bytes", "n_out"):
            assert hasattr(handle, f"{name}_{entry}")


def test_casadi_external_loads_the_library(built):
    """The library also loads back into CasADi (the CLI's self-check uses this path)."""
    q, dq, ddq = _states(np.random.default_rng(6), 200)
    got = codegen.evaluate(codegen.load_external(built[1], "tau_hat"), q, dq, ddq)
    assert codegen.relative_error(got, MODEL.predict(PI, q, dq, ddq)) <= 1e-12


def test_example_main_c_compiles_strictly_and_runs(built):
    out = built[0]
    exe = out / "example"
    cmd = [
        "gcc",
        "-O2",
        "-std=c99",
        "-Wall",
        "-Wextra",
        "-Werror",
        "main.c",
        "-L.",
        "-lident_opt_model",
        "-Wl,-rpath,.",
        "-o",
        str(exe),
        "-lm",
    ]
    subprocess.run(cmd, cwd=out, check=True, capture_output=True)
    done = subprocess.run([str(exe)], cwd=out, check=True, capture_output=True, text=True)
    printed = {
        m[0]: np.array([float(m[1]), float(m[2])])
        for m in re.findall(r"(tau_hat\w*)\s*= \[([^,]+), ([^\]]+)\]", done.stdout)
    }
    src = (out / "main.c").read_text()
    state = [
        np.array([[float(v) for v in re.search(rf"{n}\[N_JOINTS\] = {{([^}}]+)}}", src)[1].split(",")]])
        for n in ("q", "dq", "ddq")
    ]
    assert codegen.relative_error(printed["tau_hat"], MODEL.predict(PI, *state)) <= 1e-12
    assert set(printed) == {"tau_hat", "tau_hat_gmr"}


def test_generated_source_compiles_cleanly_as_the_readme_says(built):
    out = built[0]
    cmd = [
        "gcc",
        "-std=c99",
        "-Wall",
        "-Wextra",
        "-Wno-unused-parameter",
        "-Werror",
        "-pedantic",
        "-c",
        "ident_opt_model.c",
        "-o",
        "model.o",
    ]
    subprocess.run(cmd, cwd=out, check=True, capture_output=True)
    readme = (out / "README.md").read_text()
    assert "-Wno-unused-parameter" in readme and "`tau_hat_gmr`" in readme and "$" not in readme


def test_no_dynamic_allocation_and_no_mutable_state_in_the_generated_code(built):
    """What the README promises: no heap, and every file-scope variable is const (so calls are reentrant)."""
    source = (built[0] / "ident_opt_model.c").read_text()
    assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", source)
    file_scope = [
        line
        for line in source.splitlines()  # declarations at file scope, not functions
        if line.rstrip().endswith(";")
        and "(" not in line.split("=")[0]
        and not line.startswith((" ", "\t", "#", "/", "}", "*", "typedef"))
    ]
    assert file_scope  # the sparsity patterns, at least: the filter sees declarations
    assert all(" const " in f" {line} " for line in file_scope), file_scope


# ---------------------------------------------------------------------------------------------- bad input
def test_nonfinite_parameters_cannot_be_generated():
    with pytest.raises(InputError, match="finite"):
        codegen.build_functions(MODEL, np.full(MODEL.n_params, np.nan))


def test_wrong_number_of_parameters_is_an_input_error():
    with pytest.raises(InputError, match="needs 12"):
        codegen.build_functions(MODEL, np.ones(9))


def _gmr_like(gmr: GMR, covariances: np.ndarray):
    """A GMR-shaped object with the fitted weights and means and other covariances."""

    class Fake:
        weights_, means_, covariances_, n_inputs = gmr.weights_, gmr.means_, covariances, 6

    return Fake()


def test_gmr_with_singular_input_covariance_is_an_input_error(gmr):
    rank_one = np.broadcast_to(np.ones((8, 8)), gmr.covariances_.shape)  # unit variances, perfectly correlated
    with pytest.raises(InputError, match="not positive definite"):
        codegen.build_functions(MODEL, PI, _gmr_like(gmr, rank_one))


def test_gmr_with_a_constant_input_is_an_input_error(gmr):
    """A joint at rest in the training data: q2 variance at rounding level (as on exp1's first 15 s)."""
    covs = gmr.covariances_.copy()
    covs[1, 1, :], covs[1, :, 1] = 0.0, 0.0
    covs[1, 1, 1] = 2e-31
    with pytest.raises(InputError, match="input q2 has a standard deviation"):
        codegen.build_functions(MODEL, PI, _gmr_like(gmr, covs))


def test_missing_compiler(monkeypatch):
    monkeypatch.setenv("CC", "no-such-compiler-xyz")
    with pytest.raises(InputError, match="no-such-compiler-xyz"):
        codegen.find_compiler()
    monkeypatch.setenv("CC", "gcc -m64")  # a command with arguments, as make would pass it
    assert codegen.find_compiler() == [shutil.which("gcc"), "-m64"]
    monkeypatch.delenv("CC")
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.raises(InputError, match="no C compiler"):
        codegen.find_compiler()


def test_ldl_solve_of_any_size():
    """The unrolled LDLᵀ of ddq_hat solves M x = b for n×n symmetric positive definite M (n = 1 … 4)."""
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4):
        A = rng.normal(size=(n, n))
        M, b = A @ A.T + 0.1 * np.eye(n), rng.normal(size=n)
        Ms, bs = ca.SX.sym("M", n, n), ca.SX.sym("b", n)
        x = np.asarray(ca.Function("f", [Ms, bs], [codegen.solve_ldl(Ms, bs)])(M, b)).ravel()
        np.testing.assert_allclose(M @ x, b, rtol=1e-12, atol=1e-12)


def test_gmr_input_names_follow_the_number_of_joints():
    assert codegen.gmr_inputs(2) == ("q1", "q2", "dq1", "dq2", "ddq1", "ddq2")
    assert codegen.gmr_inputs(3) == ("q1", "q2", "q3", "dq1", "dq2", "dq3", "ddq1", "ddq2", "ddq3")
