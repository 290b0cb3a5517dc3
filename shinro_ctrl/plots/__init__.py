"""Plots a control engineer reads: closed-loop runs (one loop, or standalone and MuJoCo overlaid).

Every function draws on a fresh :class:`matplotlib.figure.Figure` with the Agg
canvas and writes a PNG, PDF or SVG (by the extension) atomically; none touches pyplot's global state or
calls ``matplotlib.use`` (the backend is the caller's choice).

Units come from the plant's state and input names (:func:`unit_of`: a plant
may also declare ``state_units`` / ``input_units``); figures keep at most
:data:`MAX_ROWS` rows by grouping signals of one kind (position, attitude,
velocity, rate, inputs by unit) on shared axes.

The package's modules: :mod:`~shinro_ctrl.plots.units` (units, panels),
:mod:`~shinro_ctrl.plots.run` (:func:`run_figure`, :func:`plot_run`) and
:mod:`~shinro_ctrl.plots.sweep` (:func:`sweep_figure`, :func:`plot_sweep`);
every name is importable from ``shinro_ctrl.plots``.
"""

from shinro_ctrl.plots.run import PLANAR_KINDS, plot_run, run_figure
from shinro_ctrl.plots.sweep import plot_sweep, sweep_figure
from shinro_ctrl.plots.units import MAX_ROWS, axis_label, param_unit, signal_groups, unit_of

__all__ = [
    "MAX_ROWS",
    "PLANAR_KINDS",
    "axis_label",
    "param_unit",
    "plot_run",
    "plot_sweep",
    "run_figure",
    "signal_groups",
    "sweep_figure",
    "unit_of",
]
