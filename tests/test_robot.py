"""The arm model against independent references: Pinocchio's RNEA, the paper's printed regressor,
the structure of Lagrangian mechanics (symmetry, Ṁ − 2C skew, energy conservation)."""

from __future__ import annotations

import itertools

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from ident_opt.arm.datasheet import datasheet_pi, grouped, rigid_body
from ident_opt.arm.planar import EXTENSIONS, RIGID, PlanarArm

RNG = np.random.default_rng(7)


def random_states(n: int, rng=RNG):
    q = rng.uniform(-np.pi, np.pi, (n, 2))
    dq = rng.uniform(-3, 3, (n, 2))
    ddq = rng.uniform(-20, 20, (n, 2))
    return q, dq, ddq


def pinocchio_arm(body) -> pin.Model:
    """A two-link planar arm (revolute z axes, gravity along −y) built directly from rigid-body parameters."""
    model = pin.Model()
    model.gravity = pin.Motion(np.array([0.0, -body.gravity, 0.0]), np.zeros(3))
    j1 = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "joint1")
    model.appendBodyToJoint(
        j1, pin.Inertia(body.m1, np.array([body.lc1, 0, 0]), np.diag([1e-4, 1e-4, body.Ic1])), pin.SE3.Identity()
    )
    j2 = model.addJoint(j1, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([body.l1, 0, 0])), "joint2")
    model.appendBodyToJoint(
        j2, pin.Inertia(body.m2, np.array([body.lc2, 0, 0]), np.diag([1e-4, 1e-4, body.Ic2])), pin.SE3.Identity()
    )
    model.armature = np.array(body.armature)
    return model


def test_rnea_matches_pinocchio(physical_problem):
    body = rigid_body(physical_problem.robot, "physical")
    model = pinocchio_arm(body)
    data = model.createData()
    arm = PlanarArm(("armature",))
    pi = arm.vector(datasheet_pi(physical_problem.robot, "physical"))
    for name in ("fv1", "fv2", "fc1", "fc2"):  # Pinocchio's RNEA has no friction
        pi[arm.names.index(name)] = 0.0
    q, dq, ddq = random_states(200)
    ours = arm.predict(pi, q, dq, ddq)
    theirs = np.array([pin.rnea(model, data, q[k], dq[k], ddq[k]) for k in range(len(q))])
    assert np.max(np.abs(ours - theirs)) < 1e-9


def test_pinocchio_mass_matrix_matches(physical_problem):
    body = rigid_body(physical_problem.robot, "physical")
    model = pinocchio_arm(body)
    data = model.createData()
    arm = PlanarArm(("armature",))
    pi = arm.vector(datasheet_pi(physical_problem.robot))
    for q in random_states(20)[0]:
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        assert np.allclose(arm.mass_matrix(pi, q[1]), M, atol=1e-12)


ALL_MODELS = [PlanarArm(ext) for r in range(len(EXTENSIONS) + 1) for ext in itertools.combinations(EXTENSIONS, r)]
ALL_MODELS.append(PlanarArm(gravity="paper"))


@pytest.mark.parametrize("model", ALL_MODELS, ids=lambda m: "+".join(m.extensions) or m.gravity)
def test_numpy_regressor_equals_symbolic_jacobian(model):
    q, dq, ddq = random_states(50)
    dq[0] = 0.0  # sign(0) = 0 in both paths
    Y_np = model.regressor(q, dq, ddq)
    fY = model.function("Y")
    pi = RNG.normal(size=model.n_params)
    for k in range(len(q)):
        Y_ca = np.array(fY(q[k], dq[k], ddq[k], pi))
        assert np.allclose(Y_np[k], Y_ca, rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", ALL_MODELS, ids=lambda m: "+".join(m.extensions) or m.gravity)
def test_regressor_times_pi_is_the_dynamics(model):
    """Y π = M ddq + C dq + G + F with the four terms evaluated separately."""
    fM, fC, fG, fF = (model.function(w) for w in "MCGF")
    q, dq, ddq = random_states(30)
    pi = RNG.normal(size=model.n_params)
    tau = model.predict(pi, q, dq, ddq)
    for k in range(len(q)):
        args = (q[k], dq[k], ddq[k], pi)
        terms = (
            np.array(fM(*args)) @ ddq[k]
            + np.array(fC(*args)) @ dq[k]
            + np.array(fG(*args)).ravel()
            + np.array(fF(*args)).ravel()
        )
        assert np.allclose(tau[k], terms, atol=1e-12)


def test_paper_printed_regressor_columns():
    """The paper's printed Yᵀ (its Eq. for Y), row by row, with g taken out of the gravity columns."""
    q, dq, ddq = random_states(10)
    Y = PlanarArm(gravity="paper").regressor(q, dq, ddq)
    c1, c2, s2, c12 = np.cos(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 1]), np.cos(q[:, 0] + q[:, 1])
    printed = np.stack(
        [
            np.stack([ddq[:, 0], 0 * c1], -1),
            np.stack(
                [
                    2 * c2 * ddq[:, 0] + c2 * ddq[:, 1] - 2 * s2 * dq[:, 0] * dq[:, 1] - s2 * dq[:, 1] ** 2,
                    c2 * ddq[:, 0] + s2 * dq[:, 0] ** 2,
                ],
                -1,
            ),
            np.stack([ddq[:, 1], ddq[:, 0] + ddq[:, 1]], -1),
            np.stack([c1, 0 * c1], -1),
            np.stack([c1 + c12, c12], -1),
            np.stack([dq[:, 0], 0 * c1], -1),
            np.stack([0 * c1, dq[:, 1]], -1),
            np.stack([np.sign(dq[:, 0]), 0 * c1], -1),
            np.stack([0 * c1, np.sign(dq[:, 1])], -1),
        ],
        axis=-1,
    )
    assert np.allclose(Y, printed, atol=1e-14)
    # The physically correct gravity vector differs only in the β2 column of joint 1.
    Y_phys = RIGID.regressor(q, dq, ddq)
    diff = Y - Y_phys
    assert np.allclose(diff[:, 0, 4], c1) and np.count_nonzero(np.abs(diff) > 1e-14) == len(q)


