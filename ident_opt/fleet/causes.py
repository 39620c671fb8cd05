"""What each cause of a fleet's change explains, from a robot's statistics alone: its columns (directions in π and
the joints they act on) fitted by weighted least squares against the baseline π0 (`tasks.baseline` for the null,
`tasks.evidence` for a change)."""

from __future__ import annotations

import numpy as np

from ident_opt.fitting.fit import solve_normal
from ident_opt.fitting.stats import Stats

#: A block of a cause's columns: directions in π (P, m), or "pi0" (the baseline π0 itself), and the joints (rows of
#: Y, a bool mask) they act on.
Block = tuple[np.ndarray | str, np.ndarray]


def _columns(blocks: list[Block], pi0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A cause's columns: directions A (P, m), π0 for "pi0", and the joints each acts on, (m, n) bool."""
    directions, rows = [], []
    for A, joints in blocks:
        A = pi0[:, None] if isinstance(A, str) else A
        directions.append(A)
        rows += [joints] * A.shape[1]
    return np.hstack(directions), np.array(rows, dtype=float)


def cause_gains(
    causes: dict[str, list[Block]], S: Stats, pi0: np.ndarray, w: np.ndarray
) -> tuple[dict[str, float], np.ndarray, dict]:
    """(gains, drive factors k_j, friction growths) of every cause (`tasks.Setup.causes`: key → its column blocks) on
    statistics S against π0 with joint weights w: each cause's weighted least-squares step δ on the misfit to π0, its
    gain δ·h the misfit it removes."""
    residual = S.b - np.einsum("jpr,r->jp", S.G, pi0)  # b_j − G_j π0
    gains, growth, scale = {}, {}, np.ones(S.n_joints)
    for key, blocks in causes.items():
        A, rows = _columns(blocks, pi0)
        H, h = np.zeros((A.shape[1], A.shape[1])), np.zeros(A.shape[1])
        for j in range(S.n_joints):
            Aj = A * rows[:, j]  # the columns acting on joint j
            H += w[j] * (Aj.T @ S.G[j] @ Aj)
            h += w[j] * (Aj.T @ residual[j])
        delta = solve_normal(H, h)
        gains[key] = float(delta @ h)
        cause, _, joint = key.partition(":")
        if cause == "drive":
            scale[int(joint) - 1] = 1.0 + delta[0]
        elif cause == "wear":
            f = A.T @ pi0
            growth[key] = float(delta @ f / max(f @ f, 1e-300))
    return gains, scale, growth
