"""The scenario's tables and keys, and the dataclasses a parsed scenario is made of."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "ENGINE_KEYS",
    "REFERENCE_KINDS",
    "SIM_KEYS",
    "TABLES",
    "ControllerConfig",
    "EngineConfig",
    "EstimatorConfig",
    "PlantConfig",
    "Scenario",
    "SimConfig",
]

TABLES = ("plant", "engine", "controller", "plan", "sim", "estimator", "regression")
ENGINE_KEYS = ("type", "model", "substeps")
SIM_KEYS = (
    "duration",
    "initial_state",
    "reference",
    "track",
    "settle_tol",
    "measurement_noise",
    "seed",
    "measured",
    "sensor_noise",
    "process_noise",
    "disturbance",
    "actuator",
    "sensor",
    "excitation",
)
REFERENCE_KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # kind: (required keys, optional keys)
    "constant": ((), ("value",)),
    "step": (("time",), ("initial", "final")),
    "circle": (("radius", "frequency"), ("center", "axes", "phase")),
    "square": (("side", "speed"), ("center", "axes")),
    "waypoints": (("points", "times"), ("interpolation",)),
}


#: ``[sim] disturbance``: a table or a list of tables (parsed into DisturbanceSpec; checked structurally here).
DisturbanceTables = list
#: ``[sim] excitation``: a table or a list of tables (checked by :func:`shinro_ctrl.sim.excitation.parse_excitation`).
ExcitationTables = list


@dataclass
class PlantConfig:
    """``[plant]``: the class name and its constructor arguments."""

    type: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class EngineConfig:
    """``[engine]``: MuJoCo with an optional model and substeps.

    Attributes:
        type: ``"mujoco"``.
        model: ``"matched"`` (the plant's exact twin), ``"realistic"`` (a built-in plant's realistic variant;
            a model file as written), an MJCF path or a shipped asset name; None: the plant's default
            (``matched`` for the built-in plants, the file as written for ``MjcfPlant``). See
            ``MujocoEngine.for_plant``.
        substeps: ``mj_step`` calls per control step.
    """

    type: str = "mujoco"
    model: str | None = None
    substeps: int = 1


@dataclass
class ControllerConfig:
    """``[controller]``: the class name and the keyword arguments of its ``from_plant``."""

    type: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class SimConfig:
    """``[sim]``: run length, initial state, reference and metric settings.

    Attributes:
        duration: Simulated time [s].
        initial_state: ``(n,)``, default the controller's operating point.
        reference: A reference table (``kind`` plus its keys), default constant.
        track: Names of the states the error metrics use (default: the plant's
            ``tracked_states``).
        settle_tol: Absolute band on the tracking-error norm for ``settling_time``.
        measurement_noise: Standard deviations ``(n,)`` of Gaussian noise added
            to the state the controller sees (seeded by ``seed``).
        seed: Seed of every random draw of the run.
        measured: Names of the measured states, in the order of ``y`` (default all).
        sensor_noise: Standard deviations ``(p,)`` of the Gaussian noise on ``y``.
        process_noise: Standard deviations ``(m,)`` of the Gaussian noise added
            to the applied input (the controller does not see it).
        disturbance: Parsed ``disturbance`` entries
            (:class:`~shinro_ctrl.disturbances.DisturbanceSpec`); see
            :mod:`shinro_ctrl.disturbances`.
        actuator: The ``actuator`` table as written (checked): ``delay``, ``lag``,
            ``quantization``, ``rate_limit``, each a scalar or one value per input
            (:class:`~shinro_ctrl.sim.nonideal.ActuatorModel`).
        sensor: The ``sensor`` table as written (checked): ``delay``, ``quantization``,
            each a scalar or one value per state (:class:`~shinro_ctrl.sim.nonideal.SensorModel`).
        excitation: The ``excitation`` entries as written (checked): PRBS, chirp or multisine signals added to
            the controller's output (:mod:`shinro_ctrl.sim.excitation`).
    """

    duration: float = 5.0
    initial_state: list[float] | None = None
    reference: dict[str, Any] = field(default_factory=lambda: {"kind": "constant"})
    track: list[str] | None = None
    settle_tol: float = 0.01
    measurement_noise: list[float] | None = None
    seed: int = 0
    measured: list[str] | None = None
    sensor_noise: list[float] | None = None
    process_noise: list[float] | None = None
    disturbance: DisturbanceTables | None = None
    actuator: dict[str, Any] | None = None
    sensor: dict[str, Any] | None = None
    excitation: ExcitationTables | None = None


@dataclass
class EstimatorConfig:
    """``[estimator]``: the estimator class name and the keyword arguments of its ``from_plant``.

    ``measured`` comes from ``[sim] measured``; ``Qn`` and ``Rn``, when the
    table leaves them out, from ``[sim] process_noise`` and ``sensor_noise``
    (variances: the standard deviations squared).
    """

    type: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class Scenario:
    """A parsed scenario.

    Attributes:
        name: File stem (or ``"<dict>"``).
        path: Source file, or None for a dict.
        plant, engine, controller, sim: The parsed tables (``engine`` None when standalone).
        regression: Metric → ``{"rel": r, "abs": a}`` tolerances.
        raw: The document as loaded (for saving the resolved config).
        plan: The validated ``[plan]`` table (also passed to the controller as its
            ``plan`` option), or None.
    """

    name: str
    path: Path | None
    plant: PlantConfig
    engine: EngineConfig | None
    controller: ControllerConfig
    sim: SimConfig
    regression: dict[str, dict[str, float]]
    raw: dict[str, Any]
    plan: dict[str, Any] | None = None
    estimator: EstimatorConfig | None = None
