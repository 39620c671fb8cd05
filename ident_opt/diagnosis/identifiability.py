"""Can these data tell? (`docs/effects.md`, "Can these data tell"): how many independent motions the training part
holds and what they leave undetermined, and whether the held-out part is a motion of its own or a repeat of the
training one. Read before anything is named; nothing here is fitted beyond least squares on the joint paths.

- **Independent motions**: the numerical rank of the training part's centred joint paths q (N, n): the singular
  values above `RANK_TOL` × the largest. A joint whose path is a scaled copy of another's, or a combination of
  others' (a right singular vector below the threshold reaches it), is *undetermined*: a cause on it cannot be told
  from the same cause on the joints it copies, nor from the rigid model's parameters the motions leave free.
- **Undetermined parameters**: the rigid model's parameters in the null space of its regressor along the training
  motion beyond the arm's structural one (parameters no motion determines, which the base parameters regroup):
  `undetermined_parameters`.
- **Held out distinct**: the held-out joint path against the nearest training stretch. Each held-out stretch of
  `STRETCH_S` (sampled at `STRETCH_POINTS` instants) is matched to the training stretch closest to it in q (every
  start, every `START_S`); its distance is the RMS over the instants of the Euclidean norm over all joints [rad], and
  the held-out part's is the median over its stretches (`held_out_distance`). Within `REPEAT_RAD` it repeats the
  training motion: its gains are not evidence.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ident_opt.data.dataset import Dataset

#: A singular value of the centred joint paths below this share of the largest is no motion of its own: below 1 % of
#: the largest motion's amplitude (10 mrad on a 1 rad motion), the torques it changes move by about 1 % of gravity's
#: and inertia's swing, a fifth of the naming margin (5 % of the MSE), so no cause can be told on it.
RANK_TOL = 1e-2
#: A joint is undetermined when a right singular vector below `RANK_TOL` reaches it by more than this (its share of
#: that dependent combination).
REACH = 0.1
#: A joint path within this share (RMS) of a multiple of another joint's path is a scaled copy of it (`copies`).
COPY_TOL = 1e-2
#: Length [s] and sampling instants of the stretches compared, and the step [s] between the training stretches' starts.
STRETCH_S, STRETCH_POINTS, START_S = 1.0, 11, 0.02
#: A held-out part whose median stretch lies within this distance [rad] of the training motion repeats it: within
#: 0.02 rad every gravity torque differs by at most 2 % of its amplitude (|sin(q + 0.02) − sin q| ≤ 0.02), below the
#: 5 % naming margin, so the held-out part cannot show what the training part does not.
REPEAT_RAD = 0.02
#: Training stretches and held-out stretches read at most (strided), to bound the nearest-neighbour search.
MOST_STARTS = 20000
#: A rigid parameter direction whose singular value (columns scaled to unit norm along the motion) is below this
#: share of the largest along the motion is undetermined by it (its variance 10⁴ times the best-determined
#: direction's); the structural null space (parameters no motion determines, singular values ~1e-16 on random
#: states) is left out (`undetermined_parameters`). On the KUKA's two motions 10 directions fall below it (the
#: smallest at 3e-3), on the Panda's excitation none (the smallest at 4e-2).
PARAMETER_TOL = 1e-2
#: A parameter is named undetermined when a direction the motion leaves free (beyond the structural ones) reaches
#: it by more than this share.
PARAMETER_REACH = 0.2
#: Samples of the training part the regressor is read on (strided) for `undetermined_parameters`.
PARAMETER_SAMPLES = 1500


@dataclass
class Identifiability:
    """What the data can tell (module doc): the training part's independent motions, the singular values of its
    centred joint paths relative to the largest, the joints and rigid parameters those motions leave undetermined,
    the scaled copies among the joints, the held-out part's distance from the training motion [rad] and whether it
    is a motion of its own, and the trial the gains are scored on."""

    independent_motions: int
    n_joints: int
    singular_values: list[float]
    undetermined_joints: list[int]  # 0-based
    copies: list[dict]  # {"joints", "factors"} (0-based): joints whose paths are scaled copies of the first's
    undetermined_parameters: list[str]
    undetermined_directions: int
    held_out_distance_rad: float
    scored_on: str
    joints: tuple[str, ...] = ()
    notes: list[str] = field(default_factory=list)

    @property
    def held_out_distinct(self) -> bool:
        """Whether the held-out part is a motion of its own (`REPEAT_RAD`): a NaN distance (too short to compare)
        counts as distinct."""
        return not bool(self.held_out_distance_rad <= REPEAT_RAD)

    @property
    def full_rank(self) -> bool:
        return self.independent_motions >= self.n_joints

    def undetermined(self) -> list[str]:
        """The `undetermined` list of the JSON: the joints (each with the joint it copies, if one) and the parameters
        the motions leave undetermined, in words."""
        names = self.joints or tuple(f"joint {j + 1}" for j in range(self.n_joints))
        out = []
        grouped = set()
        for g in self.copies:
            first, rest = g["joints"][0], list(zip(g["joints"][1:], g["factors"][1:]))
            grouped |= set(g["joints"])
            copies = ", ".join(f"{names[j]} {a:.3g} ×" for j, a in rest)
            members = ", ".join(names[j] for j in g["joints"])
            out.append(f"joints {members}: one motion ({copies} {names[first]}'s path)")
        for j in self.undetermined_joints:
            if j not in grouped:
                out.append(f"joint {names[j]}: its path is a combination of the other joints'")
        if self.undetermined_directions:
            shown = ", ".join(self.undetermined_parameters[:12])
            more = len(self.undetermined_parameters) - 12
            out.append(
                f"rigid parameters: {self.undetermined_directions} direction(s) of π that these motions leave free "
                f"beyond the arm's structural ones, reaching {shown}" + (f" and {more} more" if more > 0 else "")
            )
        return out

    def as_json(self) -> dict:
        return {
            "independent_motions": self.independent_motions,
            "undetermined": self.undetermined(),
            "held_out_distinct": self.held_out_distinct,
            "held_out_distance_rad": self.held_out_distance_rad,
            "scored_on": self.scored_on,
            "n_joints": self.n_joints,
            "singular_values_relative": self.singular_values,
            "undetermined_joints": [self.joints[j] if self.joints else j + 1 for j in self.undetermined_joints],
            "undetermined_parameters": self.undetermined_parameters,
            "thresholds": {
                "rank": f"singular values of the centred joint paths above {RANK_TOL:g} × the largest",
                "copy": f"a joint path within {COPY_TOL:.0%} (RMS) of a multiple of another's",
                "parameters": f"directions of the column-scaled regressor below {PARAMETER_TOL:g} × its largest "
                "singular value, beyond the arm's structural null space",
                "repeat": f"held-out stretches of {STRETCH_S:g} s whose median distance (RMS over "
                f"{STRETCH_POINTS} instants of the norm over all joints) to the nearest training stretch is within "
                f"{REPEAT_RAD:g} rad",
            },
            "notes": self.notes,
        }


def motions(q: np.ndarray) -> tuple[int, np.ndarray, list[int], list[dict]]:
    """(independent motions, singular values relative to the largest, undetermined joints (0-based), scaled copies)
    of joint paths q (N, n) (module doc)."""
    x = q - q.mean(axis=0)
    _, s, vt = np.linalg.svd(x[:: max(1, len(x) // 20000)], full_matrices=False)
    rel = s / s[0] if s[0] > 0 else np.zeros_like(s)
    rank = int(np.sum(rel > RANK_TOL))
    low = vt[rank:]
    undetermined = [j for j in range(q.shape[1]) if low.size and float(np.max(np.abs(low[:, j]))) > REACH]
    return rank, rel, undetermined, copies(x, undetermined)


def copies(x: np.ndarray, joints: list[int]) -> list[dict]:
    """The groups of `joints` (0-based) whose centred paths x (N, n) are scaled copies of one another (each within
    `COPY_TOL` of a multiple of another of the group): {"joints": [j, …], "factors": [a_j, …]} with x_j ≈ a_j × x of
    the group's first joint (a_first = 1)."""
    norms = np.linalg.norm(x, axis=0)
    parent = {j: j for j in joints}

    def root(j: int) -> int:
        while parent[j] != j:
            j = parent[j]
        return j

    for a, j in enumerate(joints):
        for i in joints[a + 1 :]:
            if norms[i] == 0 or norms[j] == 0:
                continue
            factor = float(x[:, i] @ x[:, j] / norms[i] ** 2)
            if np.linalg.norm(x[:, j] - factor * x[:, i]) / norms[j] < COPY_TOL:
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for j in joints:
        groups.setdefault(root(j), []).append(j)
    out = []
    for members in groups.values():
        if len(members) < 2:
            continue
        first = members[0]
        out.append({"joints": members, "factors": [float(x[:, first] @ x[:, j] / norms[first] ** 2) for j in members]})
    return out


