"""LQR weight trade-off: what a faster loop costs in input, margin and damping.

``shinro-ctrl design lqr CONFIG --tradeoff KEY=LO:HI --points N`` sweeps one
weight over ``N`` log-spaced values. For each value it designs the LQR on the
scenario's plant, computes the loop margins and the closed-loop damping
(:mod:`shinro_ctrl.analysis`), and runs the scenario's nonlinear closed loop
(standalone, or MuJoCo with ``engine="mujoco"``). Keys:

* ``R`` / ``Q``: the scenario's whole matrix times the value (a multiplier);
* ``R[i]``, ``Q[i]`` or ``Q.theta`` (a state name), ``R.force`` (an input
  name): the diagonal entry itself takes the value.

Points run in a local process pool (``forkserver`` workers, as
:mod:`shinro_ctrl.sweep`); each worker parses the scenario once. The table
depends only on the scenario, the key, the range and ``points``: never on
the worker count. Outputs (``out``): ``tradeoff.csv`` (one row per point),
``tradeoff.json`` (rows, the scenario's current design, the elapsed time)
and ``tradeoff.png`` (tracking RMS against peak input, coloured by disk
margin, the Pareto front joined, the current design starred), written as
one set (all three new or all three old, even if killed).
"""

from __future__ import annotations

import copy
import csv
import io
import math
import re
import time
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl._interrupts import deferred_interrupts, forkserver_context, ignore_sigint, stop_pool
from shinro_ctrl.config import load_scenario
from shinro_ctrl.errors import InvalidArgument, ShinroError
from shinro_ctrl.files import atomic_folder, atomic_write, dump_json

__all__ = ["COLUMNS", "MAX_POINTS", "MAX_WORKERS", "OUTPUT_FILES", "TradeoffResult", "parse_tradeoff", "run_tradeoff"]

#: Largest number of trade-off points (each a design, an analysis and a nonlinear run).
MAX_POINTS = 1_000
#: Largest number of worker processes.
MAX_WORKERS = 256

#: The files a trade-off writes into its ``out`` folder.
OUTPUT_FILES = ("tradeoff.csv", "tradeoff.json", "tradeoff.png")

#: Columns of ``tradeoff.csv`` after the swept value.
COLUMNS = (
    "gain_margin_low",
    "gain_margin_high",
    "phase_margin_deg",
    "disk_margin",
    "Ms",
    "zeta_min",
    "wn_max",
    "rms_error",
    "max_abs_input",
    "settling_time",
    "overshoot",
    "rise_time",
)
_KEY = re.compile(r"^(Q|R)(?:\[(\d+)\]|\.([A-Za-z_][\w]*))?$")
#: Exceptions a point may raise that are recorded in its row (anything else is a bug and propagates).
POINT_ERRORS: tuple[type[BaseException], ...] = (ShinroError, ValueError, ArithmeticError, np.linalg.LinAlgError)


