"""MujocoEngine: matched models, named access, faults, poses and the plants' engine mode."""

from __future__ import annotations

import ctypes
import dataclasses
import math
import re

import mujoco
import numpy as np
import pytest

from shinro_ctrl.engine import TINY_INERTIA, MujocoEngine
from shinro_ctrl.errors import InvalidArgument, NonFiniteError, SimulationDiverged, UnknownName
from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum
from shinro_ctrl.resources import asset_path, shipped_asset

from .conftest import PENDULUM_FAMILY

FREE_BODY_XML = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="base" pos="0 0 0.3">
      <freejoint name="root"/>
      <inertial pos="0 0 0" mass="2" diaginertia="0.1 0.1 0.1"/>
      <site name="tip" pos="0.2 0 0"/>
      <body name="arm">
        <joint name="elbow" type="hinge" axis="0 0 1" range="-1 1.5" limited="true"/>
        <inertial pos="0.1 0 0" mass="0.5" diaginertia="1e-3 1e-3 1e-3"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor name="elbow_motor" joint="elbow"/></actuator>
</mujoco>
"""


def attached(plant):
    engine = MujocoEngine.for_plant(plant)
    plant.physics_engine(engine)
    return engine


# ---------------------------------------------------------------- trajectories
TRAJECTORY_CASES = [
    pytest.param(CartPole, [0.0, 0.0, 0.05, 0.0], [0.2], id="cartpole"),
    pytest.param(InvertedPendulum, [0.05, 0.0], [0.01], id="pendulum"),
    pytest.param(DoublePendulum, [0.05, -0.03, 0.0, 0.0], [0.01, -0.005], id="double"),
]


@pytest.mark.parametrize(("cls", "x0", "u"), TRAJECTORY_CASES)
def test_standalone_and_mujoco_trajectories_agree(cls, x0, u):
    standalone, simulated = cls(dt=0.001), cls(dt=0.001)
    engine = attached(simulated)
    standalone.set_state(x0)
    simulated.set_state(x0)
    errors = []
    for _ in range(400):  # 0.4 s
        errors.append(np.abs(standalone.step(u) - simulated.step(u)).max())
    assert max(errors) < 5e-3
    assert engine.time == pytest.approx(0.4)
    # The motion is not trivial: the state left x0 by far more than the tolerance.
    assert np.abs(simulated.get_state() - np.asarray(x0)).max() > 0.02


def test_substeps_keep_the_plant_step():
    plant = CartPole(dt=0.01)
    engine = MujocoEngine.for_plant(plant, substeps=4)
    assert engine.model.opt.timestep == pytest.approx(0.0025)
    assert engine.dt == pytest.approx(0.01)
    plant.physics_engine(engine)
    plant.set_state([0.0, 0.0, 0.05, 0.0])
    for _ in range(10):
        plant.step(0.0)
    assert engine.time == pytest.approx(0.1)
    with pytest.raises(ValueError, match="substeps"):
        MujocoEngine.for_plant(plant, substeps=0)


# ------------------------------------------------------------------ for_plant
def test_for_plant_honours_parameters():
    plant = CartPole(cart_mass=1.3, pole_mass=0.27, pole_length=0.8, damping=0.05, gravity=3.7, dt=0.004)
    m = MujocoEngine.for_plant(plant).model
    cart, pole = m.body("cart").id, m.body("pole").id
    np.testing.assert_allclose(m.body_mass[[cart, pole]], [1.3, 0.27])
    np.testing.assert_allclose(m.body_ipos[pole], [0.0, 0.0, 0.8])
    np.testing.assert_allclose(m.body_inertia[pole], [TINY_INERTIA] * 3)
    assert m.dof_damping[m.joint("hinge").dofadr[0]] == pytest.approx(0.05)
    assert m.dof_damping[m.joint("slider").dofadr[0]] == 0.0
    assert m.opt.timestep == pytest.approx(0.004)
    np.testing.assert_allclose(m.opt.gravity, [0.0, 0.0, -3.7])
    np.testing.assert_allclose(m.geom("pole_rod").size[1], 0.4)  # capsule half-length = l / 2
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    assert m.jnt_limited[m.joint("slider").id] == 0


def test_for_plant_moves_child_bodies():
    m = MujocoEngine.for_plant(DoublePendulum(mass_top=0.4, length_top=0.9, length_bottom=0.3)).model
    np.testing.assert_allclose(m.body_pos[m.body("link2").id], [0.0, 0.0, -0.9])
    np.testing.assert_allclose(m.body_ipos[m.body("link2").id], [0.0, 0.0, -0.3])
    assert m.body_mass[m.body("link1").id] == pytest.approx(0.4)


@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_mass_matrix_is_the_point_mass_one(cls):
    """Visual geoms carry no mass: the total mass is the plant's point masses."""
    plant = cls()
    m = MujocoEngine.for_plant(plant).model
    masses = [v for k, v in plant.params().items() if "mass" in k]
    assert m.body_mass.sum() == pytest.approx(sum(masses))
    assert (m.geom_contype == 0).all() and (m.geom_conaffinity == 0).all()


