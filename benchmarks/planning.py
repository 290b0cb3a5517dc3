"""Trajectory optimization of the cart-pole swing-up: our TrajectoryOptimizer per method vs Drake; TVLQR design time.

Problem (the issue's): ``CartPole()`` defaults (M = 0.5, m = 0.1, l = 0.5 kg/m), from hanging
``[0, 0, π, 0]`` to upright ``0``, ``|F| <= 5`` N, ``|x| <= 1`` m at every knot, 61 knots, free
final time ``T`` in [0.5, 5] s, cost ``T + 10 ∫ F² dt``. Every solver starts from the same guess:
states linear from start to goal, zero force, ``T = 2.75`` s (the middle of its range).

Rows:

* ``ours <method>``: :class:`~shinro_ctrl.planning.TrajectoryOptimizer`, the NLP built once
  (``build`` column) and re-solved (``solve`` = median wall time of the IPOPT call).
* ``ours hermite_simpson from Drake's``: our solve started at Drake's result (a diagnostic: the
  swing-up has several local optima; this row shows whether both transcriptions agree on Drake's).
* ``drake DirectCollocation``: Drake's Hermite-Simpson transcription (first-order-hold inputs, like
  ours) of the same dynamics, written as a ``SymbolicVectorSystem`` (so Drake can differentiate
  it), equal time steps, the same bounds, ``AddRunningCost(10 F²)`` and the sum of the time steps
  as the time cost, solved by IPOPT (Drake's default options); ``solve`` includes nothing but
  ``Solve(prog)``. Skipped with a message when pydrake is not importable.

Objectives: ``objective`` is each solver's own value (Drake integrates the running cost with the
trapezoidal rule on the knots; ours exactly for the linear input); ``J common`` re-evaluates every
result as ``T + 10 Σ h (u_k² + u_k u_{k+1} + u_{k+1}²)/3`` (exact for first-order-hold inputs),
so the rows compare like with like. ``defect`` is the largest Hermite-Simpson defect of the
returned knots recomputed here with numpy (for trapezoid / multiple shooting: their own).

TVLQR: ``TVLQR.from_trajectory`` along a fixed 3 s swing-up plan at 100 Hz (300 steps): Jacobians
in one CasADi map call, Euler discretization, Riccati recursion, the goal LQR; median of repeats.

Run: ``python benchmarks/planning.py [--repeats 5] [--drake-repeats 2]``. Figures vary with machine
load (2 shared cores here): read the ratios, and the ``cpu s`` column (process CPU time of the same
calls) beside the wall-clock ``solve s``. OpenBLAS is pinned to one thread unless
``OPENBLAS_NUM_THREADS`` is set: every matrix here is tiny, and on a loaded machine OpenBLAS's worker
threads made scipy's DARE (inside the goal LQR) about 10x slower (15 ms instead of 1.2 ms).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS (see the module doc)

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from shinro_ctrl.controllers.tvlqr import TVLQR
from shinro_ctrl.errors import PlanningFailed
from shinro_ctrl.planning import METHODS, TrajectoryOptimizer
from shinro_ctrl.plants import CartPole

START = np.array([0.0, 0.0, np.pi, 0.0])
GOAL = np.zeros(4)
KNOTS = 61
T_RANGE = (0.5, 5.0)
U_MAX = 5.0
X_MAX = 1.0
W_EFFORT = 10.0


def common_objective(t: np.ndarray, u: np.ndarray) -> float:
    """``T + 10 ∫ u² dt`` for inputs linear between knots (exact)."""
    h = np.diff(t)
    a, b = u[:-1], u[1:]
    return float(t[-1] - t[0] + W_EFFORT * np.sum(h * (a * a + a * b + b * b) / 3))


def hs_defect(plant: CartPole, t: np.ndarray, x: np.ndarray, u: np.ndarray) -> float:
    """Largest Hermite-Simpson (first-order hold) defect of knots ``x (N, 4)``, ``u (N, 1)``."""
    h = np.diff(t)[:, None]
    fa, fb = plant.dynamics(x[:-1], u[:-1]), plant.dynamics(x[1:], u[1:])
    xc = (x[:-1] + x[1:]) / 2 + h / 8 * (fa - fb)
    fc = plant.dynamics(xc, (u[:-1] + u[1:]) / 2)
    return float(np.abs(x[1:] - x[:-1] - h / 6 * (fa + 4 * fc + fb)).max())


def bench_ours(plant: CartPole, method: str, repeats: int) -> dict:
    t0 = time.perf_counter()
    opt = TrajectoryOptimizer(
        plant, knots=KNOTS, method=method, u_min=[-U_MAX], u_max=[U_MAX], x_min=[-X_MAX] + [-np.inf] * 3,
        x_max=[X_MAX] + [np.inf] * 3,
    )  # fmt: skip
    build = time.perf_counter() - t0
    times, cpus, traj, ok = [], [], None, True
    for _ in range(repeats):
        try:
            c0 = time.process_time()
            traj = opt.solve(START, GOAL, duration=T_RANGE, cost={"time": 1.0, "effort": W_EFFORT})
            cpus.append(time.process_time() - c0)
            times.append(traj.solve_time)
        except PlanningFailed as exc:  # a benchmark row reports the failure instead of stopping
            ok = False
            print(f"  ours {method}: {exc}")
    if traj is None:
        return {"name": f"ours {method}", "success": False}
    defect = hs_defect(plant, traj.t, traj.x, traj.u) if method == "hermite_simpson" else traj.max_defect
    return {
        "name": f"ours {method}",
        "build": build,
        "solve": float(np.median(times)),
        "cpu": float(np.median(cpus)),
        "iterations": traj.iterations,
        "objective": traj.objective,
        "common": common_objective(traj.t, traj.u[:, 0]) if method != "multiple_shooting" else float("nan"),
        "T": traj.duration,
        "defect": defect,
        "success": ok,
    }


def drake_cartpole_system(plant: CartPole):
    """The cart-pole's dynamics as a pydrake SymbolicVectorSystem (the same equations as ``CartPole._f``)."""
    from pydrake.symbolic import Variable, cos, sin
    from pydrake.systems.primitives import SymbolicVectorSystem

    x = [Variable(n) for n in ("x", "x_dot", "theta", "theta_dot")]
    F = Variable("F")
    M, m, l, b, g = plant.M, plant.m, plant.l, plant.b, plant.g
    _, xd, th, thd = x
    s, c = sin(th), cos(th)
    rhs_x = F + m * l * thd**2 * s
    rhs_t = m * g * l * s - b * thd
    det = m * l**2 * (M + m * s**2)
    xdd = (m * l**2 * rhs_x - m * l * c * rhs_t) / det
    thdd = ((M + m) * rhs_t - m * l * c * rhs_x) / det
    return SymbolicVectorSystem(state=x, input=[F], dynamics=[xd, xdd, thd, thdd])


