"""Robustness sweeps: one nominal controller evaluated on many perturbed plants.

The controller is designed once, on the plant the scenario describes (the
*nominal* plant). Each sample then rebuilds the plant (and, for a MuJoCo loop,
its engine via :meth:`MujocoEngine.for_plant`) from the ``[plant]`` table with
some parameters changed, and runs the scenario's closed loop with the nominal
controller. The parameters are drawn up-front in the calling process (uniform
Monte-Carlo from a seeded ``numpy`` generator, or a full grid), so the table
depends only on the scenario, the ranges, ``samples``/``grid`` and ``seed``:
never on the worker count or the executor.

Stability rule (per sample): **stable** iff the run completed without raising,
every state stayed finite, and the final tracking error
``metrics["final_error"]`` (the norm over the tracked states at the last step)
is below ``stable_tol``, by default ``10 × [sim] settle_tol``. A sample that
raises (``SimulationDiverged``, ``MPCInfeasible``, ``NonFiniteError``, any
``ShinroError``, an invalid parameter such as a negative mass, a numeric
overflow) is recorded with its message and marked unstable; it never aborts
the sweep. A diverging MuJoCo sample prints nothing: the engine records
MuJoCo's warning text instead of letting the C library print it (see
:mod:`shinro_ctrl.engine`), and the ``SimulationDiverged`` message, which
quotes it, goes in the table.

Executors (``method``):

* ``"serial"``: in this process, one sample after another.
* ``"pool"``: a local :class:`~concurrent.futures.ProcessPoolExecutor`
  (``forkserver`` processes); the scenario document and chunks of parameter
  rows are sent, each worker rebuilds and caches the nominal sim.
* ``"dask"``: the same chunks on a Dask cluster (``scheduler`` = the address
  of a ``dask.distributed`` scheduler; needs the ``distributed`` extra).
* ``"batch"``: the vectorized rollout of :mod:`shinro_ctrl.batch`: every
  instance advances in one numpy evaluation of the plant's dynamics per step
  (standalone loop, LQR, constant reference, no measurement noise, a plant
  whose constructor parameters are its dynamics parameters).
* ``"auto"`` (default): ``dask`` when a scheduler is given, else ``batch``
  when it applies, else ``pool`` (``serial`` for one worker).

Determinism: the table (:meth:`SweepResult.table`, ``sweep.csv`` and the
``rows`` of ``sweep.json``) holds only what the seed decides: the parameters,
the metrics of :data:`TABLE_METRICS`, the verdict and the error text. The
same scenario, ranges and seed give the same table, byte for byte, whatever
the executor or worker count (the batch rollout agrees to rounding). Wall-clock
measurements are kept out of it: each sample's ``solve_time_median_s`` (see
:data:`WALL_CLOCK_METRICS`) is in :attr:`SweepRow.timing`, and in
``sweep.json`` under ``"timings"`` (``"per_sample"``, by index), beside the
sweep's own ``elapsed_s``.

Output (``out``): ``sweep.csv``, ``sweep.json`` and ``sweep.png``, written
atomically.
"""

from __future__ import annotations

import copy
import csv
import io
import itertools
import json
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.config import METRICS, Scenario, load_scenario, parse_scenario
from shinro_ctrl.errors import ConfigError, ShinroError
from shinro_ctrl.files import atomic_write, dump_json
from shinro_ctrl.progress import Progress
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "METHODS",
    "TABLE_METRICS",
    "WALL_CLOCK_METRICS",
    "SweepResult",
    "SweepRow",
    "draw_samples",
    "parse_param",
    "parse_params",
    "perturbed_sim",
    "run_sweep",
    "sweep_keys",
]

METHODS = ("auto", "pool", "dask", "batch", "serial")
STABLE_TOL_FACTOR = 10.0
MAX_ROWS = 10_000_000
#: Metrics measured with a clock: they vary from run to run, so they stay out of the table.
WALL_CLOCK_METRICS = ("solve_time_median_s",)
#: The metrics of the table (every metric of :data:`shinro_ctrl.config.METRICS` but the wall-clock ones).
TABLE_METRICS = tuple(m for m in METRICS if m not in WALL_CLOCK_METRICS)
#: Exceptions a sample may raise that mark it unstable (anything else is a bug and propagates).
SAMPLE_ERRORS: tuple[type[BaseException], ...] = (ShinroError, ValueError, ArithmeticError, RuntimeError)


