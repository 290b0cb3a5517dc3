"""MjcfPlant: exact dynamics built from a model file, against MuJoCo itself.

References (all independent of the CasADi expression under test):

* ``qacc`` of ``mujoco.mj_forward`` on the same model (contacts and limits
  off): the dynamics, to 1e-9 relative;
* complex-step Jacobians of the same algorithms evaluated on complex numbers
  (``RigidBodyTree.xdot_numpy``, no CasADi involved): the exact Jacobians, to
  1e-12 relative;
* MuJoCo's ``mjd_transitionFD`` of one Euler step with explicit damping,
  converted to continuous time: the exact Jacobians, to 1e-5 relative;
* the hand-written :class:`DoublePendulum` under its documented state map.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.crosscheck import crosscheck, mujoco_continuous_jacobians
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.errors import InvalidArgument, UnknownName
from shinro_ctrl.linearization import complex_step_jacobians
from shinro_ctrl.plants import DoublePendulum, MjcfPlant, plant_class, plant_from_name
from shinro_ctrl.resources import asset_path, config_path

# Hinge and slide joints, full inertia tensors (rotated principal axes and fullinertia), off-axis centres of
# mass, damping, armature, a spring with a reference, a body with two joints, a welded body between joints, a
# branch, gravity off the z axis, non-unit (and negative) gears, motor / position / velocity / general actuators.
TREE_XML = """
<mujoco model="tree_test">
  <compiler angle="radian"/>
  <option timestep="0.002" gravity="0.3 -0.2 -9.81">
    <flag contact="disable" eulerdamp="disable"/>
  </option>
  <worldbody>
    <body name="base" pos="0.1 0.05 0.3" quat="0.9 0.1 0.3 -0.2">
      <joint name="rail" type="slide" axis="1 0.2 0" damping="0.7" armature="0.05"/>
      <inertial pos="0.02 -0.01 0.03" quat="0.8 0.2 -0.1 0.4" mass="1.3" diaginertia="0.011 0.017 0.021"/>
      <body name="upper" pos="0.05 0.1 -0.02" quat="0.7 -0.3 0.2 0.1">
        <joint name="shoulder" type="hinge" axis="0.3 1 0.1" pos="0.01 0.02 -0.03" damping="0.2" armature="0.01"
               ref="0.2" stiffness="0.5" springref="0.1"/>
        <joint name="twist" type="hinge" axis="0 0 1" pos="0.0 0.0 0.05" damping="0.05"/>
        <inertial pos="0.03 0.04 -0.2" quat="0.9 -0.2 0.3 0.1" mass="0.8" diaginertia="0.006 0.009 0.004"/>
        <body name="fixed_box" pos="0.02 0 -0.3" quat="0.5 0.5 0.5 0.5">
          <inertial pos="0.01 0.0 0.02" mass="0.2" fullinertia="0.002 0.003 0.0025 0.0003 -0.0002 0.0001"/>
          <body name="fore" pos="0 0.05 -0.1">
            <joint name="elbow" type="hinge" axis="1 0 0.2" damping="0.1" armature="0.02"/>
            <inertial pos="0.0 0.03 -0.15" quat="1 0.2 0 0.1" mass="0.5" diaginertia="0.003 0.004 0.0015"/>
            <body name="slider" pos="0 0 -0.3">
              <joint name="extend" type="slide" axis="0.1 0.3 -1" damping="1.5" armature="0.1"/>
              <inertial pos="0.01 0.02 -0.05" mass="0.25" diaginertia="0.0005 0.0007 0.0004"/>
            </body>
          </body>
        </body>
      </body>
      <body name="side" pos="-0.1 0 0.1">
        <joint name="side_hinge" type="hinge" axis="0 1 1" pos="0 0.02 0" damping="0.3"/>
        <inertial pos="-0.05 0.02 0.1" quat="0.6 0.1 0.7 0.2" mass="0.4" diaginertia="0.002 0.0025 0.001"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="rail_motor" joint="rail" gear="2.5"/>
    <motor name="shoulder_motor" joint="shoulder" gear="7"/>
    <position name="elbow_servo" joint="elbow" kp="20" kv="1.5" gear="1.3"/>
    <velocity name="extend_vel" joint="extend" kv="4" gear="0.8"/>
    <general name="twist_general" joint="twist" gear="3" gainprm="2 0.1 0.2" gaintype="affine"
             biastype="affine" biasprm="0.3 -0.4 -0.5"/>
    <motor name="side_motor" joint="side_hinge" gear="-1.7"/>
  </actuator>
