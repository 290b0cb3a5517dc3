"""TVLQR: gains against an independent Riccati recursion, Jacobians against complex step, swing-ups in both loops."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from shinro_ctrl.controllers import LQR, controller_class
from shinro_ctrl.controllers.tvlqr import TVLQR, trajectory_jacobians
from shinro_ctrl.errors import ConcurrentUse, InvalidArgument
from shinro_ctrl.linearization import complex_step_jacobians, discretize
from shinro_ctrl.planning import TrajectoryOptimizer
from shinro_ctrl.plants import CartPole, DoublePendulum
from shinro_ctrl.sim import RobotSim

from .thread_helpers import BlockingArray

INF = np.inf
Q = np.array([10.0, 1.0, 10.0, 1.0])
R = np.array([0.1])


@pytest.fixture(scope="module")
def plant() -> CartPole:
    return CartPole()


@pytest.fixture(scope="module")
def plan(plant):
    opt = TrajectoryOptimizer(
        plant,
        knots=41,
        method="hermite_simpson",
        u_min=[-5],
        u_max=[5],
        x_min=[-1, -INF, -INF, -INF],
        x_max=[1, INF, INF, INF],
    )
    return opt.solve([0, 0, np.pi, 0], np.zeros(4), duration=(0.5, 5.0), cost={"time": 1, "effort": 10}, u_goal=[0.0])


@pytest.fixture(scope="module")
def tvlqr(plant, plan):
    return TVLQR.from_trajectory(plant, plan, Q, R)


def _riccati_reference(A, B, Qm, Rm, Qf):
    """Textbook form, written independently: P = Q + AᵀPA − AᵀPB (R + BᵀPB)⁻¹ BᵀPA, K = (R + BᵀPB)⁻¹ BᵀPA."""
    P = Qf.copy()
    gains = [None] * len(A)
    for k in reversed(range(len(A))):
        a, b = A[k], B[k]
        inv = np.linalg.inv(Rm + b.T @ P @ b)
        gains[k] = inv @ b.T @ P @ a
        P = Qm + a.T @ P @ a - a.T @ P @ b @ inv @ b.T @ P @ a
    return np.array(gains), P


def test_gains_equal_an_independent_riccati_recursion(tvlqr):
    gains, P0 = _riccati_reference(tvlqr.A, tvlqr.B, np.diag(Q), np.diag(R), tvlqr.Qf)
    scale = np.abs(gains).max()
    assert np.abs(tvlqr.K - gains).max() <= 1e-9 * scale
    np.testing.assert_allclose(tvlqr.S[0], P0, rtol=1e-9, atol=1e-9 * np.abs(P0).max())


def test_terminal_weight_defaults_to_the_goal_lqr_cost_to_go(plant, tvlqr):
    lqr = LQR.from_plant(plant, Q, R, x0=np.zeros(4), u0=[0.0])
    np.testing.assert_allclose(tvlqr.Qf, lqr.S, rtol=1e-12)
    np.testing.assert_allclose(tvlqr.final.K, lqr.K, rtol=1e-12)
    # with Qf = S the recursion is stationary at the goal: the last gain is the LQR gain
    np.testing.assert_allclose(tvlqr.K[-1], lqr.K, rtol=1e-3, atol=1e-3 * np.abs(lqr.K).max())


def test_jacobians_equal_complex_step_at_random_knots(plant, tvlqr, rng):
    for k in rng.choice(tvlqr.horizon, size=6, replace=False):
        A_cs, B_cs = complex_step_jacobians(plant, tvlqr.x_ref[k], tvlqr.u_ref[k])
        np.testing.assert_allclose(tvlqr.A_c[k], A_cs, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(tvlqr.B_c[k], B_cs, rtol=1e-12, atol=1e-12)
        # the default model is the plant's semi-implicit Euler step: v⁺ = v + dt f_v, q⁺ = q + dt v⁺
        dt, q, v = plant.dt, list(plant.position_indices), list(plant.velocity_indices)
        A_d, B_d = np.eye(plant.state_dim), np.zeros_like(B_cs)
        A_d[v] += dt * A_cs[v]
        B_d[v] = dt * B_cs[v]
        A_d[q] += dt * A_d[v]
        B_d[q] = dt * B_d[v]
        np.testing.assert_allclose(tvlqr.A[k], A_d, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(tvlqr.B[k], B_d, rtol=1e-12, atol=1e-12)


def test_reference_samples_the_plan_at_the_control_rate(plant, plan, tvlqr):
    assert tvlqr.horizon == int(np.ceil(plan.duration / plant.dt - 1e-9))
    ts = plant.dt * np.arange(tvlqr.horizon)
    np.testing.assert_allclose(tvlqr.x_ref, plan.x_at(ts), atol=1e-14)
    np.testing.assert_allclose(tvlqr.u_ref, plan.u_at(ts), atol=1e-14)


def test_zoh_discretization_and_a_double_pendulum(rng):
    dp = DoublePendulum()
    opt = TrajectoryOptimizer(dp, knots=31, method="trapezoid", u_min=[-1.5, -1.5], u_max=[1.5, 1.5])
    traj = opt.solve(
        np.zeros(4), [np.pi, np.pi, 0, 0], duration=(0.5, 4.0), cost={"time": 1, "effort": 1}, u_goal=[0, 0]
    )
    ctrl = TVLQR.from_trajectory(dp, traj, [100, 100, 1, 1], [1, 1], discretization="zoh")
    k = int(rng.integers(ctrl.horizon))
    A_cs, B_cs = complex_step_jacobians(dp, ctrl.x_ref[k], ctrl.u_ref[k])
    A_d, B_d = discretize(A_cs, B_cs, dp.dt, "zoh")
    np.testing.assert_allclose(ctrl.A[k], A_d, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ctrl.B[k], B_d, rtol=1e-10, atol=1e-12)
    A_map, _ = trajectory_jacobians(dp, ctrl.x_ref[[k, 0]], ctrl.u_ref[[k, 0]])
    np.testing.assert_allclose(A_map[0], A_cs, rtol=1e-12, atol=1e-12)


def test_step_counter_time_and_hand_over(plant, tvlqr):
    x = np.array([0.01, 0.0, np.pi - 0.02, 0.1])
    tvlqr.reset()
    u0 = tvlqr(x)
    np.testing.assert_allclose(u0, tvlqr.u_ref[0] - tvlqr.K[0] @ (x - tvlqr.x_ref[0]))
    assert tvlqr.step == 1
    np.testing.assert_allclose(tvlqr(x), tvlqr.at_time(plant.dt, x))
    tvlqr.reset()
    assert tvlqr.step == 0
    np.testing.assert_array_equal(tvlqr(x), u0)
    y = np.array([0.01, 0.0, 0.02, 0.0])
    np.testing.assert_allclose(tvlqr.at_time(10.0, y), tvlqr.final(y))  # after the plan: the goal LQR
    far = [tvlqr.at_time(t, 10 * x) for t in (0.0, 0.5, 1.0, 10.0)]
    assert np.abs(far).max() > 5.0
    saturated = TVLQR.from_trajectory(plant, tvlqr.trajectory, Q, R, u_min=[-5], u_max=[5])
    np.testing.assert_array_equal([saturated.at_time(t, 10 * x) for t in (0.0, 0.5, 1.0, 10.0)], np.clip(far, -5, 5))


def test_registered_and_bad_arguments(plant, plan):
    assert controller_class("TVLQR") is TVLQR
    with pytest.raises(InvalidArgument, match="expected a trajectory with 2 states"):
        TVLQR.from_trajectory(InvertedPendulumLike(), plan, [1, 1], [1])
    with pytest.raises(InvalidArgument, match="plan"):
        TVLQR.from_plant(plant, Q, R)
    with pytest.raises(InvalidArgument, match="discretization"):
        TVLQR.from_trajectory(plant, plan, Q, R, discretization="tustin")


class InvertedPendulumLike:
    state_dim, input_dim = 2, 1


# ------------------------------------------------------------- closed loops
@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_cartpole_swingup_ends_upright(engine):
    sim = RobotSim.from_config("cartpole_swingup_mujoco", engine=engine)
    res = sim.run(duration=sim.controller.trajectory.duration + 2.0)
    after = res.t >= sim.controller.horizon * sim.plant.dt + 1.0  # a second after the hand-over
    assert np.all(np.abs(res.x[after, 2]) < 0.02)
    assert np.all(np.abs(res.x[after, 0]) < 0.05)
    assert np.all(np.abs(res.u) <= 5.0)
    assert res.metrics["constraint_violations"] == 0


@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_double_pendulum_swingup_ends_upright(engine):
    sim = RobotSim.from_config("double_pendulum_swingup_mujoco", engine=engine)
    res = sim.run(duration=sim.controller.trajectory.duration + 1.5)
    np.testing.assert_allclose(res.x[0], [0, 0, 0, 0], atol=1e-12)
    assert abs(res.x[-1, 0] - np.pi) < 0.05
    assert abs(res.x[-1, 1] - np.pi) < 0.05
    assert np.all(np.abs(res.u) <= 1.5)


def test_quadrotor_point_to_point_in_mujoco_under_two_seconds_with_the_thrust_bound_active():
    sim = RobotSim.from_config("quadrotor_point_to_point_mujoco")
    traj = sim.controller.trajectory
    assert traj.duration < 2.0
    res = sim.run(duration=2.0)
    two_mg = 2 * sim.plant.m * 9.81
    assert np.all(res.u[:, 0] >= 0.0) and np.all(res.u[:, 0] <= two_mg)
    assert np.isclose(res.u[:, 0].max(), two_mg)  # the bound is reached, never exceeded
    np.testing.assert_allclose(res.x[-1, :3], [3.0, 0.0, 1.0], atol=0.05)


def test_threads_at_time_is_correct_and_a_concurrent_call_is_refused(plant, tvlqr, rng):
    """Thread policy: 4 threads x 1,000 at_time calls on one object equal a serial run; __call__ detects reentry."""
    samples = [
        [
            (float(t), x)
            for t, x in zip(
                rng.uniform(0, 1.2 * tvlqr.trajectory.duration, 1000), rng.normal(size=(1000, 4)), strict=True
            )
        ]
        for _ in range(4)
    ]
    serial = [[tvlqr.at_time(t, x) for t, x in jobs] for jobs in samples]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(lambda jobs: [tvlqr.at_time(t, x) for t, x in jobs], samples))
    for a, b in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(np.array(a), np.array(b))

    tvlqr.reset()
    x = np.array([0.1, 0.0, np.pi - 0.1, 0.0])
    blocker = BlockingArray(x)
    with ThreadPoolExecutor(1) as pool:
        first = pool.submit(tvlqr, blocker)
        assert blocker.entered.wait(60)
        with pytest.raises(ConcurrentUse, match="another thread"):
            tvlqr(x)
        blocker.release.set()
        u = first.result(timeout=60)
    np.testing.assert_array_equal(u, tvlqr.at_time(0.0, x))  # the held call went on as step 0
    assert tvlqr.step == 1  # the refused call did not advance the counter
    tvlqr.reset()


def test_a_tvlqr_run_plots_its_plan_as_the_reference_and_reports_plan_tracking_rms():
    """Issue 23 §5: the run's reference line follows the plan over its span; plan_tracking_rms measures x − x_plan."""
    from shinro_ctrl.plots import run_figure

    sim = RobotSim.from_config("cartpole_swingup_mujoco", engine="standalone")
    traj = sim.controller.trajectory
    res = sim.run(duration=traj.duration + 1.0)
    inside = res.t <= traj.duration
    assert inside.sum() >= 10 and not inside.all()
    # the plan, sampled independently from the trajectory's own interpolation
    x_plan = traj.x_at(traj.t[0] + res.t[inside])
    np.testing.assert_allclose(res.plan[inside], x_plan, rtol=0, atol=1e-12)
    assert np.all(np.isnan(res.plan[~inside]))
    tracked = [res.state_names.index(s) for s in res.tracked]
    err = res.x[inside][:, tracked] - x_plan[:, tracked]
    expected = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert res.metrics["plan_tracking_rms"] == pytest.approx(expected, rel=1e-12)
    assert 0 < res.metrics["plan_tracking_rms"] < 0.2 < res.metrics["rms_error"]  # it tracks the plan, not the goal
    fig = run_figure(res)
    theta = res.state_names.index("theta")
    lines = [ln for ax in fig.axes for ln in ax.get_lines() if ln.get_label() == "reference"]
    ys = [ln.get_ydata() for ln in lines if len(ln.get_ydata()) == len(res.t)]
    assert any(
        np.allclose(y[inside], x_plan[:, theta]) and np.allclose(y[~inside], res.ref[~inside, theta]) for y in ys
    )
