"""LinearMPC (both QP backends) against cvxpy + OSQP and do-mpc (IPOPT) on the cart-pole: speed and exactness.

Problem: ``CartPole(dt=0.02)`` linearized (Euler) at the upright equilibrium,
``Q = diag(10, 1, 100, 1)``, ``R = 0.1``, DARE terminal cost, ``|F| <= 3`` N on
every input, ``|x_cart| <= 0.6`` m on ``x_1 … x_N``. Each solver runs its own
closed loop on the *nonlinear* standalone cart-pole from 0.3 rad (the input
bound is active for the first ~0.3 s and the cart comes within a few cm of its
bound), so warm starts see realistic state changes. Per call we time the
whole Python call (``perf_counter`` around it), read the solver's iteration
count, and compare the first move with the exact optimum of the same QP at
the same state (a cold DAQP solve of the condensed QP, itself checked against
OSQP at eps 1e-9 on the plan from 0.3 rad): ``max|du|`` in N and ``max rel``
(``|du| / |u*|``, which blows up where ``u* ≈ 0``).

Rows:

* ``LinearMPC daqp``: this project, condensed QP, DAQP (the ``"auto"`` choice here).
* ``LinearMPC osqp``: this project, sparse QP, OSQP with polishing and the
  exactness checks (re-solve, condensed referee) of the default settings.
* ``LinearMPC osqp 1e-4``: the pre-issue-15 default (eps 1e-4, no polishing).
* ``cvxpy+OSQP``: the same QP as a ``cp.Problem`` with a ``cp.Parameter`` for
  the measured state, solved by OSQP with the pre-issue-15 settings (eps
  1e-4, alpha 1.3, check_termination 5, no polishing, …) and cvxpy's warm start.
* ``do-mpc``: a ``do_mpc.model.Model("discrete")`` with the same linear
  dynamics, stage/terminal costs and bounds, solved by IPOPT (MUMPS) through
  ``make_step``; IPOPT at its default tolerance (1e-8) and at ``tol = 1e-4``.
* ``build+solve``: from scratch per call, on the states of the DAQP loop:
  ``LinearMPC(...)`` constructed (DARE, matrices, solver set-up) and called once.
* ``setup+solve``: a new ``osqp.OSQP`` set up on prebuilt matrices and solved
  cold, per call (what rebuilding the solver costs without our Python).

``--crossover`` measures both backends per call across problem sizes ``N·m``
(cart-pole and the 12-state quadrotor of ``quadrotor_mpc_mujoco``, closed loop
on the linear model), the data behind ``solver="auto"``'s rule. ``--sweep``
runs ``cartpole_mpc_mujoco`` over pole mass 0.05–0.5 (40 samples) and counts
the failed samples by cause. ``--alloc`` counts the bytes a warm DAQP call
allocates (tracemalloc).

Run: ``python benchmarks/mpc.py [--horizons 20 50 100] [--steps 250] [--crossover] [--sweep] [--alloc]``.
The peers are optional (``pip install -e ".[bench]"``); missing ones are
skipped. Figures vary with machine load: read the ratios, and rerun on a
quiet machine.
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

from shinro_ctrl.controllers.mpc import AUTO_DAQP_MAX_VARIABLES, DEFAULT_OSQP_SETTINGS, LinearMPC
from shinro_ctrl.controllers.qp.condensed import CondensedQP
from shinro_ctrl.plants import CartPole, Quadrotor

#: The pre-issue-15 default: eps 1e-4, no polishing (approximate; cvxpy's row uses it too).
OLD_OSQP_SETTINGS = {**DEFAULT_OSQP_SETTINGS, "polishing": False}

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
    X, T, it, U = [x], [], [], []
    clock = time.perf_counter
    for _ in range(steps):
        t0 = clock()
        u, n_it = solve(x)
        T.append(clock() - t0)
        it.append(n_it)
        U.append(float(np.asarray(u).ravel()[0]))
        x = plant.step(np.clip(u, -F_MAX, F_MAX))
        X.append(x)
    return {"t": np.array(T), "it": np.array(it, dtype=float), "X": np.array(X), "U": np.array(U)}


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
def linear_mpc(N: int, solver: str = "auto", settings: dict[str, Any] | None = None) -> LinearMPC:
    A, B, _ = model()
    return LinearMPC(
        A, B, Q, R, N, dt=DT, u_min=-F_MAX, u_max=F_MAX, x_min=X_MIN_V, x_max=X_MAX_V, solver=solver,
        osqp_settings=settings,
    )  # fmt: skip


def tight_plan(N: int) -> np.ndarray:
    """OSQP's input plan ``(N,)`` from ``X_INIT`` at eps 1e-9 on the sparse QP (to check everyone solves one QP)."""
    qp = linear_mpc(N, "osqp").build(X_INIT)
    solver = osqp.OSQP()
    solver.setup(qp.P, qp.q, qp.A, qp.l, qp.u, eps_abs=1e-9, eps_rel=1e-9, max_iter=400_000, verbose=False)
    iu = (N + 1) * 4
    return solver.solve(raise_error=False).x[iu : iu + N].copy()


