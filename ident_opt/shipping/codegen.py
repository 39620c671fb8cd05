"""Generated C for embedded torque prediction: CasADi expressions → C sources → a shared library.

Three functions, each in CasADi's calling convention (`f(arg, res, iw, w, mem)` plus `f_work`,
`f_incref`, `f_checkout`, ...), all with the identified π baked in as literal constants (q, dq, ddq, τ
have one entry per joint, `Arm.n_joints`):

    tau_hat(q, dq, ddq)     -> tau       τ = M(q) ddq + C(q, dq) dq + G(q) + F(dq)        [N m]
    tau_hat_gmr(q, dq, ddq) -> tau       the same + E[r | x], x = [q; dq; ddq]            [N m]
    ddq_hat(q, dq, tau)     -> ddq       M(q)⁻¹ (τ − C(q, dq) dq − G(q) − F(dq))          [rad/s²]

The rigid part is `Arm.tau_expression` (and `Arm.function` for M), never re-typed here, so the arm
and the extensions the user chose flow through unchanged. The GMR term is a fixed sum of K Gaussians, written
with precomputed constants per component k (Σxx_k = L_k L_kᵀ):

    l_k(x) = log w_k − Σ log diag L_k − ½ ‖L_k⁻¹ (x − μx_k)‖²        (log weight × density, up to a constant)
    m_k(x) = μr_k + A_k (x − μx_k),   A_k = Σrx_k Σxx_k⁻¹            (component conditional mean)
    E[r|x] = Σ_k exp(l_k − l_max) m_k / Σ_k exp(l_k − l_max)         (log-sum-exp: never 0/0 far from data)

Constants are printed by CasADi with 17 significant digits, so they round-trip exactly.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from string import Template

import casadi as ca
import numpy as np

from ident_opt import outputs
from ident_opt.adaptation.c_update import UPDATE_CFLAGS
from ident_opt.arm.base import Arm
from ident_opt.cbuild import (  # noqa: F401  (the toolchain, re-exported for codegen's callers)
    CFLAGS,
    NAME,
    compile_library,
    compile_shared,
    find_compiler,
    generate_sources,
    library_name,
    load_external,
    run_compiler,
)
from ident_opt.columns import kinematic_columns
from ident_opt.errors import InputError


def gmr_inputs(n_joints: int) -> tuple[str, ...]:
    """The GMR inputs x = [q; dq; ddq] by name, in order: q1 … qn, dq1 … dqn, ddq1 … ddqn."""
    return kinematic_columns(n_joints)[1:]


#: Smallest accepted GMR input standard deviation, relative to max(1, |mean|) of that input (rad, rad/s,
#: rad/s²). Below it the component is a near-delta in that input (a column that was constant up to rounding in
#: the training data): its log-density then changes by ~|x|·eps/σ² per ulp of x, so no two implementations
#: (C or Python) agree on it, and a micro-radian is below any encoder's resolution anyway.
MIN_INPUT_STD = 1e-6
#: Non-Python files shipped with the package (README template, example program).
FILES = Path(__file__).with_name("templates")


# ---------------------------------------------------------------------------------------------- GMR term
@dataclass(frozen=True)
class GmrConstants:
    """What the generated GMR mean needs, per component k (d inputs, o outputs).

    mu_x (K, d), mu_r (K, o), L_inv (K, d, d) lower-triangular, A (K, o, d), log_c (K,) = log w_k − ½ log det Σxx_k.
    Units: those of x (rad, rad/s, rad/s²) and r (N m).
    """

    mu_x: np.ndarray
    mu_r: np.ndarray
    L_inv: np.ndarray
    A: np.ndarray
    log_c: np.ndarray

    @property
    def n_components(self) -> int:
        """K, the number of Gaussians."""
        return len(self.log_c)


def gmr_constants(gmr) -> GmrConstants:
    """Precompute the per-component constants from a fitted GMR (`weights_`, `means_`, `covariances_`,
    `n_inputs`, in original units). Raises `InputError` when it cannot be generated (non-finite values,
    a zero weight, an input that barely varies (`MIN_INPUT_STD`), an input covariance that is not
    positive definite)."""
    w = np.asarray(gmr.weights_, dtype=float)
    means = np.asarray(gmr.means_, dtype=float)
    covs = np.asarray(gmr.covariances_, dtype=float)
    d = int(gmr.n_inputs)
    if not (np.isfinite(w).all() and np.isfinite(means).all() and np.isfinite(covs).all()):
        raise InputError("the GMR residual model has non-finite parameters: it cannot be generated")
    if np.any(w <= 0):
        raise InputError("the GMR residual model has a component with zero weight: it cannot be generated")
    std = np.sqrt(np.maximum(np.einsum("kii->ki", covs[:, :d, :d]), 0.0))
    tiny = std < MIN_INPUT_STD * np.maximum(1.0, np.abs(means[:, :d]))
    if tiny.any():
        k, i = np.argwhere(tiny)[0]
        label = gmr_inputs(d // 3)[i] if d % 3 == 0 else f"x{i}"
        raise InputError(
            f"GMR component {k}: input {label} has a standard deviation of {std[k, i]:.3g} "
            f"(mean {means[k, i]:.6g}): the training data barely vary there (a joint at rest?), "
            "so the mixture cannot be evaluated reproducibly; train it on data with motion"
        )
    L_inv, A, log_c = [], [], []
    for k in range(len(w)):
        Sxx, Srx = covs[k, :d, :d], covs[k, d:, :d]
        try:
            L = np.linalg.cholesky(Sxx)
        except np.linalg.LinAlgError:
            raise InputError(
                f"GMR component {k}: input covariance is not positive definite; it cannot be generated"
            ) from None
        Li = np.linalg.solve(L, np.eye(d))
        L_inv.append(np.tril(Li))  # exactly lower-triangular: the zeros are dropped from the C code
        A.append(Srx @ Li.T @ Li)  # Σrx Σxx⁻¹ with Σxx⁻¹ = L⁻ᵀ L⁻¹
        log_c.append(np.log(w[k]) - np.log(np.diag(L)).sum())
    return GmrConstants(means[:, :d], means[:, d:], np.array(L_inv), np.array(A), np.array(log_c))


def gmr_mean_expression(x: ca.SX, c: GmrConstants) -> ca.SX:
    """E[r | x] (o×1) as a CasADi expression of the inputs x (d×1): the module doc's formula."""
    logs, means = [], []
    for k in range(c.n_components):
        dx = x - ca.DM(c.mu_x[k])
        z = ca.mtimes(ca.sparsify(ca.DM(c.L_inv[k])), dx)
        logs.append(c.log_c[k] - 0.5 * ca.sumsqr(z))
        means.append(ca.DM(c.mu_r[k]) + ca.mtimes(ca.DM(c.A[k]), dx))
    top = logs[0]
    for lk in logs[1:]:
        top = ca.fmax(top, lk)
    weights = [ca.exp(lk - top) for lk in logs]  # the largest is exactly 1: the sum is never 0
    total = weights[0]
    for wk in weights[1:]:
        total = total + wk
    mean = weights[0] * means[0]
    for wk, mk in zip(weights[1:], means[1:]):
        mean = mean + wk * mk
    return mean / total


