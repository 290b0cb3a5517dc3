"""Plant models: dynamics written once, evaluated numerically and symbolically.

Every :class:`~shinro_ctrl.plants.base.Plant` subclass registers itself under
its class name (and its ``aliases``) when defined, and this package imports
each of its modules, so a new plant module here needs no list edit.
:data:`PLANTS` maps the class name of each plant the package ships to its
class and :data:`PLANT_ALIASES` maps the short command-line names
(``cartpole``, ``pendulum``, …) to class names; :func:`plant_class` resolves
either (and any registered plant, e.g. one defined in a test).
"""

import importlib
import pkgutil

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.plants.armrobot import ArmRobot
from shinro_ctrl.plants.base import PLANT_ALIASES_REGISTRY, PLANT_REGISTRY, MjcfPatch, Plant
from shinro_ctrl.plants.cartpole import CartPole
from shinro_ctrl.plants.double_pendulum import DoublePendulum
from shinro_ctrl.plants.holonomic import HolonomicMobileRobot
from shinro_ctrl.plants.inverted_pendulum import InvertedPendulum
from shinro_ctrl.plants.mjcf import MjcfPlant, is_model_file
from shinro_ctrl.plants.quadrotor import Quadrotor
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "PLANTS",
    "PLANT_ALIASES",
    "ArmRobot",
    "CartPole",
    "DoublePendulum",
    "HolonomicMobileRobot",
    "InvertedPendulum",
    "MjcfPatch",
    "MjcfPlant",
    "Plant",
    "Quadrotor",
    "plant_class",
    "plant_from_name",
]

for _info in pkgutil.iter_modules(__path__):  # every plant module registers its classes on import
    if not _info.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_info.name}")

#: Class name -> class of every plant this package ships (a view of the registry at import).
PLANTS: dict[str, type[Plant]] = {
    name: cls for name, cls in PLANT_REGISTRY.items() if cls.__module__.startswith(f"{__name__}.")
}

#: Alias -> class name (from each plant's ``aliases``).
PLANT_ALIASES: dict[str, str] = PLANT_ALIASES_REGISTRY


def plant_class(name: str) -> type[Plant]:
    """The plant class for a class name (``"CartPole"``) or alias (``"cartpole"``).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    if is_model_file(name):  # a model file: MjcfPlant (the caller passes the file as ``model``)
        return MjcfPlant
    key = PLANT_ALIASES.get(name, name)
    if key not in PLANT_REGISTRY:
        raise ConfigError(f"unknown plant '{name}'{did_you_mean(name, [*PLANT_REGISTRY, *PLANT_ALIASES])}")
    return PLANT_REGISTRY[key]


def plant_from_name(name: str) -> Plant:
    """A plant with its defaults from a class name, an alias, or an MJCF/URDF model file (``MjcfPlant(name)``).

    Raises:
        ConfigError: unknown name, with the closest known one.
        FileNotFoundError: a model file that does not exist.
    """
    if is_model_file(name):
        return MjcfPlant(name)
    return plant_class(name)()
