"""LinearMPC against cvxpy + OSQP and do-mpc (IPOPT) on the cart-pole.

Problem: ``CartPole(dt=0.02)`` linearized (Euler) at the upright equilibrium,
``Q = diag(10, 1, 100, 1)``, ``R = 0.1``, DARE terminal cost, ``|F| <= 3`` N on
every input, ``|x_cart| <= 0.6`` m on ``x_1 … x_N``. Each solver runs its own
closed loop on the *nonlinear* standalone cart-pole from 0.3 rad (the input
bound is active for the first ~0.3 s and the cart comes within a few cm of its
bound), so warm starts see realistic state changes. Per call we time the
whole Python call (``perf_counter`` around it) and read the solver's
iteration count.

Rows:

* ``LinearMPC``: this project (one OSQP object, shifted warm starts).
* ``cvxpy+OSQP``: the same QP as a ``cp.Problem`` with a ``cp.Parameter`` for
  the measured state, solved by OSQP with LinearMPC's settings (eps 1e-4,
  alpha 1.3, check_termination 5, no polishing, …) and cvxpy's warm start
  (previous solution, unshifted). Only the modelling layer differs.
* ``do-mpc``: a ``do_mpc.model.Model("discrete")`` with the same linear
  dynamics, stage/terminal costs and bounds, solved by IPOPT (MUMPS) through
  ``make_step``; IPOPT at its default tolerance (1e-8) and, second row, at
  ``tol = 1e-4`` (closer to OSQP's eps). do-mpc warm-starts IPOPT from its
  previous solution (not shifted).
* ``build+solve``: from scratch per call, on the states of the LinearMPC loop:
  ``LinearMPC(...)`` constructed (DARE, matrices, OSQP setup) and called once.
* ``setup+solve``: a new ``osqp.OSQP`` set up on prebuilt matrices and solved
  cold, per call (what rebuilding the solver costs without our Python).

Run: ``python benchmarks/mpc.py [--horizons 20 50 100] [--steps 250]``. The
peers are optional (``pip install -e ".[bench]"``); missing ones are skipped.
Figures vary with machine load: read the ratios, and rerun on a quiet machine.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import os
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import osqp
import scipy.linalg

from shinro_ctrl.controllers.mpc import DEFAULT_OSQP_SETTINGS, LinearMPC
from shinro_ctrl.plants import CartPole

DT = 0.02
Q = np.diag([10.0, 1.0, 100.0, 1.0])
R = np.array([[0.1]])
F_MAX = 3.0
X_MAX = 0.6
X_INIT = np.array([0.0, 0.0, 0.3, 0.0])
X_MIN_V = np.array([-X_MAX, -np.inf, -np.inf, -np.inf])
X_MAX_V = np.array([X_MAX, np.inf, np.inf, np.inf])


@functools.cache
def model() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete ``(A, B)`` and the DARE matrix, linearized once (not part of any timed build)."""
    A, B = CartPole(dt=DT).get_model()
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    return A, B, 0.5 * (P + P.T)


def closed_loop(solve: Callable[[np.ndarray], tuple[np.ndarray, int]], steps: int) -> dict[str, Any]:
    """Run ``solve(x) -> (u, iterations)`` in closed loop on the nonlinear cart-pole; time each call."""
    plant = CartPole(dt=DT)
    plant.set_state(X_INIT)
    x = plant.get_state()
    X, T, it = [x], [], []
    clock = time.perf_counter
    for _ in range(steps):
        t0 = clock()
        u, n_it = solve(x)
        T.append(clock() - t0)
        it.append(n_it)
        x = plant.step(np.clip(u, -F_MAX, F_MAX))
        X.append(x)
    return {"t": np.array(T), "it": np.array(it, dtype=float), "X": np.array(X)}


def replay(solve: Callable[[np.ndarray], tuple[np.ndarray, int]], states: np.ndarray) -> dict[str, Any]:
    """Time ``solve`` on a fixed sequence of states (no warm start to preserve)."""
    T, it = [], []
    for x in states:
        t0 = time.perf_counter()
        _, n_it = solve(x)
        T.append(time.perf_counter() - t0)
        it.append(n_it)
    return {"t": np.array(T), "it": np.array(it, dtype=float), "X": states}


# ----------------------------------------------------------------- solvers
def linear_mpc(N: int) -> LinearMPC:
    A, B, _ = model()
    return LinearMPC(A, B, Q, R, N, dt=DT, u_min=-F_MAX, u_max=F_MAX, x_min=X_MIN_V, x_max=X_MAX_V)


def tight_plan(N: int) -> np.ndarray:
    """LinearMPC's input plan ``(N,)`` from ``X_INIT`` at eps 1e-9 (to check the peers solve the same QP)."""
    A, B, _ = model()
    settings = {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200_000}
    mpc = LinearMPC(A, B, Q, R, N, u_min=-F_MAX, u_max=F_MAX, x_min=X_MIN_V, x_max=X_MAX_V, osqp_settings=settings)
    mpc(X_INIT)
    return mpc.last.inputs[:, 0].copy()