# ---------------------------------------------------------------------------------------------- functions
def build_functions(model: Arm, pi: np.ndarray, gmr=None, forward: bool = True) -> list[ca.Function]:
    """The CasADi Functions to generate: tau_hat, tau_hat_gmr (when `gmr` is given), ddq_hat (when
    `forward`). π (model.n_params,) is baked in as constants."""
    pi = np.asarray(pi, dtype=float).ravel()
    if pi.shape != (model.n_params,):
        raise InputError(f"{pi.size} parameters given, the model {list(model.names)} needs {model.n_params}")
    if not np.isfinite(pi).all():
        raise InputError("the parameters are not all finite: the model cannot be generated")
    n = model.n_joints
    q, dq, ddq, tau = (ca.SX.sym(name, n) for name in ("q", "dq", "ddq", "tau"))
    pi_dm = ca.DM(pi)
    tau_rigid = model.tau_expression(q, dq, ddq, pi_dm)
    out = [ca.Function("tau_hat", [q, dq, ddq], [tau_rigid], ["q", "dq", "ddq"], ["tau"])]
    if gmr is not None:
        c = gmr_constants(gmr)
        if c.mu_x.shape[1] != 3 * n or c.mu_r.shape[1] != n:
            raise InputError(
                f"the GMR must map {3 * n} inputs [q dq ddq] to {n} outputs, got {c.mu_x.shape[1]} → {c.mu_r.shape[1]}"
            )
        r = gmr_mean_expression(ca.vertcat(q, dq, ddq), c)
        out.append(ca.Function("tau_hat_gmr", [q, dq, ddq], [tau_rigid + r], ["q", "dq", "ddq"], ["tau"]))
    if forward:
        # τ − M ddq = C dq + G + F: the bias is τ̂ at ddq = 0, so M⁻¹ (τ − bias) reuses the one model.
        M = model.function("M")(q, dq, ddq, pi_dm)
        bias = model.tau_expression(q, dq, ca.DM.zeros(n), pi_dm)
        out.append(ca.Function("ddq_hat", [q, dq, tau], [solve_ldl(M, tau - bias)], ["q", "dq", "tau"], ["ddq"]))
    return out


