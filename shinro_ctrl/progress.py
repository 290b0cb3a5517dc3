"""One progress bar for long runs (simulations, sweeps, video renders)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

__all__ = ["Progress"]


class Progress:
    """A one-line progress bar on stderr, or a callback ``f(done, total)``.

    Args:
        total: Number of units of work.
        label: Text before the bar.
        enabled: True / False, None for "when stderr is a terminal", or a
            callback that receives every update instead of a bar.
        delay: Seconds of work before the bar first appears (short runs stay quiet).
        unit: Word after the ``done/total`` count (``"frames"``, ``"samples"``, …).
    """

    def __init__(
        self,
        total: int,
        label: str,
        enabled: bool | Callable[[int, int], None] | None,
        *,
        delay: float = 2.0,
        unit: str = "",
    ):
        self.total, self.label, self.unit = max(int(total), 1), label, unit
        self.callback = enabled if callable(enabled) else None
        self.enabled = self.callback is None and (sys.stderr.isatty() if enabled is None else bool(enabled))
        self.start = time.perf_counter()
        self.delay, self.shown, self.last = delay, False, 0.0

    def elapsed(self) -> float:
        """Seconds since the bar was created."""
        return time.perf_counter() - self.start

    def update(self, done: int) -> None:
        """Report ``done`` units finished (redrawn at most every 0.2 s)."""
        if self.callback is not None:
            self.callback(done, self.total)
            return
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.start < self.delay or now - self.last < 0.2:
            return
        self.last, self.shown = now, True
        frac = done / self.total
        eta = f"{(now - self.start) * (1 - frac) / frac:5.1f} s" if frac > 0 else "    ? s"
        count = f"{done}/{self.total} {self.unit}".rstrip()
        sys.stderr.write(f"\r{self.label} [{'#' * int(30 * frac):30s}] {count}  eta {eta} ")
        sys.stderr.flush()

    def close(self) -> None:
        """Finish the line if the bar was shown."""
        if self.shown:
            count = f"{self.total}/{self.total} {self.unit}".rstrip()
            sys.stderr.write(f"\r{self.label} [{'#' * 30}] {count}  {self.elapsed():.1f} s\n")
            sys.stderr.flush()
