r"""How well a model reproduces measured outputs: normalized RMSE, MATLAB's fit %, and the plot.

For an output ``y (N,)`` and the model's ``ŷ``

.. math::

    \mathrm{NRMSE} = \frac{\lVert y - \hat y\rVert}{\lVert y - \bar y\rVert}, \qquad
    \mathrm{fit} = 100\,(1 - \mathrm{NRMSE})\ \%,

as MATLAB's ``compare`` reports it: 100 % is a perfect fit, 0 % no better than the mean, negative worse.
:func:`compare` scores an identified model on held-out data: the model's parameters fixed at the
estimates, only the initial states of its shooting segments are estimated (the segments the
identification used, so an open-loop unstable plant is compared over the horizon it was fitted on).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from shinro_ctrl.identification.data import Experiment
    from shinro_ctrl.identification.result import IdentificationResult
    from shinro_ctrl.plants.base import Plant

__all__ = ["FitReport", "compare", "fit_percent", "nrmse", "plot_fit"]


def nrmse(y: np.ndarray, yhat: np.ndarray) -> float:
    """``‖y − ŷ‖ / ‖y − ȳ‖`` (inf when ``y`` is constant and the model misses it, 0 when it does not)."""
    y, yhat = np.asarray(y, float).ravel(), np.asarray(yhat, float).ravel()
    num = float(np.linalg.norm(y - yhat))
    den = float(np.linalg.norm(y - y.mean()))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return num / den


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """MATLAB's fit: ``100 (1 − NRMSE)`` [%]."""
    return 100.0 * (1.0 - nrmse(y, yhat))


@dataclass(frozen=True)
class FitReport:
    """Measured against model outputs of one experiment.

    Attributes:
        t: Times ``(N,)``; y: measured ``(N, p)``; yhat: model ``(N, p)``; outputs: names.
        fit_percent, nrmse: Per output.
        source: The experiment's name; segment: samples per simulated segment (0: the whole run).
    """

    t: np.ndarray
    y: np.ndarray
    yhat: np.ndarray
    outputs: tuple[str, ...]
    fit_percent: dict[str, float]
    nrmse: dict[str, float]
    source: str
    segment: int

    def line(self) -> str:
        """``"fit on <source>: x 97.1 %, theta 95.0 %"``."""
        return f"fit on {self.source}: " + ", ".join(f"{k} {v:.1f} %" for k, v in self.fit_percent.items())


def compare(plant: Plant, result: IdentificationResult, data: Experiment) -> FitReport:
    """Fit of the identified model on (held-out) ``data``: parameters fixed, segment starts estimated.

    Args:
        plant: The plant identified (its class and fixed parameters; the estimates replace the rest).
        result: :func:`~shinro_ctrl.identification.identify`'s result.
        data: An experiment not used for the estimation.
    """
    from shinro_ctrl.identification.estimate import simulate_segments

    yhat = simulate_segments(plant, result, data)
    fits = {o: fit_percent(data.y[:, j], yhat[:, j]) for j, o in enumerate(data.outputs)}
    nr = {o: nrmse(data.y[:, j], yhat[:, j]) for j, o in enumerate(data.outputs)}
    return FitReport(data.t, data.y, yhat, data.outputs, fits, nr, data.source, result.segment)


def plot_fit(reports: FitReport | list[FitReport], path: str | Path, *, title: str = "") -> Path:
    """Measured (dots) against model (line) outputs, one panel per output, one column per experiment."""
    from shinro_ctrl.plots._figure import _new_figure, save_figure

    reports = [reports] if isinstance(reports, FitReport) else list(reports)
    rows = max(len(r.outputs) for r in reports)
    cols = len(reports)
    fig = _new_figure(5.0 * cols, 2.0 * rows + 0.6)
    for c, r in enumerate(reports):
        for j, o in enumerate(r.outputs):
            ax = fig.add_subplot(rows, cols, j * cols + c + 1)
            ax.plot(r.t, r.y[:, j], ".", ms=2, color="0.55", label="measured")
            ax.plot(r.t, r.yhat[:, j], "-", lw=1.2, color="C0", label="model")
            ax.set_ylabel(o)
            ax.set_title(f"{Path(r.source).name}: {o} fit {r.fit_percent[o]:.1f} %", fontsize=9)
            if j == len(r.outputs) - 1:
                ax.set_xlabel("t [s]")
            if j == 0 and c == 0:
                ax.legend(fontsize=8, loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
