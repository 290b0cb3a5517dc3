"""NonlinearMPC: RTI vs LinearMPC, SQP vs IPOPT, exact stage Jacobians, swing-ups in both loops, failures."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from shinro_ctrl.backend import NumpyBackend
from shinro_ctrl.controllers.mpc import LinearMPC
from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.errors import ConcurrentUse, InvalidArgument, MPCInfeasible, NonFiniteError
from shinro_ctrl.plants import CartPole, Quadrotor
from shinro_ctrl.sim import RobotSim

from .thread_helpers import BlockingArray

Q_CP = [1e3, 1e-2, 1e3, 1e-2]
R_CP = [1e-2]
X_BOUND = ([-2.0, -np.inf, -np.inf, -np.inf], [2.0, np.inf, np.inf, np.inf])


def cartpole() -> CartPole:
    return CartPole(cart_mass=1.0, pole_mass=0.1, pole_length=0.8, dt=0.05)


def complex_step_rk4_jacobians(plant, x, u, h):
    """``∂F/∂x``, ``∂F/∂u`` of one RK4 step of ``plant._f`` (numpy, complex arithmetic), by complex step."""
    bk = NumpyBackend()
    p = plant._params

    def f(x_, u_):
        return np.asarray(plant.equations(bk, x_, u_, p))

    def F(x_, u_):
        k1 = f(x_, u_)
        k2 = f(x_ + 0.5 * h * k1, u_)
        k3 = f(x_ + 0.5 * h * k2, u_)
        k4 = f(x_ + h * k3, u_)
        return x_ + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

    eps = 1e-30
    n, m = x.size, u.size
    A = np.empty((n, n))
    B = np.empty((n, m))
    for j in range(n):
        dx = np.zeros(n, dtype=complex)
        dx[j] = 1j * eps
        A[:, j] = F(x + dx, u.astype(complex)).imag / eps
    for j in range(m):
        du = np.zeros(m, dtype=complex)
        du[j] = 1j * eps
        B[:, j] = F(x.astype(complex), u + du).imag / eps
    return F(x, u).real, A, B


@pytest.mark.parametrize("make", [cartpole, lambda: Quadrotor(dt=0.02)], ids=["cartpole", "quadrotor"])
def test_stage_jacobians_equal_complex_step(make):
    plant = make()
    n, m = plant.state_dim, plant.input_dim
    N = 6
    ctrl = NonlinearMPC.from_plant(plant, np.ones(n), np.ones(m), horizon=N, cold_start="sqp", init_iterations=1)
    rng = np.random.default_rng(3)
    x = plant.equilibrium()[0] + 0.3 * rng.standard_normal(n)
    ctrl(x)  # the call ends with the preparation for the next one: Jacobians at the shifted trajectory
    rti = ctrl.strategy
    X, U = rti.X.copy(), rti.U.copy()
    assert np.ptp(X, axis=0).max() > 1e-3  # a genuine trajectory, not one point
    for k in range(N):
        Fk, A, B = complex_step_rk4_jacobians(plant, X[k], U[k], ctrl.dt)
        np.testing.assert_allclose(rti.A[k], A, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(rti.B[k], B, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(rti.D[k], Fk - X[k + 1], rtol=1e-10, atol=1e-12)


def test_rti_near_upright_equals_linear_mpc_rk4():
    """Inactive bounds, near upright: RTI (converged over calls at one state) = LinearMPC on the RK4 model.

    At the upright equilibrium the Jacobians of the nonlinear RK4 step equal the RK4 discretization of
    the linearization (the drift vanishes there), and ``terminal_cost="lqr"`` is the same DARE terminal cost; the
    cart-pole's nonlinearity at upright is cubic, so at 1e-3 rad the two optima differ by ~1e-9.
    """
    plant = cartpole()
    kw = dict(horizon=40, u_min=-40.0, u_max=40.0)
    nmpc = NonlinearMPC.from_plant(plant, Q_CP, R_CP, terminal_cost="lqr", **kw)
    lmpc = LinearMPC.from_plant(
        plant, Q_CP, R_CP, discretization="rk4", terminal_cost="dare",
        osqp_settings={"eps_abs": 1e-12, "eps_rel": 1e-12, "polishing": True, "max_iter": 100000},
        **kw,
    )  # fmt: skip
    rng = np.random.default_rng(7)
    for _ in range(3):
        x = 1e-3 * rng.standard_normal(4)
        nmpc.reset()
        for _ in range(4):
            u_n = nmpc(x)
        u_l = lmpc(x)
        assert nmpc.last.qp_status == "solved"
        assert abs(u_l[0]) < 40.0  # the bound is inactive
        np.testing.assert_allclose(u_n, u_l, rtol=0, atol=1e-6)
        np.testing.assert_allclose(nmpc.last.inputs, lmpc.last.inputs, rtol=0, atol=1e-6)


def test_sqp_converges_to_the_ipopt_solution():
    plant = cartpole()
    kw = dict(horizon=40, u_min=-40.0, u_max=40.0, x_min=X_BOUND[0], x_max=X_BOUND[1])
    ipopt = NonlinearMPC.from_plant(plant, Q_CP, R_CP, solver="ipopt", tol=1e-10, **kw)
    sqp = NonlinearMPC.from_plant(
        plant, Q_CP, R_CP, iterations=200, cold_start="sqp", init_iterations=200, tol=1e-9, **kw
    )
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(4):
        x = rng.uniform(-1, 1, 4) * [0.1, 0.1, 0.05, 0.1]
        ipopt.reset()
        sqp.reset()
        u_i = ipopt(x)
        u_s = sqp(x)
        assert sqp.last.status == "solved" and sqp.last.kkt_residual < 1e-9
        np.testing.assert_allclose(u_s, u_i, rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(sqp.last.objective, ipopt.last.objective, rtol=1e-7)
        checked += abs(u_i[0]) < 40.0
    assert checked >= 2  # some first inputs are interior, not both at the same bound


def _run(name: str, engine: str):
    sim = RobotSim.from_config(name, engine=engine)
    return sim, sim.run()


@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_cartpole_swingup_both_loops(engine):
    sim, res = _run("cartpole_nmpc_swingup_mujoco", engine)
    X, U, t = res.x, res.u, res.t
    assert np.pi - 0.01 < X[0, 2] < np.pi + 0.01  # from hanging
    late = t >= 6.0
    assert np.all(np.abs(X[late, 2]) < 0.02) and np.all(np.abs(X[late, 0]) < 0.05)
    assert np.all(np.abs(U) <= 40.0)  # hard input bounds at every step
    assert np.max(np.abs(U)) == 40.0  # and they bind during the swing
    assert sim.controller.last.qp_status == "solved"


@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_quadrotor_recovery_both_loops(engine):
    sim, res = _run("quadrotor_nmpc_recovery_mujoco", engine)
    X, U, t = res.x, res.u, res.t
    assert abs(X[0, 3] - np.pi / 3) < 1e-9 and abs(X[0, 0] - 1.0) < 1e-9
    late = t >= 4.0
    assert np.all(np.linalg.norm(X[late, :3], axis=1) < 0.05)
    assert np.all(np.abs(X[late, 3:6]) < 0.05)
    c = sim.controller
    assert np.all(U >= c.u_min) and np.all(U <= c.u_max)
    assert np.any(U[:, 0] >= c.u_max[0] - 1e-9) and np.any(U[:, 0] <= c.u_min[0] + 1e-9)  # thrust bounds bind


@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_pendulum_pumping_swingup(engine):
    sim, res = _run("pendulum_nmpc_mujoco", engine)
    X, U, t = res.x, res.u, res.t
    plant = sim.plant
    assert np.max(np.abs(U)) <= 0.3 < plant.m * plant.g * plant.l  # too weak to lift the bob directly
    assert np.max(X[:, 0]) > np.pi  # it swings back past hanging first (pumping)
    assert np.all(np.abs(X[t >= 6.0, 0]) < 0.02)


def test_infeasible_hard_state_bound_raises():
    plant = cartpole()
    ctrl = NonlinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=20, u_min=-40.0, u_max=40.0,
        x_min=[-0.1, -np.inf, -np.inf, -np.inf], x_max=[0.1, np.inf, np.inf, np.inf], cold_start="sqp",
    )  # fmt: skip
    # 3 m/s toward a wall 0.05 m away: at 40 N the cart needs > 0.1 m to stop
    with pytest.raises(MPCInfeasible, match="infeasible"):
        ctrl(np.array([0.05, 3.0, 0.0, 0.0]))
    assert np.all(np.isnan(ctrl.last.u))
    ipopt = NonlinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=20, u_min=-40.0, u_max=40.0,
        x_min=[-0.1, -np.inf, -np.inf, -np.inf], x_max=[0.1, np.inf, np.inf, np.inf], solver="ipopt",
    )  # fmt: skip
    with pytest.raises(MPCInfeasible, match="ipopt"):
        ipopt(np.array([0.05, 3.0, 0.0, 0.0]))
    with pytest.raises(NonFiniteError):
        ctrl(np.array([0.0, np.nan, 0.0, 0.0]))


def test_hold_and_argument_errors():
    plant = cartpole()  # dt = 0.05
    fine = CartPole(cart_mass=1.0, pole_mass=0.1, pole_length=0.8, dt=0.025)
    ctrl = NonlinearMPC.from_plant(fine, Q_CP, R_CP, horizon=10, dt=0.05, u_min=-40.0, u_max=40.0)
    assert ctrl.hold == 2 and ctrl.dt == 0.05
    x = np.array([0.0, 0.0, 0.2, 0.0])
    u0 = ctrl(x)
    u1 = ctrl(x + 0.01)  # held
    u2 = ctrl(x + 0.01)  # re-planned
    assert np.array_equal(u0, u1) and not np.array_equal(u1, u2)
    with pytest.raises(InvalidArgument, match="whole multiple"):
        NonlinearMPC.from_plant(fine, Q_CP, R_CP, horizon=10, dt=0.06)
    with pytest.raises(InvalidArgument, match="solver"):
        NonlinearMPC.from_plant(plant, Q_CP, R_CP, horizon=10, solver="qpoases")
    with pytest.raises(InvalidArgument, match="terminal_cost"):
        NonlinearMPC.from_plant(plant, Q_CP, R_CP, horizon=10, terminal_cost="dare")


def test_sparse_osqp_path_matches_condensed_daqp():
    """The sparse multiple-shooting QP (OSQP, Ax updated in place) gives the condensed DAQP iterates."""
    kw = dict(horizon=40, u_min=-40.0, u_max=40.0, x_min=X_BOUND[0], x_max=X_BOUND[1], soft=True)
    runs = {}
    for solver in ("daqp", "osqp"):
        plant = cartpole()
        ctrl = NonlinearMPC.from_plant(plant, Q_CP, R_CP, solver=solver, **kw)
        plant.set_state([0.0, 0.0, np.pi, 0.0])
        X = [plant.get_state()]
        for _ in range(60):
            X.append(plant.step(ctrl(X[-1])))
        runs[solver] = np.array(X)
    assert np.max(np.abs(runs["osqp"][-1])) < 0.5  # well into the balancing phase
    np.testing.assert_allclose(runs["osqp"], runs["daqp"], rtol=0, atol=1e-5)
    # and its SQP converges to IPOPT's solution too
    x = np.array([0.05, 0.02, 0.03, -0.05])
    ipopt = NonlinearMPC.from_plant(cartpole(), Q_CP, R_CP, solver="ipopt", tol=1e-10, **kw)
    sqp = NonlinearMPC.from_plant(
        cartpole(), Q_CP, R_CP, solver="osqp", iterations=200, cold_start="sqp", init_iterations=200, tol=1e-7,
        osqp_settings={"eps_abs": 1e-10, "eps_rel": 1e-10}, **kw,
    )  # fmt: skip
    np.testing.assert_allclose(sqp(x), ipopt(x), rtol=1e-5)
    assert sqp.last.status == "solved"


FAR_OUTSIDE = {  # plant -> (Q, R, |u| bound, x_min, x_max, initial states far outside the bounds)
    "cartpole": (
        Q_CP, R_CP, 40.0, [-0.5, -1.0, -0.3, -np.inf], [0.5, 1.0, 0.3, np.inf],
        [[3.0, 0.0, 0.0, 0.0], [-4.0, -6.0, 1.0, 3.0], [0.45, 3.0, 0.0, 0.0], [0.0, 0.0, np.pi, 0.0]],
    ),
    "pendulum": ([10.0, 0.1], [1.0], 0.3, [-1.0, -2.0], [np.inf, 2.0], [[-3.0, 0.0], [0.0, 50.0], [-20.0, -100.0]]),
}  # fmt: skip


def _far_plant(name: str):
    if name == "cartpole":
        return cartpole()
    from shinro_ctrl.plants import InvertedPendulum

    return InvertedPendulum(mass=0.1, length=0.5, damping=0.01, dt=0.05)


@pytest.mark.parametrize("plant_name", sorted(FAR_OUTSIDE))
@pytest.mark.parametrize(
    ("solver", "cold_start"),
    [("daqp", "sqp"), ("daqp", "ipopt"), ("osqp", "sqp"), ("osqp", "ipopt"), ("ipopt", "ipopt")],
)
def test_soft_state_bounds_are_never_infeasible(plant_name, solver, cold_start):
    """Issue 23 §3: with soft = true no initial state, however far outside the state bounds, is infeasible.

    Every solver mode runs a closed loop from each far-away state; the hard-bounded twin of the first
    case raises (so the states really are outside what hard bounds allow), and the soft objective
    charges every violated stage (the slack of each row is its violation).
    """
    Q, R, umax, lo, hi, starts = FAR_OUTSIDE[plant_name]
    kw = dict(horizon=15, u_min=-umax, u_max=umax, x_min=lo, x_max=hi, solver=solver, cold_start=cold_start)
    ctrl = NonlinearMPC.from_plant(_far_plant(plant_name), Q, R, soft=True, **kw)
    for x_start in starts:
        plant = _far_plant(plant_name)
        plant.set_state(x_start)
        ctrl.reset()
        for _ in range(8):
            u = ctrl(plant.get_state())
            assert np.all(np.isfinite(u)) and np.all(np.abs(u) <= umax)
            assert not ctrl.last.message
            plant.step(u)
    hard = NonlinearMPC.from_plant(_far_plant(plant_name), Q, R, **kw)
    with pytest.raises(MPCInfeasible):
        hard(np.array(starts[0], dtype=float))


def test_soft_penalty_is_per_row():
    """The slack penalty is w1 Σ s + ½ w2 Σ s² over every violated (stage, component) row."""
    plant = cartpole()
    ctrl = NonlinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=4, x_min=[-1.0, -np.inf, -np.inf, -np.inf], x_max=[1.0, np.inf, np.inf, np.inf],
        soft=True, soft_weight_l1=3.0, soft_weight_quad=5.0,
    )  # fmt: skip
    X = np.zeros((5, 4))
    X[1:, 0] = [1.5, 0.5, -3.0, 2.0]  # violations 0.5, 0, 2, 1 (x_0 is never charged)
    X[0, 0] = 10.0
    U = np.zeros((4, 1))
    cost = 0.5 * sum(X[k] @ np.diag(Q_CP) @ X[k] for k in range(5))  # Q_f = Q, the target 0
    viol = np.array([0.5, 0.0, 2.0, 1.0])
    expected = cost + 3.0 * viol.sum() + 0.5 * 5.0 * viol @ viol
    np.testing.assert_allclose(ctrl.objective(X, U), expected, rtol=1e-12)


IPOPT_SCENARIO = """
[plant]
type = "CartPole"
cart_mass = 1.0
pole_mass = 0.1
pole_length = 0.8
dt = 0.05

