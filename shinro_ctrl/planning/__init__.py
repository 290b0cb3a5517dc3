"""Trajectory optimization: direct transcription of the plants' exact dynamics, solved with IPOPT.

:class:`TrajectoryOptimizer` builds the NLP once per plant and transcription
and re-solves it; :class:`Trajectory` holds the result with the interpolants
its transcription implies. See ``docs/planning.md``.
"""

from shinro_ctrl.planning.collocation import COSTS, TrajectoryOptimizer
from shinro_ctrl.planning.spec import check_origin, plan_origin, with_plan_file
from shinro_ctrl.planning.trajectory import METHODS, Trajectory

__all__ = ["COSTS", "METHODS", "Trajectory", "TrajectoryOptimizer", "check_origin", "plan_origin", "with_plan_file"]
