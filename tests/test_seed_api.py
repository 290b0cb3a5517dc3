"""The seed's documented ``shinro.plants`` API (``shared/reference/shinro-plants-api.txt``) keeps working.

Every documented method is called with the documented argument names (as keywords), orders and
defaults, and its documented result is checked against an independent reference: the seed's own
closed forms (the pendulum and cart-pole equations of motion and upright Jacobians, the omni-wheel
kinematic matrix, ``A = I, B = dt I`` of the kinematic plants), central differences, or MuJoCo.
The seed's ``Quadrotor`` is a placeholder that raises; ours is implemented and tested elsewhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from shinro_ctrl.backend import NumpyBackend
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import ArmRobot, CartPole, DoublePendulum, HolonomicMobileRobot, InvertedPendulum
from shinro_ctrl.plants.armrobot import ARM6

BK = NumpyBackend()


def central_jacobians(f, x0, u0, eps=1e-6):
    """Independent central differences of ``f(x, u)``."""
    n, m = len(x0), len(u0)
    A, B = np.zeros((n, n)), np.zeros((n, m))
    for i in range(n):
        d = np.zeros(n)
        d[i] = eps
        A[:, i] = (f(x0 + d, u0) - f(x0 - d, u0)) / (2 * eps)
    for j in range(m):
        d = np.zeros(m)
        d[j] = eps
        B[:, j] = (f(x0, u0 + d) - f(x0, u0 - d)) / (2 * eps)
    return A, B


# ------------------------------------------------------------------ InvertedPendulum
def seed_pendulum_xdot(x, u, m=0.1, l=0.5, b=0.0, g=9.81):
    """The seed's documented pendulum equation."""
    return np.array([x[1], g / l * math.sin(x[0]) + u[0] / (m * l**2) - b / (m * l**2) * x[1]])


def test_inverted_pendulum_constructor_keywords_defaults_and_dynamics():
    p = InvertedPendulum(
        mass=0.1, length=0.5, damping=0.0, gravity=9.81, dt=0.01, state_bounds=None, backend=NumpyBackend()
    )
    assert p.dt == 0.01 and p.input_dim == 1
    np.testing.assert_array_equal(p.get_state(), np.zeros(2))  # documented initial state
    rng = np.random.default_rng(0)
    for _ in range(5):
        x, u = rng.normal(size=2), rng.normal(size=1)
        np.testing.assert_allclose(p.dynamics(state=x, control=u), seed_pendulum_xdot(x, u), rtol=1e-12)
        np.testing.assert_allclose(p.dynamics(x, float(u[0])), seed_pendulum_xdot(x, u), rtol=1e-12)  # scalar


def test_inverted_pendulum_get_model_with_the_documented_arguments():
    p = InvertedPendulum(mass=0.2, length=0.4, damping=0.05, dt=0.02)
    m, l, b, g, dt = 0.2, 0.4, 0.05, 9.81, 0.02
    A_c = np.array([[0.0, 1.0], [g / l, -b / (m * l**2)]])  # the seed's documented upright Jacobians
    B_c = np.array([[0.0], [1.0 / (m * l**2)]])
    for A, B in (p.get_model(), p.get_model(x0=None, u0=None, eps=1e-6), p.get_model(None, None, 1e-6)):
        np.testing.assert_allclose(A, np.eye(2) + dt * A_c, atol=1e-9)
        np.testing.assert_allclose(B, dt * B_c, atol=1e-9)
    x0, u0 = np.array([0.3, -0.2]), np.array([0.1])
    A, B = p.get_model(x0=x0, u0=u0, eps=1e-6)
    Ac, Bc = central_jacobians(lambda x, u: seed_pendulum_xdot(x, u, m, l, b, g), x0, u0)
    np.testing.assert_allclose(A, np.eye(2) + dt * Ac, atol=1e-7)
    np.testing.assert_allclose(B, dt * Bc, atol=1e-7)


def test_inverted_pendulum_step_is_the_documented_semi_implicit_euler():
    p = InvertedPendulum(dt=0.01)
    p.set_state([0.1, -0.3])
    x = np.array([0.1, -0.3])
    for tau in (0.05, -0.2, 0.0):
        new = p.step(u=[tau])
        theta_ddot = seed_pendulum_xdot(x, [tau])[1]
        w = x[1] + theta_ddot * 0.01
        x = np.array([x[0] + w * 0.01, w])
        np.testing.assert_allclose(new, x, rtol=1e-12)
    np.testing.assert_allclose(p.step(0.01), p.get_state())  # a scalar input


