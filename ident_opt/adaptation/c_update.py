"""The online update as generated C: `pi_update`, the statistics' rank-n update and the warm-started bounded
least-squares re-solve of `fitting.bounded` (its active-set method, in range-space form on the square-root factor),
with an identifier's state baked in (`UpdateState`), from the C template in `templates/` and the CasADi-generated
regressor. `kernel` attaches it to a Python identifier; `ident-opt codegen` ships it (`shipping.pi_update`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from string import Template

import casadi as ca
import numpy as np

from ident_opt import outputs
from ident_opt.arm.base import Arm
from ident_opt.cbuild import compile_shared, find_compiler, generate_sources, library_name, run_compiler
from ident_opt.errors import InputError

#: The C templates of the update and its example program.
FILES = Path(__file__).with_name("templates")

#: Base names of the generated online update: pi_update.c/.h (statistics + active-set solver, from the template
#: in `templates/`), pi_update_casadi.c/.h (the CasADi-generated regressor), libpi_update.so, the example.
UPDATE = "pi_update"
UPDATE_EXAMPLE = "pi_update_main.c"
#: Flags of the update's library and example: `CFLAGS` with -O3, whose vectorised inner loops (the Givens sweeps)
#: halve the update's time on a 7-joint arm; still ISO C99, so no contraction into FMA changes a result.
UPDATE_CFLAGS = ("-O3", "-std=c99", "-fPIC")


@dataclass(frozen=True)
class UpdateState:
    """What the generated update starts from: the combined normal equations H (P, P), h (P,) of the offline data,
    θ (P,), its active set (P,) (−1 lower, +1 upper, 0 free), the sample count, and the box bounds (P,) each; or,
    instead of H, their square-root factor R (P, P, upper: H = RᵀR), z (P,) = R⁻ᵀh and diag H (`hdiag`), as
    `fitting.bounded.FactorBoundedLS` keeps them (more accurate than a Cholesky factor of H)."""

    H: np.ndarray | None
    h: np.ndarray
    theta: np.ndarray
    state: np.ndarray
    n: int
    lower: np.ndarray
    upper: np.ndarray
    R: np.ndarray | None = None
    z: np.ndarray | None = None
    hdiag: np.ndarray | None = None

    def factor(self, order: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R, z, diag H) in the column order `order`: R upper with a positive diagonal, RᵀR = H[order, order]."""
        if self.R is None:
            H = np.asarray(self.H, dtype=float)[np.ix_(order, order)]
            try:
                R = np.linalg.cholesky(H).T  # upper: H = RᵀR
            except np.linalg.LinAlgError:
                raise InputError(
                    "pi_update: the offline statistics do not determine every parameter (H is not positive "
                    "definite); train on data that excite every parameter"
                ) from None
            return R, np.linalg.solve(R.T, np.asarray(self.h, dtype=float)[order]), np.diag(H).copy()
        Q, R = np.linalg.qr(np.asarray(self.R, dtype=float)[:, order])  # columns permuted: triangular again
        sign = np.where(np.diag(R) < 0, -1.0, 1.0)
        if not np.all(np.abs(np.diag(R)) > 0):
            raise InputError("pi_update: the offline data do not determine every parameter; excite them all")
        return np.triu(R * sign[:, None]), sign * (Q.T @ np.asarray(self.z, dtype=float)), self.hdiag[order]


def c_string(text: str | bytes) -> str:
    """`text` as one C string literal, quotes included, whose bytes are exactly `text`'s (a str as UTF-8, a lone
    surrogate kept as "surrogatepass" writes it). Every name that reaches generated C goes through here: the C must
    hold the name as data, never read any of it as code.

    The literal is plain printable ASCII. Printable ASCII stays as is but for `\\` and `"` (backslash-escaped) and
    `?` (written `\\?`, so that no trigraph such as `??/` can form: ISO C modes replace those before anything else,
    inside string literals too); every other byte (controls, newline, DEL, all of UTF-8's bytes) is a 3-digit octal
    escape `\\ooo`, which, unlike a hex escape, never swallows a digit that follows it. So the literal has no
    newline, no line splice, no non-ASCII character (nothing for a bidirectional-text trick to reorder) and cannot
    end before its closing quote. A NUL byte is kept (`\\000`), but C code that reads the literal as a string stops
    there: refuse such names where that matters. For string literals only: never paste the result into a comment.
    """
    data = text.encode("utf-8", "surrogatepass") if isinstance(text, str) else bytes(text)
    out = ['"']
    for byte in data:
        if byte in b'\\"?':
            out.append("\\" + chr(byte))
        elif 0x20 <= byte < 0x7F:
            out.append(chr(byte))
        else:
            out.append(f"\\{byte:03o}")
    out.append('"')
    return "".join(out)


def _c_numbers(values) -> str:
    out = []
    for v in np.asarray(values, dtype=float).ravel():
        out.append("INFINITY" if v == np.inf else "-INFINITY" if v == -np.inf else f"{v:.17g}")
    return ", ".join(out)


def update_design(model: Arm, columns: tuple[int, ...] | None = None) -> ca.SX:
    """The design the update is about: the columns `columns` of the arm's regressor Y (all when None), J×P dense in
    that order, as a CasADi expression of the arm's symbols."""
    Y = model.symbols["Y"]
    return Y if columns is None else Y[:, list(columns)]


def solver_order(Y: ca.SX) -> list[int]:
    """The update's column order: by the last row (joint) where each column can be non-zero, then by index. A row
    of Y is non-zero only in columns whose last row is at or after its own, so each row's Givens sweep starts after
    every column that ends before it (the last joints' rows, the sparsest, start last)."""
    rows, cols = Y.sparsity().get_triplet()
    last = np.full(Y.shape[1], -1)
    np.maximum.at(last, np.asarray(cols, dtype=int), np.asarray(rows, dtype=int))
    return sorted(range(Y.shape[1]), key=lambda c: (last[c], c))


