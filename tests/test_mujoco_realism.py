"""The MuJoCo loop is the real thing: a model file keeps its own options, saturation is counted, bounds default to
the model's ranges, and each built-in plant has a realistic variant its LQR copes with.

References: MuJoCo itself (the integrator it runs, ``d.actuator_force`` after a step with a command beyond the
``ctrlrange``, the contact count and where a falling body stops) and hand counts over the logged inputs.
"""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.controllers import LQR, TVLQR, LinearMPC, NonlinearMPC
from shinro_ctrl.crosscheck import crosscheck
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.planning import Trajectory
from shinro_ctrl.plants import CartPole, MjcfPlant
from shinro_ctrl.sim import RobotSim
from shinro_ctrl.sim.metrics import saturation_metrics

# A pendulum upright at q = 0 (rod along +z, hinge about y), 0.1 kg at 0.5 m, the file's own implicitfast
# integrator and a motor clamped to ±0.3 N m by MuJoCo.
PEND = """<mujoco model="user_pendulum">
  <option timestep="0.005" integrator="implicitfast"/>
  <worldbody>
    <body name="pole">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.01"/>
      <inertial pos="0 0 0.5" mass="0.1" diaginertia="1e-4 1e-4 1e-6"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.01" mass="0" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator><motor name="tau" joint="hinge" {limit}/></actuator>
</mujoco>"""
CTRL = 'ctrlrange="-0.3 0.3"'
FORCE = 'forcerange="-0.3 0.3"'

