"""Output feedback in the loop: measured outputs, noise, disturbances, estimators, LQI; both loops."""

from __future__ import annotations

import copy
import tomllib

import numpy as np
import pytest

from shinro_ctrl.controllers import LQR
from shinro_ctrl.controllers.lqi import IntegralAction
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.resources import config_path
from shinro_ctrl.sim import RobotSim


def _doc(name: str) -> dict:
    return tomllib.loads(config_path(name).read_text())


def test_ekf_pendulum_converges_from_a_wrong_estimate_in_mujoco():
    sim = RobotSim.from_config("pendulum_ekf_mujoco")
    assert sim.loop == "mujoco" and type(sim.estimator).__name__ == "ExtendedKalmanFilter"
    res = sim.run()
    err = np.abs(res.x_hat - res.x).max(axis=1)
    assert sim.initial_estimate[0] - res.x[0, 0] == pytest.approx(0.3, abs=1e-12)  # the filter starts 0.3 rad off
    assert res.y.shape == (res.t.size, 1) and np.std(res.y[:, 0] - res.x[:, 0]) > 5e-4  # noisy angle only
    assert err[res.t >= 2.0].max() < 1e-2
    assert res.metrics["estimation_rms"] > 0 and "estimation_rms_theta_dot" in res.metrics


def test_lqi_removes_a_step_push_and_lqr_keeps_the_predicted_offset():
    doc = _doc("cartpole_lqi_disturbance_mujoco")
    d = doc["sim"]["disturbance"]["value"]
    lqi = RobotSim.from_config(doc).run()
    assert lqi.loop == "mujoco"
    assert abs(lqi.x[-1, 0]) < 1e-3
    np.testing.assert_allclose(lqi.disturbance[lqi.t[:-1] >= 2.0], d)
    assert lqi.disturbance_labels == ["d_force"]

    plain = copy.deepcopy(doc)
    plain["controller"].update(Q=[10, 1, 100, 1])
    del plain["controller"]["integral"]
    sim = RobotSim.from_config(plain)
    res = sim.run()
    A, B, K = sim.controller.A, sim.controller.B, sim.controller.K
    predicted = np.linalg.solve(np.eye(4) - A + B @ K, B @ [d])  # x = A x + B (-K x + d)
    assert abs(predicted[0]) > 0.02
    assert res.x[-1, 0] == pytest.approx(predicted[0], rel=0.05)


def test_disturbances_and_noise_are_identical_in_both_loops_and_seeded():
    doc = _doc("cartpole_lqg")
    doc["sim"]["disturbance"] = [
        {"kind": "impulse", "input": 0, "time": 1.0, "value": 0.05},
        {"kind": "sine", "input": "force", "value": 0.2, "frequency": 1.0, "time": 2.0, "duration": 1.0},
        {"kind": "noise", "input": "force", "value": 0.1, "time": 3.0},
    ]
    runs = {e: RobotSim.from_config(doc, engine=e).run(duration=4.0) for e in ("standalone", "mujoco")}
    a, b = runs["standalone"], runs["mujoco"]
    np.testing.assert_array_equal(a.disturbance, b.disturbance)
    assert a.disturbance.shape == (400, 3)
    k = round(1.0 / 0.01)
    assert a.disturbance[k, 0] == pytest.approx(0.05 / 0.01) and np.count_nonzero(a.disturbance[:, 0]) == 1
    np.testing.assert_allclose(a.x, b.x, atol=1e-5)  # matched models: the same loop in both engines
    again = RobotSim.from_config(doc).run(duration=4.0)
    np.testing.assert_array_equal(again.y, a.y)
    doc["sim"]["seed"] = 5
    other = RobotSim.from_config(doc).run(duration=4.0)
    assert not np.allclose(other.y, a.y)


