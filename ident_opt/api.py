"""The Python API's own pieces: trials from a problem's files or from arrays, and the recommended fit
(`docs/api.md`). Every other stage function lives in the package of its feature and is re-exported by
`ident_opt` (`ident_opt.compare`, `ident_opt.diagnose`, …); the commands call the same functions.

    import ident_opt as iopt

    problem = iopt.load_problem("problems/kuka_lwr4.toml")
    training, testing = iopt.load_trials(problem)          # the problem's [data] (or paths)
    fit = iopt.fit(problem, training)                       # the recommended fit (or estimator="ols", …)
    tau = fit.predict(testing[0])                           # τ̂ (N, n) [N m]

Every stage function takes the parsed problem first, then trials (`ident_opt.data.Dataset`: t, q, dq, ddq, tau as
arrays (N, n) in SI units), and returns the data object the matching command reports: nothing here prints.
"""

from __future__ import annotations

import contextlib
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ident_opt import outputs
from ident_opt.data.dataset import Dataset, fittable
from ident_opt.data.loader import from_arrays, held_out_overlap, load_dataset
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.errors import InputError, excerpt
from ident_opt.fitting.base import base_parameters
from ident_opt.fitting.recommend import ArmFit, choose, fit_options
from ident_opt.outputs import shown
from ident_opt.problem import Problem
from ident_opt.warnings import ResultWarning

if TYPE_CHECKING:  # the writers' modules load CasADi, Pinocchio and a C compiler's helpers: on first use only
    from ident_opt.contact.detect import Detection
    from ident_opt.shipping.description import Exported
    from ident_opt.shipping.generate import Generated


def load_trials(
    problem: Problem,
    data: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
    test: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
    *,
    allow_implausible: bool = False,
    drop_invalid: bool = False,
    min_samples: int | None = None,
    fit: bool = True,
) -> tuple[list[Dataset], list[Dataset]]:
    """(training, held-out) trials: every file of `data` trains and every file of `test` is held out (one path, or a
    list of them); without `data` the problem's `[data]` decides (`train`/`test`, or `trials`: the first trains, the
    second is held out), and a problem with only a `[simulate]` section gets its simulated trials (generated on first
    use, cached). `fit`: the trials will be fitted, so a joint whose torque never varies is an error. Bad input
    raises `InputError` naming the file, column and row."""
    checked_problem(problem, "load_trials")
    train, held = _paths(data, "data"), _paths(test, "test")
    flags = {"allow_implausible": allow_implausible, "drop_invalid": drop_invalid, "fit": fit}
    for name, value in flags.items():
        if not isinstance(value, (bool, np.bool_)):
            raise InputError(f"load_trials: {name} must be True or False, got {excerpt(value)}")
    if min_samples is not None and (isinstance(min_samples, bool) or not isinstance(min_samples, (int, np.integer))):
        raise InputError(
            f"load_trials: min_samples must be None or a whole number of samples, got {excerpt(min_samples)}"
        )
    if not train:
        train, held = list(problem.data.training), held or list(problem.data.testing)
    paths, n_train = train + held, len(train) or 1
    if not paths and problem.simulate is not None:
        from ident_opt.simulator import problem_trials  # deferred: the simulator's integrator side

        paths = problem_trials(problem)
    if not paths:
        raise InputError(f"{problem.path}: no data: give --data D or list trials under [data] in the problem file")
    options = {"allow_implausible": bool(allow_implausible), "drop_invalid": bool(drop_invalid)}
    if min_samples is not None:
        options["min_samples"] = int(min_samples)
    outputs.declare_inputs(paths)
    trials = [load_dataset(p, problem.data, problem.robot, **options) for p in paths]
    for trial in trials:
        fittable(trial, bool(fit))
    return trials[:n_train], trials[n_train:]


def _paths(value: object, argument: str) -> list[Path]:
    """`load_trials`'s `data` or `test` as paths: None (none), one path (a str or a path object: one file, never
    its characters one by one), or a list of them; an InputError naming `argument` otherwise."""
    if value is None:
        return []
    items = [value] if isinstance(value, (str, os.PathLike)) else value
    if isinstance(items, (bytes, Mapping)) or not isinstance(items, Iterable):
        raise InputError(f"load_trials: {argument} must be a path or a list of paths, got {excerpt(value)}")
    paths = []
    for i, item in enumerate(items):
        label = argument if items is not value else f"{argument}[{i}]"
        if not isinstance(item, (str, os.PathLike)) or not os.fspath(item).strip():
            raise InputError(f"load_trials: {label} must be the path of a trial file, got {excerpt(item)}")
        paths.append(Path(item))
    return paths