@functools.cache
def exact_solver(N: int) -> CondensedQP:
    """The reference: the condensed QP solved cold by DAQP (exact active-set optimum)."""
    A, B, P = model()
    return CondensedQP(A, B, Q, R, P, N, u_min=[-F_MAX], u_max=[F_MAX], x_min=X_MIN_V, x_max=X_MAX_V)


def exact_first_moves(N: int, states: np.ndarray) -> np.ndarray:
    """The exact first move ``(len(states),)`` at each state (cold solves)."""
    ref = exact_solver(N)
    out = np.empty(len(states))
    u = np.empty(1)
    for i, x in enumerate(states):
        ref.reset()
        info = ref.solve(np.asarray(x, dtype=float))
        out[i] = ref.first_input(u)[0] if info.solved else np.nan
    return out


def with_errors(N: int, r: dict[str, Any]) -> dict[str, Any]:
    """Add ``err_abs``/``err_rel``: the largest deviation of the run's first moves from the exact ones."""
    exact = exact_first_moves(N, r["X"][: len(r["U"])])
    d = np.abs(r["U"] - exact)
    r["err_abs"] = float(np.nanmax(d))
    r["err_rel"] = float(np.nanmax(d / np.maximum(np.abs(exact), 1e-12)))
    return r


def run_linear_mpc(N: int, steps: int, solver: str, settings=None, repeats: int = 3) -> dict[str, Any]:
    """Warm-started LinearMPC; ``repeats`` closed loops, pooled (the first call of each is cold)."""
    mpc = linear_mpc(N, solver, settings)
    backends: dict[str, int] = {}

    def solve(x):
        u = mpc(x)
        backends[mpc.last.backend] = backends.get(mpc.last.backend, 0) + 1
        return u, mpc.last.iterations

    runs = []
    for _ in range(repeats):
        mpc.reset()
        runs.append(closed_loop(solve, steps))
    return with_errors(
        N,
        {
            "t": np.concatenate([r["t"] for r in runs]),
            "it": np.concatenate([r["it"] for r in runs]),
            "X": runs[0]["X"],
            "U": runs[0]["U"],
            "backends": backends,
        },
    )


def run_build_solve(N: int, states: np.ndarray) -> dict[str, Any]:
    def solve(x):
        mpc = linear_mpc(N)
        u = mpc(x)
        return u, mpc.last.iterations

    return replay(solve, states)


def run_setup_solve(N: int, states: np.ndarray) -> dict[str, Any]:
    mpc = linear_mpc(N, "osqp")
    settings = dict(OLD_OSQP_SETTINGS)
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
    opts = {k: v for k, v in OLD_OSQP_SETTINGS.items() if k not in ("verbose", "warm_starting")}

    def solve(xm):
        x0.value = xm
        prob.solve(solver=cp.OSQP, warm_start=True, **opts)
        if prob.status not in ("optimal", "optimal_inaccurate"):
            raise RuntimeError(f"cvxpy: {prob.status}")
        return u.value[0], prob.solver_stats.num_iters

    solve(X_INIT)  # compile the parametrized problem once (not timed)
    out = with_errors(N, closed_loop(solve, steps))
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

    return with_errors(N, closed_loop(solve, steps))


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
        "err_abs": r.get("err_abs", float("nan")),
        "err_rel": r.get("err_rel", float("nan")),
    }


