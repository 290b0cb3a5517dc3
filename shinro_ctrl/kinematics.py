r"""Rotations on SO(3)/SE(3) and serial-chain kinematics shared by the arm plant and the IK solvers.

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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeAlias

import casadi as cs
import numpy as np

from shinro_ctrl.backend import CasadiBackend, ScalarBackend
from shinro_ctrl.errors import InvalidArgument, NonFiniteError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

#: A scalar of the chain: a Python float (numeric FK) or a CasADi ``SX`` (symbolic FK).
ChainScalar: TypeAlias = "float | cs.SX"

__all__ = [
    "IKResult",
    "KinematicsBuffer",
    "SerialChain",
    "damped_least_squares",
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


def wrap_angle(a: float | ArrayLike) -> float | np.ndarray:
    """Wrap angles [rad] into ``(-π, π]`` (float or array)."""
    if isinstance(a, float | int):
        w = math.remainder(float(a), 2.0 * math.pi)
        return math.pi if w == -math.pi else w
    w = np.remainder(np.asarray(a, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


def skew(w: ArrayLike) -> np.ndarray:
    """The ``(3, 3)`` matrix ``[w]×`` with ``[w]× v = w × v`` for ``w (3,)``."""
    x, y, z = (float(c) for c in np.asarray(w, dtype=float).reshape(3))
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(S: ArrayLike) -> np.ndarray:
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


def euler_zyx_to_matrix(rpy: ArrayLike) -> np.ndarray:
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


def euler_zyx_from_matrix(R: ArrayLike) -> np.ndarray:
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


def pose_to_transform(pose: ArrayLike) -> np.ndarray:
    """Homogeneous transform ``(4, 4)`` of a pose ``[x, y, z, roll, pitch, yaw]`` (6,) [m, rad]."""
    pose = np.asarray(pose, dtype=float).reshape(6)
    T = np.eye(4)
    T[:3, :3] = euler_zyx_to_matrix(pose[3:])
    T[:3, 3] = pose[:3]
    return T


def pose_from_transform(T: ArrayLike) -> np.ndarray:
    """Pose ``[x, y, z, roll, pitch, yaw]`` (6,) [m, rad] of a transform ``T (4, 4)``."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[:3, 3], euler_zyx_from_matrix(T[:3, :3])])


def so3_exp(w: ArrayLike) -> np.ndarray:
    """Rotation ``(3, 3)`` of a rotation vector ``w (3,)`` [rad] (Rodrigues' formula)."""
    w = np.asarray(w, dtype=float).reshape(3)
    theta = float(np.linalg.norm(w))
    K = skew(w)
    if theta < _SMALL:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (math.sin(theta) / theta) * K + ((1.0 - math.cos(theta)) / theta**2) * K @ K


def so3_log(R: ArrayLike) -> np.ndarray:
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


# ------------------------------------------------------------------ serial chains
_AXES = ("x", "y", "z")
_SCALAR = ScalarBackend()
_CASADI = CasadiBackend()