def test_inverted_pendulum_from_config_takes_the_seeds_backend_and_runtime_engine():
    cfg = {"mass": 0.2, "length": 0.6, "damping": 0.01, "gravity": 9.81, "dt": 0.005}
    p = InvertedPendulum.from_config(cfg, backend=NumpyBackend())
    assert (p.m, p.l, p.b, p.dt) == (0.2, 0.6, 0.01, 0.005)
    p = InvertedPendulum.from_config({**cfg, "state_bounds": {"min": [-1.0, -5.0], "max": [1.0, 5.0]}}, None)
    np.testing.assert_array_equal(p.state_limits()[1], [1.0, 5.0])
    engine = MujocoEngine.for_plant(InvertedPendulum(**cfg))
    p = InvertedPendulum.from_config({**cfg, "engine": engine}, backend=NumpyBackend())
    assert p.engine is engine
    np.testing.assert_array_equal(p.get_state(), np.zeros(2))  # documented: zeros on attach


def test_physics_engine_attach_step_and_detach():
    p = InvertedPendulum(dt=0.01)
    engine = MujocoEngine.for_plant(p)
    p.physics_engine(engine=engine)
    engine.set_joint_qpos("hinge", 0.05)
    np.testing.assert_allclose(p.get_state(), [0.05, 0.0])  # documented: read from the engine
    x = p.step(0.0)
    assert engine.get_joint_qpos("hinge") == pytest.approx(x[0]) and x[1] > 0  # falls away from upright
    p.physics_engine(None)
    assert p.engine is None
    np.testing.assert_allclose(p.step(0.0)[0], x[0] + 0.01 * (x[1] + 0.01 * seed_pendulum_xdot(x, [0.0])[1]))


# ------------------------------------------------------------------ CartPole
def seed_cartpole_xdot(x, u, M=0.5, m=0.1, l=0.5, g=9.81):
    """The seed's documented cart-pole equations (no damping)."""
    _, xd, th, thd = x
    F = u[0]
    s, c = math.sin(th), math.cos(th)
    tdd = (g * s - c * (F + m * l * thd**2 * s) / (M + m)) / (l - m * l * c**2 / (M + m))
    xdd = (F + m * l * (thd**2 * s - tdd * c)) / (M + m)
    return np.array([xd, xdd, thd, tdd])


def test_cartpole_dynamics_step_and_model_match_the_seeds_equations():
    p = CartPole(
        cart_mass=0.5,
        pole_mass=0.1,
        pole_length=0.5,
        damping=0.0,
        gravity=9.81,
        dt=0.01,
        track_limits=None,
        backend=None,
    )
    rng = np.random.default_rng(1)
    for _ in range(5):
        x, u = rng.normal(size=4), rng.normal(size=1)
        np.testing.assert_allclose(p.dynamics(state=x, control=u), seed_cartpole_xdot(x, u), rtol=1e-10, atol=1e-12)
    M, m, l, g, dt = 0.5, 0.1, 0.5, 9.81, 0.01
    A_c = np.array([[0, 1, 0, 0], [0, 0, -m * g / M, 0], [0, 0, 0, 1], [0, 0, (M + m) * g / (M * l), 0]])
    B_c = np.array([[0], [1 / M], [0], [-1 / (M * l)]])
    A, B = p.get_model(x0=None, u0=None, eps=1e-6)
    np.testing.assert_allclose(A, np.eye(4) + dt * A_c, atol=1e-9)
    np.testing.assert_allclose(B, dt * B_c, atol=1e-9)
    p.set_state([0.0, 0.1, 0.05, 0.0])
    x = np.array([0.0, 0.1, 0.05, 0.0])
    new = p.step(u=np.array([0.3]))
    a = seed_cartpole_xdot(x, [0.3])
    v = x[[1, 3]] + dt * a[[1, 3]]
    np.testing.assert_allclose(new, [x[0] + dt * v[0], v[0], x[2] + dt * v[1], v[1]], rtol=1e-12)


