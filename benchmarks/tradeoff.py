"""LQR trade-off wall time: a 20-point R sweep of the cart-pole, standalone and MuJoCo.

Each point designs the LQR, computes the loop margins (classical, disk,
sensitivity peak) and the pole damping, and runs the scenario's 5 s nonlinear
closed loop. Points run in a process pool of ``--workers`` (``forkserver``;
the first, "cold" run includes starting it, the later "warm" runs reuse it). Other processes may share the CPUs: the
figures are as measured, with the load average printed next to them.

Run: ``python benchmarks/tradeoff.py [--points N] [--workers W]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from shinro_ctrl.analysis.tradeoff import run_tradeoff


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    print(f"cart-pole LQR, R x 1e-3..1e2, {args.points} points, {args.workers} workers, cpus {os.cpu_count()}")
    # The first run starts the forkserver (and its imports); it then serves the later runs.
    for k, engine in enumerate(("standalone", "mujoco", "standalone")):
        load = os.getloadavg()
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as out:
            res = run_tradeoff(
                "cartpole_lqr.toml", "R", 1e-3, 1e2, points=args.points, engine=engine, out=out, workers=args.workers
            )
        wall = time.perf_counter() - t0
        failed = sum(bool(e) for e in res.errors)
        state = "cold" if k == 0 else "warm"
        print(
            f"  {engine:10s} {state} {wall:6.2f} s wall ({wall / args.points * 1e3:4.0f} ms/point, {failed} failed)   "
            f"load average before {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
        )


if __name__ == "__main__":
    main()
