"""Robustness-sweep throughput: MuJoCo samples on 1 vs 2 worker processes, and the batch rollout.

(a) A Monte-Carlo sweep of the MuJoCo cart-pole LQR scenario
    (``configs/cartpole_lqr_mujoco.toml``) over ``plant.pole_mass`` and
    ``plant.pole_length``: every sample builds its plant and a matched MuJoCo
    model and runs the 5 s loop. One worker runs in-process; two workers are a
    process pool (timed cold, i.e. including the start of the ``forkserver``
    and its imports, and warm, with the server already running). The tables
    must be identical.
(b) A 10,000-sample standalone cart-pole LQR sweep through the vectorized
    batch rollout (goal: <= 10 s on one core; BLAS threads are pinned to one).

Other processes may share the CPUs: the figures are as measured, with the
load average printed next to them.

Run: ``python benchmarks/sweep.py [--mujoco-samples N] [--batch-samples N]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # "one core" for the batch rollout (set before numpy loads)

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

from shinro_ctrl.sweep import SweepResult, run_sweep  # noqa: E402

MUJOCO_CONFIG = "cartpole_lqr_mujoco"
MUJOCO_RANGES = {"plant.pole_mass": (0.05, 0.5), "plant.pole_length": (0.25, 1.25)}
BATCH_CONFIG = "cartpole_lqr"
BATCH_RANGES = {"plant.pole_mass": (0.05, 0.5), "plant.pole_length": (0.25, 1.25)}
GOAL_BATCH_S = 10.0


def _load() -> str:
    try:
        return "load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:  # pragma: no cover
        return "load average n/a"


def _table(result: SweepResult) -> list[tuple]:
    """The deterministic part of a table (every column but the wall-clock solve time)."""
    out = []
    for r in result.rows:
        metrics = tuple(
            "nan" if isinstance(v, float) and math.isnan(v) else v
            for k, v in r.metrics.items()
            if k != "solve_time_median_s"
        )
        out.append((r.index, tuple(r.params.values()), metrics, r.stable, r.error))
    return out


def _timed(**kw) -> tuple[SweepResult, float, float]:
    cpu0, t0 = time.process_time(), time.perf_counter()
    res = run_sweep(**kw)
    return res, time.perf_counter() - t0, time.process_time() - cpu0


def bench_mujoco(samples: int) -> None:
    print(f"(a) {MUJOCO_CONFIG}: {samples} Monte-Carlo samples over {', '.join(MUJOCO_RANGES)} (5 s loops)")
    kw = {"config": MUJOCO_CONFIG, "params": MUJOCO_RANGES, "samples": samples, "seed": 0, "progress": False}
    one, t1, _ = _timed(workers=1, **kw)
    print(f"    1 worker  ({one.method:6s}) {t1:7.2f} s   {1e3 * t1 / samples:7.1f} ms/sample   {_load()}")
    cold, t2c, _ = _timed(workers=2, method="pool", **kw)
    print(f"    2 workers ({cold.method:6s}) {t2c:7.2f} s   cold (starts the forkserver)  speed-up {t1 / t2c:.2f}x")
    warm, t2w, _ = _timed(workers=2, method="pool", **kw)
    print(f"    2 workers ({warm.method:6s}) {t2w:7.2f} s   warm                          speed-up {t1 / t2w:.2f}x")
    same = "yes" if _table(one) == _table(cold) == _table(warm) else "NO"
    print(f"    stable {int(one.stable.sum())}/{samples}; tables identical across worker counts: {same}")
    print(f"    {_load()}")


def bench_batch(samples: int) -> None:
    print(f"(b) {BATCH_CONFIG}: {samples} Monte-Carlo samples through the batch rollout (standalone LQR, 5 s loops)")
    res, wall, cpu = _timed(config=BATCH_CONFIG, params=BATCH_RANGES, samples=samples, seed=0, progress=False)
    tm = res.timings
    inst_steps = tm["instances"] * tm["steps"]
    print(f"    method {res.method}; {int(tm['instances'])} instances x {int(tm['steps'])} steps")
    print(
        f"    run_sweep total  {wall:6.2f} s wall, {cpu:6.2f} s CPU (drawing, the nominal LQR design, "
        f"plants, rollout, table)"
    )
    print(f"    building plants  {tm['build_plants_s']:6.2f} s")
    print(
        f"    rollout          {tm['rollout_s']:6.2f} s   {1e6 * tm['rollout_s'] / inst_steps:.3f} µs per instance-step"
    )
    verdict = "met" if wall <= GOAL_BATCH_S else "MISSED"
    print(f"    goal <= {GOAL_BATCH_S:g} s: {verdict}; stable {int(res.stable.sum())}/{samples}   {_load()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mujoco-samples", type=int, default=200)
    parser.add_argument("--batch-samples", type=int, default=10_000)
    args = parser.parse_args()
    bench_mujoco(args.mujoco_samples)
    print()
    bench_batch(args.batch_samples)


if __name__ == "__main__":
    main()