class SerialChain:
    r"""Forward kinematics and Jacobians of a serial chain of revolute joints (numeric and CasADi).

    Joint ``i`` turns about one principal axis (``x``, ``y`` or ``z``) of its
    own frame, and that frame is its parent's frame translated by the link
    offset ``o_i`` and then rotated by ``q_i``:

    .. math::

        T_i = T_{i-1}\, \mathrm{Trans}(o_i)\, \mathrm{Rot}(a_i, q_i), \qquad
        T_{ee} = T_n\, \mathrm{Trans}(o_{ee}).

    Joint ``i`` sits at :math:`p_i = p_{i-1} + R_{i-1} o_i` and turns about
    the world axis :math:`z_i = R_i e_{a_i}`. The geometric Jacobian ``(6, n)``
    (world frame, position rows first) has columns
    :math:`[z_i \times (p_{ee} - p_i);\ z_i]`. The chain is written once
    (:meth:`chain`) against a scalar backend: on Python floats it is the
    numeric FK, on ``casadi.SX`` symbols the symbolic FK from which the exact
    Jacobian and the compiled evaluator (:meth:`evaluator`) are built. Used by
    :class:`~shinro_ctrl.plants.ArmRobot` and
    :class:`~shinro_ctrl.controllers.ik_qp.IKQP`.

    Args:
        offsets: Link offsets ``(n, 3)`` [m], each in the parent joint's frame.
        axes: ``n`` axis letters (``"x"``, ``"y"`` or ``"z"``).
        ee_offset: End-effector offset ``(3,)`` [m] in the last joint's frame.
    """

    def __init__(self, offsets: ArrayLike, axes: Sequence[str], ee_offset: ArrayLike = (0.0, 0.0, 0.0)):
        self.offsets = [tuple(float(v) for v in row) for row in np.asarray(offsets, dtype=float)]
        self.axes = tuple(axes)
        for i, a in enumerate(self.axes):
            if a not in _AXES:
                raise InvalidArgument(f"rot_axes[{i}] must be one of 'x', 'y', 'z', got {a!r}")
        if len(self.axes) != len(self.offsets):
            raise InvalidArgument(f"rot_axes: expected {len(self.offsets)} axes but found {len(self.axes)}")
        self.n = len(self.axes)
        self._axis_index = [_AXES.index(a) for a in self.axes]
        self.ee = tuple(float(v) for v in ee_offset)
        self._sym: tuple | None = None
        self._fk_fun: cs.Function | None = None
        self._exact_fun: cs.Function | None = None
        self._fast: KinematicsBuffer | None = None

    def chain(self, bk: ScalarBackend | CasadiBackend, q: Sequence[ChainScalar]) -> tuple[list, list, list, list]:
        """The kinematic chain against a scalar backend.

        Args:
            bk: ``ScalarBackend`` (Python floats) or ``CasadiBackend`` (SX scalars).
            q: ``n`` joint angles (floats or SX scalars).

        Returns:
            ``(p_ee, cols, positions, axes)``: end-effector position (3 scalars), the three
            columns of ``R_ee`` (each 3 scalars), and per joint its world position and
            world axis (lists of 3 scalars).
        """
        c = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]  # columns of R
        p = [0.0, 0.0, 0.0]
        positions, axes = [], []
        for i in range(self.n):
            p = _add_rotated(p, c, self.offsets[i])
            k = self._axis_index[i]
            a, b = (k + 1) % 3, (k + 2) % 3
            cq, sq = bk.cos(q[i]), bk.sin(q[i])
            ca, cb = c[a], c[b]
            c[a] = [cq * ca[r] + sq * cb[r] for r in range(3)]
            c[b] = [cq * cb[r] - sq * ca[r] for r in range(3)]
            positions.append(p)
            axes.append(c[k])
        return _add_rotated(p, c, self.ee), c, positions, axes

    @staticmethod
    def geometric_columns(p_ee: list, positions: list, axes: list) -> list[list]:
        """Columns ``[z_i × (p_ee − p_i); z_i]`` of the geometric Jacobian (lists of 6 scalars)."""
        cols = []
        for p, z in zip(positions, axes, strict=True):
            dx, dy, dz = p_ee[0] - p[0], p_ee[1] - p[1], p_ee[2] - p[2]
            cols.append([z[1] * dz - z[2] * dy, z[2] * dx - z[0] * dz, z[0] * dy - z[1] * dx, z[0], z[1], z[2]])
        return cols

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """``(T_ee (4, 4), joint positions [(3,)] [m], joint world axes [(3,)])`` at joints ``q (n,)``."""
        p, c, positions, axes = self.chain(_SCALAR, np.asarray(q, dtype=float).tolist())
        T = np.eye(4)
        T[:3, :3] = np.array(c).T
        T[:3, 3] = p
        return T, [np.array(v) for v in positions], [np.array(v) for v in axes]

    def symbolic(self) -> tuple:
        """``(q, p (3, 1), R (3, 3), J_geometric (6, n))`` as CasADi SX, built once."""
        if self._sym is None:
            qs = cs.SX.sym("q", self.n)
            p, c, positions, axes = self.chain(_CASADI, [qs[i] for i in range(self.n)])
            P = cs.vertcat(*p)
            R = cs.horzcat(*[cs.vertcat(*col) for col in c])
            J = cs.horzcat(*[cs.vertcat(*col) for col in self.geometric_columns(p, positions, axes)])
            self._sym = (qs, P, R, J)
        return self._sym

    def symbolic_fk(self) -> cs.Function:
        """The FK as a CasADi ``Function`` named ``"fk"``: ``q (n,) -> (p (3,), R (3, 3))``."""
        if self._fk_fun is None:
            qs, p, R, _ = self.symbolic()
            self._fk_fun = cs.Function("fk", [qs], [p, R], ["q"], ["p", "R"])
        return self._fk_fun

    def exact_jacobian(self, q: np.ndarray) -> np.ndarray:
        r"""CasADi derivative of the symbolic FK ``(6, n)``.

        Angular rows :math:`\mathrm{vee}(\partial R/\partial q_i\, R^\top)`.
        """
        if self._exact_fun is None:
            qs, p, R, _ = self.symbolic()
            Jp = cs.jacobian(p, qs)
            Rt = R.T
            cols = []
            for i in range(self.n):
                S = cs.reshape(cs.jacobian(cs.vec(R), qs[i]), 3, 3) @ Rt  # ∂R/∂q_i Rᵀ (skew)
                cols.append(cs.vertcat(S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]) / 2)
            self._exact_fun = cs.Function("jac_exact", [qs], [cs.densify(cs.vertcat(Jp, cs.horzcat(*cols)))])
        return np.array(self._exact_fun(q), dtype=float)

    def fd_jacobian(self, q: np.ndarray, eps: float) -> np.ndarray:
        """Central differences of the FK ``(6, n)`` with step ``eps`` [rad]; angular rows from the log map."""
        J = np.empty((6, self.n))
        for i in range(self.n):
            qp, qm = q.copy(), q.copy()
            qp[i] += eps
            qm[i] -= eps
            Tp, _, _ = self.fk(qp)
            Tm, _, _ = self.fk(qm)
            J[:3, i] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * eps)
            J[3:, i] = so3_log(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * eps)
        return J

    def evaluator(self) -> KinematicsBuffer:
        """The compiled evaluator of ``(p, R, J)`` at a joint vector (the IK hot path), built once."""
        if self._fast is None:
            self._fast = KinematicsBuffer(self)
        return self._fast


