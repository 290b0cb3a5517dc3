"""Holonomic base: omni-wheel kinematics against an independent formula, pose integration, MuJoCo pinning."""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.errors import ConfigError, NonFiniteError
from shinro_ctrl.plants.holonomic import HolonomicMobileRobot


def wheel_speeds_ref(u_world, theta, n, R, gamma, r):
    """Each wheel's speed from first principles.

    The world command is expressed in the body frame; the contact point of
    wheel i moves at ``v + ω ẑ × p_i``; the wheel (axle radial, ``n̂_i``)
    rolls along ``n̂_i × ẑ``; speed = rolling component / wheel radius.
    """
    c, s = np.cos(theta), np.sin(theta)
    R_wb = np.array([[c, -s], [s, c]])  # body → world
    v_body = R_wb.T @ np.asarray(u_world[:2])
    omega = u_world[2]
    speeds = []
    for i in range(n):
        a = gamma + 2 * np.pi * i / n
        p = R * np.array([np.cos(a), np.sin(a), 0.0])
        v_contact = np.array([*v_body, 0.0]) + np.cross([0.0, 0.0, omega], p)
        axle = p / np.linalg.norm(p)
        rolling = np.cross(axle, [0.0, 0.0, 1.0])
        speeds.append(rolling @ v_contact / r)
    return np.array(speeds)


