"""The plot of a robustness sweep: the metric against one parameter, a 2-D stability map, or one marginal per
parameter."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.plots._figure import _new_figure, _write_png
from shinro_ctrl.plots.units import _param_label

__all__ = ["plot_sweep", "sweep_figure"]


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
    metric = metric or result.metric
    y = np.asarray(result.metric_values(metric), dtype=float)
    stable = np.asarray(result.stable, dtype=bool)
    failed = np.array([r.error is not None for r in result.rows], dtype=bool) | ~np.isfinite(y)
    unstable = ~stable & ~failed
    values = np.asarray(result.values, dtype=float)
    keys = list(result.ranges)
    title = (
        f"{result.scenario} ({result.loop}, {result.method}): {int(stable.sum())}/{len(result.rows)} stable, "
        f"{int(unstable.sum())} unstable, {int(failed.sum())} raised   (stable: final_error < {result.stable_tol:g})"
    )
    if len(keys) == 2:
        return _map_figure(result, metric, keys, values, y, stable, failed, title)
    return _marginals_figure(result, metric, keys, values, y, stable, failed, title)


def plot_sweep(result: Any, path: str | Path, metric: str | None = None) -> Path:
    """Write :func:`sweep_figure` to the PNG ``path`` (atomically) and return ``path``."""
    return _write_png(sweep_figure(result, metric), path)


def _map_figure(
    result: Any,
    metric: str,
    keys: list[str],
    values: np.ndarray,
    y: np.ndarray,
    stable: np.ndarray,
    failed: np.ndarray,
    title: str,
) -> Any:
    """Two parameters: the stability map (grid cells or sample points) beside the metric as colour."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    fig = _new_figure(12.0, 5.0)
    ax_map, ax_metric = fig.subplots(1, 2)
    v1, v2 = values[:, 0], values[:, 1]
    category = np.where(failed, 2, np.where(stable, 0, 1))
    cmap = ListedColormap(["#4caf50", "#e53935", "#9e9e9e"])
    u1, u2 = np.unique(v1), np.unique(v2)
    is_grid = bool(getattr(result, "grid", False)) and u1.size * u2.size == len(v1)
    if is_grid:
        im = _grid_cells(ax_map, ax_metric, v1, v2, u1, u2, category, y, cmap)
    else:
        ax_map.scatter(v1, v2, c=category, cmap=cmap, vmin=-0.5, vmax=2.5, s=22, edgecolors="none")
        ok = ~failed
        im = ax_metric.scatter(v1[ok], v2[ok], c=y[ok], cmap="viridis", s=22)
        if failed.any():
            ax_metric.scatter(v1[failed], v2[failed], marker="x", color="0.4", s=22, label="run raised")
    ax_map.legend(
        handles=[
            Patch(color=c, label=lab) for c, lab in zip(cmap.colors, ("stable", "unstable", "run raised"), strict=True)
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
        _set_span(ax.set_xlim, result.ranges[keys[0]])
        _set_span(ax.set_ylim, result.ranges[keys[1]])
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _grid_cells(
    ax_map: Any,
    ax_metric: Any,
    v1: np.ndarray,
    v2: np.ndarray,
    u1: np.ndarray,
    u2: np.ndarray,
    category: np.ndarray,
    y: np.ndarray,
    cmap: Any,
) -> Any:
    """A full grid as cells: the stability category on ``ax_map``, the metric (failed cells grey) on
    ``ax_metric``; returns the metric's mappable."""
    import matplotlib
    from matplotlib.colors import LogNorm, Normalize

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
    viridis = matplotlib.colormaps["viridis"].with_extremes(bad="0.72")  # failed cells grey
    return ax_metric.pcolormesh(
        _edges(u1), _edges(u2), np.ma.masked_invalid(mgrid), cmap=viridis, norm=norm, shading="flat"
    )


def _marginals_figure(
    result: Any,
    metric: str,
    keys: list[str],
    values: np.ndarray,
    y: np.ndarray,
    stable: np.ndarray,
    failed: np.ndarray,
    title: str,
) -> Any:
    """One parameter (or more than two): the metric against each parameter, with a strip of raised runs below."""
    P = len(keys)
    unstable = ~stable & ~failed
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
        _set_span(strip.set_xlim, result.ranges[key])
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


def _set_span(set_lim: Callable[[float, float], object], span: tuple[float, float]) -> None:
    """Set an axis to a swept range; a constant parameter (LO = HI) keeps matplotlib's automatic limits."""
    if span[0] < span[1]:
        set_lim(*span)