def trial(
    problem: Problem,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray | None = None,
    *,
    current: np.ndarray | None = None,
    dq: np.ndarray | None = None,
    ddq: np.ndarray | None = None,
    source: str = "arrays",
    allow_implausible: bool = False,
) -> Dataset:
    """A trial of the problem's arm from arrays: `t` (N,) [s], `q` (N, n) [rad], the torques `tau` (N, n) [N m] or
    the motor currents `current` (N, n) [A], optionally `dq` and `ddq`; missing derivatives are estimated by the
    same pipeline as a file's, at the problem's `derivative_cutoff_hz` (`ident_opt.data.loader.from_arrays`): each
    array of the shape its joints ask for, every value finite, or an InputError naming it."""
    checked_problem(problem, "trial")
    if not isinstance(source, str) or not source.strip():
        raise InputError(f"trial: source must be a name for the trial (a non-empty string), got {excerpt(source)}")
    if not isinstance(allow_implausible, (bool, np.bool_)):
        raise InputError(f"trial: allow_implausible must be True or False, got {excerpt(allow_implausible)}")
    return from_arrays(
        t,
        q,
        tau,
        problem.data,
        problem.robot,
        current=current,
        dq=dq,
        ddq=ddq,
        source=source,
        allow_implausible=allow_implausible,
    )


def fit(problem: Problem, trials: Sequence[Dataset], estimator: str | None = None, **options) -> ArmFit:
    """π of the problem's arm (`problem.robot.model()`) on all `trials` (their statistics add up), by `estimator`
    (default: the recommended fit, chosen from the trials' own evidence, `ident_opt.fitting.recommend.choose`), with
    standard errors: the fit `compare` reports as recommended, `export` and `codegen` write. `fit.predict(trial)` is
    τ̂; `options` go to the estimator (e.g. `weights="wls"`, `margin=1e-4`; `fitting.recommend.FIT_OPTIONS` lists
    each fit's). Everything is checked before any fitting: the trials (`checked_trials`: each of the arm's joints,
    finite), the estimator's name, each option's name, type and range; an InputError names what is wrong."""
    checked_problem(problem, "fit")
    robot, model = problem.robot, problem.robot.model()
    if estimator is not None:  # an unknown fit is refused before the trials' evidence is weighed
        choose(problem, [], estimator=estimator, command="fit")
    # The recommended fit is the arm's consistent one or the robust one, which takes the same options.
    checked = fit_options(robot, estimator or robot.default_estimator, model, options, "fit")
    trials = checked_trials(problem, trials, "fit", "trials", fit=True)
    choice = choose(problem, trials, estimator=estimator, command="fit")
    try:
        return choice.fit(robot, model, trials, **checked)
    except RuntimeError as exc:  # the solver failed: nothing to stand behind
        raise InputError(f"the {choice.estimator} fit failed ({exc}); try another estimator") from None


def detect(
    problem: Problem,
    training: Sequence[Dataset],
    calibration: Sequence[Dataset] | None = None,
    data: Sequence[Dataset] = (),
    *,
    estimator: str | None = None,
    margin: float | None = None,
) -> Detection:
    """`ident-opt detect` (`ident_opt.contact.detect.detect`, `docs/contacts.md`): the fit on `training`, thresholds
    calibrated on the collision-free `calibration` trials (default: `training`; false alarms per minute held out one
    trial at a time), and the external-torque observer with its alarms over each trial of `data`."""
    from ident_opt.contact.detect import detect as run
    from ident_opt.contact.thresholds import MARGIN

    return run(problem, training, calibration, data, estimator=estimator, margin=MARGIN if margin is None else margin)