@pytest.mark.parametrize("field", ["inertials", "body_pos", "joint_damping", "geom_fromto"])
def test_patch_with_unknown_name_lists_valid_names(field, monkeypatch):
    plant = CartPole()
    value = {"inertials": (1.0, (0, 0, 0)), "body_pos": (0, 0, 0), "joint_damping": 0.1}.get(field, (0,) * 6)
    bad = dataclasses.replace(plant.mjcf_patch(), **{field: {"nope": value}})
    monkeypatch.setattr(plant, "mjcf_patch", lambda: bad)
    with pytest.raises(KeyError, match="nope") as info:
        MujocoEngine.for_plant(plant)
    valid = {"inertials": "cart", "body_pos": "pole", "joint_damping": "slider", "geom_fromto": "pole_rod"}[field]
    assert valid in str(info.value)


def test_for_plant_accepts_another_model():
    plant = InvertedPendulum()
    engine = MujocoEngine.for_plant(plant, model=asset_path("inverted_pendulum.xml"))
    assert engine.joint_names == ("hinge",)


# --------------------------------------------------------------------- loading
def test_missing_file_names_the_path(tmp_path):
    missing = tmp_path / "nowhere" / "robot.xml"
    with pytest.raises(FileNotFoundError, match=re.escape(str(missing))):
        MujocoEngine(missing)


def test_bad_model_arguments_raise_our_errors(tmp_path):
    for empty in ("", "   "):
        with pytest.raises(InvalidArgument, match=r"path is empty.*shipped assets: .*cartpole\.xml"):
            MujocoEngine(empty)
    with pytest.raises(InvalidArgument, match=r"must be an MJCF file path.*got int 3"):
        MujocoEngine(3)
    with pytest.raises(FileNotFoundError, match=r"is a directory, not an MJCF file.*shipped assets"):
        MujocoEngine(tmp_path)
    with pytest.raises(FileNotFoundError, match="is a directory"):
        MujocoEngine(str(tmp_path))


def test_for_plant_loads_the_shipped_asset_not_a_file_in_the_cwd(tmp_path, monkeypatch):
    # A user's cartpole.xml in the current directory must not replace the plant's own model.
    (tmp_path / "cartpole.xml").write_text("<mujoco><worldbody><body name='bogus'/></worldbody></mujoco>")
    monkeypatch.chdir(tmp_path)
    engine = MujocoEngine.for_plant(CartPole())
    assert engine.joint_names == ("slider", "hinge")
    assert engine.source == str(shipped_asset("cartpole.xml")) and "bogus" not in engine.body_names
    assert tmp_path not in shipped_asset("cartpole.xml").parents
    # An explicit model= still means "this path first": the user's file is taken (and fails the patch).
    with pytest.raises(KeyError, match="unknown body 'cart'"):
        MujocoEngine.for_plant(CartPole(), model="cartpole.xml")
    assert MujocoEngine("cartpole.xml").body_names == ("world", "bogus")


def test_invalid_xml_raises_value_error_with_mujoco_message(tmp_path):
    with pytest.raises(ValueError, match="invalid keyword"):
        MujocoEngine("<mujoco><worldbody><body><joint type='spiral'/></body></worldbody></mujoco>")
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><bdy/></worldbody></mujoco>")
    with pytest.raises(ValueError, match="unrecognized element"):
        MujocoEngine(bad)