@pytest.mark.parametrize("n", [3, 4, 5])
def test_wheel_speeds_match_omni_wheel_formula(n, rng):
    for _ in range(10):
        R, gamma, r = rng.uniform(0.1, 0.4), rng.uniform(-np.pi, np.pi), rng.uniform(0.02, 0.1)
        robot = HolonomicMobileRobot(num_wheels=n, radius_robots=R, gamma=gamma, radius_wheels=r)
        theta = rng.uniform(-10, 10)
        robot.set_pose(rng.normal(), rng.normal(), theta)
        u = rng.normal(size=3)
        expected = wheel_speeds_ref(u, theta, n, R, gamma, r)
        np.testing.assert_allclose(robot.wheel_speeds(u), expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(robot.step(u), expected, rtol=1e-12, atol=1e-12)
        assert robot.A_kinematics.shape == (n, 3) and robot.A_pinv_kin.shape == (3, n)


def test_step_uses_the_heading_before_the_step(rng):
    robot = HolonomicMobileRobot(dt=0.1)
    robot.set_pose(0.0, 0.0, 0.4)
    u = np.array([0.5, -0.2, 3.0])  # fast turn: the heading changes by 0.3 rad in the step
    speeds = robot.step(u)
    np.testing.assert_allclose(speeds, wheel_speeds_ref(u, 0.4, 3, robot.R, robot.gamma, robot.r), atol=1e-12)
    assert not np.allclose(speeds, wheel_speeds_ref(u, 0.7, 3, robot.R, robot.gamma, robot.r))


def test_pseudoinverse_recovers_the_body_twist(rng):
    for n in (3, 4, 6):
        robot = HolonomicMobileRobot(num_wheels=n, gamma=rng.uniform(0, 1))
        np.testing.assert_allclose(robot.A_pinv_kin @ robot.A_kinematics, np.eye(3), atol=1e-12)
        theta = rng.uniform(-3, 3)
        u = rng.normal(size=3)
        c, s = np.cos(theta), np.sin(theta)
        v_body = [c * u[0] + s * u[1], -s * u[0] + c * u[1], u[2]]
        np.testing.assert_allclose(robot.body_twist(robot.wheel_speeds(u, theta)), v_body, atol=1e-12)


def test_pose_integrates_world_command_without_wrapping(rng):
    dt = 0.02
    robot = HolonomicMobileRobot(dt=dt)
    robot.set_pose(1.0, -2.0, 3.0)
    U = rng.normal(size=(200, 3)) + np.array([0.0, 0.0, 2.0])
    for u in U:
        robot.step(u)
    expected = np.array([1.0, -2.0, 3.0]) + dt * U.sum(axis=0)
    np.testing.assert_allclose(robot.get_state(), expected, rtol=1e-12, atol=1e-12)
    assert robot.get_state()[2] > 2 * np.pi  # no angle wrapping


def test_linear_model_is_identity_and_dt():
    robot = HolonomicMobileRobot(dt=0.05)
    A, B = robot.get_model()
    np.testing.assert_array_equal(A, np.eye(3))
    np.testing.assert_allclose(B, 0.05 * np.eye(3), atol=1e-16)
    for method in ("exact", "fd"):
        A_c, B_c = robot.linearize([1, 2, 3], [0.1, 0.2, 0.3], method=method)
        np.testing.assert_allclose(A_c, np.zeros((3, 3)), atol=1e-10)
        np.testing.assert_allclose(B_c, np.eye(3), atol=1e-10)
    np.testing.assert_allclose(robot.dynamics([1, 2, 3], [4, 5, 6]), [4, 5, 6])


def test_defaults_match_the_shipped_asset():
    robot = HolonomicMobileRobot()
    assert robot.n == 3 and robot.drive_joints == ["wheel_0", "wheel_1", "wheel_2"]
    engine = MujocoEngine(robot.asset)
    m = engine.model
    for i, a in enumerate(robot.wheel_angles):
        body = m.body(f"wheel_link_{i}")
        np.testing.assert_allclose(m.body_pos[body.id], [robot.R * np.cos(a), robot.R * np.sin(a), robot.r], atol=1e-6)
        j = m.joint(f"wheel_{i}").id
        np.testing.assert_allclose(m.jnt_axis[j], [np.cos(a), np.sin(a), 0.0], atol=1e-6)
        assert m.geom_size[m.geom(f"wheel_geom_{i}").id][0] == pytest.approx(robot.r)


@pytest.mark.parametrize(
    "kwargs,name",
    [
        ({"num_wheels": 2}, "num_wheels"),
        ({"num_wheels": 3.5}, "num_wheels"),
        ({"radius_robots": 0.0}, "radius_robots"),
        ({"radius_wheels": -0.1}, "radius_wheels"),
        ({"gamma": float("nan")}, "gamma"),
        ({"dt": -1.0}, "dt"),
        ({"drive_joints": ["a", "b"]}, "drive_joints"),
        ({"drive_joints": "wheel_0"}, "drive_joints"),
    ],
)
def test_invalid_arguments_name_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        HolonomicMobileRobot(**kwargs)


def test_config_and_input_checks():
    robot = HolonomicMobileRobot.from_config({"type": "HolonomicMobileRobot", "num_wheels": 4, "gamma": 0.5})
    assert robot.n == 4 and robot.gamma == 0.5
    with pytest.raises(ConfigError, match="did you mean 'radius_wheels'"):
        HolonomicMobileRobot.from_config({"radius_wheel": 0.05})
    with pytest.raises(ValueError, match=r"\(3,\)"):
        robot.step([1.0, 0.0])
    with pytest.raises(NonFiniteError):
        robot.step([np.inf, 0.0, 0.0])


# ------------------------------------------------------------------ MuJoCo
def test_mujoco_base_follows_the_plant_pose(rng):
    robot = HolonomicMobileRobot(radius_robots=0.18, radius_wheels=0.05, dt=0.01)
    engine = MujocoEngine.for_plant(robot)
    robot.set_pose(0.2, -0.1, 0.5)
    robot.physics_engine(engine)
    np.testing.assert_allclose(engine.get_joint_qpos("root")[:2], [0.2, -0.1])
    total = np.zeros(3)
    for k in range(300):
        u = np.array([0.4 * np.cos(0.02 * k), 0.3, 2.5]) + 0.1 * rng.normal(size=3)
        total += robot.step(u) * robot.dt
        x, y, theta = robot.get_state()
        qpos, qvel = engine.get_joint_qpos("root"), engine.get_joint_vel("root")
        np.testing.assert_allclose(qpos[:3], [x, y, robot.base_height], atol=1e-15)
        quat = qpos[3:7]
        # Upright: a pure rotation about z by the (unwrapped) heading, up to the quaternion sign.
        ref = np.array([np.cos(theta / 2), 0.0, 0.0, np.sin(theta / 2)])
        assert min(np.abs(quat - ref).max(), np.abs(quat + ref).max()) < 1e-12
        np.testing.assert_array_equal(qvel, np.zeros(6))
    assert theta > 2 * np.pi
    wheels = [engine.get_joint_qpos(f"wheel_{i}") for i in range(3)]
    np.testing.assert_allclose(wheels, total, rtol=1e-10, atol=1e-10)
    # The patched geometry matches the plant.
    m = engine.model
    np.testing.assert_allclose(m.body_pos[m.body("wheel_link_1").id][2], 0.05)
    assert m.geom_size[m.geom("wheel_geom_1").id][0] == pytest.approx(0.05)
    # Body pose queries see the pinned chassis.
    pos, euler = engine.get_body_pose("chassis")
    np.testing.assert_allclose(pos[:2], robot.get_state()[:2], atol=1e-12)
    np.testing.assert_allclose(euler[:2], 0.0, atol=1e-12)


def test_post_engine_step_applies_wheel_rotation_once():
    robot = HolonomicMobileRobot()
    engine = MujocoEngine.for_plant(robot)
    robot.physics_engine(engine)
    speeds = robot.step([0.5, 0.0, 0.0])
    before = engine.get_joint_qpos("wheel_1")
    robot.post_engine_step(engine)  # as a generic sim loop might also do
    assert engine.get_joint_qpos("wheel_1") == before == pytest.approx(speeds[1] * robot.dt)


def test_engine_without_free_joint_is_a_no_op():
    xml = """<mujoco><worldbody><body name="b"><joint name="wheel_0" type="hinge"/>
    <joint name="wheel_1" type="hinge" axis="1 0 0"/><joint name="wheel_2" type="hinge" axis="0 1 0"/>
    <inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>"""
    engine = MujocoEngine(xml)
    robot = HolonomicMobileRobot()
    robot.physics_engine(engine)
    q_before = engine.data.qpos.copy()
    robot.step([0.1, 0.2, 0.3])
    np.testing.assert_allclose(robot.get_state(), [0.001, 0.002, 0.003])
    np.testing.assert_array_equal(engine.data.qpos, q_before)


def test_attach_checks_drive_joints():
    robot = HolonomicMobileRobot(num_wheels=4)  # the shipped asset has 3 wheels
    with pytest.raises(KeyError, match="wheel_3"):
        robot.physics_engine(MujocoEngine.for_plant(robot))
