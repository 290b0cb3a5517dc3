"""Plant models: dynamics written once, evaluated numerically and symbolically.

:data:`PLANTS` maps each class name to its class and :data:`PLANT_ALIASES`
maps the short command-line names (``cartpole``, ``pendulum``, …) to class
names; :func:`plant_class` resolves either.
"""

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.plants.armrobot import ArmRobot
from shinro_ctrl.plants.base import MjcfPatch, Plant
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

PLANTS: dict[str, type[Plant]] = {
    "InvertedPendulum": InvertedPendulum,
    "CartPole": CartPole,
    "DoublePendulum": DoublePendulum,
    "HolonomicMobileRobot": HolonomicMobileRobot,
    "Quadrotor": Quadrotor,
    "ArmRobot": ArmRobot,
    "MjcfPlant": MjcfPlant,
}

PLANT_ALIASES: dict[str, str] = {
    "pendulum": "InvertedPendulum",
    "cartpole": "CartPole",
    "double_pendulum": "DoublePendulum",
    "holonomic": "HolonomicMobileRobot",
    "quadrotor": "Quadrotor",
    "arm6": "ArmRobot",
}


def plant_class(name: str) -> type[Plant]:
    """The plant class for a class name (``"CartPole"``) or alias (``"cartpole"``).

    Raises:
        ConfigError: unknown name, with the closest known one.
    """
    if is_model_file(name):  # a model file: MjcfPlant (the caller passes the file as ``model``)
        return MjcfPlant
    key = PLANT_ALIASES.get(name, name)
    if key not in PLANTS:
        raise ConfigError(f"unknown plant '{name}'{did_you_mean(name, [*PLANTS, *PLANT_ALIASES])}")
    return PLANTS[key]


def plant_from_name(name: str) -> Plant:
    """A plant with its defaults from a class name, an alias, or an MJCF/URDF model file (``MjcfPlant(name)``).

    Raises:
        ConfigError: unknown name, with the closest known one.
        FileNotFoundError: a model file that does not exist.
    """
    if is_model_file(name):
        return MjcfPlant(name)
    return plant_class(name)()
