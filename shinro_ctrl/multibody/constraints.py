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

**Compiled linearization** (:meth:`ConstrainedDynamics.jacobians`). Differentiating the Schur-complement
solution itself gives an expression too large to compile on a legged robot. Instead the KKT residual
``R(q, v, u; a, λ) = [RNEA(q, v, a) − τ − Jᵀλ; J a + J̇v]`` is differentiated with ``a``, ``λ`` held (reverse
mode, row by row), then ``a``, ``λ`` are replaced by the solution, so that ``∂(v̇, λ)/∂z = −K⁻¹ ∂R/∂z`` with
``K = [[M̃, −Jᵀ], [J, 0]]`` (:meth:`~ConstrainedDynamics.linearization_function`); a second small function reduces
that system on the null space ``S`` and chains ``v = S(q) v_I`` along the manifold
(:meth:`~ConstrainedDynamics.chain_function`). Both, and the Newton completion, are compiled to C once
(:mod:`shinro_ctrl.codegen`, disk cache) and evaluated through bound buffers: the 18-DOF quadruped on four feet
linearizes in under 100 µs (``benchmarks/contacts.py``). The plain ``cs.jacobian`` of the Schur solution stays
available as the reference (:attr:`~ConstrainedDynamics.jacobian_function`, virtual machine).

:meth:`ConstrainedDynamics.symbolic_xdot` (for NMPC, collocation, the EKF) is the
same expression with ``q_D`` from a fixed number of Newton steps unrolled in ``SX``
(:data:`SYMBOLIC_NEWTON_STEPS`): equal to the exact one once Newton has converged,
i.e. near the reference's assembly branch.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as cs
import numpy as np
import scipy.linalg

from shinro_ctrl._scalar_algebra import _ldl_back, _ldl_factor, _ldl_solve
from shinro_ctrl.codegen import compiled, compiled_by_key
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
#: Most continuation stages :meth:`ConstrainedDynamics.complete` takes (a state further from the reference is refused).
MAX_STAGES = 10_000
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


def _dense(fun: cs.Function) -> cs.Function:
    """``fun`` with dense outputs (itself when they are): buffers hold dense arrays."""
    if all(fun.sparsity_out(k).is_dense() for k in range(fun.n_out())):
        return fun
    sx_in = fun.sx_in()
    return cs.Function(fun.name(), sx_in, [cs.densify(o) for o in fun.call(sx_in)])


class _Numeric:
    """A CasADi function evaluated on numpy arrays through one buffer (a lock serializes threads)."""

    def __init__(self, fun: cs.Function):
        # the buffers hold dense arrays: a structurally sparse output (e.g. a null-space basis with
        # structural zeros) would be written as its nonzeros only, in the wrong places
        fun = self.fun = _dense(fun)
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