def test_mass_matrix_spd_and_maps(physical_problem):
    arm = PlanarArm(("armature",))
    pi = arm.vector(datasheet_pi(physical_problem.robot))
    fM = arm.function("M")
    for q in random_states(50)[0]:
        M_sym = np.array(fM(q, [0, 0], [0, 0], pi))
        assert np.allclose(M_sym, M_sym.T)
        assert np.linalg.eigvalsh(M_sym)[0] > 0
        assert np.allclose(arm.mass_matrix(pi, q[1]), M_sym, atol=1e-14)
    grid = np.linspace(-np.pi, np.pi, 2001)
    brute = np.linalg.eigvalsh(arm.mass_matrix(pi, grid))[:, 0].min()
    assert arm.min_mass_eigenvalue(pi) == pytest.approx(brute, rel=1e-6)
    assert arm.min_mass_eigenvalue(pi) > 0


def test_min_eigenvalue_detects_inconsistent_parameters():
    pi = RIGID.vector({"a1": 0.75, "a2": 0.05, "a3": -0.034})  # plain OLS on the real trial looks like this
    assert RIGID.min_mass_eigenvalue(pi) < 0


def test_mdot_minus_2c_is_skew_symmetric():
    arm = PlanarArm(("armature",))
    s = arm.symbols
    Mdot = ca.jtimes(s["M"], s["q"], s["dq"])
    f = ca.Function("N", [s["q"], s["dq"], s["pi"]], [Mdot - 2 * s["C"]])
    q, dq, _ = random_states(30)
    pi = np.abs(RNG.normal(size=arm.n_params))
    for k in range(len(q)):
        N = np.array(f(q[k], dq[k], pi))
        assert np.allclose(N, -N.T, atol=1e-12)
        assert np.allclose(
            np.array(arm.function("C")(q[k], dq[k], [0, 0], pi)) @ dq[k], _paper_printed_c(pi, q[k], dq[k]), atol=1e-12
        )


def _paper_printed_c(pi, q, dq):
    a2, s2 = pi[1], np.sin(q[1])
    C = np.array([[-2 * a2 * s2 * dq[1], -a2 * s2 * dq[1]], [a2 * s2 * dq[0], 0.0]])
    return C @ dq


def test_free_motion_conserves_energy(physical_problem):
    """No friction, no input: ½ dqᵀ M dq + V(q) is constant along the forward simulation."""
    body = rigid_body(physical_problem.robot, "physical")
    a1, a2, a3, b1, b2 = grouped(body.m1, body.m2, body.l1, body.lc1, body.lc2, body.Ic1, body.Ic2, body.gravity)
    arm = RIGID
    pi = arm.vector({"a1": a1, "a2": a2, "a3": a3, "b1": b1, "b2": b2})
    fM, fC, fG = (arm.function(w) for w in "MCG")

    def rhs(_, x):
        q, dq = x[:2], x[2:]
        M = np.array(fM(q, dq, [0, 0], pi))
        h = np.array(fC(q, dq, [0, 0], pi)) @ dq + np.array(fG(q, dq, [0, 0], pi)).ravel()
        return np.concatenate([dq, np.linalg.solve(M, -h)])

    def energy(x):
        q, dq = x[:2], x[2:]
        V = b1 * np.sin(q[0]) + b2 * np.sin(q[0] + q[1])  # G = ∂V/∂q
        return 0.5 * dq @ np.array(fM(q, dq, [0, 0], pi)) @ dq + V

    sol = solve_ivp(rhs, (0, 3.0), [0.3, -0.5, 0.0, 1.0], method="DOP853", rtol=1e-11, atol=1e-12, dense_output=True)
    E = np.array([energy(sol.sol(t)) for t in np.linspace(0, 3, 50)])
    assert np.ptp(E) < 1e-7 * (b1 + b2)
    assert np.ptp(sol.y[0]) > 0.5  # it actually moved


def test_vector_and_dict_round_trip():
    arm = PlanarArm(("asymmetric_coulomb", "armature"))
    pi = arm.vector({"a1": 1.0, "fc1": 0.5, "fc2p": 0.7})
    d = arm.as_dict(pi)
    assert d["fc1p"] == 0.5 and d["fc1n"] == 0.5 and d["fc2p"] == 0.7 and d["fc2n"] == 0.0
    assert "fc1" not in arm.names and arm.names[-1] == "ia2"
    with pytest.raises(ValueError):
        PlanarArm(("springs",))
    with pytest.raises(ValueError):
        PlanarArm(("offset",), gravity="paper")