def test_engine_from_asset_name_and_xml_string():
    engine = MujocoEngine("cartpole.xml")
    assert engine.joint_names == ("slider", "hinge")
    assert engine.actuator_names == ("slider",)
    assert engine.body_names == ("world", "cart", "pole")
    engine = MujocoEngine(FREE_BODY_XML)
    assert engine.joint_names == ("root", "elbow")
    assert engine.has_free_joint


# ---------------------------------------------------------------- named access
@pytest.mark.parametrize("cls", PENDULUM_FAMILY, ids=lambda c: c.__name__)
def test_unknown_names_raise_key_error_listing_names(cls):
    engine = MujocoEngine.for_plant(cls())
    joint_calls = [
        lambda: engine.get_joint_qpos("nope"),
        lambda: engine.get_joint_vel("nope"),
        lambda: engine.set_joint_qpos("nope", 0.0),
        lambda: engine.set_joint_vel("nope", 0.0),
        lambda: engine.get_joint_limits("nope"),
    ]
    for call in joint_calls:
        with pytest.raises(KeyError) as info:
            call()
        assert all(name in str(info.value) for name in engine.joint_names)
    with pytest.raises(KeyError) as info:
        engine.set_joint_ctrl("nope", 0.0)
    assert all(name in str(info.value) for name in engine.actuator_names)
    for call in (lambda: engine.get_body_pose("nope"), lambda: engine.get_body_jacobian("nope")):
        with pytest.raises(KeyError) as info:
            call()
        assert all(name in str(info.value) for name in engine.body_names)


def test_near_miss_suggests_the_name():
    engine = MujocoEngine.for_plant(DoublePendulum())
    with pytest.raises(KeyError, match="did you mean 'hinge_1'"):
        engine.get_joint_qpos("hinge1")


def test_joint_access_roundtrip_and_limits():
    engine = MujocoEngine(FREE_BODY_XML)
    engine.set_joint_qpos("elbow", 0.7)
    engine.set_joint_vel("elbow", -1.5)
    assert engine.get_joint_qpos("elbow") == 0.7 and isinstance(engine.get_joint_qpos("elbow"), float)
    assert engine.get_joint_vel("elbow") == -1.5
    assert engine.get_joint_limits("elbow") == (-1.0, 1.5)
    assert engine.get_joint_limits("root") == (-math.inf, math.inf)
    assert engine.get_joint_qpos("root").shape == (7,)
    assert engine.get_joint_vel("root").shape == (6,)
    with pytest.raises(ValueError, match="expected shape"):
        engine.set_joint_qpos("root", [0.0, 0.0, 0.0])


def test_bad_control_and_joint_values_raise_invalid_argument():
    engine = MujocoEngine.for_plant(CartPole())
    engine.set_joint_ctrl("slider", 0.5)
    for bad in ([1, 2], "a", None, 1j):
        with pytest.raises(InvalidArgument, match="control of actuator 'slider' must be one real number"):
            engine.set_joint_ctrl("slider", bad)
        with pytest.raises(InvalidArgument, match="joint 'hinge' position must be one real number"):
            engine.set_joint_qpos("hinge", bad)
        with pytest.raises(InvalidArgument, match="joint 'slider' velocity must be one real number"):
            engine.set_joint_vel("slider", bad)
    assert engine.data.ctrl[0] == 0.5
    for call in (
        lambda: engine.set_joint_ctrl(["slider"], 0.0),
        lambda: engine.get_joint_qpos(["hinge"]),
        lambda: engine.set_joint_vel({}, 0.0),
    ):
        with pytest.raises(UnknownName, match="slider"):
            call()
    free = MujocoEngine(FREE_BODY_XML)
    with pytest.raises(InvalidArgument, match="free joint 'root' qpos: expected 7 real numbers"):
        free.set_joint_qpos("root", "abcdefg")


def test_actuator_reachable_by_joint_name():
    engine = MujocoEngine.for_plant(DoublePendulum())
    engine.set_joint_ctrl("hinge_2", 0.25)
    engine.set_joint_ctrl("torque_1", -0.5)
    np.testing.assert_array_equal(engine.data.ctrl, [-0.5, 0.25])


