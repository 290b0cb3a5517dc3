"""Kalman filters, EKF and Luenberger observer against independent references (python-control, scipy, complex step)."""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg

from shinro_ctrl.backend import NumpyBackend
from shinro_ctrl.controllers import LQR
from shinro_ctrl.errors import InvalidArgument, NonFiniteError, NotStabilizable, ShinroError
from shinro_ctrl.estimators import estimator_class
from shinro_ctrl.estimators.kalman import ExtendedKalmanFilter, KalmanFilter
from shinro_ctrl.estimators.luenberger import Luenberger
from shinro_ctrl.plants import CartPole, InvertedPendulum, Quadrotor

from .thread_helpers import BlockingArray, in_threads

QN, RN = np.array([[0.2]]), np.diag([1e-4, 4e-4])


def _cartpole_kf(**kw):
    return KalmanFilter.from_plant(CartPole(), measured=["x", "theta"], Qn=QN, Rn=RN, **kw)


def test_registry_names_the_estimators():
    for name in ("KalmanFilter", "ExtendedKalmanFilter", "Luenberger", "FullState"):
        assert estimator_class(name).__name__ == name


def test_steady_state_gain_equals_dlqe():
    kf = _cartpole_kf()
    A, B = kf.model.A, kf.model.B
    L, P, _ = control.dlqe(A, B, kf.C, QN, RN)  # G = B: the noise enters on the input
    np.testing.assert_allclose(kf.L, L, rtol=0, atol=1e-10)
    np.testing.assert_allclose(kf.P_prior, P, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(kf.A @ kf.M, kf.L, atol=1e-12)
    np.testing.assert_allclose(np.sort_complex(kf.poles), np.sort_complex(np.linalg.eigvals(A - L @ kf.C)), atol=1e-9)


def test_time_varying_covariance_converges_to_dare():
    kf = _cartpole_kf(steady_state=False)
    kf.reset(np.zeros(4), P0=np.eye(4))
    rng = np.random.default_rng(3)
    for _ in range(3000):  # the covariance does not depend on the data
        kf.update(rng.standard_normal(2), rng.standard_normal(1))
    A, B, C = kf.model.A, kf.model.B, kf.C
    X = scipy.linalg.solve_discrete_are(A.T, C.T, B @ QN @ B.T, RN)
    np.testing.assert_allclose(kf.P_prior, X, rtol=1e-8, atol=1e-12 * np.abs(X).max())
    gain = X @ C.T @ np.linalg.inv(C @ X @ C.T + RN)
    np.testing.assert_allclose(kf.M, gain, rtol=1e-7, atol=1e-9)


def test_state_noise_option_uses_identity_input_matrix():
    plant = InvertedPendulum()
    Qs = np.diag([1e-6, 1e-3])
    kf = KalmanFilter.from_plant(plant, measured=["theta"], Qn=Qs, Rn=[1e-4], Qn_on="state")
    L, _, _ = control.dlqe(kf.model.A, np.eye(2), kf.C, Qs, [[1e-4]])
    np.testing.assert_allclose(kf.L, L, atol=1e-10)


def _complex_rk4(plant, x, u, h=1e-30):
    """Independent complex-step Jacobians of one RK4 step of ``plant._f`` in numpy."""
    bk, dt, n, m = NumpyBackend(), plant.dt, plant.state_dim, plant.input_dim

    def f(X, U):
        return np.asarray(plant.equations(bk, X, U, plant._params))

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


@pytest.mark.parametrize("plant", [InvertedPendulum(), CartPole(damping=0.05), Quadrotor()], ids=type)
def test_ekf_jacobians_equal_complex_step_of_the_rk4_step(plant, rng):
    ekf = ExtendedKalmanFilter.from_plant(plant, Qn=np.eye(plant.input_dim) * 1e-3, Rn=np.ones(plant.state_dim) * 1e-4)
    x0, u0 = plant.equilibrium()
    for _ in range(3):
        x = x0 + 0.3 * rng.standard_normal(plant.state_dim)
        u = u0 + 0.2 * rng.standard_normal(plant.input_dim)
        xn, Fx, Fu = ekf.step_jacobians(x, u)
        xr, Ar, Br = _complex_rk4(plant, x, u)
        np.testing.assert_allclose(xn, xr, rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(Fx, Ar, rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(Fu, Br, rtol=1e-11, atol=1e-13)


def test_ekf_covariance_step_matches_the_textbook_update(rng):
    plant = CartPole()
    Qn, Rn = np.array([[0.05]]), np.diag([1e-3, 2e-3])
    ekf = ExtendedKalmanFilter.from_plant(plant, measured=["x", "theta"], Qn=Qn, Rn=Rn)
    x, P0 = np.array([0.1, -0.2, 0.15, 0.3]), np.diag([0.1, 0.2, 0.05, 0.3])
    ekf.reset(x, P0)
    y0 = np.array([0.12, 0.14])
    ekf.update(y0, np.zeros(1))  # correction only
    C = plant.output_matrix(["x", "theta"])
    K0 = P0 @ C.T @ np.linalg.inv(C @ P0 @ C.T + Rn)
    xh = x + K0 @ (y0 - C @ x)
    P = (np.eye(4) - K0 @ C) @ P0
    u, y = np.array([0.3]), np.array([0.11, 0.16])
    out = ekf.update(y, u)
    xb, F, G = _complex_rk4(plant, xh, u)
    Pm = F @ P @ F.T + G @ Qn @ G.T
    K = Pm @ C.T @ np.linalg.inv(C @ Pm @ C.T + Rn)
    np.testing.assert_allclose(out, xb + K @ (y - C @ xb), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ekf.P, (np.eye(4) - K @ C) @ Pm, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(ekf.M, K, rtol=1e-9, atol=1e-12)


def _closed_loop_matrix(est, K, A, B, C, rng):
    """Identify the map (x_k, x̂_k) -> (x_{k+1}, x̂_{k+1}) of the implemented LQG loop on the linear model."""
    n = A.shape[0]
    S0, S1 = [], []
    for _ in range(4 * n):
        x, xh = rng.standard_normal(n), rng.standard_normal(n)
        est.reset(xh)
        xh = est.update(C @ x, np.zeros(B.shape[1]))  # correction only: a generic (x, x̂) pair
        u = -K @ xh
        x1 = A @ x + B @ u
        xh1 = est.update(C @ x1, u)
        S0.append(np.r_[x, xh])
        S1.append(np.r_[x1, xh1])
    Phi = np.linalg.lstsq(np.array(S0), np.array(S1), rcond=None)[0].T
    return Phi


def _match(found, expected, tol):
    rest = list(found)
    for lam in expected:
        j = int(np.argmin(np.abs(np.array(rest) - lam)))
        assert abs(rest[j] - lam) < tol, (lam, rest)
        rest.pop(j)


@pytest.mark.parametrize("kind", ["kalman", "luenberger"])
def test_separation_lqg_poles_are_the_union(kind, rng):
    plant = CartPole()
    lqr = LQR.from_plant(plant, [10, 1, 100, 1], [0.1], discretization="zoh")
    A, B = lqr.model.A, lqr.model.B
    if kind == "kalman":
        est = KalmanFilter.from_plant(plant, measured=["x", "theta"], Qn=QN, Rn=RN)
        est_poles = control.dlqe(A, B, est.C, QN, RN)[2]
    else:
        est_poles = np.array([0.8, 0.82, 0.85 + 0.05j, 0.85 - 0.05j])
        est = Luenberger.from_plant(plant, measured=["x", "theta"], poles=est_poles)
        _match(np.linalg.eigvals(A - est.L @ est.C), est_poles, 1e-8)
    Phi = _closed_loop_matrix(est, lqr.K, A, B, est.C, rng)
    expected = np.concatenate([np.linalg.eigvals(A - B @ lqr.K), est_poles])
    _match(np.linalg.eigvals(Phi), expected, 1e-7)


def test_input_disturbance_estimate_converges_to_the_true_bias():
    plant = CartPole()
    kf = KalmanFilter.from_plant(plant, measured=["x", "theta"], Qn=QN, Rn=RN, disturbance_model="input", Qd=[1e-3])
    A, B, C = kf.model.A, kf.model.B, kf.C[:, :4]
    lqr = LQR.from_plant(plant, [10, 1, 100, 1], [0.1], discretization="zoh")
    d = np.array([0.4])
    x, u = np.zeros(4), np.zeros(1)
    kf.reset(np.zeros(4))
    for _ in range(3000):
        z = kf.update(C @ x, u)
        u = -lqr.K @ z[:4]
        x = A @ x + B @ (u + d)
    assert z.shape == (5,)
    np.testing.assert_allclose(kf.d_hat, d, atol=1e-6)
    np.testing.assert_allclose(z[:4], x, atol=1e-6)


def test_ekf_converges_on_the_pendulum_in_mujoco_with_noise():
    from shinro_ctrl.engine import MujocoEngine

    plant = InvertedPendulum()
    plant.physics_engine(MujocoEngine.for_plant(plant))
    plant.set_state([0.1, 0.0])
    ekf = ExtendedKalmanFilter.from_plant(plant, measured=["theta"], Qn=[1e-4], Rn=[1e-6])
    lqr = LQR.from_plant(plant, [10, 1], [0.1])
    ekf.reset([0.4, 0.0], P0=np.diag([0.1, 0.1]))  # 0.3 rad off
    rng = np.random.default_rng(7)
    x, u, errs = plant.get_state(), np.zeros(1), []
    for _ in range(200):  # 2 s
        y = x[:1] + 1e-3 * rng.standard_normal(1)
        xh = ekf.update(y, u)
        errs.append(np.abs(xh - x).max())
        u = lqr(xh)
        x = plant.step(u)
    assert errs[0] > 0.05 or errs[1] > 0.05  # it did start wrong
    assert max(errs[-20:]) < 1e-2


@pytest.mark.parametrize(
    "build,match",
    [
        (lambda p: KalmanFilter.from_plant(p, measured=["thetta"], Qn=[1], Rn=[1]), r"did you mean 'theta'.*valid: x"),
        (lambda p: KalmanFilter.from_plant(p, measured=["theta"], Qn=[1], Rn=[1]), r"mode λ = 1 \(mostly state 'x'\)"),
        (lambda p: KalmanFilter.from_plant(p, measured=["x"], Qn=[1], Rn=[-1e-3]), r"Rn\[0\] = -0.001"),
        (lambda p: KalmanFilter.from_plant(p, measured=["x"], Qn=[-1], Rn=[1]), r"Qn\[0\] = -1"),
        (lambda p: KalmanFilter.from_plant(p, measured=["x"], Qn=[1], Rn=[0]), r"Rn must be positive definite"),
        (lambda p: KalmanFilter.from_plant(p, measured=["x"], Qn=[1, 2], Rn=[1]), r"Qn.*\(1,\)"),
        (lambda p: KalmanFilter.from_plant(p, Qn=[1], Rn=[1] * 4, Qn_on="output"), r"Qn_on.*input, state"),
        (lambda p: ExtendedKalmanFilter.from_plant(p, measured=["theta_dot"], Qn=[1], Rn=[1]), r"not detectable"),
        (lambda p: Luenberger.from_plant(p, measured=["theta"], poles=[0.5, 0.6, 0.7, 0.8]), r"not observable"),
        (lambda p: Luenberger.from_plant(p, measured=["x"], poles=[0.5, 0.6, 1.2, 0.8]), r"inside the unit circle"),
        (lambda p: Luenberger.from_plant(p, measured=["x"], poles=[0.5, 0.6]), r"expected 4"),
    ],
)
def test_bad_input(build, match):
    with pytest.raises(ShinroError, match=match) as info:
        build(CartPole())
    # a mode the measurements cannot see is the one PBH check's NotStabilizable (as for the LQR's Q)
    assert isinstance(info.value, NotStabilizable if "PBH" in str(info.value) else InvalidArgument)


def test_reset_and_update_check_shapes():
    kf = _cartpole_kf()
    with pytest.raises(InvalidArgument, match=r"x0_hat.*\(4,\)"):
        kf.reset([0.0, 0.0])
    kf.reset(np.zeros(4))
    with pytest.raises(InvalidArgument, match=r"y.*\(2,\)"):
        kf.update([0.0], [0.0])
    with pytest.raises(InvalidArgument, match="steady-state"):
        kf.reset(np.zeros(4), P0=np.eye(4))


# ------------------------------------------------------------ threads (issue 23.3)
def _estimators(plant):
    return {
        "KalmanFilter": lambda: KalmanFilter.from_plant(plant, measured=["x", "theta"], Qn=[0.1], Rn=[1e-4, 1e-4]),
        "KalmanFilter (time-varying)": lambda: KalmanFilter.from_plant(
            plant, measured=["x", "theta"], Qn=[0.1], Rn=[1e-4, 1e-4], steady_state=False
        ),
        "ExtendedKalmanFilter": lambda: ExtendedKalmanFilter.from_plant(
            plant, measured=["x", "theta"], Qn=[0.1], Rn=[1e-4, 1e-4]
        ),
        "Luenberger": lambda: Luenberger.from_plant(plant, measured=["x", "theta"], poles=[0.5, 0.6, 0.7, 0.8]),
    }


@pytest.mark.parametrize("kind", list(_estimators(CartPole())))
def test_one_estimator_per_thread_gives_the_serial_estimates(kind):
    build = _estimators(CartPole(dt=0.01))[kind]
    rng = np.random.default_rng(4)
    Y = rng.normal(scale=0.05, size=(4, 1000, 2))
    U = rng.normal(scale=0.5, size=(4, 1000, 1))

    def run(est, i):
        est.reset(np.zeros(4))
        return np.array([est.update(y, u) for y, u in zip(Y[i], U[i], strict=True)])

    serial = [run(build(), i) for i in range(4)]
    own = [build() for _ in range(4)]
    threaded = in_threads(lambda i: run(own[i], i), range(4))
    for s, t in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(s, t)


@pytest.mark.parametrize("kind", list(_estimators(CartPole())))
def test_an_estimator_shared_between_threads_refuses_the_second_caller(kind):
    import threading

    from shinro_ctrl.errors import ConcurrentUse

    build = _estimators(CartPole(dt=0.01))[kind]
    shared, twin = build(), build()
    for est in (shared, twin):
        est.reset(np.zeros(4))
    y0, y1, u = np.array([0.01, 0.02]), np.array([0.02, 0.01]), np.array([0.3])

    held, result = BlockingArray(y0), {}
    inside = threading.Thread(target=lambda: result.setdefault("x", shared.update(held, u)))
    inside.start()
    assert held.entered.wait(30)
    for call in (lambda: shared.update(y1, u), lambda: shared.reset(np.zeros(4))):
        with pytest.raises(ConcurrentUse, match="one object per thread"):
            call()
    held.release.set()
    inside.join()
    np.testing.assert_array_equal(result["x"], twin.update(y0, u))
    np.testing.assert_array_equal(shared.update(y1, u), twin.update(y1, u))  # the refused calls changed nothing

    # hammered from four threads, every call either completes or is refused (any other error fails the
    # test), and afterwards the guard is free and a reset filter is exact again
    def hammer(i):
        for _ in range(1000):
            try:
                shared.update(y0, u)
            except ConcurrentUse:
                pass

    in_threads(hammer, range(4))
    fresh = build()
    for est in (shared, fresh):
        est.reset(np.zeros(4))
    np.testing.assert_array_equal(shared.update(y1, u), fresh.update(y1, u))


@pytest.mark.parametrize("kind", list(_estimators(CartPole())))
@pytest.mark.parametrize("u", [[np.inf], [np.nan], [-np.inf], [0.0, 0.0]], ids=["inf", "nan", "-inf", "too long"])
@pytest.mark.parametrize("first", [True, False], ids=["first call", "later call"])
def test_update_refuses_a_bad_input_also_on_the_first_call(kind, u, first):
    """The first update after reset skips the prediction, but a non-finite or misshapen ``u`` is refused there too."""
    est = _estimators(CartPole())[kind]()
    est.reset(np.zeros(4))
    if not first:
        est.update([0.0, 0.0], [0.0])
    before = est.update([0.0, 0.0], [0.0]).copy() if not first else None
    with pytest.raises((NonFiniteError, InvalidArgument), match=r"\bu\b"):
        est.update([0.0, 0.0], u)
    if before is not None:
        assert np.all(np.isfinite(est.update([0.0, 0.0], [0.0])))
