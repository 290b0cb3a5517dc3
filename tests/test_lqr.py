"""LQR against scipy's Riccati solvers, closed loops, and its failure modes."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from shinro_ctrl.controllers import LQR
from shinro_ctrl.errors import NonFiniteError, NotStabilizable
from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum

from .thread_helpers import BlockingArray, in_threads


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


# --------------------------------------------------------------- scale-invariant PBH (issue 23.3 "Scale", 24.6)
def _scipy_stabilizes(A, B, Q, R) -> bool:
    """The independent reference: scipy's DARE returns a solution whose gain makes every pole |p| < 1."""
    try:
        S = scipy.linalg.solve_discrete_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError):
        return False
    if not np.all(np.isfinite(S)):
        return False
    K = np.linalg.solve(R + B.T @ S @ B, B.T @ S @ A)
    return bool(np.max(np.abs(np.linalg.eigvals(A - B @ K))) < 1.0)


def _joint(k: float, dt: float, method: str):
    from shinro_ctrl.linearization import discretize

    return discretize(np.array([[0.0, 1.0], [-k, -1.0]]), np.array([[0.0], [1.0]]), dt, method)


def _stabilizable_cases():
    """The two reported cases (a stiff joint at dt 0.01, a cart-pole at dt 1e-9) and their neighbours."""
    cases = []
    for k, dt, method in ((1e6, 0.01, "euler"), (1e6, 0.01, "zoh"), (1e8, 0.001, "euler"), (1.0, 0.01, "euler")):
        A, B = _joint(k, dt, method)
        cases.append((f"joint k={k:g} dt={dt:g} {method}", A, B, np.eye(2), np.eye(1)))
    for dt in (1e-9, 1e-7, 1e-4, 0.01):
        lm = CartPole(dt=dt).linear_model(discretization="euler")
        cases.append((f"cartpole dt={dt:g}", lm.A, lm.B, np.diag([10.0, 1, 100, 1]), np.array([[0.1]])))
    return cases


@pytest.mark.parametrize("case", _stabilizable_cases(), ids=lambda c: c[0])
def test_stabilizable_systems_at_any_scale_are_accepted_as_scipy_says(case):
    from shinro_ctrl.analysis.structure import check_detectable, check_stabilizable

    _, A, B, Q, R = case
    assert _scipy_stabilizes(A, B, Q, R)
    check_stabilizable(A, B)  # the PBH test alone agrees with scipy (it refused both reported cases)
    check_detectable(A, np.sqrt(Q))
    ctrl = LQR(A, B, Q, R)
    assert np.all(np.abs(ctrl.poles) < 1.0)
    S = scipy.linalg.solve_discrete_are(A, B, Q, R)
    np.testing.assert_allclose(ctrl.S, S, rtol=1e-6, atol=1e-12 * np.abs(S).max())


def _hidden_unstable(dt: float, unit: float, seed: int):
    """``A = I + dt·A_c`` with an unstable mode the input cannot reach, in states scaled by ``unit`` and mixed."""
    rng = np.random.default_rng(seed)
    Ac = np.array([[0.0, 1.0, 0.0], [-4.0, -1.0, 0.0], [0.0, 0.0, 0.5]])  # the third mode: unstable, unreachable
    Bc = np.array([[0.0], [1.0], [0.0]])
    T = np.diag([1.0, unit, 1.0 / unit]) @ (np.eye(3) + 0.3 * rng.standard_normal((3, 3)))
    Ti = np.linalg.inv(T)
    return np.eye(3) + dt * (T @ Ac @ Ti), dt * (T @ Bc)


@pytest.mark.parametrize("dt", [1e-9, 1e-5, 1e-2, 0.2])
@pytest.mark.parametrize("unit", [1e-4, 1.0, 1e4])
def test_unstabilizable_systems_at_any_scale_are_refused_as_scipy_says(dt, unit):
    from shinro_ctrl.analysis.structure import check_stabilizable

    A, B = _hidden_unstable(dt, unit, seed=3)
    Q, R = np.eye(3), np.eye(1)
    assert not _scipy_stabilizes(A, B, Q, R)
    with pytest.raises(
        NotStabilizable, match=r"not stabilizable: the mode λ = 1(\.\d+)? \(mostly state \d\).*input cannot reach it"
    ):
        check_stabilizable(A, B)
    with pytest.raises(NotStabilizable, match="not stabilizable"):
        LQR(A, B, Q, R)


