"""The sweep's result: one row per sample, the table (CSV/JSON), the summary and the plot."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.config import METRICS
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.files import atomic_write, dump_json
from shinro_ctrl.sweep.spec import TABLE_METRICS, WALL_CLOCK_METRICS
from shinro_ctrl.validation import did_you_mean

__all__ = ["SweepResult", "SweepRow"]


# -------------------------------------------------------------------- result
@dataclass
class SweepRow:
    """One sample of a sweep.

    Attributes:
        index: Sample number (row of the drawn parameter array).
        params: Swept key (``plant.pole_mass``) → value.
        metrics: The :data:`TABLE_METRICS` of :func:`shinro_ctrl.sim.compute_metrics`
            (NaN when the run failed): deterministic, the same whatever the executor.
        stable: The verdict (see the module docstring).
        error: ``"<ExceptionType>: <message>"`` when the run raised, else None.
        timing: The :data:`WALL_CLOCK_METRICS` of the run (NaN when it failed): measured
            with a clock, so not part of the table.
    """

    index: int
    params: dict[str, float]
    metrics: dict[str, float]
    stable: bool
    error: str | None = None
    timing: dict[str, float] = field(default_factory=dict)


@dataclass
class SweepResult:
    """The table of a sweep, with its settings.

    Attributes:
        scenario: Scenario name; ``loop``: ``"standalone"`` or ``"mujoco"``.
        ranges: Swept key → ``(lo, hi)``.
        rows: One :class:`SweepRow` per sample, by index.
        method: Executor actually used (``serial``, ``pool``, ``dask`` or ``batch``).
        workers: Local worker processes (pool), or the cluster's threads (dask).
        seed, samples, grid: The sampling settings.
        stable_tol: Final-error bound of the stability rule.
        metric: The metric :meth:`plot` shows by default.
        elapsed_s: Wall time of the sweep [s].
        notes: Remarks about the run (e.g. why the batch rollout was not used).
        timings: Wall-clock figures of the sweep (not part of the table):
            ``solve_time_median_s``, the median over the samples that ran of
            their median controller call; with the batch rollout also
            ``build_plants_s`` (constructing and validating the perturbed
            plants), ``rollout_s`` (the vectorized loop, metrics included),
            ``instances`` and ``steps``.
        files: Paths written (``csv``, ``json``, ``png``).
    """

    scenario: str
    loop: str
    ranges: dict[str, tuple[float, float]]
    rows: list[SweepRow]
    method: str
    workers: int
    seed: int
    samples: int
    grid: bool
    stable_tol: float
    metric: str = "rms_error"
    elapsed_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def keys(self) -> list[str]:
        """The swept keys, in column order."""
        return list(self.ranges)

    @property
    def values(self) -> np.ndarray:
        """Parameter values ``(S, P)``."""
        return np.array([[r.params[k] for k in self.ranges] for r in self.rows], dtype=float).reshape(
            len(self.rows), len(self.ranges)
        )

    @property
    def stable(self) -> np.ndarray:
        """Verdicts ``(S,)`` bool."""
        return np.array([r.stable for r in self.rows], dtype=bool)

    def metric_values(self, name: str) -> np.ndarray:
        """One metric over the samples ``(S,)`` (NaN where the run failed); a wall-clock one from ``timing``."""
        if name not in METRICS:
            raise ConfigError(f"unknown metric {name!r}{did_you_mean(name, METRICS)}")
        if name in WALL_CLOCK_METRICS:
            return np.array([r.timing.get(name, math.nan) for r in self.rows], dtype=float)
        return np.array([r.metrics.get(name, math.nan) for r in self.rows], dtype=float)

    def columns(self) -> list[str]:
        """CSV header: ``index``, the swept keys, the :data:`TABLE_METRICS`, ``stable``, ``error``."""
        return ["index", *self.ranges, *TABLE_METRICS, "stable", "error"]

    def table(self) -> list[dict[str, Any]]:
        """The rows as flat dicts keyed by :meth:`columns` (no wall-clock values: see the module doc)."""
        return [
            {
                "index": r.index,
                **{k: r.params[k] for k in self.ranges},
                **{k: r.metrics.get(k, math.nan) for k in TABLE_METRICS},
                "stable": r.stable,
                "error": r.error,
            }
            for r in self.rows
        ]

    def to_csv(self, path: str | Path) -> Path:
        """Write the table as CSV (floats round-trip: ``repr``; ``stable`` as yes/no), atomically."""
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(self.columns())
        for row in self.table():
            cells = []
            for key, v in row.items():
                if key == "stable":
                    cells.append("yes" if v else "no")
                elif v is None:
                    cells.append("")
                elif isinstance(v, float):
                    cells.append(repr(v))
                else:
                    cells.append(str(v))
            writer.writerow(cells)
        text = buf.getvalue()
        return atomic_write(path, lambda f: f.write(text))

    def to_dict(self) -> dict[str, Any]:
        """Settings, rows and timings as plain data (what :meth:`to_json` writes).

        ``rows`` is the deterministic table; ``elapsed_s`` and ``timings`` (the
        sweep's :attr:`timings` plus ``per_sample``: each wall-clock metric as a
        list by sample index) are clock readings.
        """
        return {
            "scenario": self.scenario,
            "loop": self.loop,
            "method": self.method,
            "workers": self.workers,
            "seed": self.seed,
            "samples": self.samples,
            "grid": self.grid,
            "ranges": {k: list(v) for k, v in self.ranges.items()},
            "stable_rule": f"run completes, all states finite and final_error < {self.stable_tol:g}",
            "stable_tol": self.stable_tol,
            "n_stable": int(self.stable.sum()),
            "elapsed_s": self.elapsed_s,
            "timings": {
                **self.timings,
                "per_sample": {k: [r.timing.get(k, math.nan) for r in self.rows] for k in WALL_CLOCK_METRICS},
            },
            "notes": list(self.notes),
            "rows": [
                {"index": r.index, "params": r.params, "metrics": r.metrics, "stable": r.stable, "error": r.error}
                for r in self.rows
            ],
        }

    def to_json(self, path: str | Path) -> Path:
        """Write :meth:`to_dict` as JSON (NaN as null, infinities as ``"inf"``), atomically."""
        return dump_json(path, self.to_dict())

    def plot(self, path: str | Path, metric: str | None = None) -> Path:
        """Plot a metric (log scale) against each swept parameter to a PNG, atomically.

        Stable samples are green dots, unstable ones red crosses; samples whose
        run raised (no metric) are red triangles along the top edge. The
        stable region is shaded: with one parameter, each interval between
        consecutive stable samples (in parameter order) with no unstable
        sample inside; with several, per-parameter bins shaded by the fraction
        of stable samples in them (the marginal).
        """
        import matplotlib.pyplot as plt  # the backend is the caller's (the CLI picks one)

        metric = metric or self.metric
        y = self.metric_values(metric)
        stable = self.stable
        values = self.values
        P = len(self.ranges)
        fig, axes = plt.subplots(1, P, figsize=(5.2 * P, 4.2), squeeze=False, sharey=True)
        ok = np.isfinite(y) & (y > 0)
        floor = float(y[ok].min()) if ok.any() else 1e-6
        # Diverging runs reach absurd values; keep the axis about the stable ones (3 decades above them).
        ceiling = (
            float(y[ok & stable].max()) * 1e3 if (ok & stable).any() else (float(y[ok].max()) if ok.any() else 1.0)
        )
        clipped = bool((y[ok] > ceiling).any())
        y_plot = np.where(np.isfinite(y), np.clip(y, floor, max(ceiling, floor)), np.nan)
        top = max(ceiling, floor) * 3
        failed = ~np.isfinite(y)
        for j, key in enumerate(self.ranges):
            ax = axes[0, j]
            v = values[:, j]
            if P == 1:
                _shade_runs(ax, v, stable)
            else:
                _shade_marginal(ax, v, stable, self.ranges[key])
            if stable.any():
                ax.scatter(v[stable], y_plot[stable], s=14, color="tab:green", label="stable", zorder=3)
            unst = ~stable & ~failed
            if unst.any():
                ax.scatter(v[unst], y_plot[unst], s=22, color="tab:red", marker="x", label="unstable", zorder=3)
            if failed.any():
                ax.scatter(
                    v[failed],
                    np.full(failed.sum(), top),
                    s=22,
                    color="tab:red",
                    marker="^",
                    label="run raised",
                    zorder=3,
                    clip_on=False,
                )
            ax.set_yscale("log")
            ax.set_ylim(floor / 2, top * 2)
            ax.set_xlabel(key)
            ax.grid(alpha=0.3, which="both")
        axes[0, 0].set_ylabel(f"{metric} (log" + (f"; clipped at {ceiling:.3g})" if clipped else ")"))
        handles: dict[str, Any] = {}
        for ax in axes[0]:
            for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
                handles.setdefault(lab, h)
        axes[0, -1].legend(handles.values(), handles.keys(), fontsize=8, loc="best")
        fig.suptitle(
            f"{self.scenario} ({self.loop}, {self.method}): {int(stable.sum())}/{len(self.rows)} stable "
            f"(final_error < {self.stable_tol:g})",
            fontsize=10,
        )
        fig.tight_layout()
        path = Path(path)
        atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110), binary=True)
        plt.close(fig)
        return path

    def save(self, directory: str | Path) -> dict[str, Path]:
        """Write ``sweep.csv``, ``sweep.json`` and ``sweep.png`` into ``directory``."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.files = {
            "csv": self.to_csv(d / "sweep.csv"),
            "json": self.to_json(d / "sweep.json"),
            "png": self.plot(d / "sweep.png"),
        }
        return self.files

    def summary(self) -> str:
        """A few lines for a terminal: counts, the stable parameter ranges, notes and files."""
        n = len(self.rows)
        stable = self.stable
        errors = sum(r.error is not None for r in self.rows)
        how = f"{self.method}, {self.workers} worker{'s' if self.workers != 1 else ''}"
        kind = f"grid of {self.samples} per parameter" if self.grid else f"seed {self.seed}"
        lines = [
            f"sweep {self.scenario} ({self.loop}; {how}; {kind}): {n} samples in {self.elapsed_s:.2f} s",
            f"  stable: {int(stable.sum())}/{n} ({100 * stable.mean() if n else 0:.1f}%), "
            f"{errors} raised; rule: final_error < {self.stable_tol:g}",
        ]
        values = self.values
        for j, key in enumerate(self.ranges):
            lo, hi = self.ranges[key]
            if stable.any():
                s = values[stable, j]
                lines.append(f"  {key:24s} swept {lo:g}..{hi:g}; stable samples span {s.min():.4g}..{s.max():.4g}")
            else:
                lines.append(f"  {key:24s} swept {lo:g}..{hi:g}; no stable sample")
        lines.extend(f"  note: {note}" for note in self.notes)
        if self.files:
            lines.append("  wrote " + ", ".join(str(p) for p in self.files.values()))
        return "\n".join(lines)


