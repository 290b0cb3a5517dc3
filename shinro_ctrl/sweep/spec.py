"""The sweep specification: parameter ranges, their keys, and the drawn samples; the table's metric lists."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from shinro_ctrl.errors import ConfigError, ShinroError
from shinro_ctrl.sim.metrics import (
    METRICS,
    WALL_CLOCK_METRICS,  # measured with a clock: they stay out of the table
)
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "MAX_ROWS",
    "METHODS",
    "SAMPLE_ERRORS",
    "STABLE_TOL_FACTOR",
    "TABLE_METRICS",
    "WALL_CLOCK_METRICS",
    "check_keys",
    "check_range",
    "draw_samples",
    "parse_param",
    "parse_params",
    "sweep_keys",
]

METHODS = ("auto", "pool", "dask", "batch", "serial")
STABLE_TOL_FACTOR = 10.0
MAX_ROWS = 10_000_000
#: The metrics of the table (every metric of :data:`shinro_ctrl.sim.metrics.METRICS` but the wall-clock ones).
TABLE_METRICS = tuple(m for m in METRICS if m not in WALL_CLOCK_METRICS)
#: Exceptions a sample may raise that mark it unstable (anything else is a bug and propagates).
SAMPLE_ERRORS: tuple[type[BaseException], ...] = (ShinroError, ValueError, ArithmeticError, RuntimeError)


# ------------------------------------------------------------------ the spec
def parse_param(text: str) -> tuple[str, tuple[float, float]]:
    """Parse one ``KEY=LO:HI`` range, e.g. ``plant.pole_mass=0.05:0.5``.

    Raises:
        ConfigError: malformed text, a non-finite bound or ``LO > HI``.
    """
    key, sep, rng = text.partition("=")
    key = key.strip()
    lo_text, sep2, hi_text = rng.partition(":")
    if not sep or not sep2 or not key:
        raise ConfigError(f"--param expects KEY=LO:HI (e.g. plant.pole_mass=0.05:0.5), got {text!r}")
    try:
        lo, hi = float(lo_text), float(hi_text)
    except ValueError:
        raise ConfigError(f"--param {key}: LO and HI must be numbers, got {rng!r}") from None
    return key, check_range(key, (lo, hi))


SWEEP_LIMIT = 1e12  # |value| of a swept parameter: a mass or length of 1e12 already overflows the dynamics' squares


def parse_params(texts: Iterable[str]) -> dict[str, tuple[float, float]]:
    """Parse several ``KEY=LO:HI`` ranges into a dict (a key given twice is an error)."""
    out: dict[str, tuple[float, float]] = {}
    for text in texts:
        key, rng = parse_param(text)
        if key in out:
            raise ConfigError(f"--param {key} given twice")
        out[key] = rng
    return out


def check_range(key: str, rng: Any) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise ConfigError(f"sweep range of {key!r} must be a (LO, HI) pair of numbers, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ConfigError(f"sweep range of {key!r} must be finite, got {lo:g}:{hi:g}")
    if lo > hi:
        raise ConfigError(f"sweep range of {key!r}: LO must be <= HI, got {lo:g}:{hi:g}")
    if not math.isfinite(hi - lo) or max(abs(lo), abs(hi)) > SWEEP_LIMIT:
        raise ConfigError(
            f"sweep range of {key!r} is {lo:g}:{hi:g}; values are limited to |v| <= {SWEEP_LIMIT:g} "
            "(the perturbed plant's arithmetic overflows beyond)"
        )
    return lo, hi


def sweep_keys(plant: Any) -> tuple[str, ...]:
    """The dotted keys a sweep may perturb: ``plant.<name>`` for each scalar constructor parameter."""
    return tuple(
        f"plant.{k}"
        for k, v in plant.params().items()
        if isinstance(v, int | float | np.floating) and not isinstance(v, bool)
    )


def check_keys(params: Mapping[str, Any], valid: Sequence[str]) -> None:
    for key in params:
        if key in valid:
            continue
        if not key.startswith("plant."):
            raise ConfigError(
                f"cannot sweep {key!r}: only [plant] parameters are perturbed (the controller is designed "
                f"once on the nominal plant){did_you_mean(key, valid)}"
            )
        raise ConfigError(f"unknown sweep key {key!r}{did_you_mean(key, valid)}")


def draw_samples(
    ranges: Mapping[str, tuple[float, float]], samples: int, *, grid: bool = False, seed: int = 0
) -> np.ndarray:
    """The parameter rows of a sweep, ``(S, P)`` with columns in ``ranges`` order.

    Monte-Carlo: ``S = samples`` rows of ``numpy.random.default_rng(seed).uniform(lo, hi)``
    (drawn as one ``(S, P)`` array). Grid: ``samples`` evenly spaced points per
    parameter (``linspace(lo, hi, samples)``), full product, ``S = samples ** P``,
    the last parameter varying fastest.
    """
    los = np.array([r[0] for r in ranges.values()], dtype=float)
    his = np.array([r[1] for r in ranges.values()], dtype=float)
    if grid:
        axes = [np.linspace(lo, hi, samples) for lo, hi in zip(los, his, strict=True)]
        return np.array(list(itertools.product(*axes)), dtype=float).reshape(-1, len(axes))
    rng = np.random.default_rng(seed)
    return rng.uniform(los, his, size=(samples, len(los)))
