"""Bryson's rule: weights from the largest acceptable deviations.

Scale each state and input by the largest value you will tolerate,

    Q = diag(1 / x_max²),   R = diag(1 / u_max²),

so that every term of ``xᵀ Q x + uᵀ R u`` is 1 at its limit. An infinite
``x_max`` means "do not care" (weight 0); inputs need finite limits, since
``R`` must be positive definite.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument

__all__ = ["bryson", "bryson_diagonal"]


def bryson_diagonal(name: str, limits: Any, *, allow_inf: bool = True) -> np.ndarray:
    """``1 / limits²`` elementwise, validated.

    Args:
        name: Argument name for messages (``"Q"``, ``"x_max"``, …).
        limits: Largest acceptable deviations ``(k,)``, positive (``inf`` allowed
            when ``allow_inf``, giving weight 0).
        allow_inf: Whether ``inf`` (weight 0) is accepted.

    Returns:
        The diagonal ``(k,)``.

    Raises:
        InvalidArgument: empty, non-numeric, non-positive, NaN, or ``inf`` where not allowed.
    """
    try:
        v = np.atleast_1d(np.asarray(limits, dtype=float))
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name}: bryson limits must be a list of positive numbers, got {limits!r}") from None
    if v.ndim != 1 or v.size == 0:
        raise InvalidArgument(f"{name}: bryson limits must be a non-empty list of numbers, got {limits!r}")
    for x in v:
        if math.isnan(x) or x <= 0 or (math.isinf(x) and not allow_inf):
            what = "positive and finite" if not allow_inf else "positive (inf = weight 0)"
            raise InvalidArgument(f"{name}: bryson limits must be {what}, got {x:g} in {v.tolist()}")
    return 1.0 / v**2


def bryson(x_max: Any, u_max: Any) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule ``Q = diag(1/x_max²)``, ``R = diag(1/u_max²)``.

    Args:
        x_max: Largest acceptable state deviations ``(n,)`` (``inf``: weight 0).
        u_max: Largest acceptable inputs ``(m,)``, positive and finite.

    Returns:
        ``(Q (n, n), R (m, m))``.

    Example:
        >>> Q, R = bryson([0.5, 1, 0.2, 1], [5])
        >>> float(Q[2, 2]), float(R[0, 0])
        (25.0, 0.04)
    """
    return np.diag(bryson_diagonal("x_max", x_max)), np.diag(bryson_diagonal("u_max", u_max, allow_inf=False))
