"""Metrics of a closed-loop run: tracking error, settling, inputs, bound excess, response shape.

:data:`METRIC_REGISTRY` is the one list of the metrics a run reports (name,
unit, kind, description); every other list of metric names in the package
(the scenario layer's ``METRICS``, the sweep's table and wall-clock metrics,
the regression checker's) is derived from it here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.errors import NonFiniteError

if TYPE_CHECKING:
    from shinro_ctrl.engine.contacts import BalanceRecord

__all__ = [
    "BALANCE_METRICS",
    "FLAG_METRICS",
    "METRICS",
    "METRIC_KINDS",
    "METRIC_REGISTRY",
    "NEVER_METRICS",
    "NEWER_METRICS",
    "OUTPUT_FEEDBACK_METRICS",
    "PER_INPUT_METRICS",
    "RESPONSE_METRICS",
    "WALL_CLOCK_METRICS",
    "MetricInfo",
    "StreamingMetrics",
    "at_bounds",
    "balance_metrics",
    "bound_excess",
    "compute_metrics",
    "format_metric",
    "format_metrics",
    "is_newer_metric",
    "metric_unit",
    "plan_tracking_rms",
    "response_metrics",
    "saturation_metrics",
    "settling_time",
]

#: What a metric is: a value of the response, the time of an event in it (None: it never happened),
#: a clock reading (varies from run to run), a count, or a yes/no flag.
METRIC_KINDS = ("response", "timing", "wall-clock", "count", "flag")
#: Which runs report a metric.
REPORTED_BY = ("every run", "step response", "output feedback", "bounded input", "floating base")


@dataclass(frozen=True)
class MetricInfo:
    """One metric of a run.

    Attributes:
        name: Key in :attr:`SimResult.metrics <shinro_ctrl.sim.SimResult.metrics>`.
        unit: Unit as printed (``""``: the units of the tracked states or inputs, or none).
        kind: One of :data:`METRIC_KINDS`.
        description: One line.
        reported: One of :data:`REPORTED_BY` (``output feedback``: also ``NAME_<state>`` per state;
            ``bounded input``: only ``NAME_<input>``, for each input with a bound on that side).
    """

    name: str
    unit: str
    kind: str
    description: str
    reported: str = "every run"

    def __post_init__(self) -> None:
        if self.kind not in METRIC_KINDS or self.reported not in REPORTED_BY:
            raise ValueError(f"metric {self.name}: kind {self.kind!r} or reported {self.reported!r} is not known")


#: Name -> :class:`MetricInfo` of every metric a run reports, in the order they are printed.
METRIC_REGISTRY: dict[str, MetricInfo] = {
    m.name: m
    for m in (
        MetricInfo("rms_error", "", "response", "root mean square of the tracking-error norm over the run"),
        MetricInfo("max_error", "", "response", "largest tracking-error norm"),
        MetricInfo("final_error", "", "response", "tracking-error norm at the last sample"),
        MetricInfo("settling_time", "s", "timing", "time after which the error stays within settle_tol (None: never)"),
        MetricInfo("stable", "", "flag", "the run settled within the band and every state stayed finite"),
        MetricInfo("max_abs_input", "", "response", "largest |u| over every input and step (None: no step)"),
        MetricInfo("constraint_violations", "steps", "count", "steps at which a bound or plant limit is exceeded"),
        MetricInfo("max_violation", "", "response", "largest excess over a bound or plant limit"),
        MetricInfo("solve_time_median_s", "s", "wall-clock", "median controller call (None: no call)"),
        MetricInfo(
            "saturation_fraction",
            "",
            "response",
            "fraction of steps with an input at a bound: the controller's, the plant's range or a MuJoCo "
            "ctrlrange/forcerange clamp (None: no bounds)",
        ),
        MetricInfo("time_at_min", "s", "response", "time an input spent at its lower bound", "bounded input"),
        MetricInfo("time_at_max", "s", "response", "time an input spent at its upper bound", "bounded input"),
        MetricInfo("overshoot", "%", "response", "swing past the reference of the step response", "step response"),
        MetricInfo("rise_time", "s", "timing", "10-90 % rise time of the step response (None: never)", "step response"),
        MetricInfo(
            "estimation_rms", "", "response", "root mean square of the estimation error ‖x̂ − x‖", "output feedback"
        ),
        MetricInfo(
            "trunk_height_error",
            "m",
            "response",
            "largest |z − z_ref| of the trunk (the free joint's body) over the run; z_ref its height at t = 0",
            "floating base",
        ),
        MetricInfo(
            "trunk_orientation_error",
            "rad",
            "response",
            "largest angle of the rotation from the trunk's orientation at t = 0 to its orientation",
            "floating base",
        ),
        MetricInfo(
            "foot_slip",
            "m",
            "response",
            "largest horizontal travel of a robot geom's floor contact point during one unbroken contact (None: "
            "no contact)",
            "floating base",
        ),
        MetricInfo(
            "friction_cone_fraction",
            "",
            "response",
            "worst geom's fraction of its in-contact samples whose floor force had ‖f_t‖ ≤ μ f_n (None: no contact)",
            "floating base",
        ),
    )
}


def _names(kind: str | None = None, reported: str | None = None, *, flags: bool = True) -> tuple[str, ...]:
    return tuple(
        m.name
        for m in METRIC_REGISTRY.values()
        if (kind is None or m.kind == kind)
        and (reported is None or m.reported == reported)
        and (flags or m.kind != "flag")
    )


#: The metrics every run reports that take a tolerance (a ``[regression]`` key, a sweep column): all but the flags.
METRICS = _names(reported="every run", flags=False)
#: Measured with a clock: they vary from run to run (compared only with a tolerance, kept out of sweep tables).
WALL_CLOCK_METRICS = _names("wall-clock")
#: Times of events: None means the event never happened (printed ``never``).
NEVER_METRICS = _names("timing")
#: Yes/no metrics (compared exactly).
FLAG_METRICS = _names("flag")
#: The step-response metrics of :func:`response_metrics` (newer than some stored baselines).
RESPONSE_METRICS = _names(reported="step response")
#: Metrics only output-feedback runs report (``estimation_rms`` and ``estimation_rms_<state>``).
OUTPUT_FEEDBACK_METRICS = _names(reported="output feedback")
#: Per-input metrics (``time_at_min_<input>``, ``time_at_max_<input>``) of the inputs with a bound on that side.
PER_INPUT_METRICS = _names(reported="bounded input")
#: Balance metrics of a MuJoCo run of a floating-base model with a floor (:func:`balance_metrics`).
BALANCE_METRICS = _names(reported="floating base")
#: Metrics newer than some stored baselines: a baseline without them passes (``regress --update`` stores them).
NEWER_METRICS = (*RESPONSE_METRICS, *FLAG_METRICS, "saturation_fraction", *PER_INPUT_METRICS, *BALANCE_METRICS)


def is_newer_metric(name: str) -> bool:
    """True for a metric (or a per-input one, ``time_at_min_<input>``) that older baselines may lack."""
    return name in NEWER_METRICS or name.startswith(tuple(f"{m}_" for m in PER_INPUT_METRICS))


def metric_unit(name: str) -> str:
    """The unit of a metric (``estimation_rms_<state>`` as ``estimation_rms``, ``time_at_min_<input>`` as
    ``time_at_min``), ``""`` when unknown or none."""
    info = METRIC_REGISTRY.get(name)
    if info is None and name.startswith((*OUTPUT_FEEDBACK_METRICS, *PER_INPUT_METRICS)):
        info = METRIC_REGISTRY[next(m for m in (*OUTPUT_FEEDBACK_METRICS, *PER_INPUT_METRICS) if name.startswith(m))]
    return info.unit if info is not None and info.unit != "steps" else ""


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


#: An input within this relative distance of a bound (``tol · max(1, |bound|)``) is at it: an MPC's solution at an
#: active bound lies within its solver tolerance of it when it is not clipped exactly.
AT_BOUND_TOL = 1e-6


def at_bounds(
    u: np.ndarray, lo: np.ndarray | None, hi: np.ndarray | None, clamped: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Which inputs are at (or beyond) a bound: ``(at_lo (T, m), at_hi (T, m))`` booleans.

    ``u[k, i] <= lo[i] + tol`` or ``u[k, i] >= hi[i] − tol`` with ``tol = AT_BOUND_TOL · max(1, |bound|)``
    (a command beyond a bound is at it: the actuator delivers the bound); ``clamped (T, m)`` adds the
    clamps measured in MuJoCo (``-1`` lower, ``+1`` upper; see ``engine.ForceClamps``).
    """
    shape = u.shape
    out = []
    for bound, sign in ((lo, -1.0), (hi, 1.0)):
        at = np.zeros(shape, dtype=bool)
        if bound is not None:
            b = np.broadcast_to(np.asarray(bound, dtype=float), shape[1:])
            finite = np.isfinite(b)
            if finite.any():
                tol = AT_BOUND_TOL * np.maximum(1.0, np.abs(b[finite]))
                at[:, finite] = sign * (u[:, finite] - b[finite]) >= -tol
        if clamped is not None:
            at |= clamped == int(sign)
        out.append(at)
    return out[0], out[1]


