r"""Configurations with quaternions: rates, integration and differences on the manifold (MuJoCo's conventions).

A tree with ball or free joints has more coordinates ``qpos (nq,)`` than velocities
``qvel (nv,)``. The conventions are MuJoCo's (``mj_integratePos``, ``mj_differentiatePos``):

* hinge, slide: one coordinate, its rate;
* ball: a unit quaternion ``q = (w, x, y, z)`` (body relative to its parent), and the body-frame
  angular velocity ``ω`` (3 ``qvel``): ``q̇ = ½ q ⊗ (0, ω)``;
* free: the body's world position ``p`` and orientation ``q`` (7 ``qpos``), and the world-frame
  linear velocity ``ṗ`` then the body-frame angular velocity ``ω`` (6 ``qvel``).

On the manifold, a tangent vector ``v (nv,)`` moves a configuration by

.. math::

    \operatorname{integrate}(q, v) = q \otimes \exp(v/2), \qquad \exp(\phi) =
        (\cos\lvert\phi\rvert, \tfrac{\phi}{\lvert\phi\rvert}\sin\lvert\phi\rvert)

on every quaternion (``+ v`` elsewhere), and ``difference(q_1, q_0)`` is its inverse: the ``v`` with
``integrate(q_0, v) = q_1``, on a quaternion ``2 log(q_0^{-1} ⊗ q_1)`` taken on the short arc
(MuJoCo's ``mju_subQuat``). Neither has a singularity (no Euler angles: gimbal-lock free by
construction); ``difference`` is smooth away from a half-turn.

:func:`qpos_rate` works on any scalar type (CasADi ``SX``, floats, complex numbers);
:func:`integrate` and :func:`difference` on floats (NumPy); :func:`integrate_sx` on ``SX``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from shinro_ctrl._scalar_algebra import _add, _mul, _sub

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.multibody.tree import ModelTree

__all__ = [
    "difference",
    "difference_jacobian",
    "integrate",
    "integrate_sx",
    "normalize_quaternions",
    "plain_indices",
    "qpos_rate",
    "quat_matrix",
    "quaternion_slices",
    "tangent_basis",
]


def quat_matrix(q: Sequence[object]) -> list[list[object]]:
    r"""Rotation matrix of a quaternion ``(w, x, y, z)`` on any scalar type, as nested lists.

    ``R = I + 2 (w [v]× + [v]×²) / |q|²``: exact for a unit quaternion and a rotation for any
    non-zero one (scaling ``q`` does not change ``R``).
    """
    w, x, y, z = q
    s = _add(_mul(w, w), _mul(x, x), _mul(y, y), _mul(z, z))
    k = 2.0 / s
    xx, yy, zz = _mul(x, x), _mul(y, y), _mul(z, z)
    xy, xz, yz = _mul(x, y), _mul(x, z), _mul(y, z)
    wx, wy, wz = _mul(w, x), _mul(w, y), _mul(w, z)
    return [
        [_sub(1.0, _mul(k, _add(yy, zz))), _mul(k, _sub(xy, wz)), _mul(k, _add(xz, wy))],
        [_mul(k, _add(xy, wz)), _sub(1.0, _mul(k, _add(xx, zz))), _mul(k, _sub(yz, wx))],
        [_mul(k, _sub(xz, wy)), _mul(k, _add(yz, wx)), _sub(1.0, _mul(k, _add(xx, yy)))],
    ]


def _quat_rate(q: Sequence[object], w: Sequence[object]) -> list[object]:
    """``½ q ⊗ (0, ω)``."""
    qw, qx, qy, qz = q
    wx, wy, wz = w
    return [
        _mul(-0.5, _add(_mul(qx, wx), _mul(qy, wy), _mul(qz, wz))),
        _mul(0.5, _add(_mul(qw, wx), _mul(qy, wz), _mul(-1.0, _mul(qz, wy)))),
        _mul(0.5, _add(_mul(qw, wy), _mul(qz, wx), _mul(-1.0, _mul(qx, wz)))),
        _mul(0.5, _add(_mul(qw, wz), _mul(qx, wy), _mul(-1.0, _mul(qy, wx)))),
    ]


def quaternion_slices(tree: ModelTree) -> list[tuple[int, int]]:
    """``(qpos index, qvel index)`` of each quaternion and of its angular velocity, in joint order."""
    out = []
    for j, a, d in zip(tree.joints, tree.qposadr, tree.dofadr, strict=True):
        if j.type == "ball":
            out.append((a, d))
        elif j.type == "free":
            out.append((a + 3, d + 3))
    return out


def plain_indices(tree: ModelTree) -> tuple[list[int], list[int]]:
    """The ``qpos`` and ``qvel`` indices that are plain coordinates and their rates (``q̇ = v``)."""
    qi: list[int] = []
    vi: list[int] = []
    for j, a, d in zip(tree.joints, tree.qposadr, tree.dofadr, strict=True):
        n = {"hinge": 1, "slide": 1, "ball": 0, "free": 3}[j.type]
        qi += range(a, a + n)
        vi += range(d, d + n)
    return qi, vi


def qpos_rate(tree: ModelTree, q: Sequence[object], v: Sequence[object]) -> list[object]:
    """``q̇pos (nq,)`` from ``qpos (nq,)``, ``qvel (nv,)``: ``v`` on coordinates, ``½ q ⊗ (0, ω)`` on quaternions."""
    out: list[object] = [0.0] * tree.nq
    qi, vi = plain_indices(tree)
    for a, d in zip(qi, vi, strict=True):
        out[a] = v[d]
    for a, d in quaternion_slices(tree):
        out[a : a + 4] = _quat_rate(q[a : a + 4], v[d : d + 3])
    return out


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, av = a[0], a[1:]
    bw, bv = b[0], b[1:]
    return np.r_[aw * bw - av @ bv, aw * bv + bw * av + np.cross(av, bv)]


def _qexp(phi: np.ndarray) -> np.ndarray:
    """``exp(φ/2)``: the unit quaternion of the rotation vector ``φ``."""
    th = float(np.linalg.norm(phi))
    if th < 1e-8:  # second-order series: exact to rounding here
        return np.r_[1.0 - th * th / 8.0, 0.5 * phi * (1.0 - th * th / 24.0)]
    return np.r_[np.cos(th / 2.0), np.sin(th / 2.0) * phi / th]


def _qlog(q: np.ndarray) -> np.ndarray:
    """The rotation vector ``φ`` of the unit quaternion ``q`` on the short arc (``q`` and ``−q`` give the same)."""
    if q[0] < 0.0:
        q = -q
    s = float(np.linalg.norm(q[1:]))
    if s < 1e-12:
        return 2.0 * q[1:] / max(q[0], 1e-300)
    return 2.0 * np.arctan2(s, q[0]) * q[1:] / s


def integrate(tree: ModelTree, qpos: ArrayLike, v: ArrayLike, dt: float = 1.0) -> np.ndarray:
    """``qpos ⊕ v dt (nq,)``: MuJoCo's ``mj_integratePos`` (quaternions renormalized)."""
    q = np.array(qpos, dtype=float)
    v = np.asarray(v, dtype=float) * dt
    qi, vi = plain_indices(tree)
    q[qi] += v[vi]
    for a, d in quaternion_slices(tree):
        r = _qmul(q[a : a + 4] / np.linalg.norm(q[a : a + 4]), _qexp(v[d : d + 3]))
        q[a : a + 4] = r / np.linalg.norm(r)
    return q