class _Linearization:
    """``(A, B)`` from the compiled :meth:`ConstrainedDynamics.linearization_function` and ``chain_function``.

    The first's output arrays are bound as the second's inputs, its inputs ``q``, ``v`` to the Newton completion's
    arrays (:attr:`newton`): no copies. The caller holds ``newton.lock``.
    """

    def __init__(self, jac: cs.Function, chain: cs.Function, newton: _NewtonBuffers, ni: int, m: int):
        chain = _dense(chain)
        self.newton = newton
        self.u = np.zeros(m)
        self.mid = [np.zeros(jac.nnz_out(k)) for k in range(jac.n_out())]  # nonzeros: the chain's inputs
        self.A = np.zeros((2 * ni, 2 * ni))
        self.B = np.zeros((2 * ni, m))
        self.jac_buf, self.run_jac = jac.buffer()
        for k, a in enumerate((newton.q, newton.v, self.u)):
            self.jac_buf.set_arg(k, memoryview(a))
        self.chain_buf, self.run_chain = chain.buffer()
        for k, a in enumerate(self.mid):
            if jac.sparsity_out(k) != chain.sparsity_in(k):
                raise ValueError(f"constrained_chain input {k} does not match constrained_jac output {k}")
            self.jac_buf.set_res(k, memoryview(a))
            self.chain_buf.set_arg(k, memoryview(a))
        for k, o in enumerate((self.A, self.B)):
            self.chain_buf.set_res(k, memoryview(o.reshape(-1)))

    def __call__(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` at the Newton buffers' ``(q, v)`` and ``u`` (fresh arrays)."""
        self.u[:] = u
        self.run_jac()
        self.run_chain()
        return self.A.copy(), self.B.copy()


class _NewtonBuffers:
    """The Newton function ``(q, δ_D, v_I) -> (q_n, v, max|φ|, S_D)`` bound to arrays it reads and writes in place.

    :meth:`ConstrainedDynamics.complete` holds :attr:`lock` while it uses them (threads share one set).
    """

    def __init__(self, fun: cs.Function):
        fun = _dense(fun)
        self.q, self.dD, self.vi = (np.zeros(fun.size1_in(k)) for k in range(3))
        self.qn, self.v, self.res = (np.zeros(fun.size1_out(k)) for k in range(3))
        self.SD = np.zeros(fun.size_out(3), order="F")
        self.buf, self.run = fun.buffer()
        for k, a in enumerate((self.q, self.dD, self.vi)):
            self.buf.set_arg(k, memoryview(a))
        for k, o in enumerate((self.qn, self.v, self.res, self.SD.reshape(-1, order="F"))):
            self.buf.set_res(k, memoryview(o))
        self.lock = threading.Lock()


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
    Jacobians by the implicit function theorem, compiled at the first :meth:`jacobians`).

    Args:
        rb: The tree's equations of motion.
        constraints: The constraints (at least one).
        active: Indices of the actuators that are the inputs ``u``.
        q_ref: Reference configuration ``(nq,)``; projected onto the constraints first
            (:meth:`project`). The row and coordinate choices are made there.
        what: How messages name ``q_ref`` (e.g. ``"MjcfPlant('arm.xml'): keyframe 'home'"``).
        compile_key: What the model's expressions depend on (its numbers and the code that builds them), as
            text: the compiled functions are then found on disk by it plus the constraints, inputs, kept rows
            and coordinates (:func:`shinro_ctrl.codegen.compiled_by_key`: a cache hit builds nothing). None:
            keyed by their generated source (built at the first :meth:`jacobians`).

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
        compile_key: str | None = None,
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
        L, D = _ldl_factor(M)  # one factorization for every right-hand side
        qdd_f = _col(_ldl_back(L, D, [tau[i] - c[i] for i in range(n)]))
        MinvJT = cs.horzcat(*[_col(_ldl_back(L, D, [Jr[k, j] for j in range(n)])) for k in range(r)])
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
        self.reduced_function = cs.Function("f_reduced", [q, vi, u], [cs.vertcat(vi, F)], ["q", "vi", "u"], ["xdot"])
        self._schur_sym = (q, vi, u, F, E, S)  # for jacobian_function (built on first use)
        self._jacobian_function: cs.Function | None = None
        self._f = _Numeric(self.reduced_function)
        self._nu = len(active)
        self._active = tuple(int(a) for a in active)
        self._compile_key = compile_key
        self._linearization: _Linearization | None = None
        self._symbolic: cs.Function | None = None
        self._build_lock = threading.Lock()
        self._phir = cs.Function("phir", [q], [phir, cs.densify(Jr)])
        # the predictor step q ⊕ δ_D, then NEWTON_UNROLL Newton steps on q_D per call, with max|φ| (all rows),
        # v = S v_I and ∂q_D/∂q_I at the result
        phi_fun = cs.Function("phi_all", [q], [phi])
        S_fun = cs.Function("S", [q], [S])
        dD = cs.SX.sym("dD", r)
        qn = self._step_sx(q, dD)
        for _ in range(NEWTON_UNROLL):  # Newton in the dependent tangent directions, on the manifold
            phin, Jn = self._phir(qn)
            qn = self._step_sx(qn, -cs.solve(Jn[:, dep], phin))
        Sn = S_fun(qn)
        self._newton_function = cs.Function(
            "constrained_newton", [q, dD, vi], [qn, cs.mtimes(Sn, vi), cs.mmax(cs.fabs(phi_fun(qn))), Sn[dep, :]]
        )
        self._newton = _NewtonBuffers(self._newton_function)
        J0r = J0[list(rows)]
        self._predict = -np.linalg.solve(J0r[:, dep], J0r[:, ind])  # ∂δ_D/∂q_I at the reference
        self._indq = np.array(self.independent_q, dtype=int)
        self._qref_I = self.q_ref[self._indq]

    def _step_sx(self, q: cs.SX, dD: cs.SX) -> cs.SX:
        """``q ⊕ v`` with ``v`` zero but on the dependent tangent directions (``dD``)."""
        v = [cs.SX(0.0)] * self.nv
        for b, d in enumerate(self.dependent):
            v[d] = dD[b]
        return integrate_sx(self.rb.tree, q, cs.vertcat(*v))

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
            joints = ", ".join(dict.fromkeys(repr(rb.tree.joints[dof_joint[i]].name or dof_joint[i]) for i in left))
            raise InvalidArgument(
                f"the constraints leave {len(left)} rotation(s) of a ball or free joint free (joint {joints}, "
                f"tangent dofs {left}): "
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
        nb = self._newton
        with nb.lock:  # the buffers are shared
            self._complete_locked(nb, x, what)
            return np.concatenate([nb.q, nb.v])

    def _complete_locked(self, nb: _NewtonBuffers, x: np.ndarray, what: str) -> None:
        """:meth:`complete` into ``nb``'s buffers (``q``, ``v``); the caller holds ``nb.lock``."""
        x = np.asarray(x, dtype=float)
        ni = self.ni
        if x.shape != (2 * ni,):
            raise InvalidArgument(f"{what}: expected the design state [q_I; v_I] of shape ({2 * ni},), got {x.shape}")
        qi, vi = x[:ni], x[ni:]
        delta = qi - self._qref_I
        far = float(np.abs(delta).max()) if ni else 0.0
        if not (math.isfinite(far) and math.isfinite(vi.sum())):
            raise InvalidArgument(f"{what} holds NaN or inf: {self._independent_names(qi, vi)}")
        if far > MAX_STAGES * CONTINUATION_STEP:  # the continuation would take too long: refuse, never hang
            raise InvalidArgument(
                f"{what} ({self._independent_names(qi)}) is {far:.3g} (m or rad) from the reference "
                f"configuration; at most {MAX_STAGES * CONTINUATION_STEP:g} is followed along its branch"
            )
        indq, q, step = self._indq, nb.q, nb.dD  # q: the Newton function's input, updated in place
        q[:] = self.q_ref
        nb.vi[:] = vi
        res = math.inf
        # continuation from the reference in steps of at most CONTINUATION_STEP: stays on its assembly branch
        stages = max(1, math.ceil(far / CONTINUATION_STEP))
        if stages == 1:  # from the reference: the first-order prediction of the dependent directions
            np.dot(self._predict, delta, out=step)
            q[indq] = qi
        for s in range(1, stages + 1):
            if stages > 1:
                target = qi if s == stages else self._qref_I + delta * (s / stages)
                step[:] = (self._predict if s == 1 else nb.SD) @ (target - q[indq])
                q[indq] = target
            previous = math.inf
            for _ in range(25):
                nb.run()
                q[:] = nb.qn
                step.fill(0.0)
                res = nb.res[0]
                if not res <= 1e-14 and res <= 0.5 * previous:  # neither converged nor stalled (nor NaN)
                    previous = res
                    continue
                break
            if not math.isfinite(res):
                break
        if not math.isfinite(res) or res > TOLERANCE:
            raise self._violation(
                q.copy() if np.isfinite(q).all() else self.q_ref,
                f"{what} ({self._independent_names(qi)})",
                "the dependent joints cannot close the constraints there (Newton failed)",
            )

    def independent_names(self) -> list[str]:
        """Each independent tangent direction named by its joint (``"knee"``; a free joint's translation ``"root y"``).

        :attr:`independent` holds tangent (``qvel``) indices, not joint indices: a free joint has six.
        """
        tree, dof_joint = self.rb.tree, _dof_joint(self.rb.tree)
        out = []
        for i in self.independent:
            j = dof_joint[i]
            joint = tree.joints[j]
            name = joint.name or f"joint {j}"
            if joint.type == "free":  # only its translations can be independent (its rotation is dependent)
                name += f" {'xyz'[i - tree.dofadr[j]]}"
            out.append(name)
        return out

    def _independent_names(self, qi: np.ndarray, vi: np.ndarray | None = None) -> str:
        """``"knee = 0.3, root y = 0.1"`` (and ``"knee_dot = …"`` with ``vi``): the values ``qi`` are the ``qpos``
        entries :attr:`independent_q`."""
        names = self.independent_names()
        parts = [f"{name} = {qi[k]:.4g}" for k, name in enumerate(names)]
        if vi is not None:
            parts += [f"{name}_dot = {vi[k]:.4g}" for k, name in enumerate(names)]
        return ", ".join(parts)

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
        """Exact ``(A (2nᵢ, 2nᵢ), B (2nᵢ, m))`` of :meth:`xdot` (implicit function theorem; module docstring).

        Compiled: the first call compiles :meth:`linearization_function`, :meth:`chain_function` and the Newton
        completion to C (:mod:`shinro_ctrl.codegen`, cached on disk; CasADi's virtual machine when no compiler
        builds them); every call completes ``x`` and evaluates the two, through buffers bound to each other.
        """
        lin = self._linearization or self._compile()
        nb = lin.newton
        with nb.lock:  # the completion's buffers are the linearization's inputs
            self._complete_locked(nb, x, "the state")
            return lin(u)

    @property
    def jacobian_function(self) -> cs.Function:
        """``(q, v_I, u) -> (A, B)``: ``cs.jacobian`` of the Schur-complement solution, in ``SX`` (built on first use).

        The reference :meth:`jacobians` is tested against: exact and the same values, but its expression
        is far larger (too large to compile on an 18-DOF robot; evaluated in CasADi's virtual machine).
        """
        with self._build_lock:
            if self._jacobian_function is None:
                q, vi, u, F, E, S = self._schur_sym
                A = cs.vertcat(
                    cs.horzcat(cs.SX.zeros(self.ni, self.ni), cs.SX.eye(self.ni)),
                    cs.horzcat(cs.mtimes(cs.mtimes(cs.jacobian(F, q), E), S), cs.jacobian(F, vi)),
                )
                B = cs.vertcat(cs.SX.zeros(self.ni, u.shape[0]), cs.jacobian(F, u))
                self._jacobian_function = cs.Function(
                    "jac_reduced", [q, vi, u], [cs.densify(A), cs.densify(B)], ["q", "vi", "u"], ["A", "B"]
                )
            return self._jacobian_function

    def linearization_function(self) -> cs.Function:
        r"""``G(q (nq,), v (nv,), u (m,)) -> (M̃, J, W, R_z)``: the KKT system's derivatives at its solution, in ``SX``.

        With the residual of the KKT system (kept rows ``J (r, nv)``, tangent, ``M̃ = M + diag(armature)``)

        .. math::

            R(q, v, u; a, \lambda) = \begin{bmatrix} \operatorname{RNEA}(q, v, a) - \tau(q, v, u)
                - J^\top\lambda \\ J(q) a + \dot J v \end{bmatrix} = 0
            \quad\text{at } (a, \lambda) = (\dot v, \lambda)(q, v, u),

        the outputs are ``M̃ (nv, nv)`` and ``J`` (so ``K = ∂R/∂(a, λ) = [[M̃, −Jᵀ], [J, 0]]``), ``W = ∂(J v)/∂q · E
        (r, nv)`` and ``R_z = ∂R/∂z (nv + r, 2nv + m)``, columns ``[q, v, u]`` (``∂/∂q`` in the tangent space:
        ``∂R/∂q · E``). ``R_z`` is built by reverse-mode derivatives of ``R``, one row at a time, with ``a``, ``λ``
        free symbols, which are then replaced by the KKT solution (Schur complement, one LDLᵀ of ``M̃``): no
        derivative goes through the solve, so the expression stays a few times the size of the dynamics. Then
        ``∂(a, λ)/∂z = −K⁻¹ R_z`` (:meth:`chain_function`). Built afresh on every call (:meth:`jacobians`
        compiles it once).
        """
        rb, tree, n, nq, m = self.rb, self.rb.tree, self.nv, self.nq, self._nu
        rows, r = list(self.rows), len(self.rows)
        q, v, u = cs.SX.sym("q", nq), cs.SX.sym("v", n), cs.SX.sym("u", m)
        a, lam = cs.SX.sym("a", n), cs.SX.sym("lam", r)
        ql, vl, ul = [q[i] for i in range(nq)], [v[i] for i in range(n)], [u[k] for k in range(m)]
        rate = _col(qpos_rate(tree, ql, vl))
        E = cs.jacobian(rate, v)
        phi = cs.vertcat(*[v_ for c in self.constraints for v_ in c.residual(rb, ql)])[rows]
        J = cs.mtimes(cs.jacobian(phi, q), E)
        Jv = cs.mtimes(J, v)
        X = rb.transforms(ql, CASADI_OPS)
        inv = rb.inverse_dynamics(ql, vl, [a[i] for i in range(n)], CASADI_OPS, X)
        tau = rb.generalized_forces(ql, vl, ul, self._active, (), CASADI_OPS, X)
        jdv = cs.jtimes(Jv, q, rate)  # J̇v = ∂(J v)/∂q · q̇
        R = cs.vertcat(_col([inv[i] - tau[i] for i in range(n)]) - cs.mtimes(J.T, lam), cs.mtimes(J, a) + jdv)
        z = cs.vertcat(q, v, u)
        Rz = cs.vertcat(*[cs.gradient(R[i], z).T for i in range(n + r)])
        Rz = cs.horzcat(cs.mtimes(Rz[:, :nq], E), Rz[:, nq:])
        W = cs.mtimes(cs.jacobian(Jv, q), E)
        # the KKT solution (Schur complement, one LDLᵀ of M̃), substituted for the symbols a, λ
        M = rb.mass_matrix(ql, CASADI_OPS, X)
        for i, arm in enumerate(_dof_armature(tree)):
            M[i][i] = M[i][i] + arm
        L, D = _ldl_factor(M)
        c = rb.bias(ql, vl, CASADI_OPS, X)
        a_f = _col(_ldl_back(L, D, [tau[i] - c[i] for i in range(n)]))
        MinvJT = cs.horzcat(*[_col(_ldl_back(L, D, [J[k, j] for j in range(n)])) for k in range(r)])
        rhs = -jdv - cs.mtimes(J, a_f)
        lam_s = _col(_ldl_solve(_lists(cs.mtimes(J, MinvJT)), [rhs[k] for k in range(r)]))
        a_s = a_f + cs.mtimes(MinvJT, lam_s)
        Rz = cs.substitute(Rz, cs.vertcat(a, lam), cs.vertcat(a_s, lam_s))
        Mm = cs.vertcat(*[cs.horzcat(*[cs.SX(M[i][j]) for j in range(n)]) for i in range(n)])
        # outputs keep their structural zeros: chain_function takes them with the same sparsity (fewer operations)
        return cs.Function("constrained_jac", [q, v, u], [Mm, J, W, Rz], ["q", "v", "u"], ["M", "J", "W", "R_z"])

    def chain_function(self, sparsity: Sequence[cs.Sparsity] | None = None) -> cs.Function:
        r"""``(M̃, J, W, R_z) -> (Aᵀ, Bᵀ)``: the reduced Jacobians from :meth:`linearization_function`'s outputs.

        With ``S = [I; S_D]`` (rows ``I``, ``D``), ``S_D = −J_D⁻¹ J_I``, the velocity map along the manifold
        ``∂v_D/∂q_I = −J_D⁻¹ W S`` (differentiate ``J(q) S(q) v_I = 0`` with ``v_I`` held), the columns of ``R_z``
        chained to ``C = [R_q S + R_{v_D} ∂v_D/∂q_I, R_v S, R_u]``; then the null-space solution of
        ``K [da; dλ] = −C``: ``da = S da_I + P(−C₂)`` with ``P = [0; J_D⁻¹]`` satisfies the constraint rows for any
        ``da_I``, and ``Sᵀ`` (with ``Sᵀ Jᵀ = 0``) removes ``dλ`` from the others:

        .. math::

            (S^\top \tilde M S)\, \frac{dF}{d(q_I, v_I, u)} = -\left(S^\top C_1 - S^\top \tilde M P\, C_2\right),

        ``Sᵀ M̃ S`` (``nᵢ × nᵢ``, positive definite) by LDLᵀ. A separate function of numbers (no model in it): the
        same arithmetic inside :meth:`linearization_function` made the compiler take ten times longer.
        ``sparsity``: the inputs' structural sparsity (:meth:`linearization_function`'s outputs'; default dense):
        their structural zeros drop out of the products, and the inputs are their nonzeros. Transposed outputs:
        their column-major entries are ``A``'s and ``B``'s row-major ones.
        """
        n, r, m, ni = self.nv, len(self.rows), self._nu, self.ni
        ind, dep = list(self.independent), list(self.dependent)
        shapes = ((n, n), (r, n), (r, n), (n + r, 2 * n + m))
        if sparsity is None:
            sparsity = [cs.Sparsity.dense(*shape) for shape in shapes]
        if [sp.shape for sp in sparsity] != list(shapes):
            raise ValueError(f"chain_function: sparsity shapes {[sp.shape for sp in sparsity]}, expected {shapes}")
        Mm, J, W, Rz = (cs.SX.sym(name, sp) for name, sp in zip(("M", "J", "W", "R_z"), sparsity, strict=True))
        JDinv = cs.inv(J[:, dep])
        SD = -cs.mtimes(JDinv, J[:, ind])  # the null-space basis S = [I; S_D] (rows I, D)
        dvD = -cs.mtimes(JDinv, W[:, ind] + cs.mtimes(W[:, dep], SD))  # ∂v_D/∂q_I = −J_D⁻¹ W S
        Rq, Rv = Rz[:, :n], Rz[:, n : 2 * n]
        Cq = Rq[:, ind] + cs.mtimes(Rq[:, dep], SD) + cs.mtimes(Rv[:, dep], dvD)
        C = cs.horzcat(Cq, Rv[:, ind] + cs.mtimes(Rv[:, dep], SD), Rz[:, 2 * n :])
        MS = Mm[:, ind] + cs.mtimes(Mm[:, dep], SD)
        Mr = MS[ind, :] + cs.mtimes(SD.T, MS[dep, :])  # Sᵀ M̃ S
        Xt = cs.mtimes(MS[dep, :].T, JDinv)  # Sᵀ M̃ P (M̃ symmetric)
        C1, C2 = C[:n, :], C[n:, :]
        rhs = C1[ind, :] + cs.mtimes(SD.T, C1[dep, :]) - cs.mtimes(Xt, C2)
        Lr, Dr = _ldl_factor(_lists(Mr))
        AB = cs.horzcat(*[_col(_ldl_back(Lr, Dr, [-rhs[i, j] for i in range(ni)])) for j in range(rhs.shape[1])])
        A = cs.vertcat(cs.horzcat(cs.SX.zeros(ni, ni), cs.SX.eye(ni)), AB[:, : 2 * ni])
        B = cs.vertcat(cs.SX.zeros(ni, m), AB[:, 2 * ni :])
        return cs.Function(
            "constrained_chain",
            [Mm, J, W, Rz],
            [cs.densify(A.T), cs.densify(B.T)],
            ["M", "J", "W", "R_z"],
            ["A_T", "B_T"],
        )

    def _chain_for(self, jac: cs.Function) -> cs.Function:
        """:meth:`chain_function` for the inputs ``jac``'s outputs are (their sparsity)."""
        return self.chain_function([jac.sparsity_out(k) for k in range(jac.n_out())])

    def _key(self) -> str:
        """What the compiled functions depend on beyond ``compile_key``: inputs, kept rows, coordinates, constraints."""
        cons = [
            {k: (val.tolist() if isinstance(val, np.ndarray) else val) for k, val in vars(c).items()}
            for c in self.constraints
        ]
        return f"active={list(self._active)}|rows={list(self.rows)}|dependent={list(self.dependent)}|{cons!r}"

    def _compile(self) -> _Linearization:
        """Compile the linearization and Newton functions (once; see :meth:`jacobians`)."""
        with self._build_lock:
            if self._linearization is None:
                if self._compile_key is None:  # keyed by the generated source (built here)
                    jac = compiled(self.linearization_function())
                    chain = compiled(self._chain_for(jac))
                    newton = compiled(_dense(self._newton_function))
                else:  # keyed by what the functions depend on: a cache hit builds nothing
                    key = f"{self._compile_key}|{self._key()}"
                    jac = compiled_by_key("constrained_jac", f"jac|{key}", self.linearization_function)
                    chain = compiled_by_key("constrained_chain", f"chain|{key}", lambda: self._chain_for(jac))
                    newton = compiled_by_key(
                        "constrained_newton", f"newton|{key}", lambda: _dense(self._newton_function)
                    )
                nb = _NewtonBuffers(newton)
                self._linearization = _Linearization(jac, chain, nb, self.ni, self._nu)
                self._newton = nb
            return self._linearization

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
