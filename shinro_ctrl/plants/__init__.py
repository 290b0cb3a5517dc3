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
    "Plant",
    "Quadrotor",
    "plant_class",
]

PLANTS: dict[str, type[Plant]] = {
    "InvertedPendulum": InvertedPendulum,
    "CartPole": CartPole,
    "DoublePendulum": DoublePendulum,
    "HolonomicMobileRobot": HolonomicMobileRobot,
    "Quadrotor": Quadrotor,
    "ArmRobot": ArmRobot,
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
    key = PLANT_ALIASES.get(name, name)
    if key not in PLANTS:
        raise ConfigError(f"unknown plant '{name}'{did_you_mean(name, [*PLANTS, *PLANT_ALIASES])}")
    return PLANTS[key]