def solve_ldl(M: ca.SX, b: ca.SX) -> ca.SX:
    """M⁻¹ b for a symmetric n×n M by LDLᵀ without pivoting, unrolled into scalar expressions: branch-free,
    no work arrays, and backward stable for M ≻ 0 even when it is ill-conditioned (Cramer's rule is not).
    An arm's mass matrix is positive definite, so every pivot d_j > 0. For n = 2: l = M21/M11,
    d2 = M22 − l M21, x2 = (b2 − l b1)/d2, x1 = b1/M11 − l x2.

    u_ij = M_ij − Σ_{k<j} l_jk u_ik (i > j) is L_ij d_j, l_ij = u_ij / d_j, d_j = M_jj − Σ_{k<j} l_jk u_jk;
    then L y = b, and Lᵀ x = D⁻¹ y.
    """
    n = M.shape[0]
    u = [[M[i, j] for j in range(n)] for i in range(n)]
    l = [[None] * n for _ in range(n)]
    d = [None] * n
    for j in range(n):
        d[j] = u[j][j]
        for k in range(j):
            d[j] = d[j] - l[j][k] * u[j][k]
        for i in range(j + 1, n):
            for k in range(j):
                u[i][j] = u[i][j] - l[j][k] * u[i][k]
            l[i][j] = u[i][j] / d[j]
    y = [b[i] for i in range(n)]
    for i in range(n):
        for k in range(i):
            y[i] = y[i] - l[i][k] * y[k]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = y[i] / d[i]
        for k in range(i + 1, n):
            x[i] = x[i] - l[k][i] * x[k]
    return ca.vertcat(*x)


# ---------------------------------------------------------------------------------------------- C files


#: What each generated function does, for the README.
DESCRIPTIONS = {
    "tau_hat": "τ = M(q) ddq + C(q, dq) dq + G(q) + F(dq), the identified rigid-body model with its joint terms "
    "and extensions.",
    "tau_hat_gmr": "`tau_hat` plus the conditional mean E[r | x] of the Gaussian-mixture residual model, "
    "x = [q; dq; ddq] (a fixed sum of Gaussians, evaluated with a log-sum-exp, so it stays finite far from the "
    "training data).",
    "ddq_hat": "forward dynamics ddq = M(q)⁻¹ (τ − C dq − G − F), for on-board simulation (an LDLᵀ solve).",
    "observer_step": "the contact observer, one sample: the external torque τ_ext [N m] from q, dq, τ (a "
    "generalized-momentum observer) and the alarm (0/1), with the thresholds calibrated on the training trials baked "
    "in; the state (zeros before the first sample) is laid out as parameters.json's `observer.state_layout` says; "
    "samples at the calibration's step `observer.dt`.",
}
#: The example's state (q [rad], dq [rad/s], ddq [rad/s²]) for joint j, cycled over the joints.
EXAMPLE_STATE = {"q": (0.3, -0.5, 0.2, -0.1), "dq": (0.8, -0.2, 0.4, -0.6), "ddq": (1.5, 2.0, -1.0, 0.5)}
#: The example's call of tau_hat_gmr, when the library has it.
EXAMPLE_GMR = """  {
    casadi_real tau_gmr[N_JOINTS] = {0.0};
    EVALUATE(tau_hat_gmr, q, dq, ddq, tau_gmr, status);
    if (status != 0) {
      fprintf(stderr, "tau_hat_gmr failed (%d)\\n", status);
      return 1;
    }
    finite = report("tau_hat_gmr", tau_gmr) && finite;
  }"""


# ---------------------------------------------------------------------------------------------- names in the README
# Names (a URDF's joints, its path) are the user's: the README shows them, escaped, and never lets them change the
# document. No name enters the generated C but through `adaptation.c_update.c_string` (pi_update's parameter names);
# the CasADi sources and main.c hold none.

