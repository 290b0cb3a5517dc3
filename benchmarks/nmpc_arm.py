"""Nonlinear MPC on the 7-DOF arm: RTI step time in both loops beside do-mpc (IPOPT) on the same problem.

The problem of ``configs/panda_nmpc_reach_mujoco.toml``: ``MjcfPlant`` of ``assets/panda_like_arm.xml``
(14 states, 7 torque inputs), |u| <= 0.87 on joints 1-4 and 0.24 on joints 5-7, N = 20, dt = 0.01 s, the
shooting model = the plant's own semi-implicit Euler step, Q = diag(1e3 x 7, 10 x 7), R = diag(10 x 4, 40 x 3),
terminal weight Q, a reach from the ready pose to a pose 0.8-1.0 rad away on every joint. Every controller runs
the same closed loop (the plant stepped at dt: standalone = the plant's own integration, mujoco = MuJoCo) for
``--seconds`` of simulated time, and is scored by

* time per step of the controller call (median, p90, max), wall clock and the thread's CPU time (the machine
  has 2 cores shared with other jobs: CPU time is what the call costs, wall clock adds the waits for a core);
  RTI's first call (its cold start: SQP iterations from the held state) is left out and printed apart;
* for RTI the split of the median call: linearization (one compiled call for all stages), condensing (the
  compiled Riccati recursion, plus the condensed QP on the steps where its unconstrained step breaks a torque
  bound), QP (the Riccati policy's rollout, plus DAQP on those steps), other; and how many calls needed DAQP;
* the closed-loop cost ``Σ_k ½ (e_kᵀ Q e_k + (u_k − u0)ᵀ R (u_k − u0))`` and the final joint error.

do-mpc (in the ``bench`` extra) solves the same OCP (the same CasADi step function ``F``, weights and bounds)
to convergence with IPOPT at every step. acados is not pip-installable here (``pip download acados_template``
finds no distribution); the figures its users report for problems of this size are quoted at the end, with
their sources, for orientation only (other machines, other models).

OpenBLAS is pinned to one thread unless ``OPENBLAS_NUM_THREADS`` is set (as in ``benchmarks/planning.py``):
every matrix here is small, and on a loaded machine OpenBLAS's worker threads cost more than they save.

Run: ``python benchmarks/nmpc_arm.py [--seconds 1.5] [--repeats 3] [--no-peer]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS (see the module doc)

import argparse
import time
import tomllib
import warnings

import numpy as np

from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants.mjcf import MjcfPlant
from shinro_ctrl.resources import asset_path, config_path

SCENARIO = "panda_nmpc_reach_mujoco.toml"


def scenario() -> dict:
    with open(config_path(SCENARIO), "rb") as fh:
        return tomllib.load(fh)


def make_plant(doc: dict, loop: str) -> MjcfPlant:
    p = doc["plant"]
    plant = MjcfPlant(asset_path(p["model"]), dt=p["dt"], x0=p["x0"])
    if loop == "mujoco":
        plant.physics_engine(MujocoEngine.for_plant(plant))
    return plant


def make_rti(doc: dict, plant: MjcfPlant) -> NonlinearMPC:
    c = {k: v for k, v in doc["controller"].items() if k != "type"}
    Q, R, N = c.pop("Q"), c.pop("R"), c.pop("horizon")
    return NonlinearMPC.from_plant(plant, Q, R, horizon=N, **c)


def closed_loop(ctrl, plant: MjcfPlant, x0: np.ndarray, steps: int, record=None):
    """(states (steps+1, n), inputs (steps, m), wall times (steps,), CPU times (steps,))."""
    plant.set_state(x0)
    x = plant.get_state()
    X, U, T, C = [x], [], [], []
    for _ in range(steps):
        t0, c0 = time.perf_counter(), time.thread_time()
        u = ctrl(x)
        T.append(time.perf_counter() - t0)
        C.append(time.thread_time() - c0)
        if record is not None:
            record(ctrl)
        U.append(np.array(u, dtype=float).ravel())
        x = plant.step(u)
        X.append(x)
    return np.array(X), np.array(U), np.array(T), np.array(C)


def do_mpc_controller(rti: NonlinearMPC, x_init: np.ndarray):
    warnings.filterwarnings("ignore", category=UserWarning, module="do_mpc")
    warnings.filterwarnings("ignore", category=FutureWarning, module="casadi")
    import do_mpc

    n, m = rti.n, rti.m
    model = do_mpc.model.Model("discrete")
    x = model.set_variable("_x", "x", shape=(n, 1))
    u = model.set_variable("_u", "u", shape=(m, 1))
    model.set_rhs("x", rti.ocp.F(x, u))  # the same shooting step as RTI's
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = rti.N
    mpc.settings.t_step = rti.dt
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0}
    e = x - rti.x0
    du = u - rti.u0
    qx = 0.5 * sum(float(rti.Q[i, i]) * e[i] ** 2 for i in range(n))
    ru = 0.5 * sum(float(rti.R[i, i]) * du[i] ** 2 for i in range(m))
    mpc.set_objective(mterm=qx, lterm=qx + ru)
    mpc.set_rterm(u=0.0)
    mpc.bounds["lower", "_u", "u"] = rti.u_min
    mpc.bounds["upper", "_u", "u"] = rti.u_max
    mpc.setup()
    mpc.x0 = x_init
    mpc.set_initial_guess()

    def call(xk):
        return np.asarray(mpc.make_step(np.asarray(xk).reshape(n, 1))).ravel()

    return call


def score(rti: NonlinearMPC, X: np.ndarray, U: np.ndarray) -> tuple[float, float]:
    E = X[:-1] - rti.x0
    dU = U - rti.u0
    cost = 0.5 * float(np.einsum("ki,ij,kj->", E, rti.Q, E) + np.einsum("ki,ij,kj->", dU, rti.R, dU))
    return cost, float(np.max(np.abs(X[-1, :7] - rti.x0[:7])))


def us(v: float) -> str:
    return f"{1e6 * v:9.0f}"


def stats(T: np.ndarray) -> str:
    return f"{us(np.median(T))} {us(np.percentile(T, 90))} {us(np.max(T))}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.5, help="simulated time per run [s]")
    ap.add_argument("--repeats", type=int, default=3, help="RTI runs per loop (timing statistics over all)")
    ap.add_argument("--no-peer", action="store_true", help="skip do-mpc")
    args = ap.parse_args()
    doc = scenario()
    x_init = np.array(doc["sim"]["initial_state"], dtype=float)
    steps = round(args.seconds / doc["plant"]["dt"])
    print(
        f"7-DOF arm reach, NMPC: 14 states, 7 inputs, N = {doc['controller']['horizon']}, dt = "
        f"{doc['plant']['dt']} s, {steps} steps per run; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}"
        f", load average {os.getloadavg()[0]:.1f} (2 cores)"
    )
    t0 = time.perf_counter()
    rti = make_rti(doc, make_plant(doc, "standalone"))
    print(f"RTI controller built in {time.perf_counter() - t0:.2f} s (stage linearization compiled, or from the cache)")
    rows = []
    for loop in ("standalone", "mujoco"):
        plant = make_plant(doc, loop)
        phases: list[tuple[float, float, float, float]] = []
        daqp_calls: list[bool] = []

        def rec(c, phases=phases, daqp_calls=daqp_calls):
            last = c.last
            phases.append((last.time_linearization_s, last.time_condensing_s, last.time_qp_s, last.time_other_s))
            daqp_calls.append(last.qp_iterations > 0)  # 0: the Riccati step met every bound

        T_all, C_all, firsts = [], [], []
        for _ in range(args.repeats):
            rti.reset()
            phases_run_start = len(phases)
            X, U, T, C = closed_loop(rti, plant, x_init, steps, record=rec)
            del phases[phases_run_start]  # the cold start
            del daqp_calls[phases_run_start]
            T_all.append(T[1:])
            C_all.append(C[1:])
            firsts.append(T[0])
        T, C, P = np.concatenate(T_all), np.concatenate(C_all), np.array(phases)
        cost, err = score(rti, X, U)
        assert np.all(U <= rti.u_max) and np.all(U >= rti.u_min)
        rows.append((f"RTI, {loop}", T, C, cost, err))
        cold = us(np.median(firsts))
        print(f"\nRTI, {loop} loop: {T.size} warm calls ({args.repeats} runs); cold start (SQP) {cold} us")
        print("  median split, us:  linearize  condense        QP     other")
        print("                   " + " ".join(f"{1e6 * v:9.0f}" for v in np.median(P, axis=0)))
        print(f"  calls that needed DAQP (a bound reached): {sum(daqp_calls)} of {len(daqp_calls)}")
        if not args.no_peer:
            try:
                ctrl = do_mpc_controller(rti, x_init)
            except ImportError as exc:
                print(f"do-mpc unavailable ({exc}): pip install -e '.[bench]'")
            else:
                X, U, T, C = closed_loop(ctrl, plant, x_init, steps)
                cost, err = score(rti, X, U)
                rows.append((f"do-mpc (IPOPT), {loop}", T, C, cost, err))

    print(
        "\ncontroller                      wall us: median     p90     max |  CPU us: median     p90     max |"
        "   cost   final |q err| rad"
    )
    for name, T, C, cost, err in rows:
        print(f"{name:30s}        {stats(T)} |         {stats(C)} | {cost:8.2f}   {err:.1e}")
    rti_rows = [r for r in rows if r[0].startswith("RTI")]
    print("\ngoal: RTI median <= 1 ms per step:")
    for name, T, C, _, _ in rti_rows:
        print(f"  {name}: median {1e3 * np.median(T):.3f} ms wall, {1e3 * np.median(C):.3f} ms CPU")
    for name, T, _, _, _ in rows:
        if name.startswith("do-mpc"):
            loop = name.split(", ")[1]
            ref = next(r for r in rti_rows if r[0].endswith(loop))
            print(f"  {loop}: RTI is {np.median(T) / np.median(ref[1]):.0f}x faster per step than do-mpc (median)")
    print(
        "\nacados (not installed; users' reports on their own machines, for orientation only):\n"
        "  hexarotor, 13 states, 6 inputs, N = 20, RTI: about 2 ms average, spikes > 7 ms\n"
        "    (https://discourse.acados.org/t/how-to-stop-the-solver-after-a-certain-time-to-guarantee-"
        "constant-control-frequency/1467)\n"
        "  quadruped single-rigid-body model, RTI: preparation 0.84 ms, feedback 2.1 ms mean\n"
        "    (https://discourse.acados.org/t/advanced-step-iteration-computational-time/1529)"
    )


if __name__ == "__main__":
    main()
