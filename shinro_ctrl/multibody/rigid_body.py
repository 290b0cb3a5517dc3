r"""Exact rigid-body dynamics of a fixed-base tree of hinge and slide joints.

A :class:`ModelTree` is a plain-numpy description of a kinematic tree (as
``shinro_ctrl.engine.model_tree.read_model_tree`` reads it from an MJCF or
URDF file). :class:`RigidBodyTree` turns it into the equations of motion

.. math::

    (M(q) + \operatorname{diag}(a))\,\ddot q + c(q, \dot q) = \tau(q, \dot q, u, a_{act}),

    \tau = \tau_{act}(q, \dot q, u, a_{act}) - b \odot \dot q - k \odot (q - q_{spring})
        + \sum_t c_t f_t(c_t^\top q, c_t^\top \dot q) + \sum_b J_b(q)^\top (-s_b m_b g)

with ``M`` the joint-space mass matrix, ``c`` the Coriolis, centrifugal and
gravity terms, ``a`` the armature, ``b`` the joint damping, ``k`` the joint
stiffness, ``f_t`` the spring-damper force of fixed tendon ``t`` (coefficients
``c_t``), and the last sum MuJoCo's gravity compensation (factor ``s_b`` at
body ``b``'s centre of mass, ``J_b`` its point Jacobian), exactly as MuJoCo's
``mj_forward`` computes ``qacc_smooth`` (everything but the constraint forces:
contacts, limits, friction loss). :meth:`RigidBodyTree.generalized_forces`
computes ``τ`` in one place, apart from the forward-dynamics algorithm.
``τ_act`` and the activation rates ``ȧ_act`` are in
:mod:`~shinro_ctrl.multibody.transmission`.

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

Kinematics for transmissions at points (and later contacts):
:meth:`RigidBodyTree.world_frames` (forward kinematics of every node),
:meth:`RigidBodyTree.body_frame` (a frame fixed on a body),
:meth:`RigidBodyTree.point_jacobian` (point and angular Jacobian columns) and
:meth:`RigidBodyTree.frame_jacobian` (the dense form).
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
from shinro_ctrl.multibody.configuration import qpos_rate, quat_matrix
from shinro_ctrl.multibody.transmission import SiteFrame, Transmissions, tendon_length, tendon_velocity

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
    qadr: int = -1  # index in qpos of the coordinate (hinge, slide) or of the quaternion (ball == 1)
    ball: int = 0  # 0: a hinge or slide; 1: a ball's first rotation node (holds the quaternion); 2: its others
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
        self.nv = tree.nv
        self.nu = tree.nu
        self._nodes, self._body_frame = self._build_nodes(tree)
        self._qadr, self._dadr = tree.qposadr, tree.dofadr
        self.transmissions = Transmissions(tree)
        self.na = tree.na
        self.parent = np.array([n.parent for n in self._nodes], dtype=int)
        g = np.asarray(tree.gravity, dtype=float) if tree.gravity_enabled else np.zeros(3)
        self._a_base = _const(-g)
        # per degree of freedom (a ball's or free joint's dofs share its damping and armature)
        dof_joint = [tree.joints[nd.dof] for nd in self._nodes]
        self._damping = [j.damping if tree.damping_enabled else 0.0 for j in dof_joint]
        self._stiffness = [
            j.stiffness if tree.springs_enabled and j.type in ("hinge", "slide") else 0.0 for j in dof_joint
        ]
        self._springref = [j.springref for j in dof_joint]
        self._armature = [j.armature for j in dof_joint]
        if any(j.stiffness and j.type in ("ball", "free") for j in tree.joints) and tree.springs_enabled:
            raise ValueError("stiffness on a ball or free joint is not supported")
        self._tendons = [
            t for t in tree.tendons if (t.stiffness and tree.springs_enabled) or (t.damping and tree.damping_enabled)
        ]
        # gravity compensation: the force -s m g at each body's COM (bodies welded to the world feel none);
        # MuJoCo computes it with the passive forces, so it is off when springs and dampers both are
        gravity_on = (
            tree.gravity_enabled
            and bool(np.any(np.asarray(tree.gravity) != 0.0))
            and (tree.springs_enabled or tree.damping_enabled)
        )
        self._gravcomp = [
            (b, -body.gravcomp * body.mass * np.asarray(tree.gravity, dtype=float))
            for b, body in enumerate(tree.bodies)
            if gravity_on and body.gravcomp and body.mass and self._body_frame[b][0] >= 0
        ]
        # joints whose compensation MuJoCo routes through the actuators lose it with actuation disabled
        self._gravcomp_joints = {
            i for i, nd in enumerate(self._nodes) if tree.actuation_enabled or not tree.joints[nd.dof].actgravcomp
        }
        # children lists give each column of M its moving subtree
        self._subtree = [self._descendants(i) for i in range(self.nv)]

    # ------------------------------------------------------------- structure
    @staticmethod
    def _build_nodes(tree: ModelTree) -> tuple[list[_Node], list[tuple[int, np.ndarray, np.ndarray]]]:
        """The joint nodes, and each body's frame ``(node or -1, R, p)`` in its node's frame."""
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
                if jt.type in ("ball", "free"):
                    node, R, p = _ball_nodes(tree, nodes, j, node, R, p)
                    continue
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
                        qadr=tree.qposadr[j],
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
        order = list(dict.fromkeys(n.dof for n in nodes))
        if order != list(range(len(tree.joints))):  # MuJoCo numbers dofs in body order
            raise ValueError(f"joints are not in tree order: {order}")
        return nodes, frame

    def _descendants(self, i: int) -> list[int]:
        out = [i]
        for k in range(i + 1, self.nv):
            if self._nodes[k].parent in out:
                out.append(k)
        return out

    # ----------------------------------------------------------- kinematics
    def _joint_transforms(self, q: Sequence[Scalar], ops: Ops) -> Transforms:
        """Each node's ``(R (3, 3), p (3,))`` in its parent node frame at ``q``."""
        out = []
        for nd in self._nodes:
            R0 = [_const(r) for r in nd.R0]
            p0 = _const(nd.p0)
            if nd.ball == 2:
                out.append((R0, p0))
                continue
            if nd.ball == 1:
                Rq = quat_matrix(q[nd.qadr : nd.qadr + 4])
                out.append(([[_dot(R0[r], [Rq[0][c], Rq[1][c], Rq[2][c]]) for c in range(3)] for r in range(3)], p0))
                continue
            ax = _const(nd.axis)
            qi = q[nd.qadr]
            th = _sub(qi, nd.qpos0) if nd.qpos0 != 0.0 else qi
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

    def world_frames(self, X: Transforms) -> Transforms:
        """Each node's world ``(R (3, 3), p (3,))`` from the node transforms ``X`` (forward kinematics)."""
        out: list[tuple[list[list[Scalar]], list[Scalar]]] = []
        for i, nd in enumerate(self._nodes):
            R, p = X[i]
            if nd.parent < 0:
                out.append((R, p))
                continue
            Rp, pp = out[nd.parent]
            Rw = [[_dot(Rp[r], [R[0][c], R[1][c], R[2][c]]) for c in range(3)] for r in range(3)]
            out.append((Rw, _vadd(pp, _matvec(Rp, p))))
        return out

    def body_frame(
        self, W: Transforms, body: int, pos: ArrayLike = (0.0, 0.0, 0.0), quat: ArrayLike = (1.0, 0.0, 0.0, 0.0)
    ) -> tuple[int, list[list[Scalar]], list[Scalar]]:
        """A frame fixed on ``body`` at ``pos``/``quat`` (body frame) in world coordinates.

        Args:
            W: World node frames (:meth:`world_frames`).
            body: Body index.
            pos: Frame origin in the body frame ``(3,)``.
            quat: Frame orientation in the body frame ``(w, x, y, z)``.

        Returns:
            ``(node, R (3, 3), p (3,))``: the node the frame moves with (-1: welded to the world) and
            the frame's world orientation and origin.
        """
        node, Rb, pb = self._body_frame[body]
        Rl = Rb @ quat_to_mat(quat)
        pl = pb + Rb @ np.asarray(pos, dtype=float)
        if node < 0:
            return node, [_const(r) for r in Rl], _const(pl)
        Rn, pn = W[node]
        Rl_ = [_const(r) for r in Rl]
        R = [[_dot(Rn[r], [Rl_[0][c], Rl_[1][c], Rl_[2][c]]) for c in range(3)] for r in range(3)]
        return node, R, _vadd(pn, _matvec(Rn, _const(pl)))

    def point_jacobian(
        self, W: Transforms, node: int, point: Sequence[Scalar]
    ) -> tuple[list[list[Scalar] | None], list[list[Scalar] | None]]:
        r"""Point and angular Jacobian columns of a point moving with ``node``.

        Column ``k`` for each ancestor joint ``k`` of ``node`` (the node itself included), with
        world axis ``z_k`` and origin ``o_k``: hinge ``(z_k × (p − o_k), z_k)``, slide ``(z_k, 0)``;
        None (a structural zero) for the other joints, and for every joint when ``node`` is -1.

        Args:
            W: World node frames (:meth:`world_frames`).
            node: The node the point moves with (-1: the world).
            point: World position of the point ``(3,)``.

        Returns:
            ``(Jp, Jw)``: lists of ``nq`` columns, each a 3-list or None.
        """
        Jp: list[list[Scalar] | None] = [None] * self.nv
        Jw: list[list[Scalar] | None] = [None] * self.nv
        k = node
        while k >= 0:
            nd = self._nodes[k]
            R, o = W[k]
            z = _matvec(R, _const(nd.axis))
            if nd.slide:
                Jp[k] = z
            else:
                Jp[k] = _cross(z, [_sub(point[i], o[i]) for i in range(3)])
                Jw[k] = z
            k = nd.parent
        return Jp, Jw

    def site_frame(self, W: Transforms, site: int, at: Sequence[Scalar] | None = None) -> SiteFrame:
        """World origin, orientation and Jacobian columns of a site (see :data:`SiteFrame`).

        ``at``: the world point whose point Jacobian (moving with the site's body) is returned;
        default the site's origin.
        """
        s = self.tree.sites[site]
        node, R, p = self.body_frame(W, s.body, s.pos, s.quat)
        Jp, Jw = self.point_jacobian(W, node, p if at is None else at)
        return p, R, Jp, Jw

    def frame_jacobian(
        self, q: Sequence[Scalar], body: int, pos: ArrayLike = (0.0, 0.0, 0.0), ops: Ops = NUMPY_OPS
    ) -> tuple[list[Scalar], list[list[Scalar]], list[list[Scalar]], list[list[Scalar]]]:
        """World position, orientation and dense Jacobians of a point fixed on ``body``.

        Returns:
            ``(p (3,), R (3, 3), Jp (3, nq), Jw (3, nq))`` as nested lists (``ṗ = Jp q̇``, ``ω = Jw q̇``
            in the world frame).
        """
        W = self.world_frames(self._joint_transforms(q, ops))
        node, R, p = self.body_frame(W, body, pos)
        Jp, Jw = self.point_jacobian(W, node, p)

        def dense(cols: list[list[Scalar] | None]) -> list[list[Scalar]]:
            return [[0.0 if c is None else c[r] for c in cols] for r in range(3)]

        return p, R, dense(Jp), dense(Jw)

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
        n = self.nv
        zero3 = [0.0, 0.0, 0.0]
        w: list[list[Scalar]] = [zero3] * n
        al: list[list[Scalar]] = [zero3] * n
        a: list[list[Scalar]] = [zero3] * n
        f: list[list[Scalar]] = [zero3] * n
        m_: list[list[Scalar]] = [zero3] * n
        wb: list[list[Scalar]] = [zero3] * n  # a ball's rate before the joint, in its frame
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
                # a ball's velocity product uses the rate before the joint (see _ball_nodes)
                wb[i] = wb[pi] if nd.ball == 2 and pi in moving else wpl
                w[i] = _vadd(wpl, vj)
                al[i] = _vadd(alpl, _cross(wb[i], vj), aj)
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
        n = self.nv
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
        return self._rnea(X, qd, [0.0] * self.nv, self._a_base)

    def actuator_forces(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        u: Sequence[Scalar],
        active: Sequence[int],
        act: Sequence[Scalar] = (),
        ops: Ops = NUMPY_OPS,
        W: Transforms | None = None,
    ) -> list[Scalar]:
        """Generalized actuator forces ``(nq,)`` of the actuators ``active`` driven by ``u``.

        Actuators not in ``active`` get control 0 (their bias still acts); actuators with
        activation dynamics are driven by their activation ``act (na,)`` instead (see
        :mod:`~shinro_ctrl.multibody.transmission`).
        """
        tr = self.transmissions
        inputs = tr.actuator_inputs(u, act, active)
        frames: dict[int, SiteFrame] = {}

        def site(s: int, at: Sequence[Scalar] | None = None) -> SiteFrame:
            nonlocal W
            if W is None:
                W = self.world_frames(self._joint_transforms(q, ops))
            if at is not None:
                return self.site_frame(W, s, at)
            if s not in frames:
                frames[s] = self.site_frame(W, s)
            return frames[s]

        return tr.generalized_forces(q, qd, inputs, site)

    def passive_forces(self, q: Sequence[Scalar], qd: Sequence[Scalar]) -> list[Scalar]:
        r"""Joint and tendon damping and spring forces ``(nq,)``.

        ``−b ⊙ q̇ − k ⊙ (q − q_spring) + Σ_t c_t (−k_t (L_t − L_{s,t}) − b_t L̇_t)`` over the fixed
        tendons ``t`` (length ``L_t = c_tᵀ q``).
        """
        tau = [
            _sub(
                _mul(-self._damping[i], qd[i]) if self._damping[i] else 0.0,
                _mul(self._stiffness[i], _sub(q[self._nodes[i].qadr], self._springref[i]))
                if self._stiffness[i]
                else 0.0,
            )
            for i in range(self.nv)
        ]
        for t in self._tendons:
            k = t.stiffness if self.tree.springs_enabled else 0.0
            b = t.damping if self.tree.damping_enabled else 0.0
            force = _sub(
                _mul(-k, _sub(tendon_length(t, q, self._qadr), t.springlength)) if k else 0.0,
                _mul(b, tendon_velocity(t, qd, self._dadr)) if b else 0.0,
            )
            for j, c in zip(t.joints, t.coefs, strict=True):
                tau[self._dadr[j]] = _add(tau[self._dadr[j]], _mul(c, force))
        return tau

    def gravity_compensation(self, W: Transforms) -> list[Scalar]:
        r"""``τ_gc = Σ_b J_{p,b}ᵀ (−s_b m_b g)`` ``(nq,)``: MuJoCo's ``gravcomp`` at each body's COM.

        Off when gravity is off or springs and dampers are both disabled (MuJoCo computes it with the
        passive forces); on a joint with ``actuatorgravcomp`` it goes through the actuators, so it is
        off there when actuation is disabled (MuJoCo then clamps it to the joint's
        ``actuatorfrcrange``: its loop only).
        """
        tau: list[Scalar] = [0.0] * self.nv
        for b, force in self._gravcomp:
            body = self.tree.bodies[b]
            node, _, c = self.body_frame(W, b, body.ipos)
            Jp, _ = self.point_jacobian(W, node, c)
            f = _const(force)
            for k, col in enumerate(Jp):
                if col is not None and k in self._gravcomp_joints:
                    tau[k] = _add(tau[k], _dot(col, f))
        return tau

    def generalized_forces(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        u: Sequence[Scalar],
        active: Sequence[int],
        act: Sequence[Scalar] = (),
        ops: Ops = NUMPY_OPS,
        X: Transforms | None = None,
    ) -> list[Scalar]:
        r"""All applied generalized forces ``τ (nq,)``: actuators, passive forces and gravity compensation.

        ``τ = τ_act(q, q̇, u, a) + τ_passive(q, q̇) + τ_gc(q)``; the forward dynamics solve
        ``(M + diag(armature)) q̈ = τ − c(q, q̇)``.
        """
        W = None
        if self._gravcomp or any(a.transmission == "site" for a in self.tree.actuators):
            W = self.world_frames(self._joint_transforms(q, ops) if X is None else X)
        ta = self.actuator_forces(q, qd, u, active, act, ops, W)
        tp = self.passive_forces(q, qd)
        out = [_add(ta[i], tp[i]) for i in range(self.nv)]
        if self._gravcomp:
            tg = self.gravity_compensation(W)
            out = [_add(out[i], tg[i]) for i in range(self.nv)]
        return out

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
        return [_add(tau[i], _mul(self._armature[i], qdd[i])) for i in range(self.nv)]

    def forward_dynamics(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        tau: Sequence[Scalar],
        ops: Ops = NUMPY_OPS,
        X: Transforms | None = None,
    ) -> list[Scalar]:
        r"""Accelerations ``q̈ = (M(q) + diag(a))⁻¹ (τ − c(q, q̇))`` ``(nq,)`` for a generalized force ``τ``.

        The one place the forward-dynamics algorithm is chosen
        (:attr:`algorithm`): ``"aba"``, the articulated-body algorithm
        (:mod:`shinro_ctrl.multibody.aba`, ``O(n)``, the default: the smaller
        expression and Jacobian), or ``"crba"``, ``M`` column by column by
        RNEA then an LDLᵀ solve (``O(n³)``; the reference it is tested
        against). Both are exact. ``X``: the node transforms at ``q`` when already built.
        """
        X = self._joint_transforms(q, ops) if X is None else X
        if self.algorithm == "aba":
            return articulated_body_accelerations(self._nodes, X, qd, tau, self._armature, self._a_base)
        M = self.mass_matrix(q, ops, X)
        for i in range(self.nv):
            M[i][i] = _add(M[i][i], self._armature[i])
        c = self.bias(q, qd, ops, X)
        return _ldl_solve(M, [_sub(tau[i], c[i]) for i in range(self.nv)])

    def accelerations(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        u: Sequence[Scalar],
        active: Sequence[int],
        ops: Ops = NUMPY_OPS,
        act: Sequence[Scalar] = (),
    ) -> list[Scalar]:
        """Forward dynamics ``q̈ = (M + diag(a))⁻¹ (τ − c)`` ``(nq,)`` with ``τ`` from :meth:`generalized_forces`."""
        X = self._joint_transforms(q, ops)
        return self.forward_dynamics(q, qd, self.generalized_forces(q, qd, u, active, act, ops, X), ops, X)

    def xdot_jacobians_sx(self, x: cs.SX, u: cs.SX, active: Sequence[int]) -> tuple[cs.SX, cs.SX]:
        r"""The exact Jacobians ``(A = ∂ẋ/∂x (nx, nx), B = ∂ẋ/∂u (nx, m))`` of :meth:`xdot_sx`, as dense ``SX``.

        Differentiating the forward dynamics through its own graph (an LDLᵀ
        solve or the articulated-body recursion) gives an expression 8-10 times
        the size of ``f``. Instead, differentiate the identity the
        accelerations satisfy, the inverse dynamics

        .. math::

            g(z, \ddot q) = (M(q) + \operatorname{diag}(a))\,\ddot q + c(q, \dot q) - \tau(q, \dot q, u, a_{act}) = 0,
            \qquad z = (q, \dot q, a_{act}, u),

        so that, with ``M̃ = M + diag(a)`` factored once (LDLᵀ, the same
        factors give ``q̈``),

        .. math::

            \frac{\partial \ddot q}{\partial z} = -\tilde M^{-1}\,
                \frac{\partial g}{\partial z}\Big|_{\ddot q = f(z)}

        where ``∂g/∂z`` is the reverse-mode derivative of RNEA (``O(n)``
        nodes per row) with ``q̈`` held as a symbol, then replaced by its
        expression. Exact (no truncation); the rows ``∂q̇/∂x = [0, I, 0]`` are
        constants and the activation rows ``∂ȧ/∂(x, u)`` (affine) are differentiated directly.

        Args:
            x: State symbols ``(2nq + na,)`` ``[q; q̇; a_act]``.
            u: Input symbols ``(len(active),)``.
            active: The actuators ``u`` drives (see :meth:`actuator_forces`).
        """
        nq, n, m, na = self.nq, self.nv, len(active), self.na
        q = [x[i] for i in range(nq)]
        qd = [x[nq + i] for i in range(n)]
        act = [x[nq + n + i] for i in range(na)]
        uu = [u[k] for k in range(m)]
        a = cs.SX.sym("qdd", n)
        X = self._joint_transforms(q, CASADI_OPS)
        tau = self.generalized_forces(q, qd, uu, active, act, CASADI_OPS, X)
        inv = self.inverse_dynamics(q, qd, [a[i] for i in range(n)], CASADI_OPS, X)
        g = cs.vertcat(*[cs.SX(_sub(inv[i], tau[i])) for i in range(n)])
        z = cs.vertcat(x, u)
        # (n, 2n + na + m), affine in the symbol q̈; one reverse sweep per row: ~20 % fewer nodes than cs.jacobian
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

        nx = nq + n + na
        cols = [
            cs.vertcat(*[cs.SX(v) for v in _ldl_back(L, D, [entry(i, j) for i in range(n)])]) for j in range(nx + m)
        ]
        Y = cs.horzcat(*cols)
        if nq == n:
            top = cs.horzcat(cs.SX.zeros(n, n), cs.SX.eye(n), cs.SX.zeros(n, na))
        else:  # the quaternion rates ½ q ⊗ (0, ω) (configuration.qpos_rate)
            top = cs.jacobian(cs.vertcat(*[cs.SX(v) for v in qpos_rate(self.tree, q, qd)]), x)
        A = cs.vertcat(top, Y[:, :nx])
        B = cs.vertcat(cs.SX.zeros(nq, m), Y[:, nx:])
        if na:
            adot = cs.vertcat(*[cs.SX(v) for v in self.transmissions.activation_rates(uu, act, active)])
            A = cs.vertcat(A, cs.jacobian(adot, x))
            B = cs.vertcat(B, cs.jacobian(adot, u))
        return cs.densify(A), cs.densify(B)

    def xdot_sx(self, x: cs.SX, u: cs.SX, active: Sequence[int]) -> cs.SX:
        """``ẋ = [q̇; q̈; ȧ]`` as a CasADi ``SX`` column from ``x = [q; q̇; a] (2nq + na,)`` and ``u (len(active),)``."""
        nq, n, na = self.nq, self.nv, self.na
        q = [x[i] for i in range(nq)]
        qd = [x[nq + i] for i in range(n)]
        act = [x[nq + n + i] for i in range(na)]
        uu = [u[k] for k in range(len(active))]
        qdd = self.accelerations(q, qd, uu, active, CASADI_OPS, act)
        adot = self.transmissions.activation_rates(uu, act, active)
        rate = qd if nq == n else qpos_rate(self.tree, q, qd)
        return cs.vertcat(*[cs.SX(v) if isinstance(v, float | int) else v for v in (*rate, *qdd, *adot)])

    def xdot_numpy(self, x: ArrayLike, u: ArrayLike, active: Sequence[int]) -> np.ndarray:
        """``ẋ (2nq + na,)`` evaluated directly on numbers (float or complex; the complex-step path)."""
        nq, n = self.nq, self.nv
        x = np.asarray(x)
        u = np.asarray(u)
        q, qd, act = list(x[:nq]), list(x[nq : nq + n]), list(x[nq + n :])
        qdd = self.accelerations(q, qd, list(u), active, NUMPY_OPS, act)
        adot = self.transmissions.activation_rates(list(u), act, active)
        rate = qd if nq == n else qpos_rate(self.tree, q, qd)
        return np.array([*rate, *qdd, *adot], dtype=np.result_type(x, u, float))

    # ---------------------------------------------- frame kinematics (equality and contact constraints)
    def transforms(self, q: Sequence[Scalar], ops: Ops = NUMPY_OPS) -> Transforms:
        """Each joint node's ``(R (3, 3), p (3,))`` in its parent node frame at ``q``.

        Pass the result as ``X`` to :meth:`mass_matrix`, :meth:`bias` and :meth:`frame_pose` to build the
        transforms once for several quantities at the same ``q``.
        """
        return self._joint_transforms(q, ops)

    def body_placement(self, body: int) -> tuple[int, np.ndarray, np.ndarray]:
        """Where body ``body``'s frame is fixed: ``(node, R (3, 3), p (3,))``, its pose in that node's frame.

        ``node`` is the index of the last joint node at or above the body (-1: the body is welded to the
        world, and ``R``, ``p`` are its world pose).
        """
        return self._body_frame[body]

    def frame_pose(
        self,
        q: Sequence[Scalar],
        body: int,
        pos: ArrayLike = (0.0, 0.0, 0.0),
        quat: ArrayLike = (1.0, 0.0, 0.0, 0.0),
        ops: Ops = NUMPY_OPS,
        X: Transforms | None = None,
    ) -> tuple[list[list[Scalar]], list[Scalar]]:
        """World pose ``(R (3, 3), p (3,))`` at ``q`` of a frame fixed to body ``body`` (0: the world).

        Args:
            q: Joint coordinates ``(nq,)`` (floats, complex numbers or ``SX``).
            body: Body index (MuJoCo's order).
            pos: The frame's origin in the body frame ``(3,)`` [m].
            quat: The frame's orientation in the body frame ``(w, x, y, z)``.
            ops: ``sin``/``cos`` of the number type.
            X: Node transforms already computed at ``q`` (else computed here).

        Returns:
            ``R`` and ``p`` as nested lists of scalars: ``p_world = p + R v`` for a point ``v`` of the frame.
        """
        node, Rb, pb = self.body_placement(body)
        R = [_const(r) for r in Rb @ quat_to_mat(np.asarray(quat, dtype=float))]
        p = _const(pb + Rb @ np.asarray(pos, dtype=float))
        if node >= 0 and X is None:
            X = self._joint_transforms(q, ops)
        while node >= 0:
            Rn, pn = X[node]
            p = _vadd(pn, _matvec(Rn, p))
            R = [[_dot(Rn[r], [R[0][c], R[1][c], R[2][c]]) for c in range(3)] for r in range(3)]
            node = self._nodes[node].parent
        return R, p


