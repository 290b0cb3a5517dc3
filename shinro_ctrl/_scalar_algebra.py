"""Scalar algebra of :mod:`shinro_ctrl.multibody` that skips structural zeros.

Every helper works on Python floats, complex numbers (complex step) and CasADi
``SX`` alike; an exact ``0``/``1`` is never multiplied or added, so the
symbolic expressions the recursive algorithms build stay small.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def _zero(a: Any) -> bool:
    return isinstance(a, float | int) and a == 0


def _mul(a: Any, b: Any) -> Any:
    if _zero(a) or _zero(b):
        return 0.0
    if isinstance(a, float | int) and a == 1:
        return b
    if isinstance(b, float | int) and b == 1:
        return a
    return a * b


def _add(*terms: Any) -> Any:
    out: Any = 0.0
    for t in terms:
        if _zero(t):
            continue
        out = t if _zero(out) else out + t
    return out


def _sub(a: Any, b: Any) -> Any:
    if _zero(b):
        return a
    if _zero(a):
        return -b
    return a - b


def _dot(a: Sequence[Any], b: Sequence[Any]) -> Any:
    return _add(*(_mul(x, y) for x, y in zip(a, b, strict=True)))


def _cross(a: Sequence[Any], b: Sequence[Any]) -> list[Any]:
    return [
        _sub(_mul(a[1], b[2]), _mul(a[2], b[1])),
        _sub(_mul(a[2], b[0]), _mul(a[0], b[2])),
        _sub(_mul(a[0], b[1]), _mul(a[1], b[0])),
    ]


def _vadd(*vs: Sequence[Any]) -> list[Any]:
    return [_add(*(v[k] for v in vs)) for k in range(3)]


def _vscale(v: Sequence[Any], s: Any) -> list[Any]:
    return [_mul(c, s) for c in v]


def _matvec(R: Sequence[Sequence[Any]], v: Sequence[Any]) -> list[Any]:
    return [_dot(R[k], v) for k in range(3)]


def _matTvec(R: Sequence[Sequence[Any]], v: Sequence[Any]) -> list[Any]:
    return [_dot([R[0][k], R[1][k], R[2][k]], v) for k in range(3)]


def _const(v: np.ndarray) -> list[float]:
    """Numeric constants as Python floats, with round-off dust snapped to exact zeros."""
    return [0.0 if abs(float(c)) < 1e-15 else float(c) for c in np.asarray(v, dtype=float).ravel()]


def quat_to_mat(q: Any) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` of a quaternion ``(w, x, y, z)`` (normalized first)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _all_zero(v: Sequence[Any]) -> bool:
    return all(_zero(c) for c in v)


def _ldl_factor(M: list[list[Any]]) -> tuple[list[list[Any]], list[Any]]:
    """``M = L D Lᵀ`` (``L`` unit lower triangular, ``D`` diagonal) of a symmetric positive definite ``M``.

    No pivoting; structural zeros of ``M`` stay zeros of ``L`` where no fill-in reaches them.
    """
    n = len(M)
    L: list[list[Any]] = [[0.0] * n for _ in range(n)]
    D: list[Any] = [0.0] * n
    for j in range(n):
        D[j] = _sub(M[j][j], _add(*(_mul(_mul(L[j][k], L[j][k]), D[k]) for k in range(j))))
        for i in range(j + 1, n):
            s = _sub(M[i][j], _add(*(_mul(_mul(L[i][k], L[j][k]), D[k]) for k in range(j))))
            L[i][j] = 0.0 if _zero(s) else s / D[j]
    return L, D


def _ldl_back(L: list[list[Any]], D: list[Any], b: list[Any]) -> list[Any]:
    """Solve ``L D Lᵀ x = b`` with the factors of :func:`_ldl_factor`."""
    n = len(b)
    y: list[Any] = [0.0] * n
    for i in range(n):
        y[i] = _sub(b[i], _add(*(_mul(L[i][k], y[k]) for k in range(i))))
    x: list[Any] = [0.0] * n
    for i in range(n - 1, -1, -1):
        x[i] = _sub(y[i] / D[i] if not _zero(y[i]) else 0.0, _add(*(_mul(L[k][i], x[k]) for k in range(i + 1, n))))
    return x


def _ldl_solve(M: list[list[Any]], b: list[Any]) -> list[Any]:
    """Solve ``M x = b`` for symmetric positive definite ``M`` by LDLᵀ (structural zeros skipped)."""
    L, D = _ldl_factor(M)
    return _ldl_back(L, D, b)
