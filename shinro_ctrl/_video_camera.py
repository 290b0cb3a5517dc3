"""Camera helpers of :mod:`shinro_ctrl.video`: the box the moving parts sweep, its framing, the time stamp."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _moving_bounds(engine: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """Axis-aligned box ``(lo (3,), hi (3,))`` [m] around the geoms of moving bodies, at the current state."""
    model, data = engine.model, engine.data
    moving = np.asarray(model.geom_bodyid) != 0
    if not np.any(moving):
        return None
    pos = np.asarray(data.geom_xpos)[moving]
    rad = np.minimum(np.asarray(model.geom_rbound)[moving], 0.5 * float(model.stat.extent) + 1e-9)[:, None]
    return (pos - rad).min(axis=0), (pos + rad).max(axis=0)


def _framing(lo: np.ndarray, hi: np.ndarray, fovy_deg: float, aspect: float, extent: float) -> dict[str, Any]:
    """A free-camera pose that keeps the box ``[lo, hi]`` in view."""
    center = 0.5 * (lo + hi)
    size = np.maximum(hi - lo, 1e-3)
    radius = max(0.5 * float(np.linalg.norm(size)), 0.05 * extent, 0.05)
    half_v = math.radians(fovy_deg) / 2
    half_h = math.atan(math.tan(half_v) * aspect)
    distance = 1.1 * radius / math.sin(min(half_v, half_h))
    planar = size[2] < 0.3 * max(size[0], size[1])  # ground robots: look down on the plane
    return {"center": center, "distance": distance, "azimuth": 90.0, "elevation": -50.0 if planar else -12.0}


def _stamp(image: np.ndarray, text: str) -> np.ndarray:
    """A copy of ``image`` with ``text`` in its top-left corner."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(image)
    ImageDraw.Draw(im).text((6, 4), text, fill=(235, 235, 235))
    return np.asarray(im)
