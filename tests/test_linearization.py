"""Exact vs finite-difference Jacobians, closed forms, and the discretizations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from shinro_ctrl.linearization import compare, discretize, fd_jacobians
from shinro_ctrl.plants import CartPole, InvertedPendulum

from .conftest import PENDULUM_FAMILY, random_params


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_exact_matches_fd_at_random_points_and_parameters(cls, rng):
    for _ in range(5):
        plant = cls(**random_params(cls, rng))
        x0 = rng.normal(size=plant.state_dim)
        u0 = rng.normal(size=plant.input_dim)
        A, B = plant.linearize(x0, u0, method="exact")
        Af, Bf = plant.linearize(x0, u0, method="fd", eps=1e-6)
        scale = max(1.0, np.abs(A).max(), np.abs(B).max())
        np.testing.assert_allclose(A, Af, atol=1e-6 * scale)
        np.testing.assert_allclose(B, Bf, atol=1e-6 * scale)


def test_cartpole_closed_form_at_upright():
    M, m, l, g = 0.7, 0.2, 0.6, 9.81
    plant = CartPole(cart_mass=M, pole_mass=m, pole_length=l, gravity=g)
    A, B = plant.linearize()
    A_ref = np.array([[0, 1, 0, 0], [0, 0, -m * g / M, 0], [0, 0, 0, 1], [0, 0, (M + m) * g / (M * l), 0]])
    B_ref = np.array([[0], [1 / M], [0], [-1 / (M * l)]])
    np.testing.assert_allclose(A, A_ref, atol=1e-12)
    np.testing.assert_allclose(B, B_ref, atol=1e-12)


def test_cartpole_hinge_damping_closed_form():
    # Hinge torque -b·θ̇ (Lagrange), not the seed docstring's -b/(M l²).
    M, m, l, b = 0.5, 0.1, 0.5, 0.03
    A, _ = CartPole(cart_mass=M, pole_mass=m, pole_length=l, damping=b).linearize()
    assert A[3, 3] == pytest.approx(-b * (M + m) / (M * m * l**2), rel=1e-12)
    assert A[1, 3] == pytest.approx(b / (M * l), rel=1e-12)


def test_pendulum_closed_form():
    m, l, b, g = 0.3, 0.8, 0.05, 9.81
    A, B = InvertedPendulum(mass=m, length=l, damping=b, gravity=g).linearize()
    np.testing.assert_allclose(A, [[0, 1], [g / l, -b / (m * l**2)]], atol=1e-12)
    np.testing.assert_allclose(B, [[0], [1 / (m * l**2)]], atol=1e-12)


def test_exact_is_within_1e9_of_closed_form_at_random_point():
    # Independent reference: the cart-pole accelerations differentiated by hand.
    M, m, l, b, g = 0.5, 0.1, 0.5, 0.02, 9.81
    plant = CartPole(cart_mass=M, pole_mass=m, pole_length=l, damping=b, gravity=g)
    th, thd, F = 0.4, -0.7, 1.3
    A, B = plant.linearize([0.1, 0.2, th, thd], [F])
    s, c = np.sin(th), np.cos(th)
    D = M + m * s**2
    num_x = F + m * l * s * thd**2 - m * g * s * c + b * c * thd / l
    dnum_x_dth = m * l * c * thd**2 - m * g * (c**2 - s**2) - b * s * thd / l
    dD_dth = 2 * m * s * c
    assert A[1, 2] == pytest.approx((dnum_x_dth * D - num_x * dD_dth) / D**2, abs=1e-9)
    assert A[1, 3] == pytest.approx((2 * m * l * s * thd + b * c / l) / D, abs=1e-9)
    assert B[1, 0] == pytest.approx(1 / D, abs=1e-12)
    assert B[3, 0] == pytest.approx(-c / (l * D), abs=1e-12)


def test_fd_jacobians_of_a_linear_map_are_exact():
    rng = np.random.default_rng(0)
    A0, B0 = rng.normal(size=(3, 3)), rng.normal(size=(3, 2))
    A, B = fd_jacobians(lambda X, U: X @ A0.T + U @ B0.T, rng.normal(size=3), rng.normal(size=2), 1e-3)
    np.testing.assert_allclose(A, A0, atol=1e-10)
    np.testing.assert_allclose(B, B0, atol=1e-10)


@pytest.fixture
def linear_pair(rng):
    return rng.normal(size=(4, 4)), rng.normal(size=(4, 2))


def test_zoh_equals_expm_of_augmented_matrix(linear_pair):
    A_c, B_c = linear_pair
    dt = 0.05
    aug = np.zeros((6, 6))
    aug[:4, :4], aug[:4, 4:] = A_c, B_c
    E = scipy.linalg.expm(aug * dt)
    A, B = discretize(A_c, B_c, dt, "zoh")
    np.testing.assert_allclose(A, E[:4, :4], atol=1e-14)
    np.testing.assert_allclose(B, E[:4, 4:], atol=1e-14)


def test_euler_and_rk4_equal_their_series(linear_pair):
    A_c, B_c = linear_pair
    dt = 0.05
    A, B = discretize(A_c, B_c, dt, "euler")
    np.testing.assert_allclose(A, np.eye(4) + dt * A_c, atol=1e-15)
    np.testing.assert_allclose(B, dt * B_c, atol=1e-15)
    mp = np.linalg.matrix_power
    A4, B4 = discretize(A_c, B_c, dt, "rk4")
    A_ref = sum(mp(dt * A_c, k) / _fact(k) for k in range(5))
    B_ref = sum(dt**k * mp(A_c, k - 1) / _fact(k) for k in range(1, 5)) @ B_c
    np.testing.assert_allclose(A4, A_ref, atol=1e-14)
    np.testing.assert_allclose(B4, B_ref, atol=1e-14)


def test_rk4_matches_one_rk4_step_of_the_linear_system(linear_pair):
    A_c, B_c = linear_pair
    dt, x, u = 0.05, np.arange(4.0), np.array([0.3, -0.2])

    def f(z):
        return A_c @ z + B_c @ u

    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    A4, B4 = discretize(A_c, B_c, dt, "rk4")
    np.testing.assert_allclose(A4 @ x + B4 @ u, x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), atol=1e-12)


def test_unknown_discretization_is_a_clear_error(linear_pair):
    with pytest.raises(ValueError, match="valid: euler, zoh, rk4"):
        discretize(*linear_pair, 0.1, "tustin")


def test_get_model_uses_requested_discretization():
    plant = CartPole(dt=0.02)
    A_c, B_c = plant.linearize()
    for method in ("euler", "zoh", "rk4"):
        A, B = plant.get_model(discretization=method)
        A_ref, B_ref = discretize(A_c, B_c, 0.02, method)
        np.testing.assert_allclose(A, A_ref, atol=1e-15)
        np.testing.assert_allclose(B, B_ref, atol=1e-15)
    lm = plant.linear_model(discretization="zoh")
    assert lm.discretization == "zoh" and lm.dt == 0.02 and lm.A.shape == (4, 4)


def test_compare_reports_small_errors():
    cmp = compare(CartPole(), [0, 0, 0.3, 0.1], [0.5])
    assert cmp.max_abs_error < 1e-6
    assert cmp.max_rel_error <= cmp.max_abs_error + 1e-15


def _fact(k: int) -> int:
    return math.factorial(k)


# ------------------------------------------------------------ discretization="step"
def _step_plants():
    from shinro_ctrl.plants import DoublePendulum, HolonomicMobileRobot, MjcfPlant, Quadrotor

    return [
        CartPole(cart_mass=0.7, pole_mass=0.2, pole_length=0.4, damping=0.03, dt=0.02),
        InvertedPendulum(mass=0.3, length=0.6, damping=0.02, dt=0.01),
        DoublePendulum(mass_top=0.2, mass_bottom=0.1, dt=0.005),
        Quadrotor(dt=0.01),
        HolonomicMobileRobot(dt=0.05),
        MjcfPlant("furuta_pendulum.xml"),
    ]


def _central_step_jacobians(plant, x0, u0, eps=1e-6):
    """Independent central differences of the plant's own standalone step ``plant.integrate``."""
    n, m = len(x0), len(u0)
    A, B = np.zeros((n, n)), np.zeros((n, m))
    for i in range(n):
        d = np.zeros(n)
        d[i] = eps
        A[:, i] = (plant.integrate(x0 + d, u0.copy()) - plant.integrate(x0 - d, u0.copy())) / (2 * eps)
    for j in range(m):
        d = np.zeros(m)
        d[j] = eps
        B[:, j] = (plant.integrate(x0.copy(), u0 + d) - plant.integrate(x0.copy(), u0 - d)) / (2 * eps)
    return A, B