def test_cartpole_from_config_with_the_seeds_fields():
    cfg = {"cart_mass": 1.0, "pole_mass": 0.2, "pole_length": 0.4, "damping": 0.0, "gravity": 9.81, "dt": 0.01}
    p = CartPole.from_config({**cfg, "track_limits": [-1.0, 1.0]}, backend=NumpyBackend())
    assert p.track_limits == (-1.0, 1.0) and p.M == 1.0
    engine = MujocoEngine.for_plant(CartPole(**cfg))
    p = CartPole.from_config({**cfg, "engine": engine})
    assert p.engine is engine and p.get_state().shape == (4,)


# ------------------------------------------------------------------ DoublePendulum
def test_double_pendulum_documented_api():
    p = DoublePendulum(
        mass_top=0.1,
        mass_bottom=0.1,
        length_top=0.5,
        length_bottom=0.5,
        dt=0.01,
        g=9.81,
        state_bounds=None,
        backend=None,
    )
    assert p.input_dim == 2
    # Hanging at rest is an equilibrium; a single pendulum's small-angle frequency holds for a rigid pair.
    np.testing.assert_allclose(p.dynamics(state=np.zeros(4), control=np.zeros(2)), np.zeros(4), atol=1e-15)
    x0, u0 = np.array([0.2, -0.1, 0.3, 0.1]), np.zeros(2)
    A, B = p.get_model(x0=x0, u0=u0, eps=1e-6)
    Ac, Bc = central_jacobians(lambda x, u: p.dynamics(x, u), x0, u0)
    np.testing.assert_allclose(A, np.eye(4) + 0.01 * Ac, atol=1e-7)
    np.testing.assert_allclose(B, 0.01 * Bc, atol=1e-7)
    # Free motion conserves energy to O(dt) with semi-implicit Euler (symplectic: bounded drift).
    p.set_state([0.5, 0.2, 0.0, 0.0])
    e0 = p.energy(p.get_state())
    for _ in range(500):
        p.step(u=[0.0, 0.0])
    assert abs(p.energy(p.get_state()) - e0) < 0.01 * abs(e0)
    p = DoublePendulum.from_config(
        {"mass_top": 0.2, "state_bounds": {"min": [-3.0, -3.0, -9.0, -9.0], "max": [3.0, 3.0, 9.0, 9.0]}},
        backend=NumpyBackend(),
    )
    assert p.m1 == 0.2 and p.state_limits()[0][0] == -3.0