def run_linear_mpc(N: int, steps: int, repeats: int = 3) -> dict[str, Any]:
    """Warm-started LinearMPC; ``repeats`` closed loops, pooled (the first call of each is cold)."""
    mpc = linear_mpc(N)

    def solve(x):
        u = mpc(x)
        return u, mpc.last.iterations

    runs = []
    for _ in range(repeats):
        mpc.reset()
        runs.append(closed_loop(solve, steps))
    return {
        "t": np.concatenate([r["t"] for r in runs]),
        "it": np.concatenate([r["it"] for r in runs]),
        "X": runs[0]["X"],
        "plan": tight_plan(N),
    }


def run_build_solve(N: int, states: np.ndarray) -> dict[str, Any]:
    def solve(x):
        mpc = linear_mpc(N)
        u = mpc(x)
        return u, mpc.last.iterations

    return replay(solve, states)


def run_setup_solve(N: int, states: np.ndarray) -> dict[str, Any]:
    mpc = linear_mpc(N)
    settings = dict(DEFAULT_OSQP_SETTINGS)
    n, m = mpc.n, mpc.m
    iu = (N + 1) * n

    def solve(x):
        qp = mpc.build(x)  # fresh vectors; P and A are the prebuilt ones
        s = osqp.OSQP()
        s.setup(qp.P, qp.q, qp.A, qp.l, qp.u, **settings)
        r = s.solve(raise_error=False)
        return r.x[iu : iu + m], r.info.iter

    return replay(solve, states)


