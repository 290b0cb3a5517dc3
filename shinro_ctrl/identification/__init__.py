"""Grey-box identification of a plant's physical parameters from logged data, with honest uncertainty.

From sampled inputs and measured outputs (:mod:`~shinro_ctrl.identification.data`: ``run --out``
results or CSV files with named columns), :func:`identify` estimates chosen physical parameters of a
plant by least squares over its exact CasADi dynamics (:mod:`~shinro_ctrl.identification.estimate`),
reports standard errors, 95 % intervals, correlations and the combinations the data cannot determine
(:mod:`~shinro_ctrl.identification.uncertainty`) and the fit on held-out data
(:mod:`~shinro_ctrl.identification.fit`). The result (:class:`IdentificationResult`) gives the
parameters a scenario's ``[plant]`` table takes, so design and runs start from the identified plant.
"""

from shinro_ctrl.identification.data import Experiment, check_sampling, experiment, load_data, select_outputs
from shinro_ctrl.identification.estimate import IdentificationError, identify
from shinro_ctrl.identification.fit import FitReport, compare, fit_percent, nrmse, plot_fit
from shinro_ctrl.identification.result import IdentificationResult
from shinro_ctrl.identification.uncertainty import Uncertainty, parameter_uncertainty

__all__ = [
    "Experiment",
    "FitReport",
    "IdentificationError",
    "IdentificationResult",
    "Uncertainty",
    "check_sampling",
    "compare",
    "experiment",
    "fit_percent",
    "identify",
    "load_data",
    "nrmse",
    "parameter_uncertainty",
    "plot_fit",
    "select_outputs",
]
