"""The scenario side of output feedback: the estimator a scenario names, its noise, and estimation metrics.

:func:`build_estimator` turns ``[estimator]`` and ``[sim] measured`` into an
:class:`~shinro_ctrl.estimators.base.Estimator` (default
:class:`~shinro_ctrl.estimators.full_state.FullState`); :func:`loop_signals`
draws every noise and disturbance of a run once, before the loop, from
streams seeded by ``[sim] seed``; :func:`estimation_metrics` scores the
estimate against the true state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from shinro_ctrl.disturbances import DisturbanceProfile, disturbance_profile, noise_stream
from shinro_ctrl.errors import ConfigError, ShinroError
from shinro_ctrl.plants.standalone import StandaloneEngine
from shinro_ctrl.types import Weight

if TYPE_CHECKING:
    from shinro_ctrl.config import Scenario
    from shinro_ctrl.controllers.base import Controller
    from shinro_ctrl.estimators.base import Estimator
    from shinro_ctrl.plants.base import Plant

__all__ = ["LOOP_KEYS", "LoopSignals", "build_estimator", "estimation_metrics", "loop_signals", "uses_estimation"]

#: ``[estimator]`` keys the loop reads itself (not ``from_plant`` arguments): the initial estimate and covariance.
LOOP_KEYS = ("initial_estimate", "P0")

# Floors for noise covariances the scenario leaves at zero (a Kalman filter needs Rn > 0).
_RN_FLOOR, _QN_FLOOR = 1e-8, 1e-6


def uses_estimation(scenario: Scenario) -> bool:
    """Whether the scenario measures less than the full noiseless state (estimation metrics are then reported)."""
    s = scenario.sim
    return bool(scenario.estimator is not None or s.measured is not None or s.sensor_noise is not None)


def _default_noise(scenario: Scenario, options: dict[str, Any], plant: Plant, est_type: str) -> dict[str, Any]:
    """``Qn`` / ``Rn`` from ``process_noise`` / ``sensor_noise`` (squared, floored) where the table omits them."""
    s = scenario.sim
    out = dict(options)
    if est_type not in ("KalmanFilter", "ExtendedKalmanFilter"):
        return out
    p = len(s.measured) if s.measured is not None else plant.state_dim
    if "Rn" not in out:
        sd = np.asarray(s.sensor_noise if s.sensor_noise is not None else np.zeros(p), dtype=float)
        out["Rn"] = np.maximum(sd**2, _RN_FLOOR).tolist()
    if "Qn" not in out and out.get("Qn_on", "input") == "input":
        sd = np.asarray(s.process_noise if s.process_noise is not None else np.zeros(plant.input_dim), dtype=float)
        out["Qn"] = np.maximum(sd**2, _QN_FLOOR).tolist()
    return out


def build_estimator(
    scenario: Scenario, plant: Plant, controller: Controller, src: str
) -> tuple[Estimator, np.ndarray | None, Weight | None]:
    """The estimator of a scenario, with its initial estimate and covariance.

    * No ``[estimator]`` table: :class:`FullState`, unless the controller
      needs a disturbance estimate (``LinearMPC(disturbance_model="input")``):
      then a :class:`KalmanFilter` augmented with the input disturbance.
    * ``Qn`` / ``Rn`` default to the squares of ``[sim] process_noise`` /
      ``sensor_noise`` (floored at 1e-6 / 1e-8).

    Returns:
        ``(estimator, initial_estimate (n,) or None, P0 or None)``.

    Raises:
        ConfigError: a filter that cannot be built (the estimator's message, with the file and table).
    """
    from shinro_ctrl.estimators import estimator_class

    cfg = scenario.estimator
    wants_d = getattr(controller, "disturbance_model", None) == "input"
    if cfg is None and not wants_d:
        from shinro_ctrl.estimators import FullState

        return FullState(plant.state_dim), None, None
    est_type = cfg.type if cfg is not None else "KalmanFilter"
    options = dict(cfg.options) if cfg is not None else {}
    x_init = options.pop("initial_estimate", None)
    P0 = options.pop("P0", None)
    if wants_d:
        if est_type != "KalmanFilter":
            raise ConfigError(
                f"{src}: [estimator] the offset-free LinearMPC (disturbance_model = 'input') needs a KalmanFilter "
                f"that estimates the disturbance, got {est_type}"
            )
        options.setdefault("disturbance_model", "input")
        if options["disturbance_model"] != "input":
            raise ConfigError(f"{src}: [estimator] 'disturbance_model' must be 'input' for an offset-free LinearMPC")
    options = _default_noise(scenario, options, plant, est_type)
    if est_type != "FullState":
        options["measured"] = scenario.sim.measured
        if "x0" not in options and "x0" in _keywords(estimator_class(est_type)):
            op = getattr(controller, "x0", None)
            if op is not None and np.shape(op) == (plant.state_dim,):
                options["x0"], options["u0"] = list(np.asarray(op, dtype=float)), _u0(controller, plant)
    try:
        est = estimator_class(est_type).from_plant(plant, **options)
    except ShinroError as exc:
        raise ConfigError(f"{src}: [estimator] {exc}") from exc
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{src}: [estimator] {exc}") from exc
    if x_init is not None:
        x_init = np.asarray(x_init, dtype=float)
        if x_init.shape != (plant.state_dim,):
            raise ConfigError(f"{src}: [estimator] 'initial_estimate' must have {plant.state_dim} values")
    return est, x_init, P0


def _keywords(cls: type[Estimator]) -> tuple[str, ...]:
    import inspect

    return tuple(inspect.signature(cls.from_plant).parameters)


def _u0(controller: Controller, plant: Plant) -> list[float] | None:
    u0 = getattr(controller, "u0", None)
    if u0 is not None and np.shape(u0) == (plant.input_dim,):
        return list(np.asarray(u0, dtype=float))
    return None


@dataclass
class LoopSignals:
    """Every random draw and disturbance of one run, sampled before the loop.

    Attributes:
        sensor: ``(T + 1, p)`` sensor noise added to ``y``, or None.
        process: ``(T, m)`` process noise added to the applied input, or None.
        disturbance: The sampled :class:`~shinro_ctrl.disturbances.DisturbanceProfile`.
        extra_input: ``(T, m)`` process noise plus input disturbances, or None when both are absent.
        forces: ``[(body, (T, 3), G (n, 3))]`` world body forces and their standalone state map (None in MuJoCo,
            which applies the force itself).
    """

    sensor: np.ndarray | None
    process: np.ndarray | None
    disturbance: DisturbanceProfile
    extra_input: np.ndarray | None
    forces: list[tuple[str, np.ndarray, np.ndarray | None]]


def loop_signals(scenario: Scenario, plant: Plant, t: np.ndarray, p: int) -> LoopSignals:
    """Draw the sensor noise ``(T + 1, p)``, process noise and disturbances ``(T, ·)`` of a run on the grid ``t``."""
    s = scenario.sim
    T = t.shape[0] - 1
    m = plant.input_dim
    sensor = None
    if s.sensor_noise is not None and any(v > 0 for v in s.sensor_noise):
        sensor = np.asarray(s.sensor_noise) * noise_stream(s.seed, "sensor").standard_normal((T + 1, p))
    process = None
    if s.process_noise is not None and any(v > 0 for v in s.process_noise):
        process = np.asarray(s.process_noise) * noise_stream(s.seed, "process").standard_normal((T, m))
    prof = disturbance_profile(list(s.disturbance or []), t[:-1], plant.dt, m, s.seed)
    extra = None
    if process is not None or np.any(prof.inputs):
        extra = prof.inputs + (process if process is not None else 0.0)
    # the standalone loop moves the state by G F (checked here, before the loop); MuJoCo applies F itself
    standalone = isinstance(plant.simulation, StandaloneEngine)
    forces = [(body, F, plant.body_force_map(body) if standalone else None) for body, F in prof.forces]
    return LoopSignals(sensor, process, prof, extra, forces)


def estimation_metrics(x: np.ndarray, x_hat: np.ndarray, names: tuple[str, ...]) -> dict[str, float]:
    """``estimation_rms`` (``sqrt(mean_k ‖x̂_k − x_k‖²)``) and ``estimation_rms_<state>`` per state."""
    err = x_hat - x
    out = {"estimation_rms": float(math.sqrt(np.mean(np.sum(err**2, axis=1))))}
    for i, name in enumerate(names):
        out[f"estimation_rms_{name}"] = float(np.sqrt(np.mean(err[:, i] ** 2)))
    return out
