"""ArmRobot: construction, FK and Jacobians against independent references, IK, step, engine mode."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shinro_ctrl.errors import ConfigError, NonFiniteError
from shinro_ctrl.kinematics import (
    euler_zyx_from_matrix,
    euler_zyx_to_matrix,
    pose_from_transform,
    pose_to_transform,
    so3_exp,
    so3_log,
    wrap_angle,
)
from shinro_ctrl.plants.armrobot import ARM6_JOINTS, ArmRobot
from shinro_ctrl.resources import config_path

engine_mod = pytest.importorskip("shinro_ctrl.engine")
MujocoEngine = engine_mod.MujocoEngine

AXIS = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def arm6_config() -> dict:
    with open(config_path("arm6"), "rb") as fh:
        return tomllib.load(fh)["plant"]


@pytest.fixture
def cfg() -> dict:
    return arm6_config()


@pytest.fixture
def arm(cfg) -> ArmRobot:
    return ArmRobot.from_config(cfg)


@pytest.fixture
def engine_arm(cfg) -> ArmRobot:
    standalone = ArmRobot.from_config(cfg)
    engine = MujocoEngine.for_plant(standalone)
    return ArmRobot.from_config({k: v for k, v in cfg.items() if k != "joint_limits"}, engine=engine)


def random_q(arm: ArmRobot, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(arm.joint_limits[:, 0], arm.joint_limits[:, 1])


def reference_fk(offsets, axes, q, ee_offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Independent chain: 4x4 products of Trans(o) and scipy rotations about unit axes."""
    T = np.eye(4)
    for o, a, qi in zip(offsets, axes, q, strict=True):
        step = np.eye(4)
        step[:3, 3] = o
        step[:3, :3] = Rotation.from_rotvec(qi * AXIS[a]).as_matrix()
        T = T @ step
    tail = np.eye(4)
    tail[:3, 3] = ee_offset
    return T @ tail


# ---------------------------------------------------------------- construction
def test_public_attributes(arm, cfg):
    assert arm.num_dof == 6
    assert arm.joint_limits.shape == (6, 2) and arm.joint_offsets.shape == (6, 3)
    assert arm.axes == tuple(cfg["rot_axes"]) == ("z", "y", "y", "y", "z", "x")
    assert arm.joint_names == ARM6_JOINTS
    assert arm.dt == cfg["dt"]
    assert arm.state_names == ("x", "y", "z", "roll", "pitch", "yaw")
    assert len(arm.input_names) == 6 and arm.param_names == ()
    assert arm.state_dim == arm.input_dim == 6


def _kwargs(**over):
    kw = {
        "num_dof": 2,
        "dt": 0.01,
        "joint_limits": [[-1, 1], [-1, 1]],
        "joint_offsets": [[0, 0, 0.1], [0.2, 0, 0]],
        "rot_axes": ["z", "y"],
    }
    kw.update(over)
    return kw


@pytest.mark.parametrize(
    ("over", "word"),
    [
        ({"num_dof": 0}, "num_dof"),
        ({"dt": 0.0}, "dt"),
        ({"dt": -0.1}, "dt"),
        ({"joint_limits": [[-1, 1]]}, "joint_limits"),
        ({"joint_limits": [[1, -1], [-1, 1]]}, "joint_limits"),
        ({"joint_offsets": [[0, 0], [0, 0]]}, "joint_offsets"),
        ({"rot_axes": ["z"]}, "rot_axes"),
        ({"rot_axes": ["z", "w"]}, "rot_axes"),
        ({"joint_names": ["a"]}, "joint_names"),
        ({"joint_names": ["a", "a"]}, "joint_names"),
        ({"ee_offset": [0, 0]}, "ee_offset"),
    ],
)
def test_constructor_rejects_bad_arguments(over, word):
    with pytest.raises(ValueError, match=word):
        ArmRobot(**_kwargs(**over))


def test_constructor_rejects_non_finite():
    with pytest.raises(NonFiniteError, match="joint_offsets"):
        ArmRobot(**_kwargs(joint_offsets=[[0, 0, np.nan], [0, 0, 0]]))


def test_axes_string_and_defaults():
    arm = ArmRobot(**_kwargs(rot_axes="zy"))
    assert arm.axes == ("z", "y")
    assert arm.joint_names == ("joint_0", "joint_1")
    np.testing.assert_array_equal(arm.ee_offset, np.zeros(3))


