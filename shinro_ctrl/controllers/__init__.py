"""Controllers: LQR, linear MPC (OSQP) and differential IK as a QP.

:data:`CONTROLLERS` maps class names to classes; each is built from a plant
by its ``from_plant(plant, ...)`` factory, whose keyword names are the keys a
``[controller]`` table may hold (:func:`controller_keys`).
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean

__all__ = ["CONTROLLERS", "IKQP", "LQR", "Controller", "LinearMPC", "controller_class", "controller_keys"]

# Class name -> module; imported lazily so a missing optional piece never breaks LQR.
_MODULES = {"LQR": "lqr", "LinearMPC": "mpc", "IKQP": "ik_qp"}
CONTROLLERS = tuple(_MODULES)


def controller_class(name: str) -> type:
    """The controller class named ``name`` (``LQR``, ``LinearMPC`` or ``IKQP``).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    if name not in _MODULES:
        raise ConfigError(f"unknown controller '{name}'{did_you_mean(name, _MODULES)}")
    module = importlib.import_module(f"shinro_ctrl.controllers.{_MODULES[name]}")
    return getattr(module, name)


def controller_keys(cls: type) -> tuple[str, ...]:
    """The keyword names of ``cls.from_plant`` after the plant argument (``cls.option_keys()`` when defined)."""
    if hasattr(cls, "option_keys"):
        return tuple(cls.option_keys())
    params = list(inspect.signature(cls.from_plant).parameters.values())[1:]
    return tuple(p.name for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))


def __getattr__(name: str) -> Any:  # LinearMPC, IKQP on first use
    if name in _MODULES:
        return controller_class(name)
    raise AttributeError(f"module 'shinro_ctrl.controllers' has no attribute '{name}'")
