"""Closed-loop simulation of a scenario: plant + (engine) + controller + reference.

:class:`RobotSim` builds everything a scenario names; :meth:`RobotSim.run`
steps the loop ``y_k = C x_k + noise``, ``x̂_k = estimator.update(y_k,
u_{k-1})``, ``u_k = controller(x̂_k, r(t_k))``, ``x_{k+1} = plant.step(u_k)``
(the controller never sees the plant's state, only the estimate; the default
:class:`~shinro_ctrl.estimators.full_state.FullState` passes ``y`` through) and
returns a :class:`SimResult` with the trajectories and
the metrics that regression baselines are made of.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.config import Scenario, load_scenario, parse_scenario
from shinro_ctrl.errors import ConfigError, InvalidArgument, NonFiniteError, ShinroError
from shinro_ctrl.files import atomic_write, dump_json, dump_toml
from shinro_ctrl.output_feedback import estimation_metrics, loop_signals, uses_estimation
from shinro_ctrl.progress import Progress

NEVER_METRICS = ("settling_time", "rise_time")  # inf means the event never happened, not an overflow
MAX_STEPS = 10_000_000  # trajectories are kept in memory: 10 M steps of a 12-state plant is about 2 GB

__all__ = ["Reference", "RobotSim", "SimResult", "bound_excess", "compute_metrics", "format_metrics"]


# ------------------------------------------------------------------ references
class Reference:
    """A state reference ``r(t) (n,)`` and its rate ``ṙ(t) (n,)``.

    Kinds (keys as in the ``[sim] reference`` table; vectors are full states):

    * ``constant``: ``value`` (default: the operating point).
    * ``step``: ``initial`` until ``time``, then ``final``.
    * ``circle``: in the plane of state ``axes`` (default ``[0, 1]``), radius
      ``radius`` [m], ``frequency`` [Hz], around ``center``; without a centre
      the circle starts at the default point (``phase`` 0 there).
    * ``square``: side ``side`` [m] traversed at ``speed`` [m/s], starting at
      ``center`` (default: the default point) as a corner, counter-clockwise.
    * ``waypoints``: ``points`` at ``times``, ``linear`` or ``hold`` interpolation.
    """

    def __init__(self, spec: dict[str, Any], default: np.ndarray):
        self.kind = spec.get("kind", "constant")
        self.spec = spec
        self.default = np.asarray(default, dtype=float)
        n = self.default.shape[0]
        self.axes = spec.get("axes", [0, 1] if n >= 2 else [0, 0])
        if self.kind == "circle":
            r = spec["radius"]
            self.omega = 2 * math.pi * spec["frequency"]
            self.phase = spec.get("phase", 0.0)
            if "center" in spec:
                self.center = np.asarray(spec["center"], dtype=float)
            else:
                self.center = self.default.copy()
                self.center[self.axes[0]] -= r * math.cos(self.phase)
                self.center[self.axes[1]] -= r * math.sin(self.phase)
        elif self.kind == "square":
            self.center = np.asarray(spec.get("center", self.default), dtype=float)
        elif self.kind == "waypoints":
            self.points = np.asarray(spec["points"], dtype=float)
            self.times = np.asarray(spec["times"], dtype=float)

    def __call__(self, t: float) -> np.ndarray:
        k, s = self.kind, self.spec
        if k == "constant":
            return np.asarray(s.get("value", self.default), dtype=float).copy()
        if k == "step":
            key = "initial" if t < s["time"] else "final"
            return np.asarray(s.get(key, self.default), dtype=float).copy()
        if k == "circle":
            r = self.center.copy()
            a = self.omega * t + self.phase
            r[self.axes[0]] += s["radius"] * math.cos(a)
            r[self.axes[1]] += s["radius"] * math.sin(a)
            return r
        if k == "square":
            r = self.center.copy()
            side = s["side"]
            d = (s["speed"] * t) % (4 * side)
            leg, along = int(d // side), d % side
            corner = [(0.0, 0.0), (side, 0.0), (side, side), (0.0, side)][leg]
            direction = [(1, 0), (0, 1), (-1, 0), (0, -1)][leg]
            r[self.axes[0]] += corner[0] + direction[0] * along
            r[self.axes[1]] += corner[1] + direction[1] * along
            return r
        # waypoints
        if t <= self.times[0]:
            return self.points[0].copy()
        if t >= self.times[-1]:
            return self.points[-1].copy()
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        if s.get("interpolation", "linear") == "hold":
            return self.points[i].copy()
        w = (t - self.times[i]) / (self.times[i + 1] - self.times[i])
        return (1 - w) * self.points[i] + w * self.points[i + 1]

    def rate(self, t: float) -> np.ndarray:
        """``ṙ(t)``: analytic for circles and squares, slopes for linear waypoints, else zero."""
        out = np.zeros_like(self.default)
        s = self.spec
        if self.kind == "circle":
            a = self.omega * t + self.phase
            out[self.axes[0]] = -s["radius"] * self.omega * math.sin(a)
            out[self.axes[1]] = s["radius"] * self.omega * math.cos(a)
        elif self.kind == "square":
            leg = int(((s["speed"] * t) % (4 * s["side"])) // s["side"])
            direction = [(1, 0), (0, 1), (-1, 0), (0, -1)][leg]
            out[self.axes[0]] = s["speed"] * direction[0]
            out[self.axes[1]] = s["speed"] * direction[1]
        elif self.kind == "waypoints" and s.get("interpolation", "linear") == "linear":
            if self.times[0] < t < self.times[-1]:
                i = int(np.searchsorted(self.times, t, side="right")) - 1
                out = (self.points[i + 1] - self.points[i]) / (self.times[i + 1] - self.times[i])
        return out


# --------------------------------------------------------------------- metrics
def bound_excess(values: np.ndarray, lo: np.ndarray | None, hi: np.ndarray | None) -> np.ndarray:
    """Largest excess of each row of ``values (T, k)`` over the bounds ``lo``/``hi (k,)`` (0 when inside).

    An excess counts only beyond a relative 1e-9 (solver rounding at an active bound).
    """
    out = np.zeros(values.shape[0])
    for bound, sign in ((lo, -1.0), (hi, 1.0)):
        if bound is None:
            continue
        b = np.asarray(bound, dtype=float)
        finite = np.isfinite(b)
        if not finite.any():
            continue
        over = sign * (values[:, finite] - b[finite]) - 1e-9 * (1.0 + np.abs(b[finite]))
        out = np.maximum(out, np.maximum(over, 0.0).max(axis=1))
    return out


def compute_metrics(
    t: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    ref: np.ndarray,
    *,
    tracked: list[int],
    settle_tol: float = 0.01,
    u_min: np.ndarray | None = None,
    u_max: np.ndarray | None = None,
    x_min: np.ndarray | None = None,
    x_max: np.ndarray | None = None,
    plant_violation: np.ndarray | None = None,
    solve_times: np.ndarray | None = None,
) -> dict[str, float]:
    """Metrics of a closed-loop run.

    The tracking error is ``e_k = ‖x_k[tracked] − r_k[tracked]‖₂``.

    Returns:
        ``rms_error`` (``sqrt(mean e_k²)``), ``max_error``, ``final_error``,
        ``settling_time`` (first time after which ``e`` stays within
        ``settle_tol``; ``inf`` if it never does), ``max_abs_input``,
        ``constraint_violations`` (steps at which an input or state bound, or
        a plant limit, is exceeded by more than 1e-9 relative),
        ``max_violation`` (the largest such excess),
        ``solve_time_median_s`` (median controller call), and for a step or
        initial-condition response ``overshoot`` and ``rise_time`` (see
        :func:`response_metrics`).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        d = x[:, tracked] - ref[:, tracked]
        scale = float(np.abs(d).max(initial=0.0))
        if scale > 1e150 and math.isfinite(scale):  # squares would overflow: norms of the scaled errors
            e = scale * np.linalg.norm(d / scale, axis=1)
            rms = scale * float(np.sqrt(np.mean((e / scale) ** 2)))
        else:
            e = np.linalg.norm(d, axis=1)
            rms = float(np.sqrt(np.mean(e**2)))
    if not (math.isfinite(rms) and np.all(np.isfinite(e))):
        raise NonFiniteError(
            f"the tracking-error metrics overflow float64 (errors up to {scale:.3g}): the run left the range "
            "where its metrics can be computed"
        )
    outside = np.nonzero(e > settle_tol)[0]
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == len(e) - 1:
        settling = math.inf
    else:
        settling = float(t[outside[-1] + 1])

    viol = np.zeros(len(t))
    viol[:-1] = np.maximum(viol[:-1], bound_excess(u, u_min, u_max))
    viol[1:] = np.maximum(viol[1:], bound_excess(x[1:], x_min, x_max))
    if plant_violation is not None:
        viol = np.maximum(viol, plant_violation)
    return {
        "rms_error": rms,
        "max_error": float(e.max()),
        "final_error": float(e[-1]),
        "settling_time": settling,
        "max_abs_input": float(np.abs(u).max()) if u.size else 0.0,
        "constraint_violations": int(np.count_nonzero(viol > 0)),
        "max_violation": float(viol.max()),
        "solve_time_median_s": float(np.median(solve_times)) if solve_times is not None and solve_times.size else 0.0,
        **response_metrics(t, x[:, tracked], ref[:, tracked], settle_tol),
    }