def saturation_metrics(
    t: np.ndarray,
    u: np.ndarray,
    lo: np.ndarray | None,
    hi: np.ndarray | None,
    input_names: tuple[str, ...] | list[str],
    *,
    clamped: np.ndarray | None = None,
    clamp_inputs: tuple[int, ...] = (),
) -> dict[str, float | None]:
    """``saturation_fraction`` and the per-input ``time_at_min_<input>`` / ``time_at_max_<input>`` [s] of a run.

    ``saturation_fraction`` is the fraction of the ``T`` steps at which any input is at a bound
    (:func:`at_bounds`; None when no input has a bound and none can be clamped). Input ``k`` is held for
    ``t[k+1] − t[k]``, so ``time_at_min_<input>`` sums those steps' durations. Per-input times are reported
    for the inputs with a finite bound on that side, and for the inputs in ``clamp_inputs`` (driving an
    actuator with a ``forcerange``) on both sides.

    Args:
        t: Sample times ``(T + 1,)`` [s].
        u: Inputs ``(T, m)`` (the controller's commands).
        lo, hi: Bounds ``(m,)`` (±inf or None: none).
        input_names: The ``m`` input names.
        clamped: Flags ``(T, m)`` of the clamps measured in MuJoCo (-1, 0, +1), or None.
        clamp_inputs: The inputs ``clamped`` can flag.
    """
    m = u.shape[1]
    bounded = [np.zeros(m, dtype=bool), np.zeros(m, dtype=bool)]
    for side, bound in enumerate((lo, hi)):
        if bound is not None:
            bounded[side] |= np.isfinite(np.broadcast_to(np.asarray(bound, dtype=float), (m,)))
        bounded[side][list(clamp_inputs)] = True
    if not (bounded[0].any() or bounded[1].any()):
        return {"saturation_fraction": None}
    at_lo, at_hi = at_bounds(u, lo, hi, clamped)
    steps = u.shape[0]
    out: dict[str, float | None] = {
        "saturation_fraction": float(np.count_nonzero((at_lo | at_hi).any(axis=1))) / steps if steps else None
    }
    held = np.diff(t)[:steps]
    for side, (name, at) in enumerate((("time_at_min", at_lo), ("time_at_max", at_hi))):
        for i in np.flatnonzero(bounded[side]).tolist():
            out[f"{name}_{input_names[i]}"] = float(held[at[:, i]].sum())
    return out


