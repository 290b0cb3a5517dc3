"""``shinro-ctrl export``: record the Python loop, write the C folder, build and verify it, then move it in place.

:func:`export_scenario` runs the scenario's closed loop in both loops (standalone and MuJoCo, when the
plant has a model) with the Python controller for at least :data:`MIN_STEPS` steps in all, adds a run
from a larger initial deviation when no recorded step reached an input bound of a bounded controller,
writes the folder (:func:`~shinro_ctrl.export.assemble.assemble`) into a temporary sibling of ``--out``,
builds it with the system compiler, checks that its controller objects use no heap, runs its test program
(C equals Python to the tolerance on every recorded step) and only then renames it to ``--out``.
"""

from __future__ import annotations

import keyword
import os
import re
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.errors import ExportError, InvalidArgument, ShinroError
from shinro_ctrl.export.assemble import EXPORT_FORMAT, Recording, Unit, assemble
from shinro_ctrl.export.build import BuildResult, build_and_verify
from shinro_ctrl.export.registry import ExportContext, exporter_for
from shinro_ctrl.sim.metrics import at_bounds

if TYPE_CHECKING:
    from shinro_ctrl.sim import RobotSim

__all__ = ["MIN_STEPS", "ExportReport", "check_name", "export_scenario", "prepare", "record_run", "replay_drift"]

#: Closed-loop steps recorded in all (split over the loops).
MIN_STEPS = 1000

