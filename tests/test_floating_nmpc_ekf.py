"""NonlinearMPC and the ExtendedKalmanFilter on a floating base (the drone of ``assets/quadrotor_free.xml``).

The references are the plant's own manifold step (``MjcfPlant.integrate``, checked against MuJoCo in
``test_floating_base.py``) and the true simulated state; errors are measured on the manifold
(``plant.difference``), so a yaw near π is no special case.
"""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.estimators.kalman import ExtendedKalmanFilter
from shinro_ctrl.plants import MjcfPlant

Q12 = [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1]
R4 = [0.5, 200, 200, 200]


@pytest.fixture(scope="module")
def drone():
    return MjcfPlant("quadrotor_free.xml")


def test_ekf_tangent_step_jacobians_match_central_differences_on_the_manifold(drone):
    ekf = ExtendedKalmanFilter.from_plant(drone, measured=list(drone.state_names[:7]), Qn=[1e-2] * 4, Rn=[1e-4] * 7)
    x0, u0 = drone.equilibrium()
    x = drone.retract(x0, np.r_[0.1, -0.2, 0.3, 0.4, -0.5, 2.9, 0.3, 0.2, -0.1, 0.5, -0.4, 0.3])
    u = u0 + np.array([0.5, 0.01, -0.02, 0.01])
    xn, A, B = ekf.step_jacobians(x, u)
    assert A.shape == (12, 12) and B.shape == (12, 4)
    assert np.abs(xn - drone.integrate(x, u)).max() < 1e-12  # the prediction is the plant's manifold step
    h = 1e-6
    Afd = np.column_stack(
        [
            drone.difference(drone.integrate(drone.retract(x, h * e), u), drone.integrate(drone.retract(x, -h * e), u))
            / (2 * h)
            for e in np.eye(12)
        ]
    )
    Bfd = np.column_stack(
        [drone.difference(drone.integrate(x, u + h * e), drone.integrate(x, u - h * e)) / (2 * h) for e in np.eye(4)]
    )
    assert np.abs(A - Afd).max() < 1e-6 and np.abs(B - Bfd).max() < 1e-6


def test_ekf_tracks_the_drone_pose_from_noisy_measurements(drone):
    x0, u = drone.equilibrium()
    ctrl = LQR.from_plant(drone, Q12, R4)
    sig = 1e-3
    ekf = ExtendedKalmanFilter.from_plant(drone, measured=list(drone.state_names[:7]), Qn=[1e-4] * 4, Rn=[sig**2] * 7)
    assert ekf.P.shape == (12, 12)  # the covariance of the tangent deviation
    rng = np.random.default_rng(7)
    # a yaw near π and a tilt: the estimate starts at hover, far off
    x = drone.retract(x0, np.r_[0.3, -0.3, 0.2, 0.3, -0.3, 3.1, np.zeros(6)])
    ekf.reset(x0, np.diag([1.0] * 6 + [0.1] * 6))
    assert np.abs(drone.difference(x0, x)).max() > 3.0  # the estimate starts at hover, a yaw of 3.1 rad off
    errs = []
    for k in range(100):
        y = x[:7] + sig * rng.normal(size=7)
        if k % 2:
            y[3:7] = -y[3:7]  # q and −q are the same attitude: the innovation is on the manifold
        x_hat = ekf.update(y, u)
        assert abs(np.linalg.norm(x_hat[3:7]) - 1.0) < 1e-12
        err = np.abs(drone.difference(x_hat, x))
        errs.append(err)
        u = ctrl(x_hat)
        x = drone.integrate(x, u)
    # a quaternion component's noise sig is a rotation noise 2 sig: the pose to a few noise sigmas, from the first
    # correction on (which closes the half-turn across the short arc)
    assert errs[0][:3].max() < 4 * sig and errs[0][3:6].max() < 4 * 2 * sig
    tail = np.array(errs[-30:])
    assert tail[:, :3].max() < 4 * sig and tail[:, 3:6].max() < 4 * 2 * sig and tail[:, 6:].max() < 0.1
    assert np.abs(drone.difference(x, x0)[3:6]).max() < 0.5  # the LQR on the estimate turns it home (from 3.1 rad)


def test_the_floating_ekf_is_not_exported_but_refused_in_one_line(drone):
    from shinro_ctrl.errors import ExportError
    from shinro_ctrl.export.registry import ExportContext, exporter_for

    ekf = ExtendedKalmanFilter.from_plant(drone, measured=list(drone.state_names[:7]), Qn=[1e-2] * 4, Rn=[1e-4] * 7)
    ctx = ExportContext(name="d", plant=drone, controller=None, estimator=ekf, x_hat_dim=13, initial_covariance=None)
    with pytest.raises(ExportError, match="floating base"):
        exporter_for(ekf, "estimator").part(ekf, ctx)


NMPC = dict(Q=Q12, R=R4, horizon=8, dt=0.03, terminal_cost="lqr", u_min=[0, -1, -1, -0.5], u_max=[19.62, 1, 1, 0.5])


