"""State estimators: what the closed loop feeds the controller instead of the true state.

:class:`Estimator` is the interface; :class:`FullState` (the identity) is the
default. Each concrete estimator class registers itself in
:data:`ESTIMATOR_REGISTRY` (a :class:`~shinro_ctrl.registry.Registry`) under
its class name when it is defined; this package imports each estimator module
below, and :func:`estimator_class` looks one up for an ``[estimator]`` table.
"""

from __future__ import annotations

from shinro_ctrl.estimators.base import ESTIMATOR_REGISTRY, Estimator
from shinro_ctrl.estimators.full_state import FullState
from shinro_ctrl.estimators.kalman import ExtendedKalmanFilter, KalmanFilter
from shinro_ctrl.estimators.luenberger import Luenberger

__all__ = [
    "ESTIMATORS",
    "ESTIMATOR_REGISTRY",
    "Estimator",
    "ExtendedKalmanFilter",
    "FullState",
    "KalmanFilter",
    "Luenberger",
    "estimator_class",
]

#: Class name -> class of every estimator this package ships.
ESTIMATORS: dict[str, type[Estimator]] = ESTIMATOR_REGISTRY.shipped()


def estimator_class(name: str) -> type[Estimator]:
    """The estimator class named ``name`` (``"FullState"``, ``"KalmanFilter"``, or one defined elsewhere).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    return ESTIMATOR_REGISTRY.lookup(name)
