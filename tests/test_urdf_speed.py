"""The URDF regressor's compiled path (generated C of the CasADi model, called on chunks of samples) against
Pinocchio's per-sample regressor, its fallback without a C compiler, and its cache of compiled libraries.
The speed itself is measured by benchmarks/bench_urdf.py, not here (timings on a shared machine are noise)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ident_opt.arm.chain import ChainArm
from ident_opt.cbuild import REGRESSOR_CHUNK

ROOT = Path(__file__).resolve().parents[1]
ARMS = {
    "kuka": ("kuka_lwr4/kuka_lwr4.urdf", tuple(f"lwr_{i}_joint" for i in range(7)), ()),
    "panda": ("franka_panda/panda.urdf", tuple(f"panda_joint{i}" for i in range(1, 8)), ()),
    "tx40": ("staubli_tx40/tx40.urdf", tuple(f"joint_{i}" for i in range(1, 7)), (("joint_6", "joint_5", 1.0),)),
}


def _arm(which: str) -> ChainArm:
    path, joints, couplings = ARMS[which]
    return ChainArm(str(ROOT / "data" / path), joints, offsets=True, couplings=couplings)


def _states(arm: ChainArm, n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    size = (n, arm.n_joints)
    q, dq, ddq = rng.uniform(-np.pi, np.pi, size), rng.uniform(-2, 2, size), rng.uniform(-5, 5, size)
    dq[:3] = 0.0  # sign(0) = 0 in both paths
    return q, dq, ddq


@pytest.mark.parametrize("which", sorted(ARMS))
def test_compiled_regressor_is_pinocchios(which, monkeypatch):
    """Several full chunks and a partial one: every entry within 1e-10 of the Pinocchio path."""
    arm = _arm(which)
    assert arm._compiled_regressor is not None, "a C compiler is available here, so the compiled path must be used"
    q, dq, ddq = _states(arm, 2 * REGRESSOR_CHUNK + 37)
    Y = arm.regressor(q, dq, ddq)
    monkeypatch.setenv("IDENT_OPT_REGRESSOR", "pinocchio")
    reference = _arm(which)
    assert reference._compiled_regressor is None
    expected = reference.regressor(q, dq, ddq)
    assert Y.shape == expected.shape == (len(q), arm.n_joints, arm.n_params)
    assert np.abs(Y - expected).max() <= 1e-10
    one = arm.regressor(q[5], dq[5], ddq[5])  # a single sample (one partial chunk)
    assert np.abs(one[0] - expected[5]).max() <= 1e-10


def test_without_a_compiler_the_regressor_is_pinocchios(tmp_path, monkeypatch):
    """An empty cache and no working compiler: no error, Pinocchio's regressor instead."""
    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    arm = _arm("tx40")
    assert arm._compiled_regressor is None
    q, dq, ddq = _states(arm, 4)
    assert arm.regressor(q, dq, ddq).shape == (4, 6, arm.n_params)


def test_compiled_library_is_cached(tmp_path, monkeypatch):
    """The first arm compiles into the cache; a second arm of the same model loads it without compiling."""
    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path))
    assert _arm("tx40")._compiled_regressor is not None
    libraries = list((tmp_path / "regressor").iterdir())
    assert len(libraries) == 1 and libraries[0].name.startswith("liburdf_regressor_")
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))  # a compile would now fail
    assert _arm("tx40")._compiled_regressor is not None


def test_threads_share_one_compiled_regressor():
    """The compiled path has one CasADi buffer per arm: concurrent callers take turns and get their own rows."""
    from concurrent.futures import ThreadPoolExecutor

    arm = _arm("kuka")
    states = [_states(arm, REGRESSOR_CHUNK + 11, seed=s) for s in range(4)]
    alone = [arm.regressor(*x) for x in states]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda x: arm.regressor(*x), states * 3))
    for k, Y in enumerate(together):
        np.testing.assert_array_equal(Y, alone[k % 4])
