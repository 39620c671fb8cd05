"""`ident-opt codegen`: identify (or load) the model, write its C code, compile it, check it against Python.

DIR receives the CasADi-generated `ident_opt_model.c`/`.h`, the shared library `libident_opt_model.so`,
`parameters.json` (the parameters baked in, by name, the estimator, the GMR residual model), a README for
embedding and the example `main.c`. Exported functions: `tau_hat(q, dq, ddq) -> tau`, `tau_hat_gmr` (the same
plus the GMR residual's conditional mean) and `ddq_hat(q, dq, tau) -> ddq` (forward dynamics), each with the
standard CasADi entry points. The compiled library is loaded back and compared with the Python model on the
training states and on random states; a mismatch is an error.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ident_opt.commands.common import add_problem_arguments
from ident_opt.errors import InputError

#: Largest accepted relative difference between the compiled library and the Python model.
TOLERANCE = {"tau_hat": 1e-12, "tau_hat_gmr": 1e-10, "ddq_hat": 1e-12}
#: What is compared: τ with the NumPy model (+ GMR), ddq by how well it solves M ddq = τ − C dq − G − F.
MEASURE = {"tau_hat": "max_relative_error", "tau_hat_gmr": "max_relative_error", "ddq_hat": "max_backward_error"}
#: Random states for the check, in addition to the training states.
N_RANDOM = 4000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The standard problem flags, --out (required) and the model/estimator/GMR choices."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", required=True, help="output folder for the C code and library")
    parser.add_argument(
        "--extension",
        metavar="NAME",
        action="append",
        default=None,
        help="model extension to include (repeatable): armature, asymmetric_coulomb, stribeck, offset",
    )
    parser.add_argument(
        "--estimator",
        choices=("constrained", "ols"),  # the names of ident_opt.identify.estimators.ESTIMATORS
        default="constrained",
        help="how π is identified (default: the physically consistent fit)",
    )
    parser.add_argument(
        "--parameters",
        metavar="FILE",
        help="use the parameters (and GMR, if present) of a parameters.json from an earlier run "
        "instead of identifying them",
    )
    parser.add_argument(
        "--components", metavar="K", type=int, help="GMR components (default: the problem's [residual] setting)"
    )
    parser.add_argument("--no-forward", action="store_true", help="do not generate ddq_hat (forward dynamics)")


def run(args: argparse.Namespace) -> int:
    """Identify (or load), generate, compile, check; 0 when the library agrees with Python, 1 when not."""
    import numpy as np

    from ident_opt import codegen
    from ident_opt.commands.common import load, output_dir, write_json
    from ident_opt.problem import load_problem

    problem = load_problem(args.problem)
    out = output_dir(args, problem)
    compiler = codegen.find_compiler()  # fail before any fitting when there is none
    saved = _read_parameters(args.parameters) if args.parameters else None
    model = _model(args.extension if args.extension is not None else (saved or {}).get("extensions", []))

    trials = None
    if saved is None or saved.get("gmr") is None:
        trials = load(args).trials
    train = trials[0] if trials else None

    if saved is not None:
        pi, estimator = _saved_vector(saved, model), f"{saved['estimator']} (loaded from {args.parameters})"
        status = saved.get("estimator_status", "")
    else:
        pi, estimator, status = _identify(model, train, args.estimator)
    gmr = (
        _gmr_from_saved(saved["gmr"])
        if saved and saved.get("gmr")
        else _fit_gmr(model, pi, train, problem, args.components)
    )

    print(
        f"ident-opt codegen: {len(model.names)} parameters ({estimator}), GMR with {len(gmr.weights_)} "
        f"components; generating C in {out}",
        flush=True,
    )
    functions = codegen.build_functions(model, pi, gmr, forward=not args.no_forward)
    source, header = codegen.generate_sources(functions, out)
    library = codegen.compile_library(source, out, compiler)
    example = codegen.copy_example(out)
    readme = codegen.write_readme(out, functions)

    errors = _check(codegen, library, model, pi, gmr, train, [f.name() for f in functions], np.random.default_rng(0))
    payload = {
        "estimator": estimator,
        "estimator_status": status,
        "model": {
            "extensions": list(model.extensions),
            "gravity": model.gravity,
            "stribeck_velocity": list(model.stribeck_velocity),
        },
        "parameters": model.as_dict(pi),
        "units": {"a": "kg m^2", "ia": "kg m^2", "b": "N m", "fv": "N m s/rad", "fc": "N m", "fs": "N m"},
        "gmr": {
            "inputs": list(codegen.GMR_INPUTS),
            "outputs": ["r1", "r2"],
            "n_components": len(gmr.weights_),
            "weights": gmr.weights_,
            "means": gmr.means_,
            "covariances": gmr.covariances_,
        },
        "problem": problem.name,
        "data": [t.source for t in trials] if trials else [],
        "functions": [f.name() for f in functions],
        "library": library.name,
        "check": {name: {MEASURE[name]: err, "limit": TOLERANCE[name]} for name, err in errors.items()},
    }
    write_json(out / "parameters.json", payload)
    for name, err in errors.items():
        print(
            f"  {name}: compiled vs Python, {MEASURE[name].replace('_', ' ')} {err:.2e} (limit {TOLERANCE[name]:.0e})"
        )
    print(f"  wrote {', '.join(p.name for p in (source, header, library, example, readme))}, parameters.json")
    write_json(getattr(args, "json", None), payload)
    bad = {name: err for name, err in errors.items() if not err <= TOLERANCE[name]}
    if bad:
        print(f"ident-opt codegen: the compiled code disagrees with the Python model: {bad}", file=sys.stderr)
        return 1
    return 0


def _model(extensions):
    """The ArmModel with the chosen extensions (an unknown name is an input error)."""
    from ident_opt.robot import ArmModel

    try:
        return ArmModel(extensions=tuple(dict.fromkeys(extensions)))
    except ValueError as exc:
        raise InputError(f"codegen: {exc}") from None


#: The solver status written for estimators that have none to report.
STATUS = {"ols": "least squares (no constraints)"}


def _identify(model, train, estimator: str):
    """(π, estimator name, solver status) from the training trial, by the chosen estimator (registry)."""
    from ident_opt.identify import estimators
    from ident_opt.identify.stats import Stats

    stats = Stats.from_data(model, train.q, train.dq, train.ddq, train.tau)
    try:
        fit = estimators.fit(estimator, stats, model)
    except RuntimeError as exc:  # the solver failed: nothing consistent to generate
        raise InputError(f"codegen: the physically consistent fit failed ({exc}); try --estimator ols") from None
    return fit.pi, fit.method, STATUS.get(fit.method, fit.status)


def _fit_gmr(model, pi, train, problem, components: int | None):
    """The GMR residual model on x = [q dq ddq], r = τ − τ̂(π), with the problem's [residual] settings."""
    from ident_opt.models import features, make_gmr

    spec = problem.residual
    if components is not None and components < 1:
        raise InputError(f"codegen: --components must be >= 1, got {components}")
    k = components if components is not None else spec.components
    print(
        f"ident-opt codegen: fitting the GMR residual ({k or 'K chosen among ' + str(list(spec.candidates))}"
        f" components) on {train.n} samples",
        flush=True,
    )
    residual = train.tau - model.predict(pi, train.q, train.dq, train.ddq)
    return make_gmr(spec, components).fit(features(train), residual)


