"""Parsing of the optional clipping bounds that some plants accept."""

from __future__ import annotations

from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument


def state_bounds(value: Any, n: int, default_lo: list[float], default_hi: list[float]):
    """Normalize ``state_bounds`` to a ``(lo (n,), hi (n,))`` pair of arrays, or None.

    Accepts ``None``, a ``(lo, hi)`` pair of length-``n`` sequences, or a
    mapping with optional ``min`` / ``max`` lists (the TOML form); a missing
    side takes the plant's documented default.
    """
    if value is None:
        return None
    if isinstance(value, dict):
        extra = set(value) - {"min", "max"}
        if extra:
            raise InvalidArgument(f"state_bounds: unknown key {sorted(extra)[0]!r}; valid: max, min")
        lo, hi = value.get("min", default_lo), value.get("max", default_hi)
    else:
        try:
            lo, hi = value
        except (TypeError, ValueError):
            raise InvalidArgument("state_bounds must be a (min, max) pair or {min = [...], max = [...]}") from None
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    if lo.shape != (n,) or hi.shape != (n,):
        raise InvalidArgument(f"state_bounds: expected min and max of shape ({n},) but found {lo.shape} and {hi.shape}")
    if np.any(np.isnan(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
        raise InvalidArgument("state_bounds: every min must be <= its max")
    return lo, hi


class StateBoundsMixin:
    """For plants with an optional ``state_bounds = (lo (n,), hi (n,))``: clip to it and declare it as limits."""

    state_bounds: tuple[np.ndarray, np.ndarray] | None

    def clip_state(self, x: np.ndarray) -> np.ndarray:
        if self.state_bounds is None:
            return x
        return np.clip(x, *self.state_bounds)

    def state_limits(self) -> tuple[np.ndarray, np.ndarray]:
        if self.state_bounds is None:
            return super().state_limits()  # type: ignore[misc]
        return self.state_bounds[0].copy(), self.state_bounds[1].copy()
