"""Tests of LinearMPC against independent references.

References: scipy's DARE (LQR equivalence), an exact bounded least-squares
solution of the condensed input-only QP (scipy's BVLS), the unconstrained
condensed optimum, the nonlinear cart-pole in closed loop, and OSQP itself on
the QP that ``build()`` returns.

``run_mpc_loop`` and ``soft_bound_scenario`` take any plant, so the same
checks can run with a MuJoCo engine attached to the plant.
"""

from __future__ import annotations

import ctypes
import re
from typing import Any

import numpy as np
import osqp
import pytest
import scipy.linalg
import scipy.optimize
import scipy.sparse as sp

from shinro_ctrl.controllers.mpc import QP, LinearMPC, MPCSolution
from shinro_ctrl.controllers.qp.sparse import qp_size
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError, NotStabilizable, ShinroError
from shinro_ctrl.plants import CartPole

INF = np.inf
Q_CP = np.diag([10.0, 1.0, 100.0, 1.0])
R_CP = np.array([[0.1]])
#: Tight OSQP tolerances for comparisons with exact references.
TIGHT = {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200_000}


def cart_bounds(limit: float) -> dict[str, list[float]]:
    """State bounds ``|x_cart| <= limit`` on the cart-pole, other states free."""
    return {"x_min": [-limit, -INF, -INF, -INF], "x_max": [limit, INF, INF, INF]}


@pytest.fixture
def cartpole() -> tuple[CartPole, np.ndarray, np.ndarray]:
    plant = CartPole(dt=0.02)
    A, B = plant.get_model()
    return plant, A, B


