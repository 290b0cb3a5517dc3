"""The shipped 6-DOF arm as Python constants (never read from a file: a local ``arm6.toml`` changes nothing)."""

from __future__ import annotations

import copy
from typing import Any

__all__ = ["ARM6", "ARM6_AXES", "ARM6_BODIES", "ARM6_JOINTS", "shipped_arm6"]

_TAU = 6.283185307179586

ARM6_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
ARM6_AXES = ("z", "y", "y", "y", "z", "x")
ARM6_BODIES = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")

#: The shipped 6-DOF arm (UR5 link lengths, axes z y y y z x), matched to ``assets/arm6.xml``: the
#: geometry ``ArmRobot()`` builds. ``configs/arm6.toml`` repeats it as a scenario (a test checks they agree);
#: nothing is read from a file, so a local ``arm6.toml`` never changes the arm.
ARM6: dict[str, Any] = {
    "num_dof": 6,
    "dt": 0.002,
    "joint_names": list(ARM6_JOINTS),
    "rot_axes": list(ARM6_AXES),
    "joint_offsets": [
        [0.0, 0.0, 0.089159],
        [0.0, 0.13585, 0.0],
        [0.0, -0.1197, 0.425],
        [0.39225, 0.0, 0.0],
        [0.0, 0.093, 0.0],
        [0.0, 0.0, -0.09465],
    ],
    "joint_limits": [[-_TAU, _TAU], [-1.6, 1.6], [-1.4, 1.4], [-_TAU, _TAU], [-_TAU, _TAU], [-_TAU, _TAU]],
}


def shipped_arm6() -> dict:
    """The shipped arm's constructor arguments (a fresh copy of :data:`ARM6`), the default arm."""
    return copy.deepcopy(ARM6)