def bench_drake(plant: CartPole, repeats: int) -> dict | None:
    try:
        from pydrake.planning import DirectCollocation
        from pydrake.solvers import IpoptSolver, SolverOptions
        from pydrake.trajectories import PiecewisePolynomial
    except ImportError as exc:
        print(f"drake DirectCollocation: skipped (pydrake not importable: {exc}); pip install 'shinro_ctrl[bench]'")
        return None
    system = drake_cartpole_system(plant)
    context = system.CreateDefaultContext()
    t0 = time.perf_counter()
    N = KNOTS
    dircol = DirectCollocation(system, context, N, T_RANGE[0] / (N - 1), T_RANGE[1] / (N - 1))
    prog = dircol.prog()
    dircol.AddEqualTimeIntervalsConstraints()
    u = dircol.input()
    dircol.AddConstraintToAllKnotPoints(-U_MAX <= u[0])
    dircol.AddConstraintToAllKnotPoints(u[0] <= U_MAX)
    xs = dircol.state()
    dircol.AddConstraintToAllKnotPoints(-X_MAX <= xs[0])
    dircol.AddConstraintToAllKnotPoints(xs[0] <= X_MAX)
    prog.AddBoundingBoxConstraint(START, START, dircol.initial_state())
    prog.AddBoundingBoxConstraint(GOAL, GOAL, dircol.final_state())
    dircol.AddRunningCost(W_EFFORT * u[0] ** 2)
    prog.AddLinearCost(sum(dircol.time_step(i)[0] for i in range(N - 1)))
    T0 = 0.5 * (T_RANGE[0] + T_RANGE[1])
    guess_x = PiecewisePolynomial.FirstOrderHold([0.0, T0], np.column_stack([START, GOAL]))
    guess_u = PiecewisePolynomial.FirstOrderHold([0.0, T0], np.zeros((1, 2)))
    dircol.SetInitialTrajectory(guess_u, guess_x)
    build = time.perf_counter() - t0
    solver = IpoptSolver()
    log = Path(tempfile.mkdtemp()) / "ipopt.log"
    options = SolverOptions()  # Drake's IPOPT defaults, plus a log file to read the iteration count from
    options.SetOption(solver.solver_id(), "output_file", str(log))
    options.SetOption(solver.solver_id(), "file_print_level", 3)
    times, cpus, result = [], [], None
    for _ in range(repeats):
        t1, c1 = time.perf_counter(), time.process_time()
        result = solver.Solve(prog, None, options)
        times.append(time.perf_counter() - t1)
        cpus.append(time.process_time() - c1)
    ok = result.is_success()
    t = np.asarray(dircol.GetSampleTimes(result))
    x = np.asarray(dircol.GetStateSamples(result)).T
    uu = np.asarray(dircol.GetInputSamples(result)).T
    details = result.get_solver_details()
    found = re.search(r"Number of Iterations\.*:\s*(\d+)", log.read_text()) if log.exists() else None
    iters = int(found.group(1)) if found else None
    return {
        "name": "drake DirectCollocation (IPOPT)",
        "build": build,
        "solve": float(np.median(times)),
        "cpu": float(np.median(cpus)),
        "iterations": iters if iters is not None else -1,
        "objective": float(result.get_optimal_cost()),
        "common": common_objective(t, uu[:, 0]),
        "T": float(t[-1]),
        "defect": hs_defect(plant, t, x, uu),
        "success": ok,
        "status": str(details.status) if hasattr(details, "status") else "",
        "knots": (t, x, uu),
    }


