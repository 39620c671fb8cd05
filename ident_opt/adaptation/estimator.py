"""How an online model's θ follows from its statistics (`Estimator`): fixed, ridge, bounded least squares (on the
statistics or on their square-root factor), the consistent fit re-solved warm, or a fit re-solved from scratch at a
cadence (`Cadence`, with the instruments of a robust fit, `Instruments`); and the box bounds of an arm's base parameters
(`base_bounds`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.consistency import necessarily_nonnegative
from ident_opt.fitting import estimators
from ident_opt.fitting.base import BaseParameters
from ident_opt.fitting.bounded import Bounds, FactorBoundedLS, WarmBoundedLS
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.stats import Stats

#: Samples between two from-scratch re-solves of an estimator without an exact online counterpart (`Cadence`).
CONSISTENT_EVERY = 500


@dataclass
class Estimator:
    """How θ follows from the statistics: ``fixed``, ``ridge`` (with `penalty` (P,) = λ per column, 0 for
    an unpenalised intercept), ``bounded`` (with `bounds`), ``factor`` (the same with the statistics kept as a
    square-root factor of the rows, `fitting.bounded.FactorBoundedLS`: base parameters of an n-joint arm),
    ``consistent`` (with `solver`, an object with `.solve(H, h) -> θ`, e.g. `WarmConsistentLS`) or ``cadence`` (with
    `solver` a `Cadence`: a from-scratch fit every `Cadence.every` samples, θ held in between)."""

    kind: str
    penalty: np.ndarray | None = None
    bounds: Bounds | None = None
    solver: object | None = None

    def make_solver(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """A callable (H, h) -> θ keeping whatever warm-start state the estimator needs."""
        if self.kind in ("fixed", "cadence", "factor"):  # none on (H, h): `OnlineIdentifier.add` asks these itself
            return None
        if self.kind == "ridge":
            D = np.diag(self.penalty)
            return lambda H, h: np.linalg.solve(H + D, h)
        if self.kind == "bounded":
            return WarmBoundedLS(self.bounds).solve
        if self.kind == "consistent":
            return self.solver.solve
        raise ValueError(f"unknown estimator {self.kind!r}")


def lift(base: BaseParameters, stats: Stats) -> Stats:
    """The arm's statistics from those of its base parameters' design (exact: Y = Y_b K, so G = Kᵀ G_b K and
    b = Kᵀ b_b)."""
    K = base.K
    G = np.einsum("bp,jbc,cq->jpq", K, stats.G, K)
    return Stats(G, np.einsum("bp,jb->jp", K, stats.b), stats.s.copy(), stats.n)


@dataclass(frozen=True)
class Instruments:
    """An instrumented estimator's (`estimators.INSTRUMENTED`: the robust fit) statistics for the cadence: the
    training part's instrument statistics `offline` and its least-squares statistics `trained` (both on the arm's
    π; the instruments from the trial, `fitting.iv.InstrumentStats.from_data`). Samples arriving online carry no
    instruments (a stream has one derivative estimate): each enters as its own instrument (Z = Y), i.e. as least
    squares, so the re-solves keep the training part's correction of the noise bias and add the online samples as
    they are."""

    offline: InstrumentStats
    trained: Stats

    def with_online(self, seen: Stats) -> InstrumentStats:
        """The instrument statistics of every sample seen, from the arm's least-squares statistics of them all."""
        t = self.trained
        G, b = seen.G - t.G, seen.b - t.b
        return self.offline + InstrumentStats(G, b, G, Stats(G, b, seen.s - t.s, seen.n - t.n))