@pytest.mark.parametrize("dt", [1e-9, 1e-4, 0.01])
def test_detectability_is_scale_invariant_too(dt):
    from shinro_ctrl.analysis.structure import check_detectable

    lm = CartPole(dt=dt).linear_model(discretization="euler")
    check_detectable(lm.A, np.diag([1.0, 0.0, 1.0, 0.0]))  # positions seen: detectable at every dt
    with pytest.raises(NotStabilizable, match=r"not detectable: the mode λ = 1 \(mostly state 'x'\)"):
        check_detectable(lm.A, np.diag([0.0, 1.0, 1.0, 1.0]), names=CartPole().state_names)  # the cart's x unseen
    with pytest.raises(NotStabilizable, match="not detectable"):
        LQR(lm.A, lm.B, [0.0, 1.0, 1.0, 1.0], [1.0], state_names=CartPole().state_names)


def test_one_pbh_function_lists_repeated_eigenvalues_once_with_their_multiplicity():
    from shinro_ctrl.analysis import structure_report
    from shinro_ctrl.analysis.structure import pbh_modes

    lm = CartPole(dt=1e-9).linear_model(discretization="euler")
    modes = pbh_modes(lm.A, lm.B)
    assert sorted(m.multiplicity for m in modes) == [1, 1, 2]  # the cart's double integrator at z = 1
    assert all(m.full_rank for m in modes)
    A = np.diag([0.5, 0.5, 0.5, 0.9])  # a triple eigenvalue one input cannot reach along every direction
    rep = structure_report(A, np.array([[1.0], [1.0], [1.0], [1.0]]))
    triple = next(m for m in rep.modes if abs(m.eigenvalue - 0.5) < 1e-12)
    assert triple.multiplicity == 3 and not triple.controllable and len(rep.modes) == 2
    assert "(×3, repeated)" in rep.format()


# --------------------------------------------------------------- operating points (issue 23.3)
@pytest.mark.parametrize(
    "kwargs,needle",
    [
        ({"x0": [0.0, 1.0, 0.0, 0.0]}, r"dx/dt = 1 .*no input holds x0 at rest"),  # moving: no input stops it
        ({"x0": [0.0, 0.0, 0.3, 0.0]}, r"dx_dot/dt = -0\.5444, dtheta_dot/dt = 6\.838.*no input holds x0 at rest"),
        ({"u0": [1.0]}, r"dx_dot/dt = 2, dtheta_dot/dt = -4 .*nearest equilibrium input is u0 = \[0\]"),
        ({"u0": [1.0], "integral": ["x"]}, r"dx_dot.*nearest equilibrium input is u0 = \[0\]"),  # LQI too
    ],
)
def test_an_operating_point_that_is_not_an_equilibrium_is_refused(kwargs, needle):
    from shinro_ctrl.errors import InvalidArgument

    Q = [10, 1, 100, 1, 1] if "integral" in kwargs else [10, 1, 100, 1]
    with pytest.raises(
        InvalidArgument, match="LQR: the operating point is not an equilibrium: f\\(x0, u0\\) has " + needle
    ):
        LQR.from_plant(CartPole(), Q, [0.1], **kwargs)


def test_the_nearest_equilibrium_input_is_the_one_that_holds_the_point():
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.plants import Quadrotor

    # hover: the plant's own equilibrium input, m g on the thrust (the closed form)
    q = Quadrotor()
    with pytest.raises(InvalidArgument, match=r"dvz/dt = -9\.81 .*nearest equilibrium input is u0 = \[") as info:
        LQR.from_plant(q, np.ones(12), np.ones(4), u0=np.zeros(4))
    hover = q.equilibrium()[1]
    assert f"{hover[0]:.6g}" in str(info.value)
    # a fully actuated double pendulum held tilted: the named input is the gravity torque, and it holds the pose
    p = DoublePendulum(dt=0.005)
    x0 = np.array([0.4, -0.2, 0.0, 0.0])
    with pytest.raises(InvalidArgument, match=r"nearest equilibrium input is u0 = \[[-\d.e, ]+\]") as info:
        LQR.from_plant(p, [100, 100, 1, 1], [1, 1], x0=x0)
    u_star = np.array([float(v) for v in str(info.value).split("u0 = [")[-1].split("]")[0].split(",")])
    np.testing.assert_allclose(p.dynamics(x0, u_star), 0.0, atol=1e-8)
    ctrl = LQR.from_plant(p, [100, 100, 1, 1], [1, 1], x0=x0, u0=u_star)
    p.set_state(x0 + np.array([0.05, 0.0, 0.0, 0.0]))
    for _ in range(1000):
        p.step(ctrl(p.get_state()))
    np.testing.assert_allclose(p.get_state(), x0, atol=1e-3)


