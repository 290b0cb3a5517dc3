"""Shared pieces of the model-based estimators: noise covariances, observability, the measured rows."""

from __future__ import annotations

from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import as_matrix, weight_matrix

__all__ = ["QN_ON", "check_detectable", "measured_indices", "noise_covariance", "process_noise_input"]

#: Where the process noise ``Qn`` enters: on the inputs (``G = B``) or directly on the states (``G = I``).
QN_ON = ("input", "state")


def noise_covariance(name: str, value: Any, size: int, *, definite: bool) -> np.ndarray:
    """A noise covariance ``(size, size)`` from a matrix or its diagonal ``(size,)`` (variances, not std devs).

    Raises:
        InvalidArgument: wrong shape, a negative variance (naming the index),
            asymmetric, or not (semi)definite.
    """
    arr = np.asarray(value, dtype=float) if value is not None else None
    if arr is None:
        raise InvalidArgument(f"{name}: a noise covariance ({size},) or ({size}, {size}) is required")
    diag = arr if arr.ndim <= 1 else np.diagonal(arr) if arr.ndim == 2 else arr
    neg = np.flatnonzero(np.asarray(diag).reshape(-1) < 0)
    if neg.size:
        i = int(neg[0])
        raise InvalidArgument(
            f"{name}: a noise variance cannot be negative, found {name}[{i}] = {np.asarray(diag).reshape(-1)[i]:g}"
        )
    return weight_matrix(name, arr, size, definite=definite)


def process_noise_input(Qn_on: str, B: np.ndarray) -> np.ndarray:
    """The noise input matrix ``G``: ``B`` (``Qn_on="input"``) or the identity (``"state"``)."""
    if Qn_on == "input":
        return B
    if Qn_on == "state":
        return np.eye(B.shape[0])
    raise InvalidArgument(f"Qn_on: expected one of {', '.join(QN_ON)} but found {Qn_on!r}")


def measured_indices(C: np.ndarray) -> tuple[int, ...]:
    """The state indices of a selection matrix ``C (p, n)`` (rows of the identity); () for another C."""
    C = np.asarray(C, dtype=float)
    rows = []
    for row in C:
        nz = np.flatnonzero(row)
        if nz.size != 1 or row[nz[0]] != 1.0:
            return ()
        rows.append(int(nz[0]))
    return tuple(rows)


def check_detectable(
    A: np.ndarray,
    C: np.ndarray,
    *,
    names: Any = None,
    measured: Any = None,
    strict: bool = False,
) -> None:
    """Raise :class:`InvalidArgument` naming a mode of the discrete ``A`` that ``y = C x`` cannot see.

    PBH test: the mode ``λ`` is observable iff ``rank [A − λI; C] = n``; the
    rank is judged by the smallest singular value relative to ``‖[A; C]‖``.
    ``strict`` (pole placement) requires every mode to be observable;
    otherwise (a Kalman filter) only modes with ``|λ| ≥ 1`` must be
    (detectability).

    Args:
        A: Discrete state matrix ``(n, n)``.
        C: Measurement matrix ``(p, n)``.
        names: State names ``(n,)`` for the message.
        measured: The measured names, quoted in the message.
        strict: Require observability instead of detectability.
    """
    n = A.shape[0]
    C = as_matrix("C", C, (C.shape[0], n))
    scale = max(1.0, float(np.linalg.norm(np.vstack([A, C]), 2)))
    eigvals, eigvecs = np.linalg.eig(A)
    for k, lam in enumerate(eigvals):
        if not strict and abs(lam) < 1.0 - 1e-12:
            continue
        pbh = np.vstack([A - lam * np.eye(n), C.astype(complex)])
        smin = np.linalg.svd(pbh, compute_uv=False)[-1]
        if smin <= 1e-9 * scale:
            v = eigvecs[:, k]
            i = int(np.argmax(np.abs(v)))
            state = f"'{names[i]}'" if names is not None else str(i)
            seen = f"the measured states {list(measured)}" if measured is not None else "y = C x"
            what = "observable" if strict else "detectable"
            raise InvalidArgument(
                f"(A, C) is not {what}: the mode λ = {complex(lam).real:.6g}"
                f"{'' if abs(complex(lam).imag) < 1e-12 else f'{complex(lam).imag:+.6g}j'} (mostly state {state}) "
                f"cannot be seen from {seen} (PBH rank test, σ_min = {smin:.2e}); measure a state that moves with it"
            )