def _read_parameters(path: str) -> dict:
    """A parameters.json written by an earlier `codegen` run: {estimator, parameters, extensions, gmr}."""
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot read the parameters file ({exc})") from None
    if not isinstance(raw, dict) or not isinstance(raw.get("parameters"), dict):
        raise InputError(f"{path}: not a parameters file (expected an object with a 'parameters' object)")
    return {
        "parameters": raw["parameters"],
        "estimator": str(raw.get("estimator", "unknown")),
        "estimator_status": str(raw.get("estimator_status", "")),
        "extensions": list((raw.get("model") or {}).get("extensions", [])),
        "gmr": raw.get("gmr"),
        "path": path,
    }


def _saved_vector(saved: dict, model):
    """π in the model's order; every model parameter must be in the file, as a finite number."""
    import numpy as np

    params = saved["parameters"]
    missing = [n for n in model.names if n not in params]
    if missing:
        raise InputError(f"{saved['path']}: parameters {missing} of the model are missing")
    try:
        pi = np.array([float(params[n]) for n in model.names])
    except (TypeError, ValueError):
        raise InputError(f"{saved['path']}: every parameter must be a number") from None
    return pi


def _gmr_from_saved(raw: dict):
    """The 'gmr' object of a parameters.json (6 inputs, 2 outputs) back as a fitted `GMR`."""
    import numpy as np

    from ident_opt.gmr import GMR

    try:
        w, m, c = (np.asarray(raw[key], dtype=float) for key in ("weights", "means", "covariances"))
    except (KeyError, TypeError, ValueError):
        raise InputError("parameters file: 'gmr' needs numeric weights, means and covariances") from None
    K = w.shape[0] if w.ndim == 1 else 0
    if K == 0 or w.ndim != 1 or m.shape != (K, 8) or c.shape != (K, 8, 8):
        raise InputError(
            f"parameters file: GMR shapes {w.shape}, {m.shape}, {c.shape}; expected (K,), (K, 8), (K, 8, 8)"
        )
    gmr = GMR(n_components=K)
    gmr.weights_, gmr.means_, gmr.covariances_, gmr.n_inputs = w, m, c, 6
    return gmr


def _check(codegen, library: Path, model, pi, gmr, train, names: list[str], rng) -> dict[str, float]:
    """Max relative error of each compiled function against the Python model, on the training states (if
    any) and random states spanning them."""
    import numpy as np

    if train is not None:
        lo = np.minimum(train.q.min(0), -np.pi), np.minimum(train.dq.min(0), -1), np.minimum(train.ddq.min(0), -1)
        hi = np.maximum(train.q.max(0), np.pi), np.maximum(train.dq.max(0), 1), np.maximum(train.ddq.max(0), 1)
    else:
        lo, hi = (
            (-np.pi * np.ones(2), -3 * np.ones(2), -10 * np.ones(2)),
            (np.pi * np.ones(2), 3 * np.ones(2), 10 * np.ones(2)),
        )
    q, dq, ddq = (rng.uniform(a, b, (N_RANDOM, 2)) for a, b in zip(lo, hi))
    if train is not None:
        q, dq, ddq = np.vstack([q, train.q]), np.vstack([dq, train.dq]), np.vstack([ddq, train.ddq])
    tau = model.predict(pi, q, dq, ddq)
    errors = {}
    for name in names:
        f = codegen.load_external(library, name)
        if name == "tau_hat":
            errors[name] = codegen.relative_error(codegen.evaluate(f, q, dq, ddq), tau)
        elif name == "tau_hat_gmr":
            ref = tau + gmr.predict_mean(np.hstack([q, dq, ddq]))
            errors[name] = codegen.relative_error(codegen.evaluate(f, q, dq, ddq), ref)
        elif name == "ddq_hat":  # backward error of the solve: meaningful however ill-conditioned M(q) is
            errors[name] = codegen.forward_backward_error(model, pi, q, dq, tau, codegen.evaluate(f, q, dq, tau))
    return errors
