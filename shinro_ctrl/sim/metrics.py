"""Metrics of a closed-loop run: tracking error, settling, inputs, bound excess, response shape."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from shinro_ctrl.errors import NonFiniteError

__all__ = [
    "NEVER_METRICS",
    "RESPONSE_METRICS",
    "StreamingMetrics",
    "bound_excess",
    "compute_metrics",
    "format_metrics",
    "plan_tracking_rms",
    "response_metrics",
    "settling_time",
]

NEVER_METRICS = ("settling_time", "rise_time")  # inf means the event never happened, not an overflow
#: The step-response metrics of :func:`response_metrics` (newer than some stored baselines).
RESPONSE_METRICS = ("overshoot", "rise_time")


def bound_excess(values: np.ndarray, lo: np.ndarray | None, hi: np.ndarray | None) -> np.ndarray:
    """Largest excess of each row of ``values (T, k)`` over the bounds ``lo``/``hi (k,)`` (0 when inside).

    An excess counts only beyond a relative 1e-9 (solver rounding at an active bound).
    """
    out = np.zeros(values.shape[0])
    for bound, sign in ((lo, -1.0), (hi, 1.0)):
        if bound is None:
            continue
        b = np.asarray(bound, dtype=float)
        finite = np.isfinite(b)
        if not finite.any():
            continue
        over = sign * (values[:, finite] - b[finite]) - 1e-9 * (1.0 + np.abs(b[finite]))
        out = np.maximum(out, np.maximum(over, 0.0).max(axis=1))
    return out


def settling_time(t: np.ndarray, last_outside: Any) -> np.ndarray:
    """Settling time from the index of the last sample outside the tolerance band.

    The run has settled at ``t[k + 1]`` when sample ``k`` is the last whose
    tracking error exceeds the tolerance: ``0`` when no sample does (``k = -1``),
    ``inf`` when the final sample does.

    Args:
        t: Sample times ``(T + 1,)`` [s].
        last_outside: ``k`` (a scalar, or ``(N,)`` for N instances).

    Returns:
        The settling time(s) [s], shaped like ``last_outside``.
    """
    last = np.asarray(last_outside)
    steps = t.shape[0] - 1
    settled = np.where(last < 0, 0.0, t[np.minimum(last + 1, steps)])
    return np.where(last == steps, math.inf, settled)


def compute_metrics(
    t: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    ref: np.ndarray,
    *,
    tracked: list[int],
    settle_tol: float = 0.01,
    u_min: np.ndarray | None = None,
    u_max: np.ndarray | None = None,
    x_min: np.ndarray | None = None,
    x_max: np.ndarray | None = None,
    plant_violation: np.ndarray | None = None,
    solve_times: np.ndarray | None = None,
) -> dict[str, float]:
    """Metrics of a closed-loop run.

    The tracking error is ``e_k = ‖x_k[tracked] − r_k[tracked]‖₂``.

    Returns:
        ``rms_error`` (``sqrt(mean e_k²)``), ``max_error``, ``final_error``,
        ``settling_time`` (first time after which ``e`` stays within
        ``settle_tol``; ``inf`` if it never does), ``max_abs_input``,
        ``constraint_violations`` (steps at which an input or state bound, or
        a plant limit, is exceeded by more than 1e-9 relative),
        ``max_violation`` (the largest such excess),
        ``solve_time_median_s`` (median controller call), and for a step or
        initial-condition response ``overshoot`` and ``rise_time`` (see
        :func:`response_metrics`).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        d = x[:, tracked] - ref[:, tracked]
        scale = float(np.abs(d).max(initial=0.0))
        if scale > 1e150 and math.isfinite(scale):  # squares would overflow: norms of the scaled errors
            e = scale * np.linalg.norm(d / scale, axis=1)
            rms = scale * float(np.sqrt(np.mean((e / scale) ** 2)))
        else:
            e = np.linalg.norm(d, axis=1)
            rms = float(np.sqrt(np.mean(e**2)))
    if not (math.isfinite(rms) and np.all(np.isfinite(e))):
        raise NonFiniteError(
            f"the tracking-error metrics overflow float64 (errors up to {scale:.3g}): the run left the range "
            "where its metrics can be computed"
        )
    outside = np.nonzero(e > settle_tol)[0]
    settling = float(settling_time(t, outside[-1] if outside.size else -1))

    viol = np.zeros(len(t))
    viol[:-1] = np.maximum(viol[:-1], bound_excess(u, u_min, u_max))
    viol[1:] = np.maximum(viol[1:], bound_excess(x[1:], x_min, x_max))
    if plant_violation is not None:
        viol = np.maximum(viol, plant_violation)
    return {
        "rms_error": rms,
        "max_error": float(e.max()),
        "final_error": float(e[-1]),
        "settling_time": settling,
        "max_abs_input": float(np.abs(u).max()) if u.size else 0.0,
        "constraint_violations": int(np.count_nonzero(viol > 0)),
        "max_violation": float(viol.max()),
        "solve_time_median_s": float(np.median(solve_times)) if solve_times is not None and solve_times.size else 0.0,
        **response_metrics(t, x[:, tracked], ref[:, tracked], settle_tol),
    }