@pytest.mark.parametrize("plant", _step_plants(), ids=lambda p: type(p).__name__)
def test_step_model_is_the_jacobian_of_the_plants_own_step_at_random_points(plant):
    rng = np.random.default_rng(7)
    xe, ue = plant.equilibrium()
    for _ in range(4):
        x0 = xe + 0.4 * rng.standard_normal(plant.state_dim)
        u0 = ue + 0.3 * rng.standard_normal(plant.input_dim)
        A, B = plant.get_model(x0, u0, discretization="step")
        A_ref, B_ref = _central_step_jacobians(plant, x0, u0)
        np.testing.assert_allclose(A, A_ref, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(B, B_ref, rtol=1e-6, atol=1e-7)
        # the affine term of the step model is the step itself
        lm = plant.linear_model(x0, u0, discretization="step")
        np.testing.assert_allclose(x0 + plant.discrete_offset(lm), plant.integrate(x0.copy(), u0.copy()), atol=1e-12)


def test_step_model_of_semi_implicit_euler_in_closed_form():
    """v⁺ = v + dt f_v, q⁺ = q + dt v⁺ gives, per position/velocity block,

    A = [[I + dt² F_q, dt I + dt² F_v], [dt F_q, I + dt F_v]], B = [dt² F_u; dt F_u].
    """
    plant = CartPole(dt=0.02)
    dt = 0.02
    A_c, B_c = plant.linearize([0.1, 0.2, 0.3, -0.1], [0.5])
    q, v = [0, 2], [1, 3]
    Fq, Fv, Fu = A_c[np.ix_(v, q)], A_c[np.ix_(v, v)], B_c[v]
    A_ref = np.zeros((4, 4))
    A_ref[np.ix_(v, q)] = dt * Fq
    A_ref[np.ix_(v, v)] = np.eye(2) + dt * Fv
    A_ref[np.ix_(q, q)] = np.eye(2) + dt**2 * Fq
    A_ref[np.ix_(q, v)] = dt * np.eye(2) + dt**2 * Fv
    B_ref = np.zeros((4, 1))
    B_ref[v], B_ref[q] = dt * Fu, dt**2 * Fu
    A, B = plant.get_model([0.1, 0.2, 0.3, -0.1], [0.5], discretization="step")
    np.testing.assert_allclose(A, A_ref, atol=1e-14)
    np.testing.assert_allclose(B, B_ref, atol=1e-14)
    assert np.all(B[q] != 0.0)  # the first predicted position depends on the input (Euler's does not)


def test_controllers_from_a_plant_default_to_the_step_model_get_model_to_euler():
    from shinro_ctrl.controllers import LQR, LinearMPC

    plant = CartPole()
    A_e, B_e = plant.get_model()
    A_c, B_c = plant.linearize()
    np.testing.assert_allclose(A_e, np.eye(4) + plant.dt * A_c, atol=1e-15)  # the seed's documented default
    np.testing.assert_allclose(B_e, plant.dt * B_c, atol=1e-15)
    lqr = LQR.from_plant(plant, [10, 1, 100, 1], [0.1])
    mpc = LinearMPC.from_plant(plant, [10, 1, 100, 1], [0.1], horizon=10)
    A_s, B_s = plant.get_model(discretization="step")
    for ctrl in (lqr, mpc):
        assert ctrl.model.discretization == "step"
        np.testing.assert_allclose(ctrl.model.A, A_s, atol=0)
        np.testing.assert_allclose(ctrl.model.B, B_s, atol=0)
    with pytest.raises(ValueError, match="valid: euler, zoh, rk4, step"):
        plant.get_model(discretization="tustin")
