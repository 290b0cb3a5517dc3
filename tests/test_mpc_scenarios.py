"""MPC scenarios in both loops: hard bounds held at every step, soft bounds reported, preview used."""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import CartPole
from shinro_ctrl.sim import RobotSim

from .test_mpc import soft_bound_scenario

MPC_SCENARIOS = ["cartpole_mpc", "cartpole_mpc_mujoco", "pendulum_mpc_mujoco", "double_pendulum_mpc_mujoco"]


@pytest.mark.parametrize("name", MPC_SCENARIOS)
def test_mpc_scenarios_hold_hard_bounds_and_stabilize(name):
    sim = RobotSim.from_config(name)
    res = sim.run()
    ctrl = sim.controller
    assert res.loop == ("mujoco" if name.endswith("mujoco") else "standalone")
    assert np.all(res.u >= ctrl.u_min) and np.all(res.u <= ctrl.u_max)  # exactly, every step
    assert res.metrics["constraint_violations"] == 0
    assert np.isclose(np.abs(res.u).max(), np.abs(ctrl.u_max).max(), rtol=1e-3)  # an input bound was active
    assert res.metrics["final_error"] < 0.02


def test_quadrotor_mpc_thrust_bound_binds_and_holds():
    sim = RobotSim.from_config("quadrotor_mpc_mujoco")
    res = sim.run()
    plant = sim.plant
    assert res.loop == "mujoco"
    T = res.u[:, 0]
    top = 2.0 * plant.params()["mass"] * plant.params()["gravity"]
    assert sim.controller.u_min[0] == 0.0 and sim.controller.u_max[0] == top  # the scenario's bound is 2 m g
    assert np.all(T >= 0.0) and np.all(T <= top)  # exactly, at every step
    assert np.all(np.abs(res.u[:, 1:]) <= sim.controller.u_max[1:])
    at_top = np.isclose(T, top, rtol=1e-3, atol=0.0)
    at_zero = np.abs(T) <= 1e-3 * top
    assert at_top.any() or at_zero.any()  # a thrust bound is reached during the step
    assert at_top.sum() >= 5  # for more than a marginal instant
    assert res.metrics["constraint_violations"] == 0
    settle_tol = sim.scenario.sim.settle_tol
    assert res.metrics["settling_time"] < 3.0 and res.metrics["final_error"] < settle_tol


def test_cartpole_state_bound_tight_but_held_in_both_loops():
    peaks = [np.abs(RobotSim.from_config(n).run().x[:, 0]).max() for n in ("cartpole_mpc", "cartpole_mpc_mujoco")]
    assert all(0.45 < p <= 0.6 + 1e-6 for p in peaks)


@pytest.mark.parametrize("loop", ["standalone", "mujoco"])
def test_soft_state_bound_is_held_near_the_bound(loop):
    plant = CartPole(dt=0.02)
    if loop == "mujoco":
        plant.physics_engine(MujocoEngine.for_plant(plant))
    out = soft_bound_scenario(plant)
    assert out["max_slack"] > 0  # the bound really became active
    assert out["violation"] < 0.02  # held near |x| <= 0.3 m
    assert np.abs(out["X"][-1]).max() < 0.05  # and stabilized


def test_mpc_previews_a_step_reference():
    doc = {
        "plant": {"type": "CartPole", "dt": 0.02},
        "controller": {
            "type": "LinearMPC",
            "horizon": 30,
            "Q": [10, 1, 100, 1],
            "R": [0.1],
            "u_min": [-5],
            "u_max": [5],
        },
        "sim": {"duration": 2.0, "reference": {"kind": "step", "time": 1.0, "final": [0.3, 0, 0, 0]}},
    }
    res = RobotSim.from_config(doc).run()
    before = res.t < 1.0
    # with preview the cart starts moving (away first, the non-minimum-phase way) before the step
    assert np.abs(res.u[before[:-1]]).max() > 0.05


def test_reset_makes_runs_repeat_exactly():
    sim = RobotSim.from_config("cartpole_mpc")
    a = sim.run(duration=2.0)
    b = sim.run(duration=2.0)  # run() resets the controller: OSQP's adaptive state must not leak
    np.testing.assert_array_equal(a.u, b.u)


def test_osqp_settings_come_from_the_scenario():
    from shinro_ctrl.errors import ShinroError

    doc = {
        "plant": {"type": "CartPole", "dt": 0.02},
        "controller": {
            "type": "LinearMPC",
            "horizon": 20,
            "Q": [10, 1, 100, 1],
            "R": [0.1],
            "osqp_settings": {"eps_abs": 1e-6, "eps_rel": 1e-6, "max_iter": 2000, "polishing": True},
        },
        "sim": {"duration": 0.2, "initial_state": [0, 0, 0.1, 0]},
    }
    sim = RobotSim.from_config(doc)
    assert sim.controller.osqp_settings["eps_abs"] == 1e-6 and sim.controller.osqp_settings["polishing"] is True
    sim.run()
    doc["controller"]["osqp_settings"] = {"eps_absolute": 1e-6}
    with pytest.raises(ShinroError, match="did you mean 'eps_abs'"):
        RobotSim.from_config(doc)