def _add_rotated(p: list, c: list, o: tuple[float, float, float]) -> list:
    """``p + R o`` for ``R`` given by columns ``c``, skipping zero offset components."""
    out = list(p)
    for j in range(3):
        if o[j] != 0.0:
            col = c[j]
            out = [out[r] + col[r] * o[j] for r in range(3)]
    return out


class KinematicsBuffer:
    """``q -> (p (3,), R (3, 3), J (6, n))`` through a CasADi buffer (about 1 µs).

    The compiled function is the symbolic form of :meth:`SerialChain.chain` and
    :meth:`SerialChain.geometric_columns`, so it equals the geometric Jacobian. Outputs are
    written into arrays this object owns (CasADi writes column-major nonzeros, so the
    function returns transposes, whose column-major layout is numpy's row-major one); the
    returned arrays are overwritten by the next call.
    """

    def __init__(self, chain: SerialChain):
        qs, p, R, J = chain.symbolic()
        n = chain.n
        f = cs.Function("fk_jac", [qs], [cs.densify(p), cs.densify(R.T), cs.densify(J.T)])
        self._q = np.zeros(n)
        self.p = np.zeros(3)
        self.R = np.zeros((3, 3))
        self.J = np.zeros((6, n))
        self._buf, self._eval = f.buffer()
        self._buf.set_arg(0, memoryview(self._q))
        self._buf.set_res(0, memoryview(self.p))
        self._buf.set_res(1, memoryview(self.R.reshape(-1)))
        self._buf.set_res(2, memoryview(self.J.reshape(-1)))

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self._q[:] = q
        self._eval()
        if not math.isfinite(self.p[0] + self.p[1] + self.p[2]):
            raise NonFiniteError(f"joint angles must be finite, got {np.array2string(q, precision=4)}")
        return self.p, self.R, self.J


def damped_least_squares(
    error_jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    q: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    max_iters: int,
    max_step: float,
    lam: float,
    converged: Callable[[np.ndarray], bool],
) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    r"""The damped-least-squares IK loop (one for the analytic and the engine kinematics).

    Each iteration evaluates ``(e, J) = error_jacobian(q)``, stops when
    ``converged(e)`` or after ``max_iters`` steps, else takes
    :math:`\Delta q = J^\top (J J^\top + \lambda^2 I)^{-1} e`, clamps every
    component to ``±max_step`` and clips ``q`` to ``[lo, hi]``.

    Args:
        error_jacobian: ``q (n,) -> (e (k,), J (k, n))``.
        q: Start ``(n,)`` [rad].
        lo: Lower joint limits ``(n,)``.
        hi: Upper joint limits ``(n,)``.
        max_iters: Largest number of steps.
        max_step: Largest joint change per step [rad].
        lam: Damping ``λ``.
        converged: ``e -> bool``.

    Returns:
        ``(q, steps, e, J)`` at the last evaluation.
    """
    it = 0
    lam2: np.ndarray | None = None
    while True:
        e, J = error_jacobian(q)
        if converged(e) or it >= max_iters:
            return q, it, e, J
        if lam2 is None:
            lam2 = float(lam) ** 2 * np.eye(J.shape[0])
        dq = J.T @ np.linalg.solve(J @ J.T + lam2, e)
        q = np.clip(q + np.clip(dq, -max_step, max_step), lo, hi)
        it += 1