def settling_time(t: np.ndarray, last_outside: int | np.ndarray) -> np.ndarray:
    """Settling time from the index of the last sample outside the tolerance band.

    The run has settled at ``t[k + 1]`` when sample ``k`` is the last whose
    tracking error exceeds the tolerance: ``0`` when no sample does (``k = -1``),
    NaN (undefined: it never settled) when the final sample does.

    Args:
        t: Sample times ``(T + 1,)`` [s].
        last_outside: ``k`` (a scalar, or ``(N,)`` for N instances).

    Returns:
        The settling time(s) [s], shaped like ``last_outside`` (NaN where undefined;
        :func:`compute_metrics` reports it as None).
    """
    last = np.asarray(last_outside)
    steps = t.shape[0] - 1
    settled = np.where(last < 0, 0.0, t[np.minimum(last + 1, steps)])
    return np.where(last == steps, math.nan, settled)


def _defined(v: float) -> float | None:
    """``v``, or None when it is undefined (NaN or infinite: an event that never happened)."""
    return float(v) if math.isfinite(v) else None


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
    saturation: dict[str, float | None] | None = None,
) -> dict[str, float | int | bool | None]:
    """Metrics of a closed-loop run (an undefined one is None, never NaN or inf).

    The tracking error is ``e_k = ‖x_k[tracked] − r_k[tracked]‖₂``.

    Returns:
        ``rms_error`` (``sqrt(mean e_k²)``), ``max_error``, ``final_error``,
        ``settling_time`` (first time after which ``e`` stays within
        ``settle_tol``; None if it never does), ``stable`` (True when the run
        settled within the band, i.e. the final error is within
        ``settle_tol``, and every state stayed finite: False flags a run that
        diverged, fell or never settled), ``max_abs_input`` (None
        without a step),
        ``constraint_violations`` (steps at which an input or state bound, or
        a plant limit, is exceeded by more than 1e-9 relative),
        ``max_violation`` (the largest such excess),
        ``solve_time_median_s`` (median controller call; None without one),
        ``saturation_fraction`` and the per-input times at a bound (``saturation`` as
        :func:`saturation_metrics` gives them; None: from ``u_min`` / ``u_max`` alone), and for a step or
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
    settling = _defined(float(settling_time(t, outside[-1] if outside.size else -1)))

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
        "stable": bool(settling is not None and np.all(np.isfinite(x))),
        "max_abs_input": float(np.abs(u).max()) if u.size else None,
        "constraint_violations": int(np.count_nonzero(viol > 0)),
        "max_violation": float(viol.max()),
        "solve_time_median_s": float(np.median(solve_times)) if solve_times is not None and solve_times.size else None,
        **(saturation if saturation is not None else _bound_saturation(t, u, u_min, u_max)),
        **response_metrics(t, x[:, tracked], ref[:, tracked], settle_tol),
    }


def _bound_saturation(
    t: np.ndarray, u: np.ndarray, lo: np.ndarray | None, hi: np.ndarray | None
) -> dict[str, float | None]:
    """``saturation_fraction`` of :func:`saturation_metrics` for bounds alone (no names: no per-input times)."""
    return {
        "saturation_fraction": saturation_metrics(t, u, lo, hi, [f"u{i}" for i in range(u.shape[1])])[
            "saturation_fraction"
        ]
    }


def response_metrics(
    t: np.ndarray, x: np.ndarray, ref: np.ndarray, settle_tol: float = 0.01
) -> dict[str, float | None]:
    """``overshoot`` [%] and ``rise_time`` [s] of a step or initial-condition response (else ``{}``).

    Meaningful when the reference ``ref (T+1, k)`` is constant (the run recovers
    from its initial deviation) or changes once (a step; measured from the
    step). The response is that of the tracked state with the largest
    deviation from the new reference at the start, and it must exceed
    ``settle_tol``; see :func:`shinro_ctrl.analysis.step_metrics` (overshoot
    past the reference, 10–90 % rise time, None if 10 % or 90 % is never reached).
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