# --------------------------------------------------------------- crossover
def crossover(steps: int) -> None:
    """Both backends per call across problem sizes (closed loop on the linear model, warm, pooled)."""
    cases = [("cart-pole", n_) for n_ in (50, 100, 200, 300, 400, 600)]
    cases += [("quadrotor", n_) for n_ in (10, 30, 40, 60, 100)]
    print()
    print("crossover: median / p95 ms per call (LinearMPC, warm), linear closed loop; nz = N·m + slacks")
    print(f"{'plant':10s} {'N':>4s} {'nz':>5s} {'daqp med':>9s} {'p95':>7s} {'osqp med':>9s} {'p95':>7s} "
          f"{'daqp build s':>12s} {'osqp/daqp':>9s} {'auto':>5s}")  # fmt: skip
    for plant_name, N in cases:
        if plant_name == "cart-pole":
            plant = CartPole(dt=DT)
            kw = {"u_min": -F_MAX, "u_max": F_MAX, "x_min": X_MIN_V, "x_max": X_MAX_V}
            Qp, Rp, start = Q, R, X_INIT
        else:
            plant = Quadrotor(mass=0.5, inertia=[3e-3, 3e-3, 5e-3], dt=0.01)
            kw = {
                "u_min": [0.0, -0.05, -0.05, -0.05],
                "u_max": [9.81, 0.05, 0.05, 0.05],
                "x_min": [-np.inf] * 3 + [-0.5, -0.5] + [-np.inf] * 7,
                "x_max": [np.inf] * 3 + [0.5, 0.5] + [np.inf] * 7,
                "soft": True,
            }
            Qp, Rp = [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], [0.1, 200, 200, 200]
            start = np.array([-1.0, 0.5, -1.5] + [0.0] * 9)
        med = {}
        build = float("nan")
        for solver in ("daqp", "osqp"):
            t0 = time.perf_counter()
            mpc = LinearMPC.from_plant(plant, Qp, Rp, horizon=N, solver=solver, **kw)
            if solver == "daqp":
                build = time.perf_counter() - t0
            A, B, x0, u0 = mpc.A, mpc.B, mpc.x0, mpc.u0
            T = []
            for _ in range(2):
                mpc.reset()
                x = np.array(start, dtype=float)
                for _ in range(steps):
                    t1 = time.perf_counter()
                    u = mpc(x)
                    T.append(time.perf_counter() - t1)
                    x = x0 + A @ (x - x0) + B @ (u - u0) + mpc.offset
            T = np.array(T) * 1e3
            med[solver] = (float(np.median(T)), float(np.percentile(T, 95)))
        auto = LinearMPC.from_plant(plant, Qp, Rp, horizon=N, **kw)
        nz = N * (plant.input_dim + (2 if kw.get("soft") else 0))
        print(
            f"{plant_name:10s} {N:4d} {nz:5d} {med['daqp'][0]:9.3f} {med['daqp'][1]:7.3f} "
            f"{med['osqp'][0]:9.3f} {med['osqp'][1]:7.3f} {build:12.2f} {med['osqp'][0] / med['daqp'][0]:9.1f} "
            f"{auto.solver:>5s}"
        )
    print(f"auto rule: daqp while N·m + slacks <= {AUTO_DAQP_MAX_VARIABLES} (and the dense matrices fit), else osqp")


