"""State limits, body-force map and measurement matrix of a :class:`~shinro_ctrl.plants.base.Plant`."""

from __future__ import annotations

from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import did_you_mean

__all__ = ["StateIOMixin"]


class StateIOMixin:
    """The state-bounds and measurement part of :class:`~shinro_ctrl.plants.base.Plant`."""

    def state_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Declared limits ``(lo (n,), hi (n,))`` of the state (±inf where none), e.g. ``state_bounds``."""
        return np.full(self.state_dim, -np.inf), np.full(self.state_dim, np.inf)

    def body_force_map(self, body: str) -> np.ndarray:
        """``G (n, 3)``: how a world-frame force ``F`` [N] at ``body``'s centre of mass changes ``ẋ`` (``ẋ += G F``).

        Used for ``[sim] disturbance`` body forces in the standalone loop
        (MuJoCo applies the force itself). Plants that accept such forces
        override this; the base accepts none.

        Raises:
            InvalidArgument: the plant takes no force on ``body``.
        """
        raise InvalidArgument(
            f"{type(self).__name__} takes no body-force disturbance on '{body}'; disturb an input "
            f"({', '.join(self.input_names)}) instead"
        )

    def output_matrix(self, measured: Any = None) -> np.ndarray:
        """The measurement matrix ``C (p, n)`` of the measured states: ``y = C x``.

        Args:
            measured: State names (or indices) in the order of ``y``; None
                means every state (``C = I``).

        Returns:
            The rows of the identity at the measured states, ``(p, n)``.

        Raises:
            InvalidArgument: an unknown name (listing the valid ones), an index
                out of range, a repeated state, or an empty list.
        """
        names = self.state_names
        if measured is None:
            return np.eye(self.state_dim)
        if isinstance(measured, str) or not hasattr(measured, "__iter__"):
            measured = [measured]
        idx: list[int] = []
        for s in measured:
            if isinstance(s, str):
                if s not in names:
                    hint = did_you_mean(s, names)
                    raise InvalidArgument(
                        f"measured: unknown state '{s}' of {type(self).__name__}"
                        f"{hint if 'did you mean' in hint else ''} (valid: {', '.join(names)})"
                    )
                i = names.index(s)
            elif isinstance(s, int | np.integer) and not isinstance(s, bool) and 0 <= s < self.state_dim:
                i = int(s)
            else:
                raise InvalidArgument(f"measured: expected state names ({', '.join(names)}) but found {s!r}")
            if i in idx:
                raise InvalidArgument(f"measured: state '{names[i]}' is listed twice")
            idx.append(i)
        if not idx:
            raise InvalidArgument(f"measured: expected at least one state name ({', '.join(names)}) but found []")
        return np.eye(self.state_dim)[idx]
