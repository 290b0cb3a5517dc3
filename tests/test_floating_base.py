"""Free and ball joints (a floating base): the dynamics, the manifold maps and the tangent-space models.

References, all independent of the CasADi expressions under test:

* MuJoCo's ``qacc_smooth`` (``mj_forward``) on the same file: the smooth dynamics (1e-9 relative);
* MuJoCo's ``mj_integratePos`` / ``mj_differentiatePos``: the manifold maps (to rounding);
* MuJoCo's ``mj_step`` (Euler, ``eulerdamp`` off): the standalone step;
* MuJoCo's ``mjd_transitionFD`` (centred, eps 1e-7): the discrete tangent Jacobians, whose own truncation and
  rounding are ~1e-9 here (tolerance 1e-7 relative);
* central differences on the manifold ``difference(F(retract(x0, ±ε e_k)), F(x0)) / 2ε``: the same Jacobians
  without MuJoCo; and a five-point stencil for the continuous tangent Jacobian (of ``d/dt difference(x, x0)``);
* the built-in Euler-angle ``Quadrotor`` at hover, where the tangent state and its state coincide (1e-9).
"""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.controllers.mpc import LinearMPC
from shinro_ctrl.engine.model_tree import read_model_tree
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.multibody import RigidBodyTree, configuration
from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.plants.quadrotor import Quadrotor

# a free base with a hinge, a ball and a slide below it, off-axis inertias, damping and armature, gravity
# off the z axis, a joint motor, a site thrust and a site moment
TREE = """<mujoco model="floating_tree">
  <option timestep="0.002" gravity="0.3 -0.2 -9.81"><flag eulerdamp="disable" contact="disable"/></option>
  <worldbody>
    <body name="base" pos="0.1 0.2 1.0" quat="0.9 0.1 0.3 0.2">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.1 0.05" mass="3"/>
      <site name="imu" pos="0.01 0.02 0.03"/>
      <body name="l1" pos="0.2 0.0 0.0" quat="0.8 0.2 0.1 0.4">
        <joint name="h1" type="hinge" axis="0 1 0.3" pos="0.01 0 0" damping="0.1" armature="0.01"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0.1" size="0.03" mass="0.5"/>
        <body name="l2" pos="0.3 0 0.1">
          <joint name="b1" type="ball" pos="0.02 0.01 0" damping="0.05" armature="0.002"/>
          <geom type="capsule" fromto="0 0 0 0 0.2 -0.1" size="0.02" mass="0.3"/>
          <body name="l3" pos="0 0.2 -0.1">
            <joint name="s1" type="slide" axis="1 0 0"/>
            <geom type="sphere" size="0.05" mass="0.2"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="m1" joint="h1" gear="2"/>
    <motor name="m2" joint="s1"/>
    <motor name="thrust" site="imu" gear="0 0 1 0 0 0"/>
    <motor name="mx" site="imu" gear="0 0 0 1 0.2 0"/>
  </actuator>
</mujoco>"""


@pytest.fixture(scope="module")
def tree_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("floating") / "floating_tree.xml"
    path.write_text(TREE)
    return path


@pytest.fixture(scope="module")
def model(tree_file):
    m = mujoco.MjModel.from_xml_path(str(tree_file))
    return m, mujoco.MjData(m)


@pytest.fixture(scope="module")
def plant(tree_file):
    return MjcfPlant(tree_file)


@pytest.fixture(scope="module")
def drone():
    return MjcfPlant("quadrotor_free.xml")


def _random_state(m: mujoco.MjModel, rng: np.random.Generator) -> np.ndarray:
    q = m.qpos0.copy()
    mujoco.mj_integratePos(m, q, rng.normal(size=m.nv), 1.0)  # every quaternion far from the identity
    return np.r_[q, rng.normal(size=m.nv)]


def test_accelerations_match_qacc_smooth(model, plant):
    m, d = model
    rng = np.random.default_rng(0)
    rb = RigidBodyTree(read_model_tree(m), "crba")  # the second algorithm, on floats
    for _ in range(3):
        x, u = _random_state(m, rng), rng.normal(size=m.nu)
        d.qpos[:], d.qvel[:], d.ctrl[:] = x[: m.nq], x[m.nq :], u
        mujoco.mj_forward(m, d)
        scale = max(1.0, np.abs(d.qacc_smooth).max())
        xd = plant.dynamics(x, u)
        assert np.abs(xd[m.nq :] - d.qacc_smooth).max() < 1e-9 * scale
        assert np.abs(rb.xdot_numpy(x, u, range(m.nu))[m.nq :] - d.qacc_smooth).max() < 1e-9 * scale
        # the qpos rate is the derivative of mj_integratePos along qvel
        q1, q2 = x[: m.nq].copy(), x[: m.nq].copy()
        mujoco.mj_integratePos(m, q1, x[m.nq :], 1e-6)
        mujoco.mj_integratePos(m, q2, x[m.nq :], -1e-6)
        assert np.abs((q1 - q2) / 2e-6 - xd[: m.nq]).max() < 1e-8


