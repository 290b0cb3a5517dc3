"""The EKF update the C export is generated from: sequential scalar corrections and the structured covariance.

``ExtendedKalmanFilter`` processes the measurements one at a time when ``C`` selects states and ``Rn`` is
diagonal, and builds its covariances on their upper triangle from the sparse step Jacobians. These tests hold
it to an independent numpy reference of the batch update (complex-step Jacobians of the RK4 step, the gain
from a ``p × p`` solve, the Joseph form). The exported C of the same function is checked against Python by
``tests/test_export.py`` (pendulum) and ``benchmarks/export.py`` (quadrotor).
"""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.backend import NumpyBackend
from shinro_ctrl.estimators.kalman import ExtendedKalmanFilter
from shinro_ctrl.plants import Quadrotor

POSE = ["x", "y", "z", "roll", "pitch", "yaw"]


def _rk4_complex_step(plant, x, u, h=1e-30):
    """One RK4 step of ``plant.equations`` in numpy and its Jacobians by complex step (independent of CasADi)."""
    bk, dt, n, m = NumpyBackend(), plant.dt, plant.state_dim, plant.input_dim
    params = plant.dynamics_params()

    def f(X, U):
        return np.asarray(plant.equations(bk, X, U, params))

    def step(X, U):
        k1 = f(X, U)
        k2 = f(X + 0.5 * dt * k1, U)
        k3 = f(X + 0.5 * dt * k2, U)
        k4 = f(X + dt * k3, U)
        return X + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    k = n + m
    Z = np.repeat(np.concatenate([x, u]).astype(complex)[None, :], k, axis=0)
    Z[np.arange(k), np.arange(k)] += 1j * h
    J = (step(Z[:, :n], Z[:, n:]).imag / h).T
    return step(np.asarray(x, dtype=float), np.asarray(u, dtype=float)), J[:, :n], J[:, n:]


def _batch_reference(plant, C, Qn, Rn, Qn_on, x, P, u, y, predict):
    """The textbook batch EKF update: ``K = P⁻Cᵀ(CP⁻Cᵀ + R)⁻¹``, Joseph-form covariance."""
    if predict:
        x, F, G = _rk4_complex_step(plant, x, u)
        P = F @ P @ F.T + (G @ Qn @ G.T if Qn_on == "input" else Qn)
    S = C @ P @ C.T + Rn
    K = np.linalg.solve(S, C @ P).T
    ImKC = np.eye(len(x)) - K @ C
    return x + K @ (y - C @ x), ImKC @ P @ ImKC.T + K @ Rn @ K.T, K


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _compare(plant, ekf, C, Qn, Rn, Qn_on, P0, rng, steps, noise):
    x = 0.1 * rng.standard_normal(plant.state_dim)
    u0 = plant.equilibrium()[1]
    ekf.reset(x, P0)
    xr, Pr = x.copy(), np.array(P0, dtype=float)
    worst = 0.0
    for k in range(steps):
        u = u0 + 0.05 * rng.standard_normal(plant.input_dim)
        y = C @ xr + noise * rng.standard_normal(C.shape[0])
        out = ekf.update(y, u)
        xr, Pr, K = _batch_reference(plant, C, Qn, Rn, Qn_on, xr, Pr, u, y, predict=k > 0)
        worst = max(worst, _rel(out, xr), _rel(ekf.P, Pr), _rel(ekf.M, K))
    return worst


@pytest.fixture(scope="module")
def quad():
    return Quadrotor()


@pytest.mark.parametrize(
    ("Rn", "Qn_on", "sequential"),
    [
        (np.diag([1e-3, 2e-3, 1.5e-3, 3e-3, 1e-3, 2.5e-3]), "input", True),
        (np.diag([1e-3, 2e-3, 1.5e-3, 3e-3, 1e-3, 2.5e-3]), "state", True),
        (np.diag([1e-3, 2e-3, 1.5e-3, 3e-3, 1e-3, 2.5e-3]) + 4e-4 * (np.eye(6, k=1) + np.eye(6, k=-1)), "input", False),
    ],
    ids=["sequential", "sequential-state-noise", "batch-correlated-R"],
)
def test_update_equals_the_batch_joseph_reference(quad, rng, Rn, Qn_on, sequential):
    C = quad.output_matrix(POSE)
    Qn = np.diag([1e-2, 1e-3, 2e-3, 1e-3]) if Qn_on == "input" else 1e-3 * np.eye(12) + 1e-4
    ekf = ExtendedKalmanFilter(quad, C, Qn, Rn, Qn_on=Qn_on)
    assert ekf.sequential is sequential
    A = rng.standard_normal((12, 12))
    P0 = 1e-3 * (A @ A.T) + 1e-3 * np.eye(12)  # correlated: every entry of the update matters
    assert _compare(quad, ekf, C, Qn, Rn, Qn_on, P0, rng, steps=25, noise=0.03) < 1e-12


def test_sequential_update_with_precise_sensors_from_the_identity(quad, rng):
    # The benchmark's setting: P0 = I, Rn = 1e-6 I. The first correction cancels six digits of P (the
    # conditional variance P r / (P + r)) in the batch Joseph form and in the sequential form alike, so the two
    # differ there by about eps P / r, not eps; the filter forgets it: the estimates stay within 1e-10 (about
    # 5e-12 measured), and the covariances agree to 1e-12 again, P symmetric positive definite.
    C, Qn, Rn = quad.output_matrix(POSE), np.diag([1e-4, 1e-6, 1e-6, 1e-6]), 1e-6 * np.eye(6)
    ekf = ExtendedKalmanFilter(quad, C, Qn, Rn)
    x = 0.1 * rng.standard_normal(12)
    ekf.reset(x, np.eye(12))
    xr, Pr, u0 = x.copy(), np.eye(12), quad.equilibrium()[1]
    for k in range(150):
        u = u0 + 0.01 * rng.standard_normal(4)
        y = C @ xr + 1e-3 * rng.standard_normal(6)
        out = ekf.update(y, u)
        xr, Pr, _ = _batch_reference(quad, C, Qn, Rn, "input", xr, Pr, u, y, predict=k > 0)
        assert _rel(out, xr) < 1e-10
    P = ekf.P
    np.testing.assert_array_equal(P, P.T)
    assert np.min(np.linalg.eigvalsh(P)) > 0
    assert _rel(P, Pr) < 1e-12


def test_update_reads_the_upper_triangle_of_the_covariance(quad, rng):
    C = quad.output_matrix(POSE)
    ekf = ExtendedKalmanFilter(quad, C, [1e-2, 1e-3, 1e-3, 1e-3], [1e-3] * 6)
    f_pred, f_first = ekf.update_functions
    A = rng.standard_normal((12, 12))
    P = 1e-2 * (A @ A.T) + 1e-2 * np.eye(12)
    garbled = np.triu(P) + np.tril(rng.standard_normal((12, 12)), -1)  # only the upper triangle is P's
    x, u, y = 0.1 * rng.standard_normal(12), quad.equilibrium()[1], 0.1 * rng.standard_normal(6)
    for f in (f_pred, f_first):
        a = [np.asarray(v) for v in f(x, P, u, y)]
        b = [np.asarray(v) for v in f(x, garbled, u, y)]
        for va, vb in zip(a, b, strict=True):
            np.testing.assert_array_equal(va, vb)
