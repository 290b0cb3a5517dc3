"""The plot of a closed-loop run: states, inputs and disturbances against time (one loop, or two overlaid)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.plots._figure import _fmt_metric, _new_figure, _write_png
from shinro_ctrl.plots.units import _label, _units, signal_groups

__all__ = ["PLANAR_KINDS", "plot_run", "run_figure"]

PLANAR_KINDS = ("circle", "square", "waypoints")
_RUN_STYLES = ({"ls": "-", "lw": 1.4}, {"ls": (0, (4, 2)), "lw": 1.3})  # the first loop solid, the second dashed


def run_figure(
    result: Any,
    *,
    compare: Any = None,
    state_units: Sequence[str] | None = None,
    input_units: Sequence[str] | None = None,
) -> Path:
    """Plot a closed-loop run to a PNG: states, inputs and disturbances against time.

    Each panel's y label carries its unit; the reference is dashed, bounds are
    dotted red, the settling band ``r ± settle_tol`` on every tracked state is
    shaded (with the settling time marked), the legend sits outside the data
    to the right. Planar tasks (circle, square, waypoint references) get an
    x–y panel. More than :data:`~shinro_ctrl.plots.MAX_ROWS` signals are grouped by unit.

    Args:
        result: A :class:`~shinro_ctrl.sim.SimResult`.
        compare: A second result of the same scenario (the other loop) drawn
            over the first, with the metric differences in the title.
        state_units, input_units: Units overriding the ones read from the names.

    Returns:
        The :class:`matplotlib.figure.Figure` (Agg canvas); :func:`plot_run` writes it.
    """
    runs = [result] if compare is None else [result, compare]
    dist = result.disturbance if getattr(result, "disturbance", None) is not None else None
    dist_labels = list(getattr(result, "disturbance_labels", []) or []) if dist is not None else []
    panels = signal_groups(
        result.state_names,
        result.input_names,
        state_units=state_units,
        input_units=input_units,
        extra_rows=1 if dist_labels else 0,
    )
    rows = len(panels) + (1 if dist_labels else 0)
    planar = _planar_axes(result)
    width = 12.5 if planar else 8.5
    fig = _new_figure(width, 1.55 * rows + 1.2)
    gs = fig.add_gridspec(
        rows, 2 if planar else 1, width_ratios=(1.9, 1.0) if planar else None, hspace=0.12, wspace=0.4
    )
    axes = [fig.add_subplot(gs[0, 0])]
    axes += [fig.add_subplot(gs[r, 0], sharex=axes[0]) for r in range(1, rows)]
    for row, (title, _unit, members) in enumerate(panels):
        _draw_panel(axes[row], title, members, result, runs)
    if dist_labels:
        ax = axes[-1]
        for j, lab in enumerate(dist_labels):
            ax.step(result.t[:-1], dist[:, j], where="post", color=f"C{(5 + j) % 10}", lw=1.2, label=lab)
        ax.set_ylabel("disturbance", fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    axes[-1].set_xlabel("time [s]")
    if planar:
        _draw_planar(fig.add_subplot(gs[:, 1]), planar, result, runs, state_units)
    _figure_legend(fig, axes, panels, result, planar)
    fig.suptitle(_title(result, compare), x=0.01, ha="left", fontsize=10)
    fig.subplots_adjust(left=0.1, right=0.97, top=1 - 0.75 / (1.55 * rows + 1.2), bottom=0.6 / (1.55 * rows + 1.2))
    return fig


def plot_run(
    result: Any,
    path: str | Path,
    *,
    compare: Any = None,
    state_units: Sequence[str] | None = None,
    input_units: Sequence[str] | None = None,
) -> Path:
    """Write :func:`run_figure` to the PNG ``path`` (atomically) and return ``path``."""
    return _write_png(run_figure(result, compare=compare, state_units=state_units, input_units=input_units), path)


def _draw_panel(ax: Any, title: str, members: list[tuple[str, int]], result: Any, runs: list[Any]) -> None:
    """One panel: its signals in every run, references, settling bands, bounds, the settling time and its label."""
    tol, settling = _settle_info(result)
    tracked = {result.state_names.index(s) for s in result.tracked if s in result.state_names}
    grouped = len(members) > 1
    signal_handles = []
    for c, (kind, i) in enumerate(members):
        signal_handles += _draw_signal(ax, kind, i, c, grouped, result, runs)
        if kind == "x":
            color = f"C{c % 10}" if grouped else "0.25"
            ax.plot(result.t, _reference(result, i), color=color, lw=0.9, ls="--", alpha=0.8, label="reference")
            if i in tracked and np.isfinite(tol):
                ax.fill_between(
                    result.t,
                    result.ref[:, i] - tol,
                    result.ref[:, i] + tol,
                    color="C1",
                    alpha=0.18,
                    lw=0,
                    label=f"settling band ±{tol:g}",
                )
            bounds = (result.x_min, result.x_max)
        else:
            bounds = (result.u_min, result.u_max)
        for b in bounds:
            if b is not None and np.isfinite(b[i]):
                ax.axhline(b[i], color="C3", lw=0.9, ls=":", label="bound")
    if any(kind == "x" and i in tracked for kind, i in members) and np.isfinite(settling) and settling > 0:
        ax.axvline(settling, color="C1", lw=0.9, ls="-.", label=f"settled at {settling:.3g} s")
    ax.set_ylabel(title, fontsize=9)
    ax.grid(alpha=0.3)
    _data_limits(ax, result, members)
    if grouped:  # the signals of a shared panel are named beside it, outside the data
        ax.legend(handles=signal_handles, loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7, frameon=False)


def _draw_signal(ax: Any, kind: str, i: int, c: int, grouped: bool, result: Any, runs: list[Any]) -> list[Any]:
    """State ``i`` (``kind`` ``"x"``, with its measurement and estimate) or input ``i`` of every run; the lines."""
    name = (result.state_names if kind == "x" else result.input_names)[i]
    handles = []
    for k, run in enumerate(runs):
        if grouped:
            color = f"C{c % 10}"
        else:  # the second loop in its own colour as well as dashed: close curves stay distinguishable
            color = ("C0", "C4")[k] if kind == "x" else ("C2", "C8")[k]
        label = name if grouped else ("state" if kind == "x" else "input")
        if len(runs) > 1:
            label = f"{label} ({run.loop})"
        if kind == "x":
            if k == 0:
                _estimate_lines(ax, run, i, grouped)  # measurement and estimate under the true state
            (h,) = ax.plot(run.t, run.x[:, i], color=color, label=label, **_RUN_STYLES[k])
        else:
            (h,) = ax.step(run.t[:-1], run.u[:, i], where="post", color=color, label=label, **_RUN_STYLES[k])
        handles.append(h)
    return handles


def _draw_planar(ax: Any, planar: tuple[int, int], result: Any, runs: list[Any], state_units: Any) -> None:
    """The x–y path of a planar task against its reference, with start and end marked."""
    i, j = planar
    for k, run in enumerate(runs):
        label = f"path ({run.loop})" if len(runs) > 1 else "path"
        ax.plot(run.x[:, i], run.x[:, j], color="C0" if k == 0 else "C4", label=label, **_RUN_STYLES[k])
    ax.plot(result.ref[:, i], result.ref[:, j], color="0.25", ls="--", lw=0.9, label="reference")
    ax.plot(result.x[0, i], result.x[0, j], "o", color="C2", ms=5, label="start")
    ax.plot(result.x[-1, i], result.x[-1, j], "s", color="C3", ms=5, label="end")
    su = _units(result.state_names, state_units, is_input=False)
    ax.set_xlabel(_label(result.state_names[i], su[i]))
    ax.set_ylabel(_label(result.state_names[j], su[j]))
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.set_title(f"{result.state_names[i]}–{result.state_names[j]} path", fontsize=9)


def _figure_legend(fig: Any, axes: list[Any], panels: list[Any], result: Any, planar: Any) -> None:
    """One legend for the single-signal panels, outside the data (right of the figure, or below it when the
    right margin holds the signal names of shared panels)."""
    handles: dict[str, Any] = {}
    for ax, (_, _, members) in zip(axes, panels, strict=False):
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if len(members) == 1 or not any(lab.startswith(n) for n in (*result.state_names, *result.input_names)):
                handles.setdefault(lab, h)
    if planar:
        for h, lab in zip(*fig.axes[-1].get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    if handles and any(len(members) > 1 for _, _, members in panels):  # the right margin holds signal names
        fig.legend(
            handles.values(),
            handles.keys(),
            loc="upper center",
            bbox_to_anchor=(0.5, 0.0),
            ncol=min(len(handles), 6),
            fontsize=8,
            frameon=False,
        )
    elif handles:
        fig.legend(
            handles.values(), handles.keys(), loc="upper left", bbox_to_anchor=(1.0, 0.93), fontsize=8, frameon=False
        )


def _settle_info(result: Any) -> tuple[float, float]:
    sim = (result.config or {}).get("sim", {}) if isinstance(result.config, dict) else {}
    tol = float(sim.get("settle_tol", 0.01)) if isinstance(sim, dict) else 0.01
    settling = result.metrics.get("settling_time")
    return tol, math.inf if settling is None else float(settling)


def _planar_axes(result: Any) -> tuple[int, int] | None:
    """The state pair of a planar task (a circle, square or waypoint reference in the plane of ``axes``)."""
    sim = (result.config or {}).get("sim", {}) if isinstance(result.config, dict) else {}
    ref = sim.get("reference", {}) if isinstance(sim, dict) else {}
    if not isinstance(ref, dict) or ref.get("kind") not in PLANAR_KINDS:
        return None
    axes = ref.get("axes", [0, 1])
    n = result.x.shape[1]
    if len(axes) != 2 or not all(isinstance(a, int) and 0 <= a < n for a in axes):
        return None
    return int(axes[0]), int(axes[1])


def _reference(result: Any, i: int) -> np.ndarray:
    """State ``i``'s reference line: a tracked plan where it has one (TVLQR), else the run's reference."""
    plan = getattr(result, "plan", None)
    if plan is None:
        return result.ref[:, i]
    return np.where(np.isfinite(plan[:, i]), plan[:, i], result.ref[:, i])


def _data_limits(ax: Any, result: Any, members: list[tuple[str, int]]) -> None:
    """Y limits from the signals (not from a bound far away); bounds within reach stay visible."""
    values = []
    for kind, i in members:
        if kind == "x":
            values += [result.x[:, i], _reference(result, i)]
        else:
            values.append(result.u[:, i])
    data = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.zeros(1)
    if data.size == 0:
        return
    lo, hi = float(data.min()), float(data.max())
    if hi - lo < 2e-3:  # rounding-level wiggles are not drawn as motion: at least ±1e-3 around the data
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 1e-3, mid + 1e-3
    span = hi - lo
    pad = 0.08 * span
    lo, hi = lo - pad, hi + pad
    for kind, i in members:
        bounds = (result.x_min, result.x_max) if kind == "x" else (result.u_min, result.u_max)
        for b in bounds:
            if b is not None and np.isfinite(b[i]) and lo - span <= b[i] <= hi + span:
                lo, hi = min(lo, b[i] - pad), max(hi, b[i] + pad)
    ax.set_ylim(lo, hi)


def scenario_label(result: Any) -> str:
    """The scenario's name, or for a scenario given as a dict (``"<dict>"``) its plant and controller."""
    name = str(result.scenario)
    config = getattr(result, "config", None) or {}
    if name.startswith("<") and isinstance(config, dict):
        plant = (config.get("plant") or {}).get("type")
        controller = (config.get("controller") or {}).get("type")
        if plant:
            return f"{plant} + {controller}" if controller else str(plant)
    return name