# ------------------------------------------------------------------ the spec
def parse_param(text: str) -> tuple[str, tuple[float, float]]:
    """Parse one ``KEY=LO:HI`` range, e.g. ``plant.pole_mass=0.05:0.5``.

    Raises:
        ConfigError: malformed text, a non-finite bound or ``LO > HI``.
    """
    key, sep, rng = text.partition("=")
    key = key.strip()
    lo_text, sep2, hi_text = rng.partition(":")
    if not sep or not sep2 or not key:
        raise ConfigError(f"--param expects KEY=LO:HI (e.g. plant.pole_mass=0.05:0.5), got {text!r}")
    try:
        lo, hi = float(lo_text), float(hi_text)
    except ValueError:
        raise ConfigError(f"--param {key}: LO and HI must be numbers, got {rng!r}") from None
    return key, _check_range(key, (lo, hi))


def parse_params(texts: Iterable[str]) -> dict[str, tuple[float, float]]:
    """Parse several ``KEY=LO:HI`` ranges into a dict (a key given twice is an error)."""
    out: dict[str, tuple[float, float]] = {}
    for text in texts:
        key, rng = parse_param(text)
        if key in out:
            raise ConfigError(f"--param {key} given twice")
        out[key] = rng
    return out


def _check_range(key: str, rng: Any) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise ConfigError(f"sweep range of {key!r} must be a (LO, HI) pair of numbers, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ConfigError(f"sweep range of {key!r} must be finite, got {lo:g}:{hi:g}")
    if lo > hi:
        raise ConfigError(f"sweep range of {key!r}: LO must be <= HI, got {lo:g}:{hi:g}")
    return lo, hi


def sweep_keys(plant: Any) -> tuple[str, ...]:
    """The dotted keys a sweep may perturb: ``plant.<name>`` for each scalar constructor parameter."""
    return tuple(
        f"plant.{k}"
        for k, v in plant.params().items()
        if isinstance(v, int | float | np.floating) and not isinstance(v, bool)
    )


def _check_keys(params: Mapping[str, Any], valid: Sequence[str]) -> None:
    for key in params:
        if key in valid:
            continue
        if not key.startswith("plant."):
            raise ConfigError(
                f"cannot sweep {key!r}: only [plant] parameters are perturbed (the controller is designed "
                f"once on the nominal plant){did_you_mean(key, valid)}"
            )
        raise ConfigError(f"unknown sweep key {key!r}{did_you_mean(key, valid)}")


def draw_samples(
    ranges: Mapping[str, tuple[float, float]], samples: int, *, grid: bool = False, seed: int = 0
) -> np.ndarray:
    """The parameter rows of a sweep, ``(S, P)`` with columns in ``ranges`` order.

    Monte-Carlo: ``S = samples`` rows of ``numpy.random.default_rng(seed).uniform(lo, hi)``
    (drawn as one ``(S, P)`` array). Grid: ``samples`` evenly spaced points per
    parameter (``linspace(lo, hi, samples)``), full product, ``S = samples ** P``,
    the last parameter varying fastest.
    """
    los = np.array([r[0] for r in ranges.values()], dtype=float)
    his = np.array([r[1] for r in ranges.values()], dtype=float)
    if grid:
        axes = [np.linspace(lo, hi, samples) for lo, hi in zip(los, his, strict=True)]
        return np.array(list(itertools.product(*axes)), dtype=float).reshape(-1, len(axes))
    rng = np.random.default_rng(seed)
    return rng.uniform(los, his, size=(samples, len(los)))


# -------------------------------------------------------------- perturbation
def perturbed_sim(nominal: Any, overrides: Mapping[str, float]) -> Any:
    """A :class:`~shinro_ctrl.sim.RobotSim` that runs the nominal controller on a perturbed plant.

    The plant is rebuilt from the scenario's ``[plant]`` table with
    ``overrides`` (constructor name → value) applied; in a MuJoCo loop a fresh
    engine is built for it with :meth:`MujocoEngine.for_plant` (same substeps
    and model as the nominal sim) and attached. Everything else is the
    nominal sim's: the controller designed on the nominal plant, the
    reference, the initial state, the tracked states and the scenario
    settings. ``nominal`` is not modified (the result is a shallow copy).

    A memoryless controller (one that keeps the base no-op ``reset``, such as
    LQR) is shared as the very object. A controller with memory (MPC, IK-QP:
    OSQP warm starts and adaptive ``rho``) is designed again from the
    *nominal* plant with the scenario's options, so that a sample's result
    never depends on which samples ran before it in the same worker.

    Args:
        nominal: The sim built from the nominal scenario.
        overrides: Plant constructor arguments to change, e.g. ``{"pole_mass": 0.3}``.

    Raises:
        ConfigError: an invalid value (e.g. a negative mass), naming the key.
    """
    from shinro_ctrl.controllers import controller_class

    scenario: Scenario = nominal.scenario
    sim = nominal.with_plant(dict(overrides))
    if nominal.controller.stateful:  # memory between calls: a fresh controller per sample
        ccls = controller_class(scenario.controller.type)
        sim.controller = ccls.from_plant(nominal.plant, **scenario.controller.options)
    return sim


def _error_text(exc: BaseException) -> str:
    """``"<Type>: <message on one line>"``; a float overflow is said to be a divergence."""
    text = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    if isinstance(exc, OverflowError):
        text += " (a state left the float range: the loop diverged)"
    return text


def _verdict(metrics: Mapping[str, float], finite: bool, stable_tol: float) -> bool:
    fe = metrics.get("final_error", math.nan)
    return bool(finite and math.isfinite(fe) and fe < stable_tol)


# One sample's outcome as it travels back from a worker: (index, metrics, stable, error, timing).
_Outcome = tuple[int, dict[str, float], bool, str | None, dict[str, float]]


def _nan_metrics() -> dict[str, float]:
    return dict.fromkeys(TABLE_METRICS, math.nan)


def _nan_timing() -> dict[str, float]:
    return dict.fromkeys(WALL_CLOCK_METRICS, math.nan)


def _run_one(nominal: Any, names: Sequence[str], index: int, values: Sequence[float], stable_tol: float) -> _Outcome:
    overrides = {name: float(v) for name, v in zip(names, values, strict=True)}
    try:
        with np.errstate(all="ignore"):
            result = perturbed_sim(nominal, overrides).run(progress=False)
    except SAMPLE_ERRORS as exc:
        return index, _nan_metrics(), False, _error_text(exc), _nan_timing()
    finite = bool(np.all(np.isfinite(result.x)))
    metrics = {k: result.metrics.get(k, math.nan) for k in TABLE_METRICS}
    timing = {k: float(result.metrics.get(k, math.nan)) for k in WALL_CLOCK_METRICS}
    return index, metrics, _verdict(metrics, finite, stable_tol), None, timing


@dataclass(frozen=True)
class _Job:
    """What a worker needs: the scenario document and a chunk of parameter rows (picklable)."""

    doc: dict[str, Any]
    source: str | None
    engine: str | None
    names: tuple[str, ...]
    indices: tuple[int, ...]
    rows: tuple[tuple[float, ...], ...]
    stable_tol: float


_CACHE = threading.local()


def _nominal_for(job: _Job) -> Any:
    """The nominal sim of ``job``'s scenario, built once per worker thread."""
    key = (json.dumps(job.doc, sort_keys=True, default=str), job.source, job.engine)
    cached = getattr(_CACHE, "sim", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    sim = _build_nominal(job.doc, job.source, job.engine)
    _CACHE.sim = (key, sim)
    return sim


def _build_nominal(doc: Mapping[str, Any], source: str | None, engine: str | None) -> Any:
    from shinro_ctrl.sim import RobotSim

    path = Path(source) if source else None
    scenario = parse_scenario(doc, source=source or "<dict>", path=path)
    return RobotSim(scenario, engine=engine)


def _run_job(job: _Job) -> list[_Outcome]:
    """Worker entry point: run a chunk of samples (module level, so it pickles by reference)."""
    nominal = _nominal_for(job)
    return [_run_one(nominal, job.names, i, row, job.stable_tol) for i, row in zip(job.indices, job.rows, strict=True)]


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
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

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


# ----------------------------------------------------------------- executors
def _chunks(indices: Sequence[int], size: int) -> list[Sequence[int]]:
    return [indices[i : i + size] for i in range(0, len(indices), size)]


def _jobs(base: _Job, values: np.ndarray, n_tasks: int) -> list[_Job]:
    S = values.shape[0]
    size = max(1, math.ceil(S / max(n_tasks, 1)))
    jobs = []
    for idx in _chunks(range(S), size):
        rows = tuple(tuple(float(x) for x in values[i]) for i in idx)
        jobs.append(_Job(base.doc, base.source, base.engine, base.names, tuple(idx), rows, base.stable_tol))
    return jobs


def _run_serial(nominal: Any, base: _Job, values: np.ndarray, bar: Progress) -> list[_Outcome]:
    out = []
    for i, row in enumerate(values):
        out.append(_run_one(nominal, base.names, i, row, base.stable_tol))
        bar.update(i + 1)
    return out


_POOL_PRELOAD = [
    "shinro_ctrl.sweep",
    "shinro_ctrl.sim",
    "shinro_ctrl.plants",
    "shinro_ctrl.controllers",
    "shinro_ctrl.engine",
    "control",
]


def _run_pool(base: _Job, values: np.ndarray, workers: int, bar: Progress) -> list[_Outcome]:
    import multiprocessing

    # forkserver: workers fork from a clean server process (safe when this process runs threads,
    # e.g. a Dask client), and the preloaded imports are paid once, not once per worker.
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(_POOL_PRELOAD)
    jobs = _jobs(base, values, workers * 4)
    out: list[_Outcome] = []
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        futures = [pool.submit(_run_job, job) for job in jobs]
        for fut in as_completed(futures):
            out.extend(fut.result())
            bar.update(len(out))
    return out


def _run_dask(base: _Job, values: np.ndarray, scheduler: Any, bar: Progress) -> tuple[list[_Outcome], int]:
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_completed
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ConfigError("--scheduler needs dask.distributed: pip install 'shinro_ctrl[distributed]'") from exc
    own = not isinstance(scheduler, Client)
    if own:
        try:
            client = Client(scheduler, timeout="10s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise OSError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
    else:
        client = scheduler
    try:
        threads = max(1, sum(client.nthreads().values()))
        jobs = _jobs(base, values, threads * 4)
        futures = [client.submit(_run_job, job, pure=False) for job in jobs]
        out: list[_Outcome] = []
        for fut in dask_completed(futures, loop=client.loop):
            out.extend(fut.result())
            bar.update(len(out))
        return out, threads
    finally:
        if own:
            client.close()


def _batch_reason(nominal: Any, names: Sequence[str]) -> str | None:
    """Why the batch rollout cannot run this sweep (None if it can)."""
    from shinro_ctrl.batch import batch_unsupported_reason

    reason = batch_unsupported_reason(nominal.plant, nominal.controller)
    if reason is not None:
        return reason
    sim = nominal.scenario.sim
    if nominal.reference.kind != "constant":
        return f"the reference is {nominal.reference.kind!r}, not constant"
    if sim.measurement_noise and any(v != 0 for v in sim.measurement_noise):
        return "the scenario adds measurement noise"
    missing = [n for n in names if n not in nominal.plant.param_names]
    if missing:  # pragma: no cover - implied by batch_unsupported_reason
        return f"{missing[0]!r} is not a dynamics parameter"
    return None


def _run_batch(
    nominal: Any, names: Sequence[str], values: np.ndarray, stable_tol: float, bar: Progress, timings: dict[str, float]
) -> list[_Outcome]:
    from shinro_ctrl.batch import lqr_batch_rollout
    from shinro_ctrl.plants import plant_class

    scenario: Scenario = nominal.scenario
    cls = plant_class(scenario.plant.type)
    S = values.shape[0]
    outcomes: dict[int, _Outcome] = {}
    t0 = time.perf_counter()
    ok: list[int] = []
    plist: list[dict[str, float]] = []
    # Build each perturbed plant, as the per-sample path does: the constructor validates the values
    # (a negative mass is recorded as that sample's error) and gives the dynamics parameters.
    # The keys were checked once, so call the constructor directly (from_config inspects the signature on
    # every call); when it rejects a value, from_config reproduces the per-sample path's exact message.
    fixed = {k: v for k, v in scenario.plant.params.items() if k != "type"}
    for i in range(S):
        kwargs = {**fixed, **{n: float(v) for n, v in zip(names, values[i], strict=True)}}
        try:
            plant = cls(**kwargs)
        except (TypeError, ValueError):
            try:
                plant = cls.from_config(kwargs)
            except SAMPLE_ERRORS as exc:
                outcomes[i] = (i, _nan_metrics(), False, _error_text(exc), _nan_timing())
                continue
        ok.append(i)
        plist.append(plant.params())
    timings["build_plants_s"] = time.perf_counter() - t0
    timings["instances"] = len(ok)
    if ok:
        pnames = nominal.plant.param_names
        params = {p: np.array([d[p] for d in plist], dtype=float) for p in pnames}
        steps = max(1, round(scenario.sim.duration / nominal.plant.dt))
        ref = nominal.reference(0.0)
        roll = lqr_batch_rollout(
            nominal.plant,
            nominal.controller,
            params=params,
            x0=nominal.initial_state,
            ref=ref,
            steps=steps,
            tracked=nominal.tracked,
            settle_tol=scenario.sim.settle_tol,
            progress=lambda k, total: bar.update(int(S * k / total)),
        )
        timings["rollout_s"] = roll.elapsed_s
        timings["steps"] = steps
        label = f"{scenario.name} ({nominal.loop})"
        pname = type(nominal.plant).__name__
        for j, i in enumerate(ok):
            k = int(roll.diverged_step[j])
            if k >= 0:
                err = (
                    f"SimulationDiverged: {label} at t = {roll.t[k]:.4g} s: "
                    f"{pname} state became non-finite (batch rollout)"
                )
                outcomes[i] = (i, _nan_metrics(), False, err, _nan_timing())
                continue
            metrics = {m: float(roll.metrics[m][j]) for m in TABLE_METRICS}
            metrics["constraint_violations"] = int(metrics["constraint_violations"])
            timing = {m: float(roll.metrics[m][j]) for m in WALL_CLOCK_METRICS}
            outcomes[i] = (i, metrics, _verdict(metrics, True, stable_tol), None, timing)
    bar.update(S)
    return [outcomes[i] for i in range(S)]


# ---------------------------------------------------------------------- API
def run_sweep(
    config: str | Path | Mapping[str, Any],
    params: Mapping[str, tuple[float, float]],
    *,
    samples: int,
    grid: bool = False,
    workers: int = 1,
    seed: int = 0,
    out: str | Path | None = None,
    scheduler: Any = None,
    engine: str | None = None,
    method: str = "auto",
    progress: bool | Callable[[int, int], None] | None = None,
    stable_tol: float | None = None,
    metric: str = "rms_error",
    duration: float | None = None,
) -> SweepResult:
    """Evaluate the scenario's nominal controller on perturbed plants.

    Args:
        config: Scenario path, shipped name, or an already-loaded document (dict).
        params: Dotted ``plant.*`` key → ``(lo, hi)``, e.g. ``{"plant.pole_mass": (0.05, 0.5)}``.
        samples: Monte-Carlo sample count, or points per parameter with ``grid``.
        grid: Full grid instead of uniform random samples.
        workers: Local worker processes for the ``pool`` executor.
        seed: Seed of the Monte-Carlo draws.
        out: Directory for ``sweep.csv``, ``sweep.json`` and ``sweep.png`` (None: write nothing).
        scheduler: Address of a ``dask.distributed`` scheduler (or a ``Client``).
        engine: Override the scenario's loop, ``"standalone"`` or ``"mujoco"``.
        method: ``"auto"``, ``"pool"``, ``"dask"``, ``"batch"`` or ``"serial"`` (see the module doc).
            An explicit ``"batch"`` that does not apply falls back to ``pool``/``serial`` with a note.
        progress: Progress bar on stderr: None (when stderr is a terminal), True, False, or a
            ``callback(done, total)``.
        stable_tol: Bound on ``final_error`` for a stable verdict (default ``10 × settle_tol``).
        metric: Metric :meth:`SweepResult.plot` shows.
        duration: Override the scenario's duration [s].

    Returns:
        A :class:`SweepResult`, rows ordered by sample index.

    Raises:
        ConfigError: an invalid scenario or sweep specification (unknown key, bad range, ...).
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise ConfigError(f"unknown sweep method {method!r}{did_you_mean(method, METHODS)}")
    if isinstance(samples, bool) or not isinstance(samples, int | np.integer) or samples < 1:
        raise ConfigError(f"samples must be a positive integer, got {samples!r}")
    if isinstance(workers, bool) or not isinstance(workers, int | np.integer) or workers < 1:
        raise ConfigError(f"workers must be a positive integer, got {workers!r}")
    if metric not in METRICS:
        raise ConfigError(f"unknown metric {metric!r}{did_you_mean(metric, METRICS)}")
    if not params:
        raise ConfigError("a sweep needs at least one parameter range (plant.<name> = (lo, hi))")
    ranges = {str(k): _check_range(str(k), v) for k, v in params.items()}
    if grid and samples ** len(ranges) > MAX_ROWS:
        raise ConfigError(f"a grid of {samples}^{len(ranges)} points is too large (max {MAX_ROWS})")

    if isinstance(config, Mapping):
        doc, source = copy.deepcopy(dict(config)), None
    else:
        scenario = load_scenario(config)
        doc, source = copy.deepcopy(scenario.raw), str(scenario.path)
    if duration is not None:
        doc.setdefault("sim", {})["duration"] = duration
    from shinro_ctrl.plants import plant_class

    scenario = parse_scenario(doc, source=source or "<dict>", path=Path(source) if source else None)
    _check_keys(ranges, sweep_keys(plant_class(scenario.plant.type).from_config(scenario.plant.params)))
    nominal = _build_nominal(doc, source, engine)  # designs the controller
    tol = STABLE_TOL_FACTOR * scenario.sim.settle_tol if stable_tol is None else float(stable_tol)
    if not (math.isfinite(tol) and tol > 0):
        raise ConfigError(f"stable_tol must be positive and finite, got {stable_tol!r}")

    values = draw_samples(ranges, samples, grid=grid, seed=seed)
    names = tuple(k.removeprefix("plant.") for k in ranges)
    notes: list[str] = []
    chosen = method
    if scheduler is not None and method in ("auto", "dask"):
        chosen = "dask"
    elif method == "dask":
        raise ConfigError("method 'dask' needs a scheduler address (--scheduler)")
    elif method in ("auto", "batch"):
        reason = _batch_reason(nominal, names)
        if reason is None:
            chosen = "batch"
        else:
            chosen = "pool" if workers > 1 else "serial"
            if method == "batch":
                notes.append(f"batch rollout not used ({reason}); ran the per-sample loop ({chosen})")
    elif method == "pool" and workers == 1:
        chosen = "serial"

    base = _Job(doc, source, engine, names, (), (), tol)
    bar = Progress(values.shape[0], f"sweep {scenario.name}", progress, delay=0.0, unit="samples")
    timings: dict[str, float] = {}
    used_workers = 1 if chosen in ("serial", "batch") else workers
    try:
        if chosen == "batch":
            outcomes = _run_batch(nominal, names, values, tol, bar, timings)
        elif chosen == "serial":
            outcomes = _run_serial(nominal, base, values, bar)
        elif chosen == "pool":
            outcomes = _run_pool(base, values, workers, bar)
        else:
            outcomes, used_workers = _run_dask(base, values, scheduler, bar)
    finally:
        bar.close()

    outcomes.sort(key=lambda o: o[0])
    rows = [
        SweepRow(i, {k: float(values[i, j]) for j, k in enumerate(ranges)}, metrics, stable, error, timing)
        for i, metrics, stable, error, timing in outcomes
    ]
    for key in WALL_CLOCK_METRICS:
        measured = [r.timing[key] for r in rows if math.isfinite(r.timing.get(key, math.nan))]
        timings[key] = float(np.median(measured)) if measured else math.nan
    result = SweepResult(
        scenario=scenario.name,
        loop=nominal.loop,
        ranges=ranges,
        rows=rows,
        method=chosen,
        workers=used_workers,
        seed=seed,
        samples=samples,
        grid=grid,
        stable_tol=tol,
        metric=metric,
        notes=notes,
        timings=timings,
    )
    result.elapsed_s = time.perf_counter() - t_start
    if out is not None:
        result.save(out)
    return result
