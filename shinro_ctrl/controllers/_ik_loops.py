"""The iteration loops of :class:`~shinro_ctrl.controllers.ik_qp.IKQP`: solve to a tolerance, track for one step.

:class:`IKLoops` is a mixin of ``IKQP``: it repeats ``IKQP``'s one-iteration
QP step (kinematics, task error, box QP) inside a bounded step, either to
convergence with random restarts (:meth:`IKLoops.solve`, inverse kinematics) or
for the few iterations of one control step inside the velocity box
(:meth:`IKLoops.track`).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import osqp

from shinro_ctrl.controllers._ik_parts import IKStep
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.kinematics import IKResult
from shinro_ctrl.validation import check_positive

__all__ = ["IKLoops"]


class IKLoops:
    """``solve`` (IK to a tolerance, with restarts) and ``track`` (one control step) of ``IKQP`` (a mixin)."""

    n: int
    k: int
    last: IKStep | None

    def solve(
        self,
        T_target: Any,
        q0: Any,
        *,
        max_iters: int = 100,
        tol: float = 1e-4,
        restarts: int = 0,
        seed: int | None = None,
    ) -> IKResult:
        """Iterate QP steps from ``q0`` until the pose error is below ``tol``.

        Each iteration may move a joint by at most
        :attr:`~shinro_ctrl.controllers.ik_qp.IKQP.max_step`. If the first attempt does not
        converge, up to ``restarts`` further attempts start from random joint vectors
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
        q0 = self._joints(q0, "q0")
        pt, Rt = self._target(T_target, "T_target")
        if not isinstance(max_iters, int) or max_iters < 0:
            raise InvalidArgument(f"max_iters must be a non-negative integer, got {max_iters!r}")
        if not isinstance(restarts, int) or restarts < 0:
            raise InvalidArgument(f"restarts must be a non-negative integer, got {restarts!r}")
        tol = check_positive("tol", tol)
        self._qp.reset()  # the same call gives the same answer, whatever was solved before
        pt = pt.tolist()
        best, total = self._attempt(q0, pt, Rt, max_iters, tol)
        attempts = 1
        rng = None
        while not best[1] and attempts <= restarts:
            rng = rng or np.random.default_rng(0 if seed is None else seed)
            res, its = self._attempt(rng.uniform(self._sample_lo, self._sample_hi), pt, Rt, max_iters, tol)
            total += its
            attempts += 1
            if res[1] or res[4] < best[4]:
                best = res
        q, converged, pos_err, ori_err, _ = best
        if q is not self._evaluated:  # a restart was run after the best attempt
            self._evaluate(q)
        return IKResult(q, converged, total, pos_err, ori_err, self._J[: self.k].copy(), attempts)

    def _attempt(
        self, q: np.ndarray, pt: Any, Rt: np.ndarray, max_iters: int, tol: float
    ) -> tuple[tuple[np.ndarray, bool, float, float, float], int]:
        """One local solve; returns ``((q, converged, pos_err, ori_err, cost), iterations)``."""
        lo, hi, s, neg_s = self.lo, self.hi, self._s_solve, self._neg_s_solve
        w0, w1, w2 = self.weights[:3].tolist()
        w3, w4, w5 = self.weights[3:].tolist() if self.k == 6 else (0.0, 0.0, 0.0)
        pose = self.k == 6
        best_cost = math.inf
        stalled = 0
        it = 0
        while True:
            self._evaluate(q)
            pos_err, ori_err = self._error(pt, Rt)
            if pos_err < tol and (ori_err < tol or not pose):
                return (q, True, pos_err, ori_err, 0.0), it
            e0, e1, e2, e3, e4, e5 = self._et
            cost = w0 * e0 * e0 + w1 * e1 * e1 + w2 * e2 * e2 + w3 * e3 * e3 + w4 * e4 * e4 + w5 * e5 * e5
            if cost < best_cost * (1.0 - 1e-6):
                best_cost, stalled = cost, 0
            else:
                stalled += 1
            if it >= max_iters or stalled >= 10:
                return (q, False, pos_err, ori_err, cost), it
            scale = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2 + (e3 * e3 + e4 * e4 + e5 * e5 if pose else 0.0))
            q, _ = self._qp_step(q, lo, hi, s, neg_s, scale)
            it += 1

    # -------------------------------------------------------------- control
    def track(self, q: Any, target: Any, *, iters: int | None = None, tol: float = 1e-9) -> np.ndarray:
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
        t0 = time.perf_counter()
        q0 = self._joints(q, "q")
        pt, Rt = self._target(target)
        iters = self.control_iters if iters is None else int(iters)
        pt = pt.tolist()
        vdt = self.velocity_limit * self.dt
        neg_vdt = -vdt
        box_lo = np.maximum(self.lo, q0 - vdt)
        box_hi = np.minimum(self.hi, q0 + vdt)
        q = q0
        status = -1
        it = 0
        while True:
            self._evaluate(q)
            pos_err, ori_err = self._error(pt, Rt)
            if it >= iters or self._converged(pos_err, ori_err, tol):
                break
            scale = math.hypot(pos_err, ori_err) if self.k == 6 else pos_err
            q, status = self._qp_step(q, box_lo, box_hi, vdt, neg_vdt, scale)
            it += 1
        name = osqp.SolverStatus(status).name if status >= 0 else "not run"
        self.last = IKStep(q.copy(), q - q0, it, pos_err, ori_err, name, time.perf_counter() - t0)
        return q
