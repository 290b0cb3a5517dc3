r"""Differential inverse kinematics as a small quadratic program (OSQP).

At joints ``q`` with task Jacobian ``J`` (``(6, n)`` for a pose task, its
position rows ``(3, n)`` for a position task) and task error ``e``, one
iteration solves

.. math::

    \min_{\Delta q}\ \tfrac12 \lVert J \Delta q - e \rVert_W^2 + \tfrac12 \lambda \lVert \Delta q \rVert^2
    \quad \text{s.t.}\quad
    \max(q_{min} - q,\ -s) \le \Delta q \le \min(q_{max} - q,\ s),

i.e. ``P = Jᵀ W J + λ I``, ``c = −Jᵀ W e``, ``A = I``. The error is
``e = [p_t − p; log(R_t Rᵀ)]``: a position error [m] and the world-frame
rotation vector [rad] that the geometric Jacobian's angular rows act on
(the log map is robust near pitch ±90° and at a rotation of π). The step
bound ``s`` is ``max_step`` [rad] in :meth:`IKQP.solve` and
``velocity_limit · dt`` in control (:meth:`IKQP.track`, :meth:`IKQP.__call__`).

One OSQP problem is set up at construction with a fixed sparsity pattern
(the full upper triangle of ``P``, the identity ``A``) and updated in place
every iteration; the kinematics, ``P``'s upper triangle and ``Jᵀ W`` come
from one compiled CasADi function evaluated through its buffer. The QP is
posed for ``Δq / ‖e‖`` (``c`` and the bounds divided by the error norm), so
OSQP's tolerances are relative to the step and do not cap the IK precision.
Every joint vector this module returns is clipped to the joint limits exactly
(OSQP satisfies bounds only to about its tolerance).
"""

from __future__ import annotations

import math
from typing import Any

import casadi as cs
import numpy as np
import osqp

from shinro_ctrl.controllers._ik_loops import IKLoops
from shinro_ctrl.controllers._ik_parts import IKProblem, IKStep, _BoxQP
from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.kinematics import (
    IKResult,
    euler_zyx_from_matrix,
    euler_zyx_to_matrix,
    so3_log_flat,
    wrap_angle,
)
from shinro_ctrl.validation import as_matrix, as_vector, check_nonnegative, check_positive

__all__ = ["IKQP", "IKProblem", "IKResult", "IKStep"]

#: OSQP settings used unless ``osqp_settings`` overrides them (measured on the arm6 benchmark).
DEFAULT_OSQP_SETTINGS: dict[str, Any] = {
    "verbose": False,
    "eps_abs": 1e-5,
    "eps_rel": 1e-5,
    "max_iter": 400,
    "polishing": False,
    "warm_starting": True,
    "check_termination": 5,
    "adaptive_rho": True,
}

_SOLVED = int(osqp.SolverStatus.OSQP_SOLVED)
_USABLE = {
    int(osqp.SolverStatus.OSQP_SOLVED),
    int(osqp.SolverStatus.OSQP_SOLVED_INACCURATE),
    int(osqp.SolverStatus.OSQP_MAX_ITER_REACHED),
    int(osqp.SolverStatus.OSQP_TIME_LIMIT_REACHED),
}


