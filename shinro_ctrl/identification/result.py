"""The result of a grey-box identification: :class:`IdentificationResult`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["IdentificationResult"]


@dataclass
class IdentificationResult:
    r"""Estimated parameters with their uncertainty, the identifiability report and the fit.

    Attributes:
        plant_type: The plant's class name.
        params: Names of the parameters asked for, in order.
        estimate: Parameter name → estimate (a parameter left at its prior has the prior here).
        prior: Parameter name → the value the plant had (the starting point).
        std_error: Parameter name → standard error from the Fisher information (Cramér–Rao bound with
            the noise variances estimated from the residuals); 0 for a parameter held at its prior.
        interval: Parameter name → 95 % interval ``estimate ± 1.96 std_error``.
        correlation: Correlation matrix ``(k, k)`` of the estimates (``params``' order).
        unidentifiable: One sentence per direction of parameter space the data cannot determine, naming
            the parameters (``"pole_mass and cart_mass enter only as their sum in this experiment"``).
        held: Parameters pinned at their prior because the data cannot see them.
        warnings: Everything the user should read (unidentifiable combinations, strong correlations).
        noise_std: Output name → the sensor noise standard deviation estimated from the residuals.
        fit_percent: Output name → MATLAB's fit ``100 (1 - ‖y - ŷ‖ / ‖y - ȳ‖)`` on the estimation data.
        nrmse: Output name → ``‖y - ŷ‖ / ‖y - ȳ‖`` on the estimation data.
        x0: Estimated initial state ``(n,)`` of each experiment.
        mode: ``"simulation"`` or ``"prediction"``.
        segment: Samples per shooting segment (simulation mode; each segment's start is estimated).
        fixed_params: Every plant parameter that was not estimated, with its value.
        cost: Final weighted least-squares cost ``½ Σ r²``.
        iterations: Solver iterations; solve_time: wall time of the whole identification [s].
        success: Whether the solver converged.
        discretization: ``"plant"`` (the plant's own step) or ``"rk4"``; dt: the sample interval [s].
    """

    plant_type: str
    params: tuple[str, ...]
    estimate: dict[str, float]
    prior: dict[str, float]
    std_error: dict[str, float]
    interval: dict[str, tuple[float, float]]
    correlation: np.ndarray
    unidentifiable: list[str] = field(default_factory=list)
    held: tuple[str, ...] = ()
    warnings: list[str] = field(default_factory=list)
    noise_std: dict[str, float] = field(default_factory=dict)
    fit_percent: dict[str, float] = field(default_factory=dict)
    nrmse: dict[str, float] = field(default_factory=dict)
    x0: list[np.ndarray] = field(default_factory=list)
    mode: str = "simulation"
    segment: int = 0
    fixed_params: dict[str, float] = field(default_factory=dict)
    cost: float = float("nan")
    iterations: int = 0
    solve_time: float = 0.0
    success: bool = True
    discretization: str = "plant"
    dt: float = 0.0

    @property
    def plant_params(self) -> dict[str, float]:
        """Every physical parameter of the identified plant: the estimates and the fixed ones."""
        return {**self.fixed_params, **self.estimate}

    def table(self) -> str:
        """The parameter table: estimate, prior, standard error and 95 % interval, one row a parameter."""
        w = max(9, *(len(p) for p in self.params))
        lines = [f"{'parameter':<{w}}  {'estimate':>11}  {'prior':>11}  {'std error':>10}  95 % interval"]
        for p in self.params:
            lo, hi = self.interval[p]
            note = "  (held at prior)" if p in self.held else ""
            lines.append(
                f"{p:<{w}}  {self.estimate[p]:>11.5g}  {self.prior[p]:>11.5g}  {self.std_error[p]:>10.3g}  "
                f"[{lo:.5g}, {hi:.5g}]{note}"
            )
        return "\n".join(lines)

    def summary(self) -> str:
        """The table, the fit per output, the noise estimates and every warning, as printed by the CLI."""
        out = [self.table(), ""]
        out.append(
            "fit (estimation data): "
            + ", ".join(f"{k} {v:.1f} %" for k, v in self.fit_percent.items())
            + f"   [{self.mode} error, {self.iterations} iterations, {self.solve_time:.2f} s]"
        )
        out.append("noise std (from residuals): " + ", ".join(f"{k} {v:.3g}" for k, v in self.noise_std.items()))
        out += [f"warning: {w}" for w in self.warnings]
        return "\n".join(out)
