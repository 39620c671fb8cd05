"""The one statement of physical consistency: which π an arm may have, as a list of named constraints.

What physics requires of π is declared next to the parameters, by the arm (`ident_opt.arm.Arm`):

- each parameter's kind (`ident_opt.parameters`): friction and armature parameters must be ≥ 0 (friction
  dissipates; a reflected rotor inertia N² J is a mass, and M(q) ≻ 0 alone would allow a negative one
  offset by the link inertias). Inertia sums are ≥ 0 as well: the constrained fits leave them to the
  mass-matrix LMIs (no separate constraint, as in the paper's CPBR); box bounds (`physical_bounds`) use
  every non-negative kind.
- `arm.mass_lmis()`: named affine maps A (P, k, k), Σ_p π_p A_p ⪰ margin·I for each being the arm's
  statement of M(q) ≻ 0. The two-link arm's two 2×2 ones, at cos q2 = ±1, are exactly M(q) ⪰ margin·I for
  every q; an arm from a URDF would give one 4×4 pseudo-inertia per link.

`Consistency.of(arm, margin, signs, mass, bounds)` turns them (with optional box bounds) into constraint
objects, each of which gives what every consumer needs, so the statement is written once:

| constraint                         | slack (≥ 0: feasible, ≈ 0: active) | name                       |
|------------------------------------|------------------------------------|----------------------------|
| Σ_p π_p A_p ⪰ margin·I  (k×k)       | λ_min − margin [kg m²]             | the arm's, `mass_pd_q2_0`… |
| π_p ≥ 0 (kind friction, armature)  | π_p                                | `friction_<p>`, `armature_<p>` |
| π_p ≥ lb_p / π_p ≤ ub_p (optional) | π_p − lb_p / ub_p − π_p            | `lower_<p>`, `upper_<p>`   |

| consumer                                   | uses                                                        |
|--------------------------------------------|-------------------------------------------------------------|
| `fitting.fit`: `LinearFit.consistent`     | `sign_violations`, `Arm.min_mass_eigenvalue`                |
| `fitting.constrained`, Clarabel path      | `Consistency.blocks` (A π + s = b, s ∈ cone), `.feasible`   |
| `fitting.constrained`, cvxpy (test oracle) | `Consistency.cvxpy`                                        |
| active sets in reports                     | `Consistency.slacks`                                        |
| `fitting.bounded` (online CPBR)           | `MatrixInequality.rotated_cone` (2×2), `physical_bounds`    |
| `fitting.nlp`                             | `sign_constraints` (bounds of friction parameters)          |
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.parameters import Parameter

#: Kinds whose sign gets its own named constraint "<kind>_<p>": π_p ≥ 0.
SIGN_KINDS = ("friction", "armature")
#: Kinds whose sign follows the centre of mass's side of a joint: fixed only from a reference π.
GEOMETRIC_KINDS = ("coupling", "gravity")
#: The default margin of the constrained fits: M(q) ⪰ MARGIN·I [kg m²].
MARGIN = 1e-6


@dataclass(frozen=True, eq=False)
class Block:
    """One named constraint as numbers for a conic solver: A π + s = b with s in `cone` — "nonneg"
    (s ≥ 0 elementwise, `size` rows) or "psd" (a `size`×`size` PSD matrix in Clarabel's order, `svec`)."""

    name: str
    A: np.ndarray  # (m, P)
    b: np.ndarray  # (m,)
    cone: str
    size: int


def svec(S: np.ndarray) -> np.ndarray:
    """Scaled vectorisation of symmetric k×k matrices (..., k, k) → (..., k(k+1)/2): the upper triangle
    column by column, off-diagonal entries × √2, so ⟨X, Y⟩ = svec X · svec Y (Clarabel's PSD triangle)."""
    cols, rows = np.tril_indices(S.shape[-1])  # (row, col) of the lower triangle = (col, row) of the upper
    scale = np.where(rows == cols, 1.0, np.sqrt(2.0))
    return S[..., rows, cols] * scale


@dataclass(frozen=True, eq=False)
class MatrixInequality:
    """Σ_p π_p A_p ⪰ margin·I with A = `maps` (P, k, k) symmetric: one of the arm's mass-matrix LMIs."""

    name: str
    maps: np.ndarray
    margin: float = 0.0

    @property
    def size(self) -> int:
        """k, the side of the matrix."""
        return self.maps.shape[-1]

    def matrix(self, pi: np.ndarray) -> np.ndarray:
        """Σ_p π_p A_p (k, k) [kg m² for the two-link arm]."""
        return np.tensordot(pi, self.maps, 1)

    def slack(self, pi: np.ndarray) -> float:
        """λ_min(Σ_p π_p A_p) − margin: ≥ 0 feasible."""
        return float(np.linalg.eigvalsh(self.matrix(pi))[0] - self.margin)

    def block(self, n_params: int) -> Block:
        """s = svec(Σ_p π_p A_p − margin·I) ∈ PSD: A = −svec(A_p) per column, b = −margin svec I."""
        return Block(self.name, -svec(self.maps).T, -self.margin * svec(np.eye(self.size)), "psd", self.size)

    def cvxpy(self, pi):
        """The cvxpy constraint for the variable `pi`."""
        return sum(pi[p] * self.maps[p] for p in range(len(self.maps))) >> self.margin * np.eye(self.size)

    def rotated_cone(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(gp, gs, gr), each (P,): a 2×2 LMI [[p, r], [r, s]] ⪰ margin·I with p = gp·π, s = gs·π, r = gr·π,
        i.e. p − m ≥ 0, s − m ≥ 0, (p − m)(s − m) ≥ r²: a rotated second-order cone (the online solver's)."""
        if self.size != 2:
            raise ValueError(
                f"mass LMI {self.name!r} is {self.size}×{self.size}: the warm-started online solver handles 2×2 "
                "LMIs only (use identify.constrained.solve_constrained for this arm)"
            )
        return self.maps[:, 0, 0], self.maps[:, 1, 1], self.maps[:, 0, 1]


@dataclass(frozen=True)
class Bound:
    """π_p ≥ value (`lower`) or π_p ≤ value: a sign constraint (value 0) or a box bound; p = `index`."""

    name: str
    index: int
    value: float
    lower: bool = True

    def slack(self, pi: np.ndarray) -> float:
        """π_p − value (lower) or value − π_p (upper): ≥ 0 feasible."""
        return float(pi[self.index] - self.value) if self.lower else float(self.value - pi[self.index])

    def block(self, n_params: int) -> Block:
        """s = π_p − value = −(−e_p)π + (−value), or value − π_p: one non-negative row."""
        row = np.zeros((1, n_params))
        row[0, self.index] = -1.0 if self.lower else 1.0
        return Block(self.name, row, np.array([-self.value if self.lower else self.value]), "nonneg", 1)

    def cvxpy(self, pi):
        """The cvxpy constraint for the variable `pi`."""
        return pi[self.index] >= self.value if self.lower else pi[self.index] <= self.value


Constraint = MatrixInequality | Bound


def mass_constraints(arm: Arm, margin: float = MARGIN) -> tuple[MatrixInequality, ...]:
    """The arm's mass-matrix LMIs (`Arm.mass_lmis`), each Σ_p π_p A_p ⪰ margin·I [kg m²]."""
    return tuple(MatrixInequality(name, np.asarray(A, dtype=float), margin) for name, A in arm.mass_lmis().items())


def sign_constraints(parameters: Sequence[Parameter]) -> tuple[Bound, ...]:
    """π_p ≥ 0, named "<kind>_<p>", for every parameter whose kind is in `SIGN_KINDS` (kinds in that
    order, parameters in π's order): decided by the declared kind, never by the name."""
    return tuple(
        Bound(f"{kind}_{p.name}", i, 0.0) for kind in SIGN_KINDS for i, p in enumerate(parameters) if p.kind == kind
    )


def bound_constraints(names: Sequence[str], bounds: tuple[Sequence[float], Sequence[float]]) -> tuple[Bound, ...]:
    """The box bounds "lower_<p>" / "upper_<p>" for every finite entry of (lb, ub) (each (P,) or a scalar)."""
    lb, ub = (np.broadcast_to(np.asarray(v, dtype=float), (len(names),)) for v in bounds)
    out = []
    for p, name in enumerate(names):
        if np.isfinite(lb[p]):
            out.append(Bound(f"lower_{name}", p, float(lb[p])))
        if np.isfinite(ub[p]):
            out.append(Bound(f"upper_{name}", p, float(ub[p]), lower=False))
    return tuple(out)


def sign_violations(parameters: Sequence[Parameter], pi: np.ndarray) -> dict[str, list[str]]:
    """Kind → the names of its sign-constrained parameters that are not ≥ 0 at π (empty: signs consistent)."""
    out: dict[str, list[str]] = {}
    for c in sign_constraints(parameters):
        if not c.slack(pi) >= 0:  # NaN counts as a violation
            out.setdefault(parameters[c.index].kind, []).append(parameters[c.index].name)
    return out


def physical_bounds(parameters: Sequence[Parameter], signs_from: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """(lower, upper), each (P,): 0 below every parameter whose kind is non-negative (inertia, friction,
    armature), ±inf elsewhere; with `signs_from` (e.g. the datasheet π), coupling and gravity parameters are
    also kept on the side of zero where that vector has them (the centre of mass's side of the joint)."""
    P = len(parameters)
    lower, upper = np.full(P, -np.inf), np.full(P, np.inf)
    for i, p in enumerate(parameters):
        if p.nonnegative:
            lower[i] = 0.0
        if signs_from is not None and p.kind in GEOMETRIC_KINDS:
            if signs_from[i] > 0:
                lower[i] = 0.0
            elif signs_from[i] < 0:
                upper[i] = 0.0
    return lower, upper


@dataclass(frozen=True, eq=False)
class Consistency:
    """The named constraints on π (P,) for one arm and set of options, in a fixed order: mass LMIs, sign
    constraints, box bounds (module doc). One declaration, read by every consumer."""

    n_params: int
    constraints: tuple[Constraint, ...]

    @classmethod
    def of(
        cls,
        arm: Arm,
        margin: float = MARGIN,
        signs: bool = True,
        mass: bool = True,
        bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> Consistency:
        """The arm's consistency constraints: its mass LMIs ⪰ margin·I [kg m²] (`mass`), the sign
        constraints of its parameters' kinds (`signs`), and lb ≤ π ≤ ub where finite (`bounds`)."""
        return cls(
            arm.n_params,
            (mass_constraints(arm, margin) if mass else ())
            + (sign_constraints(arm.parameters) if signs else ())
            + (bound_constraints(arm.names, bounds) if bounds is not None else ()),
        )

    @property
    def names(self) -> tuple[str, ...]:
        """The constraints' names, in order."""
        return tuple(c.name for c in self.constraints)

    @cached_property
    def lmis(self) -> tuple[MatrixInequality, ...]:
        """The matrix inequalities alone."""
        return tuple(c for c in self.constraints if isinstance(c, MatrixInequality))

    def slacks(self, pi: np.ndarray) -> dict[str, float]:
        """Each constraint's slack at π by name (≥ 0 feasible, ≈ 0 active; LMIs: λ_min − margin)."""
        pi = np.asarray(pi, dtype=float)
        return {c.name: c.slack(pi) for c in self.constraints}

    def blocks(self) -> list[Block]:
        """Each constraint as a numeric block A π + s = b, s ∈ cone (for Clarabel)."""
        return [c.block(self.n_params) for c in self.constraints]

    def cvxpy(self, pi) -> list:
        """Each constraint as a cvxpy constraint on the variable `pi` (P,)."""
        return [c.cvxpy(pi) for c in self.constraints]

    @cached_property
    def _packed(self) -> tuple:
        """What `feasible` needs, as arrays: per LMI size k, the maps (P, L·k·k), the shape (L, k, k) and
        the margins (L,); the indices and values of lower and of upper bounds."""
        groups = []
        for k in sorted({c.size for c in self.lmis}):
            same = [c for c in self.lmis if c.size == k]
            maps = np.concatenate([c.maps.reshape(self.n_params, k * k) for c in same], axis=1)
            groups.append((maps, (len(same), k, k), np.array([c.margin for c in same])))
        bounds = [c for c in self.constraints if isinstance(c, Bound)]
        lower = [(c.index, c.value) for c in bounds if c.lower]
        upper = [(c.index, c.value) for c in bounds if not c.lower]
        return (
            tuple(groups),
            *(np.array([i for i, _ in side], dtype=int) for side in (lower, upper)),
            *(np.array([v for _, v in side], dtype=float) for side in (lower, upper)),
        )

    def feasible(self, pi: np.ndarray) -> bool:
        """Every slack ≥ 0 at π: the test of `slacks`, vectorised (the constrained fit's shortcut)."""
        groups, lower_index, upper_index, lower, upper = self._packed
        for maps, shape, margins in groups:
            if np.any(np.linalg.eigvalsh(np.dot(pi, maps).reshape(shape))[:, 0] - margins < 0):
                return False
        # π_p − lb_p ≥ 0 ⇔ π_p ≥ lb_p exactly in IEEE arithmetic (and likewise for ub_p − π_p).
        return bool(np.all(pi[lower_index] >= lower) and np.all(pi[upper_index] <= upper))


def lmi_eigenvalues(arm: Arm, pi: np.ndarray) -> dict[str, float]:
    """λ_min [kg m²] of each of the arm's mass LMIs at π, by name (< 0: that statement of consistency fails)."""
    pi = np.asarray(pi, dtype=float)
    return {name: float(np.linalg.eigvalsh(np.tensordot(pi, A, 1))[0]) for name, A in arm.mass_lmis().items()}


def _separable(arm: Arm) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Per LMI (its parameters, the (m, m) basis with K·π = tr(S J(π)) ⇔ K_support = basis @ upper(S)), when
    the LMIs act on disjoint sets of parameters whose maps span the symmetric matrices of their size (one
    pseudo-inertia per link); None otherwise (e.g. the planar arm's two LMIs share every inertial parameter)."""
    out, seen = [], set()
    for A in arm.mass_lmis().values():
        k = A.shape[1]
        support = np.flatnonzero(np.abs(A).reshape(len(A), -1).max(axis=1) > 0)
        rows, cols = np.triu_indices(k)
        if seen & set(support.tolist()) or len(support) != len(rows):
            return None
        seen |= set(support.tolist())
        basis = A[support][:, rows, cols] * np.where(rows == cols, 1.0, 2.0)  # tr(S A_p) = Σ_upper scale S_rc A_rc
        if abs(np.linalg.det(basis)) < 1e-12:
            return None
        out.append((support, basis))
    return out


def necessarily_nonnegative(arm: Arm, K: np.ndarray, tol: float = 1e-9) -> np.ndarray | None:
    """For each row k of K (B, P): is K_k · π ≥ 0 for every consistent π (mass LMIs ⪰ 0, friction and armature
    ≥ 0)? The consistent set is a cone, so that holds exactly when K_k is in its dual: on each LMI's parameters
    the symmetric S with K_k · π = tr(S J(π)) is ⪰ 0, on the sign-constrained parameters the coefficient is ≥ 0,
    on the others 0. None when the arm's LMIs do not separate so (`_separable`): the test would need a program."""
    blocks = _separable(arm)
    if blocks is None:
        return None
    in_lmi = np.zeros(arm.n_params, dtype=bool)
    for support, _ in blocks:
        in_lmi[support] = True
    signed = np.array([p.kind in SIGN_KINDS for p in arm.parameters])
    out = []
    for row in K:
        rest = row[~in_lmi]
        ok = bool(np.all(rest[signed[~in_lmi]] >= -tol) and np.all(np.abs(rest[~signed[~in_lmi]]) <= tol))
        for support, basis in blocks:
            k = round((np.sqrt(8 * len(support) + 1) - 1) / 2)
            upper = np.linalg.solve(basis, row[support])
            S = np.zeros((k, k))
            S[np.triu_indices(k)] = upper
            S = S + np.triu(S, 1).T
            ok = ok and np.linalg.eigvalsh(S)[0] >= -tol * max(1.0, np.abs(S).max())
        out.append(ok)
    return np.array(out)