def difference(tree: ModelTree, qpos1: ArrayLike, qpos0: ArrayLike, dt: float = 1.0) -> np.ndarray:
    """``(qpos1 ⊖ qpos0) / dt (nv,)``: MuJoCo's ``mj_differentiatePos`` (the inverse of :func:`integrate`)."""
    q1 = np.asarray(qpos1, dtype=float)
    q0 = np.asarray(qpos0, dtype=float)
    out = np.zeros(tree.nv)
    qi, vi = plain_indices(tree)
    out[vi] = q1[qi] - q0[qi]
    for a, d in quaternion_slices(tree):
        b0 = q0[a : a + 4] / np.linalg.norm(q0[a : a + 4])
        b1 = q1[a : a + 4] / np.linalg.norm(q1[a : a + 4])
        out[d : d + 3] = _qlog(_qmul(np.r_[b0[0], -b0[1:]], b1))
    return out / dt


def integrate_sx(tree: ModelTree, qpos: cs.SX, v: cs.SX, dt: float | cs.SX = 1.0) -> cs.SX:
    """:func:`integrate` on CasADi ``SX`` (the exponential written without a branch at ``|φ| = 0``).

    ``exp(φ/2) = (cos(θ/2), sinc(θ/2) φ/2)`` with ``θ = |φ|``; ``sinc`` is evaluated as
    ``sin(s)/s`` away from 0 and by its series below ``1e-4`` (``cs.if_else``), so the function and its
    derivatives are smooth at ``φ = 0``.
    """
    q = [qpos[i] for i in range(tree.nq)]
    qi, vi = plain_indices(tree)
    for a, d in zip(qi, vi, strict=True):
        q[a] = qpos[a] + v[d] * dt
    for a, d in quaternion_slices(tree):
        phi = v[d : d + 3] * dt
        th2 = cs.dot(phi, phi)
        s2 = th2 / 4.0  # (θ/2)²
        s = cs.sqrt(s2 + 1e-300)
        small = s2 < 1e-8
        sinc = cs.if_else(small, 1.0 - s2 / 6.0 + s2 * s2 / 120.0, cs.sin(s) / s)
        cos = cs.if_else(small, 1.0 - s2 / 2.0 + s2 * s2 / 24.0, cs.cos(s))
        e = cs.vertcat(cos, sinc * phi / 2.0)
        b = qpos[a : a + 4]
        b = b / cs.norm_2(b)
        r = cs.vertcat(
            b[0] * e[0] - cs.dot(b[1:4], e[1:4]),
            b[0] * e[1:4] + e[0] * b[1:4] + cs.cross(b[1:4], e[1:4]),
        )
        r = r / cs.norm_2(r)
        for k in range(4):
            q[a + k] = r[k]
    return cs.vertcat(*q)


