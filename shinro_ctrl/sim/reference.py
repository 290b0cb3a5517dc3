"""State references of a scenario's ``[sim] reference`` table: :class:`Reference`."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["Reference"]


class Reference:
    """A state reference ``r(t) (n,)`` and its rate ``ṙ(t) (n,)``.

    Kinds (keys as in the ``[sim] reference`` table; vectors are full states):

    * ``constant``: ``value`` (default: the operating point).
    * ``step``: ``initial`` until ``time``, then ``final``.
    * ``circle``: in the plane of state ``axes`` (default ``[0, 1]``), radius
      ``radius`` [m], ``frequency`` [Hz], around ``center``; without a centre
      the circle starts at the default point (``phase`` 0 there).
    * ``square``: side ``side`` [m] traversed at ``speed`` [m/s], starting at
      ``center`` (default: the default point) as a corner, counter-clockwise.
    * ``waypoints``: ``points`` at ``times``, ``linear`` or ``hold`` interpolation.
    """

    def __init__(self, spec: dict[str, Any], default: np.ndarray):
        self.kind = spec.get("kind", "constant")
        self.spec = spec
        self.default = np.asarray(default, dtype=float)
        n = self.default.shape[0]
        self.axes = spec.get("axes", [0, 1] if n >= 2 else [0, 0])
        if self.kind == "circle":
            r = spec["radius"]
            self.omega = 2 * math.pi * spec["frequency"]
            self.phase = spec.get("phase", 0.0)
            if "center" in spec:
                self.center = np.asarray(spec["center"], dtype=float)
            else:
                self.center = self.default.copy()
                self.center[self.axes[0]] -= r * math.cos(self.phase)
                self.center[self.axes[1]] -= r * math.sin(self.phase)
        elif self.kind == "square":
            self.center = np.asarray(spec.get("center", self.default), dtype=float)
        elif self.kind == "waypoints":
            self.points = np.asarray(spec["points"], dtype=float)
            self.times = np.asarray(spec["times"], dtype=float)

    def __call__(self, t: float) -> np.ndarray:
        k, s = self.kind, self.spec
        if k == "constant":
            return np.asarray(s.get("value", self.default), dtype=float).copy()
        if k == "step":
            key = "initial" if t < s["time"] else "final"
            return np.asarray(s.get(key, self.default), dtype=float).copy()
        if k == "circle":
            r = self.center.copy()
            a = self.omega * t + self.phase
            r[self.axes[0]] += s["radius"] * math.cos(a)
            r[self.axes[1]] += s["radius"] * math.sin(a)
            return r
        if k == "square":
            r = self.center.copy()
            side = s["side"]
            d = (s["speed"] * t) % (4 * side)
            leg, along = int(d // side), d % side
            corner = [(0.0, 0.0), (side, 0.0), (side, side), (0.0, side)][leg]
            direction = [(1, 0), (0, 1), (-1, 0), (0, -1)][leg]
            r[self.axes[0]] += corner[0] + direction[0] * along
            r[self.axes[1]] += corner[1] + direction[1] * along
            return r
        # waypoints
        if t <= self.times[0]:
            return self.points[0].copy()
        if t >= self.times[-1]:
            return self.points[-1].copy()
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        if s.get("interpolation", "linear") == "hold":
            return self.points[i].copy()
        w = (t - self.times[i]) / (self.times[i + 1] - self.times[i])
        return (1 - w) * self.points[i] + w * self.points[i + 1]

    def rate(self, t: float) -> np.ndarray:
        """``ṙ(t)``: analytic for circles and squares, slopes for linear waypoints, else zero."""
        out = np.zeros_like(self.default)
        s = self.spec
        if self.kind == "circle":
            a = self.omega * t + self.phase
            out[self.axes[0]] = -s["radius"] * self.omega * math.sin(a)
            out[self.axes[1]] = s["radius"] * self.omega * math.cos(a)
        elif self.kind == "square":
            leg = int(((s["speed"] * t) % (4 * s["side"])) // s["side"])
            direction = [(1, 0), (0, 1), (-1, 0), (0, -1)][leg]
            out[self.axes[0]] = s["speed"] * direction[0]
            out[self.axes[1]] = s["speed"] * direction[1]
        elif self.kind == "waypoints" and s.get("interpolation", "linear") == "linear":
            if self.times[0] < t < self.times[-1]:
                i = int(np.searchsorted(self.times, t, side="right")) - 1
                out = (self.points[i + 1] - self.points[i]) / (self.times[i + 1] - self.times[i])
        return out