def test_equilibria_away_from_the_origin_are_accepted_and_linear_mpc_carries_the_offset():
    from shinro_ctrl.controllers import LinearMPC

    LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1], x0=[5.0, 0.0, 0.0, 0.0])  # the cart anywhere on the track
    mpc = LinearMPC.from_plant(CartPole(), [10, 1, 100, 1], [0.1], horizon=10, u0=[1.0])
    assert mpc.offset is not None and np.abs(mpc.offset).max() > 0  # the drift f(x0, u0) is in its model


@pytest.mark.parametrize("bad", [None, CartPole, "CartPole", 3.0])
def test_from_plant_of_every_controller_and_estimator_names_a_non_plant(bad):
    from shinro_ctrl.controllers import CONTROLLERS, controller_class
    from shinro_ctrl.estimators import ESTIMATORS

    classes = [controller_class(name) for name in CONTROLLERS] + list(ESTIMATORS.values())
    classes = [c for c in classes if c.__module__.startswith("shinro_ctrl.")]  # not the tests' own subclasses
    for cls in classes:
        with pytest.raises(TypeError, match=rf"{cls.__name__}\.from_plant\(\) expects a plant instance") as info:
            cls.from_plant(bad)
        if bad is CartPole:
            assert "got the class CartPole; pass CartPole()" in str(info.value)


# --------------------------------------------------------------- papercuts (issue 23.5)
def test_the_lqi_weight_shape_error_says_the_integral_states_are_appended():
    from shinro_ctrl.errors import InvalidArgument

    with pytest.raises(
        InvalidArgument, match=r"expected shape \(6,\).*Q weights the 4 states and then the 2 integral "
    ):
        LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1], integral=["x", "theta"])
    with pytest.raises(InvalidArgument, match=r"expected shape \(4,\) but found \(3,\)$"):  # plain LQR: no mention
        LQR.from_plant(CartPole(), [10, 1, 100], [0.1])


@pytest.mark.parametrize("x", [[1e308] * 4, [1e308, 0, 0, 0], [0, 0, -1e308, 0]])
def test_a_state_whose_input_overflows_raises_instead_of_returning_inf(x):
    ctrl = LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1], u_min=[-5], u_max=[5])
    with np.errstate(over="ignore"), pytest.raises(NonFiniteError, match="overflows float64"):
        ctrl(x)


def test_gains_and_matrices_cannot_be_changed_through_the_attributes():
    from shinro_ctrl.controllers import LinearMPC

    Q = np.diag([10.0, 1, 100, 1])
    lqr = LQR.from_plant(CartPole(), Q, [0.1])
    mpc = LinearMPC.from_plant(CartPole(), [10, 1, 100, 1], [0.1], horizon=10)
    lqi = LQR.from_plant(CartPole(), [10, 1, 100, 1, 1], [0.1], integral=["x"])
    for ctrl in (lqr, mpc, lqi):
        public = {k: v for k, v in vars(ctrl).items() if not k.startswith("_") and isinstance(v, np.ndarray)}
        assert {"K", "S", "A", "B", "Q", "R"} & set(public)
        for name, value in public.items():
            assert not value.flags.writeable, (type(ctrl).__name__, name)
    x = np.array([0.1, 0.0, 0.1, 0.0])
    u = lqr(x)
    with pytest.raises(ValueError, match="read-only"):
        lqr.K[0, 0] = 1e6
    Q[2, 2] = 0.0  # the caller's own array stays theirs: writable, and the controller kept a copy
    assert lqr.Q[2, 2] == 100.0 and np.array_equal(lqr(x), u)