def dare_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(K, P)`` of the discrete LQR, computed independently of the controller."""
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    return K, P


def condensed(A, B, Q, R, Qf, N, x0, ref=None, u_ref=None):
    """The input-only QP ``min ½ Uᵀ H U + fᵀ U`` of the MPC cost (deviation variables).

    ``X = Φ x0 + Γ U`` stacks ``x_0 … x_N``; the cost is
    ``½ Σ_{k<N} (x_k − r_k)ᵀ Q (x_k − r_k) + (u_k − ū)ᵀ R (u_k − ū) + ½ (x_N − r_N)ᵀ Qf (x_N − r_N)``.
    """
    n, m = B.shape
    Phi = np.vstack([np.linalg.matrix_power(A, k) for k in range(N + 1)])
    Gam = np.zeros(((N + 1) * n, N * m))
    for k in range(1, N + 1):
        for j in range(k):
            Gam[k * n : (k + 1) * n, j * m : (j + 1) * m] = np.linalg.matrix_power(A, k - 1 - j) @ B
    Qbar = scipy.linalg.block_diag(*([Q] * N + [Qf]))
    Rbar = scipy.linalg.block_diag(*([R] * N))
    H = Gam.T @ Qbar @ Gam + Rbar
    rbar = np.zeros((N + 1) * n) if ref is None else np.broadcast_to(ref, (N + 1, n)).ravel()
    f = Gam.T @ Qbar @ (Phi @ x0 - rbar)
    if u_ref is not None:
        f -= Rbar @ np.tile(u_ref, N)
    return 0.5 * (H + H.T), f


def run_mpc_loop(plant: Any, mpc: LinearMPC, x_init: Any, steps: int, *, measure=None) -> dict[str, Any]:
    """Run ``steps`` closed-loop steps of ``mpc`` on ``plant`` from ``x_init``.

    Works for a standalone plant and for one with a physics engine attached.

    Args:
        plant: Any plant (``set_state``, ``get_state``, ``step``).
        mpc: The controller (reset before the run).
        x_init: Initial state ``(n,)``.
        steps: Number of control steps.
        measure: Optional ``f(k, x) -> x_measured`` (sensor glitches).

    Returns:
        ``X (steps + 1, n)``, ``U (steps, m)``, ``solutions`` (one
        :class:`MPCSolution` per step).
    """
    mpc.reset()
    plant.set_state(x_init)
    x = plant.get_state()
    X, U, sols = [x], [], []
    for k in range(steps):
        y = x if measure is None else measure(k, x)
        u = mpc(y)
        U.append(u.copy())
        sols.append(mpc.last)
        plant.step(u)
        x = plant.get_state()
        X.append(x)
    return {"X": np.array(X), "U": np.array(U), "solutions": sols}


def soft_bound_scenario(plant: Any, *, steps: int = 250, horizon: int = 50) -> dict[str, Any]:
    """Soft ``|x_cart| <= 0.3`` m with hard ``|F| <= 10`` N from 0.3 rad (the bound becomes active).

    Returns the :func:`run_mpc_loop` result plus ``violation`` (largest
    measured excess of the cart over the bound, m), ``max_slack`` (largest
    planned violation the controller reported) and ``mpc``.
    """
    mpc = LinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=horizon, u_min=-10.0, u_max=10.0, soft=True, **cart_bounds(0.3)
    )
    out = run_mpc_loop(plant, mpc, [0.0, 0.0, 0.3, 0.0], steps)
    out["violation"] = float(np.max(np.abs(out["X"][:, 0])) - 0.3)
    out["max_slack"] = max(s.max_slack for s in out["solutions"])
    out["mpc"] = mpc
    return out


# --------------------------------------------------------------- LQR equivalence
@pytest.mark.parametrize("horizon", [1, 10, 50])
def test_unconstrained_first_move_is_lqr(cartpole, horizon):
    _, A, B = cartpole
    K, P = dare_gain(A, B, Q_CP, R_CP)
    rng = np.random.default_rng(0)
    states = rng.normal(scale=[0.2, 0.2, 0.1, 0.2], size=(5, 4))
    tight = LinearMPC(A, B, Q_CP, R_CP, horizon, osqp_settings=TIGHT)
    default = LinearMPC(A, B, Q_CP, R_CP, horizon)
    np.testing.assert_allclose(tight.Qf, P, rtol=1e-10)
    for x in states:
        u_lqr = -K @ x
        np.testing.assert_allclose(tight(x), u_lqr, rtol=1e-6, atol=1e-7)
        # the whole plan is the LQR trajectory u_k = -K (A - B K)^k x
        Acl = A - B @ K
        plan = np.array([-K @ np.linalg.matrix_power(Acl, k) @ x for k in range(horizon)])
        np.testing.assert_allclose(tight.last.inputs, plan, rtol=1e-5, atol=1e-6)
        # OSQP's default-ish tolerance (eps = 1e-4): within about 1 %
        u = default(x)
        assert abs(u[0] - u_lqr[0]) <= 0.01 * abs(u_lqr[0]) + 1e-3, (u, u_lqr)
        assert default.last.status == "solved"


def test_lqr_equivalence_around_an_operating_point(cartpole):
    """Deviation variables: u = u0 - K (x - x0) with a shifted cart position and input offset."""
    _, A, B = cartpole
    K, _ = dare_gain(A, B, Q_CP, R_CP)
    x0 = np.array([0.4, 0.0, 0.0, 0.0])  # any cart position is an equilibrium
    u0 = np.array([0.0])
    mpc = LinearMPC(A, B, Q_CP, R_CP, 30, x0=x0, u0=u0, osqp_settings=TIGHT)
    x = np.array([0.5, -0.1, 0.05, 0.1])
    np.testing.assert_allclose(mpc(x), u0 - K @ (x - x0), rtol=1e-6)
    np.testing.assert_allclose(mpc.last.states[0], x, atol=1e-9)  # absolute units
    np.testing.assert_allclose(mpc.K, K, rtol=1e-8)


# ------------------------------------------------- bounds: exact condensed reference
@pytest.mark.parametrize(
    "u_min, u_max, x",
    [
        (-0.5, 8.0, [0.0, 0.0, 0.1, 0.0]),  # first move interior, lower bound active from stage 5 on
        (-1.0, 4.0, [0.0, 0.0, 0.25, 0.0]),  # upper bound early, interior middle, lower bound late
    ],
)
def test_input_bounds_match_bvls_on_condensed_qp(cartpole, u_min, u_max, x):
    _, A, B = cartpole
    N = 15
    x = np.array(x)
    _, P = dare_gain(A, B, Q_CP, R_CP)
    H, f = condensed(A, B, Q_CP, R_CP, P, N, x)
    L = np.linalg.cholesky(H)  # H = L Lᵀ: ½ UᵀHU + fᵀU = ½ ‖Lᵀ U + L⁻¹ f‖² + const
    rhs = -scipy.linalg.solve_triangular(L, f, lower=True)
    ref = scipy.optimize.lsq_linear(L.T, rhs, bounds=(u_min, u_max), method="bvls", tol=1e-14, max_iter=1000)
    assert ref.success
    U = ref.x
    active = np.flatnonzero((U <= u_min + 1e-9) | (U >= u_max - 1e-9))
    assert active.size >= 3 and active.max() > 0  # bounds bind beyond the first move
    assert active.size < N  # and not everywhere

    tight = LinearMPC(A, B, Q_CP, R_CP, N, u_min=u_min, u_max=u_max, osqp_settings=TIGHT)
    np.testing.assert_allclose(tight(x)[0], U[0], atol=1e-6)
    np.testing.assert_allclose(tight.last.inputs[:, 0], U, atol=1e-5)
    default = LinearMPC(A, B, Q_CP, R_CP, N, u_min=u_min, u_max=u_max)
    u = default(x)[0]
    assert abs(u - U[0]) <= 1e-2 * max(1.0, abs(U[0]))
    assert u_min <= u <= u_max  # clipped: exactly inside


# ---------------------------------------------------------------- closed loops
def test_closed_loop_hard_bounds_nonlinear_cartpole():
    plant = CartPole(dt=0.02)
    mpc = LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=50, u_min=-3.0, u_max=3.0, **cart_bounds(0.6))
    out = run_mpc_loop(plant, mpc, [0.0, 0.0, 0.3, 0.0], 300)
    X, U = out["X"], out["U"]
    assert all(s.status == "solved" and not s.fallback_used for s in out["solutions"])
    assert np.all(np.abs(U) <= 3.0)  # exactly, not within eps
    assert np.max(np.abs(U)) == 3.0  # the input bound was active
    assert np.all(np.abs(X[:, 0]) <= 0.6)
    assert np.max(X[:, 0]) > 0.5  # the state bound mattered (the cart comes close)
    np.testing.assert_allclose(X[-1], 0.0, atol=2e-3)  # stabilized upright at the origin
    # the returned input is the first planned input, clipped
    for u, s in zip(U, out["solutions"], strict=True):
        np.testing.assert_array_equal(u, np.clip(s.inputs[0], -3.0, 3.0))


def test_rate_bounds_hold_exactly():
    plant = CartPole(dt=0.02)
    mpc = LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=30, u_min=-5.0, u_max=5.0, du_max=0.4)
    out = run_mpc_loop(plant, mpc, [0.0, 0.0, 0.15, 0.0], 200)
    U = out["U"][:, 0]
    assert np.all(np.abs(np.diff(U)) <= 0.4 + 1e-12)  # clipped; the difference itself rounds by an ulp
    assert np.max(np.abs(np.diff(U))) >= 0.4 - 1e-9  # the rate bound was active
    np.testing.assert_allclose(out["X"][-1], 0.0, atol=1e-2)
    # reset(u_prev=...) limits the first move too
    mpc.reset(u_prev=[1.0])
    assert abs(mpc([0.0, 0.0, 0.15, 0.0])[0] - 1.0) <= 0.4


def test_soft_state_bound_becomes_active_standalone(record_property):
    out = soft_bound_scenario(CartPole(dt=0.02))
    X = out["X"]
    record_property("soft_bound_violation_m", out["violation"])
    record_property("soft_bound_max_slack_m", out["max_slack"])
    print(f"soft |x| <= 0.3: measured violation {out['violation']:.2e} m, max planned slack {out['max_slack']:.2e} m")
    assert np.max(X[:, 0]) > 0.29  # held near the bound: it is active
    assert out["violation"] < 5e-3  # small violation
    assert out["max_slack"] > 0.0  # the controller planned (and reported) a violation
    assert np.all(np.abs(out["U"]) <= 10.0)
    np.testing.assert_allclose(X[-1], 0.0, atol=5e-3)
    assert all(s.status == "solved" for s in out["solutions"])


# ---------------------------------------------------------------- infeasibility
@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_infeasible_hard_state_bound_raises(cartpole, solver):
    plant, _, _ = cartpole
    kw = dict(horizon=50, u_min=-3.0, u_max=3.0, solver=solver, discretization="euler", **cart_bounds(0.6))
    mpc = LinearMPC.from_plant(plant, Q_CP, R_CP, **kw)
    with pytest.raises(MPCInfeasible) as info:
        mpc([0.59, 3.0, 0.0, 0.0])  # 3 m/s towards the bound, 1 cm away, 3 N of braking
    msg = str(info.value)
    assert "infeasible" in msg
    # Euler model: x_1 = x_0 + dt v_0 = 0.59 + 0.06 > 0.6 whatever the input: not a constraint of the plan (left
    # out and reported); stage 2, where the input first acts, is the first that cannot be met
    assert re.search(r"state bounds at stage 2 \(x in \[-0.6, 0.6\]\)", msg), msg
    assert "input bounds" in msg  # what it conflicts with
    assert isinstance(info.value, RuntimeError) and isinstance(info.value, ShinroError)
    assert mpc.last.status == "primal infeasible" and np.isnan(mpc.last.u).all()
    assert mpc.last.dropped_rows.startswith("x in [-0.6, 0.6] at stage 1: predicted 0.65 whatever the input")


def test_infeasible_rate_and_input_bounds_name_stage_zero(cartpole):
    _, A, B = cartpole
    mpc = LinearMPC(A, B, Q_CP, R_CP, 20, u_min=-1.0, u_max=1.0, du_max=0.5)
    mpc.reset(u_prev=[3.0])  # 3 N applied before; only 2.5 N reachable; 1 N allowed
    with pytest.raises(MPCInfeasible, match=r"infeasible.*rate bounds at stage 0.*input bounds at stages 0"):
        mpc([0.0, 0.0, 0.01, 0.0])


def test_fallback_shift_survives_a_glitch_and_flags_it():
    plant = CartPole(dt=0.02)
    mpc = LinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=50, u_min=-3.0, u_max=3.0, fallback="shift", **cart_bounds(0.6)
    )
    glitch = 40

    def measure(k, x):  # one corrupted measurement: the cart seems to rush at the bound
        return np.array([0.59, 3.0, 0.0, 0.0]) if k == glitch else x

    out = run_mpc_loop(plant, mpc, [0.0, 0.0, 0.3, 0.0], 250, measure=measure)
    flags = [s.fallback_used for s in out["solutions"]]
    assert flags[glitch] and sum(flags) == 1
    sol = out["solutions"][glitch]
    assert "infeasible" in sol.message and sol.status == "primal infeasible"
    prev = out["solutions"][glitch - 1]
    np.testing.assert_array_equal(out["U"][glitch], np.clip(prev.inputs[1], -3, 3))  # the plan, shifted
    assert sol.states.shape == (51, 4) and sol.inputs.shape == (50, 1)
    assert np.all(np.abs(out["U"]) <= 3.0)
    np.testing.assert_allclose(out["X"][-1], 0.0, atol=5e-3)


def test_fallback_without_a_plan_raises(cartpole):
    _, A, B = cartpole
    mpc = LinearMPC(A, B, Q_CP, R_CP, 20, u_min=-3, u_max=3, fallback="shift", **cart_bounds(0.6))
    with pytest.raises(MPCInfeasible, match="no previous plan"):
        mpc([0.59, 3.0, 0.0, 0.0])


def test_fallback_plan_runs_out(cartpole):
    _, A, B = cartpole
    N = 4
    mpc = LinearMPC(A, B, Q_CP, R_CP, N, u_min=-3, u_max=3, fallback="shift", **cart_bounds(0.6))
    mpc([0.0, 0.0, 0.05, 0.0])
    plan = mpc.last.inputs.copy()
    bad = [0.599, 3.0, 0.0, 0.0]
    for k in range(1, N):
        np.testing.assert_array_equal(mpc(bad), np.clip(plan[k], -3, 3))
        assert mpc.last.fallback_used
    with pytest.raises(MPCInfeasible, match="exhausted"):
        mpc(bad)


# --------------------------------------------------------------- references
def test_reference_tracking_on_the_linear_model(cartpole):
    _, A, B = cartpole
    mpc = LinearMPC(A, B, Q_CP, R_CP, 40, u_min=-10, u_max=10)
    ref = np.array([0.2, 0.0, 0.0, 0.0])
    x = np.zeros(4)
    for _ in range(400):
        x = A @ x + B @ mpc(x, ref)
    np.testing.assert_allclose(x, ref, atol=1e-3)


def test_reference_trajectory_and_input_reference_match_condensed_optimum(cartpole):
    _, A, B = cartpole
    N = 12
    _, P = dare_gain(A, B, Q_CP, R_CP)
    rng = np.random.default_rng(7)
    x = np.array([0.05, 0.0, 0.08, -0.1])
    traj = np.cumsum(rng.normal(scale=0.01, size=(N + 1, 4)), axis=0)
    u_ref = np.array([0.3])
    H, f = condensed(A, B, Q_CP, R_CP, P, N, x, ref=traj, u_ref=u_ref)
    U = np.linalg.solve(H, -f)
    mpc = LinearMPC(A, B, Q_CP, R_CP, N, osqp_settings=TIGHT)
    np.testing.assert_allclose(mpc(x, traj, u_ref=u_ref), U[:1], atol=1e-6)
    np.testing.assert_allclose(mpc.last.inputs[:, 0], U, atol=1e-5)
    # the reported objective is the MPC cost of the predicted trajectory
    Xp, Up = mpc.last.states, mpc.last.inputs
    e = Xp - traj
    cost = 0.5 * (
        np.einsum("ki,ij,kj->", e[:N], Q_CP, e[:N])
        + e[N] @ P @ e[N]
        + np.einsum("ki,ij,kj->", Up - u_ref, R_CP, Up - u_ref)
    )
    assert mpc.last.objective == pytest.approx(cost, rel=1e-6)
    # a constant reference equals a trajectory of identical rows; the constructor's u_ref is the default
    r = np.array([0.1, 0.0, 0.0, 0.0])
    a = LinearMPC(A, B, Q_CP, R_CP, N, osqp_settings=TIGHT, u_ref=u_ref)
    b = LinearMPC(A, B, Q_CP, R_CP, N, osqp_settings=TIGHT)
    np.testing.assert_allclose(a(x, r), b(x, np.tile(r, (N + 1, 1)), u_ref=u_ref), atol=1e-7)
    # back to no reference: q returns to its default
    np.testing.assert_allclose(b(x), LinearMPC(A, B, Q_CP, R_CP, N, osqp_settings=TIGHT)(x), atol=1e-7)


# ------------------------------------------------------------ build / inspect
def test_build_exposes_the_qp_without_solving(cartpole):
    plant, _, _ = cartpole
    mpc = LinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=10, u_min=-3, u_max=3, du_max=1.0, osqp_settings=TIGHT, **cart_bounds(0.6)
    )
    n, m, N = 4, 1, 10
    x = np.array([0.1, 0.0, 0.2, 0.0])
    qp = mpc.build(x)
    assert isinstance(qp, QP) and mpc.last is None  # nothing solved
    assert qp.P.shape == (mpc.n_var, mpc.n_var) == ((N + 1) * n + N * m,) * 2
    assert qp.A.shape == (mpc.n_con, mpc.n_var)
    assert sp.isspmatrix_csc(qp.P) and sp.isspmatrix_csc(qp.A)
    assert sp.tril(qp.P, -1).nnz == 0  # OSQP's upper triangle
    g = mpc.groups
    assert list(g) == ["initial state", "dynamics", "input bounds", "rate bounds", "state bounds"]
    np.testing.assert_array_equal(qp.l[:n], x - mpc.x0)
    np.testing.assert_array_equal(qp.u[:n], x - mpc.x0)
    assert g["state bounds"].stages == N and g["state bounds"].first_stage == 1  # x_0 never bounded
    assert g["input bounds"].stages == N and g["dynamics"].stages == N
    # the first rate rows are open until an input has been applied
    r0 = g["rate bounds"].start
    assert qp.l[r0] <= -1e30 and qp.u[r0] >= 1e30
    # an independent OSQP solve of the built QP gives the controller's first move
    solver = osqp.OSQP()
    solver.setup(qp.P, qp.q, qp.A, qp.l, qp.u, verbose=False, **TIGHT)
    z = solver.solve(raise_error=True).x
    u = mpc(x)
    np.testing.assert_allclose(u, z[(N + 1) * n : (N + 1) * n + m] + mpc.u0, atol=1e-7)
    assert mpc.last.iterations > 0 and isinstance(mpc.last, MPCSolution)
    # after a call the rate rows are centred on the applied input
    qp2 = mpc.build(x)
    np.testing.assert_allclose([qp2.l[r0], qp2.u[r0]], [u[0] - 1.0, u[0] + 1.0])


def test_matrices_are_built_once_and_paths_agree(cartpole):
    plant, _, _ = cartpole
    kw = dict(horizon=20, u_min=-3.0, u_max=3.0, solver="osqp", **cart_bounds(0.6))
    fast = LinearMPC.from_plant(plant, Q_CP, R_CP, **kw)
    public = LinearMPC.from_plant(plant, Q_CP, R_CP, **kw)
    public.backend.qp.fast = False  # force OSQP's public Python wrapper
    assert fast.backend.qp.fast and not public.backend.qp.fast
    P, A = fast.P, fast.A_con
    Pdata, Adata = P.data.copy(), A.data.copy()
    solver = fast.backend.qp.solver

    def no_setup(*args, **kwargs):
        raise AssertionError("setup called per step")

    solver.setup = no_setup
    plant.set_state([0.0, 0.0, 0.3, 0.0])
    for _ in range(60):
        x = plant.get_state()
        u1, u2 = fast(x), public(x)
        np.testing.assert_allclose(u1, u2, atol=1e-12)
        assert fast.last.iterations == public.last.iterations
        plant.step(u1)
    assert fast.P is P and fast.A_con is A and fast.backend.qp.solver is solver
    np.testing.assert_array_equal(P.data, Pdata)
    np.testing.assert_array_equal(A.data, Adata)


def test_from_plant_off_equilibrium_has_the_drift_offset():
    plant = CartPole(dt=0.02)
    x0 = np.array([0.0, 0.0, 0.1, 0.0])  # not an equilibrium: the pole falls
    mpc = LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=30, x0=x0, terminal_cost="Q")
    # the default model is the plant's own step: the affine term is that step from (x0, u0) minus x0
    np.testing.assert_allclose(mpc.offset, plant.integrate(x0.copy(), np.zeros(1)) - x0, rtol=1e-12, atol=1e-15)
    assert mpc.model is not None and mpc.model.discretization == "step"
    euler = LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=30, x0=x0, terminal_cost="Q", discretization="euler")
    np.testing.assert_allclose(euler.offset, 0.02 * plant.dynamics(x0, [0.0]), rtol=1e-12)
    mpc(x0)
    # one predicted step from x0 with input u: x0 + A·0 + B (u - u0) + d
    u = mpc.last.inputs[0]
    np.testing.assert_allclose(mpc.last.states[1], x0 + mpc.B @ (u - mpc.u0) + mpc.offset, atol=1e-3)
    with pytest.raises(TypeError):
        LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=5, u_mx=3)  # misspelt option


@pytest.mark.parametrize("solver", ["osqp", "daqp", "auto"])
def test_describe_lists_sizes_terminal_cost_and_settings_of_the_backend_in_use(cartpole, solver):
    """The sizes and settings printed are those of the backend that solves (``design mpc`` prints this)."""
    plant, _, _ = cartpole
    mpc = LinearMPC.from_plant(
        plant, Q_CP, R_CP, horizon=20, u_min=-3, u_max=3, soft=True, solver=solver, **cart_bounds(0.6)
    )
    text = mpc.describe()
    if mpc.solver == "osqp":
        assert f"{mpc.n_var} variables" in text and f"{mpc.n_con} constraints" in text
        assert f"nnz(P) = {mpc.P.nnz}" in text and f"nnz(A) = {mpc.A_con.nnz}" in text
        assert "OSQP settings:" in text and "eps_abs=0.0001" in text and "DAQP" not in text
    else:
        dense = mpc.dense
        assert f"condensed QP (DAQP): {dense.n_var} variables ({dense.n_slack} slacks)" in text
        assert "DAQP settings:" in text and "primal_tol=1e-09" in text and "OSQP" not in text
    assert f"backend: {mpc.solver} (solver = '{solver}')" in text
    assert "terminal cost (lqr)" in text and "soft" in text
    assert "horizon N = 20" in text and "dt = 0.02 s" in text


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    "change, error, pattern",
    [
        ({"A": np.ones((4, 3))}, ValueError, r"A: expected a square"),
        ({"B": np.ones((3, 1))}, ValueError, r"B: expected \(4, m\) but found \(3, 1\)"),
        ({"Q": np.eye(3)}, ValueError, r"Q: expected \(4, 4\) but found \(3, 3\)"),
        ({"R": np.eye(2)}, ValueError, r"R: expected \(1, 1\) but found \(2, 2\)"),
        ({"Q": np.diag([1.0, 1.0, -1.0, 1.0])}, ValueError, "positive semidefinite"),
        ({"Q": np.triu(np.ones((4, 4)))}, ValueError, "symmetric"),
        ({"R": [[0.0]]}, ValueError, "positive definite"),
        ({"horizon": 0}, ValueError, "horizon"),
        ({"horizon": 2.5}, ValueError, "horizon"),
        ({"horizon": True}, ValueError, "horizon"),
        ({"A": np.full((4, 4), np.nan)}, NonFiniteError, "A must be finite"),
        ({"Q": np.diag([1.0, np.inf, 1.0, 1.0])}, NonFiniteError, "Q must be finite"),
        ({"u_min": 2.0, "u_max": 1.0}, ValueError, "u_min must be <= u_max"),
        ({"u_min": [np.nan]}, NonFiniteError, "u_min"),
        ({"x_min": [0.0, 0.0]}, ValueError, r"x_min: expected \(4,\) but found \(2,\)"),
        ({"du_max": -1.0}, ValueError, "du_max must be > 0"),
        ({"terminal_cost": "riccati"}, ValueError, "terminal_cost"),
        ({"terminal_cost": np.eye(3)}, ValueError, r"terminal_cost: expected \(4, 4\)"),
        ({"fallback": "hold"}, ValueError, "fallback"),
        ({"soft_weight_quad": 0.0}, ValueError, "soft_weight_quad"),
        ({"x0": [0.0, np.nan, 0.0, 0.0]}, NonFiniteError, "x0"),
        ({"osqp_settings": {"polish": True}}, ValueError, r"unknown OSQP setting 'polish'.*polishing.*valid settings"),
        ({"osqp_settings": {"warm_start": True}}, ValueError, "warm_starting"),
    ],
)
def test_constructor_validation(cartpole, change, error, pattern):
    _, A, B = cartpole
    args = {"A": A, "B": B, "Q": Q_CP, "R": R_CP, "horizon": 10} | change
    pos = [args.pop(k) for k in ("A", "B", "Q", "R", "horizon")]
    with pytest.raises(error, match=pattern):
        LinearMPC(*pos, **args)


@pytest.mark.parametrize(
    ("settings", "reason"),
    [({"eps_abs": -1.0}, "eps_abs must be nonnegative"), ({"max_iter": 0}, "max_iter must be positive")],
)
def test_bad_osqp_setting_values_raise_invalid_argument_silently(cartpole, capfd, settings, reason):
    # OSQP's C library prints "ERROR in validate_settings: ..." to stdout; that text belongs in our exception.
    _, A, B = cartpole
    capfd.readouterr()
    with pytest.raises(InvalidArgument, match=rf"OSQP rejected the MPC problem or its osqp_settings: {reason}"):
        LinearMPC(A, B, Q_CP, R_CP, 10, osqp_settings=settings)
    ctypes.CDLL(None).fflush(None)
    assert capfd.readouterr() == ("", "")
    LinearMPC(A, B, Q_CP, R_CP, 10, osqp_settings={"verbose": True})  # other output still gets through
    ctypes.CDLL(None).fflush(None)
    assert "OSQP" in capfd.readouterr().out


@pytest.mark.parametrize("horizon", [10**5, 10**8, 10**9])
def test_oversized_horizon_is_rejected_before_building(cartpole, horizon):
    # 10**8 used to get the process OOM-killed and 10**9 raised MemoryError.
    plant, _, _ = cartpole
    with pytest.raises(InvalidArgument) as info:
        LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=horizon, u_min=-3.0, u_max=3.0)
    text = str(info.value)
    assert f"horizon {horizon:,}" in text and "the limit is 2,000,000" in text
    assert f"{(horizon + 1) * 4 + horizon:,} decision variables" in text


@pytest.mark.parametrize("soft", [False, True])
def test_size_estimate_bounds_the_built_qp(cartpole, soft):
    _, A, B = cartpole
    mpc = LinearMPC(A, B, Q_CP, R_CP, 25, u_min=-3, u_max=3, du_max=0.5, soft=soft, **cart_bounds(0.6))
    nvar, nnz = qp_size(mpc.A, mpc.B, mpc.Q, mpc.R, mpc.N, mpc.options)
    assert nvar == mpc.n_var
    assert mpc.P.nnz + mpc.A_con.nnz <= nnz <= mpc.P.nnz + mpc.A_con.nnz + 4 * 5 // 2


def test_dare_failure_is_not_stabilizable():
    A = np.diag([1.5, 0.5])
    B = np.array([[0.0], [1.0]])  # the unstable mode is unreachable
    with pytest.raises(NotStabilizable, match="DARE"):
        LinearMPC(A, B, np.eye(2), [[1.0]], 5)
    with pytest.raises(NotStabilizable, match=r"spectral radius 1\.5 >= 1"):  # no law can move the mode
        LinearMPC(A, B, np.eye(2), [[1.0]], 5, terminal_cost="Q")


def test_call_validation(cartpole):
    _, A, B = cartpole
    mpc = LinearMPC(A, B, Q_CP, R_CP, 10)
    with pytest.raises(ValueError, match=r"expected shape \(4,\) but found \(3,\)"):
        mpc([0.0, 0.0, 0.0])
    with pytest.raises(NonFiniteError):
        mpc([0.0, np.nan, 0.0, 0.0])
    with pytest.raises(NonFiniteError):
        mpc([0.0, np.inf, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"ref: expected \(4,\) or \(11, 4\) but found \(5, 4\)"):
        mpc(np.zeros(4), np.zeros((5, 4)))
    with pytest.raises(NonFiniteError):
        mpc(np.zeros(4), [0.0, 0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="u_ref"):
        mpc(np.zeros(4), u_ref=[0.0, 1.0])
    with pytest.raises(TypeError):
        mpc(np.zeros(4), None, [0.0])  # options are keyword-only
    assert mpc.last is None  # nothing was solved
    u = mpc(np.zeros(4))
    assert u.shape == (1,) and u.dtype == np.float64


def test_keyword_only_options(cartpole):
    _, A, B = cartpole
    with pytest.raises(TypeError):
        LinearMPC(A, B, Q_CP, R_CP, 10, None)  # x0 is keyword-only


@pytest.mark.parametrize(
    "settings",
    [{"warm_starting": False}, {"polishing": True}, {"check_termination": 25, "alpha": 1.6}, {"scaling": 0}],
)
def test_osqp_settings_are_overridable(cartpole, settings):
    _, A, B = cartpole
    x = np.array([0.0, 0.0, 0.25, 0.0])
    ref = LinearMPC(A, B, Q_CP, R_CP, 15, u_min=-1.0, u_max=4.0, osqp_settings=TIGHT)(x)
    mpc = LinearMPC(A, B, Q_CP, R_CP, 15, u_min=-1.0, u_max=4.0, osqp_settings=settings)
    assert all(mpc.osqp_settings[k] == v for k, v in settings.items())
    for _ in range(3):  # repeated calls, warm or not
        u = mpc(x)
        assert abs(u[0] - ref[0]) <= 1e-2 * max(1.0, abs(ref[0]))


def test_mutating_the_returned_input_does_not_move_the_rate_window(cartpole):
    _, A, B = cartpole
    mpc = LinearMPC(A, B, Q_CP, R_CP, 10, u_min=-5.0, u_max=5.0, du_max=0.5)
    u = mpc([0.0, 0.0, 0.1, 0.0])
    applied = u.copy()
    u[:] = 100.0  # the caller reuses the array
    r0 = mpc.groups["rate bounds"].start
    qp = mpc.build([0.0, 0.0, 0.1, 0.0])
    np.testing.assert_allclose([qp.l[r0], qp.u[r0]], [applied[0] - 0.5, applied[0] + 0.5])


# ------------------------------------------------------ nominal closed loop
def _plants_for_the_nominal_loop():
    from shinro_ctrl.plants import DoublePendulum, InvertedPendulum, Quadrotor

    return [
        ("cartpole", CartPole(dt=0.02), Q_CP, R_CP),
        ("pendulum", InvertedPendulum(dt=0.02), np.diag([10.0, 1.0]), np.array([[0.1]])),
        ("acrobot", DoublePendulum(dt=0.01), np.diag([10.0, 10.0, 1.0, 1.0]), None),
        ("quadrotor", Quadrotor(dt=0.02), np.eye(12), None),
    ]


@pytest.mark.parametrize("horizon", [1, 3, 10, 40])
def test_a_non_stabilizing_mpc_is_refused_when_built(horizon):
    """The unconstrained MPC law from a plain condensed QP (H⁻¹F by simulation): refused iff A − B K is unstable."""
    outcomes = set()
    for name, plant, Q, R in _plants_for_the_nominal_loop():
        lm = plant.linear_model(discretization="euler")
        A, B = lm.A, lm.B
        m = B.shape[1]
        R = 0.1 * np.eye(m) if R is None else R
        for terminal in ("Q", 2.0 * Q):
            Qf = Q if isinstance(terminal, str) else terminal
            # the reference gain: first move of the condensed QP's unconstrained optimum, column by column
            H, _ = condensed(A, B, Q, R, Qf, horizon, np.zeros(A.shape[0]))
            K = np.column_stack(
                [np.linalg.solve(H, condensed(A, B, Q, R, Qf, horizon, e)[1])[:m] for e in np.eye(A.shape[0])]
            )
            radius = np.max(np.abs(np.linalg.eigvals(A - B @ K)))
            kw = dict(horizon=horizon, terminal_cost=terminal, discretization="euler")
            if radius >= 1.0 - 1e-9:
                with pytest.raises(NotStabilizable) as info:
                    LinearMPC.from_plant(plant, Q, R, **kw)
                text = str(info.value)
                assert f"spectral radius {radius:.4g} >= 1" in text, (name, text)
                assert "longer horizon" in text and "terminal_cost = 'lqr'" in text
                outcomes.add("refused")
            else:
                mpc = LinearMPC.from_plant(plant, Q, R, **kw)
                np.testing.assert_allclose(mpc.K_mpc, K, rtol=1e-6, atol=1e-9 * np.abs(K).max())
                outcomes.add("built")
    if horizon == 1:
        assert "refused" in outcomes  # the cart-pole at N = 1 (radius 1.07) among others
    if horizon == 40:
        assert "built" in outcomes


def test_a_stabilizing_short_horizon_builds_and_settles():
    """The fix the message names works: terminal_cost='lqr' at N = 1, or a longer horizon with 'Q'."""
    plant = CartPole(dt=0.02)
    with pytest.raises(NotStabilizable, match=r"horizon = 26 is the shortest that stabilizes it"):
        LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=1, terminal_cost="Q", discretization="euler")
    for mpc in (
        LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=1, terminal_cost="lqr"),
        LinearMPC.from_plant(plant, Q_CP, R_CP, horizon=50, terminal_cost="Q"),  # spectral radius 0.985
    ):
        x = np.array([0.0, 0.0, 0.1, 0.0])
        for _ in range(1000):
            x = mpc.A @ x + mpc.B @ mpc(x)
        assert np.abs(x).max() < 1e-3


# ------------------------------------------------------------------ threads
@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_one_controller_called_from_four_threads_equals_a_serial_run(cartpole, solver):
    """4 threads x 1,000 calls on one LinearMPC give each state's serial answer (the lock serializes the steps)."""
    import threading

    _, A, B = cartpole
    kw = dict(u_min=-3.0, u_max=3.0, solver=solver, **cart_bounds(0.6))  # no rate bounds: u depends on x only
    rng = np.random.default_rng(11)
    states = rng.uniform(-1, 1, (4, 1000, 4)) * np.array([0.3, 0.3, 0.2, 0.3])
    serial = LinearMPC(A, B, Q_CP, R_CP, 10, **kw)
    expected = np.array([[serial(x)[0] for x in chunk] for chunk in states])
    shared = LinearMPC(A, B, Q_CP, R_CP, 10, **kw)
    got = np.full((4, 1000), np.nan)
    errors: list[BaseException] = []
    start = threading.Barrier(4)

    def work(i: int) -> None:
        try:
            start.wait()
            for k, x in enumerate(states[i]):
                got[i, k] = shared(x)[0]
        except BaseException as exc:  # reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[:1]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)


