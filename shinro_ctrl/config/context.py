"""Error context of the parser: every message names the file, the table and the key."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from shinro_ctrl.config.strict import check_value
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import STEP_RTOL, did_you_mean, unknown_keys, whole_step_count

__all__ = ["ConfigContext", "whole_steps"]


def whole_steps(duration: float, dt: float, what: str = "duration") -> int:
    """The number of steps ``duration / dt``, which must be a whole number >= 1.

    A duration that is not a whole number of steps would be rounded silently (``dt = 10``,
    ``duration = 0.5`` simulated 10 s), so it is refused naming both values and the
    nearest valid durations.

    Args:
        duration: Time span [s], positive.
        dt: Step [s], positive.
        what: How the message names the duration (``"[sim] duration"``, ``"--duration"``).

    Raises:
        ConfigError: not a finite positive number, shorter than one step, not a whole number of steps, or so
            long that its number of steps overflows float64 (``1e308`` s).
    """
    if not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"{what} must be a positive finite number of seconds, got {duration:g}")
    ratio = duration / dt
    if not math.isfinite(ratio):
        raise ConfigError(
            f"{what} = {duration:g} s is too long: its number of steps of dt = {dt:g} s overflows float64 "
            "(give a shorter duration)"
        )
    if ratio < 1 - STEP_RTOL:
        raise ConfigError(f"{what} = {duration:g} s is shorter than one step (dt = {dt:g} s): give at least {dt:g} s")
    return whole_step_count(duration, dt, what, ConfigError)


class ConfigContext:
    """The parser's error context: formats errors with the file (``source``) and table they come from.

    A new table is parsed through it so its messages name the file, table and key like
    every other table's: :meth:`check_keys` (unknown keys with the closest valid one),
    :meth:`check_types` (values strictly against the table dataclass's annotations, see
    :func:`~shinro_ctrl.config.table_annotations`), :meth:`number` and :meth:`vector`.
    """

    def __init__(self, source: str):
        self.source = source

    def error(self, table: str, message: str) -> ConfigError:
        where = f"[{table}] " if table else ""
        return ConfigError(f"{self.source}: {where}{message}")

    def check_keys(self, table: str, mapping: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
        bad = unknown_keys(mapping, allowed)
        if bad:
            raise self.error(table, f"unknown key '{bad[0]}'{did_you_mean(bad[0], allowed)}")

    def number(self, table: str, key: str, value: Any, *, positive: bool = False, minimum: float | None = None):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(table, f"'{key}' must be a number, got {type(value).__name__} {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise self.error(table, f"'{key}' must be finite, got {value!r}")
        if positive and v <= 0:
            raise self.error(table, f"'{key}' must be positive, got {value!r}")
        if minimum is not None and v < minimum:
            raise self.error(table, f"'{key}' must be >= {minimum:g}, got {value!r}")
        return v

    def vector(self, table: str, key: str, value: Any, n: int | None = None, *, finite: bool = True) -> list[float]:
        if not isinstance(value, list) or not value:
            raise self.error(table, f"'{key}' must be a non-empty list of numbers, got {value!r}")
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise self.error(table, f"'{key}' must hold numbers only, got {v!r}")
            if finite and not math.isfinite(v):
                raise self.error(table, f"'{key}' must be finite, got {value!r}")
            out.append(float(v))
        if n is not None and len(out) != n:
            raise self.error(table, f"'{key}' must have {n} values, got {len(out)}")
        return out

    def check_types(self, table: str, mapping: Mapping[str, Any], annotations: Mapping[str, Any]) -> None:
        """Check every value of ``mapping`` strictly against its key's type annotation (see :func:`check_value`)."""
        for key, value in mapping.items():
            if key == "type" and table in ("plant", "controller", "estimator"):
                annotation: Any = "str"
            else:
                annotation = annotations.get(key, "")
            problem = check_value(value, annotation, key)
            if problem:
                raise self.error(table, problem)


_Ctx = ConfigContext  # the parser modules' short name
