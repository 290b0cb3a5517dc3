"""Controllers: LQR, linear MPC (OSQP), differential IK as a QP, and whatever else registers.

Every concrete :class:`~shinro_ctrl.controllers.base.Controller` subclass
registers itself under its class name when defined; this package imports each
of its modules on first look-up, so a new module here needs no list edit.
:data:`CONTROLLERS` names the controllers the package ships; each is built from
a plant by its ``from_plant(plant, ...)`` factory, whose keyword names are the
keys a ``[controller]`` table may hold (:func:`controller_keys`).
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

from shinro_ctrl.controllers.base import CONTROLLER_REGISTRY, Controller
from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "CONTROLLERS",
    "CONTROLLER_REGISTRY",
    "IKQP",
    "LQR",
    "Controller",
    "LinearMPC",
    "controller_class",
    "controller_keys",
]

_discovered = False


def _import_all() -> None:
    """Import every public module of this package (once), so each controller has registered itself."""
    global _discovered
    if _discovered:
        return
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_") and not info.ispkg:
            importlib.import_module(f"{__name__}.{info.name}")
    _discovered = True


def _shipped() -> tuple[str, ...]:
    _import_all()
    return tuple(name for name, cls in CONTROLLER_REGISTRY.items() if cls.__module__.startswith(f"{__name__}."))


def controller_class(name: str) -> type[Controller]:
    """The controller class registered as ``name`` (``LQR``, ``LinearMPC``, ``IKQP``, ...).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    if name not in CONTROLLER_REGISTRY:
        _import_all()
    if name not in CONTROLLER_REGISTRY:
        raise ConfigError(f"unknown controller '{name}'{did_you_mean(name, CONTROLLER_REGISTRY)}")
    return CONTROLLER_REGISTRY[name]


def controller_keys(cls: type) -> tuple[str, ...]:
    """The keys a ``[controller]`` table may hold for ``cls`` (``cls.option_keys()``)."""
    return tuple(cls.option_keys())


def __getattr__(name: str) -> Any:  # CONTROLLERS, and LinearMPC, IKQP, ... on first use
    if name == "CONTROLLERS":
        return _shipped()
    if not name.startswith("_"):
        _import_all()
        if name in CONTROLLER_REGISTRY:
            return CONTROLLER_REGISTRY[name]
    raise AttributeError(f"module 'shinro_ctrl.controllers' has no attribute '{name}'")
