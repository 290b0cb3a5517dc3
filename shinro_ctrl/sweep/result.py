"""The sweep's result: one row per sample, the table (CSV/JSON), the summary and the plot."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.files import atomic_write, dump_json
from shinro_ctrl.sim.metrics import METRICS
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
        """Plot the sweep to a PNG (see :func:`shinro_ctrl.plots.plot_sweep`).

        One parameter: the metric against it with stable intervals shaded and the
        samples whose run raised on a separate strip; two: a 2-D stability map
        beside the metric as colour; more: one marginal panel each. Axis ranges
        come from the data, parameter axes carry units.
        """
        from shinro_ctrl.plots import plot_sweep

        return plot_sweep(self, path, metric)

    def save(self, directory: str | Path) -> dict[str, Path]:
        """Write ``sweep.csv``, ``sweep.json`` and ``sweep.png`` into ``directory`` as one set.

        The files are built in a hidden folder swapped into place in one step
        (:func:`~shinro_ctrl.files.atomic_folder`): a kill leaves the previous
        sweep or the new one. Only a new or empty folder, or one an earlier save
        wrote (it carries the manifest), is replaced.

        Raises:
            InvalidArgument: ``directory`` is a folder shinro-ctrl did not write or a symbolic link.
        """
        from shinro_ctrl.files import atomic_folder

        d = Path(directory)
        names = ("sweep.csv", "sweep.json", "sweep.png")
        with atomic_folder(d, names) as staging:
            self.to_csv(staging / names[0])
            self.to_json(staging / names[1])
            self.plot(staging / names[2])
        self.files = {"csv": d / names[0], "json": d / names[1], "png": d / names[2]}
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
            f"unstable: {n - int(stable.sum())} ({errors} raised); rule: final_error < {self.stable_tol:g}",
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
