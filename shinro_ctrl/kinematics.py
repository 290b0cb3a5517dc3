r"""Rotation helpers on SO(3) and SE(3) shared by the arm plant and the IK solvers.

Conventions:

* Rotation matrices ``R`` are ``(3, 3)`` and map body coordinates to world
  coordinates; homogeneous transforms ``T`` are ``(4, 4)`` with ``T[:3, :3] = R``
  and ``T[:3, 3] = p`` [m].
* ZYX Euler angles ``[roll, pitch, yaw]`` [rad] compose as
  :math:`R = R_z(\psi) R_y(\theta) R_x(\phi)` (yaw about world z last). The
  inverse map returns ``roll, yaw`` in :math:`(-\pi, \pi]` and ``pitch`` in
  :math:`[-\pi/2, \pi/2]`; at the gimbal lock (``|pitch| = π/2``) only
  ``roll ∓ yaw`` is defined and ``roll`` is set to zero.
* A pose vector is ``[x, y, z, roll, pitch, yaw]`` (6,).
* The orientation error between a target ``R_t`` and a current ``R`` is the
  *world-frame* rotation vector :math:`\log(R_t R^\top)^\vee`, which is what
  the world-frame angular rows of a geometric Jacobian act on.

The scalar functions work on Python floats (faster than numpy for 3 × 3
objects in a Python loop); the array helpers accept anything ``numpy`` can
read and return fresh ``float64`` arrays.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument

__all__ = [
    "IKResult",
    "euler_zyx_from_matrix",
    "euler_zyx_to_matrix",
    "pose_from_transform",
    "pose_to_transform",
    "rotation_about",
    "skew",
    "so3_exp",
    "so3_log",
    "so3_log_flat",
    "vee",
    "wrap_angle",
]

#: Below this rotation angle [rad] the log map uses its Taylor expansion.
_SMALL = 1e-6
#: Within this distance of π [rad] the log map reads the axis from R + Rᵀ.
_NEAR_PI = 1e-3


@dataclass(frozen=True)
class IKResult:
    """Outcome of an inverse-kinematics solve.

    Attributes:
        q: Joint angles ``(n,)`` [rad], always inside the joint limits: the solution, or the
            closest configuration found when not converged.
        converged: Whether both errors fell below the tolerance.
        iterations: Iterations (QP or least-squares solves) over all attempts.
        pos_err: Position error ``|p_t − p(q)|`` [m].
        ori_err: Orientation error ``|log(R_t R(q)ᵀ)|`` [rad].
        jacobian: Task Jacobian at ``q`` (``(6, n)`` pose, ``(3, n)`` position task).
        attempts: Starts tried (1 + the restarts used).
        cond: 2-norm condition number of ``jacobian`` (computed on first access: an SVD
            costs more than a whole IK iteration).
    """

    q: np.ndarray
    converged: bool
    iterations: int
    pos_err: float
    ori_err: float
    jacobian: np.ndarray
    attempts: int = 1

    @functools.cached_property
    def cond(self) -> float:
        """2-norm condition number of the task Jacobian at ``q``."""
        return float(np.linalg.cond(self.jacobian))


def wrap_angle(a: Any) -> Any:
    """Wrap angles [rad] into ``(-π, π]`` (float or array)."""
    if isinstance(a, float | int):
        w = math.remainder(float(a), 2.0 * math.pi)
        return math.pi if w == -math.pi else w
    w = np.remainder(np.asarray(a, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


def skew(w: Any) -> np.ndarray:
    """The ``(3, 3)`` matrix ``[w]×`` with ``[w]× v = w × v`` for ``w (3,)``."""
    x, y, z = (float(c) for c in np.asarray(w, dtype=float).reshape(3))
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(S: Any) -> np.ndarray:
    """The vector ``w (3,)`` of the skew-symmetric part of ``S (3, 3)``: ``vee([w]×) = w``."""
    S = np.asarray(S, dtype=float)
    return 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])


def rotation_about(axis: str, angle: float) -> np.ndarray:
    """Rotation ``(3, 3)`` by ``angle`` [rad] about the principal ``axis`` ``"x" | "y" | "z"``."""
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == "y":
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    if axis == "z":
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    raise InvalidArgument(f"axis must be 'x', 'y' or 'z', got {axis!r}")


def euler_zyx_to_matrix(rpy: Any) -> np.ndarray:
    r"""Rotation ``(3, 3)`` of ZYX Euler angles ``[roll, pitch, yaw]`` [rad]: :math:`R_z R_y R_x`."""
    r, p, y = (float(c) for c in np.asarray(rpy, dtype=float).reshape(3))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def euler_zyx_from_matrix(R: Any) -> np.ndarray:
    """ZYX Euler angles ``[roll, pitch, yaw]`` (3,) [rad] of a rotation ``R (3, 3)``.

    ``pitch = atan2(-R20, hypot(R00, R10))`` stays accurate near ±π/2 (an
    ``asin`` would lose half the digits there); at the gimbal lock the roll
    is zero and the yaw carries the remaining angle.
    """
    R = np.asarray(R, dtype=float)
    r00, r10, r20, r21, r22 = R[0, 0], R[1, 0], R[2, 0], R[2, 1], R[2, 2]
    c = math.hypot(r00, r10)
    pitch = math.atan2(-r20, c)
    if c > 1e-12:
        return np.array([math.atan2(r21, r22), pitch, math.atan2(r10, r00)])
    # Gimbal lock: R = Rz(yaw) Ry(±π/2) Rx(roll) depends on yaw ∓ roll only.
    yaw = math.atan2(-R[0, 1], R[1, 1])
    return np.array([0.0, pitch, yaw])


def pose_to_transform(pose: Any) -> np.ndarray:
    """Homogeneous transform ``(4, 4)`` of a pose ``[x, y, z, roll, pitch, yaw]`` (6,) [m, rad]."""
    pose = np.asarray(pose, dtype=float).reshape(6)
    T = np.eye(4)
    T[:3, :3] = euler_zyx_to_matrix(pose[3:])
    T[:3, 3] = pose[:3]
    return T


def pose_from_transform(T: Any) -> np.ndarray:
    """Pose ``[x, y, z, roll, pitch, yaw]`` (6,) [m, rad] of a transform ``T (4, 4)``."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[:3, 3], euler_zyx_from_matrix(T[:3, :3])])


