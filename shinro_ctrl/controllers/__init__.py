"""Controllers: LQR, linear MPC (OSQP) and differential IK as a QP."""

from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.lqr import LQR

__all__ = ["LQR", "Controller"]
