"""The one statement of physical consistency (ident_opt.consistency) and the Arm interface (ident_opt.arm):
every constraint says the same thing as a slack, a Clarabel block and a cvxpy constraint; signs come from
declared kinds, not names; any arm that implements the interface gets its constraints, fits and C code."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import cvxpy as cp
import numpy as np
import pytest

from ident_opt.arm.base import Arm
from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import EXTENSIONS, RIGID, PlanarArm
from ident_opt.consistency import (
    Bound,
    Consistency,
    MatrixInequality,
    physical_bounds,
    sign_constraints,
    sign_violations,
)
from ident_opt.evaluation.constraints import multisine_trial
from ident_opt.fitting import constrained
from ident_opt.fitting.bounded import default_bounds
from ident_opt.fitting.bounded_consistent import WarmConsistentLS
from ident_opt.fitting.constrained import ACTIVE_TOL, fit_constrained, solve_constrained
from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.stats import Stats
from ident_opt.parameters import Parameter
from ident_opt.shipping import codegen

ARM = PlanarArm(("armature",))
#: A parameter no name rule could know: a made-up quadratic drag k·dq1·|dq1| on joint 1, of kind friction.
DRAG = Parameter("kq1", "N m s^2/rad^2", "made-up quadratic drag on joint 1 (test only)", "friction")


@dataclass(frozen=True)
class DragArm:
    """A second `Arm` (test only): `base` plus the column of DRAG. Nothing outside this class knows it."""

    base: PlanarArm = RIGID
    extra: Parameter = DRAG

    @property
    def n_joints(self) -> int:
        return self.base.n_joints

    @property
    def names(self) -> tuple[str, ...]:
        return (*self.base.names, self.extra.name)

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        return (*self.base.parameters, self.extra)

    @property
    def n_params(self) -> int:
        return self.base.n_params + 1

    @property
    def drive_matrix(self) -> np.ndarray:
        return self.base.drive_matrix

    def vector(self, pi) -> np.ndarray:
        return np.array([pi.get(n, 0.0) for n in self.names], dtype=float)

    def as_dict(self, pi) -> dict[str, float]:
        return dict(zip(self.names, map(float, pi)))

    def regressor(self, q, dq, ddq) -> np.ndarray:
        dq = np.atleast_2d(dq)
        drag = np.zeros((len(dq), self.n_joints, 1))
        drag[:, 0, 0] = dq[:, 0] * np.abs(dq[:, 0])
        return np.concatenate([self.base.regressor(q, dq, ddq), drag], axis=2)

    def predict(self, pi, q, dq, ddq) -> np.ndarray:
        return self.regressor(q, dq, ddq) @ np.asarray(pi, dtype=float)

    def tau_expression(self, q, dq, ddq, pi):
        drag = ca.vertcat(pi[-1] * dq[0] * ca.fabs(dq[0]), *([0] * (self.n_joints - 1)))
        return self.base.tau_expression(q, dq, ddq, pi[: self.base.n_params]) + drag

    @cached_property
    def symbols(self) -> dict:
        n = self.n_joints
        s = {"q": ca.SX.sym("q", n), "dq": ca.SX.sym("dq", n), "ddq": ca.SX.sym("ddq", n)}
        s["pi"] = ca.SX.sym("pi", self.n_params)
        base = self.base.symbols
        inner = ca.Function("b", [base["q"], base["dq"], base["ddq"], base["pi"]], [base["M"]])
        s["M"] = inner(s["q"], s["dq"], s["ddq"], s["pi"][: self.base.n_params])
        s["tau"] = self.tau_expression(s["q"], s["dq"], s["ddq"], s["pi"])
        s["Y"] = ca.jacobian(s["tau"], s["pi"])
        return s

    def function(self, what: str) -> ca.Function:
        s = self.symbols
        return ca.Function(what, [s["q"], s["dq"], s["ddq"], s["pi"]], [s[what]], ["q", "dq", "ddq", "pi"], [what])

    def mass_lmis(self) -> dict[str, np.ndarray]:
        return {name: np.concatenate([A, np.zeros((1, *A.shape[1:]))]) for name, A in self.base.mass_lmis().items()}

    def mass_matrices(self, pi, q) -> np.ndarray:
        return self.base.mass_matrices(np.asarray(pi)[:-1], q)

    def min_mass_eigenvalue(self, pi) -> float:
        return self.base.min_mass_eigenvalue(np.asarray(pi)[:-1])

    consistency_measure = "min eig M(q) [kg m²]"

    @property
    def extensions(self) -> tuple[str, ...]:
        return self.base.extensions

    def link_masses(self, pi) -> dict[str, float]:
        return {}

    def settings(self) -> dict:
        return {"drag": True}


@dataclass(frozen=True)
class BorderedArm(DragArm):
    """DragArm whose mass LMIs are bordered to 3×3 (test only): [[M, v], [vᵀ, a1]] with v = (0.1 a2, 0.2 a3),
    an affine map with entries in every svec position, so the Clarabel encoding of k > 2 is exercised."""

    def mass_lmis(self) -> dict[str, np.ndarray]:
        out = {}
        i = {n: self.names.index(n) for n in ("a1", "a2", "a3")}
        for name, A in super().mass_lmis().items():
            B = np.zeros((len(A), 3, 3))
            B[:, :2, :2] = A
            B[i["a1"], 2, 2] = 1.0
            B[i["a2"], 0, 2] = B[i["a2"], 2, 0] = 0.1
            B[i["a3"], 1, 2] = B[i["a3"], 2, 1] = 0.2
            out[name] = B
        return out


@pytest.fixture(scope="module")
def truth(physical_problem):
    return ARM.vector(datasheet_pi(physical_problem.robot, "physical"))


def _stats(model, trial):
    return Stats.from_data(model, trial.q, trial.dq, trial.ddq, trial.tau)


def _cvxpy_slack(constraint) -> float:
    """A cvxpy constraint's own slack at its variables' values: λ_min for PSD, rhs − lhs for ≤."""
    value = np.asarray(constraint.expr.value, dtype=float)
    return float(np.linalg.eigvalsh(value)[0]) if isinstance(constraint, cp.constraints.PSD) else float(-value)


def _block_slack(block, pi: np.ndarray) -> float:
    """The slack a Clarabel block states at π: s = b − Aπ, non-negative rows or the k×k matrix of s
    (Clarabel's documented order: the upper triangle column by column, off-diagonals × √2)."""
    s = block.b - block.A @ pi
    if block.cone == "nonneg":
        return float(s.min())
    k = block.size
    S, pos = np.zeros((k, k)), 0
    for col in range(k):
        for row in range(col + 1):
            S[row, col] = S[col, row] = s[pos] if row == col else s[pos] / np.sqrt(2.0)
            pos += 1
    return float(np.linalg.eigvalsh(S)[0])


def test_arm_model_satisfies_the_arm_protocol():
    for model in (RIGID, ARM, PlanarArm(tuple(EXTENSIONS)), PlanarArm(gravity="paper"), DragArm()):
        assert isinstance(model, Arm)
        assert model.regressor(np.zeros((3, 2)), np.ones((3, 2)), np.ones((3, 2))).shape == (
            3,
            model.n_joints,
            model.n_params,
        )
        assert [p.name for p in model.parameters] == list(model.names)
    assert not isinstance(object(), Arm)


def test_two_link_mass_lmis_are_m_at_cos_q2_plus_minus_one(truth):
    lmis = ARM.mass_lmis()
    assert list(lmis) == ["mass_pd_q2_0", "mass_pd_q2_pi"]
    for (name, A), q2 in zip(lmis.items(), (0.0, np.pi)):
        assert A.shape == (ARM.n_params, 2, 2) and np.array_equal(A, A.transpose(0, 2, 1))
        np.testing.assert_allclose(np.tensordot(truth, A, 1), ARM.mass_matrix(truth, q2), atol=1e-15, err_msg=name)
    q = np.random.default_rng(0).uniform(-3, 3, (5, 2))
    np.testing.assert_array_equal(ARM.mass_matrices(truth, q), ARM.mass_matrix(truth, q[:, 1]))


@pytest.mark.parametrize("model", [ARM, BorderedArm(ARM)], ids=["two-link", "bordered-3x3"])
def test_every_constraint_states_the_same_thing_as_slack_block_and_cvxpy(model):
    """At random π, feasible or not: each constraint's slack equals what its Clarabel block and its cvxpy
    constraint say (λ_min − margin for matrices, the bound's distance for bounds)."""
    lb, ub = np.full(model.n_params, -np.inf), np.full(model.n_params, np.inf)
    lb[model.names.index("b1")], ub[model.names.index("b2")] = 3.0, 0.5
    declared = Consistency.of(model, margin=1e-3, bounds=(lb, ub))
    assert {type(c) for c in declared.constraints} == {MatrixInequality, Bound}
    var = cp.Variable(model.n_params)
    oracle = declared.cvxpy(var)
    rng = np.random.default_rng(3)
    for _ in range(50):
        pi = rng.normal(0.0, 1.0, model.n_params)
        var.value = pi
        slacks = declared.slacks(pi)
        for c, block, con in zip(declared.constraints, declared.blocks(), oracle):
            assert block.name == c.name
            assert _block_slack(block, pi) == pytest.approx(slacks[c.name], abs=1e-12)
            assert _cvxpy_slack(con) == pytest.approx(slacks[c.name], abs=1e-12)
        assert declared.feasible(pi) == (min(slacks.values()) >= 0)


def test_slacks_equal_the_cvxpy_oracle_and_the_clarabel_active_set(truth):
    """On short trials where constraints bind: at the cvxpy oracle's optimum, the declaration's slacks equal
    what the oracle's constraints (generated from it) evaluate to, and the slacks that vanish there are
    exactly the Clarabel fit's active set."""
    declared = Consistency.of(ARM, margin=1e-5)
    var = cp.Variable(ARM.n_params)
    binding = 0
    for seed in range(4):
        amp = (0.8, 0.05) if seed % 2 else (0.05, 0.8)
        st = _stats(ARM, multisine_trial(ARM, truth, duration=2.5, seed=700 + seed, amplitude=amp))
        fast = fit_constrained(st, ARM, margin=1e-5, shortcut=False)
        oracle = fit_constrained(st, ARM, margin=1e-5, shortcut=False, backend="cvxpy")
        var.value = oracle.pi
        slacks = declared.slacks(oracle.pi)
        assert list(slacks) == list(declared.names)
        for name, con in zip(slacks, declared.cvxpy(var)):
            assert _cvxpy_slack(con) == pytest.approx(slacks[name], abs=1e-12)
        assert fast.active == oracle.active == [n for n, v in slacks.items() if v < ACTIVE_TOL]
        binding += bool(fast.active)
    assert binding >= 2  # the test exercises active constraints


def test_signs_come_from_kinds_not_names():
    made_up = (
        Parameter("zz", "N m", "a made-up friction", "friction"),
        Parameter("fv_like_but_other", "N m", "a name that looks like friction", "other"),
        Parameter("rotor", "kg m^2", "a made-up armature", "armature"),
    )
    assert [(c.name, c.index) for c in sign_constraints(made_up)] == [("friction_zz", 0), ("armature_rotor", 2)]
    assert sign_violations(made_up, np.array([-1.0, -1.0, 1.0])) == {"friction": ["zz"]}
    lower, upper = physical_bounds(made_up)
    assert lower.tolist() == [0.0, -np.inf, 0.0] and np.all(upper == np.inf)
    # The two-link arm's sign constraints, as before: friction (fv, fc, fs) then armature (ia), by kind.
    big = PlanarArm(tuple(EXTENSIONS))
    assert list(constrained.sign_constraints(big)) == [
        f"friction_{n}" for n in big.names if n.startswith(("fv", "fc", "fs"))
    ] + ["armature_ia2"]


def test_a_new_friction_parameter_is_constrained_everywhere_by_its_kind(truth):
    """DragArm's kq1 matches no name rule: only its kind makes it ≥ 0 in the OLS report, the constrained
    fit, the box bounds and the online CPBR solver."""
    arm = DragArm(ARM)
    pi_true = np.append(truth, -0.05)  # a negative "drag": OLS reproduces it, physics forbids it
    trial = multisine_trial(arm, pi_true, duration=20.0, seed=4, amplitude=(0.9, 0.6), noise=(0.05, 0.05))
    st = _stats(arm, trial)
    assert "friction_kq1" in Consistency.of(arm).names
    ols = fit_ols(st, arm)
    assert ols.as_dict()["kq1"] < 0 and not ols.friction_ok and not ols.consistent
    assert ols.min_mass_eigenvalue > 0 and "negative friction: kq1" in ols.warnings[-1]
    con = fit_constrained(st, arm)
    assert con.as_dict()["kq1"] >= -1e-9 and "friction_kq1" in con.active and con.consistent
    bounds = default_bounds(arm)
    assert bounds.lower[-1] == 0.0
    online = WarmConsistentLS(arm, bounds).solve(*st.combined()[:2])
    assert online[-1] >= 0.0
    ref = fit_constrained(st, arm, friction=False, bounds=(bounds.lower, bounds.upper)).pi
    assert np.max(np.abs(online - ref)) <= 1e-7 * np.max(np.abs(ref))


def test_codegen_needs_only_the_interface(truth):
    arm = DragArm(ARM)
    pi = np.append(truth, 0.02)
    tau_hat, ddq_hat = codegen.build_functions(arm, pi)
    rng = np.random.default_rng(5)
    q, dq, ddq = (rng.normal(size=(200, 2)) for _ in range(3))
    tau = codegen.evaluate(tau_hat, q, dq, ddq)
    np.testing.assert_allclose(tau, arm.predict(pi, q, dq, ddq), rtol=1e-12, atol=1e-12)
    assert codegen.forward_backward_error(arm, pi, q, dq, tau, codegen.evaluate(ddq_hat, q, dq, tau)) < 1e-14


def test_larger_lmis_go_to_clarabel_and_are_refused_by_the_online_cones(truth):
    """A 3×3 LMI: the Clarabel blocks (general svec) and the cvxpy statement give the same optimum with it
    binding; the warm online solver, built for 2×2 rotated cones, refuses it by name."""
    arm = BorderedArm(ARM)
    st = _stats(arm, multisine_trial(arm, np.append(truth, 0.0), duration=2.0, seed=702, amplitude=(0.05, 0.8)))
    assert not fit_ols(st, arm).consistent
    a = solve_constrained(st, arm, margin=1e-5)
    b = solve_constrained(st, arm, margin=1e-5, backend="cvxpy", shortcut=False)
    slacks = Consistency.of(arm, margin=1e-5).slacks(a)
    assert min(slacks.values()) >= -1e-8 and min(v for k, v in slacks.items() if k.startswith("mass")) < ACTIVE_TOL
    assert st.rss(a).sum() == pytest.approx(st.rss(b).sum(), rel=1e-7)
    with pytest.raises(ValueError, match=r"mass_pd_q2_0.*3×3.*2×2"):
        WarmConsistentLS(arm, default_bounds(arm))