# ---------------------------------------------------------------------- faults
def test_non_finite_control_is_rejected_before_mujoco():
    plant = CartPole()
    engine = attached(plant)
    engine.set_joint_ctrl("slider", 1.0)
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(NonFiniteError):
            engine.set_joint_ctrl("slider", bad)
    assert engine.data.ctrl[0] == 1.0
    with pytest.raises(NonFiniteError):
        engine.set_ctrl([math.nan])
    with pytest.raises(NonFiniteError):
        plant.step(math.nan)
    with pytest.raises(NonFiniteError):
        engine.set_joint_qpos("hinge", math.nan)
    with pytest.raises(NonFiniteError):
        engine.set_joint_vel("slider", math.inf)
    assert engine.data.ctrl[0] == 1.0 and np.isfinite(engine.data.qpos).all()


def test_huge_control_raises_simulation_diverged():
    plant = CartPole()
    attached(plant)
    plant.step(0.0)
    with pytest.raises(SimulationDiverged, match=r"mjWARN_BADCTRL.*'slider'") as info:
        plant.step(1e30)
    assert "t = 0.01" in str(info.value)


def _flush_c_stdio() -> None:
    """Flush C's stdio buffers (MuJoCo prints with printf; a pipe is block-buffered)."""
    ctypes.CDLL(None).fflush(None)


def test_divergence_quotes_mujoco_and_prints_nothing(tmp_path, monkeypatch, capfd):
    # MuJoCo's C warning goes into the exception, not to stdout/stderr, and no MUJOCO_LOG.TXT is written.
    monkeypatch.chdir(tmp_path)
    capfd.readouterr()
    plant = CartPole()
    attached(plant)
    with pytest.raises(SimulationDiverged) as info:
        plant.step(1e30)
    text = str(info.value)
    assert "mjWARN_BADCTRL" in text
    assert 'MuJoCo: "Nan, Inf or huge value in CTRL at ACTUATOR 0' in text
    engine = MujocoEngine.for_plant(CartPole(cart_mass=1e-6, pole_mass=1e-6))
    engine.set_joint_ctrl("slider", 1e6)
    with pytest.raises(SimulationDiverged, match=r"mjWARN_BADQACC.*MuJoCo: \"Nan, Inf or huge value in QACC at DOF 0"):
        engine.step()
    _flush_c_stdio()
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    assert list(tmp_path.iterdir()) == []


def test_bad_acceleration_raises_and_engine_recovers():
    plant = CartPole(cart_mass=1e-6, pole_mass=1e-6)
    engine = attached(plant)
    with pytest.raises(SimulationDiverged, match=r"mjWARN_BADQACC.*reset the state"):
        plant.step(1e6)  # 1e12 m/s², beyond MuJoCo's 1e10 bound
    # The warning is reported once; a sane input steps normally again.
    engine.reset()
    plant.step(0.0)
    assert engine.time == pytest.approx(plant.dt)


def test_huge_velocity_raises_simulation_diverged():
    engine = MujocoEngine.for_plant(InvertedPendulum())
    engine.step()
    engine.set_joint_vel("hinge", 1e12)
    with pytest.raises(SimulationDiverged, match=r"mjWARN_BADQVEL.*joint 'hinge'"):
        engine.step()
    engine.step()  # MuJoCo reset the state; no stale warning is re-reported


# ----------------------------------------------------------- plant engine mode
def test_double_pendulum_relative_angle_roundtrip(rng):
    plant = DoublePendulum()
    engine = attached(plant)
    for _ in range(5):
        x = rng.uniform(-2.0, 2.0, 4)
        plant.set_state(x)
        assert engine.get_joint_qpos("hinge_1") == pytest.approx(x[0])
        assert engine.get_joint_qpos("hinge_2") == pytest.approx(x[1] - x[0])
        assert engine.get_joint_vel("hinge_2") == pytest.approx(x[3] - x[2])
        np.testing.assert_allclose(plant.get_state(), x, atol=1e-14)
    # Writing the engine directly is seen by the plant in absolute angles.
    engine.set_joint_qpos("hinge_1", 0.3)
    engine.set_joint_qpos("hinge_2", -0.1)
    np.testing.assert_allclose(plant.get_state()[:2], [0.3, 0.2])


