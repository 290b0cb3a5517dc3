"""The :class:`Controller` interface shared by LQR, LinearMPC and IKQP."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["Controller"]


class Controller:
    """A feedback law ``u = controller(x, ref)``.

    Subclasses implement :meth:`__call__` and, when they carry memory (warm
    starts, previous inputs), :meth:`reset`. Input bounds, when a controller
    has them, are exposed as ``u_min`` / ``u_max`` ``(m,)`` (±inf where
    unbounded) so plots and metrics can show them.
    """

    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None

    def __call__(self, x: Any, ref: Any = None) -> np.ndarray:
        """Return the input ``u (m,)`` for the measured state ``x (n,)``."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget any internal memory (warm starts, previous input)."""