def run_cvxpy(N: int, steps: int) -> dict[str, Any] | None:
    try:
        import cvxpy as cp
    except ImportError:
        return None
    A, B, P = model()
    n, m = B.shape
    x = cp.Variable((N + 1, n))
    u = cp.Variable((N, m))
    x0 = cp.Parameter(n)
    cost = 0
    cons = [x[0] == x0]
    for k in range(N):
        cost += 0.5 * cp.quad_form(x[k], Q) + 0.5 * cp.quad_form(u[k], R)
        cons += [x[k + 1] == A @ x[k] + B @ u[k], cp.abs(u[k]) <= F_MAX, cp.abs(x[k + 1, 0]) <= X_MAX]
    cost += 0.5 * cp.quad_form(x[N], P)
    prob = cp.Problem(cp.Minimize(cost), cons)
    opts = {k: v for k, v in DEFAULT_OSQP_SETTINGS.items() if k not in ("verbose", "warm_starting")}

    def solve(xm):
        x0.value = xm
        prob.solve(solver=cp.OSQP, warm_start=True, **opts)
        if prob.status not in ("optimal", "optimal_inaccurate"):
            raise RuntimeError(f"cvxpy: {prob.status}")
        return u.value[0], prob.solver_stats.num_iters

    solve(X_INIT)  # compile the parametrized problem once (not timed)
    out = closed_loop(solve, steps)
    x0.value = X_INIT
    prob.solve(solver=cp.OSQP, warm_start=False, **{**opts, "eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200000})
    out["plan"] = u.value[:, 0].copy()
    return out


def run_do_mpc(N: int, steps: int, ipopt_tol: float | None) -> dict[str, Any] | None:
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            import casadi as ca
            import do_mpc
    except ImportError:
        return None
    A, B, P = model()
    n, m = B.shape
    mdl = do_mpc.model.Model("discrete")
    xs = mdl.set_variable("_x", "x", shape=(n, 1))
    us = mdl.set_variable("_u", "u", shape=(m, 1))
    mdl.set_rhs("x", ca.DM(A) @ xs + ca.DM(B) @ us)
    mdl.setup()
    ctrl = do_mpc.controller.MPC(mdl)
    ctrl.settings.n_horizon = N
    ctrl.settings.t_step = DT
    ctrl.settings.store_full_solution = False
    opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0}
    if ipopt_tol is not None:
        opts["ipopt.tol"] = ipopt_tol
    ctrl.settings.nlpsol_opts = opts
    ctrl.set_objective(lterm=0.5 * (xs.T @ ca.DM(Q) @ xs + us.T @ ca.DM(R) @ us), mterm=0.5 * xs.T @ ca.DM(P) @ xs)
    ctrl.set_rterm(u=0.0)
    ctrl.bounds["lower", "_u", "u"] = -F_MAX
    ctrl.bounds["upper", "_u", "u"] = F_MAX
    ctrl.bounds["lower", "_x", "x"] = X_MIN_V.reshape(-1, 1)
    ctrl.bounds["upper", "_x", "x"] = X_MAX_V.reshape(-1, 1)
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        ctrl.setup()
        ctrl.x0 = X_INIT.reshape(-1, 1)
        ctrl.set_initial_guess()

    def solve(xm):
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # casadi's notice about numpy calls inside do-mpc
            u = ctrl.make_step(xm.reshape(-1, 1))
        if not ctrl.solver_stats["success"]:
            raise RuntimeError(f"do-mpc: {ctrl.solver_stats['return_status']}")
        return u.ravel(), ctrl.solver_stats["iter_count"]

    return closed_loop(solve, steps)


# ------------------------------------------------------------------ report
def summary(name: str, N: int, r: dict[str, Any]) -> dict[str, Any]:
    t = r["t"] * 1e3
    X = r["X"]
    return {
        "name": name,
        "N": N,
        "med": float(np.median(t)),
        "p95": float(np.percentile(t, 95)),
        "max": float(t.max()),
        "it_med": float(np.median(r["it"])),
        "it_mean": float(np.mean(r["it"])),
        "calls": len(t),
        "max_x": float(np.max(np.abs(X[:, 0]))),
        "final": float(np.max(np.abs(X[-1]))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--horizons", type=int, nargs="+", default=[20, 50, 100])
    ap.add_argument("--steps", type=int, default=250, help="closed-loop steps per run (dt = 0.02 s)")
    ap.add_argument("--peer-steps", type=int, default=None, help="steps for cvxpy/do-mpc (default: --steps)")
    args = ap.parse_args()
    peer_steps = args.peer_steps or args.steps
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"cart-pole MPC, |F| <= {F_MAX} N, |x| <= {X_MAX} m, from {X_INIT[2]} rad, dt = {DT} s, "
        f"closed loop on the nonlinear plant; {os.cpu_count()} CPUs, load average {load:.2f}"
    )
    print(f"OSQP settings (LinearMPC and cvxpy): {DEFAULT_OSQP_SETTINGS}")
    header = (
        f"{'solver':24s} {'N':>4s} {'calls':>6s} {'median ms':>10s} {'p95 ms':>8s} {'max ms':>8s} "
        f"{'it med':>7s} {'it mean':>8s} {'max|x|':>7s} {'|x_end|':>8s}"
    )
    ratios = []
    for N in args.horizons:
        rows = []
        ours = run_linear_mpc(N, args.steps)
        rows.append(summary("LinearMPC (warm)", N, ours))
        notes = []
        cv = run_cvxpy(N, peer_steps)
        if cv is not None:
            rows.append(summary("cvxpy+OSQP (warm)", N, cv))
            gap = float(np.max(np.abs(cv["plan"] - ours["plan"])))
            notes.append(
                f"same QP: max |u_k(cvxpy) - u_k(LinearMPC)| over the plan from 0.3 rad, eps 1e-9: {gap:.1e} N"
            )
        else:
            notes.append("cvxpy not installed: skipped")
        for tol, label in ((None, "do-mpc IPOPT (tol 1e-8)"), (1e-4, "do-mpc IPOPT (tol 1e-4)")):
            dm = run_do_mpc(N, peer_steps, tol)
            if dm is None:
                notes.append("do-mpc not installed: skipped")
                break
            rows.append(summary(label, N, dm))
        scratch_states = ours["X"][:-1]
        rows.append(summary("build+solve (LinearMPC)", N, run_build_solve(N, scratch_states)))
        rows.append(summary("setup+solve (OSQP only)", N, run_setup_solve(N, scratch_states)))
        print()
        print(header)
        for r in rows:
            print(
                f"{r['name']:24s} {r['N']:4d} {r['calls']:6d} {r['med']:10.3f} {r['p95']:8.3f} {r['max']:8.2f} "
                f"{r['it_med']:7.0f} {r['it_mean']:8.1f} {r['max_x']:7.3f} {r['final']:8.1e}"
            )
        for note in notes:
            print("  " + note)
        base = rows[0]["med"]
        ratios.append((N, {r["name"]: r["med"] / base for r in rows[1:]}, base))
    print()
    print("median call time relative to LinearMPC (higher = LinearMPC faster):")
    names = sorted({k for _, d, _ in ratios for k in d}, key=lambda s: ratios[0][1].get(s, 0))
    print(f"{'N':>4s} {'LinearMPC ms':>13s} " + " ".join(f"{n:>24s}" for n in names))
    for N, d, base in ratios:
        print(f"{N:4d} {base:13.3f} " + " ".join(f"{d.get(n, float('nan')):23.1f}x" for n in names))
    goals = {N: (base, d) for N, d, base in ratios}
    if 50 in goals:
        base, d = goals[50]
        print()
        print("goals at N = 50 (measured):")
        print(f"  median call <= 0.4 ms: {base:.3f} ms -> {'met' if base <= 0.4 else 'NOT met'}")
        for key, want in (
            ("cvxpy+OSQP (warm)", 10),
            ("do-mpc IPOPT (tol 1e-4)", 25),
            ("do-mpc IPOPT (tol 1e-8)", 25),
            ("build+solve (LinearMPC)", 3),
            ("setup+solve (OSQP only)", 3),
        ):
            if key in d:
                print(f"  >= {want}x faster than {key}: {d[key]:.1f}x -> {'met' if d[key] >= want else 'NOT met'}")


if __name__ == "__main__":
    main()
