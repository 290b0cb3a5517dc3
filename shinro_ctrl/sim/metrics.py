"""Metrics of a closed-loop run: tracking error, settling, inputs, bound excess, response shape."""

from __future__ import annotations

import math

import numpy as np

from shinro_ctrl.errors import NonFiniteError

__all__ = ["NEVER_METRICS", "bound_excess", "compute_metrics", "format_metrics", "response_metrics"]

NEVER_METRICS = ("settling_time", "rise_time")  # inf means the event never happened, not an overflow


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
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == len(e) - 1:
        settling = math.inf
    else:
        settling = float(t[outside[-1] + 1])

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