# ---------------------------------------------------------------- model
def test_cartesian_model(arm):
    A, B = arm.get_model()
    np.testing.assert_array_equal(A, np.eye(6))
    np.testing.assert_allclose(B, arm.dt * np.eye(6), rtol=0, atol=1e-15)
    Ae, Be = arm.linearize(method="exact")
    Af, Bf = arm.linearize(method="fd")
    np.testing.assert_allclose(Ae, Af, atol=1e-9)
    np.testing.assert_allclose(Be, Bf, atol=1e-9)
    u = np.arange(6.0)
    np.testing.assert_array_equal(arm.dynamics(np.zeros(6), u), u)
    batch = np.arange(12.0).reshape(2, 6)
    np.testing.assert_array_equal(arm.dynamics(np.zeros((2, 6)), batch), batch)
    x0, u0 = arm.equilibrium()
    np.testing.assert_allclose(x0, arm.ee_pose(np.zeros(6)), atol=1e-15)
    np.testing.assert_array_equal(u0, np.zeros(6))


# ---------------------------------------------------------------- SO(3)
def test_so3_log_exp_roundtrip(rng):
    angles = np.concatenate([[0.0, 1e-9, 1e-5, 0.5, 2.0, np.pi - 1e-4, np.pi - 1e-9, np.pi], rng.uniform(0, np.pi, 50)])
    for theta in angles:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        R = Rotation.from_rotvec(theta * axis).as_matrix()
        w = so3_log(R)
        assert np.linalg.norm(w) <= np.pi + 1e-12
        np.testing.assert_allclose(so3_exp(w), R, atol=1e-9)
        np.testing.assert_allclose(Rotation.from_rotvec(w).as_matrix(), R, atol=1e-9)
        if theta < np.pi - 1e-3:  # away from π the vector itself is unique
            np.testing.assert_allclose(w, theta * axis, atol=1e-9)


def test_euler_zyx_roundtrip_including_gimbal_lock(rng):
    cases = [rng.uniform([-np.pi, -np.pi / 2, -np.pi], [np.pi, np.pi / 2, np.pi]) for _ in range(50)]
    cases += [
        np.array([0.3, np.pi / 2, -0.4]),
        np.array([0.3, -np.pi / 2, 0.2]),
        np.array([0.1, np.pi / 2 - 1e-7, 0.2]),
    ]
    for rpy in cases:
        R = euler_zyx_to_matrix(rpy)
        np.testing.assert_allclose(R, Rotation.from_euler("ZYX", rpy[::-1]).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(euler_zyx_to_matrix(euler_zyx_from_matrix(R)), R, atol=1e-9)
    pose = np.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])
    np.testing.assert_allclose(pose_from_transform(pose_to_transform(pose)), pose, atol=1e-12)
    assert wrap_angle(3 * np.pi) == pytest.approx(np.pi)
    np.testing.assert_allclose(wrap_angle(np.array([-3 * np.pi, 0.5])), [np.pi, 0.5])


# ---------------------------------------------------------------- FK
def test_fk_matches_independent_chain(arm, rng):
    for _ in range(50):
        q = random_q(arm, rng)
        T, positions, axes = arm.forward_kinematics(q)
        np.testing.assert_allclose(T, reference_fk(arm.joint_offsets, arm.axes, q), atol=1e-9)
        # joint i sits at the origin of the chain up to offset i and turns about its own axis
        for i in range(arm.num_dof):
            Ti = reference_fk(arm.joint_offsets[: i + 1], arm.axes[: i + 1], q[: i + 1])
            np.testing.assert_allclose(positions[i], Ti[:3, 3], atol=1e-9)
            np.testing.assert_allclose(axes[i], Ti[:3, :3] @ AXIS[arm.axes[i]], atol=1e-9)
        np.testing.assert_allclose(arm.ee_pose(q), pose_from_transform(T), atol=1e-12)


