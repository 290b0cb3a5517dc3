"""``ArmRobot.from_config`` with an engine: the joint limits (and, by default, the geometry) from the MJCF."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.plants._arm6 import ARM6_JOINTS, shipped_arm6


class JointLimits(Protocol):
    """What :func:`with_engine_limits` reads from an engine: a joint's ``(min, max)`` range."""

    def get_joint_limits(self, name: str) -> tuple[float, float]: ...


def with_engine_limits(cfg: dict, engine: JointLimits) -> dict:
    """``cfg`` completed for an engine (see :meth:`ArmRobot.from_config`): shipped geometry, MJCF joint limits.

    An incomplete custom geometry comes back unchanged (the constructor says what is missing).

    Raises:
        ConfigError: a joint missing from the model, or config limits that disagree with the MJCF.
    """
    num = cfg.get("num_dof", 6)
    custom = any(k in cfg for k in ("joint_offsets", "rot_axes"))
    if not custom and isinstance(num, int | np.integer) and not isinstance(num, bool) and num == 6:
        # No geometry: the shipped arm's (as standalone), with the limits read from the MJCF below.
        shipped = shipped_arm6()
        for key in ("joint_offsets", "rot_axes", "joint_names"):
            cfg.setdefault(key, shipped[key])
    elif not custom:
        return cfg  # incomplete geometry: the constructor says what is missing
    names = cfg.get("joint_names")
    if names is None and isinstance(num, int):
        names = [f"joint_{i}" for i in range(num)] if custom else list(ARM6_JOINTS)
    try:
        limits = np.array([engine.get_joint_limits(n) for n in (names or [])], dtype=float)
    except KeyError as exc:
        raise ConfigError(f"[plant] ArmRobot: {exc.args[0] if exc.args else exc}") from None
    if "joint_limits" in cfg:
        given = np.asarray(cfg["joint_limits"], dtype=float)
        if given.shape != limits.shape or not np.allclose(given, limits, rtol=0.0, atol=1e-9):
            raise ConfigError(
                "[plant] ArmRobot: joint_limits disagree with the MJCF joint ranges "
                f"{limits.tolist()}; omit them to use the model's"
            )
    cfg["joint_limits"] = limits if limits.size else cfg.get("joint_limits")
    return cfg
