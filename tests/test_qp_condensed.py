"""Tests of the condensed MPC QP (controllers/qp/condensed.py) against independent exact solves.

References, all built here without the module under test:

* a plain condensed QP in the inputs ``U`` (no pre-stabilization), built by
  simulating the model column by column, with the cost written stage by stage;
* its exact optimum: scipy's BVLS (``lsq_linear(method="bvls")``) on the
  Cholesky factor when only the inputs are bounded, else an active set taken
  started from ``trust-constr`` at tight tolerances and finished by a primal
  active-set method on linearly independent working sets (degenerate active
  sets allowed), certified by the KKT conditions (primal feasibility,
  stationarity, multiplier signs);
* the discrete LQR from ``scipy.linalg.solve_discrete_are``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

from shinro_ctrl.controllers.qp.condensed import CondensedQP
from shinro_ctrl.plants import CartPole

INF = np.inf
Q_CP = np.diag([10.0, 1.0, 100.0, 1.0])
R_CP = np.array([[0.1]])
CART = (np.array([-0.6, -INF, -INF, -INF]), np.array([0.6, INF, INF, INF]))


@pytest.fixture(scope="module")
def model() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cart-pole (dt = 0.02, Euler), its DARE matrix ``P`` and LQR gain ``K`` (scipy)."""
    A, B = CartPole(dt=0.02).get_model()
    P = scipy.linalg.solve_discrete_are(A, B, Q_CP, R_CP)
    K = np.linalg.solve(R_CP + B.T @ P @ B, B.T @ P @ A)
    return A, B, P, K


def plain_qp(A, B, Q, R, Qf, N, x0, d=None, ref=None, u_ref=None):
    """``(H, f, Φ, Γ, c)`` of ``min ½ UᵀHU + fᵀU`` with ``X = Φ x0 + Γ U + c`` (x_0 … x_N) by simulation."""
    n, m = B.shape
    d = np.zeros(n) if d is None else d
    Phi = np.zeros(((N + 1) * n, n))
    Gam = np.zeros(((N + 1) * n, N * m))
    c = np.zeros((N + 1) * n)
    for k in range(N + 1):
        Phi[k * n : (k + 1) * n] = np.linalg.matrix_power(A, k)
    for j in range(N * m):  # response to a unit input j, zero start, no offset
        u = np.zeros(N * m)
        u[j] = 1.0
        x = np.zeros(n)
        for k in range(N):
            x = A @ x + B @ u[k * m : (k + 1) * m]
            Gam[(k + 1) * n : (k + 2) * n, j] = x
    x = np.zeros(n)
    for k in range(N):
        x = A @ x + d
        c[(k + 1) * n : (k + 2) * n] = x
    Qb = scipy.linalg.block_diag(*([Q] * N + [Qf]))
    Rb = np.kron(np.eye(N), R)
    r = np.zeros((N + 1) * n) if ref is None else np.tile(ref, N + 1)
    ur = np.zeros(N * m) if u_ref is None else np.tile(u_ref, N)
    H = Gam.T @ Qb @ Gam + Rb
    f = Gam.T @ Qb @ (Phi @ x0 + c - r) - Rb @ ur
    return 0.5 * (H + H.T), f, Phi, Gam, c


def bvls(H, f, lo, hi):
    """Exact minimizer of ``½ UᵀHU + fᵀU`` on the box ``[lo, hi]`` (BVLS on ``H = L Lᵀ``).

    ``max_iter`` well above BVLS's default (the number of variables), which can stop it short of the optimum.
    """
    L = np.linalg.cholesky(H)
    res = scipy.optimize.lsq_linear(
        L.T, -np.linalg.solve(L, f), bounds=(lo, hi), method="bvls", tol=1e-15, max_iter=100 * f.size + 100
    )
    assert res.success
    return res.x


