"""RobotSim: shipped scenarios settle, metrics are right, LQR cost matches its prediction."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from shinro_ctrl.config import parse_scenario
from shinro_ctrl.resources import list_configs
from shinro_ctrl.sim import Reference, RobotSim, compute_metrics

STANDALONE_LQR = [c for c in list_configs() if c.endswith("_lqr.toml") and "/" not in c]
# the humanoid's whole run, with its balance metrics, is tests/test_humanoid_balance.py's (one build of its plant)
MUJOCO_LQR = [
    c
    for c in list_configs()
    if c.endswith("_lqr_mujoco.toml") and "/" not in c and c != "humanoid_balance_lqr_mujoco.toml"
]


@pytest.mark.parametrize("name", STANDALONE_LQR + MUJOCO_LQR)
def test_shipped_lqr_scenarios_settle(name):
    sim = RobotSim.from_config(name)
    assert sim.loop == ("mujoco" if "mujoco" in name else "standalone")
    result = sim.run()
    assert result.metrics["settling_time"] < sim.scenario.sim.duration
    assert result.metrics["final_error"] < 1e-2
    assert result.x.shape == (len(result.t), sim.plant.state_dim)
    assert result.u.shape == (len(result.t) - 1, sim.plant.input_dim)


def test_pendulum_family_mujoco_scenarios_exist():
    assert {"pendulum_lqr_mujoco.toml", "cartpole_lqr_mujoco.toml", "double_pendulum_lqr_mujoco.toml"} <= set(
        MUJOCO_LQR
    )


def test_engine_override_switches_the_loop():
    sim = RobotSim.from_config("cartpole_lqr", engine="mujoco")
    assert sim.loop == "mujoco" and sim.engine is not None and sim.plant.engine is sim.engine
    res = sim.run(duration=0.5)
    assert res.loop == "mujoco" and res.config["engine"]["type"] == "mujoco"


def test_metrics_on_a_hand_made_trajectory():
    t = np.arange(6) * 0.5
    x = np.array([[1.0, 9], [0.5, 9], [0.2, 9], [0.05, 9], [0.0, 9], [0.0, 9]])
    ref = np.zeros_like(x)
    u = np.array([[3.0], [-4.0], [1.0], [0.0], [0.0]])
    m = compute_metrics(
        t,
        x,
        u,
        ref,
        tracked=[0],
        settle_tol=0.1,
        u_min=np.array([-3.5]),
        u_max=np.array([3.5]),
        solve_times=np.array([1.0, 2.0, 3.0, 4.0, 5.0]),
    )
    assert m["rms_error"] == pytest.approx(math.sqrt((1 + 0.25 + 0.04 + 0.0025) / 6))
    assert m["max_error"] == 1.0 and m["final_error"] == 0.0
    assert m["settling_time"] == 1.5  # last sample outside 0.1 is t = 1.0
    assert m["max_abs_input"] == 4.0
    assert m["constraint_violations"] == 1 and m["max_violation"] == pytest.approx(0.5, rel=1e-6)
    assert m["solve_time_median_s"] == 3.0


def test_never_settling_is_undefined():
    t = np.arange(3.0)
    x = np.ones((3, 1))
    m = compute_metrics(t, x, np.zeros((2, 1)), np.zeros((3, 1)), tracked=[0])
    assert m["settling_time"] is None


def test_measured_lqr_cost_matches_prediction_small_angle():
    doc = {
        "plant": {"type": "CartPole", "dt": 0.005},
        # zoh: the design model closest to the plant's semi-implicit step (euler is ~4 % off at this dt)
        "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1], "discretization": "zoh"},
        "sim": {"duration": 12.0, "initial_state": [0.0, 0.0, 0.02, 0.0]},
    }
    sim = RobotSim.from_config(doc)
    res = sim.run()
    Q, R = sim.controller.Q, sim.controller.R
    x, u = res.x[:-1], res.u
    measured = 0.5 * (np.einsum("ki,ij,kj->", x, Q, x) + np.einsum("ki,ij,kj->", u, R, u))
    predicted = sim.controller.cost_to_go(res.x[0])
    assert measured == pytest.approx(predicted, rel=0.02)


@pytest.mark.parametrize(
    "spec,t,expected",
    [
        ({"kind": "constant", "value": [1.0, 2.0]}, 3.0, [1.0, 2.0]),
        ({"kind": "step", "time": 1.0, "final": [1.0, 0.0]}, 0.5, [0.0, 0.0]),
        ({"kind": "step", "time": 1.0, "final": [1.0, 0.0]}, 1.5, [1.0, 0.0]),
        ({"kind": "circle", "radius": 0.5, "frequency": 0.25}, 1.0, [-0.5, 0.5]),
        ({"kind": "square", "side": 1.0, "speed": 0.5}, 3.0, [1.0, 0.5]),
        ({"kind": "waypoints", "points": [[0, 0], [2, 2]], "times": [0, 2]}, 0.5, [0.5, 0.5]),
        ({"kind": "waypoints", "points": [[0, 0], [2, 2]], "times": [0, 2], "interpolation": "hold"}, 1.5, [0, 0]),
    ],
)
def test_reference_kinds(spec, t, expected):
    np.testing.assert_allclose(Reference(spec, np.zeros(2))(t), expected, atol=1e-12)


def test_reference_rate_matches_finite_difference():
    for spec in ({"kind": "circle", "radius": 0.3, "frequency": 0.7}, {"kind": "square", "side": 1.0, "speed": 0.2}):
        ref = Reference(spec, np.array([0.1, -0.2, 0.0]))
        for t in (0.3, 2.2, 7.1):
            fd = (ref(t + 1e-6) - ref(t - 1e-6)) / 2e-6
            np.testing.assert_allclose(ref.rate(t), fd, atol=1e-5)


def test_save_and_plot(tmp_path):
    res = RobotSim.from_config("pendulum_lqr").run(duration=0.5)
    out = res.save(tmp_path / "run")
    data = np.load(out / "result.npz")
    np.testing.assert_array_equal(data["x"], res.x)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["metrics"]["rms_error"] == pytest.approx(res.metrics["rms_error"])
    resolved = parse_scenario(__import__("tomllib").loads((out / "scenario.toml").read_text()))
    assert resolved.plant.type == "InvertedPendulum" and resolved.sim.duration == 0.5  # the duration actually run
    png = res.plot(tmp_path / "run.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_measurement_noise_is_seeded():
    doc = {
        "plant": {"type": "InvertedPendulum"},
        "controller": {"type": "LQR", "Q": [10, 1], "R": [0.1]},
        "sim": {"duration": 0.5, "initial_state": [0.1, 0.0], "measurement_noise": [0.01, 0.01], "seed": 7},
    }
    a, b = RobotSim.from_config(doc).run(), RobotSim.from_config(doc).run()
    np.testing.assert_array_equal(a.x, b.x)
    doc["sim"]["seed"] = 8
    assert not np.array_equal(a.x, RobotSim.from_config(doc).run().x)


def test_holonomic_square_tracking_in_mujoco():
    res = RobotSim.from_config("holonomic_mujoco").run()
    assert res.loop == "mujoco"
    assert res.metrics["rms_error"] < 0.02
    assert res.metrics["constraint_violations"] == 0
    # the path really is a 1 m square
    assert np.ptp(res.x[:, 0]) == pytest.approx(1.0, abs=0.02) and np.ptp(res.x[:, 1]) == pytest.approx(1.0, abs=0.02)


def test_lqr_feedforward_matters_on_a_moving_reference():
    doc = RobotSim.from_config("holonomic_mujoco").scenario.raw
    doc = {k: dict(v) for k, v in doc.items() if k != "engine"}
    with_ff = RobotSim.from_config(doc).run(duration=5.0).metrics["rms_error"]
    doc["controller"]["feedforward"] = False
    without = RobotSim.from_config(doc).run(duration=5.0).metrics["rms_error"]
    assert with_ff < 1e-6 < 1e-3 < without


@pytest.mark.parametrize("name", ["quadrotor_lqr", "quadrotor_lqr_mujoco"])
def test_quadrotor_hover_recovers(name):
    res = RobotSim.from_config(name).run()
    assert res.metrics["final_error"] < 1e-2 and res.metrics["settling_time"] < 6.0


def test_absurd_duration_is_refused_before_allocating():
    from shinro_ctrl.errors import InvalidArgument

    with pytest.raises(InvalidArgument, match="limited to"):
        RobotSim.from_config("pendulum_lqr").run(duration=1e9)


def test_saved_config_records_the_duration_actually_run(tmp_path):
    res = RobotSim.from_config("pendulum_lqr").run(duration=0.3)
    assert res.config["sim"]["duration"] == 0.3
