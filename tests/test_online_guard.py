"""The GMR extrapolation guard: outside the GMR's training support its residual shrinks toward 0 and the
interval widens to the parametric model's own; on a held-out motion the hybrid is never much worse than the
parametric model alone, and its 95 % intervals cover."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ident_opt.adaptation.start import serving_identifier
from ident_opt.data.loader import load_dataset
from ident_opt.models.gmr import GMR, Support, input_log_density
from ident_opt.problem import load_problem

ROOT = Path(__file__).resolve().parents[1]


def test_support_flags_far_inputs_only():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(3000, 2))
    R = np.sin(X[:, :1]) + 0.05 * rng.normal(size=(3000, 1))
    gmr = GMR(n_components=3).fit(X, R)
    support = Support.fit(gmr, X, quantile=0.005)
    inside = input_log_density(gmr, X) >= support.threshold
    assert 0.99 <= inside.mean() < 1.0
    far = np.array([[8.0, 0.0], [0.0, -9.0]])
    lp = input_log_density(gmr, far)
    assert (lp < support.threshold).all()
    assert all(support.weight(v) < 1e-3 for v in lp) and support.weight(support.threshold + 1) == 1.0


@pytest.fixture(scope="module")
def dfki_replay():
    """DFKI double pendulum: trained on trajectory 00, the swing-up trajectory 12 replayed online."""
    problem = load_problem(ROOT / "problems" / "dfki_c0.toml")
    train = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    test = load_dataset(problem.data.trials[1], problem.data, problem.robot)
    runs = {}
    for label, model, guard in (("guarded", "pbr+gmr", True), ("unguarded", "pbr+gmr", False), ("pbr", "pbr", False)):
        _, ident = serving_identifier(model, problem, train, guard=guard)
        preds = [ident.update(test.q[i], test.dq[i], test.ddq[i], test.tau[i]) for i in range(test.n)]
        runs[label] = (
            np.array([p.tau for p in preds]),
            np.array([p.std for p in preds]),
            np.array([p.extrapolating for p in preds]),
        )
    return test, runs


def _stretches(flags: np.ndarray, min_length: int = 50) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(int), 0]))
    return [(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_length]


def test_guarded_hybrid_on_a_held_out_motion(dfki_replay):
    test, runs = dfki_replay
    tau, std, flags = runs["guarded"]
    pbr = runs["pbr"][0]
    assert flags.mean() > 0.5  # the swing-up leaves the training motion's support
    stretches = _stretches(flags)
    assert stretches
    for a, b in stretches:
        hybrid = np.mean((test.tau[a:b] - tau[a:b]) ** 2, axis=0)
        alone = np.mean((test.tau[a:b] - pbr[a:b]) ** 2, axis=0)
        assert (hybrid <= 1.10 * alone).all(), (a, b, hybrid / alone)
    coverage = np.mean(np.abs(test.tau - tau) <= 1.959964 * std, axis=0)
    assert (coverage >= 0.90).all(), coverage
    # Without the guard the GMR extrapolates: far worse than the parametric model alone.
    unguarded = np.mean((test.tau - runs["unguarded"][0]) ** 2, axis=0)
    assert (unguarded > 2 * np.mean((test.tau - pbr) ** 2, axis=0)).all()
    assert not runs["unguarded"][2].any()  # no flags without a guard
