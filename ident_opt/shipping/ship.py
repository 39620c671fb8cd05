"""What `ident-opt codegen` ships, and the check that the compiled code computes it: π identified by the chosen
estimator (`ident_opt.fitting.estimators`) or loaded from an earlier run's parameters.json, the GMR residual
model fitted on x = [q dq ddq] (`models.features`) or loaded, and the compiled functions compared with the
Python model on the training states and on random states spanning them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.data.dataset import MAX_MAGNITUDE, Dataset, concat
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import Choice
from ident_opt.models.gmr import GMR
from ident_opt.models.hybrid import features, make_gmr
from ident_opt.problem.spec import ResidualSpec
from ident_opt.shipping import codegen

#: The solver status written for estimators that have none to report.
STATUS = {"ols": "least squares (no constraints)"}
#: Largest accepted relative difference between the compiled library and the Python model.
TOLERANCE = {"tau_hat": 1e-12, "tau_hat_gmr": 1e-10, "ddq_hat": 1e-12, "pi_update": 1e-9, "observer_step": 1e-9}
#: What is compared: τ with the NumPy model (+ GMR), ddq by how well it solves M ddq = τ − C dq − G − F.
MEASURE = {
    "tau_hat": "max_relative_error",
    "tau_hat_gmr": "max_relative_error",
    "ddq_hat": "max_backward_error",
    "observer_step": "max_relative_error",  # τ_ext along the first training trial, relative to its largest size
}
#: Random states for the check, in addition to the training states.
N_RANDOM = 4000
#: Random states on which a loaded parameter's torque contribution is bounded (`torque_bound`).
N_BOUND = 200


@dataclass
class Shipped:
    """The model baked into the C code: the arm, π in its order, how π was obtained, the GMR residual model."""

    model: Arm
    pi: np.ndarray
    estimator: str
    status: str
    gmr: GMR


def prepare(
    robot,
    model: Arm,
    trials: list[Dataset],
    residual: ResidualSpec,
    choice: Choice | None,
    components: int | None = None,
    saved: dict | None = None,
) -> Shipped:
    """π and the GMR: taken from `saved` (`read_parameters`) where it has them, else π the chosen fit on all
    `trials` (`Choice.fit`: the recommended one is the π `compare` reports) / the GMR fitted with the problem's
    `residual` settings (`components`: a fixed K) on the trials pooled."""
    if saved is not None:
        pi, label = saved_vector(saved, model), f"{saved['estimator']} (loaded from {saved['path']})"
        status = saved.get("estimator_status", "")
    else:
        pi, label, status = identify(robot, model, trials, choice)
    if saved and saved.get("gmr"):
        gmr = gmr_from_saved(saved["gmr"], model.n_joints)
    else:
        gmr = fit_residual(model, pi, concat(trials), residual, components)
    return Shipped(model, pi, label, status, gmr)


def identify(robot, model: Arm, trials: list[Dataset], choice: Choice) -> tuple[np.ndarray, str, str]:
    """(π, estimator name, solver status) on the training trials, by the chosen fit (`Choice.fit`)."""
    try:
        fit = choice.fit(robot, model, trials)
    except RuntimeError as exc:  # the solver failed: nothing consistent to generate
        raise InputError(f"codegen: the physically consistent fit failed ({exc}); try --estimator ols") from None
    return fit.pi, choice.estimator, STATUS.get(fit.method, fit.status)


def fit_residual(model: Arm, pi: np.ndarray, train: Dataset, spec: ResidualSpec, components: int | None) -> GMR:
    """The GMR residual model on x = [q dq ddq], r = τ − τ̂(π), with the problem's [residual] settings."""
    residual = train.tau - model.predict(pi, train.q, train.dq, train.ddq)
    return make_gmr(spec, components).fit(features(train), residual)


def read_parameters(path: str) -> dict:
    """A parameters.json written by an earlier `codegen` run: {estimator, parameters, extensions, gmr}."""
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot read the parameters file ({exc})") from None
    if not isinstance(raw, dict) or not isinstance(raw.get("parameters"), dict):
        raise InputError(f"{path}: not a parameters file (expected an object with a 'parameters' object)")
    model = raw.get("model") or {}
    extensions = model.get("extensions", []) if isinstance(model, dict) else None
    if not isinstance(extensions, list) or not all(isinstance(e, str) for e in extensions):
        raise InputError(f"{path}: key 'model' must be an object whose 'extensions' is a list of names")
    if raw.get("gmr") is not None and not isinstance(raw["gmr"], dict):
        raise InputError(f"{path}: key 'gmr' must be an object (weights, means, covariances) or absent")
    return {
        "parameters": raw["parameters"],
        "estimator": str(raw.get("estimator", "unknown")),
        "estimator_status": str(raw.get("estimator_status", "")),
        "extensions": extensions,
        "gmr": raw.get("gmr"),
        "path": path,
    }


def saved_vector(saved: dict, model: Arm) -> np.ndarray:
    """π in the model's order. Every model parameter must be in the file, as a finite number whose torques on the
    check's states stay within `MAX_TORQUE` (`torque_bound`); a name that is not one of the model's is refused (it
    would be silently left out of the generated code)."""
    params, path = saved["parameters"], saved["path"]
    missing = [n for n in model.names if n not in params]
    if missing:
        raise InputError(f"{path}: parameters {missing} of the model are missing")
    unknown = [str(n) for n in params if n not in model.names]
    if unknown:
        shown = ", ".join(repr(n) for n in unknown[:8]) + (", …" if len(unknown) > 8 else "")
        raise InputError(
            f"{path}: {len(unknown)} parameter(s) the model ({', '.join(model.extensions) or 'rigid'}, "
            f"{model.n_params} parameters) does not have: {shown}; remove them, or give the --extension that has them"
        )
    pi = np.empty(model.n_params)
    for k, name in enumerate(model.names):
        value = params[name]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"{path}: parameter {name} must be a number, got {value!r}")
        if not np.isfinite(value):
            raise InputError(f"{path}: parameter {name} = {value!r} is not a finite number")
        pi[k] = value
    torque_bound(model, pi, path)
    return pi


