"""The plain-numpy description of a kinematic tree: bodies, joints, actuators and model options.

``shinro_ctrl.engine.model_tree.read_model_tree`` fills these from an MJCF or
URDF file; :class:`~shinro_ctrl.multibody.rigid_body.RigidBodyTree` turns
them into equations of motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from shinro_ctrl.multibody.constraints import Constraint

__all__ = ["ActuatorInfo", "BodyInfo", "JointInfo", "ModelTree"]


@dataclass(frozen=True)
class BodyInfo:
    """One body of the tree, in its parent's frame.

    Attributes:
        name: Body name ("" when unnamed).
        parent: Index of the parent body (-1 for the world body, index 0).
        pos: Body frame origin in the parent frame ``(3,)`` [m].
        quat: Body frame orientation in the parent frame, ``(w, x, y, z)``.
        mass: Mass [kg].
        ipos: Centre of mass in the body frame ``(3,)`` [m].
        iquat: Principal axes of inertia in the body frame ``(w, x, y, z)``.
        inertia: Principal moments of inertia about the COM ``(3,)`` [kg m²].
        joints: Indices of the body's joints, in application order.
    """

    name: str
    parent: int
    pos: np.ndarray
    quat: np.ndarray
    mass: float
    ipos: np.ndarray
    iquat: np.ndarray
    inertia: np.ndarray
    joints: tuple[int, ...] = ()


@dataclass(frozen=True)
class JointInfo:
    """One hinge or slide joint.

    Attributes:
        name: Joint name.
        type: ``"hinge"`` or ``"slide"``.
        body: Index of the body the joint moves.
        axis: Unit axis in the body frame ``(3,)``.
        pos: Anchor in the body frame ``(3,)`` [m].
        qpos0: Reference coordinate (the body's pose in the model is at ``qpos0``).
        damping: Viscous damping [N m s/rad or N s/m].
        armature: Rotor inertia added to ``M``'s diagonal [kg m² or kg].
        stiffness: Spring stiffness [N m/rad or N/m].
        springref: Spring rest coordinate.
        limited: Whether the joint has a range.
        range: ``(lo, hi)`` (meaningful when ``limited``).
    """

    name: str
    type: str
    body: int
    axis: np.ndarray
    pos: np.ndarray
    qpos0: float = 0.0
    damping: float = 0.0
    armature: float = 0.0
    stiffness: float = 0.0
    springref: float = 0.0
    limited: bool = False
    range: tuple[float, float] = (-np.inf, np.inf)


@dataclass(frozen=True)
class ActuatorInfo:
    """One actuator with a joint transmission (see the module docstring for the force law).

    Attributes:
        name: Actuator name.
        kind: ``"motor"``, ``"position"``, ``"velocity"`` or ``"general"`` (informative).
        joint: Index of the driven joint.
        gear: Gear ratio ``g``.
        gaintype: ``"fixed"`` or ``"affine"``.
        gainprm: ``(p₀, p₁, p₂)``.
        biastype: ``"none"`` or ``"affine"``.
        biasprm: ``(b₀, b₁, b₂)``.
        ctrlrange: ``(lo, hi)`` when MuJoCo clamps the control, else None.
        forcerange: ``(lo, hi)`` when MuJoCo clamps the force, else None.
    """

    name: str
    kind: str
    joint: int
    gear: float
    gaintype: str = "fixed"
    gainprm: tuple[float, float, float] = (1.0, 0.0, 0.0)
    biastype: str = "none"
    biasprm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ctrlrange: tuple[float, float] | None = None
    forcerange: tuple[float, float] | None = None


@dataclass(frozen=True)
class ModelTree:
    """A fixed-base kinematic tree with its actuators and options.

    Attributes:
        name: Model name.
        path: Absolute path of the model file ("" when built in memory).
        bodies: Bodies, index 0 the world; parents precede children.
        joints: Hinge and slide joints in MuJoCo's ``qpos`` order.
        actuators: Actuators in MuJoCo's ``ctrl`` order.
        gravity: The model's gravity vector ``(3,)`` [m/s²] (``opt.gravity``).
        timestep: The model's ``opt.timestep`` [s].
        integrator: The model's integrator name (e.g. ``"Euler"``).
        gravity_enabled: False when the model disables gravity.
        damping_enabled: False when the model disables joint damping.
        springs_enabled: False when the model disables joint springs.
        actuation_enabled: False when the model disables actuation.
        disableflags: The model's raw ``opt.disableflags`` bit field.
        equalities: The model's active equality constraints (joint couplings, connects, welds), see
            :mod:`shinro_ctrl.multibody.constraints`; empty when it has none or disables them.
    """

    name: str
    path: str
    bodies: tuple[BodyInfo, ...]
    joints: tuple[JointInfo, ...]
    actuators: tuple[ActuatorInfo, ...]
    gravity: np.ndarray
    timestep: float
    integrator: str = "Euler"
    gravity_enabled: bool = True
    damping_enabled: bool = True
    springs_enabled: bool = True
    actuation_enabled: bool = True
    disableflags: int = 0
    equalities: tuple[Constraint, ...] = ()

    @property
    def nq(self) -> int:
        """Number of joint coordinates (= velocities)."""
        return len(self.joints)

    @property
    def nu(self) -> int:
        """Number of actuators."""
        return len(self.actuators)
