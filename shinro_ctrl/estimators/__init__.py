"""State estimators: what the closed loop feeds the controller instead of the true state.

:class:`Estimator` is the interface; :class:`FullState` (the identity) is the
default. Kalman filters and observers join here.
"""

from shinro_ctrl.estimators.base import Estimator
from shinro_ctrl.estimators.full_state import FullState

__all__ = ["Estimator", "FullState"]
