"""Closed-loop steps per second: cart-pole + a fixed LQR gain, standalone and in MuJoCo.

The loop is the plain Python a user writes (``u = -K @ x; x = plant.step(u)``),
so the figures include every per-step cost: input validation, the plant's
integration or the engine's ``mj_step`` plus its divergence checks, and the
state read-back. The gain comes from ``scipy.linalg.solve_discrete_are`` on
``plant.get_model()`` (no dependency on ``shinro_ctrl.controllers``).

Goals: >= 50,000 steps/s standalone and >= 20,000 steps/s in MuJoCo.
A breakdown of the MuJoCo step shows where the time goes.

Run: ``python benchmarks/engine.py [--steps N] [--repeats R]``.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
from collections.abc import Callable

import mujoco
import numpy as np
import scipy.linalg

from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import CartPole

GOAL_STANDALONE = 50_000
GOAL_MUJOCO = 20_000
X0 = np.array([0.0, 0.0, 0.1, 0.0])


def lqr_gain(plant: CartPole) -> np.ndarray:
    """Discrete LQR gain ``K (1, 4)`` at the upright equilibrium."""
    A, B = plant.get_model()
    Q, R = np.diag([10.0, 1.0, 100.0, 1.0]), np.array([[0.1]])
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    return np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)


def closed_loop_rate(plant: CartPole, K: np.ndarray, steps: int) -> tuple[float, np.ndarray]:
    """Steps per second of ``steps`` closed-loop steps from ``X0``, and the final state."""
    plant.set_state(X0)
    x = plant.get_state()
    step = plant.step
    negK = -K
    t0 = time.perf_counter()
    for _ in range(steps):
        x = step(negK @ x)
    return steps / (time.perf_counter() - t0), x


def rates(plant: CartPole, K: np.ndarray, steps: int, repeats: int) -> tuple[float, float, np.ndarray]:
    """Median and best steps/s over ``repeats`` runs, and the last final state."""
    results = [closed_loop_rate(plant, K, steps) for _ in range(repeats)]
    r = [rate for rate, _ in results]
    return float(np.median(r)), float(max(r)), results[-1][1]


def per_call_us(fn: Callable[[], object], number: int = 2_000, repeats: int = 7) -> float:
    """Best-of-``repeats`` time of one call [µs] (the least disturbed by other load)."""
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - t0) / number * 1e6)
    return float(min(samples))


def profile_standalone(plant: CartPole, K: np.ndarray, steps: int) -> None:
    """Print where a standalone closed-loop step spends its time (cProfile, by own time)."""
    profiler = cProfile.Profile()
    profiler.enable()
    closed_loop_rate(plant, K, steps)
    profiler.disable()
    out = io.StringIO()
    pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(10)
    print("\nstandalone profile (cProfile inflates every call; read the shares):")
    print("\n".join(line for line in out.getvalue().splitlines()[4:] if line.strip()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--profile", action="store_true", help="profile the standalone loop")
    args = parser.parse_args()

    standalone = CartPole()
    K = lqr_gain(standalone)
    simulated = CartPole()
    engine = MujocoEngine.for_plant(simulated)
    simulated.physics_engine(engine)

    med_sa, best_sa, x_sa = rates(standalone, K, args.steps, args.repeats)
    med_mj, best_mj, x_mj = rates(simulated, K, args.steps, args.repeats)

    print(f"cart-pole + LQR, {args.steps} steps x {args.repeats} repeats, dt = {standalone.dt} s")
    print(f"{'loop':12s} {'median/s':>10s} {'best/s':>10s} {'µs/step':>9s} {'goal':>8s}        final |theta|")
    for name, med, best, goal, x in (
        ("standalone", med_sa, best_sa, GOAL_STANDALONE, x_sa),
        ("mujoco", med_mj, best_mj, GOAL_MUJOCO, x_mj),
    ):
        ok = "ok" if med >= goal else "BELOW"
        print(f"{name:12s} {med:10,.0f} {best:10,.0f} {1e6 / med:9.2f} {goal:8,d} {ok:>5s}  {abs(x[2]):.1e}")

    # Where a MuJoCo closed-loop step goes (µs per call).
    m, d = engine.model, engine.data
    u = np.array([0.0])
    x = simulated.get_state()
    parts = {
        "mj_step": lambda: mujoco.mj_step(m, d),
        "engine.step (mj_step + checks)": engine.step,
        "engine.set_joint_ctrl": lambda: engine.set_joint_ctrl("slider", 0.0),
        "plant._engine_read (4 named reads)": lambda: simulated._engine_read(engine),
        "plant.step (engine attached)": lambda: simulated.step(u),
        "standalone plant.step": lambda: standalone.step(u),
        "u = -K @ x": lambda: -K @ x,
    }
    print("\nper-call costs (best of 7):")
    for name, fn in parts.items():
        simulated.set_state(X0)
        standalone.set_state(X0)
        print(f"  {name:36s} {per_call_us(fn):6.2f} µs")
    if args.profile or med_sa < GOAL_STANDALONE:
        profile_standalone(standalone, K, args.steps)


if __name__ == "__main__":
    main()