#: What Markdown (or the HTML it allows) reads inside a line: backslash-escaped where a name enters the README's
#: prose, so that it cannot open a link, an image, raw HTML, a code span, emphasis or a table cell. `_` is left as
#: it is: inside a word it is plain text, and ordinary names are full of it.
MARKDOWN_SPECIAL = frozenset("\\`*[]<>&|~!#")
#: Unicode categories shown as a visible escape: controls (a newline would start a new Markdown block), format
#: characters (bidirectional overrides, zero-width), surrogates, private-use and unassigned code points, line and
#: paragraph separators.
INVISIBLE = frozenset(("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"))


def one_line(text: str) -> str:
    """`text` with every `INVISIBLE` character written as a visible \\uXXXX (\\UXXXXXXXX) escape: one line of
    text that shows what it holds."""
    return "".join(
        (f"\\u{ord(ch):04x}" if ord(ch) < 0x10000 else f"\\U{ord(ch):08x}")
        if unicodedata.category(ch) in INVISIBLE
        else ch
        for ch in text
    )


def markdown_text(text: str) -> str:
    """A user's name (or any text from the user's files) as Markdown prose that shows it literally, on the line it
    is on: `one_line`, then each of `MARKDOWN_SPECIAL` backslash-escaped. Ordinary names pass unchanged."""
    return "".join("\\" + ch if ch in MARKDOWN_SPECIAL else ch for ch in one_line(text))


def markdown_code(text: str) -> str:
    """`text` (`one_line`) as one Markdown code span, backticks included: fenced by one backtick more than its
    longest run of them, padded with a space (which Markdown strips) where it starts or ends with one."""
    text = one_line(text)
    fence = "`" * (1 + max((len(run) for run in re.findall("`+", text)), default=0))
    pad = " " if text[:1] in ("`", " ") or text[-1:] in ("`", " ") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


#: The online update's files in the output folder, for the README's table (`update`: `generate.UPDATE_FILES`).
UPDATE_FILES = (
    (
        "`pi_update.c`, `pi_update.h`",
        "the online update: statistics of every sample and the bounded least-squares "
        "re-solve, started from the offline fit baked in (no dynamic allocation; the caller owns `pi_update_state`)",
    ),
    (
        "`pi_update_casadi.c`, `pi_update_casadi.h`",
        "the regressor Y(q, dq, ddq) the update uses (CasADi's code generator)",
    ),
    (
        "`libpi_update.so`",
        "those two sources compiled as a shared library (`cc $update_cflags -shared pi_update.c "
        "pi_update_casadi.c -o libpi_update.so -lm`)",
    ),
    ("`pi_update_main.c`", "an example: replays a CSV of samples through the update and times it"),
    ("`pi_update_example`", "that example compiled (the line below)"),
    (
        "`pi_update_samples.csv`",
        "the samples ident-opt checked the C update on against Python (the held-out part of the first trial)",
    ),
)
#: The README's section on the online update; the compile line is the one `adaptation.c_update.compile_pi_update`
#: runs, plus the warnings the README's other examples use (`tests/test_cli_hostile.py` compiles it as written).
UPDATE_SECTION = """

**The online update (`pi_update`).** `pi_update(&state, q, dq, ddq, tau)` folds one measured sample
in and re-solves the parameters exactly (bounded least squares, warm-started); `pi_update_initial(&state)` starts from
the offline fit baked in. See `pi_update.h`. The example uses POSIX clocks (`clock_gettime`), which `-std=c99`
hides unless `_POSIX_C_SOURCE` says which POSIX it may use:

    $update_compile
    ./pi_update_example pi_update_samples.csv"""
#: The example's compile line in the README.
UPDATE_COMPILE = (
    "cc $update_cflags -D_POSIX_C_SOURCE=199309L -Wall -Wextra -Werror -Wno-unused-parameter pi_update_main.c "
    "pi_update.c pi_update_casadi.c -o pi_update_example -lm"
)