def format_metric(name: str, value: float | int | bool | None) -> str:
    """One metric value as text: None as ``never`` (an event metric) or ``n/a``, a flag as yes/no."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "never" if name in NEVER_METRICS else "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    return f"{value:.6g}"


def format_metrics(metrics: dict[str, float | int | bool | None]) -> str:
    """A two-column table of metrics."""
    rows = []
    for k, v in metrics.items():
        unit = metric_unit(k) if v is not None else ""
        rows.append(f"  {k:22s} {format_metric(k, v):>14s} {unit}".rstrip())
    return "\n".join(rows)


class StreamingMetrics:
    """The metrics of :func:`compute_metrics` for ``N`` instances, accumulated while stepping (O(N) memory).

    Used by the vectorized batch rollout (:mod:`shinro_ctrl.sweep.batch`). Same
    definitions: ``e_k = ‖x_k[tracked] − r[tracked]‖₂``; rms over the ``T + 1``
    samples; :func:`settling_time` after the last sample outside
    ``settle_tol``; a violation counted at index ``k`` from input ``k`` and
    state ``k``; ``saturation_fraction`` from the input bounds ``u_min`` / ``u_max`` (NaN without any).
    """

    def __init__(
        self,
        N: int,
        tracked: list[int],
        r: np.ndarray,
        settle_tol: float,
        u_min: np.ndarray | None = None,
        u_max: np.ndarray | None = None,
    ):
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
        bounded = any(b is not None and np.isfinite(np.asarray(b, dtype=float)).any() for b in (u_min, u_max))
        self.u_bounds = (u_min, u_max) if bounded else None
        self.sat_count = np.zeros(N, dtype=int)
        self.steps = 0

    def track(self, X: np.ndarray, k: int) -> None:
        """The tracking error of sample ``k``."""
        e = self.e = np.linalg.norm(X[:, self.tr] - self.r_tr, axis=1)
        np.add(self.e2_sum, e * e, out=self.e2_sum)
        np.maximum(self.e_max, e, out=self.e_max)
        self.last_out[e > self.settle_tol] = k

    def inputs(self, U: np.ndarray, viol: np.ndarray) -> None:
        """The inputs of one step and the violation at its index."""
        np.maximum(self.u_abs_max, np.abs(U).max(axis=1), out=self.u_abs_max)
        self.steps += 1
        if self.u_bounds is not None:
            at_lo, at_hi = at_bounds(U, *self.u_bounds)
            self.sat_count += (at_lo | at_hi).any(axis=1)
        self.violation(viol)

    def violation(self, viol: np.ndarray) -> None:
        self.viol_count += viol > 0
        np.maximum(self.viol_max, viol, out=self.viol_max)

    def finish(self, t: np.ndarray, call_times: np.ndarray, alive: np.ndarray) -> dict[str, np.ndarray]:
        """Metric name -> ``(N,)`` (NaN for diverged instances; ``stable`` as 0/1)."""
        steps = t.shape[0] - 1
        N = alive.shape[0]
        metrics = {
            "rms_error": np.sqrt(self.e2_sum / (steps + 1)),
            "max_error": self.e_max,
            "final_error": self.e,
            "settling_time": settling_time(t, self.last_out),
            "stable": ((self.last_out < steps) & alive).astype(float),
            "max_abs_input": self.u_abs_max,
            "constraint_violations": self.viol_count.astype(float),
            "max_violation": self.viol_max,
            "solve_time_median_s": np.full(N, float(np.median(call_times)) / max(N, 1)),
            "saturation_fraction": (
                self.sat_count / max(self.steps, 1) if self.u_bounds is not None else np.full(N, math.nan)
            ),
        }
        for k, v in metrics.items():
            if k != "stable":
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


def _quat_angle(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(T,)`` angle [rad] of the rotation from ``q_ref (4,)`` to each ``q (T, 4)``: ``2 acos |⟨q_ref, q⟩|``."""
    q_ref = q_ref / np.linalg.norm(q_ref)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    return 2.0 * np.arccos(np.clip(np.abs(qn @ q_ref), 0.0, 1.0))


