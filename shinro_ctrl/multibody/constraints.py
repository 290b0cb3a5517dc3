r"""Exact constrained dynamics of a kinematic tree with holonomic equality constraints.

A :class:`Constraint` describes one holonomic constraint ``φ(q) = 0`` on the
joint coordinates of a :class:`~shinro_ctrl.multibody.RigidBodyTree`:

* ``joint``: a joint coupling, MuJoCo's ``<equality><joint>`` (a URDF ``<mimic>``
  becomes one): ``(q₁ − q₁⁰) − P(q₂ − q₂⁰) = 0`` with the quartic
  ``P(s) = c₀ + c₁ s + c₂ s² + c₃ s³ + c₄ s⁴`` (``q⁰`` the model's ``qpos0``), or
  ``q₁ − q₁⁰ − c₀ = 0`` without a second joint; one row;
* ``connect``: a point of one body held to a point of another (or of the world), MuJoCo's
  ``<connect>`` (a closed kinematic loop; a point contact is a connect to the world):
  ``p₁(q) − p₂(q) = 0`` in world coordinates; three rows;
* ``weld``: a frame of one body held to a frame of another, MuJoCo's ``<weld>`` (a flat
  foot is a weld to the world): the three position rows of ``connect`` and three
  orientation rows ``½ vee(R₂ᵀR₁ − R₁ᵀR₂)`` (zero when the frames' axes coincide; MuJoCo's
  ``torquescale = 0`` drops them).

:class:`ConstrainedDynamics` turns a tree and its constraints into the index-1
KKT system (exact, in CasADi ``SX``)

.. math::

    \begin{bmatrix} M + \operatorname{diag}(a) & J^\top \\ J & 0 \end{bmatrix}
    \begin{bmatrix} \ddot q \\ -\lambda \end{bmatrix}
    = \begin{bmatrix} \tau - c \\ -\dot J \dot q \end{bmatrix},
    \qquad J = \partial\varphi/\partial q,

i.e. ``(M + diag(a)) q̈ + c = τ + Jᵀλ`` and ``J q̈ + J̇ q̇ = 0``: ``λ`` are the
constraint forces along the rows (for ``connect``, the world-frame force on body 1's
point; body 2 feels ``−λ``), ``τ`` the applied forces (actuators, joint and tendon
springs and dampers, gravity compensation: :meth:`RigidBodyTree.generalized_forces`). It is
solved by the Schur complement ``q̈ = q̈_f + M⁻¹Jᵀλ`` with ``q̈_f = M⁻¹(τ − c)`` and
``(J M⁻¹ Jᵀ) λ = −J̇q̇ − J q̈_f``, both by LDLᵀ. ``J`` and ``J̇q̇ = ∂(J q̇)/∂q · q̇``
are exact symbolic derivatives of ``φ``, built from the tree's frame kinematics
(:meth:`RigidBodyTree.frame_pose`).

**Redundant rows** (a planar loop closed by a 3-row ``connect``, two contact points on a
welded sole) are removed once, at build time: a column-pivoted QR of ``Jᵀ`` at the
reference configuration keeps ``r = rank J`` rows (relative tolerance ``1e-9``); the
kept rows have the same null space, so the motion is the same and ``J M⁻¹ Jᵀ`` is
invertible. The rank is that of the reference configuration: a model designed at a
singular configuration of its loop is refused by the coordinate choice below.

**Coordinates.** The constraints leave ``nᵢ = nq − r`` coordinates free. A greedy
column-pivoted QR of the kept rows at the reference picks ``r`` *dependent* joints
``D`` (``J_D`` best conditioned; preferring the follower joint of a ``joint``
coupling, then joints without an actuator, within a factor 10 of the best pivot);
the others are the *independent* joints ``I``. The design state is
``x = [q_I; q̇_I]``; the full state follows from it:

* ``q_D`` solves ``φ(q_I, q_D) = 0`` by Newton's method (:meth:`ConstrainedDynamics.complete`),
  continued from the reference in stages of at most :data:`CONTINUATION_STEP` with a
  first-order predictor, so that the answer depends on ``q_I`` alone (never on earlier
  calls) and stays on the reference's assembly branch;
* ``q̇ = S(q) q̇_I`` with the null-space basis ``S = [I; −J_D⁻¹ J_I]`` (rows ordered by ``I``, ``D``).

**Floating bases (ball and free joints).** With quaternions ``nq ≠ nv``: everything above lives in
the tangent space. ``q̇`` is replaced by the tangent velocity ``v (nv,)`` (MuJoCo's ``qvel``), with
``q̇ = E(q) v``; the Jacobian is ``J = ∂φ/∂q · E(q) (r, nv)`` and ``J̇v = ∂(J v)/∂q · E(q) v``, both
exact; the KKT system is on ``(M, J)`` over ``nv``; the pivoted QR chooses among the ``nv`` tangent
directions, a ball's or free joint's rotations always dependent (refused, in one line, when the
constraints leave one free), so the independent directions are plain coordinates (``q̇_I = v_I``);
Newton steps on the dependent directions are taken on the manifold, ``q ← q ⊕ δ_D``
(:func:`~shinro_ctrl.multibody.configuration.integrate`), and ``∂q̈_I/∂q_I = (∂q̈_I/∂q) E S``.
Without quaternions ``E = I`` and this is the formulation above.

The reduced dynamics ``ẋ = [q̇_I; q̈_I(q, S q̇_I, u)]`` and their exact Jacobians
come from the implicit function theorem: on the constraint manifold
``∂q/∂q_I = S``, so ``∂q̈_I/∂q_I = (∂q̈_I/∂q) S`` with every term an explicit
``SX`` expression of the full ``q`` (no iteration is differentiated).
:meth:`ConstrainedDynamics.symbolic_xdot` (for NMPC, collocation, the EKF) is the
same expression with ``q_D`` from a fixed number of Newton steps unrolled in ``SX``
(:data:`SYMBOLIC_NEWTON_STEPS`): equal to the exact one once Newton has converged,
i.e. near the reference's assembly branch.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as cs
import numpy as np
import scipy.linalg

from shinro_ctrl._scalar_algebra import _ldl_solve
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.multibody.configuration import integrate, integrate_sx, plain_indices, qpos_rate, quaternion_slices
from shinro_ctrl.multibody.rigid_body import CASADI_OPS, RigidBodyTree
from shinro_ctrl.multibody.tree import ModelTree

__all__ = ["CONSTRAINT_KINDS", "SYMBOLIC_NEWTON_STEPS", "ConstrainedDynamics", "Constraint"]

#: The constraint kinds :class:`Constraint` describes.
CONSTRAINT_KINDS = ("joint", "connect", "weld")
#: Newton steps unrolled in :meth:`ConstrainedDynamics.symbolic_xdot`.
SYMBOLIC_NEWTON_STEPS = 4
#: Residual ``max|φ|`` [m or rad] below which a configuration satisfies the constraints.
TOLERANCE = 1e-9
#: Newton steps per call of the compiled Newton function (:meth:`ConstrainedDynamics.complete` repeats calls).
NEWTON_UNROLL = 2
#: Largest change [m or rad] of an independent coordinate per continuation stage (:meth:`ConstrainedDynamics.complete`).
CONTINUATION_STEP = 0.25
#: Relative tolerance of the rank decisions (redundant rows, dependent joints).
RANK_RTOL = 1e-9


def _identity_quat() -> np.ndarray:
    return np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class Constraint:
    """One holonomic constraint ``φ(q) = 0`` (see the module docstring for each kind).

    Attributes:
        kind: ``"joint"``, ``"connect"`` or ``"weld"``.
        label: How messages name it, e.g. ``"equality 'loop' (connecting body 'rocker' to body 'world')"``.
        joint1: ``joint``: the coupled (follower) joint index.
        joint2: ``joint``: the leading joint index, or -1 (``q₁`` held at ``q₁⁰ + c₀``).
        polycoef: ``joint``: ``(c₀, …, c₄)``.
        body1: ``connect``/``weld``: body index of frame 1 (0: the world).
        pos1: Frame 1's origin in body 1 ``(3,)`` [m].
        quat1: Frame 1's orientation in body 1 ``(w, x, y, z)`` (``weld`` only).
        body2: Body index of frame 2 (0: the world).
        pos2: Frame 2's origin in body 2 ``(3,)`` [m].
        quat2: Frame 2's orientation in body 2 ``(w, x, y, z)`` (``weld`` only).
        rotation: ``weld``: hold the orientation too (False: MuJoCo's ``torquescale = 0``).
    """

    kind: str
    label: str = ""
    joint1: int = -1
    joint2: int = -1
    polycoef: tuple[float, ...] = (0.0, 1.0, 0.0, 0.0, 0.0)
    body1: int = 0
    pos1: np.ndarray = field(default_factory=lambda: np.zeros(3))
    quat1: np.ndarray = field(default_factory=_identity_quat)
    body2: int = 0
    pos2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    quat2: np.ndarray = field(default_factory=_identity_quat)
    rotation: bool = True

    def __post_init__(self) -> None:
        if self.kind not in CONSTRAINT_KINDS:
            raise InvalidArgument(f"unknown constraint kind {self.kind!r}; valid: {', '.join(CONSTRAINT_KINDS)}")

    @property
    def rows(self) -> int:
        """Number of rows of ``φ``."""
        return {"joint": 1, "connect": 3}.get(self.kind, 6 if self.rotation else 3)

    def residual(self, rb: RigidBodyTree, q: Sequence[cs.SX]) -> list[cs.SX]:
        """``φ(q)`` as a list of ``rows`` scalars (CasADi ``SX``)."""
        if self.kind == "joint":
            joints, adr = rb.tree.joints, rb.tree.qposadr  # joint index -> its qpos entry (≠ with a free root)
            s1 = q[adr[self.joint1]] - joints[self.joint1].qpos0
            if self.joint2 < 0:
                return [s1 - self.polycoef[0]]
            s2 = q[adr[self.joint2]] - joints[self.joint2].qpos0
            return [s1 - sum(c * s2**k for k, c in enumerate(self.polycoef) if c != 0.0)]
        R1, p1 = rb.frame_pose(q, self.body1, self.pos1, self.quat1, CASADI_OPS)
        R2, p2 = rb.frame_pose(q, self.body2, self.pos2, self.quat2, CASADI_OPS)
        out = [p1[k] - p2[k] for k in range(3)]
        if self.kind == "weld" and self.rotation:
            # E = R2ᵀ R1; ½ vee(E − Eᵀ) vanishes where the frames' axes coincide (and is sin θ · axis)
            E = [[sum(R2[k][a] * R1[k][b] for k in range(3)) for b in range(3)] for a in range(3)]
            out += [0.5 * (E[2][1] - E[1][2]), 0.5 * (E[0][2] - E[2][0]), 0.5 * (E[1][0] - E[0][1])]
        return [cs.SX(v) if isinstance(v, float | int) else v for v in out]


def _col(values: Sequence[object]) -> cs.SX:
    return cs.vertcat(*[cs.SX(v) if isinstance(v, float | int) else v for v in values])


def _with(q: cs.SX, idx: Sequence[int], values: cs.SX) -> cs.SX:
    """``q`` with the entries ``idx`` replaced by ``values``."""
    parts = [q[i] for i in range(q.shape[0])]
    for k, i in enumerate(idx):
        parts[i] = values[k]
    return cs.vertcat(*parts)


def _lists(A: cs.SX) -> list[list[cs.SX]]:
    return [[A[i, j] for j in range(A.shape[1])] for i in range(A.shape[0])]


class _Numeric:
    """A CasADi function evaluated on numpy arrays through one buffer (a lock serializes threads)."""

    def __init__(self, fun: cs.Function):
        if not all(fun.sparsity_out(k).is_dense() for k in range(fun.n_out())):
            # the buffers hold dense arrays: a structurally sparse output (e.g. a null-space basis with
            # structural zeros) would be written as its nonzeros only, in the wrong places
            sx_in = fun.sx_in()
            fun = cs.Function(fun.name(), sx_in, [cs.densify(o) for o in fun.call(sx_in)])
        self.fun = fun
        self.args = [np.zeros(fun.size1_in(k) * fun.size2_in(k)) for k in range(fun.n_in())]
        self.outs = [np.zeros(fun.size1_out(k) * fun.size2_out(k)) for k in range(fun.n_out())]
        self.shapes = [fun.size_out(k) for k in range(fun.n_out())]
        self.buf, self.run = fun.buffer()
        for k, a in enumerate(self.args):
            self.buf.set_arg(k, memoryview(a))
        for k, o in enumerate(self.outs):
            self.buf.set_res(k, memoryview(o))
        self.lock = threading.Lock()

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        with self.lock:
            for a, v in zip(self.args, args, strict=True):
                a[:] = v
            self.run()
            return [o.reshape(s, order="F").copy() for o, s in zip(self.outs, self.shapes, strict=True)]


def _dof_joint(tree: ModelTree) -> list[int]:
    """The joint of each degree of freedom."""
    out: list[int] = []
    for j, joint in enumerate(tree.joints):
        out += [j] * {"hinge": 1, "slide": 1, "ball": 3, "free": 6}[joint.type]
    return out


def _dof_armature(tree: ModelTree) -> list[float]:
    """Each degree of freedom's armature (a ball's or free joint's dofs share their joint's)."""
    return [tree.joints[j].armature for j in _dof_joint(tree)]


class ConstrainedDynamics:
    """Exact dynamics of a tree under holonomic constraints, in the coordinates they leave free.

    See the module docstring for the formulation (KKT by Schur complement, redundant rows
    removed at the reference, independent coordinates by pivoted QR, Newton completion,
    Jacobians by the implicit function theorem).

    Args:
        rb: The tree's equations of motion.
        constraints: The constraints (at least one).
        active: Indices of the actuators that are the inputs ``u``.
        q_ref: Reference configuration ``(nq,)``; projected onto the constraints first
            (:meth:`project`). The row and coordinate choices are made there.
        what: How messages name ``q_ref`` (e.g. ``"MjcfPlant('arm.xml'): keyframe 'home'"``).

    Attributes:
        constraints: The constraints.
        q_ref: The projected reference configuration ``(nq,)``.
        rows: Indices of the kept (independent) rows of the stacked ``φ``.
        independent: Independent joint indices ``I`` (ascending).
        dependent: Dependent joint indices ``D``.
        ni: ``len(independent)``.

    Raises:
        InvalidArgument: ``q_ref`` cannot be projected onto the constraints (naming the
            constraint with the largest residual); the constraints leave no free motion;
            the loop is singular at the reference.
    """

    def __init__(
        self,
        rb: RigidBodyTree,
        constraints: Sequence[Constraint],
        *,
        active: Sequence[int],
        q_ref: np.ndarray,
        what: str = "the reference configuration",
    ):
        if not constraints:
            raise InvalidArgument("ConstrainedDynamics needs at least one constraint")
        self.rb = rb
        self.constraints = tuple(constraints)
        nq = self.nq = rb.nq
        n = self.nv = rb.nv
        tree = rb.tree
        # flat tangent directions (hinge, slide, a free joint's translation): q̇ = v there; the rest are rotations
        flat_q, flat_v = plain_indices(tree)
        self._qof = dict(zip(flat_v, flat_q, strict=True))  # dof -> its qpos index (flat dofs only)
        self._rotational = tuple(d + k for _, d in quaternion_slices(tree) for k in range(3))
        self._row_owner = [k for k, c in enumerate(self.constraints) for _ in range(c.rows)]
        q = cs.SX.sym("q", nq)
        qd = cs.SX.sym("qd", n)
        u = cs.SX.sym("u", len(active))
        ql = [q[i] for i in range(nq)]
        phi = cs.vertcat(*[v for c in self.constraints for v in c.residual(rb, ql)])
        # tangent-space Jacobian J = ∂φ/∂q · E(q), E the map q̇ = E(q) v (identity without quaternions)
        rate = cs.vertcat(
            *[cs.SX(r) if isinstance(r, float | int) else r for r in qpos_rate(tree, ql, [qd[i] for i in range(n)])]
        )
        E = cs.jacobian(rate, qd)
        J = cs.mtimes(cs.jacobian(phi, q), E)
        self._phi = _Numeric(cs.Function("phi", [q], [phi, cs.densify(J)]))
        self.q_ref = self.project(np.asarray(q_ref, dtype=float), what=what)

        _, J0 = self._phi(self.q_ref)
        rows, self.dependent = self._choose(J0, constraints, rb, active)
        self.rows = rows
        self.independent = tuple(i for i in range(n) if i not in self.dependent)
        self.ni = len(self.independent)
        #: qpos indices of the independent tangent directions (all flat: q̇_I = v_I)
        self.independent_q = tuple(self._qof[i] for i in self.independent)
        r = len(rows)
        Jr = J[list(rows), :]
        phir = phi[list(rows)]
        # KKT by the Schur complement (module docstring)
        X = rb.transforms(ql, CASADI_OPS)
        M = rb.mass_matrix(ql, CASADI_OPS, X)
        for i, arm in enumerate(_dof_armature(tree)):
            M[i][i] = M[i][i] + arm
        qdl = [qd[i] for i in range(n)]
        c = rb.bias(ql, qdl, CASADI_OPS, X)
        tau = rb.generalized_forces(ql, qdl, [u[k] for k in range(len(active))], active, (), CASADI_OPS, X)
        qdd_f = _col(_ldl_solve(M, [tau[i] - c[i] for i in range(n)]))
        MinvJT = cs.horzcat(*[_col(_ldl_solve(M, [Jr[k, j] for j in range(n)])) for k in range(r)])
        jdqd = cs.jtimes(cs.mtimes(Jr, qd), q, rate)  # J̇v = ∂(J v)/∂q · q̇, exact
        schur = cs.mtimes(Jr, MinvJT)
        rhs = -jdqd - cs.mtimes(Jr, qdd_f)
        lam = _col(_ldl_solve(_lists(schur), [rhs[k] for k in range(r)]))
        qdd = qdd_f + cs.mtimes(MinvJT, lam)
        self.kkt_function = cs.Function("kkt", [q, qd, u], [qdd, lam], ["q", "qd", "u"], ["qdd", "lam"])
        # reduced coordinates
        ind, dep = list(self.independent), list(self.dependent)
        vi = cs.SX.sym("vi", self.ni)
        S = cs.SX.zeros(n, self.ni)  # tangent null-space basis
        for a, i in enumerate(ind):
            S[i, a] = 1.0
        SD = -cs.solve(Jr[:, dep], Jr[:, ind])
        for b, d in enumerate(dep):
            S[d, :] = SD[b, :]
        qdd_v, _ = self.kkt_function(q, cs.mtimes(S, vi), u)
        F = qdd_v[ind]
        A = cs.vertcat(
            cs.horzcat(cs.SX.zeros(self.ni, self.ni), cs.SX.eye(self.ni)),
            cs.horzcat(cs.mtimes(cs.mtimes(cs.jacobian(F, q), E), S), cs.jacobian(F, vi)),
        )
        B = cs.vertcat(cs.SX.zeros(self.ni, u.shape[0]), cs.jacobian(F, u))
        self.reduced_function = cs.Function("f_reduced", [q, vi, u], [cs.vertcat(vi, F)], ["q", "vi", "u"], ["xdot"])
        self.jacobian_function = cs.Function(
            "jac_reduced", [q, vi, u], [cs.densify(A), cs.densify(B)], ["q", "vi", "u"], ["A", "B"]
        )
        self._f = _Numeric(self.reduced_function)
        self._jac = _Numeric(self.jacobian_function)
        self._nu = len(active)
        self._symbolic: cs.Function | None = None
        self._build_lock = threading.Lock()
        self._phir = cs.Function("phir", [q], [phir, cs.densify(Jr)])
        # NEWTON_UNROLL Newton steps on q_D per call, with max|φ| (all rows), q̇ = S q̇_I and ∂q_D/∂q_I at the result
        phi_fun = cs.Function("phi_all", [q], [phi])
        S_fun = cs.Function("S", [q], [S])
        qn = q
        for _ in range(NEWTON_UNROLL):  # Newton in the dependent tangent directions, on the manifold
            phin, Jn = self._phir(qn)
            qn = self._step_sx(qn, -cs.solve(Jn[:, dep], phin))
        Sn = S_fun(qn)
        self._newton = _Numeric(
            cs.Function("newton", [q, vi], [qn, cs.mtimes(Sn, vi), cs.mmax(cs.fabs(phi_fun(qn))), Sn[dep, :]])
        )
        J0r = J0[list(rows)]
        self._predict = -np.linalg.solve(J0r[:, dep], J0r[:, ind])  # ∂δ_D/∂q_I at the reference

    def _step_sx(self, q: cs.SX, dD: cs.SX) -> cs.SX:
        """``q ⊕ v`` with ``v`` zero but on the dependent tangent directions (``dD``)."""
        v = [cs.SX(0.0)] * self.nv
        for b, d in enumerate(self.dependent):
            v[d] = dD[b]
        return integrate_sx(self.rb.tree, q, cs.vertcat(*v))

    def _step(self, q: np.ndarray, dD: np.ndarray) -> np.ndarray:
        v = np.zeros(self.nv)
        v[list(self.dependent)] = dD
        return integrate(self.rb.tree, q, v)

    # ------------------------------------------------------------ choices at the reference
    def _choose(
        self, J0: np.ndarray, constraints: Sequence[Constraint], rb: RigidBodyTree, active: Sequence[int]
    ) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """Kept rows (pivoted QR of ``J0ᵀ``) and dependent joints (greedy pivoted QR of the kept rows)."""
        n = self.nv
        scale = max(float(np.abs(J0).max(initial=0.0)), 1e-300)
        _, R, piv = scipy.linalg.qr(J0.T, pivoting=True, mode="economic")
        diag = np.abs(np.diag(R)) if R.size else np.zeros(0)
        r = int(np.sum(diag > RANK_RTOL * scale))
        if r >= n:
            raise InvalidArgument(
                f"the constraints leave no free motion: {', '.join(c.label or c.kind for c in constraints)} fix "
                f"all {n} degrees of freedom (rank {r}); remove one or free a joint"
            )
        if r == 0:
            raise InvalidArgument(
                f"the constraints {', '.join(c.label or c.kind for c in constraints)} constrain no joint at the "
                "reference configuration (their Jacobian is zero)"
            )
        rows = tuple(sorted(int(k) for k in piv[:r]))
        # preference for dependent joints: followers of joint couplings (0), unactuated joints (1), others (2)
        dof_joint = _dof_joint(rb.tree)
        actuated = {rb.tree.actuators[a].joint for a in active}
        level = [1 if dof_joint[i] not in actuated else 2 for i in range(n)]
        for c in constraints:
            if c.kind == "joint":
                level[rb.tree.dofadr[c.joint1]] = 0
        for i in self._rotational:  # a ball's or free joint's rotation: dependent (its chart is not a coordinate)
            level[i] = -1
        res = J0[list(rows)].copy()
        dep: list[int] = []
        for _ in range(r):
            norms = np.linalg.norm(res, axis=0)
            norms[dep] = -1.0
            best = norms.max()
            near = [i for i in range(n) if norms[i] >= 0.1 * best]
            j = min(near, key=lambda i: (level[i], -norms[i]))
            dep.append(j)
            e = res[:, j] / norms[j]
            res -= np.outer(e, e @ res)
        JD = J0[np.ix_(rows, dep)]
        left = [i for i in self._rotational if i not in dep]
        if left:
            raise InvalidArgument(
                f"the constraints leave {len(left)} rotation(s) of a ball or free joint free (dofs {left}): "
                "a floating base held by too few contacts (at least three point contacts or one flat contact) "
                "is not supported yet"
            )
        if np.linalg.cond(JD) > 1e8:
            raise InvalidArgument(
                "the constraints are singular at the reference configuration (the loop is at a dead point): "
                "choose a keyframe away from it"
            )
        return rows, tuple(sorted(dep))

    # ------------------------------------------------------------ configurations
    def residuals(self, q: np.ndarray) -> np.ndarray:
        """``max|φ|`` of each constraint at ``q (nq,)`` (all rows, redundant ones included)."""
        phi, _ = self._phi(q)
        phi = phi.ravel()
        out = np.zeros(len(self.constraints))
        for row, k in enumerate(self._row_owner):
            out[k] = max(out[k], abs(phi[row]))
        return out

    def _violation(self, q: np.ndarray, what: str, fix: str) -> InvalidArgument:
        res = self.residuals(q)
        k = int(np.argmax(res))
        c = self.constraints[k]
        return InvalidArgument(
            f"{what} violates {c.label or c.kind} by {res[k]:.3g} (in m or rad; tolerance {TOLERANCE:g}): {fix}"
        )

    def project(self, q: np.ndarray, *, what: str = "the configuration", iterations: int = 100) -> np.ndarray:
        """The nearest configuration to ``q (nq,)`` that satisfies every constraint (minimum-norm Gauss–Newton).

        Raises:
            InvalidArgument: no satisfying configuration near ``q`` (naming the worst constraint).
        """
        q = np.array(q, dtype=float)
        for _ in range(iterations):
            phi, J = self._phi(q)
            phi = phi.ravel()
            if np.abs(phi).max(initial=0.0) < 1e-13 or not np.isfinite(phi).all():
                break
            step = np.linalg.lstsq(J, phi, rcond=None)[0]
            q = integrate(self.rb.tree, q, -step)
            if np.abs(step).max() < 1e-15:
                break
        if not np.isfinite(q).all() or self.residuals(q).max(initial=0.0) > TOLERANCE:
            raise self._violation(
                q if np.isfinite(q).all() else np.asarray(q, dtype=float),
                what,
                "no configuration near it satisfies the constraint (check the model's lengths and anchors)",
            )
        return q

    def complete(self, x: np.ndarray, *, what: str = "the state") -> np.ndarray:
        """The full state ``[q; v] (nq + nv,)`` of a design state ``x = [q_I; v_I] (2nᵢ,)``.

        The dependent tangent directions by Newton on the manifold (steps ``q ⊕ δ_D``) from the
        reference's first-order prediction, ``v = S(q) v_I``.

        Raises:
            InvalidArgument: Newton does not converge: no configuration of the reference's branch
                has these independent coordinates (naming the worst constraint).
        """
        ind, indq = list(self.independent), list(self.independent_q)
        qi = np.asarray(x[: self.ni], dtype=float)
        vi = np.asarray(x[self.ni :], dtype=float)
        q = self.q_ref.copy()
        predict = self._predict
        delta = qi - self.q_ref[indq]
        res = np.inf
        # continuation from the reference in steps of at most CONTINUATION_STEP: stays on its assembly branch
        stages = max(1, int(np.ceil(np.abs(delta).max(initial=0.0) / CONTINUATION_STEP)))
        for s in range(1, stages + 1):
            target = self.q_ref[indq] + delta * (s / stages)
            q = self._step(q, predict @ (target - q[indq]))
            q[indq] = target
            previous = np.inf
            for _ in range(25):
                qn, qd, r, predict = self._newton(q, vi)
                q, res = qn.ravel(), float(r[0, 0])
                if not np.isfinite(res) or res <= 1e-14 or res > 0.5 * previous:  # converged, or stalled
                    break
                previous = res
            if not np.isfinite(res):
                break
        if not np.isfinite(res) or res > TOLERANCE:
            names = ", ".join(f"{self.rb.tree.joints[i].name or i} = {qi[k]:.4g}" for k, i in enumerate(ind))
            raise self._violation(
                q if np.isfinite(q).all() else self.q_ref,
                f"{what} ({names})",
                "the dependent joints cannot close the constraints there (Newton failed)",
            )
        return np.concatenate([q, qd.ravel()])

    def reduce(self, x_full: np.ndarray) -> np.ndarray:
        """The design state ``[q_I; v_I]`` of a full state ``[q; v] (nq + nv,)``."""
        return np.concatenate([x_full[list(self.independent_q)], x_full[self.nq :][list(self.independent)]])

    def check_full(self, x_full: np.ndarray, what: str) -> np.ndarray:
        """A full state ``[q; q̇]`` that satisfies the constraints (position and velocity), else one-line error."""
        q, qd = x_full[: self.nq], x_full[self.nq :]
        if self.residuals(q).max() > TOLERANCE:
            raise self._violation(q, what, "give a configuration on the constraints, or only the independent joints")
        _, J = self._phi(q)
        vel = np.abs(J @ qd)
        if vel.max(initial=0.0) > TOLERANCE * max(1.0, np.abs(qd).max()):
            k = self._row_owner[int(np.argmax(vel))]
            c = self.constraints[k]
            raise InvalidArgument(
                f"{what}: its velocities violate {c.label or c.kind} (rate {vel.max():.3g}): give velocities along "
                "the constraints, or only the independent joints' velocities"
            )
        return x_full

    def project_state(self, x_full: np.ndarray, what: str) -> np.ndarray:
        """``x_full`` projected onto the constraints: positions (:meth:`project`), then velocities onto ``J q̇ = 0``."""
        q = self.project(x_full[: self.nq], what=what)
        _, J = self._phi(q)
        qd = np.asarray(x_full[self.nq :], dtype=float)
        qd = qd - np.linalg.lstsq(J, J @ qd, rcond=None)[0]
        return np.concatenate([q, qd])

    # ---------------------------------------------------------------- dynamics
    def xdot(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``ẋ = [q̇_I; q̈_I] (2nᵢ,)`` at a design state ``x`` (exact: Newton to machine precision, then KKT)."""
        full = self.complete(x)
        return self._f(full[: self.nq], x[self.ni :], u)[0].ravel()

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact ``(A (2nᵢ, 2nᵢ), B (2nᵢ, m))`` of :meth:`xdot` (implicit function theorem; module docstring)."""
        full = self.complete(x)
        A, B = self._jac(full[: self.nq], x[self.ni :], u)
        return A, B

    def accelerations(self, x_full: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(v̇ (nv,), λ (r,))`` of the KKT system at a full state ``[q; v]`` (on the constraints)."""
        qdd, lam = self.kkt_function(x_full[: self.nq], x_full[self.nq :], u)
        return qdd.full().ravel(), lam.full().ravel()

    def constraint_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(φ (R,), J (R, nv))`` at ``q (nq,)``: every row of every constraint, in order (redundant ones too).

        ``J = ∂φ/∂q · E(q)`` acts on tangent velocities ``v`` (``J = ∂φ/∂q`` without quaternions).
        """
        phi, J = self._phi(np.asarray(q, dtype=float))
        return phi.ravel(), J

    def constraint_forces(self, x_full: np.ndarray, u: np.ndarray) -> list[np.ndarray]:
        """Each constraint's force ``λ`` (its ``rows`` entries) at a full state ``[q; q̇]``: the minimum-norm split.

        The KKT system fixes ``Jᵀλ`` (the generalized constraint force) but not how redundant
        rows share it: this is the least-norm ``λ`` over all rows with ``J_allᵀλ = J_rᵀλ_r``.
        """
        _, lam_r = self.accelerations(x_full, u)
        _, J = self.constraint_jacobian(x_full[: self.nq])
        lam = np.linalg.lstsq(J.T, J[list(self.rows)].T @ lam_r, rcond=None)[0]
        out, r = [], 0
        for c in self.constraints:
            out.append(lam[r : r + c.rows])
            r += c.rows
        return out

    def symbolic_function(self) -> cs.Function:
        """:meth:`symbolic_xdot` as the ``casadi.Function`` ``f(x (2nᵢ,), u (m,)) -> xdot`` (built once)."""
        with self._build_lock:
            if self._symbolic is None:
                x, u = cs.SX.sym("x", 2 * self.ni), cs.SX.sym("u", self._nu)
                self._symbolic = cs.Function("f", [x, u], [self.symbolic_xdot(x, u)], ["x", "u"], ["xdot"])
            return self._symbolic

    def symbolic_xdot(self, x: cs.SX, u: cs.SX) -> cs.SX:
        """``ẋ`` in ``SX``, with ``q_D`` from :data:`SYMBOLIC_NEWTON_STEPS` Newton steps unrolled (module docstring)."""
        dep, indq = list(self.dependent), list(self.independent_q)
        qi = x[: self.ni]
        q = self._step_sx(cs.DM(self.q_ref), cs.mtimes(cs.DM(self._predict), qi - cs.DM(self.q_ref[indq])))
        q = _with(q, indq, qi)
        for _ in range(SYMBOLIC_NEWTON_STEPS):
            phir, Jr = self._phir(q)
            q = self._step_sx(q, -cs.solve(Jr[:, dep], phir))
        return self.reduced_function(q, x[self.ni :], u)