def test_difference_and_retract_are_mujocos(model, plant):
    m, _ = model
    rng = np.random.default_rng(1)
    tree = plant.tree
    for _ in range(4):
        x, dx = _random_state(m, rng), rng.normal(size=plant.tangent_dim) * 0.7
        q = x[: m.nq].copy()
        mujoco.mj_integratePos(m, q, dx[: m.nv], 1.0)
        y = plant.retract(x, dx)
        assert np.abs(y[: m.nq] - q).max() < 1e-14
        assert np.abs(y[m.nq :] - (x[m.nq :] + dx[m.nv :])).max() < 1e-14
        v = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, v, 0.5, x[: m.nq], y[: m.nq])
        assert np.abs(configuration.difference(tree, y[: m.nq], x[: m.nq], 0.5) - v).max() < 1e-13
        assert np.abs(plant.difference(y, x) - dx).max() < 1e-13  # round trip (|rotation| < π)
    # batches, the short arc (q and −q are one rotation), and D E = I
    X = np.stack([_random_state(m, rng) for _ in range(3)])
    assert plant.difference(X, X[0]).shape == (3, plant.tangent_dim)
    flipped = X[1].copy()
    flipped[3:7] *= -1.0
    assert np.abs(plant.difference(flipped, X[1])).max() < 1e-14
    D, E = plant.tangent_maps(X[2])
    assert np.abs(D @ E - np.eye(plant.tangent_dim)).max() < 1e-14


def test_step_and_its_tangent_jacobians_match_mujoco(model, plant):
    m, d = model
    rng = np.random.default_rng(2)
    x, u = _random_state(m, rng), rng.normal(size=m.nu)
    d.qpos[:], d.qvel[:], d.ctrl[:] = x[: m.nq], x[m.nq :], u
    mujoco.mj_step(m, d)
    xn = plant.integrate(x.copy(), u)
    assert np.abs(xn - np.r_[d.qpos, d.qvel]).max() < 1e-12
    assert np.abs(np.asarray(plant.symbolic_step()(x, u, [])).ravel() - xn).max() < 1e-12
    A, B = plant.step_jacobians(x, u)
    n = 2 * m.nv
    assert A.shape == (n, n) and B.shape == (n, m.nu)
    Am, Bm = np.zeros((n, n)), np.zeros((n, m.nu))
    d.qpos[:], d.qvel[:], d.ctrl[:] = x[: m.nq], x[m.nq :], u
    mujoco.mjd_transitionFD(m, d, 1e-7, 1, Am, Bm, None, None)
    assert np.abs(A - Am).max() < 1e-7 * max(1.0, np.abs(Am).max())
    assert np.abs(B - Bm).max() < 1e-7 * max(1.0, np.abs(Bm).max())
    eps, E = 1e-6, np.eye(n)
    Acd = np.column_stack(
        [
            plant.difference(plant.integrate(plant.retract(x, eps * e), u), xn)
            - plant.difference(plant.integrate(plant.retract(x, -eps * e), u), xn)
            for e in E
        ]
    ) / (2 * eps)
    assert np.abs(A - Acd).max() < 1e-7 * max(1.0, np.abs(A).max())


def test_continuous_tangent_jacobian_on_the_manifold(drone):
    plant = drone
    rng = np.random.default_rng(3)
    x0 = drone.equilibrium()[0]
    x = drone.retract(x0, rng.normal(size=12))  # tilted and spinning: the −½[ω]× terms matter
    u = rng.normal(size=4) + np.array([5.0, 0, 0, 0])

    def d5(F, h):
        return (-F(2 * h) + 8 * F(h) - 8 * F(-h) + F(-2 * h)) / (12 * h)

    def rate(dl):  # d/dt difference(x(t), x) at x(0) = retract(x, dl)
        xx = plant.retract(x, dl)
        f = plant.dynamics(xx, u)
        return d5(lambda s: plant.difference(xx + s * f, x), 1e-4)

    A, B = plant.linearize(x, u)
    E = np.eye(plant.tangent_dim)
    Acd = np.column_stack([d5(lambda s, e=e: rate(s * e), 1e-3) for e in E])
    assert np.abs(A - Acd).max() < 1e-6 * max(1.0, np.abs(A).max())
    assert B.shape == (12, 4)


