"""The sweep entry point :func:`run_sweep` (see the package docstring for the rules)."""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.config import load_scenario, parse_scenario
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.progress import Progress
from shinro_ctrl.sim.metrics import METRICS
from shinro_ctrl.sweep.executors import SweepJob, batch_reason, build_nominal, run_batch, run_dask, run_pool, run_serial
from shinro_ctrl.sweep.result import SweepResult, SweepRow
from shinro_ctrl.sweep.spec import (
    MAX_ROWS,
    METHODS,
    STABLE_TOL_FACTOR,
    WALL_CLOCK_METRICS,
    check_keys,
    check_range,
    draw_samples,
    sweep_keys,
)
from shinro_ctrl.validation import did_you_mean

__all__ = ["run_sweep"]


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
    ranges = _check_args(method, samples, workers, metric, params, grid)
    doc, source = _load_doc(config, duration)
    scenario, notes = _parse_checked(doc, source, ranges)
    nominal = build_nominal(doc, source, engine)  # designs the controller
    tol = _stable_tol(scenario.sim.settle_tol, stable_tol)

    values = draw_samples(ranges, samples, grid=grid, seed=seed)
    names = tuple(k.removeprefix("plant.") for k in ranges)
    chosen = _choose_method(method, scheduler, workers, nominal, names, notes)
    base = SweepJob(doc, source, engine, names, (), (), tol)
    bar = Progress(values.shape[0], f"sweep {scenario.name}", progress, delay=0.0, unit="samples")
    timings: dict[str, float] = {}
    outcomes, used_workers = _execute(chosen, nominal, base, names, values, tol, bar, timings, workers, scheduler)

    rows = _rows(outcomes, values, ranges, timings)
    result = SweepResult(
        scenario=scenario.name if scenario.path is not None else f"{scenario.plant.type} + {scenario.controller.type}",
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


def _parse_checked(doc: dict[str, Any], source: str | None, ranges: Mapping[str, Any]) -> tuple[Any, list[str]]:
    """The parsed scenario, once every swept key is known to be one of its plant's parameters, and notes.

    A range with no valid plant value at either end (``pole_mass = -1:-0.5``, ``0:0``) is refused; a range
    with one invalid end runs, its invalid samples recorded as such, and a note says which end.
    """
    from shinro_ctrl.plants import plant_class

    scenario = parse_scenario(doc, source=source or "<dict>", path=Path(source) if source else None)
    cls = plant_class(scenario.plant.type)
    check_keys(ranges, sweep_keys(cls.from_config(scenario.plant.params)))
    notes = []
    for key, (lo, hi) in ranges.items():
        name = key.removeprefix("plant.")
        errors = {}
        for value in dict.fromkeys((lo, hi)):
            try:
                cls.from_config({**scenario.plant.params, name: value})
            except (ConfigError, InvalidArgument) as exc:
                errors[value] = str(exc)
        if len(errors) == len(dict.fromkeys((lo, hi))):
            raise ConfigError(f"sweep range {key} = {lo:g}:{hi:g} holds no valid plant value: {errors[lo]}")
        for value in errors:
            notes.append(f"{key} = {value:g} is not a valid plant value: samples there are recorded as invalid")
    return scenario, notes


def _stable_tol(settle_tol: float, stable_tol: float | None) -> float:
    """The stability band: ``STABLE_TOL_FACTOR × settle_tol`` unless given; positive and finite."""
    tol = STABLE_TOL_FACTOR * settle_tol if stable_tol is None else float(stable_tol)
    if not (math.isfinite(tol) and tol > 0):
        raise ConfigError(f"stable_tol must be positive and finite, got {stable_tol!r}")
    return tol


def _execute(
    chosen: str,
    nominal: Any,
    base: SweepJob,
    names: tuple[str, ...],
    values: np.ndarray,
    tol: float,
    bar: Progress,
    timings: dict[str, float],
    workers: int,
    scheduler: Any,
) -> tuple[list, int]:
    """Run every sample with the chosen executor; returns ``(outcomes, workers used)`` (the bar is closed)."""
    used_workers = 1 if chosen in ("serial", "batch") else workers
    try:
        if chosen == "batch":
            outcomes = run_batch(nominal, names, values, tol, bar, timings)
        elif chosen == "serial":
            outcomes = run_serial(nominal, base, values, bar)
        elif chosen == "pool":
            outcomes = run_pool(base, values, workers, bar)
        else:
            outcomes, used_workers = run_dask(base, values, scheduler, bar)
    finally:
        bar.close()
    return outcomes, used_workers


def _load_doc(config: str | Path | Mapping[str, Any], duration: float | None) -> tuple[dict[str, Any], str | None]:
    """The scenario document (a private copy) and its source path (None for a dict)."""
    if isinstance(config, Mapping):
        doc, source = copy.deepcopy(dict(config)), None
    else:
        scenario = load_scenario(config)
        doc, source = copy.deepcopy(scenario.raw), str(scenario.path)
    if duration is not None:
        doc.setdefault("sim", {})["duration"] = duration
    return doc, source


def _choose_method(
    method: str, scheduler: Any, workers: int, nominal: Any, names: tuple[str, ...], notes: list[str]
) -> str:
    """The executor that runs: ``method``, or what ``"auto"`` resolves to (a note when ``"batch"`` cannot run)."""
    if scheduler is not None and method in ("auto", "dask"):
        return "dask"
    if method == "dask":
        raise ConfigError("method 'dask' needs a scheduler address (--scheduler)")
    if method in ("auto", "batch"):
        reason = batch_reason(nominal, names)
        if reason is None:
            return "batch"
        chosen = "pool" if workers > 1 else "serial"
        if method == "batch":
            notes.append(f"batch rollout not used ({reason}); ran the per-sample loop ({chosen})")
        return chosen
    if method == "pool" and workers == 1:
        return "serial"
    return method


def _rows(
    outcomes: list[Any], values: np.ndarray, ranges: Mapping[str, Any], timings: dict[str, float]
) -> list[SweepRow]:
    """The table rows by sample index; the median of each wall-clock metric goes into ``timings``."""
    outcomes.sort(key=lambda o: o[0])
    rows = [
        SweepRow(i, {k: float(values[i, j]) for j, k in enumerate(ranges)}, metrics, stable, error, timing)
        for i, metrics, stable, error, timing in outcomes
    ]
    for key in WALL_CLOCK_METRICS:
        measured = [r.timing[key] for r in rows if math.isfinite(r.timing.get(key, math.nan))]
        timings[key] = float(np.median(measured)) if measured else math.nan
    return rows


def _check_args(
    method: str, samples: Any, workers: Any, metric: str, params: Mapping[str, Any], grid: bool
) -> dict[str, tuple[float, float]]:
    """Validate the sweep's arguments; return the checked ranges."""
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
    ranges = {str(k): check_range(str(k), v) for k, v in params.items()}
    if grid and samples ** len(ranges) > MAX_ROWS:
        raise ConfigError(f"a grid of {samples}^{len(ranges)} points is too large (max {MAX_ROWS})")
    return ranges
