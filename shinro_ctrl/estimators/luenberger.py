r"""Luenberger observer: a linear estimator whose error poles are placed by hand.

Current-estimator form (the same predict-correct structure as the Kalman
filter, so both take ``y_k`` and return ``x̂_{k|k}``):

.. math::

    \bar x = A \hat x_{k-1} + B u_{k-1}, \qquad \hat x_k = \bar x + M (y_k - C \bar x),

in deviations from the operating point. The estimation error obeys
``e_k = (I − M C) A e_{k−1}``, whose eigenvalues are those of
``A − M C A``: ``M`` comes from ``control.place`` on the dual pair
``(Aᵀ, (C A)ᵀ)``. ``L = A M`` is the equivalent predictor gain
(``eig(A − L C)`` are the same poles).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.analysis.structure import check_detectable
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.estimators._linear import measured_indices, seen_from
from shinro_ctrl.estimators.base import Estimator
from shinro_ctrl.types import Matrix, Poles, Vector, Weight
from shinro_ctrl.validation import as_vector, measurement_matrix, state_space

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["Luenberger"]


class Luenberger(Estimator):
    """Observer with the discrete error poles ``poles``.

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        C: Measurement matrix ``(p, n)``; ``(A, C)`` must be observable.
        poles: Desired discrete error poles ``(n,)``, inside the unit circle,
            complex ones in conjugate pairs, each repeated at most ``p`` times.
        x0: Operating-point state ``(n,)`` (default zeros).
        u0: Operating-point input ``(m,)`` (default zeros).
        state_names: Names for messages.

    Attributes:
        M: Filter gain ``(n, p)``.
        L: Predictor gain ``A M`` ``(n, p)``.
        poles: The achieved poles ``eig(A − L C)`` ``(n,)``.

    Raises:
        InvalidArgument: wrong shapes, poles outside the unit circle or that
            cannot be placed, or an unobservable mode (named, PBH test).
    """

    def __init__(
        self,
        A: Matrix,
        B: Matrix,
        C: Matrix,
        poles: Poles,
        *,
        x0: Vector | None = None,
        u0: Vector | None = None,
        state_names: Sequence[str] | None = None,
    ):
        A, B = state_space(A, B)
        n, m = B.shape
        C = measurement_matrix(C, n)
        p = C.shape[0]
        try:
            want = np.asarray(poles, dtype=complex).reshape(-1)
        except (TypeError, ValueError):
            raise InvalidArgument(f"poles: expected {n} numbers but found {poles!r}") from None
        if want.shape != (n,) or not np.all(np.isfinite(want)):
            raise InvalidArgument(f"poles: expected {n} finite values but found {np.asarray(poles).tolist()}")
        if np.any(np.abs(want) >= 1.0):
            raise InvalidArgument(f"poles: discrete poles must lie inside the unit circle, got {want.tolist()}")
        names = tuple(state_names) if state_names is not None else None
        self.measured = measured_indices(C)
        measured_names = [names[i] for i in self.measured] if names and self.measured else None
        check_detectable(A, C, names=names, seen_by=seen_from(measured_names), strict=True)
        import control  # deferred: importing python-control costs about a second

        try:
            with warnings.catch_warnings():  # scipy's robustness iteration warns; the poles are checked below
                warnings.simplefilter("ignore", UserWarning)
                Mt = control.place(A.T, (C @ A).T, want)
        except (ValueError, np.linalg.LinAlgError, control.ControlArgument) as exc:
            raise InvalidArgument(f"poles {want.tolist()} cannot be placed with {p} measurement(s): {exc}") from exc
        self.A, self.B, self.C = A, B, C
        self.n, self.m, self.p = n, m, p
        self.M = np.asarray(Mt, dtype=float).T
        self.L = A @ self.M
        self.poles = np.linalg.eigvals(A - self.L @ C)
        miss = max(float(np.min(np.abs(self.poles - w))) for w in want)
        if miss > 1e-6:
            raise InvalidArgument(f"poles {want.tolist()} could not be placed accurately (off by {miss:.2e})")
        ImMC = np.eye(n) - self.M @ C
        self._Phi, self._Gam = ImMC @ A, ImMC @ B  # x̂ = (I − M C)(A x̂ + B ũ) + M ỹ
        self.x0 = np.zeros(n) if x0 is None else as_vector("x0", x0, n)
        self.u0 = np.zeros(m) if u0 is None else as_vector("u0", u0, m)
        self._yoff = C @ self.x0
        self._z = np.zeros(n)
        self._zbar = np.zeros(n)
        self._nu = np.zeros(p)
        self._first = True

    @classmethod
    def from_plant(
        cls,
        plant: Plant,
        *,
        measured: Sequence[str | int] | str | int | None = None,
        poles: Poles,
        x0: Vector | None = None,
        u0: Vector | None = None,
        discretization: str = "zoh",
    ) -> Luenberger:
        """The observer of ``plant`` linearized at ``(x0, u0)`` (default its equilibrium).

        Args:
            plant: Any plant.
            measured: Measured state names in the order of ``y`` (default all).
            poles: Discrete error poles ``(n,)``.
            x0, u0: Operating point.
            discretization: ``zoh`` (default), ``euler`` or ``rk4``.
        """
        C = plant.output_matrix(measured)
        lm = plant.linear_model(x0, u0, discretization=discretization)
        est = cls(lm.A, lm.B, C, poles, x0=lm.x0, u0=lm.u0, state_names=plant.state_names)
        est.model = lm
        return est

    def reset(self, x0_hat: Vector, P0: Weight | None = None) -> None:
        """Start from ``x0_hat (n,)``; an observer has no covariance, so ``P0`` must be None."""
        with self._busy:
            self._reset(x0_hat, P0)

    def _reset(self, x0_hat: Vector, P0: Weight | None = None) -> None:
        if P0 is not None:
            raise InvalidArgument("P0: a Luenberger observer has no covariance")
        self._z[:] = as_vector("x0_hat", x0_hat, self.n) - self.x0
        self._first = True

    def update(self, y: Vector, u: Vector) -> np.ndarray:
        """Predict with ``u (m,)`` (skipped right after :meth:`reset`) and correct with ``y (p,)``; ``x̂ (n,)``."""
        with self._busy:  # one thread at a time (class docstring)
            return self._update(y, u)

    def _update(self, y: Vector, u: Vector) -> np.ndarray:
        y = as_vector("y", y, self.p)
        u = as_vector("u", u, self.m)  # checked also on the first call, whose prediction is skipped
        z = self._z
        if self._first:
            self._first = False
            np.subtract(y, self._yoff, out=self._nu)
            self._nu -= self.C @ z
            z += self.M @ self._nu
        else:
            np.subtract(y, self._yoff, out=self._nu)
            np.dot(self._Phi, z, out=self._zbar)
            self._zbar += self._Gam @ (u - self.u0)
            self._zbar += self.M @ self._nu
            z[:] = self._zbar
        return z + self.x0

    def __repr__(self) -> str:
        return f"Luenberger(n={self.n}, measured={self.measured}, poles={np.round(self.poles, 4).tolist()})"
