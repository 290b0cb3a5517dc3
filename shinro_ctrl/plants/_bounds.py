"""Parsing of the optional state bounds (inelastic stops) that some plants accept."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from shinro_ctrl.errors import InvalidArgument

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


#: ``state_bounds`` as a plant accepts it: a ``(lo, hi)`` pair or the TOML ``{min = [...], max = [...]}``.
StateBounds: TypeAlias = "tuple[ArrayLike, ArrayLike] | Mapping[str, ArrayLike]"


def state_bounds(
    value: StateBounds | None, n: int, default_lo: list[float], default_hi: list[float]
) -> tuple[np.ndarray, np.ndarray] | None:
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
    if np.any(np.isnan(lo)) or np.any(np.isnan(hi)) or np.any(lo >= hi):
        i = int(np.flatnonzero(~(lo < hi))[0])
        raise InvalidArgument(
            f"state_bounds: every min must be < its max (an empty range leaves no state), "
            f"got min[{i}] = {lo[i]:g}, max[{i}] = {hi[i]:g}"
        )
    return lo, hi
