"""Controllers: LQR, linear MPC (OSQP or DAQP), nonlinear MPC, TVLQR, differential IK as a QP.

Every concrete :class:`~shinro_ctrl.controllers.base.Controller` subclass
registers itself in :data:`CONTROLLER_REGISTRY` (a
:class:`~shinro_ctrl.registry.Registry`) under its class name when defined,
in this package or anywhere else. This package imports each controller module
below, so importing it registers every shipped controller (a new module here
adds its import line). :data:`CONTROLLERS` names the controllers the package
ships; each is built from a plant by its ``from_plant(plant, ...)`` factory,
whose keyword names are the keys a ``[controller]`` table may hold
(:func:`controller_keys`).
"""

from __future__ import annotations

from shinro_ctrl.controllers.base import CONTROLLER_REGISTRY, Controller
from shinro_ctrl.controllers.exported import Exported
from shinro_ctrl.controllers.ik_qp import IKQP
from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.controllers.mpc import LinearMPC
from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.controllers.tvlqr import TVLQR

__all__ = [
    "CONTROLLERS",
    "CONTROLLER_REGISTRY",
    "IKQP",
    "LQR",
    "TVLQR",
    "Controller",
    "Exported",
    "LinearMPC",
    "NonlinearMPC",
    "controller_class",
    "controller_keys",
]

#: Class names of the controllers this package ships, in order of definition.
CONTROLLERS: tuple[str, ...] = tuple(CONTROLLER_REGISTRY.names(shipped=True))


def controller_class(name: str) -> type[Controller]:
    """The controller class registered as ``name`` (``LQR``, ``LinearMPC``, ``IKQP``, or one defined elsewhere).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    return CONTROLLER_REGISTRY.lookup(name)


def controller_keys(cls: type[Controller]) -> tuple[str, ...]:
    """The keys a ``[controller]`` table may hold for ``cls`` (``cls.option_keys()``)."""
    return tuple(cls.option_keys())