def response_metrics(t: np.ndarray, x: np.ndarray, ref: np.ndarray, settle_tol: float = 0.01) -> dict[str, float]:
    """``overshoot`` [%] and ``rise_time`` [s] of a step or initial-condition response (else ``{}``).

    Meaningful when the reference ``ref (T+1, k)`` is constant (the run recovers
    from its initial deviation) or changes once (a step; measured from the
    step). The response is that of the tracked state with the largest
    deviation from the new reference at the start, and it must exceed
    ``settle_tol``; see :func:`shinro_ctrl.analysis.step_metrics` (overshoot
    past the reference, 10–90 % rise time, ``inf`` if 90 % is never reached).
    """
    from shinro_ctrl.analysis.response import step_metrics

    changes = np.flatnonzero(np.any(ref[1:] != ref[:-1], axis=1))
    if changes.size > 1 or x.shape[1] == 0:
        return {}
    k0 = int(changes[0]) + 1 if changes.size else 0
    d0 = x[k0] - ref[k0]
    j = int(np.argmax(np.abs(d0)))
    if not abs(d0[j]) > settle_tol or k0 >= len(t) - 1 or not np.all(np.isfinite(x[k0:, j])):
        return {}
    target = float(ref[k0, j])
    m = step_metrics(t[k0:] - t[k0], x[k0:, j], initial=float(x[k0, j]), final=target, target=target)
    return {"overshoot": m.overshoot, "rise_time": m.rise_time}


