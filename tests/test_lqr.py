"""LQR against scipy's Riccati solvers, closed loops, and its failure modes."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from shinro_ctrl.controllers import LQR
from shinro_ctrl.errors import NonFiniteError, NotStabilizable
from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum


def test_discrete_gain_equals_scipy_dare():
    plant = CartPole(dt=0.01)
    Q, R = np.diag([10.0, 1.0, 100.0, 1.0]), np.array([[0.1]])
    ctrl = LQR.from_plant(plant, Q, R)
    A, B = plant.get_model(discretization="step")  # from_plant's default model
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(ctrl.K, K, rtol=1e-9)
    np.testing.assert_allclose(ctrl.S, P, rtol=1e-9)
    np.testing.assert_allclose(np.sort(np.abs(ctrl.poles)), np.sort(np.abs(np.linalg.eigvals(A - B @ K))), rtol=1e-9)
    assert np.all(np.abs(ctrl.poles) < 1)


def test_continuous_gain_equals_scipy_care():
    plant = InvertedPendulum()
    A, B = plant.linearize()
    Q, R = np.diag([5.0, 1.0]), np.array([[0.5]])
    ctrl = LQR.from_plant(plant, Q, R, discrete=False)
    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    np.testing.assert_allclose(ctrl.K, np.linalg.solve(R, B.T @ P), rtol=1e-9)


@pytest.mark.parametrize(
    "plant,Q,R,x_op,x_init,steps",
    [
        (InvertedPendulum(dt=0.01), [10, 1], [0.1], None, [0.3, 0.0], 400),
        (CartPole(dt=0.01), [10, 1, 100, 1], [0.1], None, [0.0, 0.0, 0.2, 0.0], 800),
        (
            DoublePendulum(dt=0.005),
            [100, 100, 1, 1],
            [1, 1],
            [np.pi, np.pi, 0, 0],
            [np.pi + 0.05, np.pi - 0.05, 0.0, 0.0],
            1600,
        ),
    ],
    ids=["pendulum", "cartpole", "double-upright"],
)
def test_lqr_closed_loop_settles_standalone(plant, Q, R, x_op, x_init, steps):
    ctrl = LQR.from_plant(plant, Q, R, x0=x_op)
    plant.set_state(x_init)
    for _ in range(steps):
        plant.step(ctrl(plant.get_state()))
    target = np.zeros(plant.state_dim) if x_op is None else np.asarray(x_op)
    np.testing.assert_allclose(plant.get_state(), target, atol=1e-3)


def test_measured_cost_matches_prediction_on_the_linear_model():
    # Simulate the *linear* discrete model: the realised cost must equal ½ x0ᵀ S x0.
    plant = CartPole(dt=0.01)
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1], [0.1])
    A, B = plant.get_model(discretization="step")  # from_plant's default model
    x = np.array([0.1, 0.0, 0.05, 0.0])
    predicted = ctrl.cost_to_go(x)
    cost = 0.0
    for _ in range(5000):
        u = ctrl(x)
        cost += 0.5 * (x @ ctrl.Q @ x + u @ ctrl.R @ u)
        x = A @ x + B @ u
    assert cost == pytest.approx(predicted, rel=1e-9)


def test_non_stabilizable_pair_names_the_mode():
    A = np.diag([1.2, 0.5])
    B = np.array([[0.0], [1.0]])
    with pytest.raises(NotStabilizable, match=r"λ = 1\.2.*state 'a'"):
        LQR(A, B, [1, 1], [1], state_names=["a", "b"])


def test_unstable_but_reachable_mode_is_fine():
    LQR(np.diag([1.2, 0.5]), np.array([[1.0], [0.0]]), [1, 1], [1])


def test_saturation_and_reference():
    ctrl = LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1], u_min=[-2], u_max=[2])
    assert ctrl([0, 0, 1.0, 0])[0] == -2.0 or ctrl([0, 0, 1.0, 0])[0] == 2.0
    ref = np.array([0.5, 0, 0, 0])
    np.testing.assert_allclose(ctrl(ref, ref=ref), 0.0, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs,exc,match",
    [
        ({"Q": [[1, 2], [0, 1]]}, ValueError, "symmetric"),
        ({"Q": [-1, 1]}, ValueError, "semidefinite"),
        ({"R": [0.0]}, ValueError, "positive definite"),
        ({"Q": [1, 1, 1]}, ValueError, "expected shape"),
        ({"Q": [np.nan, 1]}, NonFiniteError, "finite"),
    ],
)
def test_bad_weights_are_clear_errors(kwargs, exc, match):
    args = {"A": np.eye(2) * 1.1, "B": np.array([[0.0], [1.0]]) + 0.1, "Q": [1, 1], "R": [1]} | kwargs
    with pytest.raises(exc, match=match):
        LQR(args["A"], args["B"], args["Q"], args["R"])


def test_symmetry_check_is_relative():
    # A large, symmetric-up-to-rounding Q must be accepted.
    Q = np.array([[1e8, 3e7 + 1e-3], [3e7, 1e8]])
    LQR(np.eye(2) * 1.1, np.eye(2), Q, [1, 1])


def test_nan_state_is_refused_not_propagated():
    ctrl = LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1], u_min=[-5], u_max=[5])
    for bad in ([np.nan, 0, 0, 0], np.array([0, np.inf, 0, 0])):
        with pytest.raises(NonFiniteError):
            ctrl(bad)
