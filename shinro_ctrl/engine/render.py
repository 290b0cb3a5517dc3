"""Offscreen rendering of an engine's current state (used by :mod:`shinro_ctrl.video`)."""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from shinro_ctrl.engine.mjcf import _mujoco_message
from shinro_ctrl.errors import InvalidArgument

if TYPE_CHECKING:
    from shinro_ctrl.engine.core import MujocoEngine

__all__ = ["OffscreenRenderer"]


# --------------------------------------------------------- offscreen rendering
class OffscreenRenderer:
    """Renders an engine's current state offscreen (made by :meth:`MujocoEngine.make_renderer`).

    The default view is a free camera, initially MuJoCo's default framing of
    the whole model; :meth:`look_at` moves it. Named model cameras can be
    used per call.

    Attributes:
        width, height: Image size [px].
        fovy: Vertical field of view of the free camera [deg].
    """

    def __init__(self, engine: MujocoEngine, width: int, height: int, *, shadows: bool = False):
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 16 <= v <= 8192:
                raise InvalidArgument(f"renderer {name} must be an integer in [16, 8192], got {v!r}")
        self.width, self.height = int(width), int(height)
        self._engine = engine
        model = engine.model
        g = model.vis.global_
        g.offwidth, g.offheight = max(int(g.offwidth), self.width), max(int(g.offheight), self.height)
        self.fovy = float(g.fovy)
        self._renderer: Any = None
        try:
            self._renderer = mujoco.Renderer(model, height=self.height, width=self.width)
        except (ImportError, RuntimeError, OSError, mujoco.FatalError) as exc:
            backend = os.environ.get("MUJOCO_GL") or "unset (glfw)"
            raise RuntimeError(
                f"cannot create an offscreen OpenGL context (MUJOCO_GL={backend}): {_mujoco_message(exc)}"
            ) from exc
        self._renderer.scene.flags[int(mujoco.mjtRndFlag.mjRND_SHADOW)] = bool(shadows)
        self._camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(model, self._camera)

    def look_at(self, center: Any, distance: float, *, azimuth: float = 90.0, elevation: float = -15.0) -> None:
        """Point the free camera at ``center (3,)`` [m] from ``distance`` [m].

        ``azimuth`` and ``elevation`` are in degrees, as in MuJoCo: azimuth
        90 looks along +y (the xz plane seen from -y, +x to the right);
        negative elevations look down.
        """
        c = np.asarray(center, dtype=float).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise InvalidArgument(f"look_at center must be 3 finite values, got {c}")
        if not (math.isfinite(distance) and distance > 0):
            raise InvalidArgument(f"look_at distance must be positive, got {distance!r}")
        cam = self._camera
        cam.type = int(mujoco.mjtCamera.mjCAMERA_FREE)
        cam.lookat[:] = c
        cam.distance = float(distance)
        cam.azimuth = float(azimuth)
        cam.elevation = float(elevation)

    def render(self, camera: str | int | None = None) -> np.ndarray:
        """Render the engine's current state: an ``(height, width, 3)`` ``uint8`` RGB image.

        Args:
            camera: None for the free camera, or a model camera's name or id.

        Raises:
            RuntimeError: the renderer is closed.
        """
        if self._renderer is None:
            raise RuntimeError("render called on a closed OffscreenRenderer")
        self._engine.ensure_kinematics()
        self._renderer.update_scene(self._engine.data, camera=self._camera if camera is None else camera)
        return self._renderer.render()

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> OffscreenRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