def response_metrics(t: np.ndarray, x: np.ndarray, ref: np.ndarray, settle_tol: float = 0.01) -> dict[str, float]:
    """``overshoot`` [%] and ``rise_time`` [s] of a step or initial-condition response (else ``{}``).

    Meaningful when the reference ``ref (T+1, k)`` is constant (the run recovers
    from its initial deviation) or changes once (a step; measured from the
    step). The response is that of the tracked state with the largest
    deviation from the new reference at the start, and it must exceed
    ``settle_tol``; see :func:`shinro_ctrl.analysis.step_metrics` (overshoot
    past the reference, 10–90 % rise time, ``inf`` if 90 % is never reached).
    """
    from shinro_ctrl.analysis.response import step_metrics

    changes = np.flatnonzero(np.any(ref[1:] != ref[:-1], axis=1))
    if changes.size > 1 or x.shape[1] == 0:
        return {}
    k0 = int(changes[0]) + 1 if changes.size else 0
    d0 = x[k0] - ref[k0]
    j = int(np.argmax(np.abs(d0)))
    if not abs(d0[j]) > settle_tol or k0 >= len(t) - 1 or not np.all(np.isfinite(x[k0:, j])):
        return {}
    target = float(ref[k0, j])
    m = step_metrics(t[k0:] - t[k0], x[k0:, j], initial=float(x[k0, j]), final=target, target=target)
    return {"overshoot": m.overshoot, "rise_time": m.rise_time}


def format_metrics(metrics: dict[str, float]) -> str:
    """A two-column table of metrics."""
    units = {"settling_time": "s", "solve_time_median_s": "s", "rise_time": "s", "overshoot": "%"}
    rows = []
    for k, v in metrics.items():
        if isinstance(v, float) and math.isinf(v):
            val = "never" if k in NEVER_METRICS else ("inf" if v > 0 else "-inf")
        elif isinstance(v, int):
            val = str(v)
        else:
            val = f"{v:.6g}"
        rows.append(f"  {k:22s} {val:>14s} {units.get(k, '')}".rstrip())
    return "\n".join(rows)


class StreamingMetrics:
    """The metrics of :func:`compute_metrics` for ``N`` instances, accumulated while stepping (O(N) memory).

    Used by the vectorized batch rollout (:mod:`shinro_ctrl.sweep.batch`). Same
    definitions: ``e_k = ‖x_k[tracked] − r[tracked]‖₂``; rms over the ``T + 1``
    samples; :func:`settling_time` after the last sample outside
    ``settle_tol``; a violation counted at index ``k`` from input ``k`` and
    state ``k``.
    """

    def __init__(self, N: int, tracked: list[int], r: np.ndarray, settle_tol: float):
        self.tr = np.asarray(tracked, dtype=int)
        self.r_tr = r[self.tr]
        self.settle_tol = settle_tol
        self.e2_sum = np.zeros(N)
        self.e_max = np.zeros(N)
        self.e = np.zeros(N)
        self.last_out = np.full(N, -1, dtype=int)
        self.u_abs_max = np.zeros(N)
        self.viol_count = np.zeros(N, dtype=int)
        self.viol_max = np.zeros(N)

    def track(self, X: np.ndarray, k: int) -> None:
        """The tracking error of sample ``k``."""
        e = self.e = np.linalg.norm(X[:, self.tr] - self.r_tr, axis=1)
        np.add(self.e2_sum, e * e, out=self.e2_sum)
        np.maximum(self.e_max, e, out=self.e_max)
        self.last_out[e > self.settle_tol] = k

    def inputs(self, U: np.ndarray, viol: np.ndarray) -> None:
        """The inputs of one step and the violation at its index."""
        np.maximum(self.u_abs_max, np.abs(U).max(axis=1), out=self.u_abs_max)
        self.violation(viol)

    def violation(self, viol: np.ndarray) -> None:
        self.viol_count += viol > 0
        np.maximum(self.viol_max, viol, out=self.viol_max)

    def finish(self, t: np.ndarray, call_times: np.ndarray, alive: np.ndarray) -> dict[str, np.ndarray]:
        """Metric name -> ``(N,)`` (NaN for diverged instances)."""
        steps = t.shape[0] - 1
        N = alive.shape[0]
        metrics = {
            "rms_error": np.sqrt(self.e2_sum / (steps + 1)),
            "max_error": self.e_max,
            "final_error": self.e,
            "settling_time": settling_time(t, self.last_out),
            "max_abs_input": self.u_abs_max,
            "constraint_violations": self.viol_count.astype(float),
            "max_violation": self.viol_max,
            "solve_time_median_s": np.full(N, float(np.median(call_times)) / max(N, 1)),
        }
        for v in metrics.values():
            v[~alive] = math.nan
        return metrics


def plan_tracking_rms(x: np.ndarray, x_plan: np.ndarray, tracked: list[int]) -> float | None:
    """RMS over a plan's span of ``‖x_k[tracked] − x_plan,k[tracked]‖₂`` (a plan-tracking controller's error).

    Args:
        x: States ``(T + 1, n)`` of the run.
        x_plan: The plan's states at the same times, NaN rows outside the plan's span
            (:meth:`~shinro_ctrl.controllers.tvlqr.TVLQR.plan_states`).
        tracked: The state indices the error metrics use.

    Returns:
        The RMS, or None when no sample lies within the plan's span.
    """
    inside = np.all(np.isfinite(x_plan[:, tracked]), axis=1)
    if not np.any(inside):
        return None
    e = np.linalg.norm(x[inside][:, tracked] - x_plan[inside][:, tracked], axis=1)
    return float(np.sqrt(np.mean(e**2)))