def _ball_nodes(
    tree: ModelTree, nodes: list[_Node], j: int, node: int, R: np.ndarray, p: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray]:
    r"""Append the nodes of ball or free joint ``j``; return the body frame after it ``(node, R, p)``.

    A free joint is three slides along the world axes (``qvel[0:3]``: the world velocity of the
    body origin, ``qpos[0:3]`` its world position; MuJoCo ignores the body's ``pos``/``quat`` then)
    followed by a ball at the body origin. A ball is three rotation nodes with the body's axes
    ``e_x, e_y, e_z`` at one origin: the first is rotated by the quaternion ``qpos[a:a+4]``
    (``R = R_0 R(q)``), the others by nothing, so the body's angular velocity in its own frame is
    ``ω = Σ e_k q̇_k = qvel[d:d+3]`` (MuJoCo's body-frame convention). The velocity-product terms
    of the rotation nodes use the angular velocity *before* the joint (``c = ω_λ × S q̇``, the true
    spherical joint's, since ``S`` is constant in the body frame), never the partial sums a chain
    of hinges would give (:mod:`~shinro_ctrl.multibody.aba`, :meth:`_rnea`).
    """
    jt = tree.joints[j]
    a = tree.qposadr[j]
    eye = np.eye(3)
    if jt.type == "free":
        if node >= 0:
            raise ValueError(f"free joint '{jt.name}' is not on a child of the world")
        for k in range(3):
            nodes.append(
                _Node(
                    parent=node,
                    dof=j,
                    slide=True,
                    R0=eye.copy(),
                    p0=np.zeros(3),
                    axis=eye[k].copy(),
                    qpos0=0.0,
                    qadr=a + k,
                )
            )
            node = len(nodes) - 1
        R, p, anchor, a = eye, np.zeros(3), np.zeros(3), a + 3
    else:
        anchor = np.asarray(jt.pos, dtype=float)
    for k in range(3):
        first = k == 0
        nodes.append(
            _Node(
                parent=node,
                dof=j,
                slide=False,
                R0=R.copy() if first else eye.copy(),
                p0=(p + R @ anchor) if first else np.zeros(3),
                axis=eye[k].copy(),
                qpos0=0.0,
                qadr=a,
                ball=1 if first else 2,
            )
        )
        node = len(nodes) - 1
    return node, eye, -anchor