def exact_qp(H, f, G, lo, hi):
    """Certified minimizer of ``½ zᵀHz + fᵀz  s.t.  lo ≤ G z ≤ hi`` (``H`` positive definite).

    ``trust-constr`` (tight tolerances) gives a starting point; a primal
    active-set method (Nocedal & Wright, Algorithm 16.3) finishes exactly
    from it. Its working set starts as a linearly *independent* subset of the
    nearly active rows (a box row and a rate row active at the same input
    are dependent: only one enters) with the point projected onto them, and
    stays independent: a blocking row ``g`` has ``gᵀp ≠ 0`` along a step
    ``p`` that every working row keeps at ``0``. Each KKT system is therefore
    nonsingular, its multipliers unique. The result is certified by the KKT
    conditions themselves (primal feasibility, multiplier signs, stationarity),
    which for a strictly convex QP make it the unique optimum.
    """
    res = scipy.optimize.minimize(
        lambda z: 0.5 * z @ H @ z + f @ z,
        np.zeros(f.size),
        jac=lambda z: H @ z + f,
        hess=lambda z: H,
        method="trust-constr",
        constraints=[scipy.optimize.LinearConstraint(G, lo, hi)],
        options={"gtol": 1e-12, "xtol": 1e-14, "maxiter": 20000},
    )
    norms = np.linalg.norm(G, axis=1)
    scale = np.where(norms > 0, norms, 1.0)  # a zero row (x_1's position under Euler) is checked unscaled
    nz = f.size
    z = res.x
    gz = G @ z
    near = np.minimum(np.abs(gz - hi), np.abs(gz - lo)) / scale
    side = np.zeros(G.shape[0], dtype=int)
    for i in np.argsort(near):  # the closest rows first, each only if independent of those taken
        if near[i] > 1e-6 or norms[i] == 0:
            break
        rows = np.flatnonzero(side)
        if np.linalg.matrix_rank(G[np.append(rows, i)], tol=1e-10 * norms.max()) == rows.size + 1:
            side[i] = 1 if abs(gz[i] - hi[i]) <= abs(gz[i] - lo[i]) else -1
    rows = np.flatnonzero(side)
    if rows.size:
        b = np.where(side[rows] > 0, hi[rows], lo[rows])
        z = z + np.linalg.lstsq(G[rows], b - G[rows] @ z, rcond=None)[0]
    for _ in range(1000):
        rows = np.flatnonzero(side)
        Ga = G[rows]
        K = np.block([[H, Ga.T], [Ga, np.zeros((rows.size, rows.size))]])
        sol = np.linalg.solve(K, np.concatenate([-(H @ z + f), np.zeros(rows.size)]))
        p, lam = sol[:nz], sol[nz:]
        if np.linalg.norm(p) <= 1e-13 * (1.0 + np.linalg.norm(z)):
            mu = lam * side[rows]  # multipliers in the sign convention of each row's side: must be >= 0
            if not mu.size or mu.min() >= -1e-10 * max(1.0, np.abs(mu).max()):
                break
            side[rows[int(np.argmin(mu))]] = 0
            continue
        # step to the first blocking row outside the working set; rows in the working set's span never block
        # (their gᵀp is zero up to rounding, which a small step can make look like a block at alpha = 0)
        gz, gp = G @ z, G @ p
        basis = np.linalg.qr(Ga.T)[0] if rows.size else np.zeros((nz, 0))
        outside = np.linalg.norm(G.T - basis @ (basis.T @ G.T), axis=0) > 1e-9 * scale
        alpha, block = 1.0, -1
        for i in np.flatnonzero((side == 0) & outside & (gp != 0)):
            a = ((hi[i] if gp[i] > 0 else lo[i]) - gz[i]) / gp[i]
            if a < alpha:
                alpha, block = max(a, 0.0), i
        z = z + alpha * p
        if block >= 0:
            side[block] = 1 if gp[block] > 0 else -1
    else:
        raise AssertionError("reference active-set method did not converge")
    # the certificate: feasible, stationary, multipliers of the right signs
    rows = np.flatnonzero(side)
    viol = np.maximum(G @ z - hi, lo - G @ z) / scale
    assert viol.max(initial=0.0) <= 1e-9, viol.max()
    lam = np.linalg.lstsq(G[rows].T, -(H @ z + f), rcond=None)[0]
    assert np.linalg.norm(H @ z + f + G[rows].T @ lam) <= 1e-9 * max(1.0, np.linalg.norm(f))
    assert np.all(lam * side[rows] >= -1e-10 * max(1.0, np.abs(lam).max(initial=0.0)))
    return z


def states(rng, count, scale):
    return [rng.uniform(-1, 1, 4) * s for s in scale for _ in range(count)]


@pytest.mark.parametrize("N", [1, 10, 50, 200])
def test_unconstrained_dare_equals_lqr(model, rng, N):
    """No bounds, DARE terminal cost: the first move is −K x to 1e-8 relative at |x| <= 0.02."""
    A, B, P, K = model
    qp = CondensedQP(A, B, Q_CP, R_CP, P, N)
    u = np.empty(1)
    for x in states(rng, 5, [1e-9, 1e-4, 0.02]):
        info = qp.solve(x)
        assert info.solved and info.active_set_size == 0
        qp.first_input(u)
        np.testing.assert_allclose(u, -K @ x, rtol=1e-8, atol=1e-14 * np.abs(x).max())
    # the pre-stabilized Hessian is (R + BᵀPB) I: condition number 1 at any horizon
    assert qp.cond_H == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("N", [10, 20])
