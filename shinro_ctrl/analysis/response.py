"""Step and initial-condition response metrics, and the linear closed-loop response.

For a response ``y(t)`` from ``y_0 = y(t_0)`` to ``y_f`` (by default the last
sample), with the normalized progress ``s(t) = (y(t) − y_0) / (y_f − y_0)``:

* rise time: first time ``s ≥ 0.9`` minus first time ``s ≥ 0.1`` (crossings
  interpolated linearly between samples; None when either level is never reached);
* overshoot: ``100 · max(0, max s − 1)`` [%];
* settling time: the time after which ``|y − y_f| ≤ 0.02 |y_f − y_0|`` holds
  (the first sample after the last one outside the band; None when the last sample is outside);
* steady-state error: ``target − y_f`` (0 when no target is given).

For a unit step from 0 these are the definitions of ``control.step_info``
(which normalizes by ``y_f`` instead of ``y_f − y_0``, the same thing when
``y_0 = 0``). An initial-condition response that decays to zero (a regulator
recovering from a tilt) has ``y_f = 0`` and ``s`` going from 0 to 1 as ``y``
goes from ``y_0`` to 0: the overshoot is then how far it swings past zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument

__all__ = ["StepMetrics", "closed_loop_response", "step_metrics"]


@dataclass(frozen=True)
class StepMetrics:
    """Result of :func:`step_metrics` (times in the units of ``t``).

    Attributes:
        rise_time: 10–90 % rise time (None if 10 % or 90 % is never reached).
        overshoot: Overshoot [%] past the final value.
        settling_time: 2 % settling time (None if the last sample is outside the band).
        steady_state_error: ``target − y_final`` (None when not applicable: see
            :func:`~shinro_ctrl.analysis.analyze_controller`).
        peak: Largest ``|y − y_0|`` relative excursion value, i.e. ``y`` at the peak of ``s``.
        peak_time: Time of that peak.
        final_value: ``y_final``.
    """

    rise_time: float | None
    overshoot: float
    settling_time: float | None
    steady_state_error: float | None
    peak: float
    peak_time: float
    final_value: float


def _crossing(t: np.ndarray, s: np.ndarray, level: float) -> float | None:
    idx = np.flatnonzero(s >= level)
    if idx.size == 0:
        return None
    k = int(idx[0])
    if k == 0:
        return float(t[0])
    s0, s1 = s[k - 1], s[k]
    return float(t[k - 1] + (level - s0) / (s1 - s0) * (t[k] - t[k - 1]))


def step_metrics(
    t: Any,
    y: Any,
    *,
    target: float | None = None,
    initial: float | None = None,
    final: float | None = None,
    settle: float = 0.02,
    rise: tuple[float, float] = (0.1, 0.9),
) -> StepMetrics:
    """Rise time, overshoot, settling time and steady-state error of a response.

    Args:
        t: Times ``(T,)``, increasing.
        y: Response ``(T,)``.
        target: The value ``y`` should reach (for the steady-state error); default ``final``.
        initial: Start value ``y_0``; default ``y[0]``.
        final: Final value ``y_f``; default ``y[-1]``.
        settle: Settling band, a fraction of ``|y_f − y_0|``.
        rise: Lower and upper rise-time fractions.

    Returns:
        A :class:`StepMetrics`.

    Raises:
        InvalidArgument: shapes differ, fewer than 2 samples, non-finite data,
            or ``y_f == y_0`` (no step to measure).
    """
    t = np.asarray(t, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if t.shape != y.shape or t.size < 2:
        raise InvalidArgument(
            f"step_metrics: expected t and y of the same shape (T,), T >= 2, found {t.shape} and {y.shape}"
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise InvalidArgument("step_metrics: t and y must be finite")
    y0 = float(y[0]) if initial is None else float(initial)
    yf = float(y[-1]) if final is None else float(final)
    span = yf - y0
    if span == 0.0 or not math.isfinite(span):
        raise InvalidArgument(f"step_metrics: the response has no step (initial {y0:g}, final {yf:g})")
    s = (y - y0) / span
    t_lo, t_hi = _crossing(t, s, rise[0]), _crossing(t, s, rise[1])
    rise_time = None if t_lo is None or t_hi is None else t_hi - t_lo
    k_peak = int(np.argmax(s))
    overshoot = 100.0 * max(0.0, float(s[k_peak]) - 1.0)
    outside = np.flatnonzero(np.abs(y - yf) > settle * abs(span))
    if outside.size == 0:
        settling = float(t[0])
    elif outside[-1] == t.size - 1:
        settling = None
    else:
        settling = float(t[outside[-1] + 1])
    return StepMetrics(
        rise_time,
        overshoot,
        settling,
        0.0 if target is None else float(target) - yf,
        float(y[k_peak]),
        float(t[k_peak]),
        yf,
    )


def closed_loop_response(A: Any, B: Any, K: Any, x_init: Any, steps: int) -> np.ndarray:
    """States of the linear closed loop ``δx_{k+1} = (A − B K) δx_k`` from ``δx_0 = x_init``.

    Args:
        A: ``(n, n)`` discrete.
        B: ``(n, m)``.
        K: ``(m, n)``.
        x_init: ``(n,)`` deviation from the operating point.
        steps: Number of steps ``T``.

    Returns:
        ``(T + 1, n)``.
    """
    A, B, K = (np.asarray(M, dtype=float) for M in (A, B, K))
    Acl = A - B @ K
    X = np.empty((steps + 1, A.shape[0]))
    X[0] = np.asarray(x_init, dtype=float)
    for k in range(steps):
        X[k + 1] = Acl @ X[k]
    return X
