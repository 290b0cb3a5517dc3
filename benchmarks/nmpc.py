"""Nonlinear MPC on the cart-pole swing-up: RTI (DAQP; OSQP) vs our IPOPT mode vs do-mpc (IPOPT).

The set-up of ``configs/cartpole_nmpc_swingup_mujoco.toml``: cart 1.0 kg, point-mass pole 0.1 kg at
0.8 m, from hanging, |F| <= 40 N, |x| <= 2 m (hard here, so do-mpc gets the same bounds), N = 40,
dt = 0.05 s, Q = diag(1e3, 1e-2, 1e3, 1e-2), R = 1e-2, terminal weight Q. Every controller runs
the same standalone closed loop (the plant steps at the controller's dt, 8 s = 160 steps) on the
same RK4 shooting model, and is scored by

* time per step (median, p95) of the controller call; for RTI also by phase
  (linearization = the one mapped CasADi call, condensing, QP, other) and without the first
  (cold, IPOPT-started) call;
* closed-loop cost ``Σ_k ½ (x_kᵀ Q x_k + u_kᵀ R u_k)`` over the run;
* success: |θ| < 0.02 rad and |x| < 0.05 m for t >= 6 s.

Goals (issue 19): RTI median <= 1 ms per call (stretch 0.5 ms), >= 20x faster than do-mpc per step,
closed-loop cost within 5 % of the IPOPT-converged NMPC. Run: ``.venv/bin/python benchmarks/nmpc.py``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.plants import CartPole

Q = np.array([1e3, 1e-2, 1e3, 1e-2])
R = np.array([1e-2])
N, DT, STEPS = 40, 0.05, 160
X0 = np.array([0.0, 0.0, np.pi, 0.0])
BOUNDS = dict(u_min=-40.0, u_max=40.0, x_min=[-2.0, -np.inf, -np.inf, -np.inf], x_max=[2.0, np.inf, np.inf, np.inf])
RTI_REPEATS = 5


def plant() -> CartPole:
    return CartPole(cart_mass=1.0, pole_mass=0.1, pole_length=0.8, dt=DT)


def closed_loop(ctrl, *, record=None):
    """Run the swing-up; returns (states (STEPS+1, 4), inputs (STEPS, 1), call times (STEPS,))."""
    p = plant()
    p.set_state(X0)
    x = p.get_state()
    X, U, T = [x], [], []
    for _ in range(STEPS):
        t0 = time.perf_counter()
        u = ctrl(x)
        T.append(time.perf_counter() - t0)
        if record is not None:
            record(ctrl)
        U.append(np.array(u, dtype=float).ravel())
        x = p.step(u)
        X.append(x)
    return np.array(X), np.array(U), np.array(T)


def score(X, U):
    cost = 0.5 * float(np.sum(X[:-1] ** 2 * Q) + np.sum(U**2 * R))
    late = np.arange(STEPS + 1) * DT >= 6.0
    ok = bool(np.all(np.abs(X[late, 2]) < 0.02) and np.all(np.abs(X[late, 0]) < 0.05))
    return cost, ok


def ms(v) -> str:
    return f"{1e3 * v:8.3f}"


def do_mpc_controller():
    warnings.filterwarnings("ignore", category=UserWarning, module="do_mpc")
    warnings.filterwarnings("ignore", category=FutureWarning, module="casadi")  # raised inside do-mpc
    import do_mpc

    p = plant()
    nm = NonlinearMPC.from_plant(p, Q, R, horizon=N, **BOUNDS)  # for its RK4 step F
    model = do_mpc.model.Model("discrete")
    x = model.set_variable("_x", "x", shape=(4, 1))
    u = model.set_variable("_u", "u", shape=(1, 1))
    model.set_rhs("x", nm.F(x, u))
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = N
    mpc.settings.t_step = DT
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0}
    qx = 0.5 * sum(float(Q[i]) * x[i] ** 2 for i in range(4))
    mpc.set_objective(mterm=qx, lterm=qx + 0.5 * float(R[0]) * u[0] ** 2)
    mpc.set_rterm(u=0.0)
    mpc.bounds["lower", "_u", "u"] = -40.0
    mpc.bounds["upper", "_u", "u"] = 40.0
    mpc.bounds["lower", "_x", "x"] = np.array([-2.0, -1e20, -1e20, -1e20])
    mpc.bounds["upper", "_x", "x"] = np.array([2.0, 1e20, 1e20, 1e20])
    mpc.setup()
    mpc.x0 = X0
    mpc.set_initial_guess()

    def call(xk):
        return np.asarray(mpc.make_step(np.asarray(xk).reshape(4, 1))).ravel()

    return call


def main() -> None:
    print(f"cart-pole NMPC swing-up: N = {N}, dt = {DT} s, {STEPS} steps (8 s), |F| <= 40 N, |x| <= 2 m")
    rows = []

    # ---- RTI (DAQP), repeated for stable timing statistics
    phases: list[tuple[float, float, float, float, float]] = []

    def rec(c):
        l = c.last
        phases.append((l.solve_time_s, l.time_linearization_s, l.time_condensing_s, l.time_qp_s, l.time_other_s))

    times = []
    for _ in range(RTI_REPEATS):
        rti = NonlinearMPC.from_plant(plant(), Q, R, horizon=N, **BOUNDS)
        X, U, T = closed_loop(rti, record=rec)
        times.append(T[1:])  # the first call is the IPOPT cold start
        first = T[0]
    T_rti = np.concatenate(times)
    cost_rti, ok_rti = score(X, U)
    P = np.array(phases).reshape(RTI_REPEATS, STEPS, 5)[:, 1:].reshape(-1, 5)
    print(f"\nRTI per call over {T_rti.size} warm calls ({RTI_REPEATS} runs), ms:")
    print("                 total   linearize  condense        QP     other")
    print(f"  median  {ms(np.median(T_rti))}  " + "  ".join(ms(v) for v in np.median(P[:, 1:], axis=0)))
    print(f"  p95     {ms(np.percentile(T_rti, 95))}  " + "  ".join(ms(v) for v in np.percentile(P[:, 1:], 95, axis=0)))
    print(f"  (first call, IPOPT cold start: {ms(first)} ms)")
    rows.append(("NMPC RTI (DAQP)", np.median(T_rti), np.percentile(T_rti, 95), cost_rti, ok_rti))

    # ---- RTI on the sparse QP with OSQP (the alternative QP path)
    sp_ctrl = NonlinearMPC.from_plant(plant(), Q, R, horizon=N, solver="osqp", **BOUNDS)
    X, U, T = closed_loop(sp_ctrl)
    cost_sp, ok_sp = score(X, U)
    rows.append(("NMPC RTI (OSQP)", np.median(T[1:]), np.percentile(T[1:], 95), cost_sp, ok_sp))

    # ---- our IPOPT mode (converged every step)
    ip = NonlinearMPC.from_plant(plant(), Q, R, horizon=N, solver="ipopt", **BOUNDS)
    X, U, T = closed_loop(ip)
    cost_ip, ok_ip = score(X, U)
    rows.append(("NMPC ipopt (ours)", np.median(T), np.percentile(T, 95), cost_ip, ok_ip))

    # ---- do-mpc
    try:
        X, U, T = closed_loop(do_mpc_controller())
        cost_dm, ok_dm = score(X, U)
        rows.append(("do-mpc (IPOPT)", np.median(T), np.percentile(T, 95), cost_dm, ok_dm))
    except ImportError as exc:  # the bench extra is not installed
        print(f"do-mpc unavailable: {exc}")

    print("\ncontroller             median ms    p95 ms   closed-loop cost   success")
    for name, med, p95, cost, ok in rows:
        print(f"{name:20s}  {ms(med)}  {ms(p95)}   {cost:16.2f}   {ok}")
    med_rti = rows[0][1]
    print("\ngoals:")
    print(f"  RTI median {1e3 * med_rti:.3f} ms (goal <= 1 ms, stretch 0.5 ms)")
    for name, med, _, _, _ in rows[2:]:
        print(f"  {name}: RTI (DAQP) is {med / med_rti:.0f}x faster per step (goal vs do-mpc >= 20x)")
    print(f"  closed-loop cost RTI / IPOPT-converged = {cost_rti / cost_ip:.4f} (goal within 5 %)")


if __name__ == "__main__":
    main()
