"""Plots a control engineer reads: closed-loop runs (one loop, or standalone and MuJoCo overlaid).

Every function draws on a fresh :class:`matplotlib.figure.Figure` with the Agg
canvas and writes a PNG atomically; none touches pyplot's global state or
calls ``matplotlib.use`` (the backend is the caller's choice).

Units come from the plant's state and input names (:func:`unit_of`: a plant
may also declare ``state_units`` / ``input_units``); figures keep at most
:data:`MAX_ROWS` rows by grouping signals of one kind (position, attitude,
velocity, rate, inputs by unit) on shared axes.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.files import atomic_write

__all__ = ["MAX_ROWS", "param_unit", "plot_run", "plot_sweep", "run_figure", "signal_groups", "sweep_figure", "unit_of"]

MAX_ROWS = 6
PLANAR_KINDS = ("circle", "square", "waypoints")

_ANGLE = re.compile(r"^(theta|phi|psi|alpha|beta|q|roll|pitch|yaw|angle|arm|pendulum|hinge|joint)(_?\d+)?$")
_RATE = re.compile(
    r"^((theta|phi|psi|alpha|beta|q|angle|arm|pendulum|hinge|joint)(_?\d+)?_dot|omega(_?\d+)?|[pqr]|\w+_rate)$"
)
_POSITION = re.compile(r"^(x|y|z|pos_?\w*|position\w*)(_?\d+)?$")
_VELOCITY = re.compile(r"^(x_dot|y_dot|z_dot|v[xyz]?|vel\w*|velocity\w*|\w+_velocity)(_?\d+)?$")
_FORCE = re.compile(r"^(f|force|thrust|f_?\w+)(_?\d+)?$", re.IGNORECASE)
_TORQUE = re.compile(r"^(tau|torque|moment|motor|m)(_?\w+)?$", re.IGNORECASE)
_KIND_TITLES = {"m": "position", "rad": "angle", "m/s": "velocity", "rad/s": "angular rate"}


def unit_of(name: str, *, is_input: bool = False) -> str:
    """The SI unit of a state or input from its name (``''`` when the name does not say).

    ``x, y, z`` → m; ``x_dot, vx`` → m/s; ``theta, roll, q1`` → rad;
    ``theta_dot, omega, p, q, r, *_rate`` → rad/s; inputs ``force, thrust`` → N,
    ``tau*, torque, motor`` → N m.
    """
    n = name.strip().lower()
    if is_input:
        if _FORCE.match(n):
            return "N"
        if _TORQUE.match(n):
            return "N m"
    if _VELOCITY.match(n):
        return "m/s"
    if _RATE.match(n):
        return "rad/s"
    if _ANGLE.match(n):
        return "rad"
    if _POSITION.match(n):
        return "m"
    return ""


def _units(names: Sequence[str], declared: Sequence[str] | None, *, is_input: bool) -> list[str]:
    if declared is not None and len(declared) == len(names):
        return [str(u) for u in declared]
    return [unit_of(s, is_input=is_input) for s in names]


def _label(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit else name


def signal_groups(
    state_names: Sequence[str],
    input_names: Sequence[str],
    *,
    state_units: Sequence[str] | None = None,
    input_units: Sequence[str] | None = None,
    extra_rows: int = 0,
    max_rows: int = MAX_ROWS,
) -> list[tuple[str, str, list[tuple[str, int]]]]:
    """The panels of a run plot: ``[(title, unit, [("x" | "u", index), ...]), ...]``.

    One panel per signal when they fit in ``max_rows``; otherwise states of one
    unit share a panel (the quadrotor: position, attitude, velocity, angular
    rate), and inputs of one unit share one (thrust [N], torques [N m]).
    """
    su = _units(state_names, state_units, is_input=False)
    iu = _units(input_names, input_units, is_input=True)
    if len(state_names) + len(input_names) + extra_rows <= max_rows:
        panels = [(_label(s, su[i]), su[i], [("x", i)]) for i, s in enumerate(state_names)]
        panels += [(_label(s, iu[j]), iu[j], [("u", j)]) for j, s in enumerate(input_names)]
        return panels
    panels: list[tuple[str, str, list[tuple[str, int]]]] = []
    for kind, names, units in (("x", state_names, su), ("u", input_names, iu)):
        order: dict[str, list[tuple[str, int]]] = {}
        for i, _ in enumerate(names):
            order.setdefault(units[i], []).append((kind, i))
        for unit, members in order.items():
            if len(members) == 1:
                title = names[members[0][1]]
            elif kind == "x":
                title = _KIND_TITLES.get(unit, "states")
                if unit == "rad" and any(names[i] in ("roll", "pitch", "yaw") for _, i in members):
                    title = "attitude"
            else:
                title = "inputs"
            panels.append((f"{title} [{unit}]" if unit else title, unit, members))
    return panels


def _new_figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _write_png(fig: Any, path: str | Path) -> Path:
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110, bbox_inches="tight"), binary=True)
    return path


def _fmt_metric(v: float) -> str:
    if isinstance(v, float) and math.isinf(v):
        return "never"
    return f"{v:.3g}"


def _settle_info(result: Any) -> tuple[float, float]:
    sim = (result.config or {}).get("sim", {}) if isinstance(result.config, dict) else {}
    tol = float(sim.get("settle_tol", 0.01)) if isinstance(sim, dict) else 0.01
    return tol, float(result.metrics.get("settling_time", math.inf))


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
    x–y panel. More than :data:`MAX_ROWS` signals are grouped by unit.

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
    tol, settling = _settle_info(result)
    tracked = {result.state_names.index(s) for s in result.tracked if s in result.state_names}
    run_styles = [{"ls": "-", "lw": 1.4}, {"ls": (0, (4, 2)), "lw": 1.3}]
    multi = len(runs) > 1

    for row, (title, _unit, members) in enumerate(panels):
        ax = axes[row]
        grouped = len(members) > 1
        signal_handles = []
        for c, (kind, i) in enumerate(members):
            name = (result.state_names if kind == "x" else result.input_names)[i]
            for k, run in enumerate(runs):
                if grouped:
                    color = f"C{c % 10}"
                else:  # the second loop in its own colour as well as dashed: close curves stay distinguishable
                    color = ("C0", "C4")[k] if kind == "x" else ("C2", "C8")[k]
                label = name if grouped else ("state" if kind == "x" else "input")
                if multi:
                    label = f"{label} ({run.loop})"
                if kind == "x":
                    if k == 0:
                        _estimate_lines(ax, run, i, grouped)  # measurement and estimate under the true state
                    (h,) = ax.plot(run.t, run.x[:, i], color=color, label=label, **run_styles[k])
                else:
                    (h,) = ax.step(run.t[:-1], run.u[:, i], where="post", color=color, label=label, **run_styles[k])
                signal_handles.append(h)
            if kind == "x":
                ax.plot(
                    result.t,
                    result.ref[:, i],
                    color=color if grouped else "0.25",
                    lw=0.9,
                    ls="--",
                    alpha=0.8,
                    label="reference",
                )
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
        i, j = planar
        ax = fig.add_subplot(gs[:, 1])
        for k, run in enumerate(runs):
            label = f"path ({run.loop})" if multi else "path"
            ax.plot(run.x[:, i], run.x[:, j], color="C0" if k == 0 else "C4", label=label, **run_styles[k])
        ax.plot(result.ref[:, i], result.ref[:, j], color="0.25", ls="--", lw=0.9, label="reference")
        ax.plot(result.x[0, i], result.x[0, j], "o", color="C2", ms=5, label="start")
        ax.plot(result.x[-1, i], result.x[-1, j], "s", color="C3", ms=5, label="end")
        su = _units(result.state_names, state_units, is_input=False)
        ax.set_xlabel(_label(result.state_names[i], su[i]))
        ax.set_ylabel(_label(result.state_names[j], su[j]))
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.set_title(f"{result.state_names[i]}–{result.state_names[j]} path", fontsize=9)

    # one legend for the single-signal panels, outside the data (right of the figure)
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


def _data_limits(ax: Any, result: Any, members: list[tuple[str, int]]) -> None:
    """Y limits from the signals (not from a bound far away); bounds within reach stay visible."""
    values = []
    for kind, i in members:
        if kind == "x":
            values += [result.x[:, i], result.ref[:, i]]
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


def _title(result: Any, compare: Any) -> str:
    m = result.metrics
    head = f"{result.scenario}"
    if compare is None:
        return (
            f"{head} ({result.loop})   rms error {_fmt_metric(m['rms_error'])}   "
            f"settling {_fmt_metric(m['settling_time'])} s   max |u| {_fmt_metric(m['max_abs_input'])}"
        )
    c = compare.metrics
    parts = []
    for key, label in (("rms_error", "rms error"), ("settling_time", "settling [s]"), ("max_abs_input", "max |u|")):
        a, b = m.get(key, math.nan), c.get(key, math.nan)
        diff = "—" if not (math.isfinite(a) and math.isfinite(b)) else f"{b - a:+.3g}"
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


# ------------------------------------------------------------------- sweeps
_PARAM_UNITS = (
    (re.compile(r"(^|_)(mass|m[0-9]?)(_|$)"), "kg"),
    (re.compile(r"(length|radius|arm_length|offset|l[0-9]?$)"), "m"),
    (re.compile(r"(^|_)(gravity|g)$"), "m/s²"),
    (re.compile(r"(^|_)dt$"), "s"),
    (re.compile(r"(inertia|^i[xyz]{2}$)"), "kg m²"),
    (re.compile(r"yaw_moment_coefficient"), "m"),
)


def param_unit(key: str) -> str:
    """The unit of a swept key such as ``plant.pole_mass`` (``''`` when its name does not say)."""
    name = key.rsplit(".", 1)[-1].lower()
    for pattern, unit in _PARAM_UNITS:
        if pattern.search(name):
            return unit
    return ""


def _param_label(key: str) -> str:
    unit = param_unit(key)
    return f"{key} [{unit}]" if unit else key


def _metric_axis(ax: Any, y: np.ndarray) -> None:
    """Log scale when the finite positive values span more than two decades, else linear; limits from the data."""
    finite = y[np.isfinite(y)]
    if finite.size == 0:
        ax.set_ylim(0, 1)
        return
    lo, hi = float(finite.min()), float(finite.max())
    if lo > 0 and hi / lo > 100:
        ax.set_yscale("log")
        ax.set_ylim(lo / 1.6, hi * 1.6)
    else:
        pad = 0.08 * (hi - lo) if hi > lo else max(0.05 * abs(hi), 1e-9)
        ax.set_ylim(lo - pad, hi + pad)


def sweep_figure(result: Any, metric: str | None = None) -> Any:
    """Plot a robustness sweep to a PNG.

    One parameter: the metric against the parameter (stable green dots,
    unstable red crosses, contiguous stable intervals shaded), with the samples
    whose run raised marked on a separate strip below (they have no metric).
    Two parameters: a 2-D stability map (the grid as cells, or random samples
    as points) beside the metric as colour; more parameters: one marginal
    panel each. The metric axis is set by the finite data (log when it spans
    more than two decades); parameter axes carry units.
    """
    from matplotlib.colors import ListedColormap, LogNorm, Normalize

    metric = metric or result.metric
    y = np.asarray(result.metric_values(metric), dtype=float)
    stable = np.asarray(result.stable, dtype=bool)
    failed = np.array([r.error is not None for r in result.rows], dtype=bool) | ~np.isfinite(y)
    unstable = ~stable & ~failed
    values = np.asarray(result.values, dtype=float)
    keys = list(result.ranges)
    P = len(keys)
    title = (
        f"{result.scenario} ({result.loop}, {result.method}): {int(stable.sum())}/{len(result.rows)} stable, "
        f"{int(unstable.sum())} unstable, {int(failed.sum())} raised   (stable: final_error < {result.stable_tol:g})"
    )
    if P == 2:
        fig = _new_figure(12.0, 5.0)
        ax_map, ax_metric = fig.subplots(1, 2)
        v1, v2 = values[:, 0], values[:, 1]
        category = np.where(failed, 2, np.where(stable, 0, 1))
        cmap = ListedColormap(["#4caf50", "#e53935", "#9e9e9e"])
        u1, u2 = np.unique(v1), np.unique(v2)
        is_grid = bool(getattr(result, "grid", False)) and u1.size * u2.size == len(v1)
        if is_grid:
            grid = np.full((u2.size, u1.size), np.nan)
            mgrid = np.full((u2.size, u1.size), np.nan)
            for k in range(len(v1)):
                i, j = np.searchsorted(u2, v2[k]), np.searchsorted(u1, v1[k])
                grid[i, j], mgrid[i, j] = category[k], y[k]
            ax_map.pcolormesh(_edges(u1), _edges(u2), grid, cmap=cmap, vmin=-0.5, vmax=2.5, shading="flat")
            finite = mgrid[np.isfinite(mgrid)]
            norm = (
                LogNorm(finite.min(), finite.max())
                if finite.size and finite.min() > 0 and finite.max() / finite.min() > 100
                else Normalize(*(finite.min(), finite.max()) if finite.size else (0, 1))
            )
            import matplotlib

            viridis = matplotlib.colormaps["viridis"].with_extremes(bad="0.72")  # failed cells grey
            im = ax_metric.pcolormesh(
                _edges(u1), _edges(u2), np.ma.masked_invalid(mgrid), cmap=viridis, norm=norm, shading="flat"
            )
        else:
            ax_map.scatter(v1, v2, c=category, cmap=cmap, vmin=-0.5, vmax=2.5, s=22, edgecolors="none")
            ok = ~failed
            im = ax_metric.scatter(v1[ok], v2[ok], c=y[ok], cmap="viridis", s=22)
            if failed.any():
                ax_metric.scatter(v1[failed], v2[failed], marker="x", color="0.4", s=22, label="run raised")
        from matplotlib.patches import Patch

        ax_map.legend(
            handles=[
                Patch(color=c, label=lab)
                for c, lab in zip(cmap.colors, ("stable", "unstable", "run raised"), strict=True)
            ],
            loc="upper left",
            bbox_to_anchor=(1.01, 1.0),
            fontsize=8,
            frameon=False,
        )
        ax_map.set_title("stability map", fontsize=9)
        ax_metric.set_title(f"{metric} (grey: run raised)", fontsize=9)
        fig.colorbar(im, ax=ax_metric, label=metric)
        for ax in (ax_map, ax_metric):
            ax.set_xlabel(_param_label(keys[0]))
            ax.set_ylabel(_param_label(keys[1]))
            ax.set_xlim(*result.ranges[keys[0]])
            ax.set_ylim(*result.ranges[keys[1]])
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        return fig

    fig = _new_figure(5.4 * P + 1.2, 4.8)
    gs = fig.add_gridspec(2, P, height_ratios=(5, 0.6), hspace=0.08)
    for j, key in enumerate(keys):
        ax = fig.add_subplot(gs[0, j])
        strip = fig.add_subplot(gs[1, j], sharex=ax)
        v = values[:, j]
        if P == 1:
            _shade_stable_runs(ax, v, stable, failed)
        if stable.any():
            ax.scatter(v[stable], y[stable], s=14, color="tab:green", label="stable", zorder=3)
        if unstable.any():
            ax.scatter(v[unstable], y[unstable], s=22, color="tab:red", marker="x", label="unstable", zorder=3)
        _metric_axis(ax, y[~failed])
        ax.set_ylabel(metric if j == 0 else "")
        ax.grid(alpha=0.3, which="both")
        ax.tick_params(labelbottom=False)
        strip.scatter(v[failed], np.zeros(int(failed.sum())), marker="^", color="tab:red", s=24, label="run raised")
        strip.set_yticks([])
        strip.set_ylim(-1, 1)
        strip.set_ylabel("raised", rotation=0, ha="right", va="center", fontsize=8)
        strip.set_xlabel(_param_label(key))
        strip.set_xlim(*result.ranges[key])
        strip.grid(alpha=0.3, axis="x")
    handles: dict[str, Any] = {}
    for ax in fig.axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    if handles:
        fig.legend(
            handles.values(), handles.keys(), loc="upper left", bbox_to_anchor=(1.0, 0.9), fontsize=8, frameon=False
        )
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.1, right=0.97, top=0.88, bottom=0.13)
    return fig


def plot_sweep(result: Any, path: str | Path, metric: str | None = None) -> Path:
    """Write :func:`sweep_figure` to the PNG ``path`` (atomically) and return ``path``."""
    return _write_png(sweep_figure(result, metric), path)


def _edges(centres: np.ndarray) -> np.ndarray:
    """Cell edges around sorted grid centres."""
    if centres.size == 1:
        return np.array([centres[0] - 0.5, centres[0] + 0.5])
    mid = 0.5 * (centres[1:] + centres[:-1])
    return np.concatenate([[2 * centres[0] - mid[0]], mid, [2 * centres[-1] - mid[-1]]])


def _shade_stable_runs(ax: Any, v: np.ndarray, stable: np.ndarray, failed: np.ndarray) -> None:
    """Shade each parameter interval whose consecutive samples (in parameter order) are all stable."""
    order = np.argsort(v)
    vs, ok = v[order], stable[order] & ~failed[order]
    start = None
    for k in range(len(vs)):
        if ok[k] and start is None:
            start = k
        if start is not None and (not ok[k] or k == len(vs) - 1):
            end = k if ok[k] else k - 1
            if end > start:
                ax.axvspan(vs[start], vs[end], color="tab:green", alpha=0.12, lw=0, label="stable interval")
            start = None