def balance_metrics(record: BalanceRecord | None) -> dict[str, float | None]:
    r"""The balance metrics of a run of a floating-base robot on a floor (every value None without a record).

    From the samples of :class:`~shinro_ctrl.engine.contacts.BalanceRecord` (one before the first step, one
    after each step):

    * ``trunk_height_error`` [m]: :math:`\max_k |z_k - z_0|`, the trunk's height against its height at t = 0.
    * ``trunk_orientation_error`` [rad]: :math:`\max_k 2\arccos|\langle q_0, q_k\rangle|`, the angle of the
      rotation taking the initial trunk orientation to the current one (unit quaternions; sign-free).
    * ``foot_slip`` [m]: for each robot geom touching the floor, its contact point (the mean when it has
      several contacts in one sample) is followed through each unbroken run of samples in contact; the slip
      of that run is the largest horizontal distance :math:`\|p_{xy,k} - p_{xy,start}\|` from where the run
      began. The metric is the largest over runs and geoms.
    * ``friction_cone_fraction``: per geom, the fraction of its in-contact samples in which every contact
      force had :math:`\|f_t\| \le \mu f_n` (1e-6 relative slack); the metric is the smallest over geoms
      (1.0: every contact force stayed inside its cone the whole time).

    ``foot_slip`` and ``friction_cone_fraction`` are None when nothing touched the floor.

    Args:
        record: The run's samples, or None (not a floating-base run with a floor).

    Returns:
        ``{name: value}`` for the names in :data:`BALANCE_METRICS`.
    """
    out: dict[str, float | None] = dict.fromkeys(BALANCE_METRICS)
    if record is None or record.trunk_pos.shape[0] == 0:
        return out
    z = record.trunk_pos[:, 2]
    out["trunk_height_error"] = float(np.max(np.abs(z - z[0])))
    out["trunk_orientation_error"] = float(np.max(_quat_angle(record.trunk_quat[0], record.trunk_quat)))
    if record.contact_step.shape[0] == 0:
        return out
    slip, fractions = 0.0, []
    steps, geoms = record.contact_step, record.contact_geom
    f_n, f_t = record.contact_force[:, 0], record.contact_force[:, 1]
    inside = f_t <= record.contact_friction * f_n * (1 + 1e-6) + 1e-9
    for g in dict.fromkeys(geoms.tolist()):
        mine = geoms == g
        ks = np.unique(steps[mine])
        pos = np.array([record.contact_pos[mine & (steps == k), :2].mean(axis=0) for k in ks])
        ok = np.array([bool(np.all(inside[mine & (steps == k)])) for k in ks])
        fractions.append(float(np.mean(ok)))
        start = 0
        for i in range(1, len(ks) + 1):
            if i == len(ks) or ks[i] != ks[i - 1] + 1:  # the run [start, i) ends
                run = pos[start:i]
                slip = max(slip, float(np.max(np.linalg.norm(run - run[0], axis=1))))
                start = i
    out["foot_slip"] = slip
    out["friction_cone_fraction"] = min(fractions)
    return out
