"""Closed-loop poles as a control engineer reads them: damping, natural frequency, time constant.

A discrete pole ``z`` at sampling time ``dt`` is mapped to its continuous
equivalent by the inverse of ``z = e^{s dt}``:

    s = ln(z) / dt    (principal branch; a negative real z gives Im s = π/dt)

and, for ``s = −ζ ωn ± j ωn √(1 − ζ²)``,

    ωn = |s|,   ζ = −Re(s) / |s|,   τ = −1 / Re(s)   (the envelope's time constant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument

__all__ = ["PoleRow", "PoleTable", "pole_table"]

#: Damping ratio below which a pole is flagged as poorly damped.
ZETA_WARN = 0.3


@dataclass(frozen=True)
class PoleRow:
    """One pole.

    Attributes:
        pole: The pole as given (``z`` for a discrete system, ``s`` for a continuous one).
        s: Continuous equivalent ``ln(z)/dt`` [1/s] (``-inf`` for ``z = 0``, a deadbeat pole).
        zeta: Damping ratio ζ (1 for a deadbeat pole, 0 for ``s = 0``; negative when unstable).
        wn: Natural frequency ωn = |s| [rad/s] (``inf`` for a deadbeat pole).
        tau: Time constant −1/Re(s) [s] (``inf`` when Re(s) ≥ 0, 0 for a deadbeat pole).
        flags: ``"unstable"`` (|z| ≥ 1 or Re s ≥ 0) and/or ``"ζ < 0.3"``; empty when neither.
    """

    pole: complex
    s: complex
    zeta: float
    wn: float
    tau: float
    flags: tuple[str, ...]


@dataclass(frozen=True)
class PoleTable:
    """Rows of :func:`pole_table`, sorted by natural frequency.

    Attributes:
        rows: One :class:`PoleRow` per pole.
        dt: Sampling time [s], or None for continuous poles.
    """

    rows: tuple[PoleRow, ...]
    dt: float | None

    @property
    def zeta_min(self) -> float:
        """Smallest damping ratio over the poles."""
        return min(r.zeta for r in self.rows)

    @property
    def wn_range(self) -> tuple[float, float]:
        """Smallest and largest finite natural frequency [rad/s]."""
        w = [r.wn for r in self.rows if math.isfinite(r.wn)]
        return (min(w), max(w)) if w else (math.inf, math.inf)

    @property
    def stable(self) -> bool:
        """True when no pole is flagged unstable."""
        return not any("unstable" in r.flags for r in self.rows)

    def format(self) -> str:
        """A fixed-width text table."""
        head = "z (discrete)" if self.dt is not None else "s"
        lines = [f"  {head:^25s} {'|z|' if self.dt else '':>8s} {'ζ':>8s} {'ωn [rad/s]':>11s} {'τ [s]':>9s}  flags"]
        for r in self.rows:
            p = r.pole
            mag = f"{abs(p):8.5f}" if self.dt is not None else " " * 8
            lines.append(
                f"  {p.real:+11.6f} {p.imag:+11.6f}j {mag} {r.zeta:8.4f} {_g(r.wn):>11s} {_g(r.tau):>9s}  "
                + ", ".join(r.flags)
            )
        lo, hi = self.wn_range
        lines.append(f"  ζ_min = {self.zeta_min:.4f}, ωn from {_g(lo)} to {_g(hi)} rad/s")
        return "\n".join(lines)


def _g(v: float) -> str:
    return "inf" if math.isinf(v) else f"{v:.4g}"


def pole_table(poles: Any, dt: float | None = None, *, zeta_warn: float = ZETA_WARN) -> PoleTable:
    """Damping ratio, natural frequency and time constant of each pole.

    Args:
        poles: Poles ``(n,)`` (complex): discrete ``z`` when ``dt`` is given, else continuous ``s``.
        dt: Sampling time [s] of discrete poles, or None for continuous ones.
        zeta_warn: Damping ratio below which a pole is flagged.

    Returns:
        A :class:`PoleTable`, rows sorted by ωn (then by Im).

    Raises:
        InvalidArgument: ``dt`` not positive, or a non-finite pole.
    """
    p = np.atleast_1d(np.asarray(poles, dtype=complex)).ravel()
    if not np.all(np.isfinite(p)):
        raise InvalidArgument(f"poles must be finite, got {p}")
    if dt is not None and not (math.isfinite(dt) and dt > 0):
        raise InvalidArgument(f"dt must be a positive number of seconds or None, got {dt!r}")
    rows = []
    for z in p:
        z = complex(z)
        if dt is not None:
            unstable = abs(z) >= 1.0 - 1e-12
            if z == 0:
                rows.append(PoleRow(z, complex(-math.inf), 1.0, math.inf, 0.0, ()))
                continue
            s = complex(np.log(z)) / dt
        else:
            unstable = z.real >= -1e-12
            s = z
        wn = abs(s)
        zeta = -s.real / wn if wn > 0 else 0.0
        tau = -1.0 / s.real if s.real < 0 else math.inf
        flags = []
        if unstable:
            flags.append("unstable")
        if zeta < zeta_warn:
            flags.append(f"ζ < {zeta_warn:g}")
        rows.append(PoleRow(z, s, float(zeta), float(wn), float(tau), tuple(flags)))
    rows.sort(key=lambda r: (r.wn, r.pole.imag))
    return PoleTable(tuple(rows), dt)