def test_nmpc_rti_flies_the_drone_home_from_a_yaw_near_pi_and_a_tilt(drone):
    from shinro_ctrl.controllers.nmpc import NonlinearMPC

    nmpc = NonlinearMPC.from_plant(drone, **NMPC)  # RTI (DAQP), IPOPT cold start, 0.24 s horizon
    assert nmpc.Q.shape == (12, 12) and nmpc.hold == 3
    x0, _ = drone.equilibrium()
    x = drone.retract(x0, np.r_[0.3, -0.3, 0.2, 0.3, -0.3, 3.1, np.zeros(6)])  # a yaw of 3.1 rad and a tilt
    for _ in range(170):
        x = drone.integrate(x, nmpc(x))
        assert abs(np.linalg.norm(x[3:7]) - 1.0) < 1e-12
        assert np.all(np.abs(np.linalg.norm(nmpc.last.states[:, 3:7], axis=1) - 1.0) < 1e-12)  # the prediction
    assert nmpc.last.status == "rti"
    assert np.abs(drone.difference(x, x0)).max() < 0.05  # home after 1.7 s (0.03 measured)


def test_nmpc_rti_flies_the_drone_home_in_mujoco():
    from shinro_ctrl.sim import RobotSim

    x0 = MjcfPlant("quadrotor_free.xml").equilibrium()[0]
    q = np.r_[np.cos(1.25), 0.0, 0.0, np.sin(1.25)]  # a yaw of 2.5 rad
    c, s = np.cos(0.2), np.sin(0.2)
    q = np.r_[q[0] * c, q[0] * s, -q[3] * s, q[3] * c]  # then a roll of 0.4 rad about the body x axis
    config = {
        "plant": {"type": "MjcfPlant", "model": "quadrotor_free.xml"},
        "engine": {"type": "mujoco"},
        "controller": {"type": "NonlinearMPC", **NMPC},
        "sim": {"duration": 1.7, "initial_state": [0.3, -0.3, 1.2, *q, *np.zeros(6)]},
    }
    res = RobotSim.from_config(config).run(None, progress=False)
    assert res.loop == "mujoco"
    assert np.all(np.abs(np.linalg.norm(res.x[:, 3:7], axis=1) - 1.0) < 1e-9)
    plant = MjcfPlant("quadrotor_free.xml")
    assert np.abs(plant.difference(res.x[0], x0)).max() > 2.4
    assert np.abs(plant.difference(res.x[-1], x0)).max() < 0.05


def test_nmpc_refuses_state_bounds_and_ipopt_on_a_floating_base_in_one_line(drone):
    from shinro_ctrl.controllers.nmpc import NonlinearMPC
    from shinro_ctrl.errors import InvalidArgument

    with pytest.raises(InvalidArgument, match=r"floating base: state bounds"):
        NonlinearMPC.from_plant(drone, Q12, R4, horizon=3, x_max=[np.inf] * 12 + [1.0])
    with pytest.raises(InvalidArgument, match=r"floating base: solver 'ipopt' is not supported"):
        NonlinearMPC.from_plant(drone, Q12, R4, horizon=3, solver="ipopt")
    with pytest.raises(InvalidArgument, match=r"Q"):
        NonlinearMPC.from_plant(drone, [1.0] * 13, R4, horizon=3)  # Q has tangent_dim = 12 entries

    from shinro_ctrl.errors import ExportError
    from shinro_ctrl.export.registry import ExportContext, exporter_for

    nmpc = NonlinearMPC.from_plant(drone, Q12, R4, horizon=3)
    x0 = drone.equilibrium()[0]
    ctx = ExportContext(name="d", plant=drone, controller=nmpc, estimator=None, x_hat_dim=13, x_start=x0)
    with pytest.raises(ExportError, match="cannot export this NonlinearMPC: a floating base"):
        exporter_for(nmpc, "controller").part(nmpc, ctx)


def test_nmpc_sqp_converges_to_a_local_minimum_on_the_manifold(drone):
    from shinro_ctrl.controllers.nmpc import NonlinearMPC

    # the LQR terminal weight couples the rotation with the rest: the chart Jacobians make its Gauss-Newton exact
    nmpc = NonlinearMPC.from_plant(drone, **{**NMPC, "u_min": None, "u_max": None}, iterations=20)
    x0, _ = drone.equilibrium()
    x = drone.retract(x0, np.r_[0.2, -0.1, 0.1, 0.3, -0.2, 2.9, 0.1, 0, 0, 0, 0.2, 0])
    nmpc(x)
    sol = nmpc.last
    assert sol.status == "solved" and sol.kkt_residual < 1e-6

    def rollout(U):  # the plant's own step, 3 per shooting interval of 0.03 s
        X = [x]
        for u in U:
            z = X[-1]
            for _ in range(3):
                z = drone.integrate(z, u)
            X.append(z)
        return np.array(X)

    X = rollout(sol.inputs)
    assert np.abs(drone.difference(X, sol.states)).max() < 1e-8  # the plan is feasible: no gaps left
    J = nmpc.objective(X, sol.inputs)
    rng = np.random.default_rng(3)
    for _ in range(10):  # any nearby feasible plan costs more
        dU = 1e-3 * rng.normal(size=sol.inputs.shape) * np.array([1.0, 0.01, 0.01, 0.01])
        assert nmpc.objective(rollout(sol.inputs + dU), sol.inputs + dU) > J
