"""LinearMPC returns the QP's optimum on both backends (issue 15: "Exact MPC").

References are independent of the controller: scipy's DARE (discrete LQR),
BVLS (``lsq_linear(method="bvls")``) on the Cholesky factor of a plain
condensed QP built in ``tests/test_mpc.py`` by explicit prediction matrices,
and the certified active-set optimum of ``tests/test_qp_condensed.py``.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import osqp
import pytest

from shinro_ctrl.controllers import controller_keys
from shinro_ctrl.controllers._osqp import OsqpQP
from shinro_ctrl.controllers.mpc import AUTO_DAQP_MAX_VARIABLES, LinearMPC, choose_solver
from shinro_ctrl.controllers.qp.condensed import CondensedQP
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible
from shinro_ctrl.plants import CartPole
from shinro_ctrl.sim import RobotSim

from .test_mpc import Q_CP, R_CP, cart_bounds, condensed, dare_gain
from .test_qp_condensed import bvls, exact_qp, plain_qp

BACKENDS = ["daqp", "osqp"]


@pytest.fixture(scope="module")
def cp() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    A, B = CartPole(dt=0.02).get_model()
    K, P = dare_gain(A, B, Q_CP, R_CP)
    return A, B, K, P


def small_and_large_states(rng: np.random.Generator) -> list[np.ndarray]:
    return [rng.uniform(-1, 1, 4) * s for s in (1e-8, 1e-4, 0.02, 0.3, 0.8) for _ in range(3)]


@pytest.mark.parametrize("solver", BACKENDS)
def test_first_move_equals_bvls_with_input_bounds(cp, rng, solver):
    """Input bounds only, N = 20: the first move equals BVLS to 1e-6 relative (bounds active and inactive)."""
    A, B, _, P = cp
    N = 20
    mpc = LinearMPC(A, B, Q_CP, R_CP, N, u_min=-3.0, u_max=3.0, solver=solver)
    assert mpc.solver == solver
    saturated = 0
    for x in small_and_large_states(rng):
        H, f = condensed(A, B, Q_CP, R_CP, P, N, x)
        U = bvls(H, f, np.full(N, -3.0), np.full(N, 3.0))
        mpc.reset()
        u = mpc(x)
        np.testing.assert_allclose(u[0], U[0], rtol=1e-6, atol=1e-9 * max(1.0, abs(U[0])) * 1e-3)
        saturated += int(abs(U[0]) == 3.0)
        last = mpc.last
        # the OSQP backend hands a step it cannot polish exactly to the condensed solver (backend "daqp")
        assert last.backend in (solver, "daqp") and last.status == "solved" and last.kkt_residual < 1e-6
        assert last.iterations >= 1 and last.active_set_size >= 0 and last.solve_time_s > 0
    assert 0 < saturated < 15


@pytest.mark.parametrize("solver", BACKENDS)
def test_first_move_equals_exact_with_state_bounds(cp, solver):
    """Hard cart bound and input bounds, N = 12: plan equals the certified optimum to 1e-6."""
    A, B, _, P = cp
    N = 12
    mpc = LinearMPC(A, B, Q_CP, R_CP, N, u_min=-3.0, u_max=3.0, solver=solver, **cart_bounds(0.6))
    sel = np.arange(1, N + 1) * 4
    for x in [np.array([0.5, 0.6, 0.1, 0.0]), np.array([-0.45, -0.5, -0.05, 0.1]), np.array([0.0, 0.0, 0.2, 0.0])]:
        H, f, Phi, Gam, c = plain_qp(A, B, Q_CP, R_CP, P, N, x)
        G = np.vstack([np.eye(N), Gam[sel]])
        off = (Phi @ x + c)[sel]
        U = exact_qp(
            H, f, G, np.concatenate([np.full(N, -3.0), -0.6 - off]), np.concatenate([np.full(N, 3.0), 0.6 - off])
        )
        mpc.reset()
        u = mpc(x)
        np.testing.assert_allclose(u[0], U[0], rtol=1e-6)
        np.testing.assert_allclose(mpc.last.inputs[:, 0], U, rtol=0, atol=1e-6 * np.abs(U).max())


@pytest.mark.parametrize("solver", BACKENDS)
def test_unconstrained_dare_equals_dlqr_near_equilibrium(cp, rng, solver):
    """No bounds, DARE terminal cost, |x| <= 0.02: u = -K x to 1e-8 relative (scipy's DARE)."""
    A, B, K, _ = cp
    mpc = LinearMPC(A, B, Q_CP, R_CP, 50, solver=solver)
    for x in [rng.uniform(-1, 1, 4) * s for s in (1e-9, 1e-5, 1e-3, 0.02) for _ in range(5)]:
        u = mpc(x)
        np.testing.assert_allclose(u, -K @ x, rtol=1e-8)


@pytest.mark.parametrize("solver", BACKENDS)
def test_soft_bound_slack_zero_when_satisfiable(cp, solver):
    """A satisfiable soft bound with an exact-penalty weight: zero slack and the hard-bounded solution."""
    A, B, _, _ = cp
    kw = {"u_min": -3.0, "u_max": 3.0, **cart_bounds(0.6)}
    hard = LinearMPC(A, B, Q_CP, R_CP, 50, solver=solver, **kw)
    soft = LinearMPC(A, B, Q_CP, R_CP, 50, solver=solver, soft=True, soft_weight_l1=1e4, soft_weight_quad=1.0, **kw)
    x = np.array([0.4, 0.5, 0.0, 0.0])  # the cart bound is active on the hard plan
    uh, us = hard(x), soft(x)
    assert np.isclose(np.abs(hard.last.states[1:, 0]).max(), 0.6, atol=1e-7)
    assert soft.last.max_slack <= 1e-7
    np.testing.assert_allclose(us, uh, rtol=1e-6)
    np.testing.assert_allclose(soft.last.inputs, hard.last.inputs, rtol=0, atol=1e-6 * np.abs(uh).max())


def test_long_horizon_daqp_matches_tight_osqp(cp):
    """N = 200, unstable cart-pole: DAQP solves it and matches OSQP itself (eps 1e-10) on the sparse QP to 1e-6."""
    A, B, _, _ = cp
    N = 200
    dense = LinearMPC(A, B, Q_CP, R_CP, N, u_min=-3.0, u_max=3.0, solver="daqp", **cart_bounds(0.6))
    for x in [np.array([0.0, 0.0, 0.3, 0.0]), np.array([0.3, 0.2, -0.1, 0.0])]:
        ud = dense(x)
        assert dense.last.status == "solved" and dense.last.kkt_residual < 1e-9
        qp = dense.build(x)  # the sparse QP of the same step, solved by OSQP directly
        solver = osqp.OSQP()
        solver.setup(qp.P, qp.q, qp.A, qp.l, qp.u, eps_abs=1e-10, eps_rel=1e-10, max_iter=400_000, verbose=False)
        res = solver.solve(raise_error=False)
        assert res.info.status == "solved"
        iu = (N + 1) * 4
        np.testing.assert_allclose(ud, res.x[iu : iu + 1], rtol=1e-6)
        np.testing.assert_allclose(dense.last.inputs[:, 0], res.x[iu : iu + N], rtol=0, atol=1e-6 * np.abs(ud).max())


@pytest.mark.parametrize("solver", BACKENDS)
def test_infeasible_raises_naming_group_and_stage(cp, solver):
    """Hard bounds that cannot hold raise MPCInfeasible on both backends, naming the state bound and a stage."""
    A, B, _, _ = cp
    mpc = LinearMPC(A, B, Q_CP, R_CP, 30, u_min=-3.0, u_max=3.0, solver=solver, **cart_bounds(0.6))
    with pytest.raises(MPCInfeasible, match=r"infeasible .*state bounds at stage \d+ \(x\[0\] in \[-0\.6, 0\.6\]\)"):
        mpc(np.array([0.5, 2.0, 0.0, 0.0]))
    assert mpc.last.backend == solver and np.isnan(mpc.last.u).all()
    u = mpc(np.array([0.0, 0.0, 0.1, 0.0]))  # recovers on a feasible state
    assert mpc.last.status == "solved" and np.isfinite(u).all()


def test_osqp_out_of_iterations_is_not_infeasible(cp):
    """An OSQP solve cut short (max_iter 3: "maximum iterations reached") is settled, never reported infeasible."""
    A, B, _, P = cp
    N = 20
    mpc = LinearMPC(A, B, Q_CP, R_CP, N, u_min=-3.0, u_max=3.0, solver="osqp", osqp_settings={"max_iter": 3})
    x = np.array([0.1, 0.0, 0.3, 0.0])
    u = mpc(x)
    H, f = condensed(A, B, Q_CP, R_CP, P, N, x)
    np.testing.assert_allclose(u[0], bvls(H, f, np.full(N, -3.0), np.full(N, 3.0))[0], rtol=1e-6)
    assert mpc.last.status == "solved"
    assert mpc.osqp_settings["max_iter"] == 3  # the tightened re-solve restored the user's settings


def test_interrupted_solve_is_never_infeasible(cp, monkeypatch):
    """OSQP's 'interrupted' status and a KeyboardInterrupt inside DAQP both surface as KeyboardInterrupt."""
    A, B, _, _ = cp
    sparse = LinearMPC(A, B, Q_CP, R_CP, 20, u_min=-3.0, u_max=3.0, solver="osqp")
    interrupted = SimpleNamespace(status="interrupted", status_polish=0, iter=7, solve_time=1e-4)
    monkeypatch.setattr(OsqpQP, "solve", lambda self: (SimpleNamespace(x=np.zeros(1), y=np.zeros(1)), interrupted))
    with pytest.raises(KeyboardInterrupt):
        sparse(np.array([0.0, 0.0, 0.2, 0.0]))
    monkeypatch.undo()
    dense = LinearMPC(A, B, Q_CP, R_CP, 20, u_min=-3.0, u_max=3.0, solver="daqp")

    def interrupt(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(CondensedQP, "solve", interrupt)
    with pytest.raises(KeyboardInterrupt):
        dense(np.array([0.0, 0.0, 0.2, 0.0]))


def test_auto_rule_and_config_key(cp):
    """'auto' resolves by N·m; 'solver' is a [controller] key; a bad value names the choices."""
    A, B, _, _ = cp
    assert LinearMPC(A, B, Q_CP, R_CP, 50).solver == "daqp"
    assert LinearMPC(A, B, Q_CP, R_CP, AUTO_DAQP_MAX_VARIABLES + 1).solver == "osqp"
    big = LinearMPC(A, B, Q_CP, R_CP, AUTO_DAQP_MAX_VARIABLES + 1)
    assert choose_solver(4, 1, AUTO_DAQP_MAX_VARIABLES + 1, big.options) == "osqp"
    assert "solver" in controller_keys(LinearMPC)
    with pytest.raises(InvalidArgument, match="solver must be one of 'auto', 'osqp', 'daqp'"):
        LinearMPC(A, B, Q_CP, R_CP, 10, solver="qpoases")
    doc = {
        "plant": {"type": "CartPole", "dt": 0.02},
        "controller": {"type": "LinearMPC", "horizon": 20, "Q": [10, 1, 100, 1], "R": [0.1], "solver": "osqp"},
        "sim": {"duration": 0.1, "initial_state": [0, 0, 0.1, 0]},
    }
    assert RobotSim.from_config(doc).controller.solver == "osqp"


SHIPPED_MPC = ["cartpole_mpc", "cartpole_mpc_mujoco", "pendulum_mpc_mujoco", "double_pendulum_mpc_mujoco"]


@pytest.mark.parametrize("name", [*SHIPPED_MPC, "quadrotor_mpc_mujoco"])
def test_shipped_mpc_scenarios_run_exact_on_auto(name):
    """Every shipped MPC scenario resolves 'auto' to DAQP, and its first move is the QP optimum (OSQP at eps 1e-10)."""
    sim = RobotSim.from_config(name)
    mpc = sim.controller
    assert mpc.options.solver == "auto" and mpc.solver == "daqp"
    res = sim.run(duration=0.6)
    assert mpc.last.status == "solved" and mpc.last.kkt_residual < 1e-8
    assert np.all(res.u <= mpc.u_max + 1e-12) and np.all(res.u >= mpc.u_min - 1e-12)
    for x in (res.x[len(res.x) // 3], res.x[-1]):
        mpc.reset()
        u = mpc(x)
        qp = mpc.build(x)  # the same step as a sparse QP, solved by OSQP itself
        solver = osqp.OSQP()
        solver.setup(qp.P, qp.q, qp.A, qp.l, qp.u, eps_abs=1e-10, eps_rel=1e-10, max_iter=400_000, verbose=False)
        out = solver.solve(raise_error=False)
        assert out.info.status == "solved"
        iu = (mpc.N + 1) * mpc.n
        u_ref = np.clip(out.x[iu : iu + mpc.m] + mpc.u0, mpc.u_min, mpc.u_max)
        np.testing.assert_allclose(u, u_ref, rtol=1e-6, atol=1e-9 * max(1.0, float(np.abs(u_ref).max())))


@pytest.mark.parametrize("solver", BACKENDS)
def test_bounds_no_input_can_move_are_left_out_not_infeasible(cp, solver):
    """Explicit Euler: x_1's cart position is x + dt·v whatever u_0. A run that raised MPCInfeasible at step 27
    (|x| <= 0.3, the measured state already past the bound one step ahead) now runs through; the step leaves
    that bound out, says so in ``dropped_rows``, and its plan is the exact optimum without it."""
    A, B, _, P = cp
    plant = CartPole(dt=0.02)
    kw = dict(horizon=30, u_min=-10.0, u_max=10.0, solver=solver, discretization="euler", **cart_bounds(0.3))
    mpc = LinearMPC.from_plant(plant, Q_CP, R_CP, **kw)
    plant.set_state([0.0, 0.0, 0.3, 0.0])
    dropped = []
    for k in range(200):
        x = plant.get_state()
        u = mpc(x)  # used to raise MPCInfeasible at k = 27 ("state bounds at stage 1")
        if mpc.last.dropped_rows:
            dropped.append((k, x.copy(), mpc.last.dropped_rows))
        plant.step(u)
    assert abs(plant.get_state()[2]) < 0.01  # the pole is balanced
    assert dropped and all("at stage 1: predicted" in text and "x in [-0.3, 0.3]" in text for _, _, text in dropped)
    k, x, text = dropped[0]
    assert k == 27 and f"predicted {x[0] + 0.02 * x[1]:.4g}" in text
    # the exact optimum of the plain condensed QP with every bound but x_1's
    N = 30
    mpc.reset()
    u = mpc(x)
    H, f, Phi, Gam, c = plain_qp(A, B, Q_CP, R_CP, P, N, x)
    sel = np.arange(2, N + 1) * 4  # cart rows of x_2 … x_N (x_1's is left out)
    off = (Phi @ x + c)[sel]
    G = np.vstack([np.eye(N), Gam[sel]])
    U = exact_qp(
        H, f, G, np.concatenate([np.full(N, -10.0), -0.3 - off]), np.concatenate([np.full(N, 10.0), 0.3 - off])
    )
    np.testing.assert_allclose(u[0], U[0], rtol=1e-6)
    assert np.abs(mpc.last.states[2:, 0]).max() <= 0.3 + 1e-7 < mpc.last.states[1, 0]
