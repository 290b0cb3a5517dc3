"""NonlinearMPC on the 7-DOF arm: the reach scenario in both loops, the condensing and the compiled linearization.

The reach (``configs/panda_nmpc_reach_mujoco.toml``) runs here for 1 s of its 2 s with the stage linearization
in CasADi's virtual machine (``codegen = false``): the compiled one gives the same numbers (checked below on a
small plant, whose C code builds in a fraction of a second), and the arm's 20,000-instruction stage function would
cost the suite a few seconds of compilation on a fresh cache. With the linearization in the virtual machine the
reach keeps condensing + DAQP at every call; the compiled Riccati step that replaces them on the arm's benchmark is
checked against them below, on a small problem and on a pendulum's closed loop (compiled in under a second).
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from shinro_ctrl.controllers._nmpc_ocp import riccati_functions
from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.controllers.qp.ltv import CondensedLTV
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.plants import InvertedPendulum
from shinro_ctrl.resources import config_path
from shinro_ctrl.sim import RobotSim

READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def _reach(engine: str):
    with open(config_path("panda_nmpc_reach_mujoco.toml"), "rb") as fh:
        doc = tomllib.load(fh)
    doc["controller"]["codegen"] = False
    doc["sim"]["duration"] = 1.0
    sim = RobotSim.from_config(doc, engine=engine)
    return sim, sim.run()


@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_reach_holds_the_torque_limits_at_every_step_and_reaches_the_target(engine):
    sim, res = _reach(engine)
    assert (sim.engine is not None) == (engine == "mujoco")
    c = sim.controller
    X, U = res.x, res.u
    target = c.x0[:7]
    np.testing.assert_allclose(X[0, :7], READY, atol=1e-12)
    assert np.all(np.abs(target - READY) >= 0.75)  # a large excursion on every joint
    # the hard input bounds at every step (the returned input is the solver's, clipped)
    violation = max(float(np.max(U - c.u_max)), float(np.max(c.u_min - U)), 0.0)
    assert violation <= 1e-12
    # and they bind: the first steps run at the limits of the big joints
    assert np.sum(np.isclose(np.abs(U[:10, :4]), 0.87, rtol=0, atol=1e-12)) >= 10
    # gravity matters: the input that holds the target differs from the one that holds the ready pose
    assert abs(c.u0[1]) > 0.25
    # reached: 1e-4 rad after 1 s (measured 1.1e-4 standalone; MuJoCo's Euler is the same step)
    assert np.max(np.abs(X[-1, :7] - target)) < 5e-4
    assert np.max(np.abs(X[-1, 7:])) < 5e-3
    assert c.last.qp_status == "solved" and c.last.status == "rti"


def _explicit_condensing(G, W, R, e, du, dx0):
    """``Γ``, ``Φ``, ``c`` built block by block from their definition, and ``H``, ``g_0``, ``G_x`` from them."""
    N, n, w = G.shape
    m = w - n - 1
    A, B, d = G[:, :, :n], G[:, :, n : n + m], G[:, :, n + m]
    Gam = np.zeros((N * n, N * m))
    Phi = np.zeros((N * n, n))
    c = np.zeros(N * n)
    P, cc = np.eye(n), np.zeros(n)
    for k in range(N):
        P, cc = A[k] @ P, A[k] @ cc + d[k]
        Phi[k * n : (k + 1) * n], c[k * n : (k + 1) * n] = P, cc
        for j in range(k + 1):
            blk = B[j]
            for i in range(j + 1, k + 1):
                blk = A[i] @ blk
            Gam[k * n : (k + 1) * n, j * m : (j + 1) * m] = blk
    Qbar = np.zeros((N * n, N * n))
    for k in range(N):
        Qbar[k * n : (k + 1) * n, k * n : (k + 1) * n] = W[k]
    Rbar = np.kron(np.eye(N), R)
    H = Gam.T @ Qbar @ Gam + Rbar
    return H, Gam.T @ Qbar @ (e + c) + Rbar @ du, Gam.T @ Qbar @ Phi, Gam, Phi, c


@pytest.mark.parametrize("bounded", [False, True], ids=["inputs-only", "soft-state-bound"])
@pytest.mark.parametrize(("N", "n", "m", "direct"), [(7, 5, 2, True), (20, 6, 3, False)], ids=["direct", "recursive"])
def test_condensing_equals_the_explicit_construction(bounded, N, n, m, direct):
    rng = np.random.default_rng(11)
    G = rng.standard_normal((N, n, n + m + 1))
    G[:, :, :n] *= 0.3
    G[:, :, :n] += np.eye(n)  # an unstable prediction
    L = rng.standard_normal((N, n, n))
    W = L @ np.swapaxes(L, 1, 2) + 0.1 * np.eye(n)
    R = np.diag(rng.uniform(0.5, 2.0, m))
    x_min, x_max = np.full(n, -np.inf), np.full(n, np.inf)
    if bounded:
        x_min[1], x_max[1] = -0.5, 0.5
    qp = CondensedLTV(G, W, R, np.full(m, -1.0), np.full(m, 1.0), x_min, x_max, soft=bounded)
    assert qp.direct == direct  # the algorithm chosen by size: one product Γᵀ Q̄ Γ, or the backward recursion
    e, du, dx0 = rng.standard_normal(N * n), rng.standard_normal(N * m), rng.standard_normal(n)
    qp.build(e, du)
    H, g0, Gx, Gam, Phi, c = _explicit_condensing(G, W, R, e, du, dx0)
    nu = N * m
    scale = np.max(np.abs(H))
    np.testing.assert_allclose(qp.H[:nu, :nu], H, rtol=0, atol=1e-12 * scale)
    if not direct:  # symmetric by construction (U + Uᵀ)
        np.testing.assert_array_equal(qp.H, qp.H.T)
    np.testing.assert_allclose(qp.g0[:nu], g0, rtol=0, atol=1e-12 * np.max(np.abs(g0)))
    np.testing.assert_allclose(qp.Gx[:nu], Gx, rtol=0, atol=1e-12 * np.max(np.abs(Gx)))
    X = rng.standard_normal((N + 1, n))
    qp.set_bounds(rng.uniform(-0.5, 0.5, (N, m)), X[1:])
    z, ok, _, _ = qp.solve(dx0)
    assert ok
    dU, dX = qp.step(z, dx0)
    ref = Gam @ dU + Phi @ dx0 + c
    np.testing.assert_allclose(dX.ravel(), ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))


def test_compiled_linearization_equals_the_virtual_machine():
    plant = InvertedPendulum(dt=0.05)
    kw = dict(horizon=5, u_min=-1.0, u_max=1.0, cold_start="sqp")
    vm = NonlinearMPC.from_plant(plant, [10.0, 0.1], [1.0], codegen=False, **kw)
    cc = NonlinearMPC.from_plant(plant, [10.0, 0.1], [1.0], codegen=True, **kw)
    assert "SXFunction" in repr(vm.ocp.linearization.find_function("nmpc_stage"))
    assert "SXFunction" not in repr(cc.ocp.linearization.find_function("nmpc_stage"))  # an external (or the VM)
    rng = np.random.default_rng(5)
    X, U = rng.standard_normal((2, 6)), rng.standard_normal((1, 5))
    np.testing.assert_array_equal(np.array(vm.ocp.linearization(X, U)), np.array(cc.ocp.linearization(X, U)))
    with pytest.raises(InvalidArgument, match="codegen"):
        NonlinearMPC.from_plant(plant, [10.0, 0.1], [1.0], codegen="yes", **kw)


@pytest.mark.parametrize("codegen", [False, True], ids=["vm", "compiled"])
def test_riccati_step_equals_the_condensed_qp_minimizer(codegen):
    """The Riccati recursion's unconstrained step, rollout and gradient against the condensed QP (numpy, LAPACK)."""
    N, n, m = 8, 5, 2
    rng = np.random.default_rng(3)
    G = rng.standard_normal((N, n, n + m + 1))
    G[:, :, :n] *= 0.2
    G[:, :, :n] += np.eye(n)
    L = rng.standard_normal((N, n, n))
    W = L @ np.swapaxes(L, 1, 2) + 0.1 * np.eye(n)
    R = np.diag(rng.uniform(0.5, 2.0, m))
    e, du, dx0 = rng.standard_normal(N * n), rng.standard_normal(N * m), rng.standard_normal(n)
    back, fwd = riccati_functions(n, m, N, codegen)
    assert ("External" in repr(back)) == codegen  # the compiled library, or the virtual machine
    Gt, Wt = G.reshape(N * n, -1).T, np.swapaxes(W, 1, 2).reshape(N * n, n).T  # the column-major layouts
    KK, _ = back(Gt, Wt, R, e, du)
    dU, dX, g, _ = (np.array(v).T for v in fwd(Gt, KK, Wt, R, e, du, dx0))
    inf = np.full(n, np.inf)
    qp = CondensedLTV(G, W, R, np.full(m, -np.inf), np.full(m, np.inf), -inf, inf)
    qp.build(e, du)
    g_ref = qp.g0 + qp.Gx @ dx0
    z = -np.linalg.solve(qp.H, g_ref)
    _, dX_ref = qp.step(z, dx0)
    np.testing.assert_allclose(g.ravel(), g_ref, rtol=0, atol=1e-12 * np.max(np.abs(g_ref)))
    np.testing.assert_allclose(dU.ravel(), z, rtol=0, atol=1e-12 * np.max(np.abs(z)))
    np.testing.assert_allclose(dX, dX_ref, rtol=0, atol=1e-12 * np.max(np.abs(dX_ref)))


