r"""Integral action for LQR (LQI): integrators of tracking errors with anti-windup clamping.

``LQR(..., integral=["x"])`` augments the discrete design model with one
integrator per named state, ``z_{k+1} = z_k + dt (x_k[i] − r_k[i])``:

.. math::

    \begin{bmatrix} x̃ \\ z \end{bmatrix}_{k+1} =
    \begin{bmatrix} A & 0 \\ dt\, C_i & I \end{bmatrix}
    \begin{bmatrix} x̃ \\ z \end{bmatrix}_k + \begin{bmatrix} B \\ 0 \end{bmatrix} ũ_k ,

designs the LQR gain ``[K, K_i]`` on it (``Q`` then has ``n + q`` entries,
the last ``q`` weighting the integrators) and applies
``u = u0 − K (x − r) − K_i z``. A constant input disturbance then leaves
no steady-state error in the integrated states.

Anti-windup by clamping (conditional integration): when the saturated
input differs from the unsaturated one, an integrator is frozen for the
step if its increment would push a saturated input further into
saturation; otherwise it integrates as usual.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shinro_ctrl.errors import InvalidArgument

__all__ = ["IntegralAction", "integral_indices"]


def integral_indices(
    integral: str | int | Sequence[str | int], n: int, names: Sequence[str] | None = None
) -> tuple[int, ...]:
    """The state indices named by ``integral`` (names, or indices when no names are known).

    Raises:
        InvalidArgument: unknown name (listing the valid ones), bad index, repeats or an empty list.
    """
    if isinstance(integral, str) or not hasattr(integral, "__iter__"):
        integral = [integral]
    names = tuple(names) if names is not None else None
    out: list[int] = []
    for s in integral:
        if isinstance(s, str):
            if names is None or s not in names:
                valid = ", ".join(names) if names else "state indices (the model has no state names)"
                raise InvalidArgument(f"integral: unknown state '{s}' (valid: {valid})")
            i = names.index(s)
        elif isinstance(s, int | np.integer) and not isinstance(s, bool) and 0 <= s < n:
            i = int(s)
        else:
            raise InvalidArgument(f"integral: expected state names or indices in [0, {n}) but found {s!r}")
        if i in out:
            raise InvalidArgument(f"integral: state {s!r} is listed twice")
        out.append(i)
    if not out:
        raise InvalidArgument("integral: expected at least one state to integrate but found []")
    return tuple(out)


class IntegralAction:
    """The integrators of an LQI controller and their anti-windup.

    Args:
        A: Discrete ``(n, n)``.
        B: Discrete ``(n, m)``.
        indices: Integrated states ``(q,)``.
        dt: Sample time [s] of the integration.

    Attributes:
        A_aug: ``(n + q, n + q)`` augmented state matrix.
        B_aug: ``(n + q, m)``.
        z: Integrator states ``(q,)`` [state unit · s].
        K_i: Integrator gain ``(m, q)`` (set by :meth:`set_gain`).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, indices: tuple[int, ...], dt: float):
        n, m = B.shape
        q = len(indices)
        self.indices = np.asarray(indices, dtype=int)
        self.dt = float(dt)
        Ci = np.eye(n)[self.indices]
        self.A_aug = np.block([[A, np.zeros((n, q))], [self.dt * Ci, np.eye(q)]])
        self.B_aug = np.vstack([B, np.zeros((q, m))])
        self.z = np.zeros(q)
        self.K_i = np.zeros((m, q))
        self._e = np.zeros(q)

    def set_gain(self, K_i: np.ndarray) -> None:
        """The integrator columns ``(m, q)`` of the augmented LQR gain."""
        self.K_i = np.asarray(K_i, dtype=float)

    def reset(self) -> None:
        """Empty the integrators."""
        self.z[:] = 0.0

    def finish(
        self, u: np.ndarray, x: np.ndarray, r: np.ndarray, u_min: np.ndarray | None, u_max: np.ndarray | None
    ) -> np.ndarray:
        """Add ``−K_i z`` to the state-feedback input ``u (m,)``, saturate, then integrate ``x − r`` with clamping.

        Args:
            u: Unsaturated state-feedback input ``(m,)`` (modified in place).
            x: State ``(n,)``.
            r: Reference ``(n,)``.
            u_min, u_max: Saturation bounds ``(m,)`` or None.

        Returns:
            The saturated input ``(m,)``.
        """
        u -= self.K_i @ self.z
        np.subtract(x[self.indices], r[self.indices], out=self._e)
        if u_min is None:
            self.z += self.dt * self._e
            return u
        sat = np.clip(u, u_min, u_max)
        over = np.sign(u - sat)  # +1 above u_max, -1 below u_min, 0 inside
        if not over.any():
            self.z += self.dt * self._e
            return sat
        dz = self.dt * self._e
        push = -(self.K_i * dz) * over[:, None]  # (m, q): how each increment moves each saturated input outward
        frozen = np.any(push > 0.0, axis=0)
        self.z += np.where(frozen, 0.0, dz)
        return sat


def integral_action(
    A: np.ndarray,
    B: np.ndarray,
    integral: str | int | Sequence[str | int] | None,
    dt: float,
    names: Sequence[str] | None,
    *,
    discrete: bool,
) -> tuple[IntegralAction | None, tuple[str, ...] | None]:
    """The :class:`IntegralAction` for LQR's ``integral`` argument (None without one) and the augmented names.

    Raises:
        InvalidArgument: a continuous design (the integrators are discrete) or a bad ``integral``.
    """
    if integral is None:
        return None, tuple(names) if names is not None else None
    if not discrete:
        raise InvalidArgument("integral: integral action needs the discrete design (discrete=True)")
    n = A.shape[0]
    idx = integral_indices(integral, n, names)
    action = IntegralAction(A, B, idx, dt)
    base = tuple(names) if names is not None else tuple(str(i) for i in range(n))
    return action, (*base, *(f"integral of {base[i]}" for i in idx))
