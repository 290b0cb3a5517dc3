"""Plots that explain a linearization: the FD step-size sweep and the three-way crosscheck."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.files import atomic_write
from shinro_ctrl.linearization import complex_step_jacobians

__all__ = ["EpsSweep", "eps_sweep", "plot_crosscheck", "plot_eps_sweep"]


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
    x0, u0 = plant._operating_point(x0, u0)
    eps = np.logspace(-13, -1, 49) if eps is None else np.asarray(eps, dtype=float)
    Ar, Br = complex_step_jacobians(plant, x0, u0)
    ref = np.hstack([Ar, Br])
    errs = np.array([np.abs(np.hstack(plant.linearize(x0, u0, method="fd", eps=e)) - ref).max() for e in eps])
    exact = float(np.abs(np.hstack(plant.linearize(x0, u0)) - ref).max())
    return EpsSweep(eps, errs, exact, float(eps[int(np.argmin(errs))]))


def _figure(nrows: int, ncols: int, size: tuple[float, float]):
    import matplotlib.pyplot as plt  # the backend is the caller's (the CLI picks one)

    return plt, *plt.subplots(nrows, ncols, figsize=size, squeeze=False)


def _save(plt: Any, fig: Any, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110), binary=True)
    plt.close(fig)
    return path


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


def plot_crosscheck(result: Any, path: str | Path) -> Path:
    """Heatmaps of ``log10 |Δ|`` of FD and MuJoCo against the exact ``[A B]``, and the exact matrix itself."""
    exact = np.hstack([result.A_exact, result.B_exact])
    panels = [
        ("exact [A | B]", exact, False),
        ("log10 |FD − exact|", np.abs(np.hstack([result.A_fd, result.B_fd]) - exact), True),
        ("log10 |MuJoCo − exact|", np.abs(np.hstack([result.A_mujoco, result.B_mujoco]) - exact), True),
    ]
    n, cols = exact.shape
    plt, fig, axes = _figure(1, 3, (4.2 * 3, 0.5 * n + 2.4))
    labels_x = [*(f"x:{s}" for s in result.state_names), *(f"u:{s}" for s in result.input_names)]
    for ax, (title, M, logscale) in zip(axes[0], panels, strict=True):
        data = np.log10(np.maximum(M, 1e-17)) if logscale else M
        im = ax.imshow(
            data,
            cmap="magma" if logscale else "coolwarm",
            aspect="auto",
            vmin=-17 if logscale else None,
            vmax=0 if logscale else None,
        )
        ax.set_title(title, fontsize=10)
        ax.set_xticks(range(cols), labels_x, rotation=60, fontsize=7)
        ax.set_yticks(range(n), result.state_names, fontsize=7)
        ax.axvline(n - 0.5, color="k", lw=1)
        if not logscale and M.size <= 16 * 16:
            for (i, j), v in np.ndenumerate(M):
                ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=6)
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle(
        f"{result.plant}: max |FD − exact| = {result.fd_max_abs_error:.1e}, "
        f"max |MuJoCo − exact| = {result.mujoco_max_abs_error:.1e}",
        fontsize=10,
    )
    return _save(plt, fig, path)