# ------------------------------------------------------------------ HolonomicMobileRobot
def test_holonomic_documented_kinematics_and_model():
    r = HolonomicMobileRobot(
        num_wheels=3, radius_robots=0.2, gamma=0.1, radius_wheels=0.05, dt=0.01, drive_joints=None, backend=None
    )
    a = 0.1 + 2 * np.pi * np.arange(3) / 3
    A_kin = np.column_stack([np.sin(a), -np.cos(a), np.full(3, -0.2)])  # the seed's documented rows
    np.testing.assert_allclose(r.A_kinematics, A_kin, atol=1e-15)
    r.set_pose(x=1.0, y=-0.5, theta=0.7)
    np.testing.assert_allclose(r.get_state(), [1.0, -0.5, 0.7])
    u = np.array([0.3, -0.2, 0.5])
    c, s = math.cos(0.7), math.sin(0.7)
    u_body = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ u
    speeds = r.step(u_world=u)
    np.testing.assert_allclose(speeds, A_kin @ u_body / 0.05, rtol=1e-12)
    np.testing.assert_allclose(r.get_state(), [1.0, -0.5, 0.7] + 0.01 * u, rtol=1e-12)
    A, B = r.get_model()
    np.testing.assert_allclose(A, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(B, 0.01 * np.eye(3), atol=1e-15)
    cfg = {"num_wheels": 3, "radius_robots": 0.15, "gamma": 0.0, "radius_wheels": 0.04, "dt": 0.01}
    r2 = HolonomicMobileRobot.from_config(cfg, backend=NumpyBackend())
    assert r2.n == 3 and r2.dt == 0.01
    wheels = ["w_a", "w_b", "w_c"]  # the seed: drive joints from the runtime joint_groups
    r3 = HolonomicMobileRobot.from_config({**cfg, "joint_groups": {"drive_joints": wheels}}, backend=None)
    assert r3.drive_joints == wheels


def test_holonomic_engine_and_post_engine_step():
    r = HolonomicMobileRobot()
    engine = MujocoEngine.for_plant(r)
    r.physics_engine(engine=engine)
    r.step(u_world=[0.2, 0.0, 0.0])
    r.post_engine_step(engine=engine)  # documented: re-pins the pose, harmless after step
    qpos = engine.get_joint_qpos("root")
    np.testing.assert_allclose(qpos[:2], r.get_state()[:2], atol=1e-12)


# ------------------------------------------------------------------ ArmRobot
def _seed_arm(**kw) -> ArmRobot:
    return ArmRobot(
        num_dof=6,
        dt=0.002,
        joint_limits=np.array(ARM6["joint_limits"]),
        joint_offsets=np.array(ARM6["joint_offsets"]),
        rot_axes=list(ARM6["rot_axes"]),
        **kw,
    )


def _rot(axis: str, q: float) -> np.ndarray:
    c, s = math.cos(q), math.sin(q)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def test_arm_forward_kinematics_chains_the_documented_transforms():
    arm = _seed_arm(joint_names=None, ee_body_name=None, backend=None)
    q = np.array([0.3, -0.5, 0.8, 0.1, -0.2, 0.4])
    T, positions, axes = arm.forward_kinematics(joint_angles=q)
    Tc = np.eye(4)
    for i in range(6):  # the seed: T_i = T_{i-1} Trans(o_i) Rot(a_i, q_i)
        Ti = np.eye(4)
        Ti[:3, :3] = _rot(ARM6["rot_axes"][i], q[i])
        Ti[:3, 3] = ARM6["joint_offsets"][i]
        Tc = Tc @ Ti
        np.testing.assert_allclose(positions[i], Tc[:3, 3], atol=1e-12)
        np.testing.assert_allclose(axes[i], Tc[:3, :3] @ np.eye(3)["xyz".index(ARM6["rot_axes"][i])], atol=1e-12)
    np.testing.assert_allclose(T, Tc, atol=1e-12)


def test_arm_inverse_kinematics_step_and_model_with_documented_arguments():
    arm = _seed_arm()
    q_goal = np.array([0.2, -0.4, 0.7, -0.3, 0.5, 0.1])
    T_goal, _, _ = arm.forward_kinematics(q_goal)
    q = arm.inverse_kinematics(target_pose=T_goal, max_iters=100, q_init=q_goal + 0.05, tol=1e-4, max_step=0.2)
    np.testing.assert_allclose(arm.forward_kinematics(q)[0][:3, 3], T_goal[:3, 3], atol=1e-4)
    A, B = arm.get_model()
    np.testing.assert_allclose(A, np.eye(6), atol=1e-15)
    np.testing.assert_allclose(B, 0.002 * np.eye(6), atol=1e-15)
    arm.set_joint_positions(q_goal)  # away from the stretched (singular) home pose
    x = arm.get_state()
    joints = arm.step(u=np.array([0.05, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert joints.shape == (6,)
    np.testing.assert_allclose(arm.get_state()[:3], x[:3] + 0.002 * np.array([0.05, 0, 0]), atol=1e-6)
    with pytest.raises(RuntimeError):
        arm.engine_ik(target_ee=x[:3])  # documented: no engine attached


def test_arm_from_config_with_runtime_engine_and_joint_groups_and_engine_ik():
    engine = MujocoEngine.for_plant(ArmRobot())
    cfg = {
        "joint_group": "arm",
        "num_dof": 6,
        "dt": 0.002,
        "joint_offsets": ARM6["joint_offsets"],
        "rot_axes": ARM6["rot_axes"],
        "engine": engine,
        "joint_groups": {"arm": ARM6["joint_names"]},
    }
    arm = ArmRobot.from_config(cfg, backend=NumpyBackend())
    assert arm.engine is engine and arm.joint_names == tuple(ARM6["joint_names"])
    np.testing.assert_allclose(arm.joint_limits, [engine.get_joint_limits(n) for n in ARM6["joint_names"]])
    x = arm.get_state()
    target = x[:3] + np.array([0.0, 0.02, -0.01])
    q = arm.engine_ik(target_ee=target, target_euler=None, max_iters=20, lam=0.01, max_dq=0.5)
    np.testing.assert_allclose(arm.forward_kinematics(q)[0][:3, 3], target, atol=2e-3)
    arm.physics_engine(engine=None)
    assert arm.engine is None
