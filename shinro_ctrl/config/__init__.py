"""Scenario files: strict TOML parsing into dataclasses.

A scenario has the tables ``[plant]`` (required), ``[engine]`` (optional;
absent means standalone), ``[controller]`` (required), ``[plan]`` (only with
a controller that tracks a plan, TVLQR), ``[sim]`` (optional), ``[estimator]``
(optional; output feedback) and ``[regression]`` (only for regression
scenarios). The docs page docs/scenarios.md lists every key.

Parsing is strict and runs table by table in that order: an unknown table or
key raises :class:`~shinro_ctrl.errors.ConfigError` naming the file, the
table and the key, with the closest valid key ("did you mean …?"); a wrong
type or an out-of-range value names the key. Shapes (initial state, weights,
bounds) are checked against the plant, whose class is resolved here, so a
scenario that loads is one that can be built.

The package's modules: :mod:`~shinro_ctrl.config.schema` (tables, keys and the
dataclasses), :mod:`~shinro_ctrl.config.parse` (loading; ``[plant]``,
``[engine]``, ``[controller]``, ``[plan]``, ``[regression]``),
:mod:`~shinro_ctrl.config.sim_table` (``[sim]``, ``[estimator]``; ``[sim] actuator`` and ``sensor`` in
:mod:`~shinro_ctrl.config.nonideal_table`),
:mod:`~shinro_ctrl.config.strict` (strict value types) and
:mod:`~shinro_ctrl.config.context` (error messages). Every name is importable
from ``shinro_ctrl.config``.
"""

from shinro_ctrl.config.context import ConfigContext, whole_steps
from shinro_ctrl.config.nonideal_table import ACTUATOR_KEYS, SENSOR_KEYS, delay_steps, nonideal_channels
from shinro_ctrl.config.parse import load_scenario, parse_scenario
from shinro_ctrl.config.schema import (
    ENGINE_KEYS,
    REFERENCE_KINDS,
    SIM_KEYS,
    TABLES,
    ControllerConfig,
    DisturbanceTables,
    EngineConfig,
    EstimatorConfig,
    PlantConfig,
    Scenario,
    SimConfig,
)
from shinro_ctrl.config.strict import (
    MAX_ELEMENTS,
    MAX_NESTING,
    SIZE_LIMITS,
    check_value,
    signature_annotations,
    table_annotations,
    toml_type,
)

__all__ = [
    "ACTUATOR_KEYS",
    "ENGINE_KEYS",
    "MAX_ELEMENTS",
    "MAX_NESTING",
    "REFERENCE_KINDS",
    "SENSOR_KEYS",
    "SIM_KEYS",
    "SIZE_LIMITS",
    "TABLES",
    "ConfigContext",
    "ControllerConfig",
    "DisturbanceTables",
    "EngineConfig",
    "EstimatorConfig",
    "PlantConfig",
    "Scenario",
    "SimConfig",
    "check_value",
    "delay_steps",
    "load_scenario",
    "nonideal_channels",
    "parse_scenario",
    "signature_annotations",
    "table_annotations",
    "toml_type",
    "whole_steps",
]
