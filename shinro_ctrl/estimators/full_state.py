"""Full-state feedback: the identity estimator (the loop's default)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from shinro_ctrl.estimators.base import Estimator
from shinro_ctrl.types import Vector, Weight
from shinro_ctrl.validation import as_vector

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["FullState"]


class FullState(Estimator):
    """Every state measured; the estimate is the measurement itself.

    Args:
        n: Number of states.
    """

    stateful = False

    def __init__(self, n: int):
        self.n = int(n)
        self.measured = tuple(range(self.n))
        self._x = np.zeros(self.n)

    @classmethod
    def from_plant(cls, plant: Plant, **options: Any) -> FullState:
        """The identity estimator for ``plant`` (takes no options)."""
        if options:
            from shinro_ctrl.errors import ConfigError

            raise ConfigError(f"[estimator] FullState takes no keys, got {sorted(options)}")
        return cls(plant.state_dim)

    def reset(self, x0_hat: Vector, P0: Weight | None = None) -> None:
        """Nothing to forget; ``x0_hat`` is only checked."""
        self._x = as_vector("x0_hat", x0_hat, self.n).copy()

    def update(self, y: Vector, u: Vector) -> np.ndarray:
        """Return ``y`` (the full state) unchanged."""
        return y

    def __repr__(self) -> str:
        return f"FullState(n={self.n})"
