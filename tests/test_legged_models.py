"""Our own legged models (assets/quadruped.xml, assets/humanoid.xml), the push disturbance, the balance metrics
and the MuJoCo-tutorial LQR recipe."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shinro_ctrl.config import parse_scenario
from shinro_ctrl.disturbances import disturbance_profile, parse_disturbances
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.engine.contacts import BalanceRecord
from shinro_ctrl.engine.tutorial_lqr import simulate_push, transition_fd_lqr
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.plants import Quadrotor
from shinro_ctrl.resources import asset_path
from shinro_ctrl.sim import RobotSim
from shinro_ctrl.sim.metrics import BALANCE_METRICS, balance_metrics

G = 9.81
QUAD_FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")


def _model(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(asset_path(name)))


@pytest.fixture(scope="module")
def quadruped() -> mujoco.MjModel:
    return _model("quadruped.xml")


@pytest.fixture(scope="module")
def humanoid() -> mujoco.MjModel:
    return _model("humanoid.xml")


def _mass(m: mujoco.MjModel, body: str) -> float:
    return float(m.body_mass[m.body(body).id])


def test_quadruped_file_has_the_published_go2_facts(quadruped):
    m = quadruped
    assert m.nu == 12 and m.njnt == 13 and m.nq == 19 and m.nv == 18
    assert int(m.jnt_type[0]) == int(mujoco.mjtJoint.mjJNT_FREE) and m.body(int(m.jnt_bodyid[0])).name == "trunk"
    assert m.opt.integrator == int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
    assert _mass(m, "trunk") == pytest.approx(6.921)
    for leg in ("FL", "FR", "RL", "RR"):
        assert _mass(m, f"{leg}_hip") == pytest.approx(0.678)
        assert _mass(m, f"{leg}_thigh") == pytest.approx(1.152)
        assert _mass(m, f"{leg}_calf") == pytest.approx(0.241)  # calf and foot
        sx, sy = (1 if leg[0] == "F" else -1), (1 if leg[1] == "L" else -1)
        np.testing.assert_allclose(m.body(f"{leg}_hip").pos, [0.1934 * sx, 0.0465 * sy, 0])
        np.testing.assert_allclose(m.body(f"{leg}_thigh").pos, [0, 0.0955 * sy, 0])
        np.testing.assert_allclose(m.body(f"{leg}_calf").pos, [0, 0, -0.213])  # thigh length
        np.testing.assert_allclose(m.site(f"{leg}_foot").pos, [0, 0, -0.213])  # calf length
        foot = m.geom(f"{leg}_foot")
        assert foot.type == mujoco.mjtGeom.mjGEOM_SPHERE and foot.size[0] == pytest.approx(0.022)
    assert float(m.body_subtreemass[1]) == pytest.approx(15.205)
    limits = {m.actuator(a).name: tuple(m.actuator_ctrlrange[a]) for a in range(m.nu)}
    for leg in ("FL", "FR", "RL", "RR"):
        assert limits[f"{leg}_hip"] == limits[f"{leg}_thigh"] == (-23.7, 23.7)
        assert limits[f"{leg}_calf"] == (-45.43, 45.43)
        np.testing.assert_allclose(m.joint(f"{leg}_calf_joint").range, [-2.7227, -0.83776])
        np.testing.assert_allclose(m.joint(f"{leg}_hip_joint").range, [-1.0472, 1.0472])
    floor = m.geom("floor")
    assert floor.type == mujoco.mjtGeom.mjGEOM_PLANE and 0.8 <= floor.friction[0] <= 1.0
    assert m.key("stand").id == 0


def test_humanoid_file_has_the_published_h1_facts(humanoid):
    m = humanoid
    assert m.nu == 19 and m.nv == 6 + 19
    masses = {
        "pelvis": 5.39,
        "torso": 17.789,
        "left_hip_yaw_link": 2.244,
        "left_hip_roll_link": 2.232,
        "left_hip_pitch_link": 4.152,
        "left_knee_link": 1.721,
        "left_ankle_link": 0.446,
        "right_shoulder_pitch_link": 1.033,
        "right_shoulder_roll_link": 0.793,
        "right_shoulder_yaw_link": 0.839,
        "right_elbow_link": 0.669,
    }
    for body, mass in masses.items():
        assert _mass(m, body) == pytest.approx(mass), body
    assert float(m.body_subtreemass[1]) == pytest.approx(51.437)
    for side in ("left", "right"):
        np.testing.assert_allclose(m.body(f"{side}_knee_link").pos, [0, 0, -0.4])  # thigh
        np.testing.assert_allclose(m.body(f"{side}_ankle_link").pos, [0, 0, -0.4])  # shin
        soles = [m.geom(f"{side}_sole_{c}") for c in ("heel_in", "heel_out", "toe_in", "toe_out")]
        assert all(int(g.bodyid[0]) == m.body(f"{side}_ankle_link").id and g.contype[0] for g in soles)
    limits = {m.actuator(a).name: float(m.actuator_ctrlrange[a, 1]) for a in range(m.nu)}
    assert limits["left_hip_pitch"] == limits["torso"] == 200 and limits["right_knee"] == 300
    assert limits["left_ankle"] == limits["right_shoulder_roll"] == 40 and limits["left_elbow"] == 18
    np.testing.assert_allclose(m.joint("left_knee").range, [-0.26, 2.05])


def _stand_under_pd(m: mujoco.MjModel, kp: float, kd: float, seconds: float = 2.0) -> tuple[MujocoEngine, float]:
    """PD on the keyframe's joint angles for ``seconds``; returns the engine and the keyframe's trunk height."""
    e = MujocoEngine.from_model(m)
    d = e.data
    mujoco.mj_resetDataKeyframe(m, d, m.key("stand").id)
    z0 = float(d.qpos[2])
    joints = [int(m.actuator_trnid[a, 0]) for a in range(m.nu)]
    qa, va = m.jnt_qposadr[joints], m.jnt_dofadr[joints]
    q_ref = d.qpos[qa].copy()
    for _ in range(round(seconds / m.opt.timestep)):
        d.ctrl[:] = kp * (q_ref - d.qpos[qa]) - kd * d.qvel[va]
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    return e, z0


@pytest.mark.parametrize(
    ("name", "kp", "kd", "contacts"), [("quadruped", 300.0, 5.0, 4), ("humanoid", 3000.0, 60.0, 8)]
)
def test_robot_stands_still_for_two_seconds_under_joint_pd(name, kp, kd, contacts, request):
    # the humanoid's joint PD must be stiffer than its weight's toppling moment m g h ≈ 490 N m/rad
    m = request.getfixturevalue(name)
    e, z0 = _stand_under_pd(m, kp, kd)
    d = e.data
    tilt = 2 * math.acos(min(1.0, abs(d.qpos[3])))
    assert abs(d.qpos[2] - z0) < 0.03 and tilt < 0.05 and np.linalg.norm(d.qpos[:2]) < 0.05
    assert np.abs(d.qvel).max() < 0.05
    floor = e.floor_contacts()
    assert len(floor) == contacts
    # the floor carries the weight (mj_contactForce read in the contact frame: normal first), inside the cones
    assert sum(c.normal_force for c in floor) == pytest.approx(float(m.body_subtreemass[1]) * G, rel=0.02)
    assert all(c.inside_cone and c.friction == pytest.approx(0.9) for c in floor)


def test_body_force_reaches_xfrc_applied_and_changes_the_momentum_by_its_impulse(quadruped):
    m = quadruped
    e = MujocoEngine.from_model(m)
    d = e.data
    mujoco.mj_resetDataKeyframe(m, d, 0)
    d.qpos[2] = 2.0  # in the air: only gravity and the push act on the whole robot
    mujoco.mj_forward(m, d)
    F = np.array([0.0, 30.0, 0.0])
    e.set_body_force("trunk", F)
    np.testing.assert_array_equal(d.xfrc_applied[m.body("trunk").id], [0, 30, 0, 0, 0, 0])
    mass = float(m.body_subtreemass[1])
    mujoco.mj_subtreeVel(m, d)
    p0 = mass * d.subtree_linvel[1].copy()
    n = 50
    for _ in range(n):
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    mujoco.mj_subtreeVel(m, d)  # the whole robot's centre-of-mass velocity
    e.clear_body_forces()
    assert not d.xfrc_applied.any()
    impulse = (F + mass * np.array([0, 0, -G])) * n * m.opt.timestep
    # exact up to implicitfast's implicit joint damping (internal forces, discretized: ~1e-5 relative)
    np.testing.assert_allclose(mass * d.subtree_linvel[1] - p0, impulse, rtol=1e-4, atol=1e-3)


def test_push_kind_parses_samples_and_rejects_bad_tables():
    plant = Quadrotor()
    [spec] = parse_disturbances(
        {"kind": "push", "body": "quadrotor", "value": [0, 30, 0], "time": 1.0, "duration": 0.1}, plant
    )
    assert spec.as_table() == {"kind": "push", "body": "quadrotor", "value": [0, 30, 0], "time": 1.0, "duration": 0.1}
    t = np.arange(200) * 0.01
    prof = disturbance_profile([spec], t, 0.01, 4, 0)
    [(body, F)] = prof.forces
    on = (t >= 1.0 - 1e-9) & (t < 1.1 - 1e-9)
    assert body == "quadrotor" and on.sum() == 10
    np.testing.assert_array_equal(F[on], np.tile([0, 30, 0], (10, 1)))
    assert not F[~on].any()
    with pytest.raises(ConfigError, match="'push' is a force on a body"):
        parse_disturbances({"kind": "push", "input": 0, "value": 1.0, "time": 0, "duration": 1}, plant)
    with pytest.raises(ConfigError, match="needs 'duration'"):
        parse_disturbances({"kind": "push", "body": "quadrotor", "value": [0, 1, 0], "time": 0}, plant)


def _quadrotor_run(push: bool):
    doc = {
        "plant": {"type": "Quadrotor", "mass": 0.5, "dt": 0.01},
        "engine": {"type": "mujoco", "model": "realistic"},
        "controller": {"type": "LQR", "Q": [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], "R": [0.5, 200, 200, 200]},
        "sim": {"duration": 0.3, "reference": {"kind": "constant", "value": [0.0] * 12}},
    }
    if push:
        doc["sim"]["disturbance"] = [
            {"kind": "push", "body": "quadrotor", "value": [0.0, 2.0, 0.0], "time": 0.1, "duration": 0.1}
        ]
    return RobotSim(parse_scenario(doc)).run(progress=False)


@pytest.fixture(scope="module")
def quadrotor_runs():
    return _quadrotor_run(False), _quadrotor_run(True)


def test_scenario_push_moves_the_simulated_body_by_its_impulse(quadrotor_runs):
    calm, pushed = quadrotor_runs
    cols = [pushed.disturbance_labels.index(f"F_quadrotor_{a}") for a in "xyz"]
    on = (pushed.t[:-1] >= 0.1 - 1e-9) & (pushed.t[:-1] < 0.2 - 1e-9)
    np.testing.assert_array_equal(pushed.disturbance[on][:, cols], np.tile([0, 2, 0], (on.sum(), 1)))
    vy = pushed.state_names.index("vy")
    k = int(np.argmin(np.abs(pushed.t - 0.2)))
    dv = pushed.x[k, vy] - calm.x[k, vy]
    assert dv == pytest.approx(2.0 * 0.1 / 0.5, rel=0.1)  # F Δt / m: MuJoCo felt the push


def test_balance_metrics_of_a_mujoco_run_match_its_trajectory(quadrotor_runs):
    calm, pushed = quadrotor_runs
    for r in (calm, pushed):
        assert set(BALANCE_METRICS) <= set(r.metrics)
        names = r.state_names
        z = r.x[:, names.index("z")]
        assert r.metrics["trunk_height_error"] == pytest.approx(np.max(np.abs(z - z[0])), abs=1e-9)
        eul = r.x[:, [names.index(a) for a in ("yaw", "pitch", "roll")]]
        rot = Rotation.from_euler("ZYX", eul)
        angle = (rot[0].inv() * rot).magnitude()
        assert r.metrics["trunk_orientation_error"] == pytest.approx(angle.max(), abs=1e-7)
        assert r.metrics["foot_slip"] is None and r.metrics["friction_cone_fraction"] is None  # in the air


def test_balance_metrics_on_a_crafted_record_against_hand_computations():
    rx = Rotation.from_rotvec([0.1, 0, 0]).as_quat(scalar_first=True)
    rz = Rotation.from_rotvec([0, 0, -0.3]).as_quat(scalar_first=True)
    steps = [0, 1, 2, 4, 5, 0, 1, 1, 2, 3]
    geoms = ["A", "A", "A", "A", "A", "B", "B", "B", "B", "B"]
    pos = [[0, 0], [0.01, 0], [0.01, 0.02], [1, 1], [1.05, 1], [2, 2], [2, 2.01], [2, 2.03], [2, 2], [2.004, 2.003]]
    forces = [[10, 1]] * 5 + [[10, 1], [10, 1], [10, 2], [10, 9.5], [10, 0]]
    rec = BalanceRecord(
        trunk_pos=np.array([[0, 0, 0.3], [0, 0, 0.31], [0, 0, 0.28], [0, 0, 0.3], [0, 0, 0.3], [0, 0, 0.3]]),
        trunk_quat=np.array([[1, 0, 0, 0], rx, -rz, [1, 0, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0]]),
        contact_step=np.array(steps),
        contact_geom=np.array(geoms, dtype=object),
        contact_pos=np.array([[*p, 0.0] for p in pos]),
        contact_force=np.array(forces, dtype=float),
        contact_friction=np.full(10, 0.9),
    )
    out = balance_metrics(rec)
    assert out["trunk_height_error"] == pytest.approx(0.02)
    assert out["trunk_orientation_error"] == pytest.approx(0.3)  # -q is the same rotation
    # A: runs {0,1,2} (largest travel |(0.01, 0.02)|) and {4,5} (0.05); B: one run 0..3, step 1 averaged to
    # (2, 2.02): largest travel 0.02
    assert out["foot_slip"] == pytest.approx(0.05)
    # A always inside (1 <= 9); B outside at step 2 (9.5 > 9): 3 of its 4 samples
    assert out["friction_cone_fraction"] == pytest.approx(0.75)
    assert balance_metrics(None) == dict.fromkeys(BALANCE_METRICS)
    rec.contact_step = rec.contact_step[:0]
    assert balance_metrics(rec)["foot_slip"] is None


@pytest.fixture(scope="module")
def recipe(quadruped):
    e = MujocoEngine.from_model(quadruped)
    return e, transition_fd_lqr(e, QUAD_FEET)


def test_tutorial_recipe_stands_the_quadruped_and_recovers_from_a_30_newton_push(recipe):
    e, ctrl = recipe
    m = e.model
    # the standing point: the contacts carry the weight, the actuators the rest (mj_inverse, independent of K)
    assert ctrl.point.residual < 0.05
    assert np.all(np.abs(ctrl.point.ctrl) <= m.actuator_ctrlrange[:, 1])
    assert ctrl.K.shape == (12, 36)
    start = (ctrl.point.qpos.copy(), np.zeros(m.nv))
    assert simulate_push(e, ctrl, start, body="trunk", force=[0, 30, 0], settle=1.5)
    assert not simulate_push(e, ctrl, start, body="trunk", force=[0, 400, 0], settle=0.5)


def test_tutorial_recipe_rejects_bad_names(quadruped):
    e = MujocoEngine.from_model(quadruped)
    with pytest.raises(InvalidArgument, match=r"unknown foot 'paw'.*FL_foot"):
        transition_fd_lqr(e, ["paw"])
    with pytest.raises(InvalidArgument, match=r"no keyframe 'sit' \(valid: stand\)"):
        transition_fd_lqr(e, QUAD_FEET, keyframe="sit")
    with pytest.raises(InvalidArgument, match="free joint"):
        transition_fd_lqr(MujocoEngine("cartpole.xml"), ["x"])


def _furuta(push_body: str, engine: str = "mujoco") -> RobotSim:
    doc = {
        "plant": {"type": "MjcfPlant", "model": "furuta_pendulum.xml", "dt": 0.005},
        "engine": {"type": "mujoco", "model": "realistic"},
        "controller": {"type": "LQR", "Q": [5, 50, 0.5, 1], "R": [200]},
        "sim": {
            "duration": 0.2,
            "initial_state": [0.0, 0.05, 0.0, 0.0],
            "disturbance": [
                {"kind": "push", "body": push_body, "value": [0.0, 0.5, 0.0], "time": 0.05, "duration": 0.05}
            ],
        },
    }
    return RobotSim(parse_scenario(doc), engine=engine)


def test_model_file_plant_takes_a_push_on_any_body_of_its_file_in_mujoco():
    sim = _furuta("pendulum")
    pushed = sim.run(progress=False)
    sim.scenario.sim.disturbance = None
    calm = sim.run(progress=False)  # the same start (initial_state), no push
    k = int(np.argmin(np.abs(pushed.t - 0.1)))
    assert np.abs(pushed.x[k] - calm.x[k]).max() > 1e-3  # MuJoCo felt it
    with pytest.raises(ConfigError, match=r"no body-force disturbance on 'pendulm'.*bodies of the model: .*pendulum"):
        _furuta("pendulm")
    with pytest.raises(InvalidArgument, match="no body-force disturbance on 'pendulum'"):
        _furuta("pendulum", engine="standalone").run(progress=False)  # standalone has no force map: says so
