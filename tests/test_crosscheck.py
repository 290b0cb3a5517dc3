"""MuJoCo's linearization of the matched MJCF models against the plants' exact one."""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.crosscheck import CrosscheckResult, crosscheck, format_crosscheck, mujoco_continuous_jacobians
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum

from .conftest import PENDULUM_FAMILY, random_params

REL_TOL = 1e-3


def assert_mujoco_matches_exact(r: CrosscheckResult) -> None:
    """|mujoco − exact| <= REL_TOL · max(1, |exact|), entry by entry, for A and B."""
    for name, got, ref in (("A", r.A_mujoco, r.A_exact), ("B", r.B_mujoco, r.B_exact)):
        bound = REL_TOL * np.maximum(1.0, np.abs(ref))
        bad = np.abs(got - ref) > bound
        assert not bad.any(), (
            f"{r.plant} at x0={r.x0}, u0={r.u0}: {name} from MuJoCo differs from the exact one at "
            f"{np.argwhere(bad).tolist()}\nexact:\n{ref}\nmujoco:\n{got}"
        )
    assert r.mujoco_max_rel_error < REL_TOL


EQUILIBRIA = [
    pytest.param(InvertedPendulum, None, id="pendulum-upright"),
    pytest.param(CartPole, None, id="cartpole-upright"),
    pytest.param(DoublePendulum, None, id="double-hanging"),
    pytest.param(DoublePendulum, "upright", id="double-upright"),
]


@pytest.mark.parametrize(("cls", "point"), EQUILIBRIA)
def test_mujoco_matches_exact_at_equilibria(cls, point):
    plant = cls()
    x0, u0 = plant.upright() if point == "upright" else plant.equilibrium()
    r = crosscheck(plant, x0, u0)
    assert_mujoco_matches_exact(r)
    # The point is an equilibrium in MuJoCo too: nothing moves when simulated from it.
    engine = MujocoEngine.for_plant(plant)
    plant.physics_engine(engine)
    plant.set_state(x0)
    np.testing.assert_allclose(plant.step(u0), x0, atol=1e-12)


@pytest.mark.parametrize("draw", range(3))
@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_mujoco_matches_exact_for_random_parameters(cls, draw):
    rng = np.random.default_rng([2024, draw, PENDULUM_FAMILY.index(cls)])
    plant = cls(**random_params(cls, rng), dt=rng.choice([0.001, 0.005, 0.02]))
    # Off-equilibrium, with velocities and an input: exercises every nonlinear term.
    x0 = np.concatenate([rng.uniform(-1.0, 1.0, plant.state_dim // 2), rng.uniform(-2.0, 2.0, plant.state_dim // 2)])
    u0 = rng.uniform(-1.0, 1.0, plant.input_dim)
    for point in ((None, None), (x0, u0)):
        assert_mujoco_matches_exact(crosscheck(plant, *point))


def test_cartpole_matches_closed_form_with_damping():
    """An independent oracle: the hinge-torque damping term −b (M+m) / (M m l²)."""
    M, m, l, b, g = 0.7, 0.2, 0.6, 0.15, 9.81
    r = crosscheck(CartPole(cart_mass=M, pole_mass=m, pole_length=l, damping=b, gravity=g))
    A_ref = np.array(
        [
            [0, 1, 0, 0],
            [0, 0, -m * g / M, b / (M * l)],
            [0, 0, 0, 1],
            [0, 0, (M + m) * g / (M * l), -b * (M + m) / (M * m * l**2)],
        ]
    )
    B_ref = np.array([[0], [1 / M], [0], [-1 / (M * l)]])
    np.testing.assert_allclose(r.A_mujoco, A_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(r.B_mujoco, B_ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_crosscheck_result_and_report(cls):
    plant = cls()
    before = plant.get_state()
    r = crosscheck(plant)
    assert plant.engine is None  # the plant is left alone
    np.testing.assert_array_equal(plant.get_state(), before)
    n, m = plant.state_dim, plant.input_dim
    for M in (r.A_exact, r.A_fd, r.A_mujoco):
        assert M.shape == (n, n)
    for M in (r.B_exact, r.B_fd, r.B_mujoco):
        assert M.shape == (n, m)
    assert r.fd_max_rel_error < 1e-6
    assert min(r.time_exact_s, r.time_fd_s, r.time_mujoco_s, r.time_build_s) > 0.0
    text = format_crosscheck(r)
    for word in (*plant.state_names, *plant.input_names, "exact", "finite differences", "MuJoCo"):
        assert word in text
    assert f"{r.mujoco_max_abs_error:.2e}" in text


def test_state_map_relates_plant_and_engine_states(rng):
    for cls in PENDULUM_FAMILY:
        plant = cls()
        engine = MujocoEngine.for_plant(plant)
        plant.physics_engine(engine)
        x = rng.uniform(-1.0, 1.0, plant.state_dim)
        plant.set_state(x)
        T, perm = plant.engine_state_map()
        np.testing.assert_allclose(T @ engine.get_state_vector(), x, atol=1e-15)
        assert sorted(perm.tolist()) == list(range(plant.state_dim))


def test_continuous_recovery_rejects_other_integrators():
    xml = """<mujoco><option integrator="RK4"/><worldbody><body><joint name="j" axis="0 1 0"/>
      <inertial pos="0 0 1" mass="1" diaginertia="1e-8 1e-8 1e-8"/></body></worldbody>
      <actuator><motor joint="j"/></actuator></mujoco>"""
    engine = MujocoEngine(xml)
    with pytest.raises(ValueError, match="Euler"):
        mujoco_continuous_jacobians(engine, np.zeros(2), np.zeros(1))


@pytest.mark.parametrize(
    "x0,u0",
    [
        (None, None),  # hover
        ([0.1, 0.2, 0.3, 0.3, -0.2, 0.5, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0], [5.0, 0.01, 0.0, 0.0]),  # tilted, moving
    ],
    ids=["hover", "tilted"],
)
def test_quadrotor_free_joint_crosscheck(x0, u0):
    from shinro_ctrl.plants import Quadrotor

    res = crosscheck(Quadrotor(), x0, u0)
    assert res.mujoco_max_rel_error < 1e-6


def test_quadrotor_crosscheck_refuses_points_where_the_coordinate_map_moves():
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.plants import Quadrotor

    x0 = [0, 0, 0, 0.3, -0.2, 0.5, 0, 0, 0, 0.2, 0.1, 0]  # body rates turn the Euler-angle map
    with pytest.raises(InvalidArgument, match="not comparable"):
        crosscheck(Quadrotor(), x0, [5.0, 0, 0, 0])
