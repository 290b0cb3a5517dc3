"""The RTI's bound-active QP in the Riccati policy's prestabilized variables (issue 27, ``qp/prestabilized.py``).

References independent of the code under test: the condensed QP of ``CondensedLTV`` (its own condensing in numpy,
its Hessian, DAQP on simple input bounds) and a Riccati recursion written out here in numpy. On an unstable random
LTV problem (the swing-up's situation): ``Tᵀ H T`` is the block diagonal of ``R_e``, the condition number falls by
orders of magnitude, and the QP's solution, its state-bound multipliers and KKT residual are the condensed QP's.
"""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.controllers.qp.ltv import CondensedLTV
from shinro_ctrl.controllers.qp.prestabilized import PrestabilizedLTV

N, n, m = 15, 4, 2


def _riccati(G, W, R, e, du, dx0):
    """Policy gains, R_e blocks, the unconstrained step and its free response, by the recursion in numpy."""
    A, B, d = G[:, :, :n], G[:, :, n : n + m], G[:, :, n + m]
    P, p = np.zeros((n, n)), np.zeros(n)
    K, kap, Re = np.zeros((N, m, n)), np.zeros((N, m)), np.zeros((N, m, m))
    for k in range(N - 1, -1, -1):
        S = W[k] + P
        h = S @ d[k] + W[k] @ e[k] + p
        Re[k] = R + B[k].T @ S @ B[k]
        K[k] = -np.linalg.solve(Re[k], B[k].T @ S @ A[k])
        kap[k] = -np.linalg.solve(Re[k], B[k].T @ h + R @ du[k])
        P = A[k].T @ S @ A[k] + (B[k].T @ S @ A[k]).T @ K[k]
        p = A[k].T @ h + (B[k].T @ S @ A[k]).T @ kap[k]
    dU, dX, fX = np.zeros((N, m)), np.zeros((N, n)), np.zeros((N, n))
    x, f = dx0, dx0
    for k in range(N):
        dU[k] = K[k] @ x + kap[k]
        x = A[k] @ x + B[k] @ dU[k] + d[k]
        f = A[k] @ f + d[k]
        dX[k], fX[k] = x, f
    return K, Re, dU, dX, fX


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(11)
    G = rng.standard_normal((N, n, n + m + 1)) * 0.3
    G[:, :, :n] += 1.25 * np.eye(n)  # unstable open loop: the condensed Hessian is ill-conditioned
    W = np.stack([np.diag([10.0, 1.0, 10.0, 1.0])] * N)
    R = 0.1 * np.eye(m)
    e, du, dx0 = rng.standard_normal((N, n)), 0.1 * rng.standard_normal((N, m)), rng.standard_normal(n)
    u_lo, u_hi = np.full(m, -0.4), np.full(m, 0.4)
    x_lo, x_hi = np.array([-0.6, -np.inf, -np.inf, -np.inf]), np.array([0.6, np.inf, np.inf, np.inf])
    Ubar, Xnext = 0.05 * rng.standard_normal((N, m)), 0.1 * rng.standard_normal((N, n))
    return G, W, R, e, du, dx0, (u_lo, u_hi, x_lo, x_hi), Ubar, Xnext


def test_prestabilized_hessian_is_block_diagonal_and_well_conditioned(problem):
    G, W, R, e, du, dx0, bounds, _, _ = problem
    K, Re, *_ = _riccati(G, W, R, e, du, dx0)
    inf = np.full(n, np.inf)
    cond = CondensedLTV(G, W, R, bounds[0], bounds[1], -inf, inf)
    cond.build(e.ravel(), du.ravel())
    pqp = PrestabilizedLTV(G, *bounds)
    pqp.factor_rows(K, Re)
    H, T = cond.H, pqp.T
    D = np.zeros_like(H)
    for k in range(N):
        D[k * m : (k + 1) * m, k * m : (k + 1) * m] = Re[k]
    np.testing.assert_allclose(T.T @ H @ T, D, rtol=0, atol=1e-9 * np.abs(D).max())
    assert np.allclose(np.tril(T), T) and np.all(np.diag(T) == 1.0)  # unit lower triangular
    assert np.linalg.cond(H) > 1e5 and np.linalg.cond(D) < 1e2


@pytest.mark.parametrize("soft", [True, False])
def test_prestabilized_qp_equals_the_condensed_qp(problem, soft):
    G, W, R, e, du, dx0, bounds, Ubar, Xnext = problem
    u_lo, u_hi, x_lo, x_hi = bounds
    if not soft:
        x_lo, x_hi = 100 * x_lo, 100 * x_hi  # hard bounds the problem can meet (the unstable modes grow)
    K, Re, dU_s, dX_s, fX = _riccati(G, W, R, e, du, dx0)
    cond = CondensedLTV(G, W, R, u_lo, u_hi, x_lo, x_hi, soft=soft)
    cond.build(e.ravel(), du.ravel())
    cond.set_bounds(Ubar, Xnext)
    z, ok, _, _ = cond.solve(dx0)
    assert ok
    dU_ref, dX_ref = cond.step(z, dx0)
    pqp = PrestabilizedLTV(G, u_lo, u_hi, x_lo, x_hi, soft=soft)
    ok, status, it = pqp.solve(K, Re, dU_s, dX_s, Ubar, Xnext)
    assert ok and it > 0, status
    active_u = np.count_nonzero(cond.lam[: N * m])
    active_x = np.count_nonzero(cond.state_bound_multipliers())
    assert active_u >= 3 and active_x >= (1 if soft else 0)  # input and (soft) state bounds are active
    scale = np.abs(dU_ref).max()
    np.testing.assert_allclose(pqp.dU, dU_ref, rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(pqp.dX, dX_ref, rtol=0, atol=1e-8 * np.abs(dX_ref).max())
    lam_ref = cond.state_bound_multipliers()
    tol = 1e-6 * max(1.0, np.abs(lam_ref).max())
    np.testing.assert_allclose(pqp.state_bound_multipliers(), lam_ref, rtol=0, atol=tol)
    g = cond.g0[: N * m] + cond.Gx[: N * m] @ dx0  # the gradient at ΔU = 0
    assert pqp.kkt(g, fX) == pytest.approx(cond.kkt(z), rel=1e-6)


def test_non_finite_data_fail_with_a_reason(problem):
    G, W, R, e, du, dx0, bounds, Ubar, Xnext = problem
    K, Re, dU_s, dX_s, _ = _riccati(G, W, R, e, du, dx0)
    pqp = PrestabilizedLTV(G, *bounds, soft=True)
    K = K.copy()
    K[3, 0, 0] = np.nan
    ok, status, _ = pqp.solve(K, Re, dU_s, dX_s, Ubar, Xnext)
    assert not ok and "not finite" in status and "not finite" in pqp.explain()