# A puck on a vertical slider 0.5 m above a floor, contacts on (the file's default).
PUCK = """<mujoco model="puck">
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="puck" pos="0 0 0.5">
      <joint name="lift" type="slide" axis="0 0 1"/>
      <geom type="box" size="0.05 0.05 0.05" mass="0.2"/>
    </body>
  </worldbody>
  <actuator><motor name="push" joint="lift"/></actuator>
</mujoco>"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("realism")
    out = {}
    for name, text in (("ctrl", PEND.format(limit=CTRL)), ("force", PEND.format(limit=FORCE)), ("puck", PUCK)):
        out[name] = folder / f"{name}.xml"
        out[name].write_text(text)
    return out


@pytest.fixture(scope="module")
def pendulum(files):
    return MjcfPlant(files["ctrl"])


def _scenario(path, *, controller: dict, x0: float = 0.2, duration: float = 1.0) -> dict:
    return {
        "plant": {"type": "MjcfPlant", "model": str(path)},
        "engine": {"type": "mujoco"},
        "controller": {"type": "LQR", "Q": [10, 1], "R": [0.1], **controller},
        "sim": {"duration": duration, "initial_state": [x0, 0.0]},
    }


# ------------------------------------------------------------ the file's own options
def test_a_model_file_keeps_its_integrator_and_clamps_in_the_loop(pendulum):
    loop = MujocoEngine.for_plant(pendulum)
    assert loop.variant == "realistic" and loop.integrator == "mjINT_IMPLICITFAST" and not loop.explicit_damping
    assert loop.model.opt.timestep == pytest.approx(0.005)
    twin = MujocoEngine.for_plant(pendulum, model="matched")  # what crosscheck compares
    assert twin.variant == "matched" and twin.integrator == "mjINT_EULER" and twin.explicit_damping
    # a command of 5 N m: MuJoCo delivers the ctrlrange's 0.3 in the loop, all of it in the idealized twin
    for engine, delivered in ((loop, 0.3), (twin, 5.0)):
        engine.set_ctrl([5.0])
        engine.step()
        assert engine.data.actuator_force[0] == pytest.approx(delivered, rel=1e-12)
    # crosscheck stays meaningful: it builds its own matched copy, whatever the loop runs
    result = crosscheck(pendulum)
    assert result.mujoco_max_rel_error < 1e-5


def test_a_model_file_keeps_its_contacts(files):
    plant = MjcfPlant(files["puck"])
    loop, twin = MujocoEngine.for_plant(plant), MujocoEngine.for_plant(plant, model="matched")
    for engine in (loop, twin):
        for _ in range(400):  # 0.8 s: a free fall of 0.45 m takes 0.3 s
            engine.step()
    # the puck (half height 0.05 m, 0.5 m up) rests on the floor in the loop and falls through it in the twin
    assert loop.data.ncon > 0 and loop.get_joint_qpos("lift") == pytest.approx(-0.45, abs=2e-3)
    assert twin.data.ncon == 0 and twin.get_joint_qpos("lift") < -1.0


# ------------------------------------------------------------ saturation, counted
def test_ctrlrange_clamps_and_saturation_fraction_equals_a_hand_count(files):
    # the controller may ask for up to ±10 N m; the model's ctrlrange clamps at ±0.3
    sim = RobotSim.from_config(_scenario(files["ctrl"], controller={"u_min": [-10.0], "u_max": [10.0]}))
    res = sim.run(progress=False)
    u = res.u[:, 0]
    assert np.abs(u).max() > 0.3  # it asked for more than the motor gives
    at_lo, at_hi = u <= -0.3 * (1 - 1e-6), u >= 0.3 * (1 - 1e-6)
    m = res.metrics
    assert m["saturation_fraction"] > 0
    assert m["saturation_fraction"] == pytest.approx(np.count_nonzero(at_lo | at_hi) / u.size, rel=1e-12)
    assert m["time_at_min_tau"] == pytest.approx(np.count_nonzero(at_lo) * 0.005, rel=1e-9)
    assert m["time_at_max_tau"] == pytest.approx(np.count_nonzero(at_hi) * 0.005, rel=1e-9)
    assert m["constraint_violations"] == 0  # within the controller's own bounds: saturated, not violated
    assert m["stable"] and abs(res.x[-1, 0]) < 0.01  # and the clamped loop still balances


def test_forcerange_clamps_are_read_from_the_actuator_force(files):
    # no ctrlrange, no controller bounds: only MuJoCo's forcerange limits the torque, and the run counts it
    sim = RobotSim.from_config(_scenario(files["force"], controller={}))
    assert sim.controller.u_min is None or not np.isfinite(sim.controller.u_min).any()
    res = sim.run(progress=False)
    u = res.u[:, 0]
    clamped = np.abs(u) >= 0.3  # gain 1: the actuator force is the command, cut at ±0.3
    assert clamped.any()
    assert res.metrics["saturation_fraction"] == pytest.approx(np.count_nonzero(clamped) / u.size, rel=1e-12)
    assert res.metrics["time_at_max_tau"] + res.metrics["time_at_min_tau"] == pytest.approx(
        np.count_nonzero(clamped) * 0.005, rel=1e-9
    )


def test_saturation_metrics_by_hand_and_none_without_bounds():
    t = np.arange(6) * 0.1
    u = np.array([[1.0, 0.0], [2.0, -1.0], [2.0, 0.5], [0.0, -1.0], [-3.0, 0.0]])
    m = saturation_metrics(t, u, np.array([-3.0, -np.inf]), np.array([2.0, np.inf]), ("a", "b"))
    assert m == pytest.approx({"saturation_fraction": 3 / 5, "time_at_min_a": 0.1, "time_at_max_a": 0.2})
    none = saturation_metrics(t, u, None, np.full(2, np.inf), ("a", "b"))
    assert none == {"saturation_fraction": None}  # no bounds: None, never NaN
    res = RobotSim.from_config("pendulum_lqr").run(duration=0.1, progress=False)  # standalone, unbounded
    assert res.metrics["saturation_fraction"] is None


# ------------------------------------------------------------ bounds from the model's ranges
def test_from_plant_takes_its_input_bounds_from_the_ctrlrange(pendulum):
    lo, hi = pendulum.input_bounds()
    np.testing.assert_array_equal(lo, [-0.3])
    np.testing.assert_array_equal(hi, [0.3])
    lqr = LQR.from_plant(pendulum, [10, 1], [0.1])
    mpc = LinearMPC.from_plant(pendulum, [10, 1], [0.1], horizon=5)
    nmpc = NonlinearMPC.from_plant(pendulum, [10, 1], [0.1], horizon=3)
    hold = Trajectory(t=[0.0, 0.05], x=np.zeros((2, 2)), u=np.zeros((2, 1)), xdot=np.zeros((2, 2)))
    tvlqr = TVLQR.from_trajectory(pendulum, hold, [10, 1], [0.1])
    for ctrl in (lqr, mpc, nmpc, tvlqr):
        np.testing.assert_array_equal(ctrl.u_min, [-0.3])
        np.testing.assert_array_equal(ctrl.u_max, [0.3])
    assert np.abs(lqr(np.array([0.5, 0.0]))).max() == pytest.approx(0.3)  # saturates at the motor's range
    wide = LQR.from_plant(pendulum, [10, 1], [0.1], u_min=-2.0)  # a side the user gives is kept
    np.testing.assert_array_equal(wide.u_min, [-2.0])
    np.testing.assert_array_equal(wide.u_max, [0.3])
    assert not np.isfinite(LQR.from_plant(CartPole(), [10, 1, 100, 1], [0.1]).u_max).any()  # built-ins: none


def test_the_mpc_controllers_take_their_default_state_bounds_from_the_joint_ranges():
    arm = MjcfPlant("panda_like_arm.xml")
    lo, hi = arm.state_ranges()
    m = MujocoEngine.for_plant(arm).model  # the reference: MuJoCo's own joint ranges
    np.testing.assert_array_equal(lo[:7], m.jnt_range[:7, 0])
    np.testing.assert_array_equal(hi[:7], m.jnt_range[:7, 1])
    assert not np.isfinite(lo[7:]).any() and not np.isfinite(hi[7:]).any()  # velocities: none
    Q, R = np.ones(14), np.ones(7)
    mpc = LinearMPC.from_plant(arm, Q, R, horizon=3)
    nmpc = NonlinearMPC.from_plant(arm, Q, R, horizon=2, codegen=False)  # no compile: the bounds are the point
    for ctrl in (mpc, nmpc):
        np.testing.assert_array_equal(ctrl.x_min, lo)
        np.testing.assert_array_equal(ctrl.x_max, hi)
    mine = LinearMPC.from_plant(arm, Q, R, horizon=3, x_max=np.full(14, 5.0))  # a side the user gives is kept
    np.testing.assert_array_equal(mine.x_max, np.full(14, 5.0))
    np.testing.assert_array_equal(mine.x_min, lo)
    pend = LinearMPC.from_plant(CartPole(), [10, 1, 100, 1], [0.1], horizon=3)  # built-ins declare none
    assert not np.isfinite(pend.x_min).any() and not np.isfinite(pend.x_max).any()


# ------------------------------------------------------------ the realistic variants
# plant: (controller table, initial state, duration [s], nominal mass [kg] or None, the states that must come back)
REALISTIC = {
    "InvertedPendulum": ({"Q": [10, 1], "R": [0.1]}, [0.2, 0.0], 1.0, 0.1, ["theta"]),
    "CartPole": ({"Q": [10, 1, 100, 1], "R": [0.1]}, [0.0, 0.0, 0.15, 0.0], 1.5, 0.6, ["theta"]),
    "DoublePendulum": (
        {"Q": [100, 100, 1, 1], "R": [1, 1], "x0": [np.pi, np.pi, 0, 0], "u0": [0, 0]},
        [np.pi + 0.03, np.pi - 0.03, 0, 0],
        0.5,
        0.2,
        ["theta_1", "theta_2"],
    ),
    "Quadrotor": (
        {"Q": [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], "R": [0.5, 200, 200, 200]},
        [0.2, -0.2, 0.2, 0.1, -0.1, 0.1, 0, 0, 0, 0, 0, 0],
        1.0,
        0.5,
        ["z", "roll", "pitch"],
    ),
    "HolonomicMobileRobot": ({"Q": [400, 400, 50], "R": [1, 1, 1]}, [0.1, -0.1, 0.1], 1.0, None, ["x", "y", "theta"]),
}


@pytest.mark.parametrize("plant", list(REALISTIC))
def test_each_realistic_variant_loads_and_its_lqr_keeps_the_plant_up(plant):
    ctrl, x0, duration, mass, up = REALISTIC[plant]
    doc = {
        "plant": {"type": plant},
        "engine": {"type": "mujoco", "model": "realistic"},
        "controller": {"type": "LQR", **ctrl},
        "sim": {"duration": duration, "initial_state": x0},
    }
    sim = RobotSim.from_config(doc)
    m = sim.engine.model
    assert sim.engine.variant == "realistic" and sim.engine.integrator == "mjINT_IMPLICITFAST"
    assert sim.engine.source.endswith("_realistic.xml")
    if mass is not None:  # the nominal mass, distributed over real geoms (no point mass)
        assert m.body_mass.sum() == pytest.approx(mass, rel=1e-9)
        moving = m.body_mass > 0
        assert (m.body_inertia[moving].max(axis=1) > 1e-5).all()
        assert m.actuator_ctrllimited.all()  # motor limits
    res = sim.run(progress=False)
    idx = [sim.plant.state_names.index(s) for s in up]
    dev = np.abs(res.x[:, idx] - sim.operating_point[idx]).max(axis=1)
    assert np.all(np.isfinite(res.x)) and dev[-1] < 0.3 * dev[0]  # kept up, and on its way back
    assert dev.max() < 2.0 * dev[0]


def test_the_realistic_arm_holds_its_pose_under_friction_gravity_and_torque_limits():
    doc = {
        "plant": {"type": "ArmRobot"},
        "engine": {"type": "mujoco", "model": "realistic"},
        "controller": {"type": "IKQP"},
        "sim": {"duration": 0.1},
    }
    sim = RobotSim.from_config(doc)
    m = sim.engine.model
    assert sim.engine.integrator == "mjINT_IMPLICITFAST" and m.actuator_forcelimited.all()
    assert (m.dof_frictionloss > 0).all() and not m.body_gravcomp.any() and m.ngeom > 1
    res = sim.run(progress=False)
    assert np.abs(res.x[:, :3] - res.x[0, :3]).max() < 5e-3  # the end effector stays within 5 mm


# ------------------------------------------------------------ choosing the model, bad input
def test_the_scenario_key_chooses_the_model_and_refuses_what_does_not_fit():
    base = {
        "plant": {"type": "CartPole"},
        "engine": {"type": "mujoco"},
        "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]},
    }
    assert RobotSim.from_config(base).engine.variant == "matched"  # the built-ins' default: the exact twin
    with pytest.raises(ConfigError, match=r"\[engine\].*'realistc'.*did you mean 'realistic'"):
        RobotSim.from_config({**base, "engine": {"type": "mujoco", "model": "realistc"}})
    heavy = {
        **base,
        "plant": {"type": "CartPole", "pole_mass": 0.3},
        "engine": {"type": "mujoco", "model": "realistic"},
    }
    with pytest.raises(ConfigError, match=r"\[engine\] model: .*pole_mass = 0.3 \(default 0.1\).*\"matched\""):
        RobotSim.from_config(heavy)
    with pytest.raises(InvalidArgument, match="built for the default parameters"):
        MujocoEngine.for_plant(CartPole(pole_length=0.7), model="realistic")