# ------------------------------------------------------------------- sweep
def sweep(samples: int) -> None:
    """``cartpole_mpc_mujoco`` over pole mass 0.05–0.5: failed samples by cause."""
    from shinro_ctrl.sweep import run_sweep

    t0 = time.perf_counter()
    res = run_sweep(
        "cartpole_mpc_mujoco", {"plant.pole_mass": (0.05, 0.5)}, samples=samples, method="serial", progress=False
    )
    causes: dict[str, int] = {}
    for row in res.rows:
        if row.error is None:
            key = "ok (stable)" if row.stable else "no error, not stable"
        elif row.error.startswith("MPCInfeasible") and "MPC problem infeasible" in row.error:
            key = "MPCInfeasible, certified (" + ("DAQP" if "DAQP status" in row.error else "OSQP") + ")"
        elif row.error.startswith("MPCInfeasible"):
            key = "MPCInfeasible without certificate"
        else:
            key = row.error.split(":")[0]
        causes[key] = causes.get(key, 0) + 1
    print()
    print(
        f"sweep cartpole_mpc_mujoco, plant.pole_mass in [0.05, 0.5], {samples} samples ({res.method}, seed 0), "
        f"{time.perf_counter() - t0:.1f} s:"
    )
    for key, count in sorted(causes.items()):
        print(f"  {key:40s} {count:3d}")
    uncertified = [r for r in res.rows if r.error and "MPC problem infeasible" not in r.error]
    certified = sorted(r.params["plant.pole_mass"] for r in res.rows if r.error and r not in uncertified)
    stable = sorted(r.params["plant.pole_mass"] for r in res.rows if r.error is None and r.stable)
    if certified and stable:
        print(
            f"  lightest certified-infeasible sample {certified[0]:.3f} kg, heaviest stable one {stable[-1]:.3f} kg "
            "(the controller's model has 0.1 kg; |F| <= 3 N, |x| <= 0.6 m hard)"
        )
    for r in uncertified[:5]:
        print(f"  e.g. pole_mass = {r.params['plant.pole_mass']:.3f}: {r.error[:160]}")
    print(f"  goal: no failure that is not a certified infeasibility -> {'met' if not uncertified else 'NOT met'}")


