"""Closed-loop simulation of a scenario: plant + (engine) + controller + reference.

:class:`RobotSim` builds everything a scenario names; :meth:`RobotSim.run`
steps the loop ``y_k = C x_k + noise``, ``x̂_k = estimator.update(y_k,
u_{k-1})``, ``u_k = controller(x̂_k, r(t_k))``, ``x_{k+1} = plant.step(u_k)``
(the controller never sees the plant's state, only the estimate; the default
:class:`~shinro_ctrl.estimators.full_state.FullState` passes ``y`` through) and
returns a :class:`SimResult` with the trajectories and
the metrics that regression baselines are made of.

The package's modules: :mod:`~shinro_ctrl.sim.robot` (the loop),
:mod:`~shinro_ctrl.sim.result` (:class:`SimResult`), :mod:`~shinro_ctrl.sim.reference`
(:class:`Reference`), :mod:`~shinro_ctrl.sim.metrics` and :mod:`~shinro_ctrl.sim.nonideal`
(:class:`ActuatorModel`, :class:`SensorModel`: ``[sim] actuator`` and ``sensor``); every name is importable from
``shinro_ctrl.sim``.
"""

from shinro_ctrl.sim.metrics import NEVER_METRICS, bound_excess, compute_metrics, format_metrics, response_metrics
from shinro_ctrl.sim.nonideal import ActuatorModel, SensorModel
from shinro_ctrl.sim.reference import Reference
from shinro_ctrl.sim.result import SimResult
from shinro_ctrl.sim.robot import MAX_STEPS, RobotSim

__all__ = [
    "MAX_STEPS",
    "NEVER_METRICS",
    "ActuatorModel",
    "Reference",
    "RobotSim",
    "SensorModel",
    "SimResult",
    "bound_excess",
    "compute_metrics",
    "format_metrics",
    "response_metrics",
]
