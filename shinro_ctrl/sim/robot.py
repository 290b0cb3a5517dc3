"""The closed loop of one scenario: :class:`RobotSim` (plant, engine, controller, estimator, reference)."""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from shinro_ctrl.config import Scenario, load_scenario, parse_scenario
from shinro_ctrl.errors import ConfigError, InvalidArgument, ShinroError
from shinro_ctrl.progress import Progress
from shinro_ctrl.sim.metrics import balance_metrics, compute_metrics, plan_tracking_rms, saturation_metrics
from shinro_ctrl.sim.output_feedback import estimation_metrics, loop_signals, uses_estimation
from shinro_ctrl.sim.reference import Reference
from shinro_ctrl.sim.result import SimResult

if TYPE_CHECKING:
    from shinro_ctrl.controllers.base import Controller
    from shinro_ctrl.engine import MujocoEngine
    from shinro_ctrl.plants.base import Plant
    from shinro_ctrl.sim.nonideal import ActuatorModel, SensorModel

__all__ = ["MAX_STEPS", "RobotSim"]

MAX_STEPS = 10_000_000  # trajectories are kept in memory: 10 M steps of a 12-state plant is about 2 GB


@dataclass
class _LoopState:
    """The buffers and signals of one run, shared by :meth:`RobotSim.run`'s set-up, loop and result steps.

    ``t (T+1,)``; ``X, R, X_hat (T+1, n)``; ``U (T, m)``; ``Y (T+1, p)``; ``solve (T,)``; ``pviol (T+1,)``;
    ``x`` and ``u_prev`` are the state and input the loop ended with; ``clamped (T, m)`` the force clamps.
    """

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray
    R: np.ndarray
    X_hat: np.ndarray
    Y: np.ndarray
    solve: np.ndarray
    pviol: np.ndarray
    limit: Any
    rng: np.random.Generator
    noise: np.ndarray | None
    measured: np.ndarray | None
    sig: Any
    x: np.ndarray
    u_prev: np.ndarray
    clamps: Any = None  # the engine's ForceClamps (MuJoCo loop with force-limited actuators), else None
    clamped: np.ndarray | None = None  # (T, m) int8: the inputs MuJoCo clamped at a forcerange in each step
    balance: Any = None  # the engine's BalanceMonitor (MuJoCo loop, free joint and floor), else None


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
        reference: The :class:`~shinro_ctrl.sim.Reference`.
        actuator: The :class:`~shinro_ctrl.sim.nonideal.ActuatorModel` between the
            controller and the plant (``[sim] actuator``), or None (ideal).
        sensor: The :class:`~shinro_ctrl.sim.nonideal.SensorModel` between the plant
            and the estimator (``[sim] sensor``), or None (ideal).
    """

    def __init__(self, scenario: Scenario, *, engine: str | None = None):
        self.scenario = scenario
        src = str(scenario.path) if scenario.path else scenario.name
        if engine not in (None, "standalone", "mujoco"):
            raise ConfigError(f"engine must be 'standalone' or 'mujoco', got {engine!r}")
        use_engine = scenario.engine is not None if engine is None else engine == "mujoco"
        self.plant, ik = self._build_plant(scenario.plant.params)
        self.engine = None
        if use_engine:
            if self.plant.asset is None and (scenario.engine is None or scenario.engine.model is None):
                raise ConfigError(f"{src}: {scenario.plant.type} has no MuJoCo model; run it standalone")
            self.engine = self._attach_engine(self.plant)
        self.controller = ik if ik is not None else self._design(self.plant)
        from shinro_ctrl.sim.output_feedback import build_estimator

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
        self.actuator, self.sensor = _nonideal(scenario, self.plant, self.estimator.measured)

    def _design(self, plant: Plant) -> Controller:
        """The scenario's controller, built by its class's ``from_plant`` on ``plant``."""
        from shinro_ctrl.controllers import controller_class

        src = str(self.scenario.path) if self.scenario.path else self.scenario.name
        ccls = controller_class(self.scenario.controller.type)
        try:
            return ccls.from_plant(plant, **self.scenario.controller.options)
        except ShinroError as exc:
            raise type(exc)(f"{src}: [controller] {exc}") from exc
        except (TypeError, ValueError, FileNotFoundError) as exc:  # FileNotFoundError: a plan file it loads
            raise ConfigError(f"{src}: [controller] {exc}") from exc

    def _build_plant(self, params: dict[str, Any]) -> tuple[Plant, Controller | None]:
        """The scenario's plant from ``params``; for a plant that takes its IK at construction (the arm)
        driven by an IK controller (one with ``track(q, T)``, such as ``IKQP``), that controller too.

        The arm is then built with ``ik=`` a factory that designs the scenario's controller on the arm
        itself, so the arm steps with the very object the loop calls (nothing is installed afterwards).
        """
        from shinro_ctrl.controllers import controller_class
        from shinro_ctrl.plants import plant_class

        pcls = plant_class(self.scenario.plant.type)
        ccls = controller_class(self.scenario.controller.type)
        if not (pcls.takes_ik and callable(getattr(ccls, "track", None))):
            return pcls.from_config(params), None
        built: list[Controller] = []

        def design(arm: Plant) -> Controller:
            built.append(self._design(arm))
            return built[0]

        plant = pcls.from_config(params, ik=design)
        return plant, built[0]

    def _attach_engine(self, plant: Plant) -> MujocoEngine:
        """Build a MuJoCo engine matched to ``plant`` (the scenario's model and substeps) and attach it."""
        from shinro_ctrl.engine import MujocoEngine

        ecfg = self.scenario.engine
        try:
            engine = MujocoEngine.for_plant(
                plant, substeps=ecfg.substeps if ecfg else 1, model=ecfg.model if ecfg else None
            )
        except (FileNotFoundError, InvalidArgument) as exc:  # a model that does not exist or does not fit the plant
            src = str(self.scenario.path) if self.scenario.path else self.scenario.name
            raise ConfigError(f"{src}: [engine] model: {exc}") from exc
        plant.physics_engine(engine)
        return engine

    def with_plant(self, overrides: dict[str, Any]) -> RobotSim:
        """A copy that runs this sim's controller and reference on a plant with changed parameters.

        The plant is rebuilt from the scenario's ``[plant]`` table with
        ``overrides`` (constructor name → value); in a MuJoCo loop it gets a
        fresh matched engine. The controller object, reference, initial state
        and settings are shared with this sim, which is not modified (an arm
        driven by its IK controller gets that controller built on the new arm:
        the two are one object).

        Raises:
            ConfigError: an invalid value (say, a negative mass), naming the key.
        """
        sim = copy.copy(self)
        sim.plant, ik = self._build_plant({**self.scenario.plant.params, **overrides})
        if ik is not None:  # the arm's IK is its controller: designed on the new arm
            sim.controller = ik
        sim.engine = self._attach_engine(sim.plant) if self.engine is not None else None
        # its own actuator and sensor: a run's FIFOs and filter states are not shared
        sim.actuator, sim.sensor = _nonideal(self.scenario, sim.plant, sim.estimator.measured)
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
        duration, steps = self._checked_steps(duration)
        state = self._start(steps)
        self._loop(state, progress)
        self._final_sample(state)
        return self._result(state, duration)

    def _checked_steps(self, duration: float | None) -> tuple[float, int]:
        """The run's duration [s] (default the scenario's) and its number of steps, both checked."""
        duration = self.scenario.sim.duration if duration is None else float(duration)
        if not math.isfinite(duration) or duration <= 0:
            raise InvalidArgument(f"duration must be positive, got {duration!r}")
        dt = self.plant.dt
        steps = max(1, round(duration / dt))
        if steps > MAX_STEPS:
            raise InvalidArgument(
                f"duration {duration:g} s at dt = {dt:g} s is {steps:,} steps; a run keeps every step in memory "
                f"and is limited to {MAX_STEPS:,} (split it, or use a larger dt)"
            )
        return duration, steps

    def _start(self, steps: int) -> _LoopState:
        """Allocate the trajectories, reset controller, plant and estimator, and draw the loop's signals."""
        sim, plant = self.scenario.sim, self.plant
        n, m = plant.state_dim, plant.input_dim
        t = np.arange(steps + 1) * plant.dt
        X = np.empty((steps + 1, n))
        U = np.empty((steps, m))
        R = np.empty((steps + 1, n))
        solve = np.empty(steps)
        pviol = np.zeros(steps + 1)
        limit = getattr(plant, "limit_violation", None)
        rng = np.random.default_rng(sim.seed)
        noise = np.asarray(sim.measurement_noise, dtype=float) if sim.measurement_noise else None

        self.controller.reset()
        if sim.initial_state is not None or self.engine is None:
            plant.set_state(self.initial_state)
        x = plant.get_state()
        X[0] = x
        est = self.estimator
        est.reset(x if self.initial_estimate is None else self.initial_estimate, self.initial_covariance)
        # y = C x (+ noise): the rows of the identity at the estimator's measured indices
        measured = None if tuple(est.measured) == tuple(range(n)) else np.asarray(est.measured, dtype=np.intp)
        u_prev = self._operating_input()
        if self.actuator is not None:
            self.actuator.reset(u_prev)  # at rest at the operating input
        if self.sensor is not None:
            states = self.sensor.states
            if states is not None and states != tuple(est.measured):  # another estimator: the scenario's sensor
                self.sensor = _nonideal(self.scenario, plant, est.measured)[1]  # on the outputs it measures
            self.sensor.reset()
        # Output feedback (output_feedback.py): sensor/process noise and disturbances drawn once, before the loop.
        p = n if measured is None else measured.shape[0]
        sig = loop_signals(self.scenario, plant, t, p)
        clamps = self.engine.force_clamp_monitor(plant) if self.engine is not None else None
        balance = self.engine.balance_monitor() if self.engine is not None else None
        if balance is not None:
            balance()  # the sample at t = 0: the reference pose of the balance metrics
        return _LoopState(
            t,
            X,
            U,
            R,
            np.empty((steps + 1, n)),
            np.empty((steps + 1, p)),
            solve,
            pviol,
            limit,
            rng,
            noise,
            measured,
            sig,
            x,
            u_prev,
            clamps,
            np.zeros((steps, m), dtype=np.int8) if clamps is not None else None,
            balance,
        )

    def _loop(self, s: _LoopState, progress: bool | None) -> None:
        """Step the closed loop, filling ``s``'s trajectories (the hot path: locals only, nothing allocated here
        that a step could reuse)."""
        plant, ctrl, ref = self.plant, self.controller, self.reference
        engine = plant.simulation  # holds the state: applies body forces in both loops
        t, X, U, R, X_hat, Y, solve, pviol = s.t, s.X, s.U, s.R, s.X_hat, s.Y, s.solve, s.pviol
        limit, rng, noise, measured = s.limit, s.rng, s.noise, s.measured
        sensor, extra, forces = s.sig.sensor, s.sig.extra_input, s.sig.forces
        n, dt, steps = plant.state_dim, plant.dt, U.shape[0]
        x, u_prev = s.x, s.u_prev
        clamps, clamped, balance = s.clamps, s.clamped, s.balance
        actuator, sensor_model = self.actuator, self.sensor
        estimate = self.estimator.update
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
                if sensor_model is not None:
                    Y[k] = sensor_model(y)  # quantized and delayed: what the estimator is given
                    y = Y[k]  # the row, not the model's buffer that the next reading overwrites
                else:
                    Y[k] = y
                x_hat = estimate(y, u_prev)  # the controller sees the estimate, never the plant's state
                X_hat[k] = x_hat[:n]  # an offset-free estimator returns [x̂; d̂]
                t0 = clock()
                u = ctrl(x_hat, r)
                solve[k] = clock() - t0
                U[k] = u
                u_prev = u
                for body, F, _ in forces:
                    engine.set_body_force(body, F[k])
                u_in = u if actuator is None else actuator(u)  # delayed, rate-limited, quantized, lagged
                plant.step(u_in if extra is None else u_in + extra[k])  # the plant feels noise and disturbances
                x = plant.get_state()
                X[k + 1] = x
                if clamps is not None:
                    clamped[k] = clamps()
                if balance is not None:
                    balance()
                if limit is not None:
                    pviol[k + 1] = limit()
                if k % 256 == 0:
                    bar.update(k)
        except ShinroError as exc:
            raise type(exc)(f"{self.scenario.name} ({self.loop}) at t = {t[k]:.4g} s: {exc}") from exc
        finally:
            bar.close()
            if forces:
                engine.clear_body_forces()
        s.x, s.u_prev = x, u_prev

    def _final_sample(self, s: _LoopState) -> None:
        """The measurement, estimate and reference at the last time (the state the loop ended in)."""
        steps, n = s.U.shape[0], self.plant.state_dim
        y = s.x + s.noise * s.rng.standard_normal(n) if s.noise is not None else s.x
        y = y[s.measured] if s.measured is not None else y
        y = y + s.sig.sensor[steps] if s.sig.sensor is not None else y
        s.Y[steps] = self.sensor(y) if self.sensor is not None else y
        s.X_hat[steps] = self.estimator.update(s.Y[steps], s.u_prev)[:n]
        s.R[steps] = self.reference(s.t[steps])

    def _result(self, s: _LoopState, duration: float) -> SimResult:
        """The :class:`~shinro_ctrl.sim.SimResult` of a finished loop: trajectories, bounds and metrics."""
        plant, ctrl = self.plant, self.controller
        n, m = plant.state_dim, plant.input_dim
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
            s.t,
            s.X,
            s.U,
            s.R,
            tracked=self.tracked,
            settle_tol=self.scenario.sim.settle_tol,
            plant_violation=s.pviol if s.limit is not None else None,
            solve_times=s.solve,
            saturation=self._saturation(s, bounds["u_min"], bounds["u_max"]),
            **bounds,
        )
        plan_states = getattr(ctrl, "plan_states", None)  # a plan-tracking controller (TVLQR)
        plan = plan_states(s.t) if plan_states is not None else None
        if plan is not None:
            metrics["plan_tracking_rms"] = plan_tracking_rms(s.X, plan, self.tracked)
        if s.balance is not None:
            metrics.update(balance_metrics(s.balance.record()))
        if uses_estimation(self.scenario):
            metrics.update(estimation_metrics(s.X, s.X_hat, tuple(plant.state_names)))
        measured = self.estimator.measured if s.measured is not None else range(n)
        return SimResult(
            t=s.t,
            x=s.X,
            u=s.U,
            ref=s.R,
            metrics=metrics,
            state_names=tuple(plant.state_names),
            input_names=tuple(plant.input_names),
            tracked=[plant.state_names[i] for i in self.tracked],
            solve_times=s.solve,
            scenario=self.scenario.name,
            loop=self.loop,
            config=self.resolved_config(duration),
            x_hat=s.X_hat,
            y=s.Y,
            measured=tuple(plant.state_names[i] for i in measured),
            disturbance=s.sig.disturbance.values,
            disturbance_labels=list(s.sig.disturbance.labels),
            plan=plan,
            **bounds,
        )

    def _saturation(self, s: _LoopState, u_min: np.ndarray | None, u_max: np.ndarray | None) -> dict[str, Any]:
        """``saturation_fraction`` and the per-input times at a bound (see ``metrics.saturation_metrics``).

        The bounds are the tighter of the controller's and the plant's physical range (``plant.input_bounds()``:
        in the MuJoCo loop the model's ``ctrlrange``), plus the ``forcerange`` clamps MuJoCo applied.
        """
        plant = self.plant
        p_lo, p_hi = plant.input_bounds()
        lo = p_lo if u_min is None else np.maximum(u_min, p_lo)
        hi = p_hi if u_max is None else np.minimum(u_max, p_hi)
        return saturation_metrics(
            s.t,
            s.U,
            lo,
            hi,
            tuple(plant.input_names),
            clamped=s.clamped,
            clamp_inputs=s.clamps.inputs if s.clamps is not None else (),
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
        for key in ("actuator", "sensor"):
            if getattr(s.sim, key):
                sim[key] = dict(getattr(s.sim, key))
        doc["sim"] = sim
        if s.estimator is not None:
            doc["estimator"] = {"type": s.estimator.type, **s.estimator.options}
        if s.regression:
            doc["regression"] = s.regression
        return doc


def _nonideal(scenario: Scenario, plant: Plant, measured: Any) -> tuple[ActuatorModel | None, SensorModel | None]:
    """The scenario's actuator and sensor models for ``plant`` (None where ``[sim]`` leaves them out).

    ``measured``: the estimator's measured state indices (the sensor's values are per state).
    """
    from shinro_ctrl.sim.nonideal import ActuatorModel, SensorModel

    sim = scenario.sim
    act = ActuatorModel.from_table(sim.actuator, plant.input_dim, plant.dt) if sim.actuator else None
    full = tuple(measured) == tuple(range(plant.state_dim))
    sen = (
        SensorModel.from_table(sim.sensor, plant.state_dim, plant.dt, None if full else measured)
        if sim.sensor
        else None
    )
    return act, sen


def _bound(value: Any, size: int) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    return arr if arr.shape == (size,) else None


def _moves(reference: dict[str, Any]) -> bool:
    """Paths (circle, square) start where the plant starts; set-points default to the operating point."""
    return reference.get("kind") in ("circle", "square")