</mujoco>
"""

SHIPPED = ("furuta_pendulum.xml", "panda_like_arm.xml", "double_pendulum.xml")


@pytest.fixture(scope="module")
def tree_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("mjcf") / "tree_test.xml"
    path.write_text(TREE_XML)
    return path


@pytest.fixture(scope="module")
def tree_flags_path(tmp_path_factory):
    """The test tree with MuJoCo's gravity, damper and spring forces disabled by flags."""
    path = tmp_path_factory.mktemp("mjcf") / "tree_flags.xml"
    path.write_text(
        TREE_XML.replace(
            'eulerdamp="disable"', 'eulerdamp="disable" gravity="disable" damper="disable" spring="disable"'
        )
    )
    return path


@pytest.fixture(scope="module", params=("tree", "tree_flags", *SHIPPED))
def model(request, tree_path, tree_flags_path):
    """(plant, MjModel) for the test tree (with and without flags) and every shipped MjcfPlant model."""
    path = {"tree": tree_path, "tree_flags": tree_flags_path}.get(request.param) or asset_path(request.param)
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    return MjcfPlant(path), m


def _random(plant, rng):
    nq = plant.state_dim // 2
    return np.r_[rng.uniform(-2, 2, nq), rng.uniform(-3, 3, nq)], rng.uniform(-1, 1, plant.input_dim)


# ------------------------------------------------------------------- dynamics
def test_dynamics_equal_mujoco_qacc(model):
    plant, m = model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(20)
    nq = m.nq
    worst = 0.0
    for _ in range(100):
        x, u = _random(plant, rng)
        d.qpos[:], d.qvel[:], d.ctrl[:] = x[:nq], x[nq:], u
        mujoco.mj_forward(m, d)
        xdot = plant.dynamics(x, u)
        np.testing.assert_array_equal(xdot[:nq], x[nq:])
        worst = max(worst, np.abs(xdot[nq:] - d.qacc).max() / max(1.0, np.abs(d.qacc).max()))
    assert worst < 1e-9


def test_batch_dynamics_equal_single(model):
    plant, _ = model
    rng = np.random.default_rng(3)
    X, U = zip(*(_random(plant, rng) for _ in range(5)), strict=True)
    batch = plant.dynamics(np.array(X), np.array(U))
    assert batch.shape == (5, plant.state_dim)
    for k in range(5):
        np.testing.assert_allclose(batch[k], plant.dynamics(X[k], U[k]), rtol=0, atol=0)


# ------------------------------------------------------------------ Jacobians
def test_exact_jacobians_equal_complex_step(model):
    plant, _ = model
    rng = np.random.default_rng(7)
    for _ in range(3):
        x, u = _random(plant, rng)
        A, B = plant.linearize(x, u)
        Ac, Bc = complex_step_jacobians(plant, x, u)  # RigidBodyTree on complex numbers: no CasADi
        J, Jc = np.hstack([A, B]), np.hstack([Ac, Bc])
        assert np.abs(J - Jc).max() <= 1e-12 * max(1.0, np.abs(Jc).max())


