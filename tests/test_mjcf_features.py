"""MjcfPlant on what real robot files contain: friction loss, joint ranges, fixed tendons, site transmissions,
activation dynamics and gravity compensation, checked on the gallery of model files (assets/gallery/).

References (all MuJoCo's own computations on the same file, independent of the CasADi expression):

* ``qacc_smooth`` and ``act_dot`` of ``mj_forward``: MuJoCo's smooth dynamics (everything but the constraint
  forces: contacts, limits, friction loss). The reference copy of the model has the ``ctrlrange``,
  ``forcerange`` and ``actuatorfrcrange`` clamps switched off: the smooth model leaves them out by design
  (they are MuJoCo-loop only), and the random inputs below would otherwise hit them. Agreement to 1e-9
  relative (the float64 rounding of two different algorithms is ~1e-15).
* central differences of those with step 1e-6: the exact Jacobians. The difference quotient is off by
  ``eps² |f'''| / 6`` (~1e-12 here) plus rounding ``~1e-16 |f| / eps`` (~1e-10 |f|), so 1e-6 relative to
  ``max(1, |J|)`` is far above both and far below any missing or wrong term (an O(1) relative error).
* ``mj_step`` with MuJoCo's Euler integrator: the standalone step's activation update (filterexact exactly).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.resources import asset_path

GALLERY = ("gripper_tendon", "servo_arm", "friction_arm", "thruster", "filtered_actuator", "gravcomp_arm")


def _smooth_reference(path: str) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """MuJoCo's model of the file without its clamps (the smooth model leaves them out by design)."""
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL)
    m.actuator_forcelimited[:] = 0
    m.jnt_actfrclimited[:] = 0
    return m, mujoco.MjData(m)