def _shade_runs(ax: Any, v: np.ndarray, stable: np.ndarray) -> None:
    order = np.argsort(v, kind="stable")
    vs, ss = v[order], stable[order]
    label = "stable region"
    k = 0
    while k < len(vs):
        if not ss[k]:
            k += 1
            continue
        j = k
        while j + 1 < len(vs) and ss[j + 1]:
            j += 1
        if vs[j] > vs[k]:
            ax.axvspan(vs[k], vs[j], color="tab:green", alpha=0.15, lw=0, label=label)
        else:
            ax.axvline(vs[k], color="tab:green", alpha=0.3, lw=2, label=label)
        label = None
        k = j + 1


def _shade_marginal(ax: Any, v: np.ndarray, stable: np.ndarray, rng: tuple[float, float]) -> None:
    lo, hi = rng
    if hi <= lo:
        ax.axvline(lo, color="tab:green", alpha=0.3 * float(stable.mean()) if stable.size else 0.0, lw=2)
        return
    bins = min(20, max(4, round(math.sqrt(len(v)))))
    edges = np.linspace(lo, hi, bins + 1)
    which = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, bins - 1)
    label = "stable fraction (marginal)"
    for b in range(bins):
        inside = which == b
        if not inside.any():
            continue
        frac = float(stable[inside].mean())
        if frac > 0:
            ax.axvspan(edges[b], edges[b + 1], color="tab:green", alpha=0.3 * frac, lw=0, label=label)
            label = None
