"""Plant models: dynamics written once, evaluated numerically and symbolically.

Every :class:`~shinro_ctrl.plants.base.Plant` subclass registers itself in
:data:`~shinro_ctrl.plants.base.PLANT_REGISTRY` (a
:class:`~shinro_ctrl.registry.Registry`) under its class name (and its
``aliases``) when defined; this package imports each plant module below (a new
module here adds its import line).
:data:`PLANTS` maps the class name of each plant the package ships to its
class and :data:`PLANT_ALIASES` maps the short command-line names
(``cartpole``, ``pendulum``, …) to class names; :func:`plant_class` resolves
either (and any registered plant, e.g. one defined in a test).
"""

from shinro_ctrl.plants.armrobot import ArmRobot
from shinro_ctrl.plants.base import PLANT_REGISTRY, MjcfPatch, Plant
from shinro_ctrl.plants.cartpole import CartPole
from shinro_ctrl.plants.double_pendulum import DoublePendulum
from shinro_ctrl.plants.holonomic import HolonomicMobileRobot
from shinro_ctrl.plants.inverted_pendulum import InvertedPendulum
from shinro_ctrl.plants.mjcf import MjcfPlant, is_model_file
from shinro_ctrl.plants.quadrotor import Quadrotor

__all__ = [
    "PLANTS",
    "PLANT_ALIASES",
    "PLANT_REGISTRY",
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

#: Class name -> class of every plant this package ships.
PLANTS: dict[str, type[Plant]] = PLANT_REGISTRY.shipped()

#: Alias -> class name of the shipped plants (from each plant's ``aliases``).
PLANT_ALIASES: dict[str, str] = {alias: name for alias, name in PLANT_REGISTRY.aliases.items() if name in PLANTS}


def plant_class(name: str) -> type[Plant]:
    """The plant class for a class name (``"CartPole"``) or alias (``"cartpole"``).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    if is_model_file(name):  # a model file: MjcfPlant (the caller passes the file as ``model``)
        return MjcfPlant
    return PLANT_REGISTRY.lookup(name)


def plant_from_name(name: str) -> Plant:
    """A plant with its defaults from a class name, an alias, or an MJCF/URDF model file (``MjcfPlant(name)``).

    Raises:
        ConfigError: unknown name, with the closest known one.
        FileNotFoundError: a model file that does not exist.
    """
    if is_model_file(name):
        return MjcfPlant(name)
    return plant_class(name)()