def _title(result: Any, compare: Any) -> str:
    m = result.metrics
    head = scenario_label(result)
    if compare is None:
        return (
            f"{head} ({result.loop})   rms error {_fmt_metric(m['rms_error'])}   "
            f"settling {_fmt_metric(m['settling_time'])} s   max |u| {_fmt_metric(m['max_abs_input'])}"
        )
    c = compare.metrics
    parts = []
    for key, label in (("rms_error", "rms error"), ("settling_time", "settling [s]"), ("max_abs_input", "max |u|")):
        a, b = m.get(key), c.get(key)
        diff = "—" if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)) else f"{b - a:+.3g}"
        parts.append(f"{label}: {_fmt_metric(a)} vs {_fmt_metric(b)} (Δ {diff})")
    return f"{head}: {result.loop} (solid) vs {compare.loop} (dashed)\n" + "   ".join(parts)


def _estimate_lines(ax: Any, run: Any, i: int, grouped: bool) -> None:
    """Draw the measurement of state ``i`` (if measured) and its estimate, when the loop used output feedback."""
    x_hat, y = getattr(run, "x_hat", None), getattr(run, "y", None)
    if x_hat is None or np.array_equal(x_hat, run.x):
        return  # full-state feedback without noise: the estimate is the state
    name = run.state_names[i]
    measured = tuple(getattr(run, "measured", ()) or ())
    if y is not None and name in measured:
        col = y[:, measured.index(name)]
        ax.plot(run.t, col, color="0.65", lw=0.6, alpha=0.8, label="measurement" if not grouped else None)
    ax.plot(run.t, x_hat[:, i], color="C6", lw=1.0, ls="-.", label="estimate" if not grouped else None)