def test_the_linear_model_keeps_the_plant_names():
    lm = CartPole().linear_model()
    ss = lm.to_statespace()
    assert list(ss.state_labels) == ["x", "x_dot", "theta", "theta_dot"] and list(ss.input_labels) == ["force"]


# --------------------------------------------------------------- threads (issue 23.3)
def test_one_lqr_called_from_four_threads_gives_the_serial_results():
    ctrl = LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1], u_min=[-5], u_max=[5], feedforward=True)
    X = np.random.default_rng(0).normal(scale=0.5, size=(4, 1000, 4))
    refs = np.random.default_rng(1).normal(scale=0.2, size=(4, 1000, 2, 4))
    serial = [np.array([ctrl(x, ref=r) for x, r in zip(X[i], refs[i], strict=True)]) for i in range(4)]
    threaded = in_threads(lambda i: np.array([ctrl(x, ref=r) for x, r in zip(X[i], refs[i], strict=True)]), range(4))
    for s, t in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(s, t)


def test_an_lqi_shared_between_threads_refuses_the_second_caller_and_one_per_thread_is_serial():
    import threading

    from shinro_ctrl.errors import ConcurrentUse

    def build():
        return LQR.from_plant(CartPole(), [10, 1, 100, 1, 1], [0.1], integral=["x"], u_min=[-3], u_max=[3])

    X = np.random.default_rng(2).normal(scale=0.3, size=(4, 1000, 4))
    ref = np.array([0.2, 0.0, 0.0, 0.0])
    serial = []
    for i in range(4):
        c = build()
        serial.append(np.array([c(x, ref) for x in X[i]]))
    own = [build() for _ in range(4)]
    threaded = in_threads(lambda i: np.array([own[i](x, ref) for x in X[i]]), range(4))
    for s, t in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(s, t)
    # one object, two threads: the second call is refused while the first is inside; the first completes
    shared, twin = build(), build()
    held = BlockingArray(X[0, 0])
    result = {}
    inside = threading.Thread(target=lambda: result.setdefault("u", shared(held, ref)))
    inside.start()
    assert held.entered.wait(30)
    with pytest.raises(ConcurrentUse, match="one object per thread"):
        shared(X[0, 1], ref)
    held.release.set()
    inside.join()
    np.testing.assert_array_equal(result["u"], twin(X[0, 0], ref))
    np.testing.assert_array_equal(shared(X[0, 1], ref), twin(X[0, 1], ref))  # the refused call changed nothing


def test_a_tvlqr_whose_plan_ends_off_equilibrium_is_refused_at_its_goal():
    from shinro_ctrl.controllers import TVLQR
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.planning import Trajectory

    plant = CartPole(dt=0.01)
    x = np.zeros((2, 4))
    for u_goal, ok in (([0.0], True), ([1.0], False)):
        u = np.array([[0.0], u_goal])
        traj = Trajectory(np.array([0.0, 0.5]), x, u, np.array([plant.dynamics(x[k], u[k]) for k in range(2)]))
        if ok:
            TVLQR.from_trajectory(plant, traj, [10, 1, 100, 1], [0.1])
            continue
        with pytest.raises(InvalidArgument, match=r"not an equilibrium.*nearest equilibrium input is u0 = \[0\]"):
            TVLQR.from_trajectory(plant, traj, [10, 1, 100, 1], [0.1])


@pytest.mark.parametrize(
    ("plant", "Q"),
    [
        (CartPole(), [10, 1, 100, 1, 50]),
        (CartPole(), np.eye(6)),
        (InvertedPendulum(), [1, 1, 1]),
        (DoublePendulum(), [1] * 5),
    ],
    ids=["cartpole diag", "cartpole matrix", "pendulum", "double pendulum"],
)
def test_more_weights_than_states_without_integral_says_integral_is_missing(plant, Q):
    from shinro_ctrl.errors import InvalidArgument

    n = plant.state_dim
    with pytest.raises(
        InvalidArgument, match=rf"Q weights the {n} states only: weights for integral states need 'integral'"
    ):
        LQR.from_plant(plant, Q, np.ones(plant.input_dim))


def test_too_few_weights_is_the_plain_shape_error():
    from shinro_ctrl.errors import InvalidArgument

    with pytest.raises(InvalidArgument, match=r"Q: expected shape \(4,\) but found \(3,\)$"):
        LQR.from_plant(CartPole(), [1, 1, 1], [0.1])
