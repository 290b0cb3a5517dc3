"""Properties shared by the pendulum-family plants, and their individual contracts."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from shinro_ctrl.errors import ConfigError, NonFiniteError
from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum, plant_class

from .conftest import PENDULUM_FAMILY, random_params
from .thread_helpers import in_threads


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_batch_equals_per_instance(cls, rng):
    plant = cls()
    X = rng.normal(size=(7, plant.state_dim))
    U = rng.normal(size=(7, plant.input_dim))
    batch = plant.dynamics(X, U)
    single = np.array([plant.dynamics(x, u) for x, u in zip(X, U, strict=True)])
    np.testing.assert_allclose(batch, single, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_batch_with_per_instance_parameters(cls, rng):
    draws = [random_params(cls, rng) for _ in range(5)]
    X = rng.normal(size=(5, cls().state_dim))
    U = rng.normal(size=(5, cls().input_dim))
    params = {k: np.array([d[k] for d in draws]) for k in draws[0]}
    batch = cls().dynamics(X, U, params=params)
    single = np.array([cls(**d).dynamics(x, u) for d, x, u in zip(draws, X, U, strict=True)])
    np.testing.assert_allclose(batch, single, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_symbolic_matches_numeric(cls, rng):
    plant = cls(**random_params(cls, rng))
    f = plant.symbolic()
    fp = plant.symbolic(params=True)
    assert f.name() == "f" and f.name_in() == ["x", "u"] and fp.name_in() == ["x", "u", "p"]
    p = np.array([plant.params()[k] for k in plant.param_names])
    for _ in range(3):
        x, u = rng.normal(size=plant.state_dim), rng.normal(size=plant.input_dim)
        np.testing.assert_allclose(np.array(f(x, u)).ravel(), plant.dynamics(x, u), atol=1e-12)
        np.testing.assert_allclose(np.array(fp(x, u, p)).ravel(), plant.dynamics(x, u), atol=1e-12)
    assert isinstance(f(cs.SX.sym("x", plant.state_dim), cs.SX.sym("u", plant.input_dim)), cs.SX)


@pytest.mark.parametrize(
    "plant,x_eq",
    [
        (InvertedPendulum(), [0, 0]),
        (CartPole(), [0.3, 0, 0, 0]),
        (DoublePendulum(), [0, 0, 0, 0]),
        (DoublePendulum(), [np.pi, np.pi, 0, 0]),
    ],
    ids=["pendulum", "cartpole", "double-hanging", "double-upright"],
)
def test_equilibria_are_fixed_points(plant, x_eq):
    u_eq = np.zeros(plant.input_dim)
    np.testing.assert_allclose(plant.dynamics(x_eq, u_eq), 0.0, atol=1e-12)
    plant.set_state(x_eq)
    for _ in range(100):
        plant.step(u_eq)
    np.testing.assert_allclose(plant.get_state(), x_eq, atol=1e-10)


def test_double_pendulum_conserves_energy_without_input():
    plant = DoublePendulum(mass_top=0.3, mass_bottom=0.2, length_top=0.6, length_bottom=0.4)
    x0 = np.array([1.2, -0.7, 0.5, 2.0])
    sol = solve_ivp(lambda t, x: plant.dynamics(x, np.zeros(2)), (0, 5), x0, rtol=1e-11, atol=1e-11)
    energy = plant.energy(sol.y.T)
    assert np.ptp(energy) < 1e-7 * max(1.0, abs(energy[0]))
    assert np.ptp(sol.y[0]) > 0.5  # it really moved


def test_double_pendulum_inputs_are_hinge_torques():
    # tau_2 acts between the rods: generalized forces [tau1 - tau2, tau2].
    plant = DoublePendulum()
    x = np.array([0.3, -0.4, 0.1, 0.2])
    a_hinge = plant.dynamics(x, [0.0, 0.7]) - plant.dynamics(x, [0.0, 0.0])
    a_equiv = plant.dynamics(x, [0.7, 0.0]) - plant.dynamics(x, [0.0, 0.0])
    # Q = [-0.7, 0.7] is the superposition of Q = [0.7, 0] scaled by -1 and Q = [0, 0.7].
    m1, m2, l1, l2 = plant.m1, plant.m2, plant.l1, plant.l2
    d = x[0] - x[1]
    M = np.array([[(m1 + m2) * l1**2, m2 * l1 * l2 * np.cos(d)], [m2 * l1 * l2 * np.cos(d), m2 * l2**2]])
    np.testing.assert_allclose(a_hinge[2:], np.linalg.solve(M, [-0.7, 0.7]), atol=1e-12)
    np.testing.assert_allclose(a_equiv[2:], np.linalg.solve(M, [0.7, 0.0]), atol=1e-12)


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_step_is_semi_implicit_euler(cls, rng):
    plant = cls(dt=0.02)
    x = rng.normal(size=plant.state_dim) * 0.3
    u = rng.normal(size=plant.input_dim)
    plant.set_state(x)
    xd = plant.dynamics(x, u)
    expected = x.copy()
    v, q = list(plant.velocity_indices), list(plant.position_indices)
    expected[v] = x[v] + 0.02 * xd[v]
    expected[q] = x[q] + 0.02 * expected[v]
    np.testing.assert_allclose(plant.step(u), expected, atol=1e-14)


def test_scalar_input_for_single_input_plants():
    a, b = CartPole(), CartPole()
    np.testing.assert_array_equal(a.step(0.5), b.step(np.array([0.5])))
    np.testing.assert_array_equal(
        InvertedPendulum().dynamics([0.1, 0], 0.2), InvertedPendulum().dynamics([0.1, 0], [0.2])
    )


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_bad_inputs_are_clear_errors(cls):
    plant = cls()
    with pytest.raises(ValueError, match="expected shape"):
        plant.step(np.zeros(plant.input_dim + 1))
    with pytest.raises(NonFiniteError, match="finite"):
        plant.step(np.full(plant.input_dim, np.nan))
    with pytest.raises(NonFiniteError):
        plant.set_state(np.full(plant.state_dim, np.inf))
    with pytest.raises(ValueError, match="x0"):
        plant.linearize(np.zeros(plant.state_dim + 2))


@pytest.mark.parametrize(
    "cls,arg",
    [
        (InvertedPendulum, "mass"),
        (InvertedPendulum, "length"),
        (CartPole, "cart_mass"),
        (CartPole, "pole_mass"),
        (CartPole, "pole_length"),
        (DoublePendulum, "mass_top"),
        (DoublePendulum, "length_bottom"),
        (CartPole, "dt"),
    ],
)
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_constructor_rejects_non_positive_arguments(cls, arg, value):
    with pytest.raises(ValueError, match=arg):
        cls(**{arg: value})


def test_track_limits_and_state_bounds_clip():
    cp = CartPole(track_limits=(-0.1, 0.1))
    cp.set_state([0.09, 5.0, 0.0, 0.0])
    assert cp.step(0.0)[0] == pytest.approx(0.1)
    ip = InvertedPendulum(state_bounds={"min": [-0.5, -1.0], "max": [0.5, 1.0]})
    ip.set_state([0.4, 0.9])
    x = ip.step(5.0)
    assert x[1] == pytest.approx(1.0) and x[0] <= 0.5


# ------------------------------------------------------------------ stops (track limits, state bounds)
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_cart_stop_is_inelastic_and_counted(side):
    """At the end of the track the cart stays on it with no velocity into it; the pole gets the impulse."""
    cp = CartPole(track_limits=(-0.5, 0.5), dt=0.01)
    cp.set_state([0.495 * side, 2.0 * side, 0.2, -0.3])
    x_before = cp.get_state()
    x = cp.step(0.0)
    free = CartPole(dt=0.01)  # the same step without a track, as the reference of the impact
    free.set_state(x_before)
    x_free = free.step(0.0)
    assert x[0] == 0.5 * side and x[1] == 0.0  # on the stop, at rest: not "sticking" at 2 m/s
    # M Δv = [J, 0]: the pole's rate changes by -(cos θ / l) Δẋ
    assert x[3] == pytest.approx(x_free[3] + np.cos(x_free[2]) / cp.l * x_free[1], rel=1e-12)
    assert cp.limit_violation() == pytest.approx(abs(x_free[0]) - 0.5, rel=1e-12)  # the contact is counted
    cp.set_state([0.0, 0.1, 0.0, 0.0])
    cp.step(0.0)
    assert cp.limit_violation() == 0.0
    # moving away from the stop keeps its velocity
    cp.set_state([0.5 * side, -1.0 * side, 0.0, 0.0])
    assert cp.step(0.0)[1] == pytest.approx(-1.0 * side, rel=1e-6)


def test_stops_act_on_a_batch_as_on_one_state():
    cp = CartPole(track_limits=(-0.5, 0.5))
    X = np.array([[0.6, 1.0, 0.3, 0.2], [-0.7, -2.0, -0.1, 0.0], [0.6, -1.0, 0.0, 0.0], [0.1, 3.0, 0.0, 0.0]])
    one = np.array([cp.clip_state(x.copy()) for x in X])
    np.testing.assert_array_equal(cp.clip_state(X.copy()), one)
    np.testing.assert_array_equal(one[:, 0], [0.5, -0.5, 0.5, 0.1])
    np.testing.assert_array_equal(one[:, 1], [0.0, 0.0, -1.0, 3.0])


@pytest.mark.parametrize("limits", [(0.3, 0.3), (0.5, -0.5), (0.0, float("inf")), (float("nan"), 1.0), (1.0,)])
def test_empty_inverted_or_unbounded_track_is_refused(limits):
    with pytest.raises(ValueError, match="track_limits"):
        CartPole(track_limits=limits)
    with pytest.raises(ConfigError, match="track_limits"):
        CartPole.from_config({"track_limits": list(limits)})


def test_empty_state_bounds_are_refused():
    with pytest.raises(ValueError, match="state_bounds"):
        InvertedPendulum(state_bounds={"min": [0.2, -1.0], "max": [0.2, 1.0]})
    with pytest.raises(ValueError, match="state_bounds"):
        DoublePendulum(state_bounds={"min": [1.0, -3, -9, -9], "max": [-1.0, 3, 9, 9]})


@pytest.mark.parametrize(
    ("plant", "x0", "u"),
    [
        (InvertedPendulum(state_bounds={"min": [-0.3, -20.0], "max": [0.3, 20.0]}), [0.29, 3.0], [0.0]),
        (
            DoublePendulum(state_bounds={"min": [-0.5, -0.5, -20, -20], "max": [0.5, 0.5, 20, 20]}),
            [0.49, 0.0, 4.0, 0.0],
            [0.0, 0.0],
        ),
    ],
    ids=["pendulum", "double_pendulum"],
)
def test_state_bound_stops_keep_no_velocity_into_the_limit(plant, x0, u):
    plant.set_state(x0)
    x = plant.step(u)
    assert x[0] == 0.5 if isinstance(plant, DoublePendulum) else x[0] == 0.3
    assert x[plant.velocity_indices[0]] == 0.0
    assert plant.limit_violation() > 0.0


def _wall_run(engine: bool, substeps: int = 1):
    from shinro_ctrl.engine import MujocoEngine

    p = CartPole(track_limits=(-0.5, 0.5))
    if engine:
        p.physics_engine(MujocoEngine.for_plant(p, substeps=substeps))
    p.set_state([0.3, 1.0, np.pi, 0.0])  # hanging pole: a stable, comparable motion after the impact
    X, contact = [], []
    for _ in range(150):
        X.append(p.step([2.0]))  # pushed into the +0.5 m end
        contact.append(p.limit_violation())
    return np.array(X), np.array(contact)


def test_standalone_and_mujoco_stop_the_cart_alike():
    Xs, Cs = _wall_run(False)
    Xm, Cm = _wall_run(True, substeps=4)
    assert Xs[:, 0].max() == 0.5 and Xm[:, 0].max() < 0.5 + 0.015  # MuJoCo's stop is a stiff soft constraint
    assert abs(Xs[-1, 1]) < 1e-12 and abs(Xm[-1, 1]) < 1e-3  # held at the end, not sliding along it
    np.testing.assert_allclose(Xm[:, 2], Xs[:, 2], atol=0.1)  # the pole swings alike after the impact
    np.testing.assert_allclose(Xm[-1], Xs[-1], rtol=0.05, atol=0.05)
    first_s, first_m = np.flatnonzero(Cs > 0)[0], np.flatnonzero(Cm > 0)[0]
    assert abs(first_s - first_m) <= 1 and (Cs > 0).sum() > 100 and (Cm > 0).sum() > 100


@pytest.mark.parametrize("loop", ["standalone", "mujoco"])
def test_wall_contacts_count_as_constraint_violations_in_both_loops(loop):
    from shinro_ctrl.sim import RobotSim

    doc = {
        "plant": {"type": "CartPole", "track_limits": [-0.05, 0.05]},
        "controller": {"type": "LQR", "Q": [10.0, 1.0, 100.0, 1.0], "R": [0.1]},
        "sim": {"duration": 1.0, "initial_state": [0.0, 0.0, 0.1, 0.0]},
    }
    res = RobotSim.from_config(doc, engine=loop).run()
    assert res.metrics["constraint_violations"] > 0
    assert res.x[:, 0].max() < 0.05 + 0.01
    free = RobotSim.from_config({**doc, "plant": {"type": "CartPole"}}, engine=loop).run()
    assert free.metrics["constraint_violations"] == 0 and free.x[:, 0].max() > 0.09  # without the stop it travels


def test_from_config_is_strict():
    plant = CartPole.from_config({"type": "CartPole", "pole_length": 0.8})
    assert plant.l == 0.8 and plant.M == 0.5
    with pytest.raises(ConfigError, match="did you mean 'pole_length'"):
        CartPole.from_config({"pole_lenght": 0.8})
    with pytest.raises(ConfigError, match="cart_mass"):
        CartPole.from_config({"cart_mass": -1})


def test_plant_class_resolves_aliases():
    assert plant_class("cartpole") is CartPole and plant_class("DoublePendulum") is DoublePendulum
    with pytest.raises(ConfigError, match="did you mean"):
        plant_class("cartpol")


def test_unknown_batch_parameter_is_named():
    with pytest.raises(ValueError, match="pole_mass"):
        CartPole().dynamics(np.zeros((2, 4)), np.zeros((2, 1)), params={"pole_mas": [1, 2]})


def test_overflow_in_a_diverging_step_is_simulation_diverged():
    from shinro_ctrl.errors import SimulationDiverged

    plant = CartPole()
    plant.set_state([0.0, 0.0, 1.0, 1e200])  # θ̇² overflows a Python float
    with pytest.raises(SimulationDiverged, match="non-finite"):
        plant.step(0.0)


def test_physics_engine_rejects_what_is_not_an_engine():
    from shinro_ctrl.errors import InvalidArgument

    with pytest.raises(InvalidArgument, match="expects a MujocoEngine"):
        CartPole().physics_engine("x")


# ------------------------------------------------------------------ non-finite input, threads
def _built_in_plants():
    from shinro_ctrl.plants import ArmRobot, HolonomicMobileRobot, Quadrotor

    return [CartPole(), InvertedPendulum(), DoublePendulum(), Quadrotor(), HolonomicMobileRobot(), ArmRobot()]


@pytest.mark.parametrize(
    "plant", [*_built_in_plants(), "mjcf"], ids=lambda p: p if isinstance(p, str) else type(p).__name__
)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", ["x", "u", "batch"])
def test_dynamics_with_nan_or_inf_raises_non_finite_error_like_step(plant, bad, where):
    if plant == "mjcf":
        from shinro_ctrl.plants import MjcfPlant

        plant = MjcfPlant("furuta_pendulum.xml")
    x, u = plant.equilibrium()
    x, u = x.copy(), u.copy()
    if where == "x":
        x[0] = bad  # x[0] is a position that several models' equations never read (the cart's x)
    elif where == "u":
        u[-1] = bad
    else:
        X = np.stack([x, x])
        X[1, -1] = bad
        with pytest.raises(NonFiniteError, match="NaN or inf"):
            plant.dynamics(X, np.stack([u, u]))
        return
    with pytest.raises(NonFiniteError, match="NaN or inf"):
        plant.dynamics(x, u)
    if where == "u":
        with pytest.raises(NonFiniteError):
            plant.step(u)


@pytest.mark.parametrize("plant", _built_in_plants(), ids=lambda p: type(p).__name__)
def test_dynamics_and_linearize_from_4_threads_equal_the_serial_results(plant):
    rng = np.random.default_rng(11)
    xe, ue = plant.equilibrium()
    pts = [
        (
            xe + 0.3 * rng.standard_normal((1000, plant.state_dim)),
            ue + 0.3 * rng.standard_normal((1000, plant.input_dim)),
        )
        for _ in range(4)
    ]

    def calls(X, U):
        return [(plant.dynamics(x, u), *plant.linearize(x, u)) for x, u in zip(X, U, strict=True)]

    serial = [calls(X, U) for X, U in pts]
    threaded = in_threads(lambda args: calls(*args), pts)
    for s_run, t_run in zip(serial, threaded, strict=True):
        for s, t in zip(s_run, t_run, strict=True):
            for a, b in zip(s, t, strict=True):
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("plant", _built_in_plants()[:5], ids=lambda p: type(p).__name__)
def test_a_plant_stepped_from_4_threads_is_correct_or_refuses_with_concurrent_use(plant):
    from shinro_ctrl.errors import ConcurrentUse

    x0, u0 = plant.equilibrium()
    x0 = x0 + 0.01
    plant.set_state(x0)
    u = u0 + 0.01

    def steps():
        done = refused = 0
        for _ in range(500):  # 2,000 steps at most: the open-loop quadrotor reaches gimbal lock after 2,291
            try:
                plant.step(u)
                done += 1
            except ConcurrentUse:
                refused += 1
        return done, refused

    results = in_threads(lambda _: steps(), range(4))
    total = sum(d for d, _ in results)
    assert total + sum(r for _, r in results) == 2000
    ref = type(plant)()  # the same number of steps, serially: every successful step is F(x, u)
    ref.set_state(x0)
    for _ in range(total):
        ref.step(u)
    np.testing.assert_array_equal(plant.get_state(), ref.get_state())
