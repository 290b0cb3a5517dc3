"""Per-call timing for the benchmarks: the median of individually timed calls, the minimum over repeats.

The machine the figures come from is shared (a 2-core VM on a shared host): a block of calls timed as one
(``total / calls``) absorbs every preemption and every slow phase of the host into its mean, so block means of
the same code vary by 2× between runs. Timing each call and taking the median discards the preempted calls;
the minimum over a few repeats discards a repeat that ran entirely in a slow phase. The mean of all samples is
returned beside it, so a loaded run can be told from a quiet one.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

CALLS, WARMUP, REPEATS = 2000, 200, 3


def per_call_us(
    fn: Callable[[], object], calls: int = CALLS, warmup: int = WARMUP, repeats: int = REPEATS
) -> tuple[float, float]:
    """``(median, mean)`` [µs] per call of ``fn``: min over ``repeats`` of the median of ``calls`` timed calls
    (after ``warmup`` untimed ones), and the mean of all timed calls."""
    clock = time.perf_counter_ns
    medians, means = [], []
    samples = np.empty(calls)
    for _ in range(repeats):
        for _ in range(warmup):
            fn()
        for k in range(calls):
            t0 = clock()
            fn()
            samples[k] = clock() - t0
        medians.append(float(np.median(samples)) / 1e3)
        means.append(float(samples.mean()) / 1e3)
    return min(medians), float(np.mean(means))