[controller]
type = "NonlinearMPC"
horizon = 120
Q = [1e3, 1e-2, 1e3, 1e-2]
R = [1e-2]
u_min = [-40.0]
u_max = [40.0]
solver = "ipopt"

[sim]
duration = 8.0
initial_state = [0.0, 0.0, 3.141592653589793, 0.0]
"""


def test_ctrl_c_during_an_ipopt_solve_exits_130(tmp_path):
    """Issue 23 §4: SIGINT inside IPOPT reaches the CLI as KeyboardInterrupt (exit 130, no traceback).

    The scenario's first IPOPT solve (N = 120 from hanging) takes seconds and starts right after the
    CLI's "running ..." line, so the signal sent when that line arrives lands inside IPOPT. CasADi
    swallows the KeyboardInterrupt there: before the fix the run ended with 'NonIpopt_Exception_Thrown'
    (exit 2), or the interrupt was lost and the run went on to exit 0, or (when the signal was seen
    outside CasADi's callbacks) exit 130 — so this test caught the bug in about half of its runs.
    """
    import os
    import signal
    import subprocess
    import sys

    scenario = tmp_path / "ipopt_swingup.toml"
    scenario.write_text(IPOPT_SCENARIO)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "shinro_ctrl.cli", "run", str(scenario), "--plot", str(tmp_path / "run.png")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    watchdog = threading.Timer(300.0, proc.kill)  # bounds the wait should the child never print
    watchdog.start()
    try:
        line = proc.stdout.readline()
        assert line.startswith("running"), line
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        watchdog.cancel()
    assert proc.returncode == 130, (proc.returncode, err)
    assert "Traceback" not in err and "NonIpopt" not in err
    assert "interrupted" in err
    assert "rms_error" not in out  # the run did not finish


def _small_nmpc() -> NonlinearMPC:
    kw = dict(horizon=10, u_min=-40.0, u_max=40.0, x_min=X_BOUND[0], x_max=X_BOUND[1], soft=True)
    return NonlinearMPC.from_plant(cartpole(), Q_CP, R_CP, cold_start="sqp", **kw)


def _closed_loop(ctrl: NonlinearMPC, x0: np.ndarray, calls: int) -> np.ndarray:
    plant = cartpole()
    plant.set_state(x0)
    out = []
    for _ in range(calls):
        u = ctrl(plant.get_state())
        out.append(np.concatenate([u, ctrl.last.inputs.ravel()]))
        plant.step(u)
    return np.array(out)


def test_threads_one_controller_per_thread_equals_serial_and_sharing_is_refused():
    """Thread policy (ConcurrentUse): 4 threads x 1,000 calls, one controller each, equal the serial runs;
    a call entering a controller another thread is inside raises ConcurrentUse, and the held call is unharmed.
    """
    starts = [np.array([0.1 * i, 0.0, 0.2 - 0.05 * i, 0.0]) for i in range(4)]
    serial = [_closed_loop(_small_nmpc(), x0, 1000) for x0 in starts]
    ctrls = [_small_nmpc() for _ in starts]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(lambda c, x0: _closed_loop(c, x0, 1000), ctrls, starts))
    for a, b in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(a, b)

    shared = _small_nmpc()
    x = starts[1]
    blocker = BlockingArray(x)
    with ThreadPoolExecutor(1) as pool:
        first = pool.submit(shared, blocker)
        assert blocker.entered.wait(60)
        with pytest.raises(ConcurrentUse, match="another thread"):
            shared(x)
        with pytest.raises(ConcurrentUse):
            shared.feedback(x)
        with pytest.raises(ConcurrentUse):
            shared.prepare()
        blocker.release.set()
        u = first.result(timeout=60)
    np.testing.assert_array_equal(u, _small_nmpc()(x))  # the held call is the serial first call


def test_threads_hammering_one_controller_gives_answers_or_concurrent_use():
    """4 threads x 100 calls on one shared controller: each call returns a finite input or raises ConcurrentUse."""
    shared = _small_nmpc()
    x = np.array([0.0, 0.0, 0.1, 0.0])

    def hammer(_):
        outcomes = []
        for _ in range(100):
            try:
                outcomes.append(bool(np.all(np.isfinite(shared(x)))))
            except ConcurrentUse:
                outcomes.append(None)
        return outcomes

    with ThreadPoolExecutor(4) as pool:
        results = [o for batch in pool.map(hammer, range(4)) for o in batch]
    assert all(o is None or o is True for o in results)
    assert any(o is True for o in results)