def so3_exp(w: Any) -> np.ndarray:
    """Rotation ``(3, 3)`` of a rotation vector ``w (3,)`` [rad] (Rodrigues' formula)."""
    w = np.asarray(w, dtype=float).reshape(3)
    theta = float(np.linalg.norm(w))
    K = skew(w)
    if theta < _SMALL:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (math.sin(theta) / theta) * K + ((1.0 - math.cos(theta)) / theta**2) * K @ K


def so3_log(R: Any) -> np.ndarray:
    r"""Rotation vector ``w (3,)`` [rad] with ``exp([w]×) = R``, ``|w| ≤ π``.

    Robust over the whole group: a Taylor expansion near the identity, the
    usual :math:`\theta / (2 \sin\theta)\, (R - R^\top)^\vee` in between, and
    near :math:`\theta = \pi` (where that quotient is 0/0) the axis from the
    symmetric part :math:`(R + R^\top)/2 = \cos\theta\, I + (1 - \cos\theta)\, n n^\top`,
    its sign fixed by the skew part.
    """
    R = np.asarray(R, dtype=float)
    return np.array(so3_log_flat(R.reshape(-1).tolist()))


def so3_log_flat(r: list[float]) -> tuple[float, float, float]:
    """:func:`so3_log` of a row-major list of 9 floats, returning a tuple (hot-path form)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    sx, sy, sz = r21 - r12, r02 - r20, r10 - r01  # 2 sin(θ) n
    cos_t = 0.5 * (r00 + r11 + r22 - 1.0)
    sin_t = 0.5 * math.sqrt(sx * sx + sy * sy + sz * sz)
    theta = math.atan2(sin_t, cos_t)  # accurate over [0, π], unlike acos
    if theta < _SMALL:
        k = 0.5 + theta * theta / 12.0  # θ / (2 sin θ) to second order
        return k * sx, k * sy, k * sz
    if math.pi - theta > _NEAR_PI:
        k = 0.5 * theta / sin_t
        return k * sx, k * sy, k * sz
    # Near π: n nᵀ = (S - cos θ I) / (1 - cos θ) with S the symmetric part.
    one_c = 1.0 - cos_t
    d = ((r00 - cos_t) / one_c, (r11 - cos_t) / one_c, (r22 - cos_t) / one_c)
    i = max(range(3), key=d.__getitem__)
    ni = math.sqrt(max(d[i], 0.0))
    off = ((r01 + r10) * 0.5 / one_c, (r02 + r20) * 0.5 / one_c, (r12 + r21) * 0.5 / one_c)
    if i == 0:
        n = (ni, off[0] / ni, off[1] / ni)
    elif i == 1:
        n = (off[0] / ni, ni, off[2] / ni)
    else:
        n = (off[1] / ni, off[2] / ni, ni)
    if n[0] * sx + n[1] * sy + n[2] * sz < 0.0:  # the skew part points along +sin θ n
        n = (-n[0], -n[1], -n[2])
    norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    return theta * n[0] / norm, theta * n[1] / norm, theta * n[2] / norm
