"""Bounded nonlinear least squares with CasADi + IPOPT: fit the parameters of a per-sample CasADi expression to data
(`fit_expression`), for model terms that are not linear in their parameters (a Stribeck velocity, a delay, an
elastic mode, an encoder offset). Knows nothing of arms: `fitting.nlp` and the effects' candidates build on it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

#: IPOPT options that keep it silent.
IPOPT_QUIET = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}


@dataclass
class ExpressionFit:
    """Result of `fit_expression`: parameter values by name, final cost, solver status."""

    values: np.ndarray
    names: tuple[str, ...]
    cost: float
    status: str
    success: bool
    iterations: int
    seconds: float
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        """Parameter values by name."""
        return {n: float(v) for n, v in zip(self.names, self.values)}


def _solve_nlp(
    theta: ca.SX,
    objective: ca.SX,
    x0: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    g: ca.SX | None = None,
    lbg=None,
    ubg=None,
    options: dict | None = None,
) -> tuple:
    """IPOPT on min objective(θ) s.t. lb ≤ θ ≤ ub (and lbg ≤ g(θ) ≤ ubg); returns (θ*, cost, stats)."""
    nlp = {"x": theta, "f": objective}
    if g is not None:
        nlp["g"] = g
    solver = ca.nlpsol("solver", "ipopt", nlp, {**IPOPT_QUIET, **(options or {})})
    kwargs = {"x0": x0, "lbx": lb, "ubx": ub}
    if g is not None:
        kwargs.update(lbg=lbg, ubg=ubg)
    sol = solver(**kwargs)
    return np.array(sol["x"]).ravel(), float(sol["f"]), solver.stats()


def _input_columns(inputs: list[ca.SX], data: Sequence[np.ndarray], N: int) -> list[np.ndarray]:
    """The data of each input as a (d_i, N) array, one column per sample (what `Function.map` takes), its shape
    checked against the input's symbol."""
    if len(data) != len(inputs):
        raise ValueError(f"{len(inputs)} inputs but {len(data)} data arrays")
    cols = []
    for sym, arr in zip(inputs, data):
        arr = np.asarray(arr, dtype=float).reshape(N, -1)
        if arr.shape[1] != sym.numel():
            raise ValueError(f"data for input {sym} has {arr.shape[1]} columns, the symbol {sym.numel()}")
        cols.append(arr.T)
    return cols


def _mean_squared_error(
    model: ca.Function, cols: list[np.ndarray], target: np.ndarray, weights: Sequence[float] | None
) -> tuple[ca.SX, ca.SX]:
    """(θ, objective(θ)): the weighted mean over the N samples of Σ_i w_i (model_i − target_i)², `model` (the
    expression of the inputs and θ) mapped over the samples so that the NLP's derivatives are exact and one
    evaluation is O(N)."""
    K, m, N = model.numel_in(model.n_in() - 1), model.numel_out(0), target.shape[0]
    theta = ca.SX.sym("theta", K)
    predicted = model.map(N)(*[ca.DM(c) for c in cols], ca.repmat(theta, 1, N))  # m × N
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=float)
    err = predicted - ca.DM(target.T)
    return theta, ca.sum2(ca.sum1(ca.diag(ca.DM(w)) @ (err * err))) / N


def fit_expression(
    expr: ca.SX,
    params: ca.SX,
    inputs: Sequence[ca.SX],
    data: Sequence[np.ndarray],
    target: np.ndarray,
    *,
    x0: Sequence[float],
    lb: Sequence[float] | None = None,
    ub: Sequence[float] | None = None,
    weights: Sequence[float] | None = None,
    names: Sequence[str] | None = None,
    options: dict | None = None,
) -> ExpressionFit:
    """Fit the parameters `params` of a per-sample CasADi expression to data, by bounded least squares.

        minimise_θ   Σ_k Σ_i w_i (expr_i(x_k, θ) − target_ki)²     subject to  lb ≤ θ ≤ ub

    Arguments:
        expr:    CasADi SX column (m×1), the model output for ONE sample (e.g. a torque, N m).
        params:  SX column of the K parameters θ to fit (symbols that `expr` depends on).
        inputs:  the per-sample SX symbols `expr` depends on (e.g. [q, dq, ddq], each d_i×1).
        data:    one array per input, shape (N, d_i) (or (N,) when d_i = 1), in the same order.
        target:  measured outputs (N, m) (or (N,) when m = 1).
        x0, lb, ub: start and bounds for θ (length K; ±inf allowed for no bound).
        weights: per-output weights w_i (length m), e.g. 1/σ_i²; default 1.
        names:   parameter names for the result (default θ0, θ1, ...).
        options: extra CasADi/IPOPT options (e.g. {"ipopt.max_iter": 200}).

    Returns an `ExpressionFit` (values, names, cost, IPOPT status, success, iterations, seconds). The
    expression is mapped over the N samples (`Function.map`), so derivatives are exact and the cost of
    one evaluation is O(N).

    Example (a Stribeck velocity vs for joint 1, other parameters known):
        vs, dq = ca.SX.sym("vs"), ca.SX.sym("dq")
        fit_expression(fs * ca.sign(dq) * ca.exp(-(dq / vs) ** 2), vs, [dq], [dq_data], residual,
                       x0=[0.05], lb=[1e-3], ub=[1.0], names=["vs1"])
    """
    inputs = list(inputs)
    K, m = params.numel(), expr.numel()
    target = np.asarray(target, dtype=float).reshape(len(target), -1)
    N = target.shape[0]
    if target.shape[1] != m:
        raise ValueError(f"target has {target.shape[1]} outputs, the expression {m}")
    cols = _input_columns(inputs, data, N)
    model = ca.Function("model", [*inputs, params], [expr])
    theta, objective = _mean_squared_error(model, cols, target, weights)
    lb = np.full(K, -np.inf) if lb is None else np.asarray(lb, dtype=float)
    ub = np.full(K, np.inf) if ub is None else np.asarray(ub, dtype=float)
    t0 = time.perf_counter()
    x, cost, st = _solve_nlp(theta, objective, np.asarray(x0, dtype=float), lb, ub, options=options)
    names = tuple(names) if names is not None else tuple(f"theta{i}" for i in range(K))
    return ExpressionFit(
        x, names, cost * N, st["return_status"], bool(st["success"]), int(st["iter_count"]), time.perf_counter() - t0
    )


# ---------------------------------------------------------------------------------------------- physical
#: Physical parameters besides friction/extension columns, with what bounds them.