# ---------------------------------------------------------------------------------------------- writers
def export(problem: Problem, fit: ArmFit, path: str | os.PathLike, format: str | None = None) -> Exported:
    """`ident-opt export` (`ident_opt.shipping.description.export`): the arm of `problem` with the parameters of
    `fit` (`ident_opt.fit`) written to `path`: a URDF with its JSON sidecar `path.json` (`format` "urdf", or a path
    ending in .urdf) or a MuJoCo MJCF ("mjcf", .xml, .mjcf). The command line's output rules hold (`_writing`): an
    output that is one of the run's inputs (the problem file, its URDF and meshes, its trials, the fit's trial
    files) or that exists as anything but a regular file is refused before anything is written."""
    from ident_opt.shipping.description import export as write_description
    from ident_opt.shipping.description import export_format

    checked_problem(problem, "export")
    problem.require("export")
    _checked_fit(problem, fit, "export")
    path = _output_path(path, "export: path")
    fmt = export_format(path, format)
    with _writing(problem, fit.trials):
        outputs.check_file_output(path, "export: path")
        if fmt == "urdf":
            outputs.check_file_output(Path(f"{path}.json"), "export: path's sidecar")
        return write_description(problem, fit, path, fmt)


def codegen(
    problem: Problem,
    training: Sequence[Dataset],
    out: str | os.PathLike,
    *,
    estimator: str | None = None,
    extensions: Sequence[str] | None = None,
    saved: dict | None = None,
    components: int | None = None,
    forward: bool = True,
    update: bool = True,
    force: bool = False,
    say: Callable[[str], None] = lambda line: None,
) -> Generated:
    """`ident-opt codegen` (`ident_opt.shipping.generate.generate`, whose arguments these are) into the folder
    `out`, with the command line's checks first: the problem, the training trials (none needed when `saved` holds
    the GMR too), `out` a folder that is none of the run's inputs nor inside one (`_writing`). The files written are
    noted as the tool's (`outputs.remember_owned`), as the command does, so a later run may replace them."""
    from ident_opt.shipping.generate import generate

    checked_problem(problem, "codegen")
    if saved is not None and not isinstance(saved, Mapping):
        raise InputError(
            f"codegen: saved must be None or an earlier run's parameters.json as a dict, got {excerpt(saved)}"
        )
    required = not (saved and saved.get("gmr"))
    trials = checked_trials(problem, training, "codegen", "training", required=required, fit=True)
    out = _output_path(out, "codegen: out")
    try:  # CasADi writes its C sources by a UTF-8 name: a folder named otherwise would not be where they land
        os.fsencode(os.path.abspath(out)).decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(
            f"codegen: out {outputs.abbreviated(out)}: the folder's path is not UTF-8, which the C code generator "
            "cannot write to; choose a folder whose path is"
        ) from None
    options = {"estimator": estimator, "extensions": extensions, "saved": saved, "components": components}
    switches = {"forward": forward, "update": update, "force": force}
    for name, value in switches.items():
        if not isinstance(value, (bool, np.bool_)):
            raise InputError(f"codegen: {name} must be True or False, got {excerpt(value)}")
    with _writing(problem, [d.source for d in trials]):
        outputs.check_folder_output(out, "codegen: out")
        made = generate(problem, trials, out, **options, **switches, say=say)
        outputs.remember_owned(out, made.written)
    return made


def _checked_fit(problem: Problem, fit: object, command: str) -> ArmFit:
    """`fit` when it is a fit of `problem`'s arm (`ident_opt.fit` makes them): its model's parameters are the
    arm's, π one finite value per parameter; an InputError naming it otherwise."""
    if not isinstance(fit, ArmFit) or fit.model is None:
        raise InputError(
            f"{command}: fit must be a fit of the problem's arm (ident_opt.fit(problem, trials) makes one), got "
            f"{type(fit).__name__} {excerpt(fit)}"
        )
    robot = problem.robot
    own = robot.model(tuple(getattr(fit.model, "extensions", ())))
    if list(fit.model.names) != list(own.names):
        raise InputError(
            f"{command}: fit is a fit of another model ({fit.model.n_params} parameters) than the arm of "
            f"{problem.path} ({robot.described_as}, {own.n_params} parameters): make it with "
            "ident_opt.fit(problem, trials)"
        )
    pi = np.asarray(fit.pi, dtype=float)
    if pi.shape != (own.n_params,) or not np.isfinite(pi).all():
        raise InputError(f"{command}: fit.pi must be {own.n_params} finite values (one per parameter of the model)")
    return fit