def test_attach_reads_the_engine_state():
    plant = CartPole()
    engine = MujocoEngine.for_plant(plant)
    engine.set_state_vector([0.1, 0.2, 0.3, 0.4])  # [x, theta, x_dot, theta_dot]
    plant.physics_engine(engine)
    np.testing.assert_allclose(plant.get_state(), [0.1, 0.3, 0.2, 0.4])


# ------------------------------------------------------------ poses, Jacobians
def test_body_pose_follows_the_state_without_forward():
    l1, l2 = 0.7, 0.4
    plant = DoublePendulum(length_top=l1, length_bottom=l2)
    engine = attached(plant)
    th1, th2 = 0.3, -0.5
    engine.set_joint_qpos("hinge_1", th1)  # no forward(): poses refresh themselves
    engine.set_joint_qpos("hinge_2", th2 - th1)
    pos, euler = engine.get_body_pose("link2")
    np.testing.assert_allclose(pos, [-l1 * math.sin(th1), 0.0, -l1 * math.cos(th1)], atol=1e-12)
    np.testing.assert_allclose(euler, [0.0, th2, 0.0], atol=1e-12)
    plant.step([0.0, 0.0])  # after a step the pose is the new state's, not the previous one
    th1 = engine.get_joint_qpos("hinge_1")
    pos, _ = engine.get_body_pose("link2")
    np.testing.assert_allclose(pos, [-l1 * math.sin(th1), 0.0, -l1 * math.cos(th1)], atol=1e-12)


def test_body_jacobian_matches_finite_differences(rng):
    engine = MujocoEngine.for_plant(DoublePendulum(length_top=0.6, length_bottom=0.9))
    engine.data.qpos[:] = rng.uniform(-1, 1, 2)
    engine.forward()
    q0 = engine.data.qpos.copy()
    J = engine.get_body_jacobian("link2")
    assert J.shape == (6, 2)
    eps = 1e-7
    for k in range(2):
        for sign in (1, -1):
            engine.data.qpos[:] = q0
            engine.set_joint_qpos(engine.joint_names[k], q0[k] + sign * eps)
            if sign == 1:
                plus = engine.get_body_pose("link2")[0]
            else:
                minus = engine.get_body_pose("link2")[0]
        np.testing.assert_allclose(J[:3, k], (plus - minus) / (2 * eps), atol=1e-7)
    np.testing.assert_allclose(J[3:], [[0, 0], [1, 1], [0, 0]], atol=1e-12)  # both hinges about +y


def test_free_base_and_sites():
    engine = MujocoEngine(FREE_BODY_XML)
    engine.set_joint_vel("root", np.ones(6))
    engine.pin_free_base(1.0, -2.0, yaw=0.5)
    qpos, qvel = engine.get_free_joint("root")
    np.testing.assert_allclose(qpos, [1.0, -2.0, 0.3, math.cos(0.25), 0.0, 0.0, math.sin(0.25)])
    np.testing.assert_array_equal(qvel, np.zeros(6))
    pos, euler = engine.get_body_pose("base")
    np.testing.assert_allclose(pos, [1.0, -2.0, 0.3], atol=1e-12)
    np.testing.assert_allclose(euler, [0.0, 0.0, 0.5], atol=1e-12)
    site_pos, site_euler = engine.get_site_pose("tip")
    np.testing.assert_allclose(site_pos, [1.0 + 0.2 * math.cos(0.5), -2.0 + 0.2 * math.sin(0.5), 0.3], atol=1e-12)
    np.testing.assert_allclose(site_euler, [0.0, 0.0, 0.5], atol=1e-12)
    J = engine.get_site_jacobian("tip")
    np.testing.assert_allclose(J[:3, :3], np.eye(3), atol=1e-12)  # free translation moves the site 1:1
    engine.set_free_joint("root", [0, 0, 1, 1, 0, 0, 0], np.zeros(6))
    assert engine.get_body_pose("base")[0][2] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="not a free joint"):
        engine.get_free_joint("elbow")
    with pytest.raises(ValueError, match="no free joint"):
        MujocoEngine.for_plant(CartPole()).pin_free_base(0.0, 0.0)


def test_reset_restores_initial_state():
    engine = MujocoEngine.for_plant(InvertedPendulum())
    engine.set_joint_qpos("hinge", 0.2)
    engine.step()
    engine.reset()
    assert engine.time == 0.0 and engine.get_joint_qpos("hinge") == 0.0