def _reflect_kernels(n_rows: int) -> str:
    """C of the update's Householder kernels (pi_update.c.in: one per number a of regressor rows taking part, each a
    single pass over the columns with the a rows unrolled) and of `reflect`, which picks one."""
    out = []
    for a in range(1, n_rows + 1):
        rows = ", ".join(f"double *restrict y{j}" for j in range(a))
        w = " + ".join(["v0 * s"] + [f"c[{j}] * y{j}[i]" for j in range(a)])
        updates = " ".join(f"y{j}[i] -= d[{j}] * w;" for j in range(a))
        out.append(
            f"static void reflect{a}(double *restrict dst, const double *restrict src, {rows}, const double *c,\n"
            f"                     const double *d, double v0, double bv, int n) {{\n"
            f"  for (int i = 0; i < n; ++i) {{\n"
            f"    double s = src[i], w = {w};\n"
            f"    dst[i] = s - bv * w;\n"
            f"    {updates}\n"
            f"  }}\n"
            f"}}\n"
        )
    cases = "\n".join(
        f"    case {a}: reflect{a}(dst, src, {', '.join(f'rows[{j}]' for j in range(a))}, c, d, v0, bv, n); break;"
        for a in range(1, n_rows + 1)
    )
    out.append(
        "static void reflect(int a, double *dst, const double *src, double **rows, const double *c, const double *d,\n"
        "                    double v0, double bv, int n) {\n"
        f"  switch (a) {{\n{cases}\n    default: break;\n  }}\n}}\n"
    )
    return "\n".join(out)


def generate_pi_update(
    model: Arm, start: UpdateState, out_dir: Path, kkt_tol: float, columns: tuple[int, ...] | None = None
) -> list[Path]:
    """Write pi_update.c/.h (the template with `start` baked in: the square-root information factor R of H in the
    solver's column order — `solver_order`, the parameters held at a bound last — z = R⁻ᵀ h, diag H) and
    pi_update_casadi.c/.h (the regressor's columns `columns`, all when
    None: Y(q, dq, ddq) (J×P, dense) by CasADi's code generator) into `out_dir`; returns the paths."""
    out_dir = Path(out_dir)
    s = model.symbols
    Y = update_design(model, columns)
    names = model.names if columns is None else tuple(model.names[i] for i in columns)
    for name in names:
        if "\0" in name:
            raise InputError(
                f"pi_update: the parameter name {name!r} holds a NUL character, which C cannot hold in a name"
            )
    f = ca.Function("pi_regressor", [s["q"], s["dq"], s["ddq"]], [ca.densify(Y)], ["q", "dq", "ddq"], ["Y"])
    casadi_c, casadi_h = generate_sources([f], out_dir, name=f"{UPDATE}_casadi")
    held = np.asarray(start.state) != 0
    order = [k for k in solver_order(Y) if not held[k]] + [k for k in solver_order(Y) if held[k]]
    R, z, hdiag = start.factor(order)
    h = np.asarray(start.h, dtype=float)[order]
    values = {
        "n_params": len(names),
        "n_joints": model.n_joints,
        "kkt_tol": f"{kkt_tol:.17g}",
        "lower": _c_numbers(start.lower),
        "upper": _c_numbers(start.upper),
        "R0": _c_numbers(np.triu(R)),
        "z0": _c_numbers(z),
        "h0": _c_numbers(h),
        "hdiag0": _c_numbers(hdiag),
        "order": ", ".join(str(int(k)) for k in order),
        "m0": str(int(held.sum())),
        "theta0": _c_numbers(start.theta),
        "state0": ", ".join(str(int(v)) for v in start.state),
        "n0": str(int(start.n)),
        "names": ", ".join(c_string(n) for n in names),  # escaped: a name is data, never code
        "kernels": _reflect_kernels(model.n_joints),
    }
    paths = [casadi_c, casadi_h]
    for suffix in ("c", "h"):
        text = Template((FILES / f"{UPDATE}.{suffix}.in").read_text(encoding="utf-8")).substitute(values)
        path = out_dir / f"{UPDATE}.{suffix}"
        outputs.write_text(path, text)
        paths.append(path)
    columns_text = ",".join(f"{k}{j + 1}" for k in ("q", "dq", "ddq", "tau") for j in range(model.n_joints))
    example = Template((FILES / UPDATE_EXAMPLE).read_text(encoding="utf-8")).substitute(columns=columns_text)
    path = out_dir / UPDATE_EXAMPLE
    outputs.write_text(path, example)
    paths.append(path)
    return paths


def compile_pi_update(out_dir: Path, compiler: list[str] | None = None) -> tuple[Path, Path]:
    """The shared library libpi_update.so and the example program `pi_update_example`, built with `UPDATE_CFLAGS`."""
    compiler = list(compiler or find_compiler())
    out_dir = Path(out_dir)
    sources = [str(out_dir / f"{UPDATE}.c"), str(out_dir / f"{UPDATE}_casadi.c")]
    lib = compile_shared(sources, out_dir / library_name(UPDATE), compiler, UPDATE_CFLAGS)
    exe = out_dir / f"{UPDATE}_example"
    example = str(out_dir / UPDATE_EXAMPLE)
    run_compiler(
        [*compiler, *UPDATE_CFLAGS, "-D_POSIX_C_SOURCE=199309L", example, *sources, "-o", str(exe), "-lm"],
        compiler[0],
    )
    return lib, exe