def format_metrics(metrics: dict[str, float]) -> str:
    """A two-column table of metrics."""
    units = {"settling_time": "s", "solve_time_median_s": "s", "rise_time": "s", "overshoot": "%"}
    rows = []
    for k, v in metrics.items():
        if isinstance(v, float) and math.isinf(v):
            val = "never" if k in NEVER_METRICS else ("inf" if v > 0 else "-inf")
        elif isinstance(v, int):
            val = str(v)
        else:
            val = f"{v:.6g}"
        rows.append(f"  {k:22s} {val:>14s} {units.get(k, '')}".rstrip())
    return "\n".join(rows)


# ---------------------------------------------------------------------- result
@dataclass
class SimResult:
    """Trajectories and metrics of one closed-loop run.

    Attributes:
        t: Times ``(T + 1,)`` [s].
        x: States ``(T + 1, n)``.
        u: Inputs ``(T, m)``.
        ref: References ``(T + 1, n)``.
        metrics: See :func:`compute_metrics`.
        state_names, input_names: Labels.
        tracked: Names of the states the error metrics use.
        u_min, u_max, x_min, x_max: Bounds for plots (None where absent).
        solve_times: Controller call times ``(T,)`` [s].
        scenario: The scenario name; ``loop``: ``"standalone"`` or ``"mujoco"``.
        config: The resolved scenario document.
        x_hat: State estimates the controller was fed ``(T + 1, n)`` (the
            true state for full-state feedback without noise).
        y: Measurements ``(T + 1, p)`` (measured states plus sensor noise).
        measured: Names of the columns of ``y``.
        disturbance: Disturbances ``(T, k)`` held over each step (see
            :mod:`shinro_ctrl.disturbances`); ``disturbance_labels`` names
            the columns.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    ref: np.ndarray
    metrics: dict[str, float]
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    tracked: list[str]
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    x_min: np.ndarray | None = None
    x_max: np.ndarray | None = None
    solve_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    scenario: str = "<dict>"
    loop: str = "standalone"
    config: dict[str, Any] = field(default_factory=dict)
    x_hat: np.ndarray | None = None
    y: np.ndarray | None = None
    measured: tuple[str, ...] = ()
    disturbance: np.ndarray | None = None
    disturbance_labels: list[str] = field(default_factory=list)

    def save(self, directory: str | Path) -> Path:
        """Write ``result.npz``, ``metrics.json`` and ``scenario.toml`` into ``directory`` (atomically)."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        arrays = {"t": self.t, "x": self.x, "u": self.u, "ref": self.ref, "solve_times": self.solve_times}
        for key in ("x_hat", "y", "disturbance"):
            if getattr(self, key) is not None:
                arrays[key] = getattr(self, key)
        atomic_write(d / "result.npz", lambda f: np.savez(f, **arrays), binary=True)
        dump_json(d / "metrics.json", {"scenario": self.scenario, "loop": self.loop, "metrics": self.metrics})
        atomic_write(d / "scenario.toml", lambda f: f.write(dump_toml(self.config)))
        return d

    def plot(self, path: str | Path, *, compare: SimResult | None = None) -> Path:
        """Plot the run to a PNG (see :func:`shinro_ctrl.plots.plot_run`).

        States with references, bounds and the settling band, inputs with bounds,
        units on every axis, an x–y panel for planar tasks; ``compare`` (the other
        loop's result) is drawn over it with the metric differences.
        """
        from shinro_ctrl.plots import plot_run

        return plot_run(self, path, compare=compare)


