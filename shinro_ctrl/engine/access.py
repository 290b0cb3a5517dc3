"""Named, checked access to an engine's joints, actuators, bodies and sites (a mixin of ``MujocoEngine``)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from shinro_ctrl.engine.mjcf import _euler_zyx_from_quat, _real, _unknown
from shinro_ctrl.errors import InvalidArgument, NonFiniteError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["NamedAccess"]

_HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
_SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)
_BALL = int(mujoco.mjtJoint.mjJNT_BALL)
_FREE = int(mujoco.mjtJoint.mjJNT_FREE)
_JOINT_TYPES = {_FREE: "free", _BALL: "ball", _SLIDE: "slide", _HINGE: "hinge"}
_NQ = {_FREE: 7, _BALL: 4, _SLIDE: 1, _HINGE: 1}
_NV = {_FREE: 6, _BALL: 3, _SLIDE: 1, _HINGE: 1}


class NamedAccess:
    """Joint, actuator, body and site access by name; the state vector; Jacobians.

    A mixin: :class:`~shinro_ctrl.engine.core.MujocoEngine` provides
    ``model``, ``data`` and the name tables this class reads.
    """

    model: mujoco.MjModel
    data: mujoco.MjData

    def get_joint_qpos(self, name: str) -> float | np.ndarray:
        """Position of a joint: a float for hinge [rad] / slide [m] joints.

        Ball and free joints return a copy of their ``qpos`` block, shape
        ``(4,)`` / ``(7,)`` (quaternions are ``w, x, y, z``).
        """
        try:
            return self._qpos.item(self._qadr[name])
        except (KeyError, TypeError):
            j = self._joint_id(name)
            a = int(self.model.jnt_qposadr[j])
            return self._qpos[a : a + _NQ[int(self.model.jnt_type[j])]].copy()

    def get_joint_vel(self, name: str) -> float | np.ndarray:
        """Velocity of a joint: a float for hinge [rad/s] / slide [m/s] joints.

        Ball and free joints return a copy of their ``qvel`` block, ``(3,)`` /
        ``(6,)`` (free: world linear velocity, then body angular velocity).
        """
        try:
            return self._qvel.item(self._vadr[name])
        except (KeyError, TypeError):
            j = self._joint_id(name)
            a = int(self.model.jnt_dofadr[j])
            return self._qvel[a : a + _NV[int(self.model.jnt_type[j])]].copy()

    def set_joint_qpos(self, name: str, value: ArrayLike) -> None:
        """Set a joint position (a float, or the ``qpos`` block of a ball/free joint).

        Derived quantities are not recomputed: call :meth:`forward` (pose and
        Jacobian queries refresh the kinematics themselves).

        Raises:
            KeyError: unknown joint (the message lists the joints).
            InvalidArgument: ``value`` is not a real number (or, for a ball or
                free joint, a block of the right shape).
            NonFiniteError: ``value`` holds NaN or inf.
        """
        try:
            adr = self._qadr[name]
        except (KeyError, TypeError):
            self._set_block(name, value, self._qpos, self.model.jnt_qposadr, _NQ, "qpos")
        else:
            v = _real(value, f"joint '{name}' position")
            if not math.isfinite(v):
                raise NonFiniteError(f"joint '{name}' position must be finite, got {v}")
            self._qpos[adr] = v
        self._kin_stale = True

    def set_joint_vel(self, name: str, value: ArrayLike) -> None:
        """Set a joint velocity (a float, or the ``qvel`` block of a ball/free joint).

        Raises:
            KeyError: unknown joint (the message lists the joints).
            InvalidArgument: ``value`` is not a real number (or, for a ball or
                free joint, a block of the right shape).
            NonFiniteError: ``value`` holds NaN or inf.
        """
        try:
            adr = self._vadr[name]
        except (KeyError, TypeError):
            self._set_block(name, value, self._qvel, self.model.jnt_dofadr, _NV, "qvel")
            return
        v = _real(value, f"joint '{name}' velocity")
        if not math.isfinite(v):
            raise NonFiniteError(f"joint '{name}' velocity must be finite, got {v}")
        self._qvel[adr] = v

    def set_joint_ctrl(self, actuator_name: str, value: float) -> None:
        """Set one actuator's control (a motor's force [N] or torque [N m] times its gear).

        ``actuator_name`` is an actuator name; the name of a joint driven by
        exactly one actuator is accepted too. No ``ctrlrange`` clamp applies
        unless the model declares one.

        Raises:
            KeyError: unknown actuator (the message lists the actuators).
            InvalidArgument: ``value`` is not one real number (a list, a
                string, ...).
            NonFiniteError: ``value`` is NaN or inf (``data.ctrl`` is left unchanged).
        """
        try:
            i = self._act[actuator_name]
        except (KeyError, TypeError):
            raise _unknown("actuator", actuator_name, self._act) from None
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InvalidArgument(
                f"control of actuator '{actuator_name}' must be one real number, got {value!r}"
            ) from None
        if not math.isfinite(v):
            raise NonFiniteError(f"control of actuator '{actuator_name}' must be finite, got {v}")
        self._ctrl[i] = v

    def set_body_force(self, name: str, force: ArrayLike) -> None:
        """Apply a world-frame force ``(3,)`` [N] at a body's centre of mass (``xfrc_applied``) until changed.

        Raises:
            UnknownName: no such body (the valid names are listed).
            NonFiniteError: NaN or inf in ``force``.
        """
        b = self._id(self._body, "body", name)
        f = np.asarray(force, dtype=float).reshape(3)
        if not np.all(np.isfinite(f)):
            raise NonFiniteError(f"force on body '{name}' must be finite, got {f}")
        self.data.xfrc_applied[b, :3] = f

    def clear_body_forces(self) -> None:
        """Remove every applied body force and torque (``xfrc_applied = 0``)."""
        self.data.xfrc_applied[:] = 0.0

    def set_ctrl(self, u: ArrayLike) -> None:
        """Set every actuator's control at once, ``u`` of shape ``(nu,)`` in actuator order.

        Raises:
            ValueError: wrong shape.
            NonFiniteError: NaN or inf (``data.ctrl`` is left unchanged).
        """
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape != self._ctrl.shape:
            raise InvalidArgument(f"ctrl: expected shape {self._ctrl.shape} but found {u.shape}")
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"ctrl must be finite, got {np.array2string(u, precision=4)}")
        self._ctrl[:] = u

    def get_joint_limits(self, name: str) -> tuple[float, float]:
        """``(lo, hi)`` range of a joint [rad or m]; ``(-inf, inf)`` when unlimited."""
        j = self._joint_id(name)
        if not self.model.jnt_limited[j]:
            return -math.inf, math.inf
        lo, hi = self.model.jnt_range[j]
        return float(lo), float(hi)

    def get_state_vector(self) -> np.ndarray:
        """``z = [qpos, qvel]``, shape ``(nq + nv,)``: MuJoCo's state order (as in
        ``mjd_transitionFD`` when ``nq == nv``)."""
        return np.concatenate([self._qpos, self._qvel])

    def set_state_vector(self, z: ArrayLike) -> None:
        """Set ``qpos`` and ``qvel`` from ``z = [qpos, qvel]`` ``(nq + nv,)`` and run :meth:`forward`.

        Raises:
            ValueError: wrong shape.
            NonFiniteError: NaN or inf.
        """
        nq, nv = self.model.nq, self.model.nv
        z = np.asarray(z, dtype=float).reshape(-1)
        if z.shape != (nq + nv,):
            raise InvalidArgument(f"state vector: expected shape ({nq + nv},) but found {z.shape}")
        if not np.all(np.isfinite(z)):
            raise NonFiniteError(f"state vector must be finite, got {np.array2string(z, precision=4)}")
        self._qpos[:] = z[:nq]
        self._qvel[:] = z[nq:]
        self.forward()

    # ---------------------------------------------------------- bodies, sites
    def get_body_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a body frame.

        Returns:
            ``(pos (3,) [m], euler (3,) [rad])`` with ZYX Euler angles
            ``[roll, pitch, yaw]`` (``R = Rz(yaw) Ry(pitch) Rx(roll)``) from
            the body quaternion.
        """
        b = self._id(self._body, "body", name)
        self._ensure_kinematics()
        return self.data.xpos[b].copy(), _euler_zyx_from_quat(self.data.xquat[b])

    def get_body_jacobian(self, name: str) -> np.ndarray:
        """Jacobian ``(6, nv)`` of a body frame's origin, world frame, position rows first.

        The angular rows map ``qvel`` to the world angular velocity.
        """
        b = self._id(self._body, "body", name)
        self._ensure_kinematics()
        jac = np.zeros((6, self.model.nv))
        mujoco.mj_jacBody(self.model, self.data, jac[:3], jac[3:], b)
        return jac

    def get_site_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a site: ``(pos (3,) [m], euler (3,) [rad])``, ZYX ``[roll, pitch, yaw]``."""
        s = self._id(self._site, "site", name)
        self._ensure_kinematics()
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, self.data.site_xmat[s])
        return self.data.site_xpos[s].copy(), _euler_zyx_from_quat(quat)

    def get_site_jacobian(self, name: str) -> np.ndarray:
        """Jacobian ``(6, nv)`` of a site, world frame, position rows first."""
        s = self._id(self._site, "site", name)
        self._ensure_kinematics()
        jac = np.zeros((6, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jac[:3], jac[3:], s)
        return jac

    def _ensure_kinematics(self) -> None:
        # After a state write or mj_step, xpos/xquat describe the previous state.
        if self._kin_stale:
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_comPos(self.model, self.data)
            self._kin_stale = False

    # ------------------------------------------------------------- free base
    def get_free_joint(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Copies of a free joint's ``(qpos (7,), qvel (6,))``.

        ``qpos`` is the world position [m] and the ``(w, x, y, z)`` orientation
        quaternion; ``qvel`` the world linear velocity [m/s] and the body-frame
        angular velocity [rad/s].

        Raises:
            KeyError: unknown joint.
            ValueError: the joint is not a free joint.
        """
        j = self._free_joint_id(name)
        a, v = int(self.model.jnt_qposadr[j]), int(self.model.jnt_dofadr[j])
        return self._qpos[a : a + 7].copy(), self._qvel[v : v + 6].copy()

    def set_free_joint(self, name: str, qpos: ArrayLike, qvel: ArrayLike) -> None:
        """Set a free joint's ``qpos (7,)`` and ``qvel (6,)`` (see :meth:`get_free_joint`).

        Raises:
            KeyError: unknown joint.
            ValueError: not a free joint, or wrong shapes.
            NonFiniteError: NaN or inf.
        """
        self._free_joint_id(name)
        self._set_block(name, qpos, self._qpos, self.model.jnt_qposadr, _NQ, "qpos")
        self._set_block(name, qvel, self._qvel, self.model.jnt_dofadr, _NV, "qvel")
        self._kin_stale = True

    def _free_joint_id(self, name: str) -> int:
        j = self._joint_id(name)
        jtype = int(self.model.jnt_type[j])
        if jtype != _FREE:
            raise InvalidArgument(f"joint '{name}' is a {_JOINT_TYPES[jtype]} joint, not a free joint")
        return j

    def pin_free_base(self, x: float, y: float, z: float | None = None, yaw: float = 0.0) -> None:
        """Place the first free joint's body at ``(x, y[, z])`` [m], upright, heading ``yaw`` [rad].

        The orientation becomes the pure yaw rotation, the free joint's
        velocity is zeroed; ``z`` is kept when None. Derived quantities are
        refreshed by the next :meth:`step` or :meth:`forward`.

        Raises:
            ValueError: the model has no free joint.
            NonFiniteError: a non-finite coordinate.
        """
        if self._free is None:
            raise InvalidArgument(f"model {self.source!r} has no free joint to pin")
        vals = [x, y, yaw] if z is None else [x, y, z, yaw]
        if not all(math.isfinite(float(v)) for v in vals):
            raise NonFiniteError(f"pin_free_base arguments must be finite, got {vals}")
        a = int(self.model.jnt_qposadr[self._free])
        dof = int(self.model.jnt_dofadr[self._free])
        q = self._qpos
        q[a], q[a + 1] = float(x), float(y)
        if z is not None:
            q[a + 2] = float(z)
        half = 0.5 * float(yaw)
        q[a + 3 : a + 7] = (math.cos(half), 0.0, 0.0, math.sin(half))
        self._qvel[dof : dof + 6] = 0.0
        self._kin_stale = True

    # ----------------------------------------------------------- derivatives
    def transition_jacobians(self, eps: float = 1e-6, *, centered: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Discrete transition Jacobians of one ``mj_step`` at the current state and control.

        ``δz⁺ = A δz + B δu`` with ``z = [qpos (tangent, nv), qvel (nv), act (na)]``
        in MuJoCo's order, by ``mjd_transitionFD``. The step is one
        ``opt.timestep`` (not :attr:`dt` when ``substeps > 1``).

        Args:
            eps: Finite-difference step.
            centered: Central (True) or forward differences.

        Returns:
            ``(A (2nv+na, 2nv+na), B (2nv+na, nu))``.
        """
        m = self.model
        n = 2 * m.nv + m.na
        A = np.zeros((n, n))
        B = np.zeros((n, m.nu))
        mujoco.mjd_transitionFD(m, self.data, float(eps), bool(centered), A, B, None, None)
        return A, B

    @property
    def integrator(self) -> str:
        """The integrator's name, e.g. ``"mjINT_EULER"``."""
        return mujoco.mjtIntegrator(int(self.model.opt.integrator)).name

    @property
    def explicit_damping(self) -> bool:
        """Whether ``mjDSBL_EULERDAMP`` is set (Euler treats damping explicitly)."""
        return bool(self.model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP))

    # ---------------------------------------------------------------- helpers
    def _joint_id(self, name: str) -> int:
        return self._id(self._joint, "joint", name)

    @staticmethod
    def _id(table: dict[str, int], kind: str, name: str) -> int:
        try:
            return table[name]
        except (KeyError, TypeError):
            raise _unknown(kind, name, table) from None

    def _set_block(
        self, name: str, value: Any, arr: np.ndarray, adr: np.ndarray, sizes: dict[int, int], what: str
    ) -> None:
        j = self._joint_id(name)
        jtype = int(self.model.jnt_type[j])
        k = sizes[jtype]
        try:
            v = np.asarray(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise InvalidArgument(
                f"{_JOINT_TYPES[jtype]} joint '{name}' {what}: expected {k} real numbers, got {value!r}"
            ) from None
        if v.shape != (k,):
            raise InvalidArgument(
                f"{_JOINT_TYPES[jtype]} joint '{name}' {what}: expected shape ({k},) but found {v.shape}"
            )
        if not np.all(np.isfinite(v)):
            raise NonFiniteError(f"joint '{name}' {what} must be finite, got {np.array2string(v, precision=4)}")
        a = int(adr[j])
        arr[a : a + k] = v
