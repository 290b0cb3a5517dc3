"""Quadrotor: a rigid body with collective thrust along body z and three body torques."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from shinro_ctrl.backend import ArrayBackend, CasadiBackend, ScalarBackend
from shinro_ctrl.errors import InvalidArgument, NonFiniteError
from shinro_ctrl.plants.base import MjcfPatch, Plant
from shinro_ctrl.validation import as_vector, check_nonnegative, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["GIMBAL_COS_MIN", "ROTOR_LAYOUTS", "Quadrotor", "quat_to_zyx_euler", "zyx_euler_to_quat"]

_SCALAR = ScalarBackend()
_CASADI = CasadiBackend()

ROTOR_LAYOUTS = ("+", "x")

#: The model is refused where ``|cos(pitch)| <`` this (pitch within about 0.057° of ±90°): the Euler-rate
#: map ``W`` has ``1/cos(pitch)`` entries (> 1e3 there) and its Jacobian ``1/cos²`` entries (> 1e6), so the
#: dynamics, their linearization and the standalone step lose every meaningful digit at the singularity.
GIMBAL_COS_MIN = 1e-3


def zyx_euler_to_quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    r"""Unit quaternion ``(w, x, y, z)`` of the ZYX Euler rotation ``Rz(yaw) Ry(pitch) Rx(roll)``.

    It is the product ``q_z(ψ) ⊗ q_y(θ) ⊗ q_x(φ)`` of the three elementary
    half-angle quaternions. The rotation maps body-frame vectors to the world
    frame, as MuJoCo's ``qpos[3:7]`` of a free joint does.

    Args:
        roll, pitch, yaw: Angles ``φ, θ, ψ`` [rad].

    Returns:
        ``(4,)`` quaternion, scalar first.
    """
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_to_zyx_euler(quat: ArrayLike) -> np.ndarray:
    r"""ZYX Euler angles ``[roll, pitch, yaw]`` of a quaternion ``(w, x, y, z)``.

    The inverse of :func:`zyx_euler_to_quat` on ``roll, yaw ∈ (−π, π]`` and
    ``pitch ∈ [−π/2, π/2]``. The quaternion is normalized first, so ``q`` and
    ``−q`` (the same rotation) give the same angles. At ``|pitch| = π/2``
    (gimbal lock) only ``yaw ∓ roll`` is defined.

    Args:
        quat: ``(4,)`` quaternion, scalar first, any non-zero norm.

    Returns:
        ``(3,)`` angles [rad].
    """
    w, x, y, z = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(min(1.0, max(-1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


class Quadrotor(Plant):
    r"""Quadrotor as a rigid body: collective thrust on body z, torques about the body axes.

    State ``[x, y, z, roll, pitch, yaw, vx, vy, vz, p, q, r]``: world position
    [m], ZYX Euler angles ``φ, θ, ψ`` [rad] (``R = Rz(ψ) Ry(θ) Rx(φ)`` maps
    body to world), world-frame linear velocity [m/s], body-frame angular
    velocity ``ω = [p, q, r]`` [rad/s]. Input ``[T, τx, τy, τz]``: thrust along
    the body z axis [N] and body torques [N m]. With mass ``m``, diagonal
    inertia ``I = diag(Ixx, Iyy, Izz)`` about the centre of mass and gravity
    ``g`` along world −z:

    .. math::

        \dot{\mathbf p} = \mathbf v, \qquad
        \begin{bmatrix}\dot\phi \\ \dot\theta \\ \dot\psi\end{bmatrix} = W(\phi, \theta)\,\omega =
        \begin{bmatrix} 1 & \sin\phi\tan\theta & \cos\phi\tan\theta \\
                        0 & \cos\phi & -\sin\phi \\
                        0 & \sin\phi/\cos\theta & \cos\phi/\cos\theta \end{bmatrix} \omega,

        \dot{\mathbf v} = \frac{T}{m} R(\phi, \theta, \psi)\, e_z - g\, e_z, \qquad
        \dot\omega = I^{-1}\left(\tau - \omega \times I \omega\right).

    The Euler-rate map is singular at ``|pitch| = π/2`` (gimbal lock): :meth:`dynamics`,
    :meth:`linearize` (and every model built on it) and the standalone :meth:`step` raise
    :class:`~shinro_ctrl.errors.NonFiniteError` where ``|cos(pitch)| <``
    :data:`GIMBAL_COS_MIN` (1e-3, within about 0.057° of ±90°); the model is meant for
    flight well inside that. Hover (zero state, ``u0 = [m g, 0, 0, 0]``) is the
    default operating point. The standalone step is semi-implicit Euler
    (velocities first, then positions and angles from the new velocities),
    the scheme MuJoCo's Euler integrator uses.

    Engine mode uses ``assets/quadrotor.xml``: a free joint ``root`` on the
    body ``quadrotor`` (``qpos = [position, quaternion (w, x, y, z)]``,
    ``qvel = [world linear velocity, body angular velocity]``) and four motors
    on the centre-of-mass site whose controls are exactly ``[T, τx, τy, τz]``.
    Euler angles read back from the engine lie in ``(−π, π]`` (yaw wraps);
    the standalone state does not wrap.

    An optional rotor mixer (:meth:`mixer_matrix`) converts four rotor thrusts
    of a ``'+'`` or ``'x'`` frame into this input and back.

    Args:
        mass: Total mass ``m`` [kg], > 0.
        inertia: Principal moments ``(Ixx, Iyy, Izz)`` [kg m²] about the body
            axes through the centre of mass: positive and satisfying the
            triangle inequality of a physical rigid body.
        arm_length: Distance from the centre to each rotor [m], > 0 (mixer
            and MuJoCo visuals only; the dynamics do not depend on it).
        gravity: Gravitational acceleration ``g`` [m/s²], >= 0.
        dt: Step [s], > 0.
        rotor_layout: ``'x'`` (rotors at ±45°, ±135° from body x) or ``'+'``
            (rotors on the body axes).
        yaw_moment_coefficient: Rotor drag torque per unit thrust ``k`` [m],
            >= 0 (mixer only).
        backend: Array backend kept for API compatibility (numpy).

    Raises:
        ValueError: a non-positive or malformed argument (named in the message).
    """

    aliases = ("quadrotor",)
    state_names = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "p", "q", "r")
    input_names = ("thrust", "tau_x", "tau_y", "tau_z")
    param_names = ("mass", "Ixx", "Iyy", "Izz", "gravity")
    asset = "quadrotor.xml"
    #: The states a simulation's error metrics use by default (the pose).
    tracked_states = ("x", "y", "z", "roll", "pitch", "yaw")
    #: Names in the MJCF asset.
    free_joint = "root"
    body = "quadrotor"
    actuators = ("thrust", "tau_x", "tau_y", "tau_z")

    def __init__(
        self,
        mass: float = 0.5,
        inertia: ArrayLike = (3.0e-3, 3.0e-3, 5.0e-3),
        arm_length: float = 0.17,
        gravity: float = 9.81,
        dt: float = 0.01,
        rotor_layout: str = "x",
        yaw_moment_coefficient: float = 0.016,
        backend: ArrayBackend | None = None,
    ):
        self.m = check_positive("mass", mass)
        self.inertia = _inertia(inertia)
        self.arm_length = check_positive("arm_length", arm_length)
        self.g = check_nonnegative("gravity", gravity)
        if rotor_layout not in ROTOR_LAYOUTS:
            raise InvalidArgument(f"rotor_layout must be one of {', '.join(ROTOR_LAYOUTS)}; got {rotor_layout!r}")
        self.rotor_layout = rotor_layout
        self.yaw_moment_coefficient = check_nonnegative("yaw_moment_coefficient", yaw_moment_coefficient)
        Ixx, Iyy, Izz = self.inertia
        self._init(
            dt=dt,
            params={"mass": self.m, "Ixx": Ixx, "Iyy": Iyy, "Izz": Izz, "gravity": self.g},
            backend=backend,
        )
        self._mixer = self._build_mixer()
        self._mixer_inv = np.linalg.inv(self._mixer) if self.yaw_moment_coefficient > 0.0 else None

    def params(self) -> dict[str, float | list[float]]:
        """The physical constructor arguments (a ``[plant]`` table can hold them as they are).

        ``mass``, ``inertia`` (a list ``[Ixx, Iyy, Izz]``), ``arm_length``,
        ``gravity`` and ``yaw_moment_coefficient``. The dynamics' own
        parameters, named as in :attr:`param_names` (``mass, Ixx, Iyy, Izz,
        gravity``: the order of ``symbolic(params=True)``'s ``p`` and the keys
        ``dynamics(params=...)`` accepts), are :meth:`dynamics_params`.
        """
        return {
            "mass": self.m,
            "inertia": list(self.inertia),
            "arm_length": self.arm_length,
            "gravity": self.g,
            "yaw_moment_coefficient": self.yaw_moment_coefficient,
        }

    def dynamics_params(self) -> dict[str, float]:
        """The dynamics' parameters by :attr:`param_names` (a copy)."""
        return dict(self._params)

    # ------------------------------------------------------------ dynamics
    def equations(self, bk, x, u, p):
        _, _, _, phi, theta, psi, vx, vy, vz, wx, wy, wz = bk.unpack(x, 12)
        thrust, tau_x, tau_y, tau_z = bk.unpack(u, 4)
        m, Ixx, Iyy, Izz, g = (p[k] for k in self.param_names)
        sphi, cphi = bk.sin(phi), bk.cos(phi)
        sth, cth = bk.sin(theta), bk.cos(theta)
        spsi, cpsi = bk.sin(psi), bk.cos(psi)
        # Euler-rate kinematics [phi_dot, theta_dot, psi_dot] = W(phi, theta) omega.
        s_q_c_r = sphi * wy + cphi * wz
        phi_dot = wx + s_q_c_r * bk.tan(theta)
        theta_dot = cphi * wy - sphi * wz
        psi_dot = s_q_c_r / cth
        # Translational: thrust along the third column of R, gravity along -z.
        a = thrust / m
        ax = a * (cpsi * sth * cphi + spsi * sphi)
        ay = a * (spsi * sth * cphi - cpsi * sphi)
        az = a * (cth * cphi) - g
        # Euler's equation with diagonal inertia: I w_dot = tau - w x (I w).
        wx_dot = (tau_x + (Iyy - Izz) * wy * wz) / Ixx
        wy_dot = (tau_y + (Izz - Ixx) * wz * wx) / Iyy
        wz_dot = (tau_z + (Ixx - Iyy) * wx * wy) / Izz
        return bk.stack([vx, vy, vz, phi_dot, theta_dot, psi_dot, ax, ay, az, wx_dot, wy_dot, wz_dot])

    def check_model_domain(self, x: np.ndarray) -> None:
        """Refuse a state at the Euler-angle singularity: ``|cos(pitch)| <`` :data:`GIMBAL_COS_MIN`.

        Raises:
            NonFiniteError: naming the pitch and the limit.
        """
        pitch = float(x[4])
        if abs(math.cos(pitch)) < GIMBAL_COS_MIN:
            raise NonFiniteError(
                f"Quadrotor: pitch = {pitch:.9g} rad is at the Euler-angle singularity (gimbal lock, "
                f"|cos(pitch)| = {abs(math.cos(pitch)):.3g} < {GIMBAL_COS_MIN:g}): the ZYX Euler-rate map is "
                "undefined there; keep |pitch| below pi/2 - 1e-3 or use MuJoCo (quaternions) for such attitudes"
            )

    def symbolic_step(self) -> cs.Function:
        """The two-stage semi-implicit Euler step of :meth:`integrate` as CasADi ``F(x, u, p)``."""
        x = cs.SX.sym("x", 12)
        u = cs.SX.sym("u", 4)
        p = cs.SX.sym("p", len(self.param_names))
        pmap = {k: p[i] for i, k in enumerate(self.param_names)}
        f1 = self.equations(_CASADI, x, u, pmap)
        new = cs.vertcat(x[:6], x[6:] + self.dt * f1[6:])
        f2 = self.equations(_CASADI, new, u, pmap)
        new = cs.vertcat(x[:6] + self.dt * f2[:6], new[6:])
        return cs.Function("F", [x, u, p], [new], ["x", "u", "p"], ["x_next"])

    def integrate(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Semi-implicit Euler: velocities first; then position and angles with the new velocities.

        ``v⁺ = v + dt v̇(x, u)``, ``ω⁺ = ω + dt ω̇(x, u)``, ``p⁺ = p + dt v⁺``,
        ``η⁺ = η + dt W(φ, θ) ω⁺`` (``η`` the Euler angles, ``W`` at the old
        angles). Both stages evaluate the one :meth:`equations`.
        """
        dt = self.dt
        new = x.copy()
        new[6:] += dt * self.equations(_SCALAR, x, u, self._params)[6:]
        new[:6] += dt * self.equations(_SCALAR, new, u, self._params)[:6]
        return new

    def body_force_map(self, body: str) -> np.ndarray:
        """``G (12, 3)``: a world force on the body ``"quadrotor"`` accelerates the world velocity by ``F / m``."""
        if body != "quadrotor":
            raise InvalidArgument(f"Quadrotor: a body force acts on body 'quadrotor', got '{body}'")
        G = np.zeros((self.state_dim, 3))
        G[6:9] = np.eye(3) / self.m
        return G

    def hover_input(self) -> np.ndarray:
        """The input that holds any hover pose: ``[m g, 0, 0, 0]`` ``(4,)``."""
        return np.array([self.m * self.g, 0.0, 0.0, 0.0])

    def equilibrium(self) -> tuple[np.ndarray, np.ndarray]:
        """Hover at the origin: ``(zeros (12,), [m g, 0, 0, 0])``."""
        return np.zeros(self.state_dim), self.hover_input()

    # --------------------------------------------------------------- mixer
    def rotor_positions(self) -> np.ndarray:
        """Rotor centres in the body frame ``(4, 3)`` [m].

        Rotor ``i`` sits at angle ``a_i = a_0 + i π/2`` from body x, at
        ``arm_length``; ``a_0 = 0`` for ``'+'`` and ``π/4`` for ``'x'``.
        """
        a0 = 0.0 if self.rotor_layout == "+" else 0.25 * math.pi
        a = a0 + 0.5 * math.pi * np.arange(4)
        L = self.arm_length
        return np.column_stack([L * np.cos(a), L * np.sin(a), np.zeros(4)])

    def _build_mixer(self) -> np.ndarray:
        pos = self.rotor_positions()
        spin = np.array([1.0, -1.0, 1.0, -1.0])
        # A thrust f at body point (x, y, 0) gives the torque (y f, -x f, 0).
        return np.vstack([np.ones(4), pos[:, 1], -pos[:, 0], self.yaw_moment_coefficient * spin])

    def mixer_matrix(self) -> np.ndarray:
        r"""The matrix ``M`` ``(4, 4)`` with ``[T, τx, τy, τz] = M f`` for rotor thrusts ``f`` [N].

        Column ``i`` is ``[1, y_i, −x_i, k s_i]`` for rotor ``i`` at body
        position ``(x_i, y_i, 0)`` (see :meth:`rotor_positions`); ``s_i = +1``
        for rotors 0 and 2 (their drag torque yaws the body toward +z) and
        ``−1`` for rotors 1 and 3; ``k`` is ``yaw_moment_coefficient``.
        Invertible whenever ``k > 0``.
        """
        return self._mixer.copy()

    def rotor_thrusts_to_input(self, f: ArrayLike) -> np.ndarray:
        """Plant input ``[T, τx, τy, τz]`` ``(4,)`` from rotor thrusts ``f`` ``(4,)`` [N]."""
        return self._mixer @ as_vector("rotor thrusts f", f, 4)

    def input_to_rotor_thrusts(self, u: ArrayLike) -> np.ndarray:
        """Rotor thrusts ``f`` ``(4,)`` [N] that produce the input ``u`` ``(4,)`` (inverse mixer).

        Raises:
            ValueError: the mixer is singular (``yaw_moment_coefficient == 0``).
        """
        if self._mixer_inv is None:
            raise InvalidArgument("the rotor mixer is singular: yaw_moment_coefficient must be > 0 to invert it")
        return self._mixer_inv @ as_vector("Quadrotor input u", u, 4)

    # -------------------------------------------------------------- engine
    def mjcf_patch(self) -> MjcfPatch:
        """Mass, inertia, gravity, step and rotor visuals of ``assets/quadrotor.xml``."""
        fromto = {}
        for i, (x, y, _) in enumerate(self.rotor_positions()):
            fromto[f"arm_{i}"] = (0.0, 0.0, 0.0, float(x), float(y), 0.0)
            fromto[f"rotor_{i}"] = (float(x), float(y), 0.005, float(x), float(y), 0.015)
        return MjcfPatch(
            asset=self.asset,
            timestep=self.dt,
            gravity=(0.0, 0.0, -self.g),
            inertials={self.body: (self.m, (0.0, 0.0, 0.0))},
            body_inertia={self.body: tuple(self.inertia)},
            geom_fromto=fromto,
        )

    def engine_state_map(self, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``δx = T @ δz`` at ``x0``, with MuJoCo's tangent ``z = [pos, rotation tangent, v, ω]``.

        ``mjd_transitionFD`` differentiates the free joint's orientation in
        its local tangent (a body-frame rotation vector ``δr``) and its
        velocity as ``[world linear, body angular]``, as the plant's state
        does. The Euler angles relate as ``δη = W(φ, θ) δr`` (the same map as
        the Euler rates from body rates), so ``T = diag(I, W, I, I)``; at any
        level attitude (hover, any yaw) ``W = I``. Default ``x0``: hover.
        """
        T = np.eye(12)
        if x0 is not None:
            self.check_model_domain(np.asarray(x0, dtype=float))
            roll, pitch = float(x0[3]), float(x0[4])
            sr, cr, tp, cp = math.sin(roll), math.cos(roll), math.tan(pitch), math.cos(pitch)
            T[3:6, 3:6] = [[1.0, sr * tp, cr * tp], [0.0, cr, -sr], [0.0, sr / cp, cr / cp]]
        return T, np.arange(12)

    def engine_read(self, engine) -> np.ndarray:
        qpos = engine.get_joint_qpos(self.free_joint)
        qvel = engine.get_joint_vel(self.free_joint)
        x = np.empty(12)
        x[0:3] = qpos[0:3]
        x[3:6] = quat_to_zyx_euler(qpos[3:7])
        x[6:12] = qvel  # [world linear velocity, body angular velocity]
        return x

    def engine_write(self, engine, x: np.ndarray) -> None:
        engine.set_joint_qpos(self.free_joint, np.concatenate([x[0:3], zyx_euler_to_quat(x[3], x[4], x[5])]))
        engine.set_joint_vel(self.free_joint, x[6:12])
        engine.forward()

    def engine_apply(self, engine, u: np.ndarray) -> None:
        for name, value in zip(self.actuators, u.tolist(), strict=True):
            engine.set_joint_ctrl(name, value)


def _inertia(value: ArrayLike) -> tuple[float, float, float]:
    """Validate ``inertia`` as three positive principal moments of a physical body."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidArgument(f"inertia must be three numbers (Ixx, Iyy, Izz), got {value!r}") from None
    if arr.shape != (3,):
        raise InvalidArgument(f"inertia: expected shape (3,) (Ixx, Iyy, Izz) but found {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        raise InvalidArgument(f"inertia must hold three positive finite values, got {arr.tolist()}")
    Ixx, Iyy, Izz = (float(v) for v in arr)
    tol = 1e-12 * (Ixx + Iyy + Izz)
    if Ixx + Iyy < Izz - tol or Iyy + Izz < Ixx - tol or Izz + Ixx < Iyy - tol:
        raise InvalidArgument(
            f"inertia {arr.tolist()} violates the triangle inequality (each moment must be <= the sum "
            "of the other two for a physical rigid body)"
        )
    return Ixx, Iyy, Izz
