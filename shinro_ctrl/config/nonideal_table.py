"""``[sim] actuator`` and ``[sim] sensor``: the non-ideal actuator and sensor of a scenario, checked and normalized.

Both tables are optional and every key in them is optional. A key takes a
scalar (every channel) or a list with one value per channel (per input for the
actuator, per state for the sensor). The checks, shared with the models'
constructors (:mod:`shinro_ctrl.sim.nonideal`), are:

* ``delay`` [s] ``>= 0`` and a whole number of steps of the plant's ``dt``
  (a delay between two whole steps is refused naming the two nearest valid
  ones: a rounded delay would silently move a stability boundary);
* ``lag`` [s] (time constant τ) ``>= 0`` (0: none);
* ``quantization`` (the step q, in the channel's unit) 0 (none) or
  ``>= 1e-100`` (:data:`MIN_QUANTUM`);
* ``rate_limit`` (r, the channel's unit per second) ``> 0``; ``inf`` means none.

Every value must be a finite number (but ``rate_limit = inf``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import did_you_mean, whole_step_count

__all__ = ["ACTUATOR_KEYS", "MAX_DELAY_STEPS", "MIN_QUANTUM", "SENSOR_KEYS", "delay_steps", "nonideal_channels"]

ACTUATOR_KEYS = ("delay", "lag", "quantization", "rate_limit")
SENSOR_KEYS = ("delay", "quantization")
#: Longest delay [steps]: the FIFO holds this many samples per channel.
MAX_DELAY_STEPS = 100_000
#: Smallest quantization step: ``y / q`` stays finite for any value a loop can hold (|y| < 1e208).
MIN_QUANTUM = 1e-100


def delay_steps(delay: float, dt: float, what: str = "delay") -> int:
    """The number of whole steps ``delay / dt`` (``>= 0``), refusing a delay between two whole steps.

    Raises:
        InvalidArgument: negative, not finite, not a whole number of steps (the message gives the two nearest
            valid delays), or longer than :data:`MAX_DELAY_STEPS` steps.
    """
    if not math.isfinite(delay) or delay < 0:
        raise InvalidArgument(f"{what} must be a finite number of seconds >= 0, got {delay!r}")
    ratio = delay / dt
    if ratio > MAX_DELAY_STEPS + 0.5:
        raise InvalidArgument(
            f"{what} = {delay:g} s is {ratio:.3g} steps of dt = {dt:g} s; the limit is {MAX_DELAY_STEPS:,}"
        )
    return whole_step_count(delay, dt, what)


def _values(key: str, value: Any, size: int, unit: str, what: str) -> np.ndarray:
    """A scalar or a list of ``size`` numbers as an array ``(size,)``, each checked for ``key``'s range."""
    items = value if isinstance(value, list) else [value]
    if isinstance(value, list) and len(value) != size:
        raise InvalidArgument(f"{what}: '{key}' must be a number or a list of {size} ({unit}), got {len(value)} values")
    for v in items:
        if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
            raise InvalidArgument(f"{what}: '{key}' must be a number or a list of {size} numbers ({unit}), got {v!r}")
    arr = np.broadcast_to(np.asarray(items, dtype=float), (size,)).copy()
    if np.isnan(arr).any():
        raise InvalidArgument(f"{what}: '{key}' must not be NaN, got {value!r}")
    if key == "rate_limit":
        if (arr <= 0).any():
            raise InvalidArgument(f"{what}: 'rate_limit' must be > 0 (inf: none), got {value!r}")
    else:
        if not np.isfinite(arr).all():
            raise InvalidArgument(f"{what}: '{key}' must be finite, got {value!r}")
        if (arr < 0).any():
            raise InvalidArgument(f"{what}: '{key}' must be >= 0 (0: none), got {value!r}")
        if key == "quantization" and ((arr > 0) & (arr < MIN_QUANTUM)).any():
            raise InvalidArgument(f"{what}: 'quantization' must be 0 (none) or >= {MIN_QUANTUM:g}, got {value!r}")
    return arr


def nonideal_channels(
    table: Mapping[str, Any], keys: tuple[str, ...], size: int, dt: float, *, unit: str, what: str
) -> dict[str, np.ndarray]:
    """Check an actuator or sensor table and return each given key as an array ``(size,)``.

    Args:
        table: The table as loaded (``{"delay": 0.02, "lag": [0.05, 0.1]}``).
        keys: The valid keys (:data:`ACTUATOR_KEYS` or :data:`SENSOR_KEYS`).
        size: Channels: inputs ``m`` (actuator) or states ``n`` (sensor).
        dt: The loop's step [s]; ``delay`` must be a whole number of it.
        unit: How a list is described in messages (``"one per input"``).
        what: The table's name in messages (``"[sim] actuator"``).

    Returns:
        Key → values ``(size,)``; ``delay`` in seconds (whole steps, checked).

    Raises:
        InvalidArgument: an unknown key, a wrong type or length, or a value out of its range (one line).
    """
    if not isinstance(table, Mapping):
        raise InvalidArgument(f"{what} must be a table such as {{ {keys[0]} = ... }}, got {table!r}")
    for key in table:
        if key not in keys:
            raise InvalidArgument(
                f"{what}: unknown key '{key}'{did_you_mean(str(key), keys)} (valid: {', '.join(keys)})"
            )
    out = {key: _values(key, table[key], size, unit, what) for key in keys if key in table}
    for i, d in enumerate(out.get("delay", ())):
        delay_steps(float(d), dt, f"{what}: 'delay'" + (f"[{i}]" if size > 1 else ""))
    return out
