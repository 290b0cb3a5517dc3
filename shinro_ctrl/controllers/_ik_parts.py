"""The pieces of :mod:`shinro_ctrl.controllers.ik_qp` besides the controller: result records, the box QP, the kernel.

:class:`IKKernel` owns everything one QP iteration needs for one arm: the
compiled kinematics and its buffers, the task error, and the box QP. The
controller (:class:`~shinro_ctrl.controllers.ik_qp.IKQP`) holds one, and the
loops of :mod:`~shinro_ctrl.controllers._ik_loops` run over it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import casadi as cs
import numpy as np
import osqp
import scipy.sparse as sp

from shinro_ctrl.controllers._osqp import OsqpQP
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.kinematics import euler_zyx_to_matrix, so3_log_flat
from shinro_ctrl.validation import as_matrix, as_vector

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.plants.armrobot import ArmRobot

__all__ = ["MAX_TARGET_DISTANCE", "IKKernel", "IKProblem", "IKStep"]

#: Farthest target position [m] from the arm's base an IK call accepts (far beyond any arm's reach).
MAX_TARGET_DISTANCE = 1e6

_SOLVED = int(osqp.SolverStatus.OSQP_SOLVED)
_USABLE = {
    int(osqp.SolverStatus.OSQP_SOLVED),
    int(osqp.SolverStatus.OSQP_SOLVED_INACCURATE),
    int(osqp.SolverStatus.OSQP_MAX_ITER_REACHED),
    int(osqp.SolverStatus.OSQP_TIME_LIMIT_REACHED),
}


@dataclass(frozen=True)
class IKProblem:
    """One IK iteration's QP, for inspection (see :meth:`IKQP.build_qp`).

    ``min ½ dqᵀ P dq + cᵀ dq  s.t.  l ≤ A dq ≤ u``.

    Attributes:
        P: Hessian ``Jᵀ W J + λ I`` ``(n, n)`` (full, symmetric).
        c: Linear term ``−Jᵀ W e`` ``(n,)``.
        A: Constraint matrix, the identity ``(n, n)``.
        l: Lower bounds ``max(q_min − q, −s)`` ``(n,)`` [rad].
        u: Upper bounds ``min(q_max − q, s)`` ``(n,)`` [rad].
        J: Task Jacobian ``(k, n)`` (k = 6 pose, 3 position).
        error: Task error ``e`` ``(k,)`` [m, rad].
        weights: Task weights ``diag(W)`` ``(k,)``.
    """

    P: np.ndarray
    c: np.ndarray
    A: np.ndarray
    l: np.ndarray
    u: np.ndarray
    J: np.ndarray
    error: np.ndarray
    weights: np.ndarray


@dataclass(frozen=True)
class IKStep:
    """What the last control call (:meth:`IKQP.track` / ``__call__``) did.

    Attributes:
        q: Joint targets ``(n,)`` [rad] (inside the limits).
        dq: Change from the starting joints ``(n,)`` [rad].
        iterations: QP solves.
        pos_err: Remaining position error to the target [m].
        ori_err: Remaining orientation error to the target [rad].
        status: OSQP status of the last QP.
        solve_time_s: Wall time of the call [s].
    """

    q: np.ndarray
    dq: np.ndarray
    iterations: int
    pos_err: float
    ori_err: float
    status: str
    solve_time_s: float


class _BoxQP:
    """``min ½ xᵀPx + cᵀx  s.t.  l ≤ x ≤ u`` in one OSQP problem, updated in place.

    ``P``'s pattern is the full upper triangle (built from ``np.triu(np.ones)``, so no
    entry is dropped as an explicit zero) and ``A`` the identity; only values change.
    Updates go through :class:`~shinro_ctrl.controllers._osqp.OsqpQP` (OSQP's compiled
    solver when available). That path neither clamps infinite bounds nor checks
    lengths, so this class only ever passes finite bounds in arrays whose lengths are
    checked once here.
    """

    stateful = True  # warm start, previous input and plan

    def __init__(self, n: int, P_upper: np.ndarray, settings: dict[str, Any]):
        pattern = sp.csc_matrix(np.triu(np.ones((n, n))))
        self.n = n
        self.nnz = pattern.nnz
        if P_upper.shape != (self.nnz,):
            raise InvalidArgument(f"P upper triangle: expected {self.nnz} values but found {P_upper.shape}")
        P = sp.csc_matrix((P_upper.copy(), pattern.indices, pattern.indptr), shape=(n, n))
        self.qp = OsqpQP(
            "IK problem or its osqp_settings",
            P,
            np.zeros(n),
            sp.identity(n, format="csc"),
            -np.ones(n),
            np.ones(n),
            settings,
        )
        self.solver = self.qp.solver
        self._rho0 = float(settings.get("rho", self.solver.settings.rho))
        self._zeros = np.zeros(n)

    def solve(self, P_upper: np.ndarray, c: np.ndarray, l: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, int, int]:
        """Solve with new values; returns ``(x (n,), status_val, admm_iterations)``."""
        self.qp.update(c, l, u, P_upper)
        sol, info = self.qp.solve()
        return sol.x, int(info.status_val), int(info.iter)

    def reset(self) -> None:
        """Back to the set-up state: no warm start (iterates zero) and the initial ``rho``.

        OSQP carries both from one solve to the next (adaptive rho included), so results
        depend on the solve history unless this is called first.
        """
        self.qp.warm_start(self._zeros, self._zeros)
        self.qp.update_rho(self._rho0)


class IKKernel:
    """One IK iteration for one arm: compiled kinematics, task error and the box QP, with their buffers.

    Args:
        arm: The arm (its chain's CasADi kinematics and its joint limits are read once).
        task_rows: ``k``, 6 (pose) or 3 (position).
        weights: Task weights ``diag(W)`` ``(k,)``.
        damping: ``λ`` of the ``½ λ ‖Δq‖²`` term.
        settings: OSQP settings of the box QP.

    Attributes:
        n: Joints.
        k: Task rows.
        lo, hi: Joint limits ``(n,)`` [rad].
        sample_lo, sample_hi: Where restarts sample: the limits, or ±π where a joint is unlimited.
        p, R, J: Position ``(3,)``, rotation ``(3, 3)`` and geometric Jacobian ``(6, n)`` of the
            last :meth:`evaluate`.
        Hu: The upper triangle of ``P = Jᵀ W J + λ I`` (column by column) at the last evaluation.
        e: Task error ``(6,)`` of the last :meth:`error`; ``et`` the same as Python floats.
        weights: The task weights ``(k,)``.
        qp: The box QP (one OSQP problem updated in place).
        evaluated: The array whose kinematics the buffers hold (by identity).
    """

    def __init__(self, arm: ArmRobot, task_rows: int, weights: np.ndarray, damping: float, settings: dict[str, Any]):
        n = self.n = int(arm.num_dof)
        k = self.k = task_rows
        limits = np.asarray(arm.joint_limits, dtype=float)
        self.lo = limits[:, 0].copy()
        self.hi = limits[:, 1].copy()
        self.sample_lo = np.maximum(self.lo, -math.pi)
        self.sample_hi = np.minimum(self.hi, math.pi)
        qs, p, R, J = arm.chain.symbolic()  # the core SerialChain's CasADi FK and geometric Jacobian
        Jt = J[:k, :]
        ws = cs.SX.sym("w", k)
        lam = cs.SX.sym("lam")
        WJ = cs.diag(ws) @ Jt  # (k, n); the column-major nonzeros of -WJ are -Jᵀ W row-major
        H = Jt.T @ WJ + lam * cs.SX.eye(n)
        Hu = cs.vertcat(*[H[i, j] for j in range(n) for i in range(j + 1)])
        f = cs.Function("ik_terms", [qs, ws, lam], [p, R.T, J.T, Hu, -WJ])
        f = cs.Function("ik_terms", [qs, ws, lam], [cs.densify(e) for e in f(qs, ws, lam)])
        self._qb = np.zeros(n)
        self._wb = self.weights = np.array(weights, dtype=float)
        self._lamb = np.array([damping])
        self.p = np.zeros(3)
        self.R = np.zeros((3, 3))
        self.J = np.zeros((6, n))
        self.Hu = np.zeros(n * (n + 1) // 2)
        self.negJtW = np.zeros((n, k))
        self._M = np.zeros((3, 3))
        self._buf, self._eval = f.buffer()
        for i, a in enumerate((self._qb, self._wb, self._lamb)):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate((self.p, self.R, self.J, self.Hu, self.negJtW)):
            self._buf.set_res(i, memoryview(a.reshape(-1)))
        self.function = f
        self.e = np.zeros(6)
        self._ek = self.e[:k]  # the task rows of e (a view)
        self.et = (0.0,) * 6  # e as Python floats (the last error())
        self._clu = np.zeros((3, n))  # QP vectors c, l, u as rows of one buffer (scaled in one call)
        self._c, self._l, self._u = self._clu
        self.evaluated: np.ndarray | None = None
        self.evaluate(np.clip(np.zeros(n), self.lo, self.hi))
        self.qp = _BoxQP(n, self.Hu, settings)
        self._osqp_update = self.qp.qp.update  # bound once: the hot path calls them per iteration
        self._osqp_solve = self.qp.qp.solve

    def evaluate(self, q: np.ndarray) -> None:
        """Fill p, R, J, upper(P), JᵀW at ``q``.

        ``q`` is remembered (by identity) as the evaluated point; the arrays the IK
        evaluates are never modified afterwards.
        """
        self._qb[:] = q
        self._eval()
        self.evaluated = q

    def error(self, pt: list[float], Rt: np.ndarray) -> tuple[float, float]:
        """Fill the task error ``e`` (and ``et``, its Python floats) from the last evaluation.

        Returns ``(pos_err, ori_err)``. ``pt`` is the target position (3 floats: a list is
        fastest), ``Rt`` the target rotation ``(3, 3)``.
        """
        px, py, pz = self.p.tolist()
        ex, ey, ez = pt[0] - px, pt[1] - py, pt[2] - pz
        np.matmul(Rt, self.R.T, out=self._M)
        wx, wy, wz = so3_log_flat(self._M.ravel().tolist())
        et = self.et = (ex, ey, ez, wx, wy, wz)
        self.e[:] = et
        return math.sqrt(ex * ex + ey * ey + ez * ez), math.sqrt(wx * wx + wy * wy + wz * wz)

    def qp_step(
        self, q: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray, s: np.ndarray, neg_s: np.ndarray, scale: float
    ) -> tuple[np.ndarray, int]:
        """Solve the QP at the last evaluation; return new joints (a fresh array inside the box) and the status.

        The QP is posed for ``z = Δq / scale`` with ``scale`` the task error norm: ``c`` and
        the bounds are divided by it, so the solution is of order one and OSQP's absolute
        tolerance acts as a relative one (otherwise steps below ``eps_abs`` come out as noise
        and the iteration stalls near that size). ``s`` and ``neg_s`` are the step bound and
        its negative as ``(n,)`` arrays. This is the hot path: every operand is an array
        (a Python scalar costs a ufunc call about 0.5 µs more) and OSQP's compiled solver is
        called directly when available.
        """
        c, l, u = self._c, self._l, self._u
        np.dot(self.negJtW, self._ek, out=c)
        np.subtract(box_lo, q, out=l)
        np.maximum(l, neg_s, out=l)
        np.subtract(box_hi, q, out=u)
        np.minimum(u, s, out=u)
        self._clu *= 1.0 / scale
        self._osqp_update(c, l, u, self.Hu)
        sol, info = self._osqp_solve()
        status = int(info.status_val)
        x = sol.x
        # "solved" means converged residuals, hence a finite x: only other statuses need the check.
        if status != _SOLVED and (status not in _USABLE or not math.isfinite(x.sum())):
            # A box QP with P ≻ 0 is always feasible; should OSQP still fail, fall back on the
            # box projection of the unconstrained minimizer so the iteration can go on.
            x = np.linalg.lstsq(self.dense_P(), -c, rcond=None)[0]
        # OSQP meets bounds to ~eps: clip the step, then the joints (rounding of q + dq).
        np.minimum(x, u, out=x)
        np.maximum(x, l, out=x)
        x *= scale
        x += q
        np.maximum(x, box_lo, out=x)
        return np.minimum(x, box_hi, out=x), status

    def dense_P(self) -> np.ndarray:
        """``P`` ``(n, n)`` (full, symmetric) from its upper triangle."""
        n = self.n
        P = np.zeros((n, n))
        idx = 0
        for j in range(n):
            for i in range(j + 1):
                P[i, j] = P[j, i] = self.Hu[idx]
                idx += 1
        return P

    def target(self, target: ArrayLike, name: str = "target") -> tuple[np.ndarray, np.ndarray]:
        """``(p (3,), R (3, 3))`` of a transform (4, 4), a pose (6,) or (position task) a point (3,).

        Raises:
            InvalidArgument: a wrong shape, or a position farther than :data:`MAX_TARGET_DISTANCE` from the
                base (no arm reaches it, and its task error would overflow the QP's arithmetic).
            NonFiniteError: NaN or inf.
        """
        a = np.asarray(target, dtype=float)
        if a.shape == (4, 4):
            if not math.isfinite(float(a.sum())):
                as_matrix(name, a, (4, 4))  # raises NonFiniteError naming the target
            p, R = a[:3, 3].copy(), a[:3, :3].copy()
        elif a.shape == (6,):
            a = as_vector(name, a, 6)
            p, R = a[:3].copy(), euler_zyx_to_matrix(a[3:])
        elif a.shape == (3,) and self.k == 3:
            p, R = as_vector(name, a, 3).copy(), np.eye(3)
        else:
            shapes = "(4, 4) or (6,)" + (" or (3,)" if self.k == 3 else "")
            raise InvalidArgument(f"{name}: expected shape {shapes} but found {a.shape}")
        if not -MAX_TARGET_DISTANCE <= p.min() <= p.max() <= MAX_TARGET_DISTANCE:
            raise InvalidArgument(
                f"{name}: position {np.array2string(p, precision=3)} m is farther than {MAX_TARGET_DISTANCE:.0e} m "
                "from the base: no arm reaches it (check the reference's units and size)"
            )
        return p, R

    def joints(self, q: ArrayLike, name: str) -> np.ndarray:
        """``q`` as a fresh ``(n,)`` array clipped to the limits (validated: shape, finite)."""
        if not (type(q) is np.ndarray and q.shape == (self.n,) and math.isfinite(float(q.sum()))):
            q = as_vector(name, q, self.n)
        return np.minimum(np.maximum(q, self.lo), self.hi)

    def converged(self, pos_err: float, ori_err: float, tol: float) -> bool:
        """Both errors below ``tol`` (the position only, for a position task)."""
        return pos_err < tol and (self.k == 3 or ori_err < tol)