def _stretches(ds: Dataset, every_s: float) -> np.ndarray | None:
    """(W, STRETCH_POINTS · n): the joint paths of `ds`'s stretches of `STRETCH_S`, one starting every `every_s`
    (at most `MOST_STARTS`), each sampled at `STRETCH_POINTS` instants; None when `ds` is shorter than one."""
    dt = float(np.median(np.diff(ds.t)))
    length = round(STRETCH_S / dt)
    if length < 1 or ds.n <= length:
        return None
    at = np.linspace(0, length, STRETCH_POINTS).round().astype(int)
    step = max(1, round(every_s / dt), -(-(ds.n - length) // MOST_STARTS))
    starts = np.arange(0, ds.n - length, step)
    return np.stack([ds.q[starts + k] for k in at], axis=1).reshape(len(starts), -1)


def held_out_distance(test: Dataset, train: Dataset) -> float:
    """The held-out part's distance [rad] from the training motion (module doc): the median over its stretches of
    the distance to the nearest training stretch; the nearest training sample's when either is shorter than one
    stretch."""
    a, b = _stretches(test, STRETCH_S / (STRETCH_POINTS - 1)), _stretches(train, START_S)
    if a is None or b is None:
        d, _ = cKDTree(train.q[:: max(1, train.n // MOST_STARTS)]).query(test.q[:: max(1, test.n // MOST_STARTS)])
        return float(np.median(d))
    d, _ = cKDTree(b).query(a)
    return float(np.median(d / np.sqrt(STRETCH_POINTS)))


def undetermined_parameters(arm, ds: Dataset, seed: int = 0) -> tuple[int, list[str]]:
    """(directions, names): the rigid model's parameters the motion of `ds` leaves undetermined beyond the arm's
    structural null space (module doc). `arm`: an `Arm` (its `regressor`, `names`, `n_joints`). The regressor along
    the motion is column-equilibrated (each column to unit norm, as `ident-opt excite`'s condition number reads it;
    a column the motion never moves is undetermined outright); the structural null space is read on random states."""
    n = arm.n_joints
    rows = ds.subset(np.unique(np.linspace(0, ds.n - 1, min(ds.n, PARAMETER_SAMPLES)).round().astype(int)))
    rng = np.random.default_rng(seed)
    q, dq, ddq = (rng.uniform(-np.pi, np.pi, size=(PARAMETER_SAMPLES, n)), *rng.normal(size=(2, PARAMETER_SAMPLES, n)))
    Yr = np.asarray(arm.regressor(q, dq, ddq)).reshape(-1, arm.n_params)
    Ym = np.asarray(arm.regressor(rows.q, rows.dq, rows.ddq)).reshape(-1, arm.n_params)
    structural_scale, scale = np.linalg.norm(Yr, axis=0), np.linalg.norm(Ym, axis=0)
    alive = structural_scale > 1e-12 * max(float(structural_scale.max()), np.finfo(float).tiny)
    moving = scale > 1e-9 * max(float(scale.max()), np.finfo(float).tiny)
    use = alive & moving
    structural = _null(Yr[:, use] / structural_scale[use])
    moved = _null(Ym[:, use] / scale[use])
    names = [name for name, ok in zip(arm.names, use) if ok]
    never = [name for name, a, m in zip(arm.names, alive, moving) if a and not m]
    free = np.zeros((len(names), 0))
    if moved.shape[1]:
        extra = moved - structural @ (structural.T @ moved) if structural.shape[1] else moved
        u, s, _ = np.linalg.svd(extra, full_matrices=False)
        free = u[:, s > 0.5]
    reach = np.linalg.norm(free, axis=1) if free.shape[1] else np.zeros(len(names))
    order = np.argsort(-reach)
    return int(free.shape[1]) + len(never), never + [names[i] for i in order if reach[i] > PARAMETER_REACH]


def _null(A: np.ndarray) -> np.ndarray:
    """An orthonormal basis (P, k) of the directions of A's columns (rows ≥ columns) below `PARAMETER_TOL` × its
    largest singular value."""
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    return vt[s < PARAMETER_TOL * (s[0] if len(s) else 1.0)].T


def read(
    train: Dataset,
    test: Dataset,
    arm,
    scored_on: str,
    joints: tuple[str, ...] = (),
    parameters: bool = True,
) -> Identifiability:
    """What the training part `train` and the held-out part `test` can tell (module doc), for the rigid model `arm`;
    `scored_on` names the trial the gains are scored on. `parameters`: read the undetermined rigid parameters too."""
    rank, rel, undetermined, found = motions(train.q)
    directions, names = (0, [])
    if parameters:
        directions, names = undetermined_parameters(arm, train)
    return Identifiability(
        independent_motions=rank,
        n_joints=train.q.shape[1],
        singular_values=[float(v) for v in rel],
        undetermined_joints=undetermined,
        copies=found,
        undetermined_parameters=names,
        undetermined_directions=directions,
        held_out_distance_rad=held_out_distance(test, train),
        scored_on=scored_on,
        joints=tuple(joints),
    )