def test_exact_jacobians_equal_mujoco_transition_fd(model):
    plant, _ = model
    engine = MujocoEngine.for_plant(plant)  # the same file: Euler with explicit damping, timestep = dt
    engine.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)  # limits are not smooth dynamics
    rng = np.random.default_rng(11)
    for _ in range(3):
        x, u = _random(plant, rng)
        x[plant.state_dim // 2 :] *= 0.3
        A, B = plant.linearize(x, u)
        Am, Bm = mujoco_continuous_jacobians(engine, x, u, eps=1e-6)
        J, Jm = np.hstack([A, B]), np.hstack([Am, Bm])
        assert np.abs(J - Jm).max() <= 1e-5 * np.abs(J).max()


@pytest.mark.parametrize("name", SHIPPED)
def test_crosscheck_every_shipped_model(name):
    result = crosscheck(MjcfPlant(name))
    assert result.mujoco_max_rel_error < 1e-5
    assert result.fd_max_rel_error < 1e-5
    assert result.model == str(asset_path(name))


# ------------------------------------------------------------ double pendulum
def test_double_pendulum_file_matches_hand_written_plant():
    mj, dp = MjcfPlant("double_pendulum.xml"), DoublePendulum()
    assert mj.dt == dp.dt and mj.input_names == ("torque_1", "torque_2")  # same motors, named by the model
    T, _ = dp.engine_state_map()
    Ti = np.linalg.inv(T)
    rng = np.random.default_rng(5)
    # The asset gives each point mass a 1e-8 kg m² inertia (MuJoCo needs one); against m l² = 0.025 kg m² it
    # moves the results by ~1e-6 relative, which bounds the agreement below.
    for z, u in [(np.zeros(4), np.zeros(2)), (np.array([np.pi, 0, 0, 0]), np.zeros(2))] + [
        (rng.uniform(-2, 2, 4), rng.uniform(-1, 1, 2)) for _ in range(5)
    ]:
        x = T @ z
        np.testing.assert_allclose(T @ mj.dynamics(z, u), dp.dynamics(x, u), rtol=1e-5, atol=1e-5)
        A, B = mj.linearize(z, u)
        Ad, Bd = dp.linearize(x, u)
        assert np.abs(T @ A @ Ti - Ad).max() <= 1e-5 * np.abs(Ad).max()
        assert np.abs(T @ B - Bd).max() <= 1e-5 * np.abs(Bd).max()


# -------------------------------------------------------------- plant contract
def test_names_operating_point_and_gravity_compensation():
    arm = MjcfPlant("panda_like_arm.xml")
    assert arm.state_names[:2] == ("joint1", "joint2") and arm.state_names[7] == "joint1_dot"
    assert arm.input_names == tuple(f"motor{i}" for i in range(1, 8))
    x0, u0 = arm.equilibrium()
    np.testing.assert_allclose(x0[:7], [0, -0.785, 0, -2.356, 0, 1.571, 0.785])  # the "home" keyframe
    assert np.abs(u0).max() > 0.05  # gravity is not negligible...
    np.testing.assert_allclose(arm.dynamics(x0, u0), 0.0, atol=1e-10)  # ...and u0 holds the pose
    # the same torque from MuJoCo's own inverse dynamics: qfrc_bias + damping (zero at rest) = gear * u0
    m = mujoco.MjModel.from_xml_path(str(asset_path("panda_like_arm.xml")))
    d = mujoco.MjData(m)
    d.qpos[:] = x0[:7]
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(m.actuator_gear[:, 0] * u0, d.qfrc_bias, rtol=1e-10, atol=1e-12)
    with pytest.raises(InvalidArgument, match="cannot hold"):
        MjcfPlant("furuta_pendulum.xml").equilibrium_input([0, 0.3, 0, 0])  # the pendulum is unactuated


def test_actuator_subset_and_options(tree_path):
    full = MjcfPlant(tree_path)
    sub = MjcfPlant(tree_path, actuators=["side_motor", "rail_motor"], dt=0.01, u0=[0.0, 0.0])
    assert sub.input_names == ("side_motor", "rail_motor") and sub.dt == 0.01
    x = np.linspace(-0.5, 0.5, 12)
    _, B = full.linearize(x, np.zeros(6))
    _, Bs = sub.linearize(x, np.zeros(2))
    np.testing.assert_allclose(Bs, B[:, [5, 0]], rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(sub.dynamics(x, [0.2, -0.3]), full.dynamics(x, [-0.3, 0, 0, 0, 0, 0.2]), rtol=1e-13)
    assert sub.params() == {} and sub.symbolic(params=True).size1_in(2) == 0


def test_standalone_step_equals_mujoco_step(tree_path):
    plant = MjcfPlant(tree_path)
    twin = MjcfPlant(tree_path)
    engine = MujocoEngine.for_plant(twin)
    twin.physics_engine(engine)
    x = np.r_[np.linspace(-0.3, 0.3, 6), np.linspace(0.5, -0.5, 6)]
    plant.set_state(x)
    twin.set_state(x)
    rng = np.random.default_rng(2)
    for _ in range(20):
        u = rng.uniform(-1, 1, 6)
        np.testing.assert_allclose(plant.step(u), twin.step(u), rtol=1e-9, atol=1e-12)


def test_scenario_runs_in_both_loops():
    from shinro_ctrl.sim import RobotSim

    doc = {
        "plant": {"type": "MjcfPlant", "model": "furuta_pendulum.xml", "dt": 0.005},
        "engine": {"type": "mujoco"},
        "controller": {"type": "LQR", "Q": [5, 50, 0.5, 1], "R": [200]},
        "sim": {"duration": 1.0, "initial_state": [0.0, 0.1, 0.0, 0.0]},
    }
    runs = [RobotSim.from_config(doc, engine=e).run() for e in ("standalone", "mujoco")]
    for r in runs:
        assert abs(r.x[-1, 1]) < 0.02 and abs(r.x[:, 1]).max() <= 0.1 + 1e-12
    np.testing.assert_allclose(runs[0].x, runs[1].x, atol=1e-8)


def test_scenario_model_file_as_type_and_relative_to_the_scenario(tmp_path, monkeypatch):
    from shinro_ctrl.config import load_scenario
    from shinro_ctrl.errors import ConfigError
    from shinro_ctrl.sim import RobotSim

    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "rotary.xml").write_text(asset_path("furuta_pendulum.xml").read_text())
    body = '[controller]\ntype = "LQR"\nQ = [5, 50, 0.5, 1]\nR = [200]\n[sim]\nduration = 0.2\n'
    (tmp_path / "a.toml").write_text('[plant]\ntype = "robots/rotary.xml"\n' + body)
    (tmp_path / "b.toml").write_text('[plant]\ntype = "MjcfPlant"\nmodel = "robots/rotary.xml"\n' + body)
    (tmp_path / "c.toml").write_text('[plant]\ntype = "robots/rotary.xml"\nmodel = "x.xml"\n' + body)
    monkeypatch.chdir(tmp_path / "robots")  # elsewhere: the paths resolve beside the scenario file
    for name in ("a.toml", "b.toml"):
        sim = RobotSim.from_config(tmp_path / name)
        assert isinstance(sim.plant, MjcfPlant) and sim.plant.model_path == str(tmp_path / "robots" / "rotary.xml")
        assert sim.plant.state_names == ("arm", "pendulum", "arm_dot", "pendulum_dot")
    with pytest.raises(ConfigError, match="remove 'model'"):
        load_scenario(tmp_path / "c.toml")


# ------------------------------------------------------------------------ URDF
URDF = """<robot name="two_link">
  <link name="base"/>
  <link name="upper">
    <inertial><origin xyz="0.02 0.01 0.2" rpy="0.1 0.2 0"/><mass value="1.2"/>
      <inertia ixx="0.011" ixy="0.001" ixz="0.0005" iyy="0.013" iyz="-0.0007" izz="0.004"/></inertial>
    <collision><origin xyz="0 0 0.2"/><geometry><cylinder radius="0.03" length="0.4"/></geometry></collision>
  </link>
  <link name="lower">
    <inertial><origin xyz="0.0 -0.01 0.15" rpy="0 0.1 0.3"/><mass value="0.7"/>
      <inertia ixx="0.006" ixy="0.0" ixz="0.0002" iyy="0.005" iyz="0.0" izz="0.002"/></inertial>
  </link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.5" rpy="0 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="3"/>
    <dynamics damping="0.3"/></joint>
  <joint name="elbow" type="continuous"><parent link="upper"/><child link="lower"/>
    <origin xyz="0 0 0.4" rpy="0.2 0 0"/><axis xyz="1 0 0"/><dynamics damping="0.1"/></joint>
</robot>"""


def test_urdf_gets_a_motor_per_joint_and_matches_mujoco(tmp_path):
    path = tmp_path / "two_link.urdf"
    path.write_text(URDF)
    plant = MjcfPlant(path)
    assert plant.state_names == ("shoulder", "elbow", "shoulder_dot", "elbow_dot")
    assert plant.input_names == ("shoulder", "elbow")
    # unforced motion against MuJoCo's own compilation of the URDF (no actuators added there); MuJoCo writes the
    # translated MJCF with 6 significant digits (the inertias' principal axes), hence 1e-5 here, while plant and
    # engine, which load the same translated file, agree to 1e-9 (the crosscheck and the qacc tests)
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(4)
    for _ in range(20):
        x = np.r_[rng.uniform(-1.5, 1.5, 2), rng.uniform(-2, 2, 2)]
        d.qpos[:], d.qvel[:] = x[:2], x[2:]
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(plant.dynamics(x, np.zeros(2))[2:], d.qacc, rtol=1e-5, atol=1e-9)
    assert crosscheck(plant, [0.3, 0.2, 0.1, -0.2], [0.1, 0.2]).mujoco_max_rel_error < 1e-5
    mt = mujoco.MjModel.from_xml_path(plant.model_path)  # the translated file, as the engine loads it
    mt.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    dt = mujoco.MjData(mt)
    x, u = np.array([0.4, -0.7, 1.0, -0.5]), np.array([2.0, -1.0])
    dt.qpos[:], dt.qvel[:], dt.ctrl[:] = x[:2], x[2:], u
    mujoco.mj_forward(mt, dt)
    np.testing.assert_allclose(plant.dynamics(x, u)[2:], dt.qacc, rtol=1e-9)


# ------------------------------------------------------------ shipped scenarios
@pytest.mark.parametrize("name", ["furuta_lqr_mujoco", "panda_hold_lqr_mujoco", "panda_mpc_move_mujoco"])
def test_shipped_scenarios_settle_in_both_loops_within_the_torque_limits(name):
    from shinro_ctrl.sim import RobotSim

    runs = {e: RobotSim.from_config(config_path(name), engine=e) for e in ("standalone", "mujoco")}
    results = {e: sim.run() for e, sim in runs.items()}
    x_star = runs["mujoco"].operating_point
    for loop, r in results.items():
        assert np.abs(r.x[-1] - x_star).max() < 1e-3, loop
        assert r.metrics["settling_time"] < 2.0, loop
        assert r.metrics["constraint_violations"] == 0, loop
    if name == "panda_mpc_move_mujoco":  # the torque limits bind, and hold exactly
        lim = np.array([0.87] * 4 + [0.24] * 3)
        u = results["mujoco"].u
        assert np.all(np.abs(u) <= lim + 1e-12)
        assert np.isclose(np.abs(u), lim, rtol=0, atol=1e-9).any()
    # the standalone step is MuJoCo's semi-implicit Euler on the same physics: the loops agree closely
    np.testing.assert_allclose(results["standalone"].x, results["mujoco"].x, atol=1e-6)


# ---------------------------------------------------------------------- errors
BALL = """<mujoco><worldbody><body><joint name="wrist" type="ball"/><geom size="0.1"/></body></worldbody>
<actuator><motor joint="wrist" gear="1 0 0"/></actuator></mujoco>"""
NO_ACT = """<mujoco><worldbody><body><joint name="j" type="hinge"/><geom size="0.1"/></body></worldbody></mujoco>"""
MUSCLE = """<mujoco><worldbody><body><joint name="j" type="hinge"/><geom size="0.1"/></body></worldbody>
<actuator><muscle name="lagged" joint="j" lengthrange="-1 1"/></actuator></mujoco>"""
ROTOR = """<mujoco><worldbody><body><joint name="j" type="hinge"/><geom size="0.1"/></body></worldbody>
<actuator><motor name="geared" joint="j" armature="0.1"/></actuator></mujoco>"""
POLY = """<mujoco><worldbody><body><joint name="soft" type="hinge" damping="0.1 0.3"/><geom size="0.1"/></body>
</worldbody><actuator><motor joint="soft"/></actuator></mujoco>"""
CRANK = """<mujoco><worldbody><body><joint name="j" type="slide"/><geom size="0.1"/><site name="s"/></body>
<site name="c" pos="0 0 0.5"/></worldbody>
<actuator><general name="crank" cranksite="c" slidersite="s" cranklength="0.6"/></actuator></mujoco>"""


@pytest.mark.parametrize(
    ("xml", "match"),
    [
        (BALL, r"actuator on a ball or free joint .*not supported yet; use a site"),
        (NO_ACT, "no actuators"),
        (MUSCLE, r"activation dynamics \(muscle\) on actuator 'lagged'"),
        (CRANK, "slidercrank transmission on actuator 'crank'"),
        (ROTOR, r"armature on actuator 'geared' \(not supported yet"),
        (POLY, r"nonlinear damping \(more than one damping coefficient\) on joint 'soft'"),
    ],
)
def test_unsupported_models_raise_one_clear_error(tmp_path, xml, match):
    path = tmp_path / "bad.xml"
    path.write_text(xml)
    with pytest.raises(InvalidArgument, match=match):
        MjcfPlant(path)


def test_other_errors(tree_path):
    with pytest.raises(FileNotFoundError, match=r"model file not found: 'no_such_robot\.xml'"):
        MjcfPlant("no_such_robot.xml")
    with pytest.raises(UnknownName, match="did you mean 'rail_motor'"):
        MjcfPlant(tree_path, actuators=["rail_motr"])
    with pytest.raises(InvalidArgument, match="x0"):
        MjcfPlant(tree_path, x0=[0, 0])


def test_model_files_where_plant_names_are_accepted(tree_path, capsys):
    assert plant_class(str(tree_path)) is MjcfPlant
    assert isinstance(plant_from_name(str(tree_path)), MjcfPlant)
    assert main(["linearize", str(tree_path), "--x0", "0,0.2,0,0,0,0,0.1,0,0,0,0,0"]) == 0
    assert "max relative" in capsys.readouterr().out
    assert main(["crosscheck", str(asset_path("furuta_pendulum.xml"))]) == 0
    assert "MuJoCo" in capsys.readouterr().out
    assert main(["linearize", "no_such_robot.urdf"]) == 2


# --------------------------------------------------------------------- threads
def test_dynamics_and_linearize_are_correct_under_concurrent_calls():
    """4 threads x 1,000 calls of dynamics and linearize on one plant give exactly the serial results."""
    import threading

    plant = MjcfPlant("panda_like_arm.xml")
    rng = np.random.default_rng(11)
    n_threads, calls = 4, 1000
    X = rng.uniform(-1.5, 1.5, (n_threads, calls, plant.state_dim))
    U = rng.uniform(-1, 1, (n_threads, calls, plant.input_dim))
    serial_f = np.array([[plant.dynamics(x, u) for x, u in zip(X[t], U[t], strict=True)] for t in range(n_threads)])
    lin = [(t, k) for t in range(n_threads) for k in range(0, calls, 10)]
    serial_AB = {(t, k): plant.linearize(X[t, k], U[t, k]) for t, k in lin}
    got_f = np.zeros_like(serial_f)
    got_AB: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    start = threading.Barrier(n_threads)
    errors: list[BaseException] = []

    def work(t: int) -> None:
        try:
            start.wait()
            for k in range(calls):
                got_f[t, k] = plant.dynamics(X[t, k], U[t, k])
                if k % 10 == 0:
                    got_AB[(t, k)] = plant.linearize(X[t, k], U[t, k])
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(t,)) for t in range(n_threads)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors, errors
    np.testing.assert_array_equal(got_f, serial_f)
    for key, (A, B) in serial_AB.items():
        np.testing.assert_array_equal(got_AB[key][0], A)
        np.testing.assert_array_equal(got_AB[key][1], B)


# ------------------------------------------------------------------ non-finite
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_dynamics_with_nan_or_inf_raises_nonfinite_error(bad):
    from shinro_ctrl.errors import NonFiniteError

    plant = MjcfPlant("furuta_pendulum.xml")
    x, u = np.array([0.1, 0.2, 0.0, 0.0]), np.array([0.3])
    with pytest.raises(NonFiniteError, match=r"x holds NaN or inf \(in pendulum\)"):
        plant.dynamics(np.r_[x[:1], bad, x[2:]], u)
    with pytest.raises(NonFiniteError, match=r"u holds NaN or inf \(in motor"):
        plant.dynamics(x, [bad])
    with pytest.raises(NonFiniteError, match=r"x holds NaN or inf \(in arm_dot\)"):
        plant.dynamics(np.array([x, [0, 0, bad, 0]]), np.zeros((2, 1)))
    with pytest.raises(NonFiniteError):
        plant.linearize(np.r_[bad, x[1:]], u)
    assert np.isfinite(plant.dynamics(x, u)).all()
