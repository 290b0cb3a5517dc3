"""Closed-loop steps per second: cart-pole + the project's LQR, standalone and in MuJoCo.

The loop is the plain Python a user writes with the library's own controller
(``lqr = LQR.from_plant(plant, Q, R)``, then ``x = plant.step(lqr(x))``), so
the figures include every per-step cost: the controller call (its input
validation and ``u = u0 - K (x - x0)``), the plant's input validation, its
integration or the engine's ``mj_step`` plus its divergence checks, and the
state read-back.

Goals: >= 50,000 steps/s standalone and >= 20,000 steps/s in MuJoCo.
A per-call breakdown shows where the time goes; the bare ``-K @ x`` row is
the floor a controller call could reach (a gain product with no checks).

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

from shinro_ctrl.controllers import LQR
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import CartPole

GOAL_STANDALONE = 50_000
GOAL_MUJOCO = 20_000
X0 = np.array([0.0, 0.0, 0.1, 0.0])
Q_CP = [10.0, 1.0, 100.0, 1.0]
R_CP = [0.1]


def closed_loop_rate(plant: CartPole, ctrl: LQR, steps: int) -> tuple[float, np.ndarray]:
    """Steps per second of ``steps`` closed-loop steps ``x = plant.step(ctrl(x))`` from ``X0``, and the final state."""
    plant.set_state(X0)
    x = plant.get_state()
    step = plant.step
    t0 = time.perf_counter()
    for _ in range(steps):
        x = step(ctrl(x))
    return steps / (time.perf_counter() - t0), x


def rates(plant: CartPole, ctrl: LQR, steps: int, repeats: int) -> tuple[float, float, np.ndarray]:
    """Median and best steps/s over ``repeats`` runs, and the last final state."""
    results = [closed_loop_rate(plant, ctrl, steps) for _ in range(repeats)]
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


def profile_standalone(plant: CartPole, ctrl: LQR, steps: int) -> None:
    """Print where a standalone closed-loop step spends its time (cProfile, by own time)."""
    profiler = cProfile.Profile()
    profiler.enable()
    closed_loop_rate(plant, ctrl, steps)
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
    lqr = LQR.from_plant(standalone, Q_CP, R_CP)
    K = lqr.K
    simulated = CartPole()
    engine = MujocoEngine.for_plant(simulated)
    simulated.physics_engine(engine)

    med_sa, best_sa, x_sa = rates(standalone, lqr, args.steps, args.repeats)
    med_mj, best_mj, x_mj = rates(simulated, lqr, args.steps, args.repeats)

    print(f"cart-pole + LQR.from_plant, {args.steps} steps x {args.repeats} repeats, dt = {standalone.dt} s")
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
        "plant.engine_read (4 named reads)": lambda: simulated.engine_read(engine),
        "plant.step (engine attached)": lambda: simulated.step(u),
        "standalone plant.step": lambda: standalone.step(u),
        "lqr(x) (LQR.__call__)": lambda: lqr(x),
        "u = -K @ x (bare product, no checks)": lambda: -K @ x,
    }
    print("\nper-call costs (best of 7):")
    for name, fn in parts.items():
        simulated.set_state(X0)
        standalone.set_state(X0)
        print(f"  {name:36s} {per_call_us(fn):6.2f} µs")
    if args.profile or med_sa < GOAL_STANDALONE:
        profile_standalone(standalone, lqr, args.steps)


if __name__ == "__main__":
    main()
