r"""Forward dynamics by the articulated-body algorithm (ABA, Featherstone), on any scalar type.

The algorithm computes ``q̈ = (M(q) + diag(a))⁻¹ (τ − c(q, q̇))`` in three
passes over the tree, in ``O(n)`` operations, without forming ``M``:

1. outward: each node's spatial velocity ``v_i = X_i v_λ + S_i q̇_i``, its
   velocity-product acceleration ``c_i = v_i ×ₘ S_i q̇_i``, its rigid-body
   inertia ``I^A_i = I_i`` and bias force ``p^A_i = v_i ×* I_i v_i``;
2. inward: ``U_i = I^A_i S_i``, ``D_i = S_iᵀ U_i + a_i`` (``a_i`` the
   armature), ``u_i = τ_i − S_iᵀ p^A_i``; the node hands its parent the
   articulated inertia ``I^a_i = I^A_i − U_i U_iᵀ / D_i`` and bias
   ``p^a_i = p^A_i + I^a_i c_i + U_i u_i / D_i``, transformed into the parent
   frame (``I^A_λ += X_iᵀ I^a_i X_i``, ``p^A_λ += X_iᵀ p^a_i``);
3. outward: ``a'_i = X_i a_λ + c_i``, ``q̈_i = (u_i − U_iᵀ a'_i) / D_i``,
   ``a_i = a'_i + S_i q̈_i``, from the base acceleration ``a_0 = (0, −g)``
   (gravity as a fictitious upward acceleration of the base).

Spatial vectors are split into 3-vectors in the node frame: a motion
``(ω, v)`` (angular velocity, velocity of the point at the node origin) and
a force ``(n, f)`` (moment about the node origin, force). A spatial inertia
is the three blocks ``(A, B, C)`` of ``[[A, B], [Bᵀ, C]]`` mapping motion to
force (a rigid body: ``A = I_O``, ``B = [h]×``, ``C = m 1`` with ``h = m c``
the first moment). A node ``i`` sits in its parent's frame with orientation
``R`` and origin ``p``; motions go parent → child as ``ω_i = Rᵀ ω``,
``v_i = Rᵀ (v + ω × p)`` and forces child → parent as ``f = R f_i``,
``n = R n_i + p × R f_i``. Each node has one degree of freedom along a
constant axis ``s`` of its node frame: a hinge ``S = (s, 0)``, a slide
``S = (0, s)``. A ball joint is three rotation nodes at one origin with no
rotation between them (``ball`` 1, 2, 2): their velocity-product terms are the
spherical joint's ``c = (ω_λ × S q̇, v × S q̇)`` with ``ω_λ`` the rate before
the joint (``S`` is constant in the body frame), not a hinge chain's.

Everything is written with the structural-zero-skipping helpers of
:mod:`shinro_ctrl._scalar_algebra`, so one code path builds CasADi ``SX``
expressions, evaluates floats and evaluates complex numbers (complex step).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, TypeAlias

import numpy as np

from shinro_ctrl._scalar_algebra import _add, _const, _cross, _dot, _matTvec, _matvec, _mul, _sub, _vadd, _vscale

__all__ = ["JointNode", "articulated_body_accelerations"]

Scalar: TypeAlias = "float | complex | object"
Vec: TypeAlias = "list[Scalar]"
Mat: TypeAlias = "list[list[Scalar]]"


class JointNode(Protocol):
    """What the algorithm reads of one joint node (``RigidBodyTree``'s nodes satisfy it)."""

    parent: int
    slide: bool
    ball: int
    axis: np.ndarray
    mass: float
    h: np.ndarray
    inertia: np.ndarray


def _skew(v: Sequence[Scalar]) -> Mat:
    return [[0.0, _mul(-1.0, v[2]), v[1]], [v[2], 0.0, _mul(-1.0, v[0])], [_mul(-1.0, v[1]), v[0], 0.0]]


def _mm(A: Mat, B: Mat) -> Mat:
    return [[_add(*(_mul(A[r][k], B[k][c]) for k in range(3))) for c in range(3)] for r in range(3)]


def _mmT(A: Mat, B: Mat) -> Mat:
    """``A Bᵀ``."""
    return [[_add(*(_mul(A[r][k], B[c][k]) for k in range(3))) for c in range(3)] for r in range(3)]


def _madd(*Ms: Mat) -> Mat:
    return [[_add(*(M[r][c] for M in Ms)) for c in range(3)] for r in range(3)]


def _msub(A: Mat, B: Mat) -> Mat:
    return [[_sub(A[r][c], B[r][c]) for c in range(3)] for r in range(3)]


def _T(A: Mat) -> Mat:
    return [[A[c][r] for c in range(3)] for r in range(3)]


def _outer_scaled(a: Vec, b: Vec, s: Scalar) -> Mat:
    """``a bᵀ s``."""
    return [[_mul(_mul(a[r], b[c]), s) for c in range(3)] for r in range(3)]


def _sym_rot(R: Mat, A: Mat) -> Mat:
    """``R A Rᵀ`` for a symmetric ``A`` (upper triangle computed, mirrored)."""
    RA = _mm(R, A)
    out: Mat = [[0.0] * 3 for _ in range(3)]
    for r in range(3):
        for c in range(r, 3):
            out[r][c] = out[c][r] = _add(*(_mul(RA[r][k], R[c][k]) for k in range(3)))
    return out


def _to_parent(R: Mat, p: Vec, A: Mat, B: Mat, C: Mat) -> tuple[Mat, Mat, Mat]:
    """A spatial inertia ``(A, B, C)`` of a child frame expressed in its parent frame.

    Rotate, ``A' = R A Rᵀ``, ``B' = R B Rᵀ``, ``C' = R C Rᵀ``, then move the
    reference point from ``p`` to the origin with ``P = [p]×``:
    ``A = A' − B'P + P B'ᵀ − P C' P``, ``B = B' + P C'``, ``C = C'``.
    """
    A1 = _sym_rot(R, A)
    B1 = _mmT(_mm(R, B), R)
    C1 = _sym_rot(R, C)
    if all(isinstance(c, float | int) and c == 0 for c in p):
        return A1, B1, C1
    P = _skew(p)
    PC = _mm(P, C1)
    B1P = _mm(B1, P)
    A0: Mat = [[0.0] * 3 for _ in range(3)]
    PCP = _mm(PC, P)
    for r in range(3):
        for c in range(r, 3):
            # -B'P + P B'^T = -(B'P) - (B'P)^T
            A0[r][c] = A0[c][r] = _sub(_sub(_sub(A1[r][c], B1P[r][c]), B1P[c][r]), PCP[r][c])
    return A0, _madd(B1, PC), C1


def articulated_body_accelerations(
    nodes: Sequence[JointNode],
    X: Sequence[tuple[Mat, Vec]],
    qd: Sequence[Scalar],
    tau: Sequence[Scalar],
    armature: Sequence[float],
    base_acceleration: Sequence[Scalar],
) -> list[Scalar]:
    """Joint accelerations ``q̈ = (M + diag(a))⁻¹ (τ − c(q, q̇))`` by the articulated-body algorithm.

    Args:
        nodes: The joint nodes in tree order (parents first), one degree of
            freedom each (see :class:`JointNode`): inertia carried by the node
            (mass, first moment ``h = m c`` and rotational inertia about the
            node origin, in the node frame).
        X: Each node's ``(R (3, 3), p (3,))`` in its parent node frame at the
            current ``q`` (``RigidBodyTree``'s joint transforms).
        qd: Joint velocities ``(n,)``.
        tau: Generalized forces ``(n,)`` (actuators, springs, dampers ...).
        armature: Rotor inertia added to each joint's diagonal of ``M``.
        base_acceleration: The fixed base's linear acceleration ``(3,)`` in the
            world (root) frame: ``−g`` puts gravity in, zeros leave it out.

    Returns:
        ``q̈`` as a list of ``n`` scalars (floats, complex or ``SX``).
    """
    n = len(nodes)
    zero3: Vec = [0.0, 0.0, 0.0]
    w: list[Vec] = [zero3] * n
    v: list[Vec] = [zero3] * n
    c_ang: list[Vec] = [zero3] * n
    c_lin: list[Vec] = [zero3] * n
    IA: list[list[Mat]] = []
    pn: list[Vec] = [zero3] * n
    pf: list[Vec] = [zero3] * n
    wb: list[Vec] = [zero3] * n  # a ball's rate before the joint
    # pass 1: velocities, velocity-product accelerations, rigid-body inertias and bias forces
    for i, nd in enumerate(nodes):
        R, p = X[i]
        s = _const(nd.axis)
        if nd.parent >= 0:
            wp, vp = w[nd.parent], v[nd.parent]
            wi = _matTvec(R, wp)
            vi = _matTvec(R, _vadd(vp, _cross(wp, p)))
        else:
            wi, vi = zero3, zero3
        sj = _vscale(s, qd[i])
        if nd.slide:
            vi = _vadd(vi, sj)
            c_ang[i], c_lin[i] = zero3, _cross(wi, sj)
        else:
            wb[i] = wb[nd.parent] if nd.ball == 2 else wi
            wi = _vadd(wi, sj)
            c_ang[i], c_lin[i] = _cross(wb[i], sj), _cross(vi, sj)
        w[i], v[i] = wi, vi
        h = _const(nd.h)
        A = [_const(r) for r in nd.inertia]
        B = _skew(h)
        m = float(nd.mass)
        C = [[m if r == c else 0.0 for c in range(3)] for r in range(3)]
        IA.append([A, B, C])
        # I v = (I_O w + h x v, m v - h x w); p = v x* (I v) = (w x n + v x f, w x f)
        mom_n = _vadd(_matvec(A, wi), _cross(h, vi))
        mom_f = _sub_vec(_vscale(vi, m), _cross(h, wi))
        pn[i] = _vadd(_cross(wi, mom_n), _cross(vi, mom_f))
        pf[i] = _cross(wi, mom_f)
    # pass 2: articulated inertias and bias forces, leaves to root
    U_ang: list[Vec] = [zero3] * n
    U_lin: list[Vec] = [zero3] * n
    D: list[Scalar] = [0.0] * n
    uu: list[Scalar] = [0.0] * n
    for i in range(n - 1, -1, -1):
        nd = nodes[i]
        s = _const(nd.axis)
        A, B, C = IA[i]
        if nd.slide:
            Ua, Ul = _matvec(B, s), _matvec(C, s)
            D[i] = _add(_dot(s, Ul), armature[i])
            uu[i] = _sub(tau[i], _dot(s, pf[i]))
        else:
            Ua, Ul = _matvec(A, s), _matTvec(B, s)
            D[i] = _add(_dot(s, Ua), armature[i])
            uu[i] = _sub(tau[i], _dot(s, pn[i]))
        U_ang[i], U_lin[i] = Ua, Ul
        if nd.parent < 0:
            continue
        inv_d = 1.0 / D[i]
        Aa = _msub(A, _outer_scaled(Ua, Ua, inv_d))
        Ba = _msub(B, _outer_scaled(Ua, Ul, inv_d))
        Ca = _msub(C, _outer_scaled(Ul, Ul, inv_d))
        # p^a = p^A + I^a c + U u / D
        ud = _mul(uu[i], inv_d)
        ca, cl = c_ang[i], c_lin[i]
        pan = _vadd(pn[i], _matvec(Aa, ca), _matvec(Ba, cl), _vscale(Ua, ud))
        paf = _vadd(pf[i], _matTvec(Ba, ca), _matvec(Ca, cl), _vscale(Ul, ud))
        R, p = X[i]
        Ap, Bp, Cp = _to_parent(R, p, Aa, Ba, Ca)
        k = nd.parent
        IA[k] = [_madd(IA[k][0], Ap), _madd(IA[k][1], Bp), _madd(IA[k][2], Cp)]
        fr = _matvec(R, paf)
        pn[k] = _vadd(pn[k], _matvec(R, pan), _cross(p, fr))
        pf[k] = _vadd(pf[k], fr)
    # pass 3: accelerations, root to leaves
    a_base: Vec = list(base_acceleration)
    al: list[Vec] = [zero3] * n
    acc: list[Vec] = [zero3] * n
    qdd: list[Scalar] = [0.0] * n
    for i, nd in enumerate(nodes):
        R, p = X[i]
        s = _const(nd.axis)
        if nd.parent >= 0:
            alp, ap = al[nd.parent], acc[nd.parent]
        else:
            alp, ap = zero3, a_base
        al_i = _vadd(_matTvec(R, alp), c_ang[i])
        a_i = _vadd(_matTvec(R, _vadd(ap, _cross(alp, p))), c_lin[i])
        qdd[i] = _mul(_sub(uu[i], _add(_dot(U_ang[i], al_i), _dot(U_lin[i], a_i))), 1.0 / D[i])
        if nd.slide:
            a_i = _vadd(a_i, _vscale(s, qdd[i]))
        else:
            al_i = _vadd(al_i, _vscale(s, qdd[i]))
        al[i], acc[i] = al_i, a_i
    return qdd


def _sub_vec(a: Vec, b: Vec) -> Vec:
    return [_sub(x, y) for x, y in zip(a, b, strict=True)]
