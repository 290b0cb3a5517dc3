"""Error context of the parser: every message names the file, the table and the key."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from shinro_ctrl.config.strict import check_value
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean, unknown_keys

__all__: list[str] = []  # _Ctx is the config layer's own


class _Ctx:
    """Formats errors with the file and table they come from."""

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
