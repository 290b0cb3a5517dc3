"""Plant models: dynamics written once, evaluated numerically and symbolically."""

from shinro_ctrl.plants.base import MjcfPatch, Plant
from shinro_ctrl.plants.cartpole import CartPole
from shinro_ctrl.plants.double_pendulum import DoublePendulum
from shinro_ctrl.plants.inverted_pendulum import InvertedPendulum

__all__ = ["CartPole", "DoublePendulum", "InvertedPendulum", "MjcfPatch", "Plant"]
