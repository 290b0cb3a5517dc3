"""Design analysis of linear state-feedback loops: pure functions over matrices and controllers.

* :func:`pole_table`: damping ratio, natural frequency and time constant of each pole.
* :func:`structure_report`: controllability/observability ranks, PBH per mode, Gramian conditioning.
* :func:`loop_margins`: gain, phase and disk margins at the plant input, sensitivity peaks.
* :func:`step_metrics`: rise time, overshoot, settling time, steady-state error.
* :func:`bryson`: Bryson's-rule weights ``Q = diag(1/x_max²)``, ``R = diag(1/u_max²)``.

python-control is imported only inside the functions that need it, so importing
this package stays cheap (the scenario layer uses :mod:`shinro_ctrl.analysis.weights`).
"""

from shinro_ctrl.analysis.design import DesignAnalysis, analyze_controller, feedback_gain
from shinro_ctrl.analysis.margins import ChannelMargins, LoopMargins, loop_margins
from shinro_ctrl.analysis.poles import PoleRow, PoleTable, pole_table
from shinro_ctrl.analysis.response import StepMetrics, closed_loop_response, step_metrics
from shinro_ctrl.analysis.structure import Mode, StructureReport, structure_report
from shinro_ctrl.analysis.weights import bryson

__all__ = [
    "ChannelMargins",
    "DesignAnalysis",
    "LoopMargins",
    "Mode",
    "PoleRow",
    "PoleTable",
    "StepMetrics",
    "StructureReport",
    "analyze_controller",
    "bryson",
    "closed_loop_response",
    "feedback_gain",
    "loop_margins",
    "pole_table",
    "step_metrics",
    "structure_report",
]