def test_fk_with_ee_offset(rng):
    kw = _kwargs(ee_offset=[0.05, -0.02, 0.1])
    arm = ArmRobot(**kw)
    q = rng.uniform(-1, 1, 2)
    T, _, _ = arm.forward_kinematics(q)
    np.testing.assert_allclose(T, reference_fk(kw["joint_offsets"], kw["rot_axes"], q, kw["ee_offset"]), atol=1e-12)
    for method in ("exact", "fd"):
        np.testing.assert_allclose(arm.jacobian(q), arm.jacobian(q, method), atol=1e-6)


def test_fk_matches_mujoco_site(engine_arm, rng):
    engine = engine_arm.engine
    for _ in range(30):
        q = random_q(engine_arm, rng)
        for name, v in zip(engine_arm.joint_names, q, strict=True):
            engine.set_joint_qpos(name, v)
        engine.forward()
        T, _, _ = engine_arm.forward_kinematics(q)
        pos, _ = engine.get_site_pose("ee_site")
        np.testing.assert_allclose(T[:3, 3], pos, atol=1e-6)
        sid = engine.model.site("ee_site").id
        np.testing.assert_allclose(T[:3, :3], engine.data.site_xmat[sid].reshape(3, 3), atol=1e-9)


def test_mjcf_patch_follows_offsets(cfg, rng):
    cfg = dict(cfg)
    cfg["joint_offsets"] = (np.array(cfg["joint_offsets"]) * 1.2 + 0.01).tolist()
    arm = ArmRobot.from_config(cfg)
    engine = MujocoEngine.for_plant(arm)
    assert engine.dt == pytest.approx(arm.dt)
    q = random_q(arm, rng)
    for name, v in zip(arm.joint_names, q, strict=True):
        engine.set_joint_qpos(name, v)
    engine.forward()
    np.testing.assert_allclose(engine.get_site_pose("ee_site")[0], arm.forward_kinematics(q)[0][:3, 3], atol=1e-9)
    with pytest.raises(ValueError, match=r"arm6\.xml"):
        ArmRobot(**_kwargs()).mjcf_patch()


# ---------------------------------------------------------------- Jacobians
def test_jacobian_three_ways(arm, rng):
    for _ in range(30):
        q = random_q(arm, rng)
        Jg = arm.jacobian(q)
        assert Jg.shape == (6, 6)
        np.testing.assert_allclose(Jg, arm.jacobian(q, "exact"), atol=1e-9)
        np.testing.assert_allclose(Jg, arm.jacobian(q, "fd"), atol=1e-6)
        # angular rows are the world joint axes; position rows axis x lever arm
        T, positions, axes = arm.forward_kinematics(q)
        for i in range(6):
            np.testing.assert_allclose(Jg[3:, i], axes[i], atol=1e-12)
            np.testing.assert_allclose(Jg[:3, i], np.cross(axes[i], T[:3, 3] - positions[i]), atol=1e-12)
    with pytest.raises(ValueError, match="geometric"):
        arm.jacobian(np.zeros(6), "analytic")


def test_jacobian_matches_mujoco(engine_arm, rng):
    engine = engine_arm.engine
    for _ in range(30):
        q = random_q(engine_arm, rng)
        for name, v in zip(engine_arm.joint_names, q, strict=True):
            engine.set_joint_qpos(name, v)
        engine.forward()
        J_mj = engine.get_site_jacobian("ee_site")
        J = engine_arm.jacobian(q)
        np.testing.assert_allclose(J[:3], J_mj[:3], atol=1e-9)
        np.testing.assert_allclose(J[3:], J_mj[3:], atol=1e-9)