def _mujoco_xdot(m: mujoco.MjModel, d: mujoco.MjData, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``[qvel; qacc_smooth; act_dot]`` at ``x = [qpos; qvel; act]``, ``u``."""
    nq, nv = m.nq, m.nv
    d.qpos[:], d.qvel[:], d.act[:] = x[:nq], x[nq : nq + nv], x[nq + nv :]
    d.ctrl[:] = u
    mujoco.mj_forward(m, d)
    return np.concatenate([d.qvel, d.qacc_smooth, d.act_dot])


def _random_point(plant: MjcfPlant, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A state with the joints inside their ranges, random velocities and activations, a random input."""
    nq = plant.tree.nq
    lo, hi = plant.state_limits()
    q = rng.uniform(np.where(np.isfinite(lo[:nq]), lo[:nq], -1.0), np.where(np.isfinite(hi[:nq]), hi[:nq], 1.0))
    rest = rng.normal(size=plant.state_dim - nq)
    return np.r_[q, rest], rng.normal(size=plant.input_dim) * 2.0


@pytest.fixture(scope="module", params=GALLERY)
def gallery(request):
    path = asset_path(f"gallery/{request.param}.xml")
    return request.param, MjcfPlant(path), *_smooth_reference(path)


def test_gallery_dynamics_equal_mujoco_smooth_dynamics(gallery):
    _, plant, m, d = gallery
    rng = np.random.default_rng(7)
    for _ in range(5):
        x, u = _random_point(plant, rng)
        ref = _mujoco_xdot(m, d, x, u)
        np.testing.assert_allclose(plant.dynamics(x, u), ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_gallery_exact_jacobians_equal_central_differences_of_mujoco(gallery):
    _, plant, m, d = gallery
    x, u = _random_point(plant, np.random.default_rng(11))
    A, B = plant.linearize(x, u)
    eps = 1e-6
    n = plant.state_dim
    z = np.r_[x, u]
    J = np.empty((n, z.size))
    for k in range(z.size):
        zp, zm = z.copy(), z.copy()
        zp[k] += eps
        zm[k] -= eps
        J[:, k] = (_mujoco_xdot(m, d, zp[:n], zp[n:]) - _mujoco_xdot(m, d, zm[:n], zm[n:])) / (2 * eps)
    exact = np.hstack([A, B])
    np.testing.assert_allclose(exact, J, rtol=0, atol=1e-6 * max(1.0, np.abs(J).max()))


# ---------------------------------------------------------------- what each file exercises
def test_the_gallery_files_hold_the_features_they_are_named_after():
    tree = MjcfPlant("gallery/gripper_tendon.xml").tree
    split, center = tree.tendons
    assert (split.coefs, center.coefs, center.stiffness) == ((0.5, 0.5), (1.0, -1.0), 40.0)
    assert [a.transmission for a in tree.actuators] == ["joint", "tendon"]
    thruster = MjcfPlant("gallery/thruster.xml")
    assert {a.transmission for a in thruster.tree.actuators} == {"site"}
    # hover: the two rotors carry the weight, the tilted thruster and the torque stay idle
    np.testing.assert_allclose(thruster.equilibrium()[1], [0.028 * 9.81 / 2] * 2 + [0.0, 0.0], atol=1e-12)
    arm = MjcfPlant("gallery/gravcomp_arm.xml").tree
    assert [b.gravcomp for b in arm.bodies[2:5]] == [1.0, 0.5, 0.0] and arm.joints[1].actgravcomp


def test_activations_are_states_and_hold_the_operating_point():
    plant = MjcfPlant("gallery/filtered_actuator.xml")
    assert plant.state_names[6:] == ("shoulder_motor_act", "elbow_servo_act", "wrist_servo_act")
    assert [a.dyntype for a in plant.tree.actuators] == ["filter", "filterexact", "integrator"]
    x0, u0 = plant.equilibrium()
    np.testing.assert_allclose(plant.dynamics(x0, u0), 0.0, atol=1e-12)
    assert abs(x0[6]) > 1.0  # the lagged motor's activation holds the arm against gravity
    np.testing.assert_allclose(u0[:2], x0[6:8], atol=1e-12)  # filters: input = activation
    assert u0[2] == 0.0  # integrator: no input at rest
    # an activation that does not hold is not an equilibrium input
    x = x0.copy()
    x[6] = 0.0
    with pytest.raises(InvalidArgument, match="cannot hold"):
        plant.equilibrium_input(x)


def test_the_standalone_step_updates_activations_as_mujocos_euler_step():
    """filter and integrator by Euler, filterexact exactly: a⁺ = a + (u − a)(1 − exp(−h/τ))."""
    path = asset_path("gallery/filtered_actuator.xml")
    plant = MjcfPlant(path)
    m, d = _smooth_reference(path)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)  # explicit damping, as the plant's step
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    m.actuator_actlimited[:] = 0  # MuJoCo-loop only
    x, u = _random_point(plant, np.random.default_rng(3))
    _mujoco_xdot(m, d, x, u)
    mujoco.mj_step(m, d)
    after = np.concatenate([d.qpos, d.qvel, d.act])
    np.testing.assert_allclose(plant.integrate(x.copy(), u), after, rtol=0, atol=1e-12)
    tau, h = 0.05, plant.dt
    assert after[7] == pytest.approx(x[7] + (u[1] - x[7]) * -np.expm1(-h / tau), abs=1e-14)
    # the symbolic step (LinearMPC's "step" model) is the same map
    F = plant.symbolic_step()
    np.testing.assert_allclose(np.asarray(F(x, u, [])).ravel(), after, rtol=0, atol=1e-12)


def test_the_mujoco_loop_carries_the_activations():
    plant = MjcfPlant("gallery/filtered_actuator.xml")
    x0, u0 = plant.equilibrium()
    plant.physics_engine(MujocoEngine.for_plant(plant))
    x = x0 + np.r_[0.1, -0.2, 0.05, 0, 0, 0, 0.5, 0.1, -0.3]
    plant.set_state(x)
    np.testing.assert_array_equal(plant.get_state(), x)
    np.testing.assert_array_equal(plant.engine.data.act, x[6:])
    plant.set_state(x0)
    for _ in range(50):
        plant.step(u0)
    np.testing.assert_allclose(plant.get_state(), x0, atol=1e-9)


# ---------------------------------------------------------------- friction loss and ranges
def test_frictionloss_is_recorded_kept_out_of_f_and_acts_in_the_mujoco_loop():
    plant = MjcfPlant("gallery/friction_arm.xml")
    assert [j.frictionloss for j in plant.tree.joints] == [0.8, 0.8, 0.5, 0.5]
    x0, u0 = plant.equilibrium()
    u = u0 + np.array([0.5, 0.0, 0.0, 0.0])  # below the first joint's 0.8 N m of dry friction
    assert plant.dynamics(x0, u)[4] > 0.1  # the smooth model accelerates
    standalone = [plant.step(u)[0] for _ in range(50)][-1]
    plant.physics_engine(MujocoEngine.for_plant(plant))
    plant.set_state(x0)
    mujoco_loop = [plant.step(u)[0] for _ in range(50)][-1]
    assert standalone > 1e-3 and abs(mujoco_loop) < 0.1 * standalone  # MuJoCo's friction holds the joint


def test_a_urdf_with_dynamics_friction_loads_and_records_it(tmp_path):
    link = '<link name="{0}"><inertial><origin xyz="0 0 {1}"/><mass value="{2}"/>' + (
        '<inertia ixx="0.01" iyy="0.01" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial></link>'
    )
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(
        '<robot name="arm">'
        + link.format("base", 0.05, 2.0)
        + link.format("upper", 0.15, 1.2)
        + link.format("fore", 0.12, 0.8)
        + '<joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>'
        '<origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="40" velocity="3"/>'
        '<dynamics damping="0.3" friction="0.7"/></joint>'
        '<joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/>'
        '<origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" effort="20" velocity="3"/>'
        '<dynamics damping="0.1" friction="0.2"/></joint></robot>'
    )
    plant = MjcfPlant(urdf)
    assert [j.frictionloss for j in plant.tree.joints] == [0.7, 0.2]
    assert [j.damping for j in plant.tree.joints] == [0.3, 0.1]
    m, d = _smooth_reference(plant.model_path)
    x, u = _random_point(plant, np.random.default_rng(5))
    ref = _mujoco_xdot(m, d, x, u)
    np.testing.assert_allclose(plant.dynamics(x, u), ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_state_bounds_default_to_the_joint_ranges():
    plant = MjcfPlant("gallery/servo_arm.xml")
    lo, hi = plant.state_bounds
    np.testing.assert_array_equal(lo, [-2, -1.7, -1.6, -np.inf, -np.inf, -np.inf])
    np.testing.assert_array_equal(hi, [2, 1.7, 1.6, np.inf, np.inf, np.inf])
    np.testing.assert_array_equal(plant.state_limits()[1], hi)
    thruster = MjcfPlant("gallery/thruster.xml")  # unlimited joints stay unbounded
    np.testing.assert_array_equal(thruster.state_bounds[0][:3], [-np.inf, -0.45, -np.inf])
    # the standalone step stops at a range, as MuJoCo's joint limit does
    x = np.array([0.0, 1.69, 0.0, 0.0, 20.0, 0.0])
    after = plant.integrate(x, plant.equilibrium()[1])
    assert after[1] == 1.7 and after[4] == 0.0


# ---------------------------------------------------------------- transmissions beyond the gallery
SITES = """<mujoco><option gravity="0.2 -0.1 -9.81"/>
<worldbody><body name="b1" pos="0 0 1" gravcomp="0.7"><joint name="a" axis="0 1 0"/><geom size=".1" mass="1"/>
<site name="s" pos="0.1 0.2 0.3" quat="0.9 0.1 0.2 0.3"/>
<body name="b2" pos="0.3 0 0.5"><joint name="b" axis="1 0 0"/><joint name="c" type="slide" axis="0 0 1"/>
<geom size=".1" pos="0.1 0 0" mass="0.5"/><site name="r" pos="0 0.1 0" quat="0.7 0.3 -0.2 0.1"/>
<body name="b3" pos="0 0.3 0"><joint name="d" axis="0 0 1"/><geom size=".05" pos="0 0.1 0" mass="0.2"/>
<site name="t" pos="0.05 0 0.1"/></body></body></body></worldbody>
<actuator>
<general name="push_r" site="r" refsite="s" gear="0.5 0 1 0 0 0" gaintype="affine" gainprm="1 0.3 0.2"
 biastype="affine" biasprm="0.1 -0.4 -0.2"/>
<general name="push_s" site="s" refsite="t" gear="0.3 -1 0.2 0 0 0" biastype="affine" biasprm="0 -2 -0.1"/>
<general name="turn" site="t" refsite="s" gear="0 0 0 1 2 0.5"/>
<general name="wrench" site="t" gear="1 0.5 -0.2 0.1 0 0.3"/>
<general name="jip" jointinparent="d" gear="2"/>
</actuator></mujoco>"""


def test_site_transmissions_with_and_without_refsite_equal_mujoco(tmp_path):
    """Reference sites on the same branch, deeper and shallower, force and torque gears."""
    path = tmp_path / "sites.xml"
    path.write_text(SITES)
    plant = MjcfPlant(path)
    assert [a.refsite >= 0 for a in plant.tree.actuators] == [True, True, True, False, False]
    m, d = _smooth_reference(path)
    rng = np.random.default_rng(2)
    for _ in range(4):
        x, u = rng.normal(size=plant.state_dim), rng.normal(size=plant.input_dim)
        ref = _mujoco_xdot(m, d, x, u)
        np.testing.assert_allclose(plant.dynamics(x, u), ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_point_and_frame_jacobians_equal_mujocos():
    """The kinematics the site transmissions (and later contacts) use: mj_jacSite and site_xmat."""
    path = asset_path("gallery/servo_arm.xml")
    plant = MjcfPlant(path)
    rb = plant.rigid_body_tree
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    d.qpos[:] = [0.3, -0.7, 1.1]
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    body = m.body("wrist").id
    p, R, Jp, Jw = rb.frame_jacobian(list(d.qpos), body, (0.03, 0.0, -0.01))
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    point = d.xpos[body] + d.xmat[body].reshape(3, 3) @ [0.03, 0.0, -0.01]
    mujoco.mj_jac(m, d, jp, jr, point, body)
    np.testing.assert_allclose(np.array(p, dtype=float), point, atol=1e-14)
    np.testing.assert_allclose(np.array(R, dtype=float), d.xmat[body].reshape(3, 3), atol=1e-14)
    np.testing.assert_allclose(np.array(Jp, dtype=float), jp, atol=1e-14)
    np.testing.assert_allclose(np.array(Jw, dtype=float), jr, atol=1e-14)


# ---------------------------------------------------------------- refused, by name and reason
BASE = """<mujoco><option {option}/><worldbody><body name="arm"><joint name="j" type="hinge"/><geom size="0.1"/>
<site name="s" pos="0 0 0.1"/><body name="tip" pos="0 0 0.3"><joint name="k" type="hinge"/><geom size="0.1"/>
<site name="r" pos="0 0.1 0"/></body></body></worldbody>{tendon}<actuator>{actuator}</actuator></mujoco>"""
MOTOR = '<motor joint="j"/>'


@pytest.mark.parametrize(
    ("parts", "match"),
    [
        (
            {
                "tendon": '<tendon><spatial name="cable" stiffness="10"><site site="s"/><site site="r"/>'
                "</spatial></tendon>"
            },
            r"spatial tendon 'cable' with stiffness \(its length follows a path",
        ),
        (
            {
                "tendon": '<tendon><fixed name="t" stiffness="5" springlength="0.1 0.2"><joint joint="j" coef="1"/>'
                "</fixed></tendon>"
            },
            r"springlength dead band on tendon 't' \(\[0.1, 0.2\]\) \(a spring slack inside a range is not smooth",
        ),
        (
            {"tendon": '<tendon><fixed name="t" armature="0.1"><joint joint="j" coef="1"/></fixed></tendon>'},
            r"armature on tendon 't' \(it couples the joints' inertia",
        ),
        (
            {"actuator": '<general name="early" joint="j" dyntype="filter" dynprm="0.1" actearly="true"/>'},
            r"actearly on actuator 'early' \(its force uses the next step's activation",
        ),
        (
            {
                "actuator": '<general name="turn" site="r" refsite="s" gear="0 0 0 0 0 1" biastype="affine" '
                'biasprm="0 -1 0"/>'
            },
            r"rotational site transmission with a refsite and a length-dependent gain or bias on actuator 'turn'",
        ),
        (
            {"actuator": '<general name="lag" joint="j" dyntype="filter" dynprm="0"/>'},
            r"actuator 'lag' dynprm \(the time constant must be > 0\) = 0",
        ),
        ({"option": 'density="1.2"'}, r"fluid forces \(<option density=\"1.2\" viscosity=\"0\">\) \(drag and lift"),
    ],
)
def test_refused_features_name_the_element_and_the_reason(tmp_path, parts, match):
    path = tmp_path / "bad.xml"
    path.write_text(BASE.format(**{"option": "", "tendon": "", "actuator": MOTOR, **parts}))
    with pytest.raises(InvalidArgument, match=match):
        MjcfPlant(path)


def test_crosscheck_compares_the_activation_rows_with_mujocos_transition_jacobians():
    """mjd_transitionFD's act rows (MuJoCo's exact filterexact update) give the continuous rows back."""
    from shinro_ctrl.crosscheck import crosscheck

    plant = MjcfPlant("gallery/filtered_actuator.xml")
    x = np.array([0.3, -0.5, 0.2, 0.1, 0.2, -0.3, 1.0, 0.5, -0.2])
    result = crosscheck(plant, x, [1.0, 2.0, 0.5])
    assert result.A_mujoco.shape == (9, 9) and result.mujoco_max_rel_error < 1e-6


def test_nonlinear_mpc_steps_the_activations_with_the_semi_implicit_integrator():
    """States that are neither positions nor velocities step by explicit Euler (they were held constant)."""
    from shinro_ctrl.controllers import NonlinearMPC

    plant = MjcfPlant("gallery/filtered_actuator.xml")
    x0, _ = plant.equilibrium()
    mpc = NonlinearMPC.from_plant(plant, np.ones(9), np.ones(3), horizon=3, integrator="semi_implicit", solver="ipopt")
    x = x0 + np.r_[np.zeros(6), 1.0, 0.2, -0.1]
    mpc(x)
    S, U = mpc.last.states, mpc.last.inputs
    assert mpc.last.status == "solved"
    act_next = S[0, 6:] + plant.dt * plant.dynamics(S[0], U[0])[6:]
    np.testing.assert_allclose(S[1, 6:], act_next, rtol=0, atol=1e-9)
    assert np.abs(S[1, 6:] - S[0, 6:]).max() > 1e-3
