"""State estimators: what the closed loop feeds the controller instead of the true state.

:class:`Estimator` is the interface; :class:`FullState` (the identity) is the
default. Each estimator class registers itself under its class name when it is
defined; :func:`estimator_class` looks one up for an ``[estimator]`` table.
"""

from __future__ import annotations

import importlib
import pkgutil

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.estimators.base import ESTIMATORS, Estimator
from shinro_ctrl.estimators.full_state import FullState
from shinro_ctrl.estimators.kalman import ExtendedKalmanFilter, KalmanFilter
from shinro_ctrl.estimators.luenberger import Luenberger
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "ESTIMATORS",
    "Estimator",
    "ExtendedKalmanFilter",
    "FullState",
    "KalmanFilter",
    "Luenberger",
    "estimator_class",
]


def _import_all() -> None:
    """Import every module of this package, so every estimator has registered itself."""
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}")


def estimator_class(name: str) -> type[Estimator]:
    """The estimator class named ``name`` (``"FullState"``, ``"KalmanFilter"``, ...).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    if name not in ESTIMATORS:
        _import_all()
    if name not in ESTIMATORS:
        raise ConfigError(f"unknown estimator '{name}'{did_you_mean(name, ESTIMATORS)}")
    return ESTIMATORS[name]