def bench_from_drake(plant: CartPole, knots: tuple) -> dict:
    """Our Hermite-Simpson solve started at Drake's optimum: do the two transcriptions agree there?"""
    t, x, u = knots
    opt = TrajectoryOptimizer(
        plant, knots=KNOTS, method="hermite_simpson", u_min=[-U_MAX], u_max=[U_MAX],
        x_min=[-X_MAX] + [-np.inf] * 3, x_max=[X_MAX] + [np.inf] * 3,
    )  # fmt: skip
    c0 = time.process_time()
    guess = {"T": float(t[-1]), "x": x, "u": u}
    traj = opt.solve(START, GOAL, duration=T_RANGE, cost={"time": 1.0, "effort": W_EFFORT}, initial_guess=guess)
    return {
        "name": "ours hermite_simpson from Drake's",
        "build": 0.0,
        "solve": traj.solve_time,
        "cpu": time.process_time() - c0,
        "iterations": traj.iterations,
        "objective": traj.objective,
        "common": common_objective(traj.t, traj.u[:, 0]),
        "T": traj.duration,
        "defect": hs_defect(plant, traj.t, traj.x, traj.u),
        "success": True,
    }


def bench_tvlqr(plant: CartPole, repeats: int) -> tuple[float, float, int]:
    opt = TrajectoryOptimizer(
        plant, knots=61, method="hermite_simpson", u_min=[-U_MAX], u_max=[U_MAX], x_min=[-X_MAX] + [-np.inf] * 3,
        x_max=[X_MAX] + [np.inf] * 3,
    )  # fmt: skip
    traj = opt.solve(START, GOAL, duration=3.0, cost={"effort": 1.0}, u_goal=[0.0])
    times, cpus = [], []
    ctrl = None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        ctrl = TVLQR.from_trajectory(plant, traj, [10, 1, 10, 1], [1.0], dt=0.01)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return float(np.median(times)), float(np.median(cpus)), ctrl.horizon


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="solves per method of ours (median)")
    ap.add_argument("--drake-repeats", type=int, default=2, help="solves by Drake (median)")
    args = ap.parse_args()
    plant = CartPole()
    print(
        f"cart-pole swing-up: {KNOTS} knots, |F| <= {U_MAX} N, |x| <= {X_MAX} m, T in {T_RANGE} s, "
        f"cost T + {W_EFFORT:g} int F^2"
    )
    rows = [bench_ours(plant, m, args.repeats) for m in METHODS]
    drake = bench_drake(plant, args.drake_repeats)
    if drake is not None:
        rows.append(drake)
        rows.append(bench_from_drake(plant, drake["knots"]))
    head = (
        f"{'solver':34s} {'build s':>8s} {'solve s':>8s} {'cpu s':>7s} {'iters':>6s} {'objective':>10s} "
        f"{'J common':>10s} {'T s':>6s} {'defect':>9s} success"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        if "solve" not in r:
            print(f"{r['name']:34s} failed")
            continue
        print(
            f"{r['name']:34s} {r['build']:8.3f} {r['solve']:8.3f} {r['cpu']:7.3f} {r['iterations']:6d} "
            f"{r['objective']:10.4f} {r['common']:10.4f} {r['T']:6.3f} {r['defect']:9.1e} {r['success']}"
        )
    ours = rows[0]
    if drake is not None and "solve" in ours:
        print(
            f"hermite_simpson vs Drake: {drake['solve'] / ours['solve']:.1f}x faster wall, "
            f"{drake['cpu'] / ours['cpu']:.1f}x cpu (goal >= 20x); "
            f"J common {ours['common']:.4f} vs {drake['common']:.4f} "
            f"({'equal or better' if ours['common'] <= drake['common'] * (1 + 1e-6) else 'worse'})"
        )
    if "solve" in ours:
        print(
            f"hermite_simpson solve {ours['solve']:.3f} s wall, {ours['cpu']:.3f} s cpu (goal <= 0.3 s, stretch 0.1 s)"
        )
    t_tv, c_tv, steps = bench_tvlqr(plant, 20)
    print(
        f"TVLQR.from_trajectory along a 3 s plan at 100 Hz ({steps} steps): {t_tv * 1e3:.2f} ms wall, "
        f"{c_tv * 1e3:.2f} ms cpu (goal <= 20 ms)"
    )
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