def test_daqp_warm_start_from_the_last_active_set_gives_the_cold_solution():
    N, n, m = 20, 6, 3
    rng = np.random.default_rng(7)
    G = rng.standard_normal((N, n, n + m + 1))
    G[:, :, :n] *= 0.1
    G[:, :, :n] += np.eye(n)
    W = np.stack([np.eye(n)] * N)
    R = 0.1 * np.eye(m)
    inf = np.full(n, np.inf)
    qp = CondensedLTV(G, W, R, np.full(m, -0.3), np.full(m, 0.3), -inf, inf)
    assert qp.warm_start and not qp.direct  # on for the large (recursive) problems only
    e, du, dx0 = 3 * rng.standard_normal(N * n), np.zeros(N * m), rng.standard_normal(n)
    qp.build(e, du)
    qp.set_bounds(np.zeros((N, m)), np.zeros((N, n)))
    z_cold, ok, _, it_cold = qp.solve(dx0)
    active = np.flatnonzero(qp.lam[: N * m])
    assert ok and active.size >= 5 and it_cold > active.size  # one iteration per bound added, cold
    z_warm, ok, _, it_warm = qp.solve(dx0)  # the same QP from its own active set
    assert ok and it_warm < it_cold
    np.testing.assert_allclose(z_warm, z_cold, rtol=0, atol=1e-12)
    qp.shift_active_set()  # the RTI shift (stage k + 1's set becomes stage k's): a start, not the answer
    z_shift, ok, _, _ = qp.solve(dx0)
    assert ok
    np.testing.assert_allclose(z_shift, z_cold, rtol=0, atol=1e-12)
    qp.clear_active_set()
    z_again, ok, _, it_again = qp.solve(dx0)
    assert ok and it_again == it_cold
    np.testing.assert_array_equal(z_again, z_cold)