def test_input_bounds_match_bvls(model, rng, N):
    """Input bounds only: the whole plan equals BVLS on the plain condensed QP, bounds active and inactive."""
    A, B, P, _ = model
    qp = CondensedQP(A, B, Q_CP, R_CP, P, N, u_min=[-3.0], u_max=[3.0])
    active = 0
    for x in states(rng, 4, [1e-6, 0.02, 0.2, 0.6]):
        H, f, *_ = plain_qp(A, B, Q_CP, R_CP, P, N, x)
        U_ref = bvls(H, f, np.full(N, -3.0), np.full(N, 3.0))
        info = qp.solve(x)
        assert info.solved and info.kkt_residual < 1e-9
        _, U, _ = qp.plan()
        scale = max(np.abs(U_ref).max(), 1e-300)
        np.testing.assert_allclose(U[:, 0], U_ref, rtol=0, atol=1e-6 * scale + 1e-15)
        np.testing.assert_allclose(U[0, 0], U_ref[0], rtol=1e-6, atol=1e-15)
        active += int(np.isclose(np.abs(U_ref), 3.0).any())
    assert active >= 4  # the larger states saturate the input, the small ones do not


def test_state_and_input_bounds_match_exact_qp(model, rng):
    """Hard cart bound and input bounds: plan equals the certified optimum (trust-constr active set + KKT)."""
    A, B, P, _ = model
    N = 12
    qp = CondensedQP(A, B, Q_CP, R_CP, P, N, u_min=[-3.0], u_max=[3.0], x_min=CART[0], x_max=CART[1])
    sel = np.arange(1, N + 1) * 4  # cart position rows of x_1 … x_N
    hits = 0
    for x in [np.array([0.5, 0.6, 0.1, 0.0]), np.array([-0.45, -0.5, -0.05, 0.1]), np.array([0.0, 0.0, 0.2, 0.0])]:
        H, f, Phi, Gam, c = plain_qp(A, B, Q_CP, R_CP, P, N, x)
        G = np.vstack([np.eye(N), Gam[sel]])
        off = (Phi @ x + c)[sel]
        lo = np.concatenate([np.full(N, -3.0), -0.6 - off])
        hi = np.concatenate([np.full(N, 3.0), 0.6 - off])
        U_ref = exact_qp(H, f, G, lo, hi)
        info = qp.solve(x)
        assert info.solved and info.kkt_residual < 1e-9
        X, U, _ = qp.plan()
        np.testing.assert_allclose(U[:, 0], U_ref, rtol=0, atol=1e-6 * np.abs(U_ref).max())
        assert np.abs(X[1:, 0]).max() <= 0.6 + 1e-9
        hits += int(np.isclose(np.abs(X[1:, 0]), 0.6, atol=1e-9).any())
    assert hits >= 1  # the state bound is active in at least one case


def test_references_offset_and_rate_bounds(model, rng):
    """Constant references, an affine term and rate bounds: equals the certified optimum of the plain QP."""
    A, B, P, _ = model
    N = 10
    d = np.array([0.0, 0.001, 0.0, -0.002])
    ref, u_ref, du, u_prev = np.array([0.3, 0.0, 0.0, 0.0]), np.array([0.5]), 0.4, np.array([1.0])
    qp = CondensedQP(A, B, Q_CP, R_CP, P, N, offset=d, u_min=[-3.0], u_max=[3.0], du_max=[du])
    qp.set_reference(ref, u_ref)
    for x in [np.array([0.0, 0.0, 0.25, 0.0]), np.array([0.1, -0.2, -0.1, 0.3])]:
        H, f, *_ = plain_qp(A, B, Q_CP, R_CP, P, N, x, d=d, ref=ref, u_ref=u_ref)
        D = np.eye(N) - np.eye(N, k=-1)
        G = np.vstack([np.eye(N), D])
        lo = np.concatenate([np.full(N, -3.0), np.full(N, -du)])
        hi = np.concatenate([np.full(N, 3.0), np.full(N, du)])
        lo[N] += u_prev[0]
        hi[N] += u_prev[0]
        U_ref = exact_qp(H, f, G, lo, hi)
        info = qp.solve(x, u_prev)
        assert info.solved and info.kkt_residual < 1e-9
        _, U, _ = qp.plan()
        np.testing.assert_allclose(U[:, 0], U_ref, rtol=0, atol=1e-6 * np.abs(U_ref).max())
        # the objective is the whole MPC cost, constants included: evaluate it on the plan
        _, _, Phi, Gam, c = plain_qp(A, B, Q_CP, R_CP, P, N, x, d=d)
        X = (Phi @ x + Gam @ U[:, 0] + c).reshape(N + 1, 4)
        J = 0.5 * sum((X[k] - ref) @ Q_CP @ (X[k] - ref) + (U[k] - u_ref) @ R_CP @ (U[k] - u_ref) for k in range(N))
        J += 0.5 * (X[N] - ref) @ P @ (X[N] - ref)
        assert info.objective == pytest.approx(J, rel=1e-9)


