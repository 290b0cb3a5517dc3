r"""Exact rigid-body dynamics of a fixed-base tree of hinge and slide joints.

A :class:`ModelTree` is a plain-numpy description of a kinematic tree (as
``shinro_ctrl.engine.model_tree.read_model_tree`` reads it from an MJCF or
URDF file). :class:`RigidBodyTree` turns it into the equations of motion

.. math::

    (M(q) + \operatorname{diag}(a))\,\ddot q + c(q, \dot q)
        = \tau_{act}(q, \dot q, u) - b \odot \dot q - k \odot (q - q_{spring})

with ``M`` the joint-space mass matrix, ``c`` the Coriolis, centrifugal and
gravity terms, ``a`` the armature, ``b`` the joint damping and ``k`` the
joint stiffness, exactly as MuJoCo's ``mj_forward`` computes ``qacc`` for a
model without contacts, limits or equality constraints.

The algorithms are the textbook ones, written on scalars so that the same
code builds a CasADi ``SX`` expression, evaluates floats or evaluates
complex numbers (complex-step differentiation):

* ``c(q, q̇)``: recursive Newton–Euler (RNEA) with ``q̈ = 0`` and the base
  accelerated by ``-g`` (gravity);
* ``M(q)``: column ``j`` is the RNEA of unit acceleration ``e_j`` at rest
  without gravity (zeros fold away symbolically, so only the branches that
  move are built);
* ``q̈``: by default the articulated-body algorithm
  (:mod:`shinro_ctrl.multibody.aba`, ``O(n)``, no ``M``); or
  (``algorithm="crba"``) an LDLᵀ factorization of ``M + diag(a)`` (no
  pivoting; ``M`` is symmetric positive definite). Both agree with MuJoCo's
  ``qacc_smooth`` to ~1e-15; :meth:`RigidBodyTree.forward_dynamics` is the one
  place the choice is made;
* the exact Jacobians of ``ẋ``: by differentiating the inverse dynamics
  (:meth:`RigidBodyTree.xdot_jacobians_sx`), about 30 % smaller than the
  automatic derivative of either forward algorithm and much cheaper to
  compile.

Each joint is one node. A node's frame is its body's frame translated to the
joint's anchor (MuJoCo ``jnt_pos``), so a hinge rotates the frame about its
origin; a body with several joints becomes a chain of nodes with the body's
inertia on the last one, and a body without joints is welded to its parent
node (its inertia is merged there). Joint coordinates are measured from the
model's ``qpos0`` as in MuJoCo.

Actuators with a joint transmission map controls to joint forces as MuJoCo
defines them: with actuator length ``l = g q`` and velocity ``l̇ = g q̇``
(``g`` the gear), force ``F = gain(l, l̇)·u + bias(l, l̇)``, where
``gain = p₀`` (fixed) or ``p₀ + p₁ l + p₂ l̇`` (affine) and
``bias = 0`` (none) or ``b₀ + b₁ l + b₂ l̇`` (affine), and generalized force
``g F``. A ``position`` servo is ``gain = k_p``, ``bias = (0, −k_p, −k_v)``;
a ``velocity`` servo ``gain = k_v``, ``bias = (0, 0, −k_v)``; a ``motor``
``gain = 1``, no bias.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeAlias

import casadi as cs
import numpy as np

from shinro_ctrl._scalar_algebra import (
    _add,
    _all_zero,
    _const,
    _cross,
    _dot,
    _ldl_back,
    _ldl_factor,
    _ldl_solve,
    _matTvec,
    _matvec,
    _mul,
    _sub,
    _vadd,
    _vscale,
    quat_to_mat,
)
from shinro_ctrl.multibody.aba import articulated_body_accelerations

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.multibody.tree import ModelTree

__all__ = ["CASADI_OPS", "FORWARD_DYNAMICS", "NUMPY_OPS", "Ops", "RigidBodyTree", "Scalar"]

#: The numbers the algorithms run on: floats, complex numbers (complex step) or CasADi ``SX`` scalars.
Scalar: TypeAlias = "float | complex | cs.SX"
#: The forward-dynamics algorithms :meth:`RigidBodyTree.forward_dynamics` offers.
FORWARD_DYNAMICS = ("aba", "crba")
#: Each node's ``(R (3, 3), p (3,))`` in its parent node frame, as nested lists of scalars.
Transforms: TypeAlias = "Transforms"


@dataclass
class _Node:
    """One joint: fixed placement in the parent node, motion, and the inertia it carries."""

    parent: int
    dof: int
    slide: bool
    R0: np.ndarray  # (3, 3) orientation in the parent node frame
    p0: np.ndarray  # (3,) origin in the parent node frame
    axis: np.ndarray  # (3,) unit axis in the node frame
    qpos0: float
    mass: float = 0.0
    h: np.ndarray = field(default_factory=lambda: np.zeros(3))  # first moment m c in the node frame
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # about the node origin


class Ops:
    """The elementwise functions the algorithms need (``sin``, ``cos``) for one number type."""

    def __init__(self, sin: Callable[[Scalar], Scalar], cos: Callable[[Scalar], Scalar]):
        self.sin = sin
        self.cos = cos


CASADI_OPS = Ops(cs.sin, cs.cos)
NUMPY_OPS = Ops(np.sin, np.cos)  # floats and complex numbers (complex step)


class RigidBodyTree:
    """Equations of motion of a :class:`ModelTree`, on any scalar type.

    Args:
        tree: The model description.
        algorithm: The forward-dynamics algorithm, one of :data:`FORWARD_DYNAMICS`:
            ``"aba"`` (articulated bodies, the default) or ``"crba"`` (``M`` by
            RNEA columns, then LDLᵀ).

    Attributes:
        tree: The description.
        algorithm: The forward-dynamics algorithm.
        nq: Number of joint coordinates.
        nu: Number of actuators.
        parent: Parent node of each node (-1 for the world), shape ``(nq,)``.
    """

    def __init__(self, tree: ModelTree, algorithm: str = "aba"):
        if algorithm not in FORWARD_DYNAMICS:
            raise ValueError(f"unknown forward-dynamics algorithm {algorithm!r}; valid: {', '.join(FORWARD_DYNAMICS)}")
        self.algorithm = algorithm
        self.tree = tree
        self.nq = tree.nq
        self.nu = tree.nu
        self._nodes = self._build_nodes(tree)
        self.parent = np.array([n.parent for n in self._nodes], dtype=int)
        g = np.asarray(tree.gravity, dtype=float) if tree.gravity_enabled else np.zeros(3)
        self._a_base = _const(-g)
        self._damping = [j.damping if tree.damping_enabled else 0.0 for j in tree.joints]
        self._stiffness = [j.stiffness if tree.springs_enabled else 0.0 for j in tree.joints]
        self._springref = [j.springref for j in tree.joints]
        self._armature = [j.armature for j in tree.joints]
        # children lists give each column of M its moving subtree
        self._subtree = [self._descendants(i) for i in range(self.nq)]

    # ------------------------------------------------------------- structure
    @staticmethod
    def _build_nodes(tree: ModelTree) -> list[_Node]:
        nb = len(tree.bodies)
        # Each body's frame relative to a node frame: (node index or -1 for the world, R, p).
        frame: list[tuple[int, np.ndarray, np.ndarray]] = [(-1, np.eye(3), np.zeros(3))] * nb
        nodes: list[_Node] = []
        for b in range(1, nb):
            body = tree.bodies[b]
            pnode, Rp, pp = frame[body.parent]
            Rb = Rp @ quat_to_mat(body.quat)
            pb = pp + Rp @ np.asarray(body.pos, dtype=float)
            node, R, p = pnode, Rb, pb
            for j in body.joints:
                jt = tree.joints[j]
                anchor = np.asarray(jt.pos, dtype=float)
                # node frame = current frame moved to the anchor (same orientation)
                nodes.append(
                    _Node(
                        parent=node,
                        dof=j,
                        slide=jt.type == "slide",
                        R0=R.copy(),
                        p0=p + R @ anchor,
                        axis=np.asarray(jt.axis, dtype=float) / np.linalg.norm(jt.axis),
                        qpos0=float(jt.qpos0),
                    )
                )
                node, R, p = len(nodes) - 1, np.eye(3), -anchor
            frame[b] = (node, R, p)
            if node >= 0 and (body.mass > 0.0 or np.any(np.asarray(body.inertia) > 0.0)):  # else: world-welded
                # body inertia expressed in the node frame, about the node origin
                Ri = R @ quat_to_mat(body.iquat)
                c = p + R @ np.asarray(body.ipos, dtype=float)
                Ic = Ri @ np.diag(np.asarray(body.inertia, dtype=float)) @ Ri.T
                m = float(body.mass)
                nd = nodes[node]
                nd.mass += m
                nd.h = nd.h + m * c
                nd.inertia = nd.inertia + Ic + m * (float(c @ c) * np.eye(3) - np.outer(c, c))
        order = [n.dof for n in nodes]
        if order != list(range(len(tree.joints))):  # MuJoCo numbers dofs in body order
            raise ValueError(f"joints are not in tree order: {order}")
        return nodes

    def _descendants(self, i: int) -> list[int]:
        out = [i]
        for k in range(i + 1, self.nq):
            if self._nodes[k].parent in out:
                out.append(k)
        return out

    # ----------------------------------------------------------- kinematics
    def _joint_transforms(self, q: Sequence[Scalar], ops: Ops) -> Transforms:
        """Each node's ``(R (3, 3), p (3,))`` in its parent node frame at ``q``."""
        out = []
        for i, nd in enumerate(self._nodes):
            R0 = [_const(r) for r in nd.R0]
            p0 = _const(nd.p0)
            ax = _const(nd.axis)
            th = _sub(q[i], nd.qpos0) if nd.qpos0 != 0.0 else q[i]
            if nd.slide:
                R = R0
                p = _vadd(p0, _vscale(_matvec(R0, ax), th))
            else:
                s, c1 = ops.sin(th), 1.0 - ops.cos(th)
                x, y, z = ax
                # Rodrigues: I + s K + (1 - cos) K², K = [axis]×
                K = [[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]
                K2 = [[_dot(K[r], [K[0][c], K[1][c], K[2][c]]) for c in range(3)] for r in range(3)]
                Rj = [
                    [_add(1.0 if r == c else 0.0, _mul(K[r][c], s), _mul(K2[r][c], c1)) for c in range(3)]
                    for r in range(3)
                ]
                R = [[_dot(R0[r], [Rj[0][c], Rj[1][c], Rj[2][c]]) for c in range(3)] for r in range(3)]
                p = p0
            out.append((R, p))
        return out

    # ------------------------------------------------------------------ RNEA
    def _rnea(
        self,
        X: Transforms,
        qd: Sequence[Scalar] | None,
        qdd: Sequence[Scalar],
        a_base: Sequence[Scalar],
        nodes: Sequence[int] | None = None,
    ) -> list[Scalar]:
        """Joint forces ``τ = M q̈ + c`` by recursive Newton–Euler.

        Args:
            X: Node transforms from :meth:`_joint_transforms`.
            qd: Joint velocities, or None for rest (all terms in q̇ dropped).
            qdd: Joint accelerations.
            a_base: Acceleration of the base ``(3,)`` (``-g`` includes gravity).
            nodes: Only these nodes move (others are at rest, and forces stop at
                the first node at rest); None: all.
        """
        n = self.nq
        zero3 = [0.0, 0.0, 0.0]
        w: list[list[Scalar]] = [zero3] * n
        al: list[list[Scalar]] = [zero3] * n
        a: list[list[Scalar]] = [zero3] * n
        f: list[list[Scalar]] = [zero3] * n
        m_: list[list[Scalar]] = [zero3] * n
        active = range(n) if nodes is None else nodes
        moving = set(active)
        for i in active:
            nd = self._nodes[i]
            R, p = X[i]
            pi = nd.parent
            if pi >= 0 and pi in moving:
                wp, alp, ap = w[pi], al[pi], a[pi]
            elif pi >= 0:
                wp, alp, ap = zero3, zero3, a_base
            else:
                wp, alp, ap = zero3, zero3, a_base
            ax = _const(nd.axis)
            wpl = _matTvec(R, wp)  # parent's rate in this frame
            apl = _matTvec(R, _vadd(ap, _cross(alp, p), _cross(wp, _cross(wp, p))))
            alpl = _matTvec(R, alp)
            vj = _vscale(ax, qd[i]) if qd is not None else zero3
            aj = _vscale(ax, qdd[i])
            if nd.slide:
                w[i] = wpl
                al[i] = alpl
                a[i] = _vadd(apl, _vscale(_cross(wpl, vj), 2.0), aj)
            else:
                w[i] = _vadd(wpl, vj)
                al[i] = _vadd(alpl, _cross(wpl, vj), aj)
                a[i] = apl
            h = _const(nd.h)
            Ib = [_const(r) for r in nd.inertia]
            wi, ali, ai = w[i], al[i], a[i]
            f[i] = _vadd(_vscale(ai, nd.mass), _cross(ali, h), _cross(wi, _cross(wi, h)))
            m_[i] = _vadd(_matvec(Ib, ali), _cross(wi, _matvec(Ib, wi)), _cross(h, ai))
        # backward pass: forces of the moving nodes propagate to every ancestor
        tau: list[Scalar] = [0.0] * n
        f = list(f)
        m_ = list(m_)
        for i in range(n - 1, -1, -1):
            nd = self._nodes[i]
            ax = _const(nd.axis)
            tau[i] = _dot(ax, f[i]) if nd.slide else _dot(ax, m_[i])
            pi = nd.parent
            if pi >= 0 and (nodes is None or pi in moving) and not (_all_zero(f[i]) and _all_zero(m_[i])):
                R, p = X[i]
                fr = _matvec(R, f[i])
                f[pi] = _vadd(f[pi], fr)
                m_[pi] = _vadd(m_[pi], _matvec(R, m_[i]), _cross(p, fr))
        return tau

    # ---------------------------------------------------------------- public
    def mass_matrix(self, q: Sequence[Scalar], ops: Ops = NUMPY_OPS, X: Transforms | None = None) -> list[list[Scalar]]:
        """Joint-space mass matrix ``M(q)`` (without armature) as nested lists ``(nq, nq)``."""
        X = self._joint_transforms(q, ops) if X is None else X
        n = self.nq
        M: list[list[Scalar]] = [[0.0] * n for _ in range(n)]
        for j in range(n):
            e = [1.0 if k == j else 0.0 for k in range(n)]
            col = self._rnea(X, None, e, [0.0, 0.0, 0.0], self._subtree[j])
            for i in self._subtree[j]:  # the lower triangle: row j and its descendants; the rest by symmetry
                M[i][j] = col[i]
                M[j][i] = col[i]
        return M

    def bias(
        self, q: Sequence[Scalar], qd: Sequence[Scalar], ops: Ops = NUMPY_OPS, X: Transforms | None = None
    ) -> list[Scalar]:
        """``c(q, q̇)``: Coriolis, centrifugal and gravity forces ``(nq,)``."""
        X = self._joint_transforms(q, ops) if X is None else X
        return self._rnea(X, qd, [0.0] * self.nq, self._a_base)

    def actuator_forces(
        self, q: Sequence[Scalar], qd: Sequence[Scalar], u: Sequence[Scalar], active: Sequence[int]
    ) -> list[Scalar]:
        """Generalized actuator forces ``(nq,)`` of the actuators ``active`` driven by ``u``.

        Actuators not in ``active`` get control 0 (their bias still acts).
        """
        tau: list[Scalar] = [0.0] * self.nq
        if not self.tree.actuation_enabled:
            return tau
        ctrl = dict(zip(active, u, strict=True))
        for k, act in enumerate(self.tree.actuators):
            j = act.joint
            g = act.gear
            length = _mul(g, q[j])
            vel = _mul(g, qd[j])
            p0, p1, p2 = (float(c) for c in act.gainprm)
            gain: Scalar = p0 if act.gaintype == "fixed" else _add(p0, _mul(p1, length), _mul(p2, vel))
            b0, b1, b2 = (float(c) for c in act.biasprm)
            bias: Scalar = 0.0 if act.biastype == "none" else _add(b0, _mul(b1, length), _mul(b2, vel))
            force = _add(_mul(gain, ctrl[k]) if k in ctrl else 0.0, bias)
            tau[j] = _add(tau[j], _mul(g, force))
        return tau

    def passive_forces(self, q: Sequence[Scalar], qd: Sequence[Scalar]) -> list[Scalar]:
        """Joint damping and spring forces ``-b q̇ - k (q - q_spring)`` ``(nq,)``."""
        return [
            _sub(
                _mul(-self._damping[i], qd[i]) if self._damping[i] else 0.0,
                _mul(self._stiffness[i], _sub(q[i], self._springref[i])) if self._stiffness[i] else 0.0,
            )
            for i in range(self.nq)
        ]

    def inverse_dynamics(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        qdd: Sequence[Scalar],
        ops: Ops = NUMPY_OPS,
        X: Transforms | None = None,
    ) -> list[Scalar]:
        """``(M(q) + diag(a)) q̈ + c(q, q̇)`` ``(nq,)`` by RNEA: the generalized force that produces ``q̈``."""
        X = self._joint_transforms(q, ops) if X is None else X
        tau = self._rnea(X, qd, qdd, self._a_base)
        return [_add(tau[i], _mul(self._armature[i], qdd[i])) for i in range(self.nq)]

    def forward_dynamics(
        self, q: Sequence[Scalar], qd: Sequence[Scalar], tau: Sequence[Scalar], ops: Ops = NUMPY_OPS
    ) -> list[Scalar]:
        r"""Accelerations ``q̈ = (M(q) + diag(a))⁻¹ (τ − c(q, q̇))`` ``(nq,)`` for a generalized force ``τ``.

        The one place the forward-dynamics algorithm is chosen
        (:attr:`algorithm`): ``"aba"``, the articulated-body algorithm
        (:mod:`shinro_ctrl.multibody.aba`, ``O(n)``, the default: the smaller
        expression and Jacobian), or ``"crba"``, ``M`` column by column by
        RNEA then an LDLᵀ solve (``O(n³)``; the reference it is tested
        against). Both are exact.
        """
        X = self._joint_transforms(q, ops)
        if self.algorithm == "aba":
            return articulated_body_accelerations(self._nodes, X, qd, tau, self._armature, self._a_base)
        M = self.mass_matrix(q, ops, X)
        for i in range(self.nq):
            M[i][i] = _add(M[i][i], self._armature[i])
        c = self.bias(q, qd, ops, X)
        return _ldl_solve(M, [_sub(tau[i], c[i]) for i in range(self.nq)])

    def accelerations(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        u: Sequence[Scalar],
        active: Sequence[int],
        ops: Ops = NUMPY_OPS,
    ) -> list[Scalar]:
        """Forward dynamics ``q̈ = (M + diag(a))⁻¹ (τ_act + τ_passive − c)`` ``(nq,)``."""
        return self.forward_dynamics(q, qd, self.generalized_forces(q, qd, u, active), ops)

    def generalized_forces(
        self, q: Sequence[Scalar], qd: Sequence[Scalar], u: Sequence[Scalar], active: Sequence[int]
    ) -> list[Scalar]:
        """All applied generalized forces ``τ = τ_act + τ_passive`` ``(nq,)``: what :meth:`forward_dynamics` takes."""
        ta = self.actuator_forces(q, qd, u, active)
        tp = self.passive_forces(q, qd)
        return [_add(ta[i], tp[i]) for i in range(self.nq)]

    def xdot_jacobians_sx(self, x: cs.SX, u: cs.SX, active: Sequence[int]) -> tuple[cs.SX, cs.SX]:
        r"""The exact Jacobians ``(A = ∂ẋ/∂x (2nq, 2nq), B = ∂ẋ/∂u (2nq, m))`` of :meth:`xdot_sx`, as dense ``SX``.

        Differentiating the forward dynamics through its own graph (an LDLᵀ
        solve or the articulated-body recursion) gives an expression 8-10 times
        the size of ``f``. Instead, differentiate the identity the
        accelerations satisfy, the inverse dynamics

        .. math::

            g(z, \ddot q) = (M(q) + \operatorname{diag}(a))\,\ddot q + c(q, \dot q) - 	au(q, \dot q, u) = 0,
            \qquad z = (q, \dot q, u),

        so that, with ``M̃ = M + diag(a)`` factored once (LDLᵀ, the same
        factors give ``q̈``),

        .. math::

            rac{\partial \ddot q}{\partial z} = -	ilde M^{-1}\,
                rac{\partial g}{\partial z}\Big|_{\ddot q = f(z)}

        where ``∂g/∂z`` is the reverse-mode derivative of RNEA (``O(n)``
        nodes per row) with ``q̈`` held as a symbol, then replaced by its
        expression. Exact (no truncation); the rows ``∂q̇/∂x = [0, I]`` are
        constants.

        Args:
            x: State symbols ``(2nq,)`` ``[q; q̇]``.
            u: Input symbols ``(len(active),)``.
            active: The actuators ``u`` drives (see :meth:`actuator_forces`).
        """
        n, m = self.nq, len(active)
        q = [x[i] for i in range(n)]
        qd = [x[n + i] for i in range(n)]
        uu = [u[k] for k in range(m)]
        tau = self.generalized_forces(q, qd, uu, active)
        a = cs.SX.sym("qdd", n)
        X = self._joint_transforms(q, CASADI_OPS)
        inv = self.inverse_dynamics(q, qd, [a[i] for i in range(n)], CASADI_OPS, X)
        g = cs.vertcat(*[cs.SX(_sub(inv[i], tau[i])) for i in range(n)])
        z = cs.vertcat(x, u)
        # (n, 2n + m), affine in the symbol q̈; one reverse sweep per row: ~20 % fewer nodes than cs.jacobian's choice
        G = cs.vertcat(*[cs.gradient(g[i], z).T for i in range(n)])
        M = self.mass_matrix(q, CASADI_OPS, X)
        for i in range(n):
            M[i][i] = _add(M[i][i], self._armature[i])
        L, D = _ldl_factor(M)
        c = self.bias(q, qd, CASADI_OPS, X)
        qdd = _ldl_back(L, D, [_sub(tau[i], c[i]) for i in range(n)])
        G = cs.substitute(G, a, cs.vertcat(*[cs.SX(v) for v in qdd]))

        def entry(i: int, j: int) -> Scalar:
            e = G[i, j]
            return 0.0 if e.is_zero() else -e

        cols = [
            cs.vertcat(*[cs.SX(v) for v in _ldl_back(L, D, [entry(i, j) for i in range(n)])]) for j in range(2 * n + m)
        ]
        Y = cs.horzcat(*cols)
        A = cs.vertcat(cs.horzcat(cs.SX.zeros(n, n), cs.SX.eye(n)), Y[:, : 2 * n])
        B = cs.vertcat(cs.SX.zeros(n, m), Y[:, 2 * n :])
        return cs.densify(A), cs.densify(B)

    def xdot_sx(self, x: cs.SX, u: cs.SX, active: Sequence[int]) -> cs.SX:
        """``ẋ = [q̇; q̈]`` as a CasADi ``SX`` column from symbols ``x (2nq,)`` and ``u (len(active),)``."""
        n = self.nq
        q = [x[i] for i in range(n)]
        qd = [x[n + i] for i in range(n)]
        uu = [u[k] for k in range(len(active))]
        qdd = self.accelerations(q, qd, uu, active, CASADI_OPS)
        return cs.vertcat(*qd, *[cs.SX(v) if isinstance(v, float | int) else v for v in qdd])

    def xdot_numpy(self, x: ArrayLike, u: ArrayLike, active: Sequence[int]) -> np.ndarray:
        """``ẋ (2nq,)`` evaluated directly on numbers (float or complex; the complex-step path)."""
        n = self.nq
        x = np.asarray(x)
        u = np.asarray(u)
        q, qd = list(x[:n]), list(x[n:])
        qdd = self.accelerations(q, qd, list(u), active, NUMPY_OPS)
        return np.array([*qd, *qdd], dtype=np.result_type(x, u, float))