def write_readme(out_dir: Path, functions: list[ca.Function], robot, name: str = NAME, update: bool = False) -> Path:
    """The embedding README (template in `templates/README.md`) for this arm (`robot`: its joints and their
    angle convention, `ident_opt.arm.base.Robot`) and this build's functions (`update`: with the online update's
    files, `pi_update`, and how to build its example). The robot's names are shown escaped (`markdown_text`,
    `markdown_code`), its headline and angle convention on one line each."""
    rows = "\n".join(f"| `{f.name()}` | {_signature(f)} |" for f in functions)
    described = "\n".join(f"- `{f.name()}`: {DESCRIPTIONS[f.name()]}" for f in functions if f.name() in DESCRIPTIONS)
    calls = [f"`{f.name()}`" for f in functions if f.name() in ("tau_hat", "tau_hat_gmr")]
    joints = ", ".join(markdown_text(joint) for joint in robot.joint_names)
    convention = robot.angle_convention
    if robot.joint_names:  # the convention's own list of the joints (a URDF arm's), escaped like the one above
        convention = convention.replace(", ".join(robot.joint_names), joints)
    text = Template((FILES / "README.md").read_text(encoding="utf-8")).substitute(
        name=name,
        library=library_name(name),
        cflags=" ".join(CFLAGS),
        functions=rows,
        descriptions=described,
        robot=markdown_code(robot.headline),
        n=robot.n_joints,
        joints=joints,
        convention=one_line(convention),
        example=" and ".join(calls),
        update_files="".join(f"| {files} | {_flags(what)} |\n" for files, what in UPDATE_FILES) if update else "",
        update_section=_flags(UPDATE_SECTION) if update else "",
    )
    path = Path(out_dir) / "README.md"
    outputs.write_text(path, text)
    return path


def _flags(text: str) -> str:
    """`text` with the online update's compiler flags in place of $update_cflags (before the text joins the README,
    so that nothing from the user's names is ever substituted)."""
    return text.replace("$update_compile", UPDATE_COMPILE).replace("$update_cflags", " ".join(UPDATE_CFLAGS))


def _signature(f: ca.Function) -> str:
    ins = ", ".join(f"{f.name_in(i)}[{f.numel_in(i)}]" for i in range(f.n_in()))
    outs = ", ".join(f"{f.name_out(i)}[{f.numel_out(i)}]" for i in range(f.n_out()))
    return f"`({ins}) -> ({outs})`"


def copy_example(out_dir: Path, n_joints: int, gmr: bool = True) -> Path:
    """The minimal example program `main.c` for an arm of `n_joints` joints (calling tau_hat_gmr too when the
    library has it), next to the generated code."""
    state = {
        key: ", ".join(f"{values[j % len(values)]:g}" for j in range(n_joints)) for key, values in EXAMPLE_STATE.items()
    }
    text = Template((FILES / "main.c").read_text(encoding="utf-8")).substitute(
        n=n_joints, gmr_call=EXAMPLE_GMR if gmr else "", **state
    )
    path = Path(out_dir) / "main.c"
    outputs.write_text(path, text)
    return path


# ---------------------------------------------------------------------------------------------- check


def evaluate(f: ca.Function, *inputs: np.ndarray) -> np.ndarray:
    """Evaluate an (n×1, n×1, n×1) -> n×1 Function on N states at once: inputs (N, n), output (N, n)."""
    n = len(inputs[0])
    return np.asarray(f.map(n)(*(np.asarray(a, dtype=float).T for a in inputs))).T


def relative_error(got: np.ndarray, ref: np.ndarray) -> float:
    """max over samples of ‖got − ref‖∞ / ‖ref‖∞ (per sample, so a small τ is judged on its own scale)."""
    got, ref = np.atleast_2d(got), np.atleast_2d(ref)
    scale = np.max(np.abs(ref), axis=1)
    scale[scale == 0] = 1.0
    return float(np.max(np.max(np.abs(got - ref), axis=1) / scale))


def forward_backward_error(
    model: Arm, pi: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray, ddq: np.ndarray
) -> float:
    """How well `ddq` (N, n) solves M(q) ddq = τ − b, b = C dq + G + F, as a normwise backward error:
    max over samples of ‖M ddq − (τ − b)‖∞ / (‖M‖∞ ‖ddq‖∞ + ‖τ‖∞ + ‖b‖∞). It is small for a correct solve
    however ill-conditioned M is (a forward error would be amplified by cond M), and τ − b is judged on the
    scale of τ and b, since it cancels at rest. M and b come from NumPy."""
    M = model.mass_matrices(pi, q)
    bias = model.predict(pi, q, dq, np.zeros_like(q))
    residual = np.einsum("nij,nj->ni", M, ddq) - (tau - bias)
    scale = (
        np.abs(M).sum(axis=2).max(axis=1) * np.abs(ddq).max(axis=1) + np.abs(tau).max(axis=1) + np.abs(bias).max(axis=1)
    )
    scale[scale == 0] = 1.0
    return float(np.max(np.abs(residual).max(axis=1) / scale))