# ------------------------------------------------------------------------ sim
class RobotSim:
    """Plant, optional MuJoCo engine, controller and reference of one scenario.

    Attributes:
        scenario: The parsed :class:`~shinro_ctrl.config.Scenario`.
        plant: The plant (engine attached when the loop is MuJoCo).
        engine: The :class:`~shinro_ctrl.engine.MujocoEngine`, or None (standalone).
        controller: The controller built by ``from_plant``
            (a :class:`~shinro_ctrl.controllers.base.Controller`).
        estimator: The :class:`~shinro_ctrl.estimators.base.Estimator` whose
            estimate the controller is fed (default
            :class:`~shinro_ctrl.estimators.full_state.FullState`); assign
            another one before :meth:`run` to close the loop through it.
        reference: The :class:`Reference`.
    """

    def __init__(self, scenario: Scenario, *, engine: str | None = None):
        from shinro_ctrl.controllers import controller_class
        from shinro_ctrl.plants import plant_class

        self.scenario = scenario
        src = str(scenario.path) if scenario.path else scenario.name
        self.plant = plant_class(scenario.plant.type).from_config(scenario.plant.params)
        if engine not in (None, "standalone", "mujoco"):
            raise ConfigError(f"engine must be 'standalone' or 'mujoco', got {engine!r}")
        use_engine = scenario.engine is not None if engine is None else engine == "mujoco"
        self.engine = None
        if use_engine:
            if self.plant.asset is None and (scenario.engine is None or scenario.engine.model is None):
                raise ConfigError(f"{src}: {scenario.plant.type} has no MuJoCo model; run it standalone")
            self.engine = self._attach_engine(self.plant)
        options = dict(scenario.controller.options)
        ccls = controller_class(scenario.controller.type)
        try:
            self.controller = ccls.from_plant(self.plant, **options)
        except ShinroError as exc:
            raise type(exc)(f"{src}: [controller] {exc}") from exc
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{src}: [controller] {exc}") from exc
        _install_ik(self.plant, self.controller)
        from shinro_ctrl.output_feedback import build_estimator

        self.estimator, self.initial_estimate, self.initial_covariance = build_estimator(
            scenario, self.plant, self.controller, src
        )
        self.operating_point = self._operating_point()
        sim = scenario.sim
        self.initial_state = (
            np.asarray(sim.initial_state, dtype=float) if sim.initial_state is not None else self.plant.get_state()
        )
        if sim.initial_state is None and self.engine is None:
            self.initial_state = self.operating_point.copy()
        self.reference = Reference(sim.reference, self.initial_state if _moves(sim.reference) else self.operating_point)
        names = sim.track or list(getattr(self.plant, "tracked_states", None) or self._default_tracked())
        self.tracked = [self.plant.state_names.index(s) for s in names]

    def _attach_engine(self, plant: Any) -> Any:
        """Build a MuJoCo engine matched to ``plant`` (the scenario's model and substeps) and attach it."""
        from shinro_ctrl.engine import MujocoEngine

        ecfg = self.scenario.engine
        engine = MujocoEngine.for_plant(
            plant, substeps=ecfg.substeps if ecfg else 1, model=ecfg.model if ecfg else None
        )
        plant.physics_engine(engine)
        return engine

    def with_plant(self, overrides: dict[str, Any]) -> RobotSim:
        """A copy that runs this sim's controller and reference on a plant with changed parameters.

        The plant is rebuilt from the scenario's ``[plant]`` table with
        ``overrides`` (constructor name → value); in a MuJoCo loop it gets a
        fresh matched engine. The controller object, reference, initial state
        and settings are shared with this sim, which is not modified.

        Raises:
            ConfigError: an invalid value (say, a negative mass), naming the key.
        """
        from shinro_ctrl.plants import plant_class

        sim = copy.copy(self)
        sim.plant = plant_class(self.scenario.plant.type).from_config({**self.scenario.plant.params, **overrides})
        sim.engine = self._attach_engine(sim.plant) if self.engine is not None else None
        _install_ik(sim.plant, sim.controller)
        return sim

    @classmethod
    def from_config(cls, config: str | Path | dict[str, Any], *, engine: str | None = None) -> RobotSim:
        """Build from a scenario path (or shipped name) or an already-loaded document.

        Args:
            config: Path, shipped scenario name, or a dict with the TOML tables.
            engine: Override the scenario's loop: ``"standalone"`` or ``"mujoco"``.
        """
        if not isinstance(config, dict | str | Path):
            raise InvalidArgument(
                f"RobotSim.from_config expects a scenario path, a shipped name or a dict, got {type(config).__name__}"
            )
        scenario = parse_scenario(config) if isinstance(config, dict) else load_scenario(config)
        return cls(scenario, engine=engine)

    @property
    def loop(self) -> str:
        """``"mujoco"`` or ``"standalone"``."""
        return "mujoco" if self.engine is not None else "standalone"

    def _default_estimator(self) -> Any:
        from shinro_ctrl.estimators import FullState

        return FullState(self.plant.state_dim)

    def _operating_point(self) -> np.ndarray:
        x0 = self.controller.x0
        if x0 is not None and np.shape(x0) == (self.plant.state_dim,):
            return np.asarray(x0, dtype=float)
        return self.plant.equilibrium()[0]

    def _operating_input(self) -> np.ndarray:
        """The input the estimator assumes before the first step: the controller's ``u0``, else the plant's."""
        u0 = self.controller.u0
        if u0 is not None and np.shape(u0) == (self.plant.input_dim,):
            return np.asarray(u0, dtype=float).copy()
        return np.asarray(self.plant.equilibrium()[1], dtype=float).copy()

    def _default_tracked(self) -> list[str]:
        p = self.plant
        idx = p.position_indices or tuple(range(p.state_dim))
        return [p.state_names[i] for i in idx]

    def run(self, duration: float | None = None, *, progress: bool | None = None) -> SimResult:
        """Run the closed loop for ``duration`` seconds (default the scenario's).

        Args:
            duration: Simulated time [s].
            progress: Show a progress bar on stderr (None: when stderr is a
                terminal and the run takes longer than 2 s).

        Raises:
            SimulationDiverged, MPCInfeasible, NonFiniteError: with the scenario
                name and the time at which the loop failed.
        """
        sim = self.scenario.sim
        duration = sim.duration if duration is None else float(duration)
        if not math.isfinite(duration) or duration <= 0:
            raise InvalidArgument(f"duration must be positive, got {duration!r}")
        plant, ctrl, ref = self.plant, self.controller, self.reference
        dt = plant.dt
        steps = max(1, round(duration / dt))
        n, m = plant.state_dim, plant.input_dim
        if steps > MAX_STEPS:
            raise InvalidArgument(
                f"duration {duration:g} s at dt = {dt:g} s is {steps:,} steps; a run keeps every step in memory "
                f"and is limited to {MAX_STEPS:,} (split it, or use a larger dt)"
            )
        t = np.arange(steps + 1) * dt
        X = np.empty((steps + 1, n))
        U = np.empty((steps, m))
        R = np.empty((steps + 1, n))
        solve = np.empty(steps)
        pviol = np.zeros(steps + 1)
        limit = getattr(plant, "limit_violation", None)
        rng = np.random.default_rng(sim.seed)
        noise = np.asarray(sim.measurement_noise, dtype=float) if sim.measurement_noise else None

        ctrl.reset()
        if sim.initial_state is not None or self.engine is None:
            plant.set_state(self.initial_state)
        x = plant.get_state()
        X[0] = x
        est = self.estimator
        est.reset(x if self.initial_estimate is None else self.initial_estimate, self.initial_covariance)
        estimate = est.update
        # y = C x (+ noise): the rows of the identity at the estimator's measured indices
        measured = None if tuple(est.measured) == tuple(range(n)) else np.asarray(est.measured, dtype=np.intp)
        u_prev = self._operating_input()
        # Output feedback (output_feedback.py): sensor/process noise and disturbances drawn once, before the loop.
        p = n if measured is None else measured.shape[0]
        sig = loop_signals(self.scenario, plant, t, p)
        sensor, extra, forces = sig.sensor, sig.extra_input, sig.forces
        X_hat = np.empty((steps + 1, n))
        Y = np.empty((steps + 1, p))
        engine = self.engine
        bar = Progress(steps, f"{self.scenario.name} ({self.loop})", progress, unit="steps")
        clock = time.perf_counter
        # Controllers that look ahead (LQR feed-forward, MPC) get the next `preview` samples too.
        preview = int(ctrl.preview) if ref.kind != "constant" else 0
        k = 0
        try:
            for k in range(steps):
                r = ref(t[k])
                R[k] = r
                if preview:
                    r = np.array([r, *(ref(t[k] + i * dt) for i in range(1, preview + 1))])
                y = x + noise * rng.standard_normal(n) if noise is not None else x
                if measured is not None:
                    y = y[measured]
                if sensor is not None:
                    y = y + sensor[k]
                Y[k] = y
                x_hat = estimate(y, u_prev)  # the controller sees the estimate, never the plant's state
                X_hat[k] = x_hat[:n]  # an offset-free estimator returns [x̂; d̂]
                t0 = clock()
                u = ctrl(x_hat, r)
                solve[k] = clock() - t0
                U[k] = u
                u_prev = u
                for body, F, _ in forces:
                    if engine is not None:
                        engine.set_body_force(body, F[k])
                plant.step(u if extra is None else u + extra[k])  # the plant feels noise and disturbances
                for _, F, G in forces:
                    if engine is None:  # standalone: the force's effect over the step, dt · G F
                        plant.state = plant.state + dt * (G @ F[k])
                x = plant.get_state()
                X[k + 1] = x
                if limit is not None:
                    pviol[k + 1] = limit()
                if k % 256 == 0:
                    bar.update(k)
        except ShinroError as exc:
            raise type(exc)(f"{self.scenario.name} ({self.loop}) at t = {t[k]:.4g} s: {exc}") from exc
        finally:
            bar.close()
            if forces and engine is not None:
                engine.clear_body_forces()
        y = x + noise * rng.standard_normal(n) if noise is not None else x
        y = y[measured] if measured is not None else y
        Y[steps] = y + sensor[steps] if sensor is not None else y
        X_hat[steps] = estimate(Y[steps], u_prev)[:n]
        R[steps] = ref(t[steps])
        bounds = {
            name: _bound(value, size)
            for name, value, size in (
                ("u_min", ctrl.u_min, m),
                ("u_max", ctrl.u_max, m),
                ("x_min", ctrl.x_min, n),
                ("x_max", ctrl.x_max, n),
            )
        }
        metrics = compute_metrics(
            t,
            X,
            U,
            R,
            tracked=self.tracked,
            settle_tol=sim.settle_tol,
            plant_violation=pviol if limit is not None else None,
            solve_times=solve,
            **bounds,
        )
        if uses_estimation(self.scenario):
            metrics.update(estimation_metrics(X, X_hat, tuple(plant.state_names)))
        return SimResult(
            t=t,
            x=X,
            u=U,
            ref=R,
            metrics=metrics,
            state_names=tuple(plant.state_names),
            input_names=tuple(plant.input_names),
            tracked=[plant.state_names[i] for i in self.tracked],
            solve_times=solve,
            scenario=self.scenario.name,
            loop=self.loop,
            config=self.resolved_config(duration),
            x_hat=X_hat,
            y=Y,
            measured=tuple(plant.state_names[i] for i in (est.measured if measured is not None else range(n))),
            disturbance=sig.disturbance.values,
            disturbance_labels=list(sig.disturbance.labels),
            **bounds,
        )

    def resolved_config(self, duration: float | None = None) -> dict[str, Any]:
        """The scenario with defaults filled in (what was run; ``duration`` if it was overridden)."""
        s = self.scenario
        plant_tbl = {"type": s.plant.type, **self.plant.params()}
        for k, v in s.plant.params.items():
            plant_tbl.setdefault(k, v)
        plant_tbl["dt"] = self.plant.dt
        doc: dict[str, Any] = {"plant": plant_tbl}
        if self.engine is not None:
            eng = {"type": "mujoco", "substeps": s.engine.substeps if s.engine else 1}
            if s.engine and s.engine.model:
                eng["model"] = s.engine.model
            doc["engine"] = eng
        doc["controller"] = {"type": s.controller.type, **s.controller.options}
        sim = {
            "duration": s.sim.duration if duration is None else duration,
            "initial_state": self.initial_state.tolist(),
            "reference": s.sim.reference,
            "track": [self.plant.state_names[i] for i in self.tracked],
            "settle_tol": s.sim.settle_tol,
            "seed": s.sim.seed,
        }
        if s.sim.measurement_noise:
            sim["measurement_noise"] = s.sim.measurement_noise
        for key in ("measured", "sensor_noise", "process_noise"):
            if getattr(s.sim, key) is not None:
                sim[key] = getattr(s.sim, key)
        if s.sim.disturbance:
            sim["disturbance"] = [d.as_table() for d in s.sim.disturbance]
        doc["sim"] = sim
        if s.estimator is not None:
            doc["estimator"] = {"type": s.estimator.type, **s.estimator.options}
        if s.regression:
            doc["regression"] = s.regression
        return doc


def _install_ik(plant: Any, controller: Any) -> None:
    """An arm driven by a differential-IK controller turns its twists into that controller's joint targets.

    The scenario layer wires the two (a controller never changes its plant): ``ArmRobot.ik``
    is the IK its ``step`` uses, and an :class:`~shinro_ctrl.controllers.ik_qp.IKQP` is one.
    """
    from shinro_ctrl.plants import ArmRobot

    if isinstance(plant, ArmRobot) and type(controller).__name__ == "IKQP":
        plant.ik = controller


def _bound(value: Any, size: int) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    return arr if arr.shape == (size,) else None


def _moves(reference: dict[str, Any]) -> bool:
    """Paths (circle, square) start where the plant starts; set-points default to the operating point."""
    return reference.get("kind") in ("circle", "square")