def parse_tradeoff(text: str) -> tuple[str, float, float]:
    """``"R=1e-3:1e2"`` → ``("R", 0.001, 100.0)``.

    Raises:
        InvalidArgument: not ``KEY=LO:HI``, a key other than ``Q``, ``R``,
            ``Q[i]``, ``R[i]``, ``Q.name``, ``R.name``, or a range that is not
            ``0 < LO < HI`` (finite).
    """
    if not isinstance(text, str) or "=" not in text or ":" not in text.split("=", 1)[1]:
        raise InvalidArgument(f"--tradeoff: expected KEY=LO:HI such as R=1e-3:1e2, got {text!r}")
    key, rng = text.split("=", 1)
    key = key.strip()
    if not _KEY.match(key):
        raise InvalidArgument(f"--tradeoff: key must be Q, R, Q[i], R[i] or Q.<state>, got {key!r}")
    lo_s, hi_s = rng.split(":", 1)
    try:
        lo, hi = float(lo_s), float(hi_s)
    except ValueError:
        raise InvalidArgument(f"--tradeoff: LO and HI must be numbers, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise InvalidArgument(f"--tradeoff: expected 0 < LO < HI (log-spaced), got {lo:g}:{hi:g}")
    return key, lo, hi


def _weight(doc: Mapping[str, Any], which: str, size: int) -> np.ndarray:
    from shinro_ctrl.validation import weight_matrix

    value = doc["controller"].get(which)
    if value is None:
        raise InvalidArgument(f"--tradeoff: the scenario's [controller] has no {which}")
    return weight_matrix(which, value, size, definite=which == "R")


def _apply(doc: dict[str, Any], key: str, value: float, names: tuple[tuple[str, ...], tuple[str, ...]]) -> dict:
    """A copy of the (parsed, Bryson-resolved) document with the weight ``key`` set by ``value``."""
    m = _KEY.match(key)
    which, index, name = m.group(1), m.group(2), m.group(3)
    labels = names[0] if which == "Q" else names[1]
    W = _weight(doc, which, len(labels))
    if index is None and name is None:
        W = W * value
    else:
        if name is not None:
            if name not in labels:
                raise InvalidArgument(f"--tradeoff: unknown {'state' if which == 'Q' else 'input'} '{name}' in {key}")
            i = labels.index(name)
        else:
            i = int(index)
            if i >= len(labels):
                raise InvalidArgument(f"--tradeoff: {key} is out of range ({which} is {len(labels)} × {len(labels)})")
        W = W.copy()
        W[i, i] = value
    out = copy.deepcopy(doc)
    out["controller"][which] = W.tolist()
    return out


@dataclass(frozen=True)
class _Job:
    doc: dict[str, Any]
    source: str | None
    engine: str | None
    key: str
    values: tuple[float, ...]
    indices: tuple[int, ...]


def _evaluate(doc: dict[str, Any], source: str | None, engine: str | None) -> dict[str, float]:
    """Design, analyse and run one weight setting."""
    from shinro_ctrl.analysis.design import feedback_gain
    from shinro_ctrl.analysis.margins import loop_margins
    from shinro_ctrl.analysis.poles import pole_table
    from shinro_ctrl.config import parse_scenario
    from shinro_ctrl.sim import RobotSim

    path = Path(source) if source else None
    sim = RobotSim(parse_scenario(doc, source=source or "<dict>", path=path), engine=engine)
    A, B, K, dt = feedback_gain(sim.controller)
    lm = loop_margins((A, B), K, dt=dt)
    poles = pole_table(np.linalg.eigvals(A - B @ K), dt)
    with np.errstate(all="ignore"):
        metrics = sim.run(progress=False).metrics
    return {
        "gain_margin_low": min(c.gain_margin_low for c in lm.channels),
        "gain_margin_high": min(c.gain_margin_high for c in lm.channels),
        "phase_margin_deg": min(c.phase_margin for c in lm.channels),
        "disk_margin": lm.disk_margin,
        "Ms": lm.Ms,
        "zeta_min": poles.zeta_min,
        "wn_max": poles.wn_range[1],
        "rms_error": metrics["rms_error"],
        "max_abs_input": metrics["max_abs_input"],
        "settling_time": math.nan if metrics["settling_time"] is None else metrics["settling_time"],  # table: NaN
        "overshoot": metrics.get("overshoot", math.nan),
        "rise_time": math.nan if metrics.get("rise_time") is None else metrics["rise_time"],
    }


def _names(doc: Mapping[str, Any]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    from shinro_ctrl.plants import plant_class

    pt = dict(doc["plant"])
    plant = plant_class(str(pt.pop("type"))).from_config(pt)
    return tuple(plant.state_names), tuple(plant.input_names)


def _run_job(job: _Job) -> list[tuple[int, dict[str, float], str]]:
    """Worker entry point (module level, so it pickles by reference)."""
    names = _names(job.doc)
    out = []
    for i, v in zip(job.indices, job.values, strict=True):
        try:
            out.append((i, _evaluate(_apply(job.doc, job.key, v, names), job.source, job.engine), ""))
        except POINT_ERRORS as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            out.append((i, dict.fromkeys(COLUMNS, math.nan), f"{type(exc).__name__}: {msg}"))
    return out


@dataclass
class TradeoffResult:
    """The trade-off table.

    Attributes:
        key: The swept weight (``"R"``, ``"Q[2]"``, ``"Q.theta"``, …).
        values: Swept values ``(N,)``, increasing.
        rows: Per point, :data:`COLUMNS` → value (NaN where the point failed).
        errors: Per point, the error text ("" when it succeeded).
        current: The scenario's own design (same columns), and ``current_value``
            its value of the key (1 for a multiplier).
        engine: ``"standalone"`` or ``"mujoco"``.
        elapsed_s: Wall time of the sweep [s].
        paths: Files written (when ``out`` was given).
    """

    key: str
    values: np.ndarray
    rows: list[dict[str, float]]
    errors: list[str]
    current: dict[str, float]
    current_value: float
    engine: str
    elapsed_s: float = 0.0
    paths: dict[str, Path] = field(default_factory=dict)

    @property
    def multiplier(self) -> bool:
        """True when the key scales a whole matrix (``Q``, ``R``) rather than setting one entry."""
        return self.key in ("Q", "R")

    def column(self, name: str) -> np.ndarray:
        """One column ``(N,)``."""
        return np.array([r[name] for r in self.rows], dtype=float)

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow([self.key, *COLUMNS, "error"])
        for v, r, e in zip(self.values, self.rows, self.errors, strict=True):
            w.writerow([repr(float(v)), *(repr(float(r[c])) for c in COLUMNS), e])
        return buf.getvalue()

    def to_dict(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "engine": self.engine,
            "columns": [self.key, *COLUMNS],
            "rows": [
                {self.key: float(v), **r, "error": e}
                for v, r, e in zip(self.values, self.rows, self.errors, strict=True)
            ],
            "current": {self.key: self.current_value, **self.current},
            "elapsed_s": self.elapsed_s,
        }

    def plot(self, path: str | Path) -> Path:
        """Tracking RMS against peak input, coloured by disk margin (PNG)."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(7.5, 5.2), dpi=110, layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        x, y, c = self.column("max_abs_input"), self.column("rms_error"), self.column("disk_margin")
        ok = np.isfinite(x) & np.isfinite(y)
        front = _pareto(x, y, ok)
        ax.plot(x[front], y[front], color="0.6", lw=1.0, zorder=1, label="Pareto front")
        sc = ax.scatter(x[ok], y[ok], c=c[ok], cmap="viridis", s=46, edgecolors="k", linewidths=0.5, zorder=2)
        fig.colorbar(sc, ax=ax, label="disk margin α (simultaneous)")
        idx = np.flatnonzero(ok)
        sym = "×" if self.multiplier else "="
        for k in idx[:: max(1, len(idx) // 6)]:
            ax.annotate(
                f"{self.key}{sym}{self.values[k]:.3g}",
                (x[k], y[k]),
                xytext=(6, 4),
                textcoords="offset points",
                fontsize=7,
            )
        cur = self.current
        if math.isfinite(cur.get("max_abs_input", math.nan)) and math.isfinite(cur.get("rms_error", math.nan)):
            ax.plot(
                [cur["max_abs_input"]],
                [cur["rms_error"]],
                "*",
                color="tab:red",
                ms=16,
                mec="k",
                zorder=3,
                label=f"scenario's design ({self.key}{sym}{self.current_value:.3g})",
            )
        if ok.any() and np.nanmax(x[ok]) / max(np.nanmin(x[ok]), 1e-300) > 20:
            ax.set_xscale("log")
        if ok.any() and np.nanmax(y[ok]) / max(np.nanmin(y[ok]), 1e-300) > 20:
            ax.set_yscale("log")
        ax.set_xlabel("peak input max |u|")
        ax.set_ylabel("tracking RMS error")
        what = f"{self.key} × the scenario's" if self.multiplier else self.key
        ax.set_title(f"LQR trade-off over {what} ({len(self.values)} points, {self.engine} loop)")
        ax.grid(True, color="0.88", lw=0.6)
        ax.legend(fontsize=8, loc="upper right")
        from shinro_ctrl.plots._figure import save_figure

        return save_figure(fig, path)

    def save(self, directory: str | Path) -> dict[str, Path]:
        """Write ``tradeoff.csv``, ``tradeoff.json`` and ``tradeoff.png`` into ``directory`` as one set.

        The three files are built in a hidden folder swapped into place in one step
        (:func:`~shinro_ctrl.files.atomic_folder`, as ``run --out``): a kill leaves the
        previous set or the new one, never a mix. Only a new or empty folder, or one
        an earlier save wrote, is replaced.

        Raises:
            InvalidArgument: ``directory`` is a folder shinro-ctrl did not write or a symbolic link.
        """
        d = Path(directory)
        text = self.to_csv()
        with atomic_folder(d, OUTPUT_FILES) as staging:
            atomic_write(staging / "tradeoff.csv", lambda f: f.write(text))
            dump_json(staging / "tradeoff.json", self.to_dict())
            self.plot(staging / "tradeoff.png")
        self.paths = {"csv": d / "tradeoff.csv", "json": d / "tradeoff.json", "png": d / "tradeoff.png"}
        return self.paths

    def summary(self) -> str:
        """A text table of the sweep."""
        head = (
            f"  {self.key:>10s} {'rms err':>9s} {'max|u|':>9s} {'disk α':>7s} {'PM [°]':>7s} {'ζ_min':>6s} {'Ms':>6s}"
        )
        lines = [f"trade-off over {self.key}, {len(self.values)} points ({self.engine}), {self.elapsed_s:.2f} s", head]
        for v, r, e in zip(self.values, self.rows, self.errors, strict=True):
            if e:
                lines.append(f"  {v:10.4g}  failed: {e}")
                continue
            lines.append(
                f"  {v:10.4g} {r['rms_error']:9.4g} {r['max_abs_input']:9.4g} {r['disk_margin']:7.3f} "
                f"{r['phase_margin_deg']:7.1f} {r['zeta_min']:6.3f} {r['Ms']:6.3f}"
            )
        for k, p in self.paths.items():
            lines.append(f"  {k}: {p}")
        return "\n".join(lines)


def _pareto(x: np.ndarray, y: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats in both (smaller x and smaller y), sorted by x."""
    idx = [
        i
        for i in np.flatnonzero(ok)
        if not any(x[j] <= x[i] and y[j] <= y[i] and (x[j] < x[i] or y[j] < y[i]) for j in np.flatnonzero(ok))
    ]
    return np.array(sorted(idx, key=lambda i: x[i]), dtype=int)


_POOL_PRELOAD = [
    "shinro_ctrl.analysis.tradeoff",
    "shinro_ctrl.sim",
    "shinro_ctrl.plants",
    "shinro_ctrl.controllers",
    "control",
]


def run_tradeoff(
    config: str | Path,
    key: str,
    lo: float,
    hi: float,
    *,
    points: int = 20,
    engine: str | None = None,
    out: str | Path | None = None,
    workers: int = 2,
) -> TradeoffResult:
    """Sweep one LQR weight over ``points`` log-spaced values (see the module docstring).

    Args:
        config: Scenario path or shipped name (an LQR scenario).
        key: ``"R"``, ``"Q"`` (multipliers), ``"Q[i]"``, ``"R[i]"``, ``"Q.<state>"``, ``"R.<input>"`` (entries).
        lo, hi: Range, ``0 < lo < hi``.
        points: Number of values, 2 to :data:`MAX_POINTS`.
        engine: ``"standalone"``, ``"mujoco"``, or None (the scenario's loop).
        out: Folder for ``tradeoff.csv``, ``tradeoff.json`` and ``tradeoff.png``.
        workers: Local worker processes (1: in this process).

    Raises:
        InvalidArgument: a bad key, range, point count or worker count; a scenario whose controller is not an LQR.
    """
    parse_tradeoff(f"{key}={lo!r}:{hi!r}")
    if isinstance(points, bool) or not isinstance(points, int) or not 2 <= points <= MAX_POINTS:
        raise InvalidArgument(f"points must be an integer in [2, {MAX_POINTS:,}] (the limit), got {points!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise InvalidArgument(f"workers must be an integer in [1, {MAX_WORKERS}] (the limit), got {workers!r}")
    scenario = load_scenario(config)
    if scenario.controller.type != "LQR":
        raise InvalidArgument(
            f"{scenario.name}: the trade-off sweeps LQR weights, the scenario has {scenario.controller.type}"
        )
    doc = copy.deepcopy(scenario.raw)
    doc["controller"] = {"type": "LQR", **scenario.controller.options}  # Bryson tables resolved
    source = str(scenario.path) if scenario.path else None
    names = _names(doc)
    _apply(doc, key, lo, names)  # a bad key fails here, before any work
    values = np.logspace(math.log10(lo), math.log10(hi), points)
    loop = engine or ("mujoco" if scenario.engine is not None else "standalone")
    current_value = _current_value(doc, key, names)

    t0 = time.perf_counter()
    n_tasks = min(points, workers * 2) if workers > 1 else 1
    chunks = np.array_split(np.arange(points), n_tasks)
    jobs = [
        _Job(doc, source, engine, key, tuple(float(values[i]) for i in c), tuple(int(i) for i in c)) for c in chunks
    ]
    results, current = _run_jobs(jobs, doc, source, engine, workers)
    result = TradeoffResult(
        key,
        values,
        [r[1] for r in results],
        [r[2] for r in results],
        current,
        current_value,
        loop,
        time.perf_counter() - t0,
    )
    if out is not None:
        result.save(out)
    return result


def _current_value(doc: dict[str, Any], key: str, names: Any) -> float:
    """The scenario's own value of the swept weight: 1 for a multiplier, else the diagonal entry."""
    m = _KEY.match(key)
    if m.group(2) is None and m.group(3) is None:
        return 1.0
    which = m.group(1)
    labels = names[0] if which == "Q" else names[1]
    i = int(m.group(2)) if m.group(2) is not None else labels.index(m.group(3))
    return float(_weight(doc, which, len(labels))[i, i])


def _run_jobs(
    jobs: list[_Job], doc: dict[str, Any], source: str | None, engine: str | None, workers: int
) -> tuple[list[tuple[int, dict[str, float], str]], Any]:
    """Run the chunks (in this process or a forkserver pool) and the scenario's own weights.

    Returns:
        ``(results sorted by point index, the scenario's own metrics)``.
    """
    results: list[tuple[int, dict[str, float], str]] = []
    if workers == 1:
        for job in jobs:
            results.extend(_run_job(job))
        current = _evaluate(doc, source, engine)
    else:
        results, current = _run_pool(_run_job, jobs, workers, (doc, source, engine))
    results.sort(key=lambda r: r[0])
    return results, current


#: The error recorded for a point whose worker process died while running it.
WORKER_DIED = "WorkerDied: the worker process died while running this point (killed, e.g. by the out-of-memory killer)"


def _run_pool(
    run_job: Any, jobs: list[_Job], workers: int, current_args: tuple[Any, ...]
) -> tuple[list[tuple[int, dict[str, float], str]], Any]:
    """The chunks in a forkserver pool whose workers ignore Ctrl-C (the parent stops them, without tracebacks).

    A worker that dies (``BrokenProcessPool``: killed by the OOM killer or a signal) breaks every chunk still
    in the pool; those chunks are run again one point at a time, each in a fresh worker, so the point that
    kills its worker is named (:data:`WORKER_DIED`) and every other point keeps its result.
    """
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    ctx = forkserver_context(_POOL_PRELOAD)  # its workers never see a Ctrl-C, not even while importing
    results: list[tuple[int, dict[str, float], str]] = []
    broken: list[_Job] = []
    current: Any = None
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=ignore_sigint)
    try:
        with deferred_interrupts():  # the workers start here: each is registered before a Ctrl-C is raised
            futures = {pool.submit(run_job, job): job for job in jobs}
            cur_future = pool.submit(_evaluate, *current_args)
        for f in as_completed(futures):
            try:
                results.extend(f.result())
            except BrokenProcessPool:
                broken.append(futures[f])
        try:
            current = cur_future.result()
        except BrokenProcessPool:
            current = None
        pool.shutdown(wait=True)
        for job in broken:
            for i, v in zip(job.indices, job.values, strict=True):
                one = _Job(job.doc, job.source, job.engine, job.key, (v,), (i,))
                results.extend(_isolated(ctx, run_job, one))
        if current is None:
            current = _isolated_current(ctx, current_args)
    except BaseException:  # Ctrl-C (or an error): stop the workers now, not after their queued chunks
        stop_pool(pool)
        raise
    return results, current


def _isolated(ctx: Any, run_job: Any, job: _Job) -> list[tuple[int, dict[str, float], str]]:
    """One point in a fresh one-worker pool: its result, or :data:`WORKER_DIED` if it kills the worker."""
    from concurrent.futures.process import BrokenProcessPool

    pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=ignore_sigint)
    try:
        with deferred_interrupts():  # the worker starts here
            future = pool.submit(run_job, job)
        out = future.result()
    except BrokenProcessPool:
        out = [(job.indices[0], dict.fromkeys(COLUMNS, math.nan), WORKER_DIED)]
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return out


def _isolated_current(ctx: Any, current_args: tuple[Any, ...]) -> dict[str, float]:
    from concurrent.futures.process import BrokenProcessPool

    pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=ignore_sigint)
    try:
        with deferred_interrupts():  # the worker starts here
            future = pool.submit(_evaluate, *current_args)
        current = future.result()
    except BrokenProcessPool:
        current = dict.fromkeys(COLUMNS, math.nan)  # the scenario's own design: not starred on the plot
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return current
