"""Shared pieces of the model-based estimators: noise covariances, observability, the measured rows."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.types import Weight
from shinro_ctrl.validation import weight_matrix

__all__ = ["QN_ON", "measured_indices", "noise_covariance", "process_noise_input", "seen_from"]

#: Where the process noise ``Qn`` enters: on the inputs (``G = B``) or directly on the states (``G = I``).
QN_ON = ("input", "state")


def noise_covariance(name: str, value: Weight | None, size: int, *, definite: bool) -> np.ndarray:
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


def seen_from(measured: Sequence[str] | None) -> str:
    """What the measurements are, for the message of :func:`~shinro_ctrl.analysis.structure.check_detectable`."""
    return f"the measured states {list(measured)}" if measured is not None else "y = C x"
