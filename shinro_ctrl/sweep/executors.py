"""Running the samples: the perturbed sim of one sample, and the serial, process-pool, Dask and batch executors."""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl._interrupts import deferred_interrupts, forkserver_context, ignore_sigint, stop_pool
from shinro_ctrl.config import Scenario, parse_scenario
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.progress import Progress
from shinro_ctrl.sweep.spec import SAMPLE_ERRORS, TABLE_METRICS, WALL_CLOCK_METRICS

__all__ = [
    "Outcome",
    "SweepJob",
    "batch_reason",
    "build_nominal",
    "perturbed_sim",
    "run_batch",
    "run_dask",
    "run_pool",
    "run_serial",
]


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
    LQR) is shared as the very object. A controller with memory (MPC: OSQP
    warm starts and adaptive ``rho``) is designed again from the *nominal*
    plant with the scenario's options, so that a sample's result never
    depends on which samples ran before it in the same worker. An arm's IK
    controller is the arm's own IK, built with the sample's arm
    (:meth:`RobotSim.with_plant`).

    Args:
        nominal: The sim built from the nominal scenario.
        overrides: Plant constructor arguments to change, e.g. ``{"pole_mass": 0.3}``.

    Raises:
        ConfigError: an invalid value (e.g. a negative mass), naming the key.
    """
    from shinro_ctrl.controllers import controller_class

    scenario: Scenario = nominal.scenario
    sim = nominal.with_plant(dict(overrides))
    if nominal.controller.stateful and sim.controller is nominal.controller:  # memory: a fresh one per sample
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
Outcome = tuple[int, dict[str, float], bool, str | None, dict[str, float]]


def _nan_metrics() -> dict[str, float]:
    return dict.fromkeys(TABLE_METRICS, math.nan)


def _nan_timing() -> dict[str, float]:
    return dict.fromkeys(WALL_CLOCK_METRICS, math.nan)


def _run_one(nominal: Any, names: Sequence[str], index: int, values: Sequence[float], stable_tol: float) -> Outcome:
    overrides = {name: float(v) for name, v in zip(names, values, strict=True)}
    try:
        with np.errstate(all="ignore"):
            result = perturbed_sim(nominal, overrides).run(progress=False)
    except SAMPLE_ERRORS as exc:
        return index, _nan_metrics(), False, _error_text(exc), _nan_timing()
    finite = bool(np.all(np.isfinite(result.x)))
    metrics = {k: math.nan if result.metrics.get(k) is None else result.metrics[k] for k in TABLE_METRICS}  # table: NaN
    timing = {k: float(result.metrics.get(k, math.nan)) for k in WALL_CLOCK_METRICS}
    return index, metrics, _verdict(metrics, finite, stable_tol), None, timing


@dataclass(frozen=True)
class SweepJob:
    """What a worker needs: the scenario document and a chunk of parameter rows (picklable)."""

    doc: dict[str, Any]
    source: str | None
    engine: str | None
    names: tuple[str, ...]
    indices: tuple[int, ...]
    rows: tuple[tuple[float, ...], ...]
    stable_tol: float


_CACHE = threading.local()


def _nominal_for(job: SweepJob) -> Any:
    """The nominal sim of ``job``'s scenario, built once per worker thread."""
    key = (json.dumps(job.doc, sort_keys=True, default=str), job.source, job.engine)
    cached = getattr(_CACHE, "sim", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    sim = build_nominal(job.doc, job.source, job.engine)
    _CACHE.sim = (key, sim)
    return sim


def build_nominal(doc: Mapping[str, Any], source: str | None, engine: str | None) -> Any:
    from shinro_ctrl.sim import RobotSim

    path = Path(source) if source else None
    scenario = parse_scenario(doc, source=source or "<dict>", path=path)
    return RobotSim(scenario, engine=engine)


def _run_job(job: SweepJob) -> list[Outcome]:
    """Worker entry point: run a chunk of samples (module level, so it pickles by reference)."""
    nominal = _nominal_for(job)
    return [_run_one(nominal, job.names, i, row, job.stable_tol) for i, row in zip(job.indices, job.rows, strict=True)]


# ----------------------------------------------------------------- executors
def _chunks(indices: Sequence[int], size: int) -> list[Sequence[int]]:
    return [indices[i : i + size] for i in range(0, len(indices), size)]


def _jobs(base: SweepJob, values: np.ndarray, n_tasks: int) -> list[SweepJob]:
    S = values.shape[0]
    size = max(1, math.ceil(S / max(n_tasks, 1)))
    jobs = []
    for idx in _chunks(range(S), size):
        rows = tuple(tuple(float(x) for x in values[i]) for i in idx)
        jobs.append(SweepJob(base.doc, base.source, base.engine, base.names, tuple(idx), rows, base.stable_tol))
    return jobs


def run_serial(nominal: Any, base: SweepJob, values: np.ndarray, bar: Progress) -> list[Outcome]:
    out = []
    for i, row in enumerate(values):
        out.append(_run_one(nominal, base.names, i, row, base.stable_tol))
        bar.update(i + 1)
    return out


_POOL_PRELOAD = [
    "shinro_ctrl.sweep.executors",
    "shinro_ctrl.sim",
    "shinro_ctrl.plants",
    "shinro_ctrl.controllers",
    "shinro_ctrl.engine",
    "control",
]


def run_pool(base: SweepJob, values: np.ndarray, workers: int, bar: Progress) -> list[Outcome]:
    # forkserver, started with SIGINT blocked: its workers never see a Ctrl-C (not even while importing), the
    # preloaded imports are paid once, and forking from a clean server is safe when this process runs threads.
    ctx = forkserver_context(_POOL_PRELOAD)
    jobs = _jobs(base, values, workers * 4)
    out: list[Outcome] = []
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=ignore_sigint)
    try:
        # Ctrl-C is held while the workers start (submit starts them), so every started worker is registered
        # and can be stopped; it is raised right after.
        with deferred_interrupts():
            futures = [pool.submit(_run_job, job) for job in jobs]
        broken: list[SweepJob] = []
        by_future = dict(zip(futures, jobs, strict=True))
        for fut in as_completed(futures):
            try:
                out.extend(fut.result())
            except BrokenProcessPool:  # a worker died (OOM killer, a signal): this chunk is run again below
                broken.append(by_future[fut])
            bar.update(len(out))
        pool.shutdown(wait=True)
        for job in broken:  # one sample at a time, each in a fresh worker: the one that kills it is named
            for i, row in zip(job.indices, job.rows, strict=True):
                one = SweepJob(job.doc, job.source, job.engine, job.names, (i,), (row,), job.stable_tol)
                out.extend(_isolated(ctx, one))
                bar.update(len(out))
    except BaseException:  # Ctrl-C (or an error): stop the workers now, not after their queued chunks
        stop_pool(pool)
        raise
    return out