def normalize_quaternions(tree: ModelTree, qpos: ArrayLike) -> tuple[np.ndarray, float]:
    """``(qpos with every quaternion scaled to unit norm, the largest | |q| − 1 | found)``.

    Raises:
        ValueError: a quaternion of norm 0 (or not finite).
    """
    q = np.array(qpos, dtype=float)
    worst = 0.0
    for a, _ in quaternion_slices(tree):
        n = float(np.linalg.norm(q[a : a + 4]))
        if not np.isfinite(n) or n == 0.0:
            raise ValueError(f"quaternion qpos[{a}:{a + 4}] = {q[a : a + 4].tolist()} has no direction")
        worst = max(worst, abs(n - 1.0))
        q[a : a + 4] /= n
    return q, worst


def _left(q: np.ndarray) -> np.ndarray:
    """``L(q)``: ``q ⊗ p = L(q) p``."""
    w, x, y, z = q
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def tangent_basis(tree: ModelTree, qpos: ArrayLike) -> np.ndarray:
    """``E = ∂ integrate(qpos, v) / ∂v`` at ``v = 0`` ``(nq, nv)``: ``½ L(q)[:, 1:]`` on a quaternion, else ``I``."""
    q = np.asarray(qpos, dtype=float)
    E = np.zeros((tree.nq, tree.nv))
    qi, vi = plain_indices(tree)
    E[qi, vi] = 1.0
    for a, d in quaternion_slices(tree):
        u = q[a : a + 4] / np.linalg.norm(q[a : a + 4])
        E[a : a + 4, d : d + 3] = 0.5 * _left(u)[:, 1:]
    return E


def difference_jacobian(tree: ModelTree, qpos: ArrayLike) -> np.ndarray:
    """``D = ∂ difference(q, qpos) / ∂q`` at ``q = qpos`` ``(nv, nq)``: ``2 L(q̄)[1:, :]`` on a quaternion.

    ``D E = I`` (:func:`tangent_basis`); ``D q = 0`` on each quaternion (a change of its norm is no motion).
    """
    q = np.asarray(qpos, dtype=float)
    D = np.zeros((tree.nv, tree.nq))
    qi, vi = plain_indices(tree)
    D[vi, qi] = 1.0
    for a, d in quaternion_slices(tree):
        n = np.linalg.norm(q[a : a + 4])
        u = q[a : a + 4] / n
        D[d : d + 3, a : a + 4] = 2.0 * _left(np.r_[u[0], -u[1:]])[1:, :] / n
    return D
