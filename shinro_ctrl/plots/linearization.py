"""Plots that explain a linearization: the FD step-size sweep and the three-way crosscheck."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.linearization import complex_step_jacobians
from shinro_ctrl.plots._figure import save_figure

__all__ = ["EpsSweep", "crosscheck_figure", "eps_sweep", "plot_crosscheck", "plot_eps_sweep"]


@dataclass(frozen=True)
class EpsSweep:
    """Finite-difference error against the step size.

    Attributes:
        eps: Steps ``(k,)``.
        fd_error: ``max |J_fd(eps) − J_cs|`` for each step ``(k,)``.
        exact_error: ``max |J_exact − J_cs|`` (the exact Jacobian's agreement).
        best_eps: The step with the smallest FD error.
    """

    eps: np.ndarray
    fd_error: np.ndarray
    exact_error: float
    best_eps: float


def eps_sweep(plant: Any, x0: Any = None, u0: Any = None, *, eps: np.ndarray | None = None) -> EpsSweep:
    """Central-FD error over a range of steps, against a complex-step reference.

    Truncation error falls as ``eps²`` and rounding error grows as
    ``1e-16 / eps``; their sum is the V-shaped curve with its minimum near
    ``eps ≈ 1e-5``. The exact (CasADi) Jacobian sits at rounding level.
    """
    x0, u0 = plant.operating_point(x0, u0)
    eps = np.logspace(-13, -1, 49) if eps is None else np.asarray(eps, dtype=float)
    Ar, Br = complex_step_jacobians(plant, x0, u0)
    ref = np.hstack([Ar, Br])
    errs = np.array([np.abs(np.hstack(plant.linearize(x0, u0, method="fd", eps=e)) - ref).max() for e in eps])
    exact = float(np.abs(np.hstack(plant.linearize(x0, u0)) - ref).max())
    return EpsSweep(eps, errs, exact, float(eps[int(np.argmin(errs))]))


def _figure(nrows: int, ncols: int, size: tuple[float, float]):
    """A figure on the Agg canvas (no pyplot state, no ``matplotlib.use``: the backend is the caller's)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return None, fig, fig.subplots(nrows, ncols, squeeze=False)


def _save(plt: Any, fig: Any, path: str | Path) -> Path:
    path = Path(path)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110, bbox_inches="tight")


def plot_eps_sweep(sweep: EpsSweep, path: str | Path, *, title: str = "") -> Path:
    """Log-log plot of the FD error against the step, with the exact Jacobian's error as a line."""
    plt, fig, axes = _figure(1, 1, (7, 4.2))
    ax = axes[0, 0]
    floor = 1e-17
    ax.loglog(sweep.eps, np.maximum(sweep.fd_error, floor), "o-", ms=3, label="central finite differences")
    ax.axhline(max(sweep.exact_error, floor), color="C2", lw=2, label=f"exact (CasADi): {sweep.exact_error:.1e}")
    ax.axvline(sweep.best_eps, color="0.5", ls=":", label=f"best step {sweep.best_eps:.0e}")
    ax.set_xlabel("finite-difference step eps")
    ax.set_ylabel("max |J − J_complex-step|")
    ax.set_title(title or "Jacobian error against the FD step")
    ax.grid(which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(plt, fig, path)


def crosscheck_figure(result: Any) -> Any:
    """Heatmaps of the exact ``[A | B]`` and of the signed differences FD − exact and MuJoCo − exact.

    Every panel uses a diverging colour scale centred on zero (symmetric
    logarithmic, so entries of very different size stay visible); cell numbers
    are printed only where a cell is large enough to read them; rows and
    columns are labelled with the state and input names.
    """
    from matplotlib.colors import SymLogNorm

    exact = np.hstack([result.A_exact, result.B_exact])
    panels = [
        ("exact [A | B]", exact),
        ("FD − exact", np.hstack([result.A_fd, result.B_fd]) - exact),
        ("MuJoCo − exact", np.hstack([result.A_mujoco, result.B_mujoco]) - exact),
    ]
    n, cols = exact.shape
    cell_in = 0.62 if cols <= 10 else 0.36  # inches per cell
    width, height = cell_in * cols + 1.6, cell_in * n + 1.9
    _, fig, axes = _figure(1, 3, (3 * width, height))
    col_labels = [*result.state_names, *result.input_names]
    readable = cell_in >= 0.5  # room for a 4-character number at 6.5 pt
    for ax, (title, M) in zip(axes[0], panels, strict=True):
        peak = float(np.abs(M).max(initial=0.0))
        vmax = peak if peak > 0 else 1.0
        nonzero = np.abs(M[M != 0])
        linthresh = max(float(nonzero.min()) if nonzero.size else vmax, vmax * 1e-4)
        norm = SymLogNorm(linthresh=linthresh, linscale=0.5, vmin=-vmax, vmax=vmax, base=10)
        im = ax.imshow(M, cmap="RdBu_r", norm=norm, aspect="equal")
        ax.set_title(f"{title}   (max |·| = {peak:.2g})", fontsize=9)
        ax.set_xticks(range(cols), col_labels, rotation=55, ha="right", fontsize=7)
        ax.set_yticks(range(n), [f"d{s}/dt" for s in result.state_names], fontsize=7)
        ax.axvline(n - 0.5, color="k", lw=1.2)
        ax.set_xlabel("columns: states (A = ∂f/∂x) | inputs (B = ∂f/∂u)", fontsize=7)
        if readable:
            for (i, j), v in np.ndenumerate(M):
                if v == 0:
                    continue
                dark = abs(norm(v) - 0.5) > 0.32  # strong colour: white text
                ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=6.5, color="w" if dark else "k")
        fig.colorbar(im, ax=ax, shrink=0.85, pad=0.02)
    fig.suptitle(
        f"{result.plant}: max |FD − exact| = {result.fd_max_abs_error:.1e}, "
        f"max |MuJoCo − exact| = {result.mujoco_max_abs_error:.1e}\n"
        "diverging colour scale centred on zero (blue < 0 < red), symmetric logarithmic",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def plot_crosscheck(result: Any, path: str | Path) -> Path:
    """Write :func:`crosscheck_figure` to the PNG ``path`` (atomically) and return ``path``."""
    path = Path(path)
    fig = crosscheck_figure(result)
    return save_figure(fig, path, dpi=110, bbox_inches="tight")
