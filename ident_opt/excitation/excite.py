"""`excite`'s stage function: the trajectory a problem's arm should run next, designed in one call (what
`ident-opt excite` and `ident_opt.excite` both run)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

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
#: Memory [bytes] one output sample (one instant at --rate) takes at the peak of a run, as (fixed, per joint): the
#: samples kept (t, q, dq, ddq, τ: 8 (1 + 4n) B), the CSV's table and its formatting, the figure's 4n lines, and
#: the allocator's slack. Measured as the slope of the peak resident memory against the number of samples
#: (`ident-opt excite` at two rates): 396 B on the planar arm, 985 B on the 7-joint KUKA LWR4+; rounded up ~20 %.
SAMPLE_BYTES = (200, 140)
#: The most memory [bytes] the output of one design may take, however much the machine has: 8 GiB is 1.5e7 samples
#: of a 2-joint arm (an hour at 4 kHz), whose CSV alone is a 1.5 GB file.
MEMORY_CAP = 8 * 2**30
#: The share of the memory available when the run starts that the output may take: the rest is the system's, the
#: other programs' and the design's own (IPOPT, the criteria).
MEMORY_SHARE = 0.5
#: A limit (cgroup, RLIMIT) at or beyond this [bytes] means none.
UNLIMITED = 2**60


def output_bytes(n_joints: int, duration: float, rate: float) -> int:
    """The memory [bytes] the samples of a design of `duration` [s] at `rate` [Hz] take at the run's peak
    (`SAMPLE_BYTES`)."""
    fixed, per_joint = SAMPLE_BYTES
    return round(duration * rate) * (fixed + per_joint * n_joints)


def available_memory() -> tuple[int | None, str]:
    """(bytes this process may still allocate, where the figure comes from): the least of the system's available
    memory (Linux: MemAvailable; else the free physical pages) and what the process's cgroup leaves (v2 memory.max −
    memory.current, v1 limit − usage); (None, …) when no figure is known."""
    found = []
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    found.append((int(line.split()[1]) * 1024, "the memory available on this machine"))
    except (OSError, ValueError):
        pages = _sysconf("SC_AVPHYS_PAGES")
        size = _sysconf("SC_PAGE_SIZE")
        if pages and size:
            found.append((pages * size, "the free memory of this machine"))
    left = _cgroup_left()
    if left is not None:
        found.append((left, "what this process's control group (its container) leaves"))
    if not found:
        return None, "unknown"
    return min(found)


def _sysconf(name: str) -> int | None:
    try:
        value = os.sysconf(name)
    except (ValueError, OSError, AttributeError):
        return None
    return value if value > 0 else None


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text(encoding="ascii").strip()
        return int(text) if text != "max" else None
    except (OSError, ValueError):
        return None


def _cgroup_left() -> int | None:
    """Bytes the process's memory cgroup still allows, or None (no limit, or none readable)."""
    root = Path("/sys/fs/cgroup")
    try:
        lines = Path("/proc/self/cgroup").read_text(encoding="utf-8").splitlines()
    except OSError:
        return None
    for line in lines:
        _, controllers, path = line.split(":", 2) if line.count(":") >= 2 else ("", "", "")
        if controllers == "":  # v2: one hierarchy
            limit, used = (_read_int(root / path.lstrip("/") / f) for f in ("memory.max", "memory.current"))
        elif "memory" in controllers.split(","):  # v1: the memory hierarchy
            folder = root / "memory" / path.lstrip("/")
            if not folder.is_dir():
                folder = root / "memory"
            limit, used = (_read_int(folder / f) for f in ("memory.limit_in_bytes", "memory.usage_in_bytes"))
        else:
            continue
        if limit is not None and limit < UNLIMITED:
            return max(limit - (used or 0), 0)
    return None


def check_output_size(n_joints: int, duration: float, rate: float) -> None:
    """InputError naming --duration and --rate when the design's output (`output_bytes`) would take more memory than
    `MEMORY_SHARE` of what is available (`available_memory`) or `MEMORY_CAP`: said before any work, where the run
    would otherwise allocate it hours later (or be killed for it)."""
    need = output_bytes(n_joints, duration, rate)
    available, where = available_memory()
    bound, why = MEMORY_CAP, f"ident-opt's cap of {MEMORY_CAP / 2**30:g} GiB for one design's output"
    if available is not None and MEMORY_SHARE * available < bound:
        bound, why = int(MEMORY_SHARE * available), f"half of {available / 2**30:.1f} GiB, {where}"
    if need <= bound:
        return
    samples = round(duration * rate)
    most = bound // (need // samples)
    raise InputError(
        f"--duration {duration:g} s at --rate {rate:g} Hz is {samples:,} samples, which would need about "
        f"{need / 2**30:.1f} GiB of memory ({need // samples} bytes a sample on a {n_joints}-joint arm); the bound is "
        f"{bound / 2**30:.1f} GiB ({why}): shorten --duration or lower --rate (at most {most:,} samples, e.g. "
        f"--rate {max(most / duration, 1.0):.0f} for this duration)"
    )


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
    check_output_size(problem.robot.n_joints, duration, rate)
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