def test_osqp_adapter_detects_a_second_thread():
    """OsqpQP raises ConcurrentUse for a call from a thread other than the latest update's, never crashes."""
    import threading

    from shinro_ctrl.controllers._osqp import OsqpQP
    from shinro_ctrl.errors import ConcurrentUse

    P = sp.csc_matrix(np.eye(2))
    A = sp.csc_matrix(np.eye(2))
    qp = OsqpQP("test QP", P, np.zeros(2), A, -np.ones(2), np.ones(2), {"verbose": False})
    qp.update(np.array([1.0, -1.0]), -np.ones(2), np.ones(2))  # the main thread owns the latest update
    caught: list[BaseException] = []
    t = threading.Thread(target=lambda: _call_into(qp.solve, caught))
    t.start()
    t.join()
    assert len(caught) == 1 and isinstance(caught[0], ConcurrentUse) and "another thread" in str(caught[0])
    sol, info = qp.solve()  # the owner goes on
    assert info.status == "solved"
    np.testing.assert_allclose(sol.x, [-1.0, 1.0], atol=1e-2)  # OSQP at its default eps 1e-3
    # a thread that takes over starts with an update and then owns the object
    done: list[BaseException] = []
    t = threading.Thread(
        target=lambda: _call_into(lambda: (qp.update(None, -np.ones(2), np.ones(2)), qp.solve()), done)
    )
    t.start()
    t.join()
    assert not done
    # four threads hammering one object: each sequence solves or is refused with ConcurrentUse, nothing else
    outcomes: list[str] = []

    def hammer() -> None:
        for _ in range(1000):
            try:
                qp.update(None, -np.ones(2), np.ones(2))
                qp.solve()
                outcomes.append("solved")
            except ConcurrentUse:
                outcomes.append("refused")

    threads = [threading.Thread(target=hammer) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(outcomes) == 4000 and set(outcomes) <= {"solved", "refused"}


def _call_into(fn, sink: list) -> None:
    try:
        fn()
    except BaseException as exc:  # handed to the main thread
        sink.append(exc)


# ---------------------------------------------------------------- settings
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("key", ["eps_abs", "eps_rel", "rho", "alpha", "time_limit"])
def test_non_finite_osqp_settings_are_refused_in_one_line(cartpole, key, value):
    _, A, B = cartpole
    with pytest.raises(InvalidArgument) as info:
        LinearMPC(A, B, Q_CP, R_CP, 10, osqp_settings={key: value})
    assert str(info.value) == f"osqp_settings: '{key}' must be a finite number, got {value!r}"


def test_non_finite_osqp_setting_in_a_scenario_file_exits_2_with_one_line(tmp_path):
    from tests.cli_runner import cli

    scenario = tmp_path / "mpc_nan.toml"
    scenario.write_text(
        '[plant]\ntype = "CartPole"\ndt = 0.02\n\n[controller]\ntype = "LinearMPC"\nhorizon = 20\nQ = [10, 1, 100, 1]\n'
        "R = [0.1]\nosqp_settings = { eps_abs = nan }\n\n[sim]\nduration = 0.1\n"
    )
    res = cli("design", "mpc", str(scenario))
    assert res.returncode == 2, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "'eps_abs' must be a finite number, got nan" in lines[0], res.stderr


@pytest.mark.parametrize("solver", ["auto", "osqp"])
def test_design_mpc_prints_the_backend_in_use(tmp_path, solver):
    """``design mpc`` prints the sizes and settings of the backend that solves, not OSQP's while DAQP solves."""
    from tests.cli_runner import cli

    scenario = tmp_path / "mpc.toml"
    scenario.write_text(
        '[plant]\ntype = "CartPole"\ndt = 0.02\n\n[controller]\ntype = "LinearMPC"\nhorizon = 20\nQ = [10, 1, 100, 1]\n'
        f'R = [0.1]\nu_min = [-3.0]\nu_max = [3.0]\nsolver = "{solver}"\n\n[sim]\nduration = 0.2\n'
    )
    res = cli("design", "mpc", str(scenario))
    assert res.returncode == 0, res.stderr
    if solver == "auto":  # N·m = 20: DAQP
        assert "backend: daqp" in res.stdout and "condensed QP (DAQP): 20 variables" in res.stdout
        assert "DAQP settings: " in res.stdout and "OSQP" not in res.stdout
    else:
        assert "backend: osqp" in res.stdout and "sparse QP (OSQP): 104 variables" in res.stdout
        assert "OSQP settings: " in res.stdout and "eps_abs=0.0001" in res.stdout and "DAQP" not in res.stdout