def test_the_riccati_step_first_gives_the_closed_loop_of_the_condensed_qp():
    """RTI with the compiled Riccati step (DAQP only where a bound is reached) against condensing + DAQP throughout.

    The pendulum at N = 52 is a large (recursive) condensed QP; compiled (``codegen = true``) it takes the
    Riccati step first, in the virtual machine it does not.
    """
    kw = dict(horizon=52, u_min=-0.5, u_max=0.5, cold_start="sqp")
    runs = []
    for codegen in (True, False):
        plant = InvertedPendulum(dt=0.02)
        c = NonlinearMPC.from_plant(plant, [10.0, 0.1], [1.0], codegen=codegen, **kw)
        assert c.strategy.riccati == codegen
        plant.set_state(np.array([0.8, 0.0]))
        x = plant.get_state()
        U, daqp_calls = [], []
        for _ in range(40):
            u = c(x)
            U.append(u)
            daqp_calls.append(c.last.qp_iterations > 0)
            x = plant.step(u)
        runs.append((np.array(U), daqp_calls))
    (U_ric, daqp_ric), (U_ref, daqp_ref) = runs
    assert all(daqp_ref) and 5 <= sum(daqp_ric) <= 35  # the torque bound binds at first: both paths ran
    assert np.max(np.abs(U_ric)) == 0.5
    np.testing.assert_allclose(U_ric, U_ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("soft", [False, True])
def test_the_riccati_step_first_with_state_bounds_gives_the_closed_loop_of_the_condensed_qp(soft):
    """The Riccati step with state bounds: taken only where the predicted states meet them, else condensing + DAQP.

    The speed bound binds while the pendulum swings back (unbounded, it reaches -2.398 rad/s), so both paths
    run; the closed loop equals condensing + DAQP throughout to 1e-12.
    """
    kw = dict(horizon=52, u_min=-0.5, u_max=0.5, cold_start="sqp", soft=soft)
    kw |= dict(x_min=[-np.inf, -2.40])
    runs = []
    for codegen in (True, False):
        plant = InvertedPendulum(dt=0.02)
        c = NonlinearMPC.from_plant(plant, [10.0, 0.1], [1.0], codegen=codegen, **kw)
        assert c.strategy.riccati == codegen
        plant.set_state(np.array([0.8, 0.0]))
        x = plant.get_state()
        U, X, daqp_calls = [], [], []
        for _ in range(40):
            u = c(x)
            U.append(u)
            daqp_calls.append(c.last.qp_iterations > 0)
            x = plant.step(u)
            X.append(x)
        runs.append((np.array(U), np.array(X), daqp_calls))
    (U_ric, X_ric, daqp_ric), (U_ref, _, daqp_ref) = runs
    assert all(daqp_ref) and 5 <= sum(daqp_ric) <= 35
    assert -2.40 - 1e-9 <= X_ric[:, 1].min() < -2.39  # the speed bound was reached and held
    np.testing.assert_allclose(U_ric, U_ref, rtol=0, atol=1e-12)