#: The largest torque [N m] a parameter may contribute on the check's states (±π rad, ±3 rad/s, ±10 rad/s²): the
#: largest value ident-opt accepts in data (`data.dataset.MAX_MAGNITUDE`). Beyond it no arm is described, and the
#: check of the compiled code against Python loses its meaning (its differences overflow to inf − inf = NaN).
MAX_TORQUE = MAX_MAGNITUDE


def torque_bound(model: Arm, pi: np.ndarray, path: str) -> None:
    """InputError naming the parameter(s) of `pi` whose torque contribution |Y_k π_k| on the check's states without
    a trial (`_states`) is not finite or exceeds `MAX_TORQUE`: finite values that overflow the prediction."""
    states = _states(model, np.zeros(model.n_params), None, np.random.default_rng(0), N_BOUND)
    Y = model.regressor(states.q, states.dq, states.ddq)  # (N, n, P)
    with np.errstate(over="ignore", invalid="ignore"):
        reach = np.max(np.abs(Y), axis=(0, 1)) * np.abs(pi)  # the largest |τ| each parameter adds
    bad = [k for k in range(len(pi)) if not reach[k] <= MAX_TORQUE]
    if bad:
        worst = ", ".join(f"{model.names[k]} = {pi[k]:.6g} (up to {reach[k]:.3g} N m)" for k in bad[:4])
        raise InputError(
            f"{path}: parameter(s) {worst} predict torques beyond {MAX_TORQUE:.0e} N m on ordinary states "
            "(±π rad, ±3 rad/s, ±10 rad/s²); no arm has them, and the compiled code could not be checked (its "
            "torques overflow): fix the parameters file"
        )


def gmr_from_saved(raw: dict, n_joints: int) -> GMR:
    """The 'gmr' object of a parameters.json (3n inputs, n outputs for an arm of n joints) back as a fitted `GMR`."""
    try:
        w, m, c = (np.asarray(raw[key], dtype=float) for key in ("weights", "means", "covariances"))
    except (KeyError, TypeError, ValueError):
        raise InputError("parameters file: 'gmr' needs numeric weights, means and covariances") from None
    K, d = (w.shape[0] if w.ndim == 1 else 0), 4 * n_joints
    if K == 0 or w.ndim != 1 or m.shape != (K, d) or c.shape != (K, d, d):
        raise InputError(
            f"parameters file: GMR shapes {w.shape}, {m.shape}, {c.shape}; expected (K,), (K, {d}), (K, {d}, {d}) "
            f"for {n_joints} joints"
        )
    gmr = GMR(n_components=K)
    gmr.weights_, gmr.means_, gmr.covariances_, gmr.n_inputs = w, m, c, 3 * n_joints
    return gmr


def check(library: Path, shipped: Shipped, train: Dataset | None, names: list[str], rng) -> dict[str, float]:
    """Each compiled function's error against the Python model (`MEASURE`), on the training states (if any)
    and random states spanning them."""
    model, pi = shipped.model, shipped.pi
    states = _states(model, pi, train, rng)
    errors = {}
    for name in names:
        f = codegen.load_external(library, name)
        if name == "tau_hat":
            errors[name] = codegen.relative_error(codegen.evaluate(f, states.q, states.dq, states.ddq), states.tau)
        elif name == "tau_hat_gmr":
            ref = states.tau + shipped.gmr.predict_mean(features(states))
            errors[name] = codegen.relative_error(codegen.evaluate(f, states.q, states.dq, states.ddq), ref)
        elif name == "ddq_hat":  # backward error of the solve: meaningful however ill-conditioned M(q) is
            ddq = codegen.evaluate(f, states.q, states.dq, states.tau)
            errors[name] = codegen.forward_backward_error(model, pi, states.q, states.dq, states.tau, ddq)
    return errors


def _states(model: Arm, pi: np.ndarray, train: Dataset | None, rng, count: int = N_RANDOM) -> Dataset:
    """`count` random states spanning the training states (at least ±π, ±1, ±1) followed by the training
    states themselves (without a trial: ±π rad, ±3 rad/s, ±10 rad/s²), with the model's torques τ(π)."""
    n = model.n_joints
    if train is not None:
        lo = np.minimum(train.q.min(0), -np.pi), np.minimum(train.dq.min(0), -1), np.minimum(train.ddq.min(0), -1)
        hi = np.maximum(train.q.max(0), np.pi), np.maximum(train.dq.max(0), 1), np.maximum(train.ddq.max(0), 1)
    else:
        lo = (-np.pi * np.ones(n), -3 * np.ones(n), -10 * np.ones(n))
        hi = (np.pi * np.ones(n), 3 * np.ones(n), 10 * np.ones(n))
    q, dq, ddq = (rng.uniform(a, b, (count, n)) for a, b in zip(lo, hi))
    if train is not None:
        q, dq, ddq = np.vstack([q, train.q]), np.vstack([dq, train.dq]), np.vstack([ddq, train.ddq])
    tau = model.predict(pi, q, dq, ddq)
    return Dataset("check states", np.arange(len(q), dtype=float), q, dq, ddq, tau)