def test_lqg_result_arrays_plot_and_save(tmp_path):
    res = RobotSim.from_config("cartpole_lqg").run(duration=1.0)
    n = 4
    assert res.x_hat.shape == res.x.shape and res.y.shape == (res.t.size, 2)
    assert res.measured == ("x", "theta")
    err = res.x_hat - res.x
    assert res.metrics["estimation_rms"] == pytest.approx(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    for i, name in enumerate(res.state_names[:n]):
        assert res.metrics[f"estimation_rms_{name}"] == pytest.approx(np.sqrt(np.mean(err[:, i] ** 2)))
    assert res.plot(tmp_path / "p.png").stat().st_size > 10_000
    saved = np.load(res.save(tmp_path / "out") / "result.npz")
    assert {"x_hat", "y", "disturbance"} <= set(saved.files)


def test_full_state_runs_report_no_estimation_metrics():
    res = RobotSim.from_config("cartpole_lqr").run(duration=0.5)
    assert "estimation_rms" not in res.metrics
    np.testing.assert_array_equal(res.x_hat, res.x)


def test_anti_windup_freezes_the_integrator_only_while_it_pushes_into_saturation():
    A, B = np.eye(2), np.array([[0.0], [1.0]])
    act = IntegralAction(A, B, (0,), dt=0.1)
    act.set_gain(np.array([[2.0]]))
    x, r = np.array([1.0, 0.0]), np.zeros(2)
    u = act.finish(np.array([-5.0]), x, r, np.array([-1.0]), np.array([1.0]))  # below u_min; K_i e pushes lower
    assert u[0] == -1.0 and act.z[0] == 0.0
    u = act.finish(np.array([-5.0]), -x, r, np.array([-1.0]), np.array([1.0]))  # the error now unwinds it
    assert act.z[0] == pytest.approx(-0.1)
    act.reset()
    act.finish(np.array([0.0]), x, r, None, None)
    assert act.z[0] == pytest.approx(0.1)


def test_lqi_design_matches_the_augmented_dare():
    import scipy.linalg

    from shinro_ctrl.plants import CartPole

    plant = CartPole()
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1, 50], [0.1], integral=["x"])
    A, B = plant.get_model(discretization="step")  # from_plant's default model
    Aa = np.block([[A, np.zeros((4, 1))], [plant.dt * np.eye(4)[[0]], np.eye(1)]])
    Ba = np.vstack([B, [[0.0]]])
    Q, R = np.diag([10, 1, 100, 1, 50.0]), np.array([[0.1]])
    S = scipy.linalg.solve_discrete_are(Aa, Ba, Q, R)
    K = np.linalg.solve(R + Ba.T @ S @ Ba, Ba.T @ S @ Aa)
    np.testing.assert_allclose(np.hstack([ctrl.K, ctrl.K_i]), K, rtol=1e-8)
    assert ctrl.stateful


def _base() -> dict:
    return {
        "plant": {"type": "CartPole"},
        "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]},
        "sim": {"measured": ["x", "theta"], "sensor_noise": [0.01, 0.01]},
        "estimator": {"type": "KalmanFilter"},
    }


def _with(**tables) -> dict:
    doc = _base()
    for table, change in tables.items():
        if change is None:
            doc.pop(table)
        else:
            doc[table] = {**doc.get(table, {}), **change}
    return doc


