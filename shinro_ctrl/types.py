"""Shared type aliases of the public signatures: the array-likes accepted at the boundary.

A public function takes what a caller naturally has (a float, a list, a
nested list, a NumPy array) and converts it once with the checks of
:mod:`shinro_ctrl.validation`; these aliases name those accepted forms so
that every signature says the same thing in one word. Inside, the code
works on ``np.ndarray``.

The scenario checker (:mod:`shinro_ctrl.config.strict`) reads the
annotations of ``from_plant`` as text: the alias names listed in
:data:`NUMERIC_ALIASES` are checked as numbers or arrays of numbers there.

This module imports only NumPy, so any layer may use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeAlias

import numpy as np

__all__ = ["NUMERIC_ALIASES", "Bound", "Matrix", "Poles", "Vector", "Weight"]

Vector: TypeAlias = float | Sequence[float] | np.ndarray
"""A real vector ``(n,)``: a sequence of floats or a 1-D array (a scalar where ``n == 1``)."""

Matrix: TypeAlias = float | Sequence[float] | Sequence[Sequence[float]] | np.ndarray
"""A real matrix ``(r, c)``: nested sequences or a 2-D array (a row ``(c,)`` or a scalar where the function says)."""

Weight: TypeAlias = float | Sequence[float] | Sequence[Sequence[float]] | np.ndarray
"""A symmetric weight or covariance ``(n, n)``: a full matrix, its diagonal ``(n,)``, or a scalar where ``n == 1``."""

Bound: TypeAlias = float | Sequence[float] | np.ndarray | None
"""A bound vector ``(n,)``: a scalar broadcasts, ``±inf`` leaves an entry unbounded, None bounds nothing."""

Poles: TypeAlias = complex | Sequence[complex] | np.ndarray
"""Poles ``(n,)``: real or complex numbers, complex ones in conjugate pairs."""

NUMERIC_ALIASES: frozenset[str] = frozenset({"Vector", "Matrix", "Weight", "Bound", "Poles"})
"""The alias names a scenario value is checked against as a number, an array of numbers or a table of them."""