# ------------------------------------------------------------- allocation
def allocations(N: int = 50, calls: tuple[int, ...] = (200, 2000)) -> None:
    """Python-heap bytes a warm DAQP call allocates (tracemalloc): transient peak, and what stays held."""
    import tracemalloc

    mpc = linear_mpc(N, "daqp")
    states = run_linear_mpc(N, 100, "daqp", repeats=1)["X"][:100]
    dq = exact_solver(N)
    for label, call in (("LinearMPC.__call__", mpc), ("CondensedQP.solve", dq.solve)):
        for x in states[:20]:
            call(x)  # warm up caches
        held = []
        for count in calls:
            peaks = np.zeros(count)  # allocated before tracing starts (a growing list would count itself)
            tracemalloc.start()
            cur0, _ = tracemalloc.get_traced_memory()
            for i in range(count):
                before, _ = tracemalloc.get_traced_memory()
                tracemalloc.reset_peak()
                call(states[i % len(states)])
                peaks[i] = tracemalloc.get_traced_memory()[1] - before
            held.append(tracemalloc.get_traced_memory()[0] - cur0)
            tracemalloc.stop()
        kept = ", ".join(f"{c} calls {h} bytes" for c, h in zip(calls, held, strict=True))
        print(
            f"  {label:22s}: transient peak median {np.median(peaks):6.0f} bytes per call (new plan arrays, "
            f"DAQP's result copies); held after {kept}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--horizons", type=int, nargs="*", default=[20, 50, 100], help="none: skip the main table")
    ap.add_argument("--steps", type=int, default=250, help="closed-loop steps per run (dt = 0.02 s)")
    ap.add_argument("--peer-steps", type=int, default=None, help="steps for cvxpy/do-mpc (default: --steps)")
    ap.add_argument("--crossover", action="store_true", help="also measure both backends across N·m")
    ap.add_argument("--sweep", action="store_true", help="also sweep cartpole_mpc_mujoco over pole mass (40 samples)")
    ap.add_argument("--alloc", action="store_true", help="also count bytes allocated per warm call")
    ap.add_argument("--no-peers", action="store_true", help="skip cvxpy, do-mpc and the rebuild rows")
    args = ap.parse_args()
    peer_steps = args.peer_steps or args.steps
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"cart-pole MPC, |F| <= {F_MAX} N, |x| <= {X_MAX} m, from {X_INIT[2]} rad, dt = {DT} s, "
        f"closed loop on the nonlinear plant; {os.cpu_count()} CPUs, load average {load:.2f}"
    )
    print(f"OSQP settings, LinearMPC osqp: {DEFAULT_OSQP_SETTINGS}")
    print("old default (LinearMPC osqp 1e-4, cvxpy): polishing False")
    print("error columns: first move vs the exact optimum at the same state; max|du| [N], max rel = |du|/|u*|")
    header = (
        f"{'solver':24s} {'N':>4s} {'calls':>6s} {'median ms':>10s} {'p95 ms':>8s} {'max ms':>8s} "
        f"{'it med':>7s} {'it mean':>8s} {'max|du|':>9s} {'max rel':>9s} {'max|x|':>7s} {'|x_end|':>8s}"
    )
    goals = {}
    for N in args.horizons:
        rows = []
        notes = []
        dq = run_linear_mpc(N, args.steps, "daqp")
        rows.append(summary("LinearMPC daqp", N, dq))
        os_ = run_linear_mpc(N, args.steps, "osqp")
        rows.append(summary("LinearMPC osqp", N, os_))
        settled = os_["backends"].get("daqp", 0)
        notes.append(
            f"LinearMPC osqp: {settled} of {sum(os_['backends'].values())} calls settled by the condensed referee "
            "(OSQP's polish not exact)"
        )
        rows.append(summary("LinearMPC osqp 1e-4 (old)", N, run_linear_mpc(N, args.steps, "osqp", OLD_OSQP_SETTINGS)))
        plan = tight_plan(N)
        ref = exact_solver(N)
        ref.reset()
        ref.solve(X_INIT)
        gap0 = float(np.max(np.abs(ref.plan()[1][:, 0] - plan)))
        notes.append(f"reference check: max |u_k(exact) - u_k(OSQP eps 1e-9)| over the plan from 0.3 rad: {gap0:.1e} N")
        if not args.no_peers:
            cv = run_cvxpy(N, peer_steps)
            if cv is not None:
                rows.append(summary("cvxpy+OSQP (warm)", N, cv))
                gap = float(np.max(np.abs(cv["plan"] - plan)))
                notes.append(f"same QP: max |u_k(cvxpy eps 1e-9) - u_k(OSQP eps 1e-9)| over the plan: {gap:.1e} N")
            else:
                notes.append("cvxpy not installed: skipped")
            for tol, label in ((None, "do-mpc IPOPT (tol 1e-8)"), (1e-4, "do-mpc IPOPT (tol 1e-4)")):
                dm = run_do_mpc(N, peer_steps, tol)
                if dm is None:
                    notes.append("do-mpc not installed: skipped")
                    break
                rows.append(summary(label, N, dm))
            scratch_states = dq["X"][:-1]
            rows.append(summary("build+solve (LinearMPC)", N, run_build_solve(N, scratch_states)))
            rows.append(summary("setup+solve (OSQP only)", N, run_setup_solve(N, scratch_states)))
        print()
        print(header)
        for r in rows:
            print(
                f"{r['name']:24s} {r['N']:4d} {r['calls']:6d} {r['med']:10.3f} {r['p95']:8.3f} {r['max']:8.2f} "
                f"{r['it_med']:7.0f} {r['it_mean']:8.1f} {r['err_abs']:9.1e} {r['err_rel']:9.1e} "
                f"{r['max_x']:7.3f} {r['final']:8.1e}"
            )
        for note in notes:
            print("  " + note)
        goals[N] = {r["name"]: r for r in rows}
    if goals:
        print()
        print("goals (median call of the exact default, LinearMPC daqp = solver='auto' here):")
    for N, want, stretch in ((50, 0.10, 0.05), (100, 0.2, None)):
        if N in goals:
            med = goals[N]["LinearMPC daqp"]["med"]
            old = goals[N]["LinearMPC osqp 1e-4 (old)"]["med"]
            verdict = "met" if med <= want else "NOT met"
            extra = "" if stretch is None else f", stretch {stretch} ms {'met' if med <= stretch else 'not met'}"
            print(
                f"  N = {N}: {med:.3f} ms <= {want} ms -> {verdict}{extra}; old approximate default {old:.3f} ms "
                f"({old / med:.1f}x slower)"
            )
    for N, rows in goals.items():
        err = max(rows["LinearMPC daqp"]["err_abs"], rows["LinearMPC osqp"]["err_abs"])
        print(f"  N = {N}: exact first moves (both backends) max |du| = {err:.1e} N")
    if args.alloc:
        print()
        print("Python-heap allocation per warm call (N = 50, tracemalloc):")
        allocations()
    if args.crossover:
        crossover(150)
    if args.sweep:
        sweep(40)


if __name__ == "__main__":
    main()
