"""Array backends: the small vocabulary each plant writes its dynamics in.

A plant writes its continuous dynamics ``f(x, u)`` once, as a function of a
backend ``bk``. Four backends evaluate that one definition:

* :class:`NumpyBackend` computes numbers and broadcasts over a leading batch
  axis: ``x`` of shape ``(N, n)``, ``u`` of ``(N, m)`` and parameters of shape
  ``(N,)`` give ``xdot`` of shape ``(N, n)``.
* :class:`ScalarBackend` computes one instance with Python floats and the
  ``math`` module; it is what a single ``plant.step`` uses, because numpy's
  per-call overhead on scalars costs more than the arithmetic.
* :class:`CasadiBackend` builds a ``casadi.SX`` expression, from which exact
  Jacobians are taken.
* :class:`ListBackend` is :class:`ScalarBackend` returning plain lists, for
  the integrators that work on Python floats.

The operations are deliberately few: elementwise ``sin``/``cos``/``tan``/
``sqrt``, ``unpack`` (a vector into its components), ``stack`` (components
into a vector), and matrix helpers for code that is not per-component
(``array``, ``zeros``, ``eye``, ``solve``, ``clip``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, TypeAlias, runtime_checkable

import casadi as cs
import numpy as np

__all__ = ["ArrayBackend", "BackendArray", "CasadiBackend", "ListBackend", "NumpyBackend", "ScalarBackend"]


#: What the backends compute on: numpy arrays (numbers, batches), Python floats/lists, or CasADi symbols.
BackendArray: TypeAlias = "np.ndarray | cs.SX | list[float] | float"


@runtime_checkable
class ArrayBackend(Protocol):
    """The operations a plant's ``equations(bk, x, u, p)`` may use (every backend provides them).

    Elementwise math on components, ``unpack`` (a vector into ``n``
    components) and ``stack`` (components into a vector), and the matrix
    helpers ``array``, ``zeros``, ``eye``, ``solve``, ``clip``.
    """

    name: str

    def sin(self, a: BackendArray, /) -> BackendArray: ...

    def cos(self, a: BackendArray, /) -> BackendArray: ...

    def tan(self, a: BackendArray, /) -> BackendArray: ...

    def sqrt(self, a: BackendArray, /) -> BackendArray: ...

    def arccos(self, a: BackendArray, /) -> BackendArray: ...

    def arctan2(self, a: BackendArray, b: BackendArray, /) -> BackendArray: ...

    def unpack(self, v: BackendArray, n: int) -> tuple[BackendArray, ...]:
        """Split the last axis of ``v`` into ``n`` components."""
        ...

    def stack(self, items: Sequence[BackendArray]) -> BackendArray:
        """Join components into a vector along the last axis."""
        ...

    def array(self, v: BackendArray) -> BackendArray: ...

    def zeros(self, n: int | tuple[int, ...]) -> BackendArray: ...

    def eye(self, n: int) -> BackendArray: ...

    def solve(self, A: BackendArray, b: BackendArray) -> BackendArray: ...

    def clip(self, v: BackendArray, lo: BackendArray, hi: BackendArray) -> BackendArray: ...


class NumpyBackend:
    """Numeric, batch-aware backend on numpy arrays.

    Components are views ``v[..., i]``, so every expression broadcasts over
    any leading batch axes; :meth:`stack` broadcasts scalars (such as a
    constant zero row) up to the batch shape.
    """

    name = "numpy"
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    tan = staticmethod(np.tan)
    sqrt = staticmethod(np.sqrt)
    arccos = staticmethod(np.arccos)
    arctan2 = staticmethod(np.arctan2)

    def unpack(self, v: BackendArray, n: int) -> tuple:
        v = np.asarray(v)  # float, or complex for complex-step differentiation
        return tuple(v[..., i] for i in range(n))

    def stack(self, items: Sequence[BackendArray]) -> np.ndarray:
        return np.stack(np.broadcast_arrays(*[np.asarray(i) for i in items]), axis=-1).astype(
            np.result_type(float, *items), copy=False
        )

    # Matrix helpers (single instance).
    @staticmethod
    def array(v: BackendArray) -> np.ndarray:
        return np.asarray(v, dtype=float)

    @staticmethod
    def zeros(n: int | tuple[int, ...]) -> np.ndarray:
        return np.zeros(n)

    @staticmethod
    def eye(n: int) -> np.ndarray:
        return np.eye(n)

    @staticmethod
    def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.linalg.solve(A, b)

    @staticmethod
    def clip(v: BackendArray, lo: BackendArray, hi: BackendArray) -> np.ndarray:
        return np.clip(v, lo, hi)

    @staticmethod
    def to_numpy(v: BackendArray) -> np.ndarray:
        return np.asarray(v, dtype=float)

    @staticmethod
    def from_numpy(v: BackendArray) -> np.ndarray:
        return np.asarray(v, dtype=float)


class ScalarBackend(NumpyBackend):
    """Single-instance fast path: components are Python floats, math is ``math``.

    Produces the same numbers as :class:`NumpyBackend` for one instance (the
    tests check it) at a fraction of the per-call cost.
    """

    name = "scalar"
    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    tan = staticmethod(math.tan)
    sqrt = staticmethod(math.sqrt)
    arccos = staticmethod(math.acos)
    arctan2 = staticmethod(math.atan2)

    def unpack(self, v: BackendArray, n: int) -> tuple:
        return tuple(v.tolist()) if isinstance(v, np.ndarray) else tuple(float(c) for c in v)

    def stack(self, items: Sequence[BackendArray]) -> np.ndarray:
        return np.array(items, dtype=float)


class ListBackend(ScalarBackend):
    """:class:`ScalarBackend` whose :meth:`stack` returns a plain list.

    Used inside integrators, which work on Python floats and would otherwise
    convert a fresh array straight back to a list.
    """

    name = "list"

    def stack(self, items: Sequence[BackendArray]) -> list:
        return list(items)


class CasadiBackend:
    """Symbolic backend on ``casadi.SX`` column vectors."""

    name = "casadi"
    sin = staticmethod(cs.sin)
    cos = staticmethod(cs.cos)
    tan = staticmethod(cs.tan)
    sqrt = staticmethod(cs.sqrt)
    arccos = staticmethod(cs.acos)
    arctan2 = staticmethod(cs.atan2)

    def unpack(self, v: BackendArray, n: int) -> tuple:
        return tuple(v[i] for i in range(n))

    def stack(self, items: Sequence[BackendArray]) -> cs.SX:
        return cs.vertcat(*items)

    @staticmethod
    def array(v: BackendArray) -> cs.SX:
        return cs.SX(np.asarray(v, dtype=float)) if not isinstance(v, cs.SX) else v

    @staticmethod
    def zeros(n: int | tuple[int, ...]) -> cs.SX:
        return cs.SX.zeros(*((n, 1) if isinstance(n, int) else n))

    @staticmethod
    def eye(n: int) -> cs.SX:
        return cs.SX.eye(n)

    @staticmethod
    def solve(A: BackendArray, b: BackendArray) -> cs.SX:
        return cs.solve(A, b)

    @staticmethod
    def clip(v: BackendArray, lo: BackendArray, hi: BackendArray) -> cs.SX:
        return cs.fmin(cs.fmax(v, lo), hi)