class Cadence:
    """An estimator without an exact online counterpart, followed by from-scratch re-solves: every `every` samples,
    `estimators.fit_for(robot, name, …)` on the exact statistics of every sample seen. The online statistics are
    those of the base parameters' design (Y_b, the independent columns); the arm's follow exactly, Y = Y_b K, so
    G = Kᵀ G_b K and b = Kᵀ b_b (`lift`). θ is the base parameters of the fit, K π; `fit` its `LinearFit` (π in
    the arm's own parameters, which the estimator keeps consistent)."""

    def __init__(
        self,
        robot,
        name: str,
        arm: Arm,
        base: BaseParameters,
        every: int = CONSISTENT_EVERY,
        instruments: Instruments | None = None,
    ):
        if every < 1:
            raise ValueError("a cadence needs every ≥ 1 samples")
        if (name in estimators.INSTRUMENTED) != (instruments is not None):
            raise ValueError(f"the {name} fit needs instruments exactly when it is instrumented")
        self.robot, self.name, self.arm, self.base, self.every = robot, name, arm, base, int(every)
        self.instruments = instruments
        self.fit: LinearFit | None = None
        self.refreshed = 0  # re-solves done
        self.seconds = 0.0  # spent in them
        self.least_eigenvalues: list[float] = []  # the fit's consistency measure at each re-solve

    def cold(self) -> Cadence:
        """The same estimator with no history (a from-scratch solve)."""
        return Cadence(self.robot, self.name, self.arm, self.base, self.every, self.instruments)

    def lift(self, stats: Stats) -> Stats:
        """The arm's statistics from those of its base parameters' design (`lift`)."""
        return lift(self.base, stats)

    def refresh(self, stats: Stats) -> np.ndarray:
        """θ = K π of the estimator's fit on `stats` (of the base design); raises what the fit raises."""
        t0 = time.perf_counter()
        lifted = self.lift(stats)
        if self.instruments is not None:
            lifted = self.instruments.with_online(lifted)
        fit = estimators.fit_for(self.robot, self.name, lifted, self.arm)
        if not np.isfinite(fit.pi).all():
            raise FloatingPointError(f"the {self.name} fit gave non-finite parameters")
        self.fit, self.refreshed = fit, self.refreshed + 1
        self.seconds += time.perf_counter() - t0
        self.least_eigenvalues.append(float(fit.min_mass_eigenvalue))
        return self.base.project(fit.pi)


def base_bounds(arm: Arm, base: BaseParameters) -> Bounds:
    """Bounds on the arm's base parameters that every consistent arm satisfies: 0 below those that are
    non-negative for every consistent π (`consistency.necessarily_nonnegative`: exactly those, where the arm's LMIs
    separate per link), else below those whose definition adds parameters of non-negative kind with positive
    coefficients only; free otherwise."""
    definite = necessarily_nonnegative(arm, base.K)
    if definite is None:
        signed = np.array([p.nonnegative for p in arm.parameters])
        K = np.where(np.abs(base.K) > 1e-9 * np.abs(base.K).max(axis=1, keepdims=True), base.K, 0.0)
        definite = np.array([bool(np.all(signed[row != 0]) and np.all(row[row != 0] > 0)) for row in K])
    lower = np.where(definite, 0.0, -np.inf)
    return Bounds(lower, np.full(base.rank, np.inf))


def batch_theta(
    estimator: Estimator,
    stats: Stats,
    theta_fixed: np.ndarray | None = None,
    rows: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The from-scratch (cold-started) solution on `stats` (a ``factor`` estimator's on `rows`, the design rows and
    torques those statistics sum): what the online θ must equal (a cadence estimator's: at the samples where it
    re-solves)."""
    if estimator.kind == "fixed":
        return np.asarray(theta_fixed, dtype=float)
    if estimator.kind == "factor":
        return FactorBoundedLS(estimator.bounds, *rows).solve().pi
    if estimator.kind == "cadence":
        return estimator.solver.cold().refresh(stats)
    H, h, _ = stats.combined()
    fresh = Estimator(
        estimator.kind,
        estimator.penalty,
        estimator.bounds,
        estimator.solver.cold() if estimator.kind == "consistent" else None,
    )
    return fresh.make_solver()(H, h)
