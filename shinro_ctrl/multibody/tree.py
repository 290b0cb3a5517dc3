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

__all__ = ["JOINT_QPOS", "JOINT_QVEL", "ActuatorInfo", "BodyInfo", "JointInfo", "ModelTree", "SiteInfo", "TendonInfo"]


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
        gravcomp: Gravity compensation factor ``s``: MuJoCo applies the force ``−s m g`` at the body's
            centre of mass (``1`` cancels the body's weight; see ``RigidBodyTree.gravity_compensation``).
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
    gravcomp: float = 0.0


@dataclass(frozen=True)
class JointInfo:
    """One joint: a hinge, a slide, a ball or a free joint.

    A hinge or slide has one coordinate and one velocity; a ball joint has a unit quaternion
    ``(w, x, y, z)`` (4 ``qpos``) and the body-frame angular velocity (3 ``qvel``); a free joint has
    the body's world position and orientation quaternion (7 ``qpos``) and the world-frame linear
    velocity then the body-frame angular velocity (6 ``qvel``), MuJoCo's conventions (see
    :mod:`shinro_ctrl.multibody.configuration`).

    Attributes:
        name: Joint name.
        type: ``"hinge"``, ``"slide"``, ``"ball"`` or ``"free"``.
        body: Index of the body the joint moves.
        axis: Unit axis in the body frame ``(3,)``.
        pos: Anchor in the body frame ``(3,)`` [m].
        qpos0: Reference coordinate (the body's pose in the model is at ``qpos0``); ball and free
            joints: 0 (their reference configuration is the identity quaternion and the body's pose).
        damping: Viscous damping [N m s/rad or N s/m].
        armature: Rotor inertia added to ``M``'s diagonal [kg m² or kg].
        stiffness: Spring stiffness [N m/rad or N/m].
        springref: Spring rest coordinate.
        limited: Whether the joint has a range.
        range: ``(lo, hi)`` (meaningful when ``limited``).
        frictionloss: Dry friction [N m or N] (0 when the model disables it). Recorded, never in
            the smooth dynamics: MuJoCo applies it as a constraint force in its own loop.
        actgravcomp: True when MuJoCo routes this joint's gravity compensation through the actuators
            (``actuatorgravcomp``): the same force, then subject to the joint's actuator force clamp.
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
    frictionloss: float = 0.0
    actgravcomp: bool = False


#: Number of ``qpos`` and ``qvel`` entries of each joint type.
JOINT_QPOS = {"hinge": 1, "slide": 1, "ball": 4, "free": 7}
JOINT_QVEL = {"hinge": 1, "slide": 1, "ball": 3, "free": 6}


@dataclass(frozen=True)
class SiteInfo:
    """A site: a frame fixed on a body (where site transmissions apply their wrench).

    Attributes:
        name: Site name.
        body: Index of the body it is fixed on.
        pos: Origin in the body frame ``(3,)`` [m].
        quat: Orientation in the body frame ``(w, x, y, z)``.
    """

    name: str
    body: int
    pos: np.ndarray
    quat: np.ndarray


@dataclass(frozen=True)
class TendonInfo:
    r"""A fixed tendon: a linear combination of joint coordinates.

    Length ``L(q) = Σ_k c_k q_{j_k}`` (MuJoCo uses ``qpos`` itself, not ``qpos − qpos0``), moment arm
    ``∂L/∂q = c`` (constant), velocity ``L̇ = cᵀ q̇``. Its passive force ``F = −k (L − L_s) − b L̇``
    acts on the joints as ``cᵀ F``.

    Attributes:
        name: Tendon name.
        joints: Indices of the joints it couples.
        coefs: Their coefficients ``c_k``.
        stiffness: Spring stiffness ``k`` [N/m or N m/rad].
        springlength: Spring rest length ``L_s``.
        damping: Viscous damping ``b``.
        frictionloss: Dry friction (recorded; MuJoCo-loop only, like a joint's).
        limited: Whether the tendon has a length range (a constraint: MuJoCo-loop only).
        range: ``(lo, hi)`` (meaningful when ``limited``).
    """

    name: str
    joints: tuple[int, ...]
    coefs: tuple[float, ...]
    stiffness: float = 0.0
    springlength: float = 0.0
    damping: float = 0.0
    frictionloss: float = 0.0
    limited: bool = False
    range: tuple[float, float] = (-np.inf, np.inf)


@dataclass(frozen=True)
class ActuatorInfo:
    """One actuator: its transmission, activation dynamics and force law.

    The force law and the transmissions are in :mod:`shinro_ctrl.multibody.transmission`.

    Attributes:
        name: Actuator name.
        kind: ``"motor"``, ``"position"``, ``"velocity"`` or ``"general"`` (informative).
        joint: Index of the driven joint (``transmission == "joint"``), else -1.
        gear: Gear ratio ``g`` (the first gear component).
        gaintype: ``"fixed"`` or ``"affine"``.
        gainprm: ``(p₀, p₁, p₂)``.
        biastype: ``"none"`` or ``"affine"``.
        biasprm: ``(b₀, b₁, b₂)``.
        ctrlrange: ``(lo, hi)`` when MuJoCo clamps the control, else None.
        forcerange: ``(lo, hi)`` when MuJoCo clamps the force, else None.
        transmission: ``"joint"``, ``"tendon"`` or ``"site"``.
        target: Index of the joint, tendon or site the actuator drives.
        refsite: Index of the reference site of a site transmission, else -1.
        gear6: The full gear ``(6,)``: for a site, force along ``gear6[0:3]`` and torque about
            ``gear6[3:6]`` in the site frame (the refsite frame when there is one).
        dyntype: ``"none"``, ``"filter"``, ``"filterexact"`` or ``"integrator"``.
        dynprm: ``(τ, ·, ·)``: the filter time constant ``τ`` [s].
        act: Index of the actuator's activation in the activation state, else -1.
        actrange: ``(lo, hi)`` when MuJoCo clamps the activation (its loop only), else None.
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
    transmission: str = "joint"
    target: int = -1
    refsite: int = -1
    gear6: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    dyntype: str = "none"
    dynprm: tuple[float, float, float] = (1.0, 0.0, 0.0)
    act: int = -1
    actrange: tuple[float, float] | None = None


@dataclass(frozen=True)
class ModelTree:
    """A kinematic tree (fixed or floating base: hinge, slide, ball and free joints) with its actuators and options.

    Attributes:
        name: Model name.
        path: Absolute path of the model file ("" when built in memory).
        bodies: Bodies, index 0 the world; parents precede children.
        joints: The joints in MuJoCo's ``qpos`` order (:attr:`qposadr` and :attr:`dofadr` index them).
        actuators: Actuators in MuJoCo's ``ctrl`` order.
        gravity: The model's gravity vector ``(3,)`` [m/s²] (``opt.gravity``).
        timestep: The model's ``opt.timestep`` [s].
        integrator: The model's integrator name (e.g. ``"Euler"``).
        gravity_enabled: False when the model disables gravity.
        damping_enabled: False when the model disables joint damping.
        springs_enabled: False when the model disables joint springs.
        actuation_enabled: False when the model disables actuation.
        disableflags: The model's raw ``opt.disableflags`` bit field.
        tendons: Fixed tendons in MuJoCo's order.
        sites: Sites in MuJoCo's order.
        frictionloss_enabled: False when the model disables friction loss.
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
    tendons: tuple[TendonInfo, ...] = ()
    sites: tuple[SiteInfo, ...] = ()
    frictionloss_enabled: bool = True
    equalities: tuple[Constraint, ...] = ()

    @property
    def nq(self) -> int:
        """Number of joint coordinates (``qpos``; a ball joint has 4, a free joint 7)."""
        return sum(JOINT_QPOS[j.type] for j in self.joints)

    @property
    def nv(self) -> int:
        """Number of joint velocities (``qvel``, degrees of freedom; a ball joint has 3, a free joint 6)."""
        return sum(JOINT_QVEL[j.type] for j in self.joints)

    @property
    def qposadr(self) -> tuple[int, ...]:
        """Each joint's first index in ``qpos`` (MuJoCo's ``jnt_qposadr``)."""
        return tuple(np.cumsum([0] + [JOINT_QPOS[j.type] for j in self.joints])[:-1].tolist())

    @property
    def dofadr(self) -> tuple[int, ...]:
        """Each joint's first index in ``qvel`` (MuJoCo's ``jnt_dofadr``)."""
        return tuple(np.cumsum([0] + [JOINT_QVEL[j.type] for j in self.joints])[:-1].tolist())

    @property
    def floating(self) -> bool:
        """Whether the tree has a ball or free joint (then ``nq != nv``)."""
        return any(j.type in ("ball", "free") for j in self.joints)

    @property
    def na(self) -> int:
        """Number of activation states (actuators with activation dynamics)."""
        return sum(1 for a in self.actuators if a.act >= 0)

    @property
    def nu(self) -> int:
        """Number of actuators."""
        return len(self.actuators)