def test_soft_bounds_slack_zero_when_satisfiable(model):
    """Soft cart bound with an exact-penalty weight: zero slack and the hard solution where the hard QP is feasible."""
    A, B, P, _ = model
    N = 50
    kw = {"u_min": [-3.0], "u_max": [3.0], "x_min": CART[0], "x_max": CART[1]}
    hard = CondensedQP(A, B, Q_CP, R_CP, P, N, **kw)
    soft = CondensedQP(A, B, Q_CP, R_CP, P, N, soft=True, soft_weight_l1=1e4, soft_weight_quad=1.0, **kw)
    x = np.array([0.4, 0.5, 0.0, 0.0])  # the hard bound is active on this plan (multiplier ~700 < w_1)
    ih, is_ = hard.solve(x), soft.solve(x)
    assert ih.solved and is_.solved and is_.kkt_residual < 1e-8
    Xh, Uh, _ = hard.plan()
    Xs, Us, smax = soft.plan()
    np.testing.assert_allclose(Xs, Xh, rtol=0, atol=1e-9 * np.abs(Xh).max())
    assert np.isclose(np.abs(Xh[1:, 0]).max(), 0.6, atol=1e-9)
    assert smax <= 1e-12
    np.testing.assert_allclose(Us, Uh, rtol=0, atol=1e-9 * np.abs(Uh).max())
    assert is_.objective == pytest.approx(ih.objective, rel=1e-7)
    # beyond the hard problem's reach the slack takes the violation
    far = np.array([0.59, 2.0, 0.0, 0.0])
    assert hard.solve(far).status == "primal infeasible"
    info = soft.solve(far)
    assert info.solved and soft.plan()[2] > 1e-3


def test_infeasible_flag_and_explanation(model):
    """Hard bounds that cannot hold: DAQP's infeasible flag and a certificate naming group and stage."""
    A, B, P, _ = model
    qp = CondensedQP(A, B, Q_CP, R_CP, P, 30, u_min=[-3.0], u_max=[3.0], x_min=CART[0], x_max=CART[1])
    x = np.array([0.5, 2.0, 0.0, 0.0])  # 2 m/s towards the wall, 3 N to stop a 1 kg cart: cannot
    info = qp.solve(x)
    assert info.status == "primal infeasible" and info.exitflag == -1
    why = qp.explain_infeasibility(x)
    assert why is not None and why.startswith("state bounds at stage") and "input bounds" in why
    # a feasible state afterwards is solved (the failed working set is not kept)
    assert qp.solve(np.array([0.0, 0.0, 0.1, 0.0])).solved
    # a fixed row (x_1 = x_0 + dt v_0 under Euler) violated: no input moves it, so it is left out and reported;
    # the problem is still infeasible here, at stage 2, which is what the explanation names
    x1 = np.array([0.59, 1.0, 0.0, 0.0])
    assert qp.solve(x1).status == "primal infeasible"
    assert qp.dropped_rows.startswith("x[0] in [-0.6, 0.6] at stage 1: predicted 0.61 whatever the input")
    assert qp.explain_infeasibility(x1).startswith("state bounds at stage 2")
    # where the later stages can still be met, the step is solved with the note
    x2 = np.array([0.5999, 0.02, 0.0, 0.0])  # x_1 = 0.6003 > 0.6, then 3 N brakes the cart in time
    info = qp.solve(x2)
    assert info.solved and "at stage 1: predicted 0.6003" in qp.dropped_rows
    X, _, _ = qp.plan()
    assert X[1, 0] == pytest.approx(0.6003) and np.abs(X[2:, 0]).max() <= 0.6 + 1e-9