_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if inline int long "
    "register restrict return short signed sizeof static struct switch typedef union unsigned void volatile while "
    "main".split()
)


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export_scenario` did.

    Attributes:
        out: The folder written.
        name: The C name.
        files: File names written.
        steps: Recorded steps per run label.
        clamped_steps: Recorded steps whose Python input lay on a bound.
        python_step_s: Median seconds per Python step (estimator update + controller call).
        build: The build and replay result (None with ``verify=False``).
    """

    out: Path
    name: str
    files: tuple[str, ...]
    steps: dict[str, int]
    clamped_steps: int
    python_step_s: float
    build: BuildResult | None


def check_name(name: str) -> str:
    """A valid C identifier for the export (letters, digits, underscores; not a C keyword).

    Raises:
        InvalidArgument: anything else.
    """
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,39}", name) or name in _C_KEYWORDS or keyword.iskeyword(name):
        raise InvalidArgument(
            f"--name: expected a C identifier of at most 40 letters, digits and underscores (not a C keyword), "
            f"got {name!r}"
        )
    return name


def _default_name(config: str | Path) -> str:
    stem = re.sub(r"[^A-Za-z0-9_]", "_", Path(str(config)).stem) or "controller"
    return stem if not stem[0].isdigit() else "c_" + stem


def _versions() -> dict[str, str]:
    out = {}
    for pkg in ("shinro_ctrl", "casadi", "numpy", "scipy", "mujoco"):
        try:
            out[pkg] = metadata.version(pkg.replace("_", "-"))
        except metadata.PackageNotFoundError:
            try:
                out[pkg] = metadata.version(pkg)
            except metadata.PackageNotFoundError:
                out[pkg] = "not installed"
    return out


def _sims(config: str | Path) -> list[RobotSim]:
    """The scenario's sim in each loop it can run in: standalone, and MuJoCo when the plant has a model."""
    from shinro_ctrl.sim import RobotSim

    sims = [RobotSim.from_config(config, engine="standalone")]
    if sims[0].plant.asset is not None or sims[0].scenario.engine is not None:
        sims.append(RobotSim.from_config(config, engine="mujoco"))
    return sims


def _initial_estimate(sim: RobotSim, x_start: np.ndarray) -> np.ndarray:
    """The estimate the loop resets its estimator to (``sim/robot.py``: the scenario's, else the true state)."""
    x0 = sim.initial_estimate if sim.initial_estimate is not None else x_start
    return np.asarray(x0, dtype=float)[: sim.plant.state_dim].copy()


def record_run(sim: RobotSim, steps: int, label: str) -> Recording:
    """Run ``sim``'s closed loop with the Python controller for ``steps`` steps and keep what the C replays."""
    res = sim.run(steps * sim.plant.dt, progress=False)
    return Recording(label, _initial_estimate(sim, res.x[0]), res.y[:-1].copy(), res.ref[:-1].copy(), res.u.copy())


def _clamped(rec: Recording, u_min: np.ndarray | None, u_max: np.ndarray | None) -> int:
    if u_min is None or u_max is None:
        return 0
    at_lo, at_hi = at_bounds(rec.u, u_min, u_max)  # within the run metrics' band (a QP's bound is met to ~1e-14)
    return int(np.count_nonzero(np.any(at_lo | at_hi, axis=1)))


def _saturating_run(sim: RobotSim, steps: int) -> Recording | None:
    """A standalone run from a larger initial deviation (×2, ×4, ×8) that reaches an input bound, or None."""
    ctrl = sim.controller
    start = np.asarray(sim.initial_state, dtype=float).copy()
    op = sim.operating_point
    for scale in (2.0, 4.0, 8.0):
        sim.initial_state = op + scale * (start - op)
        try:
            rec = record_run(sim, steps, f"standalone_x{scale:g}")
        except ShinroError:
            continue
        finally:
            sim.initial_state = start
        if _clamped(rec, ctrl.u_min, ctrl.u_max) > 0:
            return rec
    return None


def _python_step_time(sim: RobotSim, rec: Recording) -> float:
    """Median wall time [s] of one Python step (estimator update and controller call) replaying ``rec``."""
    est, ctrl = sim.estimator, sim.controller
    ctrl.reset()
    est.reset(rec.x_hat0, sim.initial_covariance)
    u_prev = _u_init(sim)
    times = []
    clock = time.perf_counter
    for k in range(rec.y.shape[0]):
        t0 = clock()
        x_hat = est.update(rec.y[k], u_prev)
        u = ctrl(x_hat, rec.ref[k])
        times.append(clock() - t0)
        u_prev = u
    return statistics.median(times)


def _replay(sim: RobotSim, rec: Recording, x_hat0: np.ndarray) -> np.ndarray:
    """The Python estimator and controller replaying ``rec`` open loop from ``x_hat0``: the inputs ``(T, m)``."""
    est, ctrl = sim.estimator, sim.controller
    ctrl.reset()
    est.reset(x_hat0, sim.initial_covariance)
    u_prev = _u_init(sim)
    out = np.empty_like(rec.u)
    for k in range(rec.y.shape[0]):
        u_prev = out[k] = ctrl(est.update(rec.y[k], u_prev), rec.ref[k])
    return out


def replay_drift(sim: RobotSim, recordings: list[Recording], *, eps: float = 1e-15) -> float:
    """How far the Python replay drifts when its initial estimate moves by ``eps`` (relative): its own sensitivity.

    An estimator and controller whose combined (open-loop) dynamics have an unstable mode (an LQG compensator
    often has one) amplify a rounding difference by that mode every step; the C replays the recording open
    loop too, so C and Python then drift apart although both compute the same law. Returns
    ``max |Δu| / max(1, |u|)`` over the recordings.
    """
    worst = 0.0
    for rec in recordings:
        base = _replay(sim, rec, rec.x_hat0)
        moved = _replay(sim, rec, rec.x_hat0 + eps * np.maximum(1.0, np.abs(rec.x_hat0)))
        worst = max(worst, float(np.max(np.abs(moved - base) / np.maximum(1.0, np.abs(base)))))
    return worst


def _u_init(sim: RobotSim) -> np.ndarray:
    """The input the loop assumes before the first step: the controller's ``u0``, else the plant's equilibrium."""
    u0 = sim.controller.u0
    if u0 is not None and np.shape(u0) == (sim.plant.input_dim,):
        return np.asarray(u0, dtype=float).copy()
    return np.asarray(sim.plant.equilibrium()[1], dtype=float).copy()


def prepare(config: str | Path, name: str | None = None) -> tuple[Unit, list[Recording], float, int, RobotSim]:
    """Record the loops and build the :class:`Unit` (no file written).

    Returns:
        ``(unit, recordings, python_step_s, clamped_steps, sim)`` (``sim``: the standalone sim recorded from).

    Raises:
        ExportError: the controller or estimator cannot be exported (why, in one line).
    """
    from shinro_ctrl.config import load_scenario

    scenario = load_scenario(config)
    if scenario.controller.type == "Exported":
        raise ExportError("the scenario's controller is already an exported one; export the scenario it came from")
    name = check_name(name) if name is not None else check_name(_default_name(config))
    sims = _sims(config)
    sim = sims[0]
    plant, ctrl, est = sim.plant, sim.controller, sim.estimator
    if int(getattr(ctrl, "preview", 0)) and sim.reference.kind != "constant":
        raise ExportError(
            f"cannot export {type(ctrl).__name__} tracking a moving reference with preview: the exported step "
            "takes one set-point reference per step"
        )
    x_hat_dim = sim.estimator.n if not hasattr(est, "n_aug") else int(est.n_aug)
    ref0 = np.asarray(sim.reference(0.0), dtype=float)
    if sim.initial_estimate is not None:
        x_hat0 = np.asarray(sim.initial_estimate, dtype=float)[: plant.state_dim]
    else:
        x_hat0 = np.asarray(sim.initial_state, dtype=float)
    ctx = ExportContext(name, plant, ctrl, est, x_hat_dim, sim.initial_covariance, x_hat0.copy(), ref0.copy())
    est_part = exporter_for(est, "estimator").part(est, ctx)
    ctl_part = exporter_for(ctrl, "controller").part(ctrl, ctx)
    per_loop = -(-MIN_STEPS // len(sims))
    recordings = []
    for s in sims:
        steps = max(per_loop, round(s.scenario.sim.duration / s.plant.dt))
        recordings.append(record_run(s, steps, s.loop))
    clamped = sum(_clamped(r, ctrl.u_min, ctrl.u_max) for r in recordings)
    if clamped == 0 and ctrl.u_min is not None and np.any(np.isfinite(np.r_[ctrl.u_min, ctrl.u_max])):
        extra = _saturating_run(sim, min(per_loop, 500))
        if extra is not None:
            recordings.append(extra)
            clamped += _clamped(extra, ctrl.u_min, ctrl.u_max)
    py_time = _python_step_time(sim, recordings[0])
    path = scenario.path
    text = Path(path).read_text(encoding="utf-8") if path is not None else repr(scenario)
    measured = tuple(plant.state_names[i] for i in est.measured)
    unit = Unit(
        name=name,
        estimator=est_part,
        controller=ctl_part,
        n=plant.state_dim,
        m=plant.input_dim,
        p=len(est.measured),
        dt=float(plant.dt),
        x_hat0=x_hat0,
        u_init=_u_init(sim),
        ref0=ref0,
        measured=measured,
        state_names=tuple(plant.state_names),
        input_names=tuple(plant.input_names),
        scenario_text=text,
        scenario_name=Path(str(path)).name if path is not None else scenario.name,
        versions=_versions(),
        design={key: _listed(getattr(ctrl, key, None)) for key in ("x0", "u0", "u_min", "u_max")},
    )
    return unit, recordings, py_time, clamped, sim


def _listed(value: object) -> list[float] | None:
    return None if value is None else [float(v) for v in np.asarray(value, dtype=float).reshape(-1)]


def is_export_folder(path: Path) -> bool:
    """Whether ``path`` holds an exported folder (its ``export.json`` names the export format)."""
    import json

    try:
        doc = json.loads((path / "export.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == EXPORT_FORMAT


def export_scenario(
    config: str | Path,
    out: str | Path,
    *,
    name: str | None = None,
    verify: bool = True,
    cflags: str = "-O2",
    time_step: bool = True,
) -> ExportReport:
    """Export the scenario's estimator and controller as a verified C folder at ``out`` (see the module docstring).

    Args:
        config: Scenario path or shipped name.
        out: The folder to write (created; an earlier export there is replaced; anything else is refused).
        name: C name (default the scenario's file stem).
        verify: Build with the system compiler and replay the recorded data before moving the folder in place.
        cflags: Optimization flags for the verification build.
        time_step: Let the test program time the C step too.

    Raises:
        ExportError: not exportable, the build failed, C disagrees with Python, or ``out`` is not an export folder.
    """
    out = Path(out)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not is_export_folder(out))):
        raise ExportError(f"--out {out} exists and is not an exported folder: refusing to overwrite it")
    unit, recordings, py_time, clamped, sim = prepare(config, name)
    files = assemble(unit, recordings)
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    try:
        for fname, text in files.items():
            (tmp / fname).write_text(text, encoding="utf-8")
        result = build_and_verify(tmp, unit.name, cflags=cflags, time_step=time_step) if verify else None
        if result is not None and not result.ok:
            why = ""
            if not result.heap and result.errors == 0:
                drift = replay_drift(sim, recordings)
                if drift > 0.1 * unit.tolerance:
                    why = (
                        f"; the estimator and controller together amplify rounding differences (the Python replay "
                        f"itself moves by {drift:.1e} when its initial estimate moves by 1e-15): their combined "
                        "dynamics have an unstable mode, so an open-loop replay cannot hold C to Python; check it in "
                        'the loop instead (--no-verify, then [controller] type = "Exported")'
                    )
            raise ExportError(f"the exported C does not reproduce the Python controller: {result.summary()}{why}")
        _replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ExportReport(
        out,
        unit.name,
        tuple(files),
        {r.label: int(r.y.shape[0]) for r in recordings},
        clamped,
        py_time,
        result,
    )


def _replace(tmp: Path, out: Path) -> None:
    """Move the finished folder ``tmp`` to ``out`` (an earlier export there is swapped out, then removed)."""
    old = None
    if out.exists():
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        os.replace(out, old)
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
