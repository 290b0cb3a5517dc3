"""The result of one closed-loop run: :class:`SimResult` (trajectories, metrics, save, plot)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.files import atomic_write, dump_json, dump_toml

__all__ = ["SimResult"]


@dataclass
class SimResult:
    """Trajectories and metrics of one closed-loop run.

    Attributes:
        t: Times ``(T + 1,)`` [s].
        x: States ``(T + 1, n)``.
        u: Inputs ``(T, m)``.
        ref: References ``(T + 1, n)``.
        metrics: See :func:`~shinro_ctrl.sim.compute_metrics` and
            :data:`~shinro_ctrl.sim.metrics.METRIC_REGISTRY`: numbers, the
            ``stable`` flag, and None for a metric that is undefined (a
            settling time that never happened); ``metrics.json`` writes it as null.
        state_names, input_names: Labels.
        tracked: Names of the states the error metrics use.
        u_min, u_max, x_min, x_max: Bounds for plots (None where absent).
        solve_times: Controller call times ``(T,)`` [s].
        scenario: The scenario name; ``loop``: ``"standalone"`` or ``"mujoco"``.
        config: The resolved scenario document.
        x_hat: State estimates the controller was fed ``(T + 1, n)`` (the
            true state for full-state feedback without noise).
        y: Measurements ``(T + 1, p)`` (measured states plus sensor noise).
        measured: Names of the columns of ``y``.
        disturbance: Disturbances ``(T, k)`` held over each step (see
            :mod:`shinro_ctrl.disturbances`); ``disturbance_labels`` names
            the columns.
        plan: The tracked plan's states ``(T + 1, n)``, NaN past its span, for a
            plan-tracking controller (TVLQR); plots draw it as the reference.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    ref: np.ndarray
    metrics: dict[str, float | int | bool | None]
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    tracked: list[str]
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    x_min: np.ndarray | None = None
    x_max: np.ndarray | None = None
    solve_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    scenario: str = "<dict>"
    loop: str = "standalone"
    config: dict[str, Any] = field(default_factory=dict)
    x_hat: np.ndarray | None = None
    y: np.ndarray | None = None
    measured: tuple[str, ...] = ()
    disturbance: np.ndarray | None = None
    disturbance_labels: list[str] = field(default_factory=list)
    plan: np.ndarray | None = None

    def save(self, directory: str | Path) -> Path:
        """Write ``result.npz``, ``metrics.json`` and ``scenario.toml`` into ``directory`` (atomically)."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        arrays = {"t": self.t, "x": self.x, "u": self.u, "ref": self.ref, "solve_times": self.solve_times}
        for key in ("x_hat", "y", "disturbance", "plan"):
            if getattr(self, key) is not None:
                arrays[key] = getattr(self, key)
        atomic_write(d / "result.npz", lambda f: np.savez(f, **arrays), binary=True)
        dump_json(d / "metrics.json", {"scenario": self.scenario, "loop": self.loop, "metrics": self.metrics})
        atomic_write(d / "scenario.toml", lambda f: f.write(dump_toml(self.config)))
        return d

    def plot(self, path: str | Path, *, compare: SimResult | None = None) -> Path:
        """Plot the run to a PNG (see :func:`shinro_ctrl.plots.plot_run`).

        States with references, bounds and the settling band, inputs with bounds,
        units on every axis, an x–y panel for planar tasks; ``compare`` (the other
        loop's result) is drawn over it with the metric differences.
        """
        from shinro_ctrl.plots import plot_run

        return plot_run(self, path, compare=compare)