#: The error recorded for a sample whose worker process died while running it.
WORKER_DIED = "WorkerDied: the worker process died while running this sample (killed, e.g. by the out-of-memory killer)"


def _isolated(ctx: Any, job: SweepJob) -> list[Outcome]:
    """One sample in a fresh one-worker pool: its outcome, or :data:`WORKER_DIED` if it kills the worker."""
    pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=ignore_sigint)
    try:
        with deferred_interrupts():  # the worker starts here
            future = pool.submit(_run_job, job)
        out = future.result()
    except BrokenProcessPool:
        out = [(job.indices[0], _nan_metrics(), False, WORKER_DIED, _nan_timing())]
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return out


def run_dask(base: SweepJob, values: np.ndarray, scheduler: Any, bar: Progress) -> tuple[list[Outcome], int]:
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
        out: list[Outcome] = []
        for fut in dask_completed(futures, loop=client.loop):
            out.extend(fut.result())
            bar.update(len(out))
        return out, threads
    finally:
        if own:
            client.close()


def batch_reason(nominal: Any, names: Sequence[str]) -> str | None:
    """Why the batch rollout cannot run this sweep (None if it can)."""
    from shinro_ctrl.sweep.batch import batch_unsupported_reason

    reason = batch_unsupported_reason(nominal.plant, nominal.controller)
    if reason is not None:
        return reason
    sim = nominal.scenario.sim
    if nominal.reference.kind != "constant":
        return f"the reference is {nominal.reference.kind!r}, not constant"
    if sim.measurement_noise and any(v != 0 for v in sim.measurement_noise):
        return "the scenario adds measurement noise"
    if type(nominal.estimator).__name__ != "FullState" or sim.measured is not None:
        return "the controller sees an estimate (output feedback)"
    if sim.sensor_noise or sim.process_noise or sim.disturbance:
        return "the scenario adds sensor or process noise or a disturbance"
    if sim.actuator or sim.sensor:
        return "the scenario has a non-ideal actuator or sensor ([sim] actuator / sensor)"
    missing = [n for n in names if n not in nominal.plant.param_names]
    if missing:  # pragma: no cover - implied by batch_unsupported_reason
        return f"{missing[0]!r} is not a dynamics parameter"
    return None


def run_batch(
    nominal: Any, names: Sequence[str], values: np.ndarray, stable_tol: float, bar: Progress, timings: dict[str, float]
) -> list[Outcome]:
    from shinro_ctrl.plants import plant_class
    from shinro_ctrl.sweep.batch import lqr_batch_rollout

    scenario: Scenario = nominal.scenario
    cls = plant_class(scenario.plant.type)
    S = values.shape[0]
    outcomes: dict[int, Outcome] = {}
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