def test_drone_linearization_equals_the_builtin_quadrotor(drone):
    x0, u0 = drone.equilibrium()
    assert drone.state_dim == 13 and drone.tangent_dim == 12
    assert np.allclose(u0, [0.5 * 9.81, 0, 0, 0]) and np.abs(drone.dynamics(x0, u0)).max() < 1e-12
    quad = Quadrotor(mass=0.5, inertia=[3e-3, 3e-3, 5e-3], gravity=9.81, dt=drone.dt)
    # at hover the tangent state [p, δθ_body, v_world, ω_body] is the built-in's [p, rpy, v, pqr] to first
    # order at any yaw: the state map is the identity (rotate the yaw to check it there too)
    for yaw in (0.0, 0.7):
        xq = np.r_[x0[:3], 0.0, 0.0, yaw, np.zeros(6)]
        xm = x0.copy()
        xm[3:7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        A, B = drone.linearize(xm, u0)
        Aq, Bq = quad.linearize(xq, u0)
        assert np.abs(A - Aq).max() < 1e-9 and np.abs(B - Bq).max() < 1e-9


@pytest.mark.parametrize("kind", ["LQR", "LinearMPC"])
def test_controllers_fly_the_drone_through_a_yaw_half_turn(drone, kind):
    x0, _ = drone.equilibrium()
    Q, R = [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], [0.5, 200, 200, 200]
    if kind == "LQR":
        ctrl = LQR.from_plant(drone, Q, R)
    else:
        ctrl = LinearMPC.from_plant(drone, Q, R, horizon=10, u_min=[0, -1, -1, -0.5], u_max=[19.62, 1, 1, 0.5])
    # 0.3 m off and a half-turn of yaw (far beyond any Euler-angle linearization's comfort), tilted
    x = drone.retract(x0, np.r_[0.3, -0.3, 0.2, 0.2, -0.2, 3.0, np.zeros(6)])
    for _ in range(300):
        x = drone.integrate(x, ctrl(x))
    assert np.abs(drone.difference(x, x0)).max() < 1e-2


def test_bad_quaternions_and_lengths(drone, tmp_path, capsys):
    x0 = drone.equilibrium()[0]
    near = x0.copy()
    near[3] = 1.0 + 5e-7
    with pytest.warns(UserWarning, match=r"quaternion \(root_qw, root_qx, root_qy, root_qz\) normalized"):
        p = MjcfPlant("quadrotor_free.xml", x0=near)
    assert np.linalg.norm(p.equilibrium()[0][3:7]) == pytest.approx(1.0, abs=1e-15)
    far = x0.copy()
    far[3:7] = [0.9, 0.1, 0.0, 0.0]
    with pytest.raises(InvalidArgument, match=r"quaternion .* has norm 0.905539, not 1"):
        MjcfPlant("quadrotor_free.xml", x0=far)
    with pytest.raises(InvalidArgument, match=r"x0 has 12 entries; expected 13 = nq 7 \(qpos, with 1 unit"):
        MjcfPlant("quadrotor_free.xml", x0=np.zeros(12))
    # the CLI: one line, exit 2
    scenario = tmp_path / "bad.toml"
    scenario.write_text(
        '[plant]\ntype = "MjcfPlant"\nmodel = "quadrotor_free.xml"\nx0 = [0, 0, 1, 2, 0, 0, 0, 0, 0, 0, 0, 0, 0]\n'
        '[controller]\ntype = "LQR"\nQ = [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\nR = [1, 1, 1, 1]\n'
        "[sim]\nduration = 0.1\n"
    )
    assert main(["run", str(scenario), "--engine", "standalone"]) == 2
    err = capsys.readouterr().err
    assert "x0 quaternion (root_qw, root_qx, root_qy, root_qz) = [2.0, 0.0, 0.0, 0.0] has norm 2, not 1" in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_unsupported_floating_features_are_refused(tmp_path):
    path = tmp_path / "stiff_ball.xml"
    path.write_text(
        '<mujoco><worldbody><body><joint name="hip" type="ball" stiffness="2"/><geom size="0.1"/><site name="s"/>'
        '</body></worldbody><actuator><motor site="s" gear="0 0 0 1 0 0"/></actuator></mujoco>'
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(InvalidArgument, match=r"stiffness on ball joint 'hip'"):
            MjcfPlant(path)


def test_crosscheck_compares_the_tangent_models_directly(drone):
    from shinro_ctrl.crosscheck import crosscheck

    rng = np.random.default_rng(5)
    x0 = drone.equilibrium()[0]
    x = drone.retract(x0, rng.normal(size=12) * 0.5)  # tilted and spinning, off equilibrium
    u = np.array([5.0, 0.01, -0.02, 0.01])
    res = crosscheck(drone, x, u)
    assert res.A_mujoco.shape == (12, 12) and res.state_names[3:6] == ("root_rx", "root_ry", "root_rz")
    assert res.mujoco_max_rel_error < 1e-6 and res.fd_max_rel_error < 1e-6


def test_kalman_filter_estimates_the_drone_from_its_pose(drone):
    from shinro_ctrl.estimators.kalman import KalmanFilter

    x0, u = drone.equilibrium()
    ctrl = LQR.from_plant(drone, [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], [0.5, 200, 200, 200])
    kf = KalmanFilter.from_plant(drone, measured=list(drone.state_names[:7]), Qn=[1e-2] * 4, Rn=[1e-4] * 7)
    assert kf.C.shape == (7, 12)  # the filter runs in the tangent space; it measures qpos (with the quaternion)
    kf.reset(x0)
    rng = np.random.default_rng(6)
    x = drone.retract(x0, np.r_[0.3, -0.3, 0.2, 0.2, -0.2, 0.5, np.zeros(6)])
    first = None
    for _ in range(300):
        x_hat = kf.update(x[:7] + 1e-3 * rng.normal(size=7), u)
        first = np.abs(drone.difference(x_hat, x)).max() if first is None else first
        u = ctrl(x_hat)
        x = drone.integrate(x, u)
    assert x_hat.shape == (13,) and np.linalg.norm(x_hat[3:7]) == pytest.approx(1.0, abs=1e-12)
    assert np.abs(drone.difference(x, x0)).max() < 0.05
    err = np.abs(drone.difference(x_hat, x))
    assert err[:6].max() < 5e-3 and err[6:].max() < 0.1 < first  # the pose to a few noise sigmas


def test_tvlqr_tracks_a_drone_trajectory(drone):
    from shinro_ctrl.controllers.tvlqr import TVLQR
    from shinro_ctrl.planning.trajectory import Trajectory

    # a feasible reference: the LQR's own flight out of a yaw offset (knots at the plant's step)
    x0, u0 = drone.equilibrium()
    lqr = LQR.from_plant(drone, [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], [0.5, 200, 200, 200])
    xs, us = [drone.retract(x0, np.r_[0.5, 0, 0, 0, 0, 1.0, np.zeros(6)])], []
    for _ in range(45):
        us.append(lqr(xs[-1]))
        xs.append(drone.integrate(xs[-1], us[-1]))
    X, U = np.array(xs[:-1]), np.array(us)
    X[-1], U[-1] = x0, u0  # the plan ends at rest, the goal's LQR takes over (an equilibrium)
    xdot = np.array([drone.dynamics(x, u) for x, u in zip(X, U, strict=True)])
    traj = Trajectory(t=drone.dt * np.arange(45), x=X, u=U, xdot=xdot)
    ctrl = TVLQR.from_trajectory(drone, traj, [100] * 6 + [10] * 6, [0.1, 1, 1, 1])
    assert ctrl.K.shape == (44, 4, 12)  # one tangent-space gain per step of the 0.44 s plan
    x = X[0].copy()  # on the plan: it is followed to rounding
    for k in range(44):
        assert np.abs(drone.difference(x, X[k])).max() < 1e-9
        x = drone.integrate(x, ctrl(x))
    ends = []
    for feedback in (True, False):  # 0.05 off the plan: the feedback pulls it back, the plan's inputs do not
        ctrl.reset()
        x = drone.retract(X[0], np.r_[0.05, -0.05, 0.0, 0.05, 0.0, -0.05, np.zeros(6)])
        for k in range(43):
            x = drone.integrate(x, ctrl(x) if feedback else U[k])
        ends.append(np.linalg.norm(drone.difference(x, X[43])))
    assert ends[0] < 0.75 * ends[1]  # about 0.14 against 0.22
