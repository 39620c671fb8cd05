"""`excite`'s stage function: the trajectory a problem's arm should run next, designed in one call (what
`ident-opt excite` and `ident_opt.excite` both run)."""

from __future__ import annotations

from collections.abc import Sequence

from ident_opt.data.dataset import Dataset
from ident_opt.errors import InputError
from ident_opt.excitation import design as optimal
from ident_opt.excitation import discrimination
from ident_opt.excitation.setup import Setup, make_setup
from ident_opt.problem.spec import Problem
from ident_opt.simulator.fourier import default_base_hz

#: Harmonics per joint of a D- or cond-optimal design (a discriminating one: `discrimination.HARMONICS`).
HARMONICS = 5
#: The criteria: D-optimal, least condition number, T-optimal between two causes.
CRITERIA = ("d", "cond", "discriminate")


def excite(
    problem: Problem,
    trial: Dataset | None = None,
    *,
    criterion: str = "d",
    duration: float = 20.0,
    between: str | None = None,
    harmonics: int | None = None,
    base_hz: float | None = None,
    extensions: Sequence[str] = (),
    starts: int = 6,
    seed: int = 0,
    rate: float = 1000.0,
    workers: int | None = None,
    progress: bool = True,
) -> optimal.Design:
    """The excitation `criterion` asks for on `problem`'s arm, within its `[limits]`: a periodic Fourier motion of
    `duration` [s] (`harmonics` per joint at `base_hz` [Hz]; defaults: 5 near 0.1 Hz, a discriminating design 16 near
    0.25 Hz, with a whole number of periods), sampled at `rate` [Hz], the best of `starts` random starts (`seed`) run
    by `workers` processes (default: the cores available; the design does not depend on it).

    `criterion`: "d" (D-optimal), "cond" (least condition number) or "discriminate" (the motion that best tells the
    two causes `between` = "A,B" apart, fitted on `trial`). `trial` also gives the noise model (the datasheet model's
    RMS residual per joint; None: 1 N m). `extensions`: design for the extended model."""
    if criterion not in CRITERIA:
        raise InputError(f"excite: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    if criterion == "discriminate":
        if not problem.robot.extensions:
            raise InputError(
                "--criterion discriminate tells two causes of the diagnosis apart, which only an arm with model "
                f"extensions has; {problem.robot.described_as} has none: design with --criterion d or cond (and "
                "see `python benchmarks/excitation_benefit.py` for the proof against random motions)"
            )
        harmonics = harmonics or discrimination.HARMONICS
        base_hz = base_hz or default_base_hz(duration, discrimination.BASE_HZ)
    if problem.limits is None:
        raise InputError(
            f"{problem.path}: section [limits] is required to design an excitation (docs/problem-files.md)"
        )
    setup = _setup(problem, trial, duration, harmonics or HARMONICS, base_hz, tuple(extensions))
    search = {
        "starts": starts,
        "seed": seed,
        "rate": rate,
        "progress": progress,
        "workers": optimal.cores() if workers is None else workers,
    }
    if criterion == "discriminate":
        return discrimination.design(setup, problem.robot, trial, between, **search)
    return optimal.design(setup, criterion, **search)


def _setup(
    problem: Problem, trial: Dataset | None, duration: float, harmonics: int, base_hz: float | None, extensions: tuple
) -> Setup:
    """The design's setup (`setup.make_setup`); its errors name the flag or the problem file at fault."""
    try:
        return make_setup(
            problem.robot,
            problem.limits,
            duration,
            harmonics=harmonics,
            base_hz=base_hz,
            extensions=extensions,
            trial=trial,
        )
    except ValueError as exc:  # an unknown extension
        raise InputError(f"--extension: {exc}") from None
    except InputError as exc:
        raise InputError(f"{problem.path}: {exc}") from None
