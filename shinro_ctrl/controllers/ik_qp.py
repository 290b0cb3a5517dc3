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
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import osqp

from shinro_ctrl.controllers._ik_loops import solve_to_tolerance, track_step
from shinro_ctrl.controllers._ik_parts import IKKernel, IKProblem, IKStep
from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.kinematics import IKResult, euler_zyx_from_matrix, wrap_angle
from shinro_ctrl.validation import as_vector, check_nonnegative, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.plants.armrobot import ArmRobot

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


class IKQP(Controller):
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

    Threads: one object may be shared. A lock serializes the calls that use the kernel's
    buffers (:meth:`solve`, :meth:`step`, :meth:`track`, :meth:`build_qp`, ``__call__``,
    :meth:`reset`), so concurrent calls give the answers of some serial order (the lock
    costs about 0.1 µs of an iteration's 50–100 µs). :meth:`solve` resets the warm start,
    so its answer does not depend on that order beyond OSQP's tolerance; :attr:`last` is
    the last call's of any thread.

    Attributes:
        last: :class:`IKStep` of the last control call, or None.
        lo, hi: Joint limits ``(n,)`` [rad].
        preview: 1: a simulation loop may pass ``ref`` as the rows ``[r(t), r(t + dt)]``;
            the controller then aims at ``r(t + dt)``, removing one step of delay.

    Raises:
        InvalidArgument: an invalid option (the message names it), including an unknown OSQP
            setting. (``InvalidArgument`` is a ``ValueError``.)
    """

    stateful = True  # the QP's warm start and the last control step

    def __init__(
        self,
        arm: ArmRobot,
        *,
        damping: float = 1e-4,
        velocity_limit: float | Sequence[float] | np.ndarray = math.pi,
        dt: float | None = None,
        max_step: float = 0.5,
        task: str = "pose",
        weights: float | Sequence[float] | np.ndarray | None = None,
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
        settings = dict(DEFAULT_OSQP_SETTINGS)
        settings.update(osqp_settings or {})
        #: The kinematics, task error and box QP of one iteration, with their buffers.
        self.kernel = IKKernel(arm, k, self.weights, self.damping, settings)
        self.lo, self.hi = self.kernel.lo, self.kernel.hi
        self._lock = threading.Lock()  # the kernel's buffers serve one call at a time
        self.last: IKStep | None = None
        self.preview = 1
        self.u_min = None
        self.u_max = None

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
        plant: ArmRobot,
        *,
        damping: float = 1e-4,
        velocity_limit: float | Sequence[float] | np.ndarray = math.pi,
        dt: float | None = None,
        max_step: float = 0.5,
        task: str = "pose",
        weights: float | Sequence[float] | np.ndarray | None = None,
        osqp_settings: dict[str, Any] | None = None,
        control_iters: int = 3,
    ) -> IKQP:
        """Build the controller of a scenario for an arm (same options as the constructor).

        The controller never changes the plant. To make ``plant.step(u)`` turn the twist
        this controller returns back into exactly the joint targets it computed, the arm
        is built with it as its IK (``ArmRobot(ik=lambda arm: IKQP.from_plant(arm, ...))``);
        :class:`~shinro_ctrl.sim.RobotSim` builds a scenario's arm that way.
        """
        return cls(
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

    # ------------------------------------------------------------------ API
    def solve(
        self,
        T_target: ArrayLike,
        q0: ArrayLike,
        *,
        max_iters: int = 100,
        tol: float = 1e-4,
        restarts: int = 0,
        seed: int | None = None,
    ) -> IKResult:
        """Iterate QP steps from ``q0`` until the pose error is below ``tol``.

        Each iteration may move a joint by at most :attr:`max_step`. If the first attempt
        does not converge, up to ``restarts`` further attempts start from random joint vectors
        drawn uniformly inside the limits (``numpy.random.default_rng(seed)``;
        ``seed=None`` means seed 0, so results are reproducible); the best attempt (converged,
        else the smallest weighted error) is returned. An attempt also stops early when its
        error has not decreased for 10 iterations (a limit or a local minimum).

        Args:
            T_target: Target transform ``(4, 4)`` (or pose ``(6,)``; a point ``(3,)`` for the
                position task).
            q0: Start joints ``(n,)`` [rad] (clipped to the limits).
            max_iters: Iterations per attempt.
            tol: Tolerance on the position [m] and orientation [rad] errors.
            restarts: Extra attempts from random starts (>= 0).
            seed: Seed of the restart generator.

        Returns:
            :class:`IKResult`; ``q`` is inside the limits even when not converged (then it is
            the closest configuration found). An unreachable target is not an error. The
            solver's warm start is reset first, so the result depends only on the arguments.
        """
        kernel = self.kernel
        q0 = kernel.joints(q0, "q0")
        pt, Rt = kernel.target(T_target, "T_target")
        if not isinstance(max_iters, int) or max_iters < 0:
            raise InvalidArgument(f"max_iters must be a non-negative integer, got {max_iters!r}")
        if not isinstance(restarts, int) or restarts < 0:
            raise InvalidArgument(f"restarts must be a non-negative integer, got {restarts!r}")
        tol = check_positive("tol", tol)
        with self._lock:
            return solve_to_tolerance(
                kernel, q0, pt.tolist(), Rt, self._s_solve, self._neg_s_solve,
                max_iters=max_iters, tol=tol, restarts=restarts, seed=seed,
            )  # fmt: skip

    def track(self, q: ArrayLike, target: ArrayLike, *, iters: int | None = None, tol: float = 1e-9) -> np.ndarray:
        """Joint targets for one control step: move from ``q`` towards ``target``.

        Up to ``iters`` (default :attr:`control_iters`) QP iterations, all inside the box
        ``|q' − q| ≤ velocity_limit · dt`` and the joint limits; stops early below ``tol``.
        The outcome is stored in :attr:`last`.

        Args:
            q: Joint angles at the start of the step ``(n,)`` [rad].
            target: Transform ``(4, 4)``, pose ``(6,)``, or (position task) point ``(3,)``.

        Returns:
            Joint targets ``(n,)`` [rad], inside the limits.
        """
        with self._lock:
            return self._track(q, target, iters, tol)

    def _track(self, q: ArrayLike, target: ArrayLike, iters: int | None, tol: float) -> np.ndarray:
        t0 = time.perf_counter()
        kernel = self.kernel
        q0 = kernel.joints(q, "q")
        pt, Rt = kernel.target(target)
        n_iters = self.control_iters if iters is None else int(iters)
        q_new, it, status, pos_err, ori_err = track_step(
            kernel, q0, pt.tolist(), Rt, self.velocity_limit * self.dt, iters=n_iters, tol=tol
        )
        name = osqp.SolverStatus(status).name if status >= 0 else "not run"
        self.last = IKStep(q_new.copy(), q_new - q0, it, pos_err, ori_err, name, time.perf_counter() - t0)
        return q_new

    def build_qp(self, q: ArrayLike, target: ArrayLike, *, max_step: float | ArrayLike | None = None) -> IKProblem:
        """The QP of one iteration at joints ``q (n,)`` towards ``target``, without solving it.

        Args:
            q: Joint angles ``(n,)`` [rad] (clipped to the limits).
            target: Transform ``(4, 4)``, pose ``(6,)``, or (position task) point ``(3,)``.
            max_step: Step bound ``s`` [rad], scalar or ``(n,)`` (default :attr:`max_step`).
        """
        kernel = self.kernel
        q = kernel.joints(q, "q")
        pt, Rt = kernel.target(target)
        s = self.max_step if max_step is None else np.asarray(max_step, dtype=float)
        k = self.k
        with self._lock:
            kernel.evaluate(q)
            kernel.error(pt, Rt)
            J = kernel.J[:k].copy()
            e = kernel.e[:k].copy()
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

    def step(self, q: ArrayLike, target: ArrayLike, *, max_step: float | ArrayLike | None = None) -> np.ndarray:
        """Solve one QP: the joint change ``dq (n,)`` [rad] from ``q`` towards ``target``.

        ``q + dq`` lies inside the joint limits and ``|dq| ≤ max_step``, both exactly (in
        floating point).

        Args:
            q: Joint angles ``(n,)`` [rad] (clipped to the limits first).
            target: Transform ``(4, 4)``, pose ``(6,)``, or (position task) point ``(3,)``.
            max_step: Step bound [rad], scalar or ``(n,)`` (default :attr:`max_step`).
        """
        kernel = self.kernel
        q = kernel.joints(q, "q")
        pt, Rt = kernel.target(target)
        if max_step is None:
            s, neg_s = self._s_solve, self._neg_s_solve
        else:
            s = np.broadcast_to(np.asarray(max_step, dtype=float), (self.n,))
            neg_s = -s
        with self._lock:
            kernel.evaluate(q)
            pos_err, ori_err = kernel.error(pt.tolist(), Rt)
            scale = math.hypot(pos_err, ori_err) if self.k == 6 else pos_err
            if scale == 0.0:
                return np.zeros(self.n)
            q_new, _ = kernel.qp_step(q, self.lo, self.hi, s, neg_s, scale)
        return _bounded_difference(q, q_new, s)

    def __call__(self, x: ArrayLike, ref: ArrayLike | None = None) -> np.ndarray:
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
        kernel = self.kernel
        with self._lock:
            q = self._track(self.arm.q_cmd, ref, None, 1e-9)
            kernel.evaluate(q)
            pose = np.concatenate([kernel.p, euler_zyx_from_matrix(kernel.R)])
        u = (pose - x) / self.dt
        u[3:] = wrap_angle(pose[3:] - x[3:]) / self.dt
        return u

    def reset(self) -> None:
        """Forget the warm start and :attr:`last`."""
        with self._lock:
            self.kernel.qp.reset()
            self.last = None

    def __repr__(self) -> str:
        return (
            f"IKQP(task={self.task!r}, n={self.n}, damping={self.damping:g}, max_step={self.max_step:g}, "
            f"dt={self.dt:g})"
        )


def _bounded_difference(q: np.ndarray, q_new: np.ndarray, s: float | np.ndarray) -> np.ndarray:
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


def _check_options(
    n: int,
    k: int,
    velocity_limit: float | Sequence[float] | np.ndarray,
    weights: float | Sequence[float] | np.ndarray | None,
    control_iters: int,
) -> tuple[np.ndarray, np.ndarray, int]:
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