def _output_path(value: object, label: str) -> Path:
    """An output path argument as a `Path`: a str or path object, not empty (as the command line's `--out`)."""
    if not isinstance(value, (str, os.PathLike)):
        raise InputError(f"{label} must be a file or folder name (a str or a path), got {excerpt(value)}")
    if not os.fspath(value).strip():
        raise InputError(f"{label}: an empty path; give a file or folder name")
    return Path(value)


@contextlib.contextmanager
def _writing(problem: Problem, sources: Iterable[str]) -> Iterator[None]:
    """The command line's output rules around an API call that writes (`ident_opt.outputs`): inside a command's run,
    that run; else a run of its own in which the problem's inputs (`_inputs`) are declared first, so that an output
    resolving to one of them is refused, a device, pipe or socket is never replaced, and what a failed call wrote is
    rolled back."""
    if outputs.current() is not None:
        yield
        return
    with outputs.run() as run:
        run.declare_inputs(_inputs(problem, sources))
        yield


def _inputs(problem: Problem, sources: Iterable[str]) -> list[Path]:
    """What a command on `problem` declares as its inputs (`load_problem` and the loader do it inside a run): the
    problem file, its trials, its URDF (and the reference's) with their meshes, and the trial files `sources` name
    (a trial from arrays names no file)."""
    data = problem.data
    paths = [Path(problem.path), *data.trials, *data.train, *data.test]
    reference = getattr(problem.reference, "urdf", None)
    for urdf in (getattr(problem.robot, "urdf", None), reference):
        if urdf is not None:
            paths += [Path(urdf), *_meshes(Path(urdf))]
    return paths + [Path(s) for s in sources if isinstance(s, str) and os.path.isfile(s)]


def _meshes(urdf: Path) -> list[Path]:
    """The mesh files a URDF references (`arm.urdf.meshes`); none when it can no longer be read."""
    from ident_opt.arm.urdf import meshes, read_urdf_text

    try:
        return meshes(urdf, ET.fromstring(read_urdf_text(urdf)))
    except (InputError, ET.ParseError):
        return []


@dataclass
class Checked:
    """What `check` found: the robot's summary (`Robot.summary` with its identifiable base parameters) and the lines
    that describe it, each trial's summary (samples, rate, derivatives, ranges), and the warnings."""

    problem: str
    robot: dict
    lines: list[str]
    trials: list[dict]
    warnings: list[ResultWarning] = field(default_factory=list)

    def as_json(self) -> dict:
        """The `check --json` payload."""
        return {
            "problem": self.problem,
            "robot": self.robot,
            "trials": self.trials,
            "warnings": [w.as_dict() for w in self.warnings],
        }


def check(problem: Problem, training: Sequence[Dataset], testing: Sequence[Dataset] = ()) -> Checked:
    """`ident-opt check`: the problem's robot and every trial summarised, nothing fitted; a held-out trial that is a
    training trial is a warning."""
    checked_problem(problem, "check")
    training = checked_trials(problem, training, "check", "training")
    testing = checked_trials(problem, testing, "check", "testing", required=False)
    robot = problem.robot
    arm = robot.model()
    info = {**robot.summary(), "base_parameters": base_parameters(arm).rank}
    if "urdf" in info:  # as people read it: relative to the working folder when inside it
        info["urdf"] = shown(info["urdf"])
    lines = [f"problem {problem.name!r} ({problem.path}): {robot.headline}", *robot.describe()]
    lines.append(f"  identifiable: {info['base_parameters']} base parameters of the {arm.n_params} of its model")
    trials = [_summary(d) for d in [*training, *testing]]
    return Checked(problem.name, info, lines, trials, held_out_overlap(list(training), list(testing)))


def _summary(trial: Dataset) -> dict:
    """A JSON-able description of one loaded trial."""
    return {
        "source": shown(trial.source),
        "samples": trial.n,
        "duration_s": float(trial.t[-1] - trial.t[0]),
        "rate_hz": trial.rate_hz,
        "derivatives": trial.derivatives,
        "dropped_rows": trial.dropped_rows,
        "extra_columns": list(trial.extra.columns),
        "ranges": {
            name: [[float(arr[:, j].min()), float(arr[:, j].max())] for j in range(arr.shape[1])]
            for name, arr in (("q", trial.q), ("dq", trial.dq), ("ddq", trial.ddq), ("tau", trial.tau))
        },
    }