def test_symbolic_fk(arm, rng):
    fk = arm.symbolic_fk()
    assert fk.name() == "fk"
    q = random_q(arm, rng)
    p, R = fk(q)
    T, _, _ = arm.forward_kinematics(q)
    np.testing.assert_allclose(np.array(p).ravel(), T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(np.array(R), T[:3, :3], atol=1e-12)


def test_home_pose_is_nonsingular_and_inside_limits(arm):
    q0 = np.zeros(6)
    assert np.all(arm.joint_limits[:, 0] < q0) and np.all(q0 < arm.joint_limits[:, 1])
    cond = np.linalg.cond(arm.jacobian(q0))
    assert cond < 10.0  # 8.1 for the shipped offsets
    np.testing.assert_array_equal(arm.q, q0)


# ---------------------------------------------------------------- IK and step
def test_dls_inverse_kinematics_near_home(arm, rng):
    lo, hi = arm.joint_limits.T
    for _ in range(10):
        q_goal = np.clip(rng.uniform(-0.3, 0.3, 6), lo, hi)
        T, _, _ = arm.forward_kinematics(q_goal)
        res = arm.inverse_kinematics(T, q_init=np.zeros(6), full_output=True)
        assert res.converged and res.pos_err < 1e-4 and res.ori_err < 1e-4
        assert np.all(res.q >= lo) and np.all(res.q <= hi)
        np.testing.assert_allclose(arm.inverse_kinematics(T, q_init=np.zeros(6)), res.q)


def test_dls_unreachable_stays_inside_limits(arm):
    T = pose_to_transform([3.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    res = arm.inverse_kinematics(T, full_output=True)
    assert not res.converged and res.pos_err > 1.0
    assert np.all(res.q >= arm.joint_limits[:, 0]) and np.all(res.q <= arm.joint_limits[:, 1])


def test_step_standalone_follows_the_twist(arm):
    x0 = arm.get_state()
    u = np.array([0.1, -0.05, 0.02, 0.1, -0.2, 0.05])
    for _ in range(50):
        q = arm.step(u)
    x = arm.get_state()
    np.testing.assert_allclose(x, x0 + 50 * arm.dt * u, atol=1e-4)  # per-step IK tolerance 1e-4
    np.testing.assert_allclose(q, arm.q)
    np.testing.assert_allclose(arm.ee_pose(q), x, atol=1e-12)
    with pytest.raises(ValueError, match="input"):
        arm.step(np.zeros(5))
    with pytest.raises(NonFiniteError):
        arm.step(np.full(6, np.nan))


def test_step_clips_to_joint_limits(arm):
    u = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # straight out along +x: leaves the workspace
    lo, hi = arm.joint_limits.T
    for _ in range(60):
        q = arm.step(u)
        assert np.all(q >= lo) and np.all(q <= hi)
    assert arm.get_state()[0] < 1.0  # the arm's reach, not the integrated command


def test_set_state_and_joint_positions(arm, rng):
    q = np.clip(rng.uniform(-0.4, 0.4, 6), *arm.joint_limits.T)
    target = arm.ee_pose(q)
    arm.set_state(target)
    np.testing.assert_allclose(arm.get_state(), target, atol=1e-6)
    with pytest.raises(ValueError, match="not reachable"):
        arm.set_state([3.0, 0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="elbow"):
        arm.set_joint_positions([0, 0, 2.0, 0, 0, 0])


# ---------------------------------------------------------------- config
def test_from_config_standalone(cfg):
    arm = ArmRobot.from_config(cfg)
    np.testing.assert_array_equal(arm.joint_limits, np.array(cfg["joint_limits"]))
    with pytest.raises(ConfigError, match="joint_limits"):
        ArmRobot.from_config({k: v for k, v in cfg.items() if k != "joint_limits"})
    with pytest.raises(ConfigError, match="did you mean 'joint_names'"):
        ArmRobot.from_config({**cfg, "joint_name": ["a"]})
    with pytest.raises(ConfigError, match="dt"):
        ArmRobot.from_config({**cfg, "dt": -1})


def test_from_config_engine_limits_from_mjcf(cfg, engine_arm):
    engine = engine_arm.engine
    np.testing.assert_array_equal(engine_arm.joint_limits, np.array(cfg["joint_limits"]))
    for name, (lo, hi) in zip(engine_arm.joint_names, engine_arm.joint_limits, strict=True):
        assert engine.get_joint_limits(name) == (lo, hi)
    same = ArmRobot.from_config(cfg, engine=engine)  # consistent limits are accepted
    np.testing.assert_array_equal(same.joint_limits, engine_arm.joint_limits)
    bad = dict(cfg)
    bad["joint_limits"] = [[-1.0, 1.0]] * 6
    with pytest.raises(ConfigError, match="MJCF"):
        ArmRobot.from_config(bad, engine=engine)
    with pytest.raises(ConfigError, match="shoulder_pan"):
        ArmRobot.from_config({**cfg, "joint_names": ["nope", *cfg["joint_names"][1:]]}, engine=engine)


@pytest.mark.parametrize("config", [{}, {"dt": 0.002}, {"type": "ArmRobot", "num_dof": 6}])
def test_from_config_engine_without_geometry_is_the_shipped_arm(config):
    # With an engine and no geometry, the limits come from the MJCF and the rest from the shipped arm.
    shipped = ArmRobot()
    engine = MujocoEngine.for_plant(shipped)
    arm = ArmRobot.from_config(config, engine=engine)
    assert arm.engine is engine
    assert arm.joint_names == shipped.joint_names and arm.axes == shipped.axes
    np.testing.assert_array_equal(arm.joint_offsets, shipped.joint_offsets)
    for name, (lo, hi) in zip(arm.joint_names, arm.joint_limits, strict=True):
        assert engine.get_joint_limits(name) == (lo, hi)
    np.testing.assert_array_equal(arm.joint_limits, shipped.joint_limits)
    with pytest.raises(ConfigError, match="num_dof = 5 needs joint_limits"):
        ArmRobot.from_config({"num_dof": 5}, engine=engine)


# ---------------------------------------------------------------- engine mode
def test_engine_attach_reads_state(engine_arm):
    np.testing.assert_allclose(engine_arm.get_state(), engine_arm.ee_pose(np.zeros(6)), atol=1e-9)
    engine_arm.set_joint_positions([0.1, -0.2, 0.3, 0.2, -0.1, 0.4])
    np.testing.assert_allclose(engine_arm.get_state(), engine_arm.ee_pose(engine_arm.q), atol=1e-9)
    engine_arm.physics_engine(None)
    assert engine_arm.engine is None
    np.testing.assert_allclose(engine_arm.get_state(), engine_arm.ee_pose([0.1, -0.2, 0.3, 0.2, -0.1, 0.4]))


def test_engine_ik_reaches_target_without_moving_the_engine(engine_arm):
    engine = engine_arm.engine
    q_goal = np.array([0.2, -0.1, 0.25, 0.1, 0.15, -0.2])
    pose = engine_arm.ee_pose(q_goal)
    before = engine.get_state_vector()
    q = engine_arm.engine_ik(pose[:3], target_euler=pose[3:], max_iters=50, tol=1e-8)
    np.testing.assert_allclose(engine_arm.ee_pose(q), pose, atol=1e-6)
    np.testing.assert_array_equal(engine.get_state_vector(), before)
    q_pos = engine_arm.engine_ik(pose[:3], max_iters=50, tol=1e-8)
    np.testing.assert_allclose(engine_arm.forward_kinematics(q_pos)[0][:3, 3], pose[:3], atol=1e-6)
    with pytest.raises(RuntimeError, match="physics engine"):
        ArmRobot(**_kwargs()).engine_ik([0, 0, 0])


def test_engine_step_moves_through_the_actuators(engine_arm):
    x0 = engine_arm.get_state()
    u = np.array([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])
    for _ in range(250):  # 0.5 s at 5 cm/s
        q = engine_arm.step(u)
    assert engine_arm.engine.time == pytest.approx(250 * engine_arm.dt)
    x = engine_arm.get_state()
    # The twist is integrated from the measured pose, so the servo lag slows an open-loop
    # twist (a feedback controller closes that gap); the motion is along +y only.
    assert 0.005 < x[1] - x0[1] <= 0.025 + 1e-4
    np.testing.assert_allclose(x[[0, 2]], x0[[0, 2]], atol=1e-3)
    np.testing.assert_allclose(q, engine_arm.q)
    np.testing.assert_allclose(x, engine_arm.ee_pose(q), atol=1e-9)


def test_a_joint_clamp_in_the_step_is_counted_as_a_limit_contact():
    arm = ArmRobot(
        num_dof=1, dt=0.01, joint_limits=[[-0.1, 0.1]], joint_offsets=[[0, 0, 0]], rot_axes=["z"], ee_offset=[1, 0, 0]
    )
    arm.set_joint_positions([0.095])
    assert arm.limit_violation() == 0.0
    q = arm.step([0.0, 1.0, 0.0, 0.0, 0.0, 1.0])  # 1 rad/s about z: the IK target is past the 0.1 rad limit
    assert q[0] == 0.1 and arm.limit_violation() > 0.0
    arm.step([0.0, -0.5, 0.0, 0.0, 0.0, -0.5])  # back inside: no contact
    assert arm.limit_violation() == 0.0