@pytest.mark.parametrize(
    "doc,match",
    [
        (_with(sim={"measured": ["x", "thta"]}), r"unknown state 'thta'; did you mean 'theta'.*valid"),
        (_with(sim={"sensor_noise": [0.01]}), r"'sensor_noise' must have 2 values"),
        (_with(sim={"process_noise": [-0.1]}), r"'process_noise' standard deviations must be >= 0"),
        (_with(sim={"disturbance": {"kind": "ramp", "input": 0, "value": 1}}), r"unknown kind 'ramp'"),
        (_with(sim={"disturbance": {"kind": "step", "input": "forse", "value": 1}}), r"did you mean 'force'"),
        (_with(sim={"disturbance": {"kind": "step", "input": 0}}), r"kind 'step' needs 'value'"),
        (_with(sim={"disturbance": {"kind": "step", "body": "cart", "value": [1, 0, 0]}}), r"no body-force"),
        (_with(sim={"disturbance": {"kind": "noise", "input": 0, "value": -1}}), r"standard deviation"),
        (_with(estimator={"Rm": [1, 1]}), r"\[estimator\] unknown key 'Rm'"),
        (_with(estimator={"type": "Kalman"}), r"did you mean 'KalmanFilter'"),
        (_with(estimator={"steady_state": "yes"}), r"'steady_state' must be a boolean"),
        (_with(estimator=None), r"add an \[estimator\] table"),
        (_with(estimator={"type": "FullState"}), r"FullState needs every state measured"),
        (_with(sim={"measured": ["theta"], "sensor_noise": [0.01]}), r"not detectable.*mostly state 'x'"),
        (_with(estimator={"Rn": [-1, 1]}), r"Rn\[0\] = -1"),
        (_with(estimator={"type": "Luenberger"}), r"poles"),
        (
            {**_base(), "sim": {"sensor_noise": [0.01, 0.01]}},  # no 'measured': every state is measured
            r"'sensor_noise' must have 4 values \(one per measured state; without 'measured' all 4 states",
        ),
        ({**_base(), "sim": {"sensor_noise": [0.01] * 5}}, r"without 'measured' all 4 states are measured\), got 5"),
        (_with(estimator={"type": "123"}), r"unknown estimator type '123'"),
        (_with(estimator={"type": ""}), r"unknown estimator type ''"),
    ],
)
def test_scenario_bad_input(doc, match):
    with pytest.raises(ConfigError, match=match):
        RobotSim.from_config(doc)


def test_offset_free_mpc_holds_the_quadrotor_against_wind_and_plain_mpc_does_not():
    doc = _doc("quadrotor_wind_mpc_mujoco")
    sim = RobotSim.from_config(doc)
    assert sim.loop == "mujoco" and sim.estimator.disturbance_model == "input"
    res = sim.run()
    late = res.t >= 7.0
    offset_free = np.abs(res.x[late, :3] - res.ref[late, :3]).mean(axis=0)
    assert offset_free.max() < 1e-2
    np.testing.assert_allclose(res.disturbance[res.t[:-1] >= 1.0, 0], 0.3)

    plain = copy.deepcopy(doc)
    del plain["controller"]["disturbance_model"], plain["estimator"], plain["sim"]["measured"]
    plain["sim"]["sensor_noise"] = [0.001] * 12  # full state, same kind of noise
    res = RobotSim.from_config(plain).run()
    drift = np.abs(res.x[late, :3] - res.ref[late, :3]).mean(axis=0)
    assert drift[0] > 5e-2  # settles downwind


def test_offset_free_call_with_zero_disturbance_is_the_plain_mpc():
    from shinro_ctrl.controllers import LinearMPC
    from shinro_ctrl.plants import CartPole

    plant = CartPole()
    kw = dict(horizon=20, u_min=[-5.0], u_max=[5.0])
    free = LinearMPC.from_plant(plant, [10, 1, 100, 1], [0.1], disturbance_model="input", **kw)
    plain = LinearMPC.from_plant(plant, [10, 1, 100, 1], [0.1], **kw)
    x = np.array([0.1, 0.0, 0.05, 0.0])
    np.testing.assert_allclose(free(np.r_[x, 0.0]), plain(x), rtol=1e-9, atol=1e-12)
    u = free(np.r_[x, 0.3])  # the effective input v = u + d is what the plain MPC returns
    np.testing.assert_allclose(u, np.clip(plain(x) - 0.3, -5, 5), rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="disturbance_model must be None or 'input'"):
        LinearMPC.from_plant(plant, [10, 1, 100, 1], [0.1], disturbance_model="output", **kw)
