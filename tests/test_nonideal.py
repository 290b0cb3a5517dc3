"""Non-ideal actuators and sensors: each stage against a hand computation, the loop in both engines replayed by
hand, allocation-free steps, and bad input refused in one line."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.config import parse_scenario
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.sim import RobotSim
from shinro_ctrl.sim.nonideal import ActuatorModel, SensorModel


def _drive(model, commands, u0=0.0):
    model.reset(np.atleast_1d(np.asarray(u0, dtype=float)))
    return [model(np.atleast_1d(np.asarray(c, dtype=float))).copy() for c in commands]


def test_delay_is_a_fifo_of_whole_steps_that_starts_full_of_the_operating_input():
    act = ActuatorModel(1, 0.1, delay=0.2)
    assert act.delay_steps.tolist() == [2]
    assert np.concatenate(_drive(act, [1, 2, 3, 4], u0=0.5)).tolist() == [0.5, 0.5, 1.0, 2.0]


def test_rate_limit_moves_at_most_r_dt_per_step():
    act = ActuatorModel(1, 0.1, rate_limit=1.0)  # 0.1 per step
    out = np.concatenate(_drive(act, [1.0, 1.0, -1.0, 0.25]))
    assert out == pytest.approx([0.1, 0.2, 0.1, 0.2], abs=1e-15)


def test_quantization_rounds_to_the_nearest_multiple():
    act = ActuatorModel(1, 0.1, quantization=0.5)
    assert np.concatenate(_drive(act, [0.2, 0.3, -0.74, 1.26])).tolist() == [0.0, 0.5, -0.5, 1.5]


def test_lag_gives_the_exact_mean_of_the_first_order_response_over_each_step():
    """Reference: the ODE u̇ = (c − u)/τ integrated with 20,000 small Euler steps per step, averaged."""
    tau, dt, commands = 0.07, 0.1, [1.0, 1.0, -0.5, 2.0]
    act = ActuatorModel(1, dt, lag=tau)
    out = np.concatenate(_drive(act, commands, u0=0.3))
    h, u, ref = dt / 20_000, 0.3, []
    for c in commands:
        total = 0.0
        for _ in range(20_000):
            total += u + 0.5 * h * (c - u) / tau  # midpoint of the small step: the mean to O(h²)
            u += h * (c - u) / tau
        ref.append(total / 20_000)
    assert out == pytest.approx(ref, abs=2e-5)
    # and by hand for τ = dt: α = e^{−1}, β = 1 − e^{−1}; from 0 a unit step gives α, then 1 − αβ
    a, b = math.exp(-1.0), 1.0 - math.exp(-1.0)
    out = np.concatenate(_drive(ActuatorModel(1, 0.1, lag=0.1), [1.0, 1.0, 0.0]))
    assert out == pytest.approx([a, 1 - a * b, (1 - a * a) * b], rel=1e-14)


def test_stages_run_delay_rate_limit_quantization_in_that_order_with_an_unquantized_ramp():
    act = ActuatorModel(1, 0.1, delay=0.1, rate_limit=2.0, quantization=0.25)
    # delayed [0, 1, 1, 1]; ramp w = [0, 0.2, 0.4, 0.6]; quantized [0, 0.25, 0.5, 0.5] (0.6 → 0.5, not 0.75)
    assert np.concatenate(_drive(act, [1, 1, 1, 0])).tolist() == [0.0, 0.25, 0.5, 0.5]


def test_per_input_values_and_reset():
    act = ActuatorModel(2, 0.1, delay=[0.1, 0.0], quantization=[0.0, 0.5])
    first = _drive(act, [[1.0, 0.3], [2.0, 0.8]], u0=[9.0, 9.0])
    assert np.array(first).tolist() == [[9.0, 0.5], [1.0, 1.0]]
    assert np.array(_drive(act, [[1.0, 0.3], [2.0, 0.8]], u0=[9.0, 9.0])).tolist() == np.array(first).tolist()


def test_sensor_quantizes_then_delays_and_repeats_its_first_reading():
    sen = SensorModel(2, 0.1, delay=[0.2, 0.0], quantization=[0.1, 0.0])
    sen.reset()
    out = [sen(np.array(y)).copy() for y in [[0.12, 1.0], [0.26, 2.0], [0.33, 3.0], [0.44, 4.0]]]
    assert np.array(out) == pytest.approx(np.array([[0.1, 1.0], [0.1, 2.0], [0.1, 3.0], [0.3, 4.0]]), abs=1e-15)
    sub = SensorModel.from_table({"delay": [0.0, 0.1, 0.2], "quantization": [1.0, 2.0, 3.0]}, 3, 0.1, [2, 0])
    assert sub.delay_steps.tolist() == [2, 0] and sub.quantization.tolist() == [3.0, 1.0]


def _step_peak_bytes(m: int) -> int:
    """Peak memory traced while stepping an actuator and a sensor of ``m`` channels (every stage on) 20 times."""
    act = ActuatorModel(m, 0.01, delay=np.arange(m) % 3 * 0.01, lag=0.02, quantization=1e-3, rate_limit=5.0)
    sen = SensorModel(m, 0.01, delay=0.02, quantization=np.arange(m) % 2 * 1e-3)
    u = np.linspace(-1, 1, m)
    act.reset(np.zeros(m))
    sen.reset()
    for _ in range(5):
        act(u), sen(u)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        for _ in range(20):
            act(u)
            sen(u)
        return tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()


def test_a_step_allocates_no_array_of_the_channel_size():
    """A temporary of the channel size would add 8 bytes per channel to the peak: 8 × 15,000 bytes here."""
    small, large = _step_peak_bytes(1_000), _step_peak_bytes(16_000)
    assert large - small < 8_000, (small, large)


# ------------------------------------------------------------ in the loop, both engines
PENDULUM = {
    "plant": {"type": "InvertedPendulum", "mass": 0.1, "length": 0.5, "damping": 0.01, "dt": 0.01},
    "controller": {"type": "LQR", "Q": [10, 1], "R": [0.1]},
    "sim": {"duration": 0.5, "initial_state": [0.2, 0.0]},
}
ACTUATOR = {"delay": 0.01, "lag": 0.03, "quantization": 0.002, "rate_limit": 1.5}
SENSOR = {"delay": 0.01, "quantization": [1e-3, 0.0]}


def _scenario(loop: str, **sim) -> dict:
    doc = {k: dict(v) for k, v in PENDULUM.items()}
    doc["sim"].update(sim)
    if loop == "mujoco":
        doc["engine"] = {"type": "mujoco"}
    return doc


def _applied_by_hand(commands: np.ndarray, dt: float) -> list[float]:
    """The documented pipeline for one input from rest at u0 = 0, written out as scalar arithmetic."""
    d, tau, q, r = round(ACTUATOR["delay"] / dt), ACTUATOR["lag"], ACTUATOR["quantization"], ACTUATOR["rate_limit"]
    w = a = 0.0
    out = []
    for k in range(len(commands)):
        v = commands[k - d] if k >= d else 0.0
        w = w + min(max(v - w, -r * dt), r * dt)
        s = q * round(w / q)
        mean = s + (a - s) * tau / dt * (1 - math.exp(-dt / tau))
        a = s + (a - s) * math.exp(-dt / tau)
        out.append(mean)
    return out


@pytest.mark.parametrize("loop", ["standalone", "mujoco"])
def test_the_loop_feeds_the_plant_the_modelled_input_and_the_estimator_the_modelled_reading(loop):
    sim = RobotSim.from_config(_scenario(loop, actuator=ACTUATOR, sensor=SENSOR))
    assert sim.loop == loop and sim.actuator is not None and sim.sensor is not None
    res = sim.run()
    applied = _applied_by_hand(res.u[:, 0], sim.plant.dt)
    assert max(abs(np.diff(applied))) > 0  # the inputs move: something is being checked
    # replay the hand-computed inputs open loop on a fresh plant of the same loop: the same states
    fresh = RobotSim.from_config(_scenario(loop)).plant
    fresh.set_state(res.x[0])
    replay = np.array([res.x[0], *(fresh.step(np.array([u])) for u in applied)])
    np.testing.assert_allclose(replay, res.x, rtol=0, atol=1e-12)
    # the reading one step late, the angle on a 1 mrad grid
    seen = np.vstack([res.x[:1], res.x[:-1]])
    seen[:, 0] = 1e-3 * np.round(seen[:, 0] / 1e-3)
    np.testing.assert_allclose(res.y, seen, rtol=0, atol=1e-15)
    # reset with the run: a second run is the same run; the resolved config carries the tables and reruns
    again = sim.run()
    np.testing.assert_array_equal(again.x, res.x)
    assert res.config["sim"]["actuator"] == ACTUATOR and res.config["sim"]["sensor"] == SENSOR
    np.testing.assert_array_equal(RobotSim.from_config(res.config).run().x, res.x)


def test_ideal_scenarios_hold_no_models():
    sim = RobotSim.from_config(_scenario("standalone"))
    assert sim.actuator is None and sim.sensor is None


# ------------------------------------------------------------ bad input: one line each
@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("actuator", {"lag": -0.1}, "'lag' must be >= 0"),
        ("actuator", {"quantization": float("nan")}, "'quantization' must not be NaN"),
        ("actuator", {"delay": 0.015}, "not a whole number of steps of dt = 0.01 s (1.5 steps): use 0.01 s or 0.02 s"),
        ("actuator", {"delay": -0.01}, "'delay' must be >= 0"),
        ("actuator", {"delay": float("inf")}, "'delay' must be finite"),
        ("actuator", {"rate_limit": 0.0}, "'rate_limit' must be > 0 (inf: none)"),
        ("actuator", {"delay": 1e308}, "is inf steps of dt = 0.01 s; the limit is 100,000"),
        ("actuator", {"quantization": 1e-320}, "must be 0 (none) or >= 1e-100"),
        ("actuator", {"delya": 0.01}, "unknown key 'delya'; did you mean 'delay'?"),
        ("actuator", {"lag": [0.1, 0.2]}, "a list of 1 (one per input), got 2 values"),
        ("actuator", {"lag": "0.1"}, "'lag' must be a number"),
        ("actuator", 0.02, "must be a table"),
        ("sensor", {"lag": 0.1}, "unknown key 'lag'"),
        ("sensor", {"quantization": [0.1, 0.2, 0.3]}, "a list of 2 (one per state), got 3 values"),
    ],
)
def test_bad_values_are_one_line_naming_the_key(key, value, message):
    with pytest.raises(ConfigError) as err:
        parse_scenario(_scenario("standalone", **{key: value}))
    text = str(err.value)
    assert "\n" not in text and "[sim]" in text and message in text


def test_the_python_api_refuses_the_same_values():
    with pytest.raises(InvalidArgument, match="whole number of steps"):
        ActuatorModel(1, 0.01, delay=0.005)
    with pytest.raises(InvalidArgument, match="'quantization' must be >= 0"):
        SensorModel(2, 0.01, quantization=[0.1, -1.0])


def test_the_cli_says_one_line_and_exits_2(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(
        '[plant]\ntype = "InvertedPendulum"\n[controller]\ntype = "LQR"\nQ = [10, 1]\nR = [0.1]\n'
        "[sim]\nactuator = { delay = 0.013 }\n"
    )
    assert main(["run", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'delay' = 0.013 s is not a whole number of steps" in err


def test_sweeps_give_each_run_its_own_models_and_the_batch_rollout_declines():
    from shinro_ctrl.sweep.executors import batch_reason

    sim = RobotSim.from_config(_scenario("standalone", actuator={"delay": 0.01}))
    other = sim.with_plant({"mass": 0.12})
    assert other.actuator is not sim.actuator and other.actuator.delay_steps.tolist() == [1]
    assert "non-ideal actuator" in batch_reason(sim, ["mass"])


def test_sensor_values_per_state_apply_to_the_measured_outputs_in_their_order():
    """The LQG cart-pole measures [theta, x] (reordered): the reading the filter gets is the noisy measurement on
    each state's own grid (x: 1 mm, theta: 10 mrad), one step late."""
    doc = {
        "plant": {"type": "CartPole", "dt": 0.01},
        "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]},
        "estimator": {"type": "KalmanFilter"},
        "sim": {
            "duration": 0.3,
            "initial_state": [0.0, 0.0, 0.1, 0.0],
            "measured": ["theta", "x"],
            "sensor_noise": [0.002, 0.002],
            "seed": 3,
            "sensor": {"delay": 0.01, "quantization": [1e-3, 0.0, 1e-2, 0.0]},
        },
    }
    res = RobotSim.from_config(doc).run()
    assert res.measured == ("theta", "x")
    for j, q in enumerate([1e-2, 1e-3]):
        np.testing.assert_allclose(res.y[:, j], q * np.round(res.y[:, j] / q), rtol=0, atol=1e-12)
    assert np.array_equal(res.y[0], res.y[1])  # the first reading, repeated until the next one arrives
    assert not np.array_equal(res.y[1], res.y[2])
    # the reading is the state a step back, within half a quantum plus the sensor noise (σ = 2 mm / 2 mrad)
    assert np.max(np.abs(res.y[2:, 0] - res.x[1:-1, 2])) < 5e-3 + 5 * 0.002


def test_an_estimator_assigned_before_the_run_gets_the_sensor_on_its_own_outputs():
    from shinro_ctrl.estimators import KalmanFilter

    sim = RobotSim.from_config(_scenario("standalone", sensor={"quantization": [1e-2, 0.0]}))
    sim.estimator = KalmanFilter.from_plant(sim.plant, Qn=[1e-4], Rn=[1e-6], measured=["theta"])
    res = sim.run(0.1)
    assert res.y.shape[1] == 1 and sim.sensor.states == (0,)
    np.testing.assert_allclose(res.y[:, 0], 1e-2 * np.round(res.x[:, 0] / 1e-2), rtol=0, atol=1e-15)