def test_long_horizon_unstable_cartpole(model):
    """N = 200 on the unstable cart-pole: well conditioned, solved, bounds held, and the first move matches N = 100."""
    A, B, P, _ = model
    kw = {"u_min": [-3.0], "u_max": [3.0], "x_min": CART[0], "x_max": CART[1]}
    long = CondensedQP(A, B, Q_CP, R_CP, P, 200, **kw)
    assert long.cond_H < 1.0 + 1e-9
    x = np.array([0.0, 0.0, 0.3, 0.0])
    info = long.solve(x)
    assert info.solved and info.kkt_residual < 1e-9
    X, U, _ = long.plan()
    assert np.abs(U).max() <= 3.0 + 1e-9 and np.abs(X[1:, 0]).max() <= 0.6 + 1e-9
    # with the DARE terminal cost the tail adds nothing once the plan is unconstrained: same first move as N = 100
    mid = CondensedQP(A, B, Q_CP, R_CP, P, 100, **kw)
    assert mid.solve(x).solved
    np.testing.assert_allclose(U[0], mid.plan()[1][0], rtol=1e-9)


def test_warm_and_cold_agree(model, rng):
    """The warm working set changes iterations only: a closed loop of warm solves equals cold solves to 1e-12."""
    A, B, P, _ = model
    kw = {"u_min": [-3.0], "u_max": [3.0], "x_min": CART[0], "x_max": CART[1]}
    warm = CondensedQP(A, B, Q_CP, R_CP, P, 40, **kw)
    cold = CondensedQP(A, B, Q_CP, R_CP, P, 40, **kw)
    plant = CartPole(dt=0.02)
    plant.set_state(np.array([0.0, 0.0, 0.3, 0.0]))
    x = plant.get_state()
    u, v = np.empty(1), np.empty(1)
    its = []
    for _ in range(60):
        iw = warm.solve(x)
        cold.reset()
        ic = cold.solve(x)
        assert iw.solved and ic.solved
        warm.first_input(u)
        cold.first_input(v)
        np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-13)
        its.append((iw.iterations, ic.iterations))
        x = plant.step(u)
    assert sum(w for w, _ in its) < sum(c for _, c in its)  # the warm start saves iterations


@pytest.mark.parametrize("seed", range(6))
def test_reference_solver_on_degenerate_active_sets(seed):
    """The reference ``exact_qp`` on box QPs with redundant rows (duplicates, sums of box rows) equals BVLS.

    The redundant rows are active exactly when the box rows they repeat are, so
    every optimum with an active bound has a linearly dependent active set (the
    kind of a box row and a rate row meeting at one input).
    """
    r = np.random.default_rng(seed)
    n = 8
    M = r.normal(size=(n, n))
    H = M @ M.T + 0.1 * np.eye(n)
    f = r.normal(scale=5.0, size=n)
    lo, hi = -np.ones(n), np.ones(n)
    pairs = np.eye(n)[:-1] + np.eye(n, k=1)[:-1]  # z_i + z_{i+1}: active with both bounds of a pair
    G = np.vstack([np.eye(n), np.eye(n), pairs])
    glo = np.concatenate([lo, lo, lo[:-1] + lo[1:]])
    ghi = np.concatenate([hi, hi, hi[:-1] + hi[1:]])
    z = exact_qp(H, f, G, glo, ghi)
    z_ref = bvls(H, f, lo, hi)
    assert np.isclose(np.abs(z_ref), 1.0).sum() >= 2  # bounds active: the duplicates make the set dependent
    np.testing.assert_allclose(z, z_ref, rtol=0, atol=1e-8)


def test_concurrent_solves_are_refused_or_right(model):
    """4 threads x 300 solves on one CondensedQP: each returns the serial answer or raises ConcurrentUse."""
    import threading

    from shinro_ctrl.errors import ConcurrentUse

    A, B, P, _ = model
    kw = {"u_min": [-3.0], "u_max": [3.0], "x_min": CART[0], "x_max": CART[1]}
    shared = CondensedQP(A, B, Q_CP, R_CP, P, 20, **kw)
    serial = CondensedQP(A, B, Q_CP, R_CP, P, 20, **kw)
    rng = np.random.default_rng(5)
    states = rng.uniform(-1, 1, (4, 300, 4)) * np.array([0.3, 0.3, 0.2, 0.3])
    expected = np.array([[serial.solve(x).objective for x in chunk] for chunk in states])
    got = np.full((4, 300), np.nan)
    refused = [0] * 4
    other: list[BaseException] = []

    def work(i: int) -> None:
        for k, x in enumerate(states[i]):
            try:
                got[i, k] = shared.solve(x).objective
            except ConcurrentUse:
                refused[i] += 1
            except BaseException as exc:  # handed to the main thread
                other.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not other, other[:1]
    done = np.isfinite(got)
    assert done.sum() + sum(refused) == 1200 and done.sum() > 0
    np.testing.assert_allclose(got[done], expected[done], rtol=1e-9)