class IKQP(IKLoops, Controller):
    r"""Joint-limit-aware differential IK for an :class:`~shinro_ctrl.plants.ArmRobot`.

    Three entry points share one QP (see the module docstring):

    * :meth:`step` — one QP: ``dq`` towards a target from ``q``;
    * :meth:`solve` — iterate QP steps (each joint moves at most ``max_step`` per
      iteration) until the pose error is below ``tol``, with optional random restarts;
    * control — :meth:`track` moves the joints towards a target within one control step
      (``|Δq| ≤ velocity_limit · dt``), and ``__call__(x, ref)`` wraps it as a
      Cartesian controller for the arm plant (below).

    As a controller (``u = ik(x, ref)`` then ``arm.step(u)``): ``x`` is the arm's state,
    the end-effector pose ``[x, y, z, roll, pitch, yaw]`` (6,), and ``ref`` the desired
    pose (6,) (or position (3,) for ``task="position"``). The arm's :meth:`step` takes a
    Cartesian twist, so the controller returns one: it runs :meth:`track` from the arm's
    commanded joints (``arm.q_cmd``) towards ``ref`` — joint limits and velocity limits
    respected — and returns the twist ``u (6,)`` [m/s, ZYX Euler rates rad/s] that carries
    the pose from ``x`` to the FK pose of those joint targets in one step. ``arm.step(u)``
    turns it back into the same joint targets when ``arm.ik`` is this object (build the
    arm with it: ``ArmRobot(ik=IKQP)``; with the arm's default damped pseudoinverse it is close). The
    returned twist is therefore always one the arm can execute, ``x`` lags ``ref`` only
    where the limits bind, and the joint targets of the last call are in :attr:`last`.

    Args:
        arm: The arm (``ArmRobot``); its joint limits and kinematics are read once here.
        damping: ``λ >= 0``, weight of the ``½ λ ‖Δq‖²`` term. The default 1e-4 keeps
            convergence quick at near-singular targets (with 1e-3, 98.5 % instead of 100 %
            of the workspace benchmark targets converge with 20 restarts).
        velocity_limit: Joint speed limit [rad/s], > 0, a scalar or ``(n,)`` (default π,
            the UR5's).
        dt: Control step [s] (default ``arm.dt``).
        max_step: Largest joint change per :meth:`solve` iteration [rad], > 0.
        task: ``"pose"`` (position and orientation, 6 rows) or ``"position"`` (3 rows).
        weights: Task weights ``diag(W)`` >= 0, a scalar or ``(k,)`` (default ones).
        osqp_settings: OSQP settings overriding :data:`DEFAULT_OSQP_SETTINGS`.
        control_iters: QP iterations per control step in :meth:`track` (>= 1).

    Attributes:
        last: :class:`IKStep` of the last control call, or None.
        lo, hi: Joint limits ``(n,)`` [rad].
        preview: 1: a simulation loop may pass ``ref`` as the rows ``[r(t), r(t + dt)]``;
            the controller then aims at ``r(t + dt)``, removing one step of delay.

    Raises:
        InvalidArgument: an invalid option (the message names it), including an unknown OSQP
            setting. (``InvalidArgument`` is a ``ValueError``.)
    """

    def __init__(
        self,
        arm: Any,
        *,
        damping: float = 1e-4,
        velocity_limit: Any = math.pi,
        dt: float | None = None,
        max_step: float = 0.5,
        task: str = "pose",
        weights: Any = None,
        osqp_settings: dict[str, Any] | None = None,
        control_iters: int = 3,
    ):
        if not all(hasattr(arm, a) for a in ("num_dof", "chain", "joint_limits")):
            raise InvalidArgument(f"IKQP needs an arm plant (ArmRobot), got {type(arm).__name__}")
        self.arm = arm
        n = self.n = int(arm.num_dof)
        if task not in ("pose", "position"):
            raise InvalidArgument(f"task must be 'pose' or 'position', got {task!r}")
        self.task = task
        k = self.k = 6 if task == "pose" else 3
        self.damping = check_nonnegative("damping", damping)
        self.dt = check_positive("dt", arm.dt if dt is None else dt)
        self.max_step = max_step  # validated by the property (which also sets the step-bound arrays)
        self.velocity_limit, self.weights, self.control_iters = _check_options(
            n, k, velocity_limit, weights, control_iters
        )
        w = self.weights
        limits = np.asarray(arm.joint_limits, dtype=float)
        self.lo = limits[:, 0].copy()
        self.hi = limits[:, 1].copy()
        # Restarts sample here: the limits, or ±π where a joint is unlimited.
        self._sample_lo = np.maximum(self.lo, -math.pi)
        self._sample_hi = np.minimum(self.hi, math.pi)

        self._compile_terms(arm, w)

        self._e = np.zeros(6)
        self._ek = self._e[:k]  # the task rows of e (a view)
        self._et = (0.0,) * 6  # e as Python floats (the last _error)
        self._clu = np.zeros((3, n))  # QP vectors c, l, u as rows of one buffer (scaled in one call)
        self._c, self._l, self._u = self._clu
        self._evaluated: np.ndarray | None = None  # the array whose kinematics the buffers hold
        self._evaluate(np.clip(np.zeros(n), self.lo, self.hi))
        settings = dict(DEFAULT_OSQP_SETTINGS)
        settings.update(osqp_settings or {})
        self._qp = _BoxQP(n, self._Hu, settings)
        self._osqp_update = self._qp.qp.update  # bound once: the hot path calls them per iteration
        self._osqp_solve = self._qp.qp.solve
        self.last: IKStep | None = None
        self.preview = 1
        self.u_min = None
        self.u_max = None

    def _compile_terms(self, arm: Any, w: np.ndarray) -> None:
        """Compile ``q -> p, R, J, upper(P), (Jᵀ W)ᵀ`` once and bind its CasADi buffer to arrays of ours."""
        n, k = self.n, self.k
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
        self._wb = w.copy()
        self._lamb = np.array([self.damping])
        self._p = np.zeros(3)
        self._R = np.zeros((3, 3))
        self._J = np.zeros((6, n))
        self._Hu = np.zeros(n * (n + 1) // 2)
        self._negJtW = np.zeros((n, k))
        self._M = np.zeros((3, 3))
        self._buf, self._eval = f.buffer()
        for i, a in enumerate((self._qb, self._wb, self._lamb)):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate((self._p, self._R, self._J, self._Hu, self._negJtW)):
            self._buf.set_res(i, memoryview(a.reshape(-1)))
        self._function = f

    @property
    def max_step(self) -> float:
        """Largest joint change per :meth:`solve` iteration [rad], > 0."""
        return self._max_step

    @max_step.setter
    def max_step(self, value: float) -> None:
        self._max_step = check_positive("max_step", value)
        # The step bounds as (n,) arrays: a Python scalar operand costs a ufunc call ~0.5 µs more.
        self._s_solve = np.full(self.n, self._max_step)
        self._neg_s_solve = -self._s_solve

    @classmethod
    def from_plant(
        cls,
        plant: Any,
        *,
        damping: float = 1e-4,
        velocity_limit: Any = math.pi,
        dt: float | None = None,
        max_step: float = 0.5,
        task: str = "pose",
        weights: Any = None,
        osqp_settings: dict[str, Any] | None = None,
        control_iters: int = 3,
    ) -> IKQP:
        """Build the controller of a scenario for an arm (same options as the constructor).

        The controller never changes the plant. To make ``plant.step(u)`` turn the twist
        this controller returns back into exactly the joint targets it computed, the arm
        is built with it as its IK (``ArmRobot(ik=lambda arm: IKQP.from_plant(arm, ...))``);
        :class:`~shinro_ctrl.sim.RobotSim` builds a scenario's arm that way.
        """
        ik = cls(
            plant,
            damping=damping,
            velocity_limit=velocity_limit,
            dt=dt,
            max_step=max_step,
            task=task,
            weights=weights,
            osqp_settings=osqp_settings,
            control_iters=control_iters,
        )
        return ik

    # ------------------------------------------------------------- internals
    def _evaluate(self, q: np.ndarray) -> None:
        """Fill p, R, J, upper(P), JᵀW at ``q`` (buffers owned by this object).

        ``q`` is remembered (by identity) as the evaluated point; the arrays this module
        evaluates are never modified afterwards.
        """
        self._qb[:] = q
        self._eval()
        self._evaluated = q

    def _error(self, pt: Any, Rt: np.ndarray) -> tuple[float, float]:
        """Fill the task error ``e`` (and ``_et``, its Python floats) from the last evaluation.

        Returns ``(pos_err, ori_err)``. ``pt`` is the target position (3 floats: a list is
        fastest), ``Rt`` the target rotation ``(3, 3)``.
        """
        px, py, pz = self._p.tolist()
        ex, ey, ez = pt[0] - px, pt[1] - py, pt[2] - pz
        np.matmul(Rt, self._R.T, out=self._M)
        wx, wy, wz = so3_log_flat(self._M.ravel().tolist())
        et = self._et = (ex, ey, ez, wx, wy, wz)
        self._e[:] = et
        return math.sqrt(ex * ex + ey * ey + ez * ez), math.sqrt(wx * wx + wy * wy + wz * wz)

    def _qp_step(
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
        np.dot(self._negJtW, self._ek, out=c)
        np.subtract(box_lo, q, out=l)
        np.maximum(l, neg_s, out=l)
        np.subtract(box_hi, q, out=u)
        np.minimum(u, s, out=u)
        self._clu *= 1.0 / scale
        self._osqp_update(c, l, u, self._Hu)
        sol, info = self._osqp_solve()
        status = int(info.status_val)
        x = sol.x
        # "solved" means converged residuals, hence a finite x: only other statuses need the check.
        if status != _SOLVED and (status not in _USABLE or not math.isfinite(x.sum())):
            # A box QP with P ≻ 0 is always feasible; should OSQP still fail, fall back on the
            # box projection of the unconstrained minimizer so the iteration can go on.
            x = np.linalg.lstsq(self._dense_P(), -c, rcond=None)[0]
        # OSQP meets bounds to ~eps: clip the step, then the joints (rounding of q + dq).
        np.minimum(x, u, out=x)
        np.maximum(x, l, out=x)
        x *= scale
        x += q
        np.maximum(x, box_lo, out=x)
        return np.minimum(x, box_hi, out=x), status

    def _dense_P(self) -> np.ndarray:
        n = self.n
        P = np.zeros((n, n))
        idx = 0
        for j in range(n):
            for i in range(j + 1):
                P[i, j] = P[j, i] = self._Hu[idx]
                idx += 1
        return P

    def _target(self, target: Any, name: str = "target") -> tuple[np.ndarray, np.ndarray]:
        """``(p (3,), R (3, 3))`` of a transform (4, 4), a pose (6,) or (position task) a point (3,)."""
        a = np.asarray(target, dtype=float)
        if a.shape == (4, 4):
            if not math.isfinite(float(a.sum())):
                as_matrix(name, a, (4, 4))  # raises NonFiniteError naming the target
            return a[:3, 3].copy(), a[:3, :3].copy()
        if a.shape == (6,):
            a = as_vector(name, a, 6)
            return a[:3].copy(), euler_zyx_to_matrix(a[3:])
        if a.shape == (3,) and self.task == "position":
            return as_vector(name, a, 3).copy(), np.eye(3)
        shapes = "(4, 4) or (6,)" + (" or (3,)" if self.task == "position" else "")
        raise InvalidArgument(f"{name}: expected shape {shapes} but found {a.shape}")

    def _joints(self, q: Any, name: str) -> np.ndarray:
        """``q`` as a fresh ``(n,)`` array clipped to the limits (validated: shape, finite)."""
        if not (type(q) is np.ndarray and q.shape == (self.n,) and math.isfinite(float(q.sum()))):
            q = as_vector(name, q, self.n)
        return np.minimum(np.maximum(q, self.lo), self.hi)

    def _converged(self, pos_err: float, ori_err: float, tol: float) -> bool:
        return pos_err < tol and (self.k == 3 or ori_err < tol)

    # ------------------------------------------------------------------ API
    def build_qp(self, q: Any, target: Any, *, max_step: Any = None) -> IKProblem:
        """The QP of one iteration at joints ``q (n,)`` towards ``target``, without solving it.

        Args:
            q: Joint angles ``(n,)`` [rad] (clipped to the limits).
            target: Transform ``(4, 4)``, pose ``(6,)``, or (position task) point ``(3,)``.
            max_step: Step bound ``s`` [rad], scalar or ``(n,)`` (default :attr:`max_step`).
        """
        q = self._joints(q, "q")
        pt, Rt = self._target(target)
        s = self.max_step if max_step is None else np.asarray(max_step, dtype=float)
        self._evaluate(q)
        self._error(pt, Rt)
        k = self.k
        J = self._J[:k].copy()
        e = self._e[:k].copy()
        P = J.T @ (self.weights[:, None] * J) + self.damping * np.eye(self.n)
        return IKProblem(
            P=P,
            c=-(J.T @ (self.weights * e)),
            A=np.eye(self.n),
            l=np.maximum(self.lo - q, -s),
            u=np.minimum(self.hi - q, s),
            J=J,
            error=e,
            weights=self.weights.copy(),
        )

    def step(self, q: Any, target: Any, *, max_step: Any = None) -> np.ndarray:
        """Solve one QP: the joint change ``dq (n,)`` [rad] from ``q`` towards ``target``.

        ``q + dq`` lies inside the joint limits and ``|dq| ≤ max_step``, both exactly (in
        floating point).

        Args:
            q: Joint angles ``(n,)`` [rad] (clipped to the limits first).
            target: Transform ``(4, 4)``, pose ``(6,)``, or (position task) point ``(3,)``.
            max_step: Step bound [rad], scalar or ``(n,)`` (default :attr:`max_step`).
        """
        q = self._joints(q, "q")
        pt, Rt = self._target(target)
        if max_step is None:
            s, neg_s = self._s_solve, self._neg_s_solve
        else:
            s = np.broadcast_to(np.asarray(max_step, dtype=float), (self.n,))
            neg_s = -s
        self._evaluate(q)
        pos_err, ori_err = self._error(pt.tolist(), Rt)
        scale = math.hypot(pos_err, ori_err) if self.k == 6 else pos_err
        if scale == 0.0:
            return np.zeros(self.n)
        q_new, _ = self._qp_step(q, self.lo, self.hi, s, neg_s, scale)
        return _bounded_difference(q, q_new, s)

    def __call__(self, x: Any, ref: Any = None) -> np.ndarray:
        """Cartesian twist ``u (6,)`` for the arm's ``step`` (see the class docstring).

        Args:
            x: The arm's state, the end-effector pose ``(6,)`` [m, rad].
            ref: Desired pose ``(6,)`` (position task: ``(3,)`` or ``(6,)``); None holds the
                current pose (zero twist). A preview ``(p, 6)`` of the reference at
                ``t, t + dt, …`` (see :attr:`preview`) targets its second row, the pose
                wanted at the end of this step.

        Returns:
            Twist ``[vx, vy, vz, roll_rate, pitch_rate, yaw_rate]`` (6,) [m/s, rad/s].
        """
        x = as_vector("x (end-effector pose)", x, 6)
        if ref is None:
            return np.zeros(6)
        ref = np.asarray(ref, dtype=float)
        if ref.ndim == 2:  # preview rows r(t_k), r(t_k + dt), ...: aim at the end of this step
            ref = ref[min(1, ref.shape[0] - 1)]
        if self.task == "position" and ref.shape == (6,):
            ref = ref[:3]
        q = self.track(self.arm.q_cmd, ref)
        self._evaluate(q)
        pose = np.concatenate([self._p, euler_zyx_from_matrix(self._R)])
        u = (pose - x) / self.dt
        u[3:] = wrap_angle(pose[3:] - x[3:]) / self.dt
        return u

    def reset(self) -> None:
        """Forget the warm start and :attr:`last`."""
        self._qp.reset()
        self.last = None

    def __repr__(self) -> str:
        return (
            f"IKQP(task={self.task!r}, n={self.n}, damping={self.damping:g}, max_step={self.max_step:g}, "
            f"dt={self.dt:g})"
        )


def _bounded_difference(q: np.ndarray, q_new: np.ndarray, s: Any) -> np.ndarray:
    """``q_new − q`` nudged towards zero until ``|dq| ≤ s`` and ``q + dq`` equals a point inside
    the box ``q_new`` came from, despite rounding (zero satisfies both, so this terminates)."""
    dq = q_new - q
    s = np.broadcast_to(np.asarray(s, dtype=float), dq.shape)
    lo, hi = np.minimum(q, q_new), np.maximum(q, q_new)
    for _ in range(8):
        bad = (np.abs(dq) > s) | (q + dq < lo) | (q + dq > hi)
        if not bad.any():
            return dq
        dq[bad] = np.nextafter(dq[bad], 0.0)
    return np.where(bad, 0.0, dq)


def _check_options(n: int, k: int, velocity_limit: Any, weights: Any, control_iters: Any) -> tuple:
    """``(velocity_limit (n,), weights (k,), control_iters)`` validated (messages name the argument)."""
    if np.ndim(velocity_limit) == 0:
        vlim = np.full(n, check_positive("velocity_limit", velocity_limit))
    else:
        vlim = as_vector("velocity_limit", velocity_limit, n)
    if not np.all(np.isfinite(vlim)) or np.any(vlim <= 0):
        raise InvalidArgument(f"velocity_limit must be positive and finite, got {velocity_limit!r}")
    if weights is None:
        w = np.ones(k)
    elif np.ndim(weights) == 0:
        w = np.full(k, check_nonnegative("weights", weights))
    else:
        w = as_vector("weights", weights, k)
        if np.any(w < 0):
            raise InvalidArgument(f"weights must be >= 0, got {w.tolist()}")
    if not isinstance(control_iters, int) or control_iters < 1:
        raise InvalidArgument(f"control_iters must be a positive integer, got {control_iters!r}")
    return vlim, w, control_iters
