"""The real-time iteration of :class:`~shinro_ctrl.controllers.nmpc.NonlinearMPC`: prepare, feedback, SQP merit.

:class:`NMPCRealTime` is a mixin of ``NonlinearMPC`` (it reads the controller's
model, weights, buffers and QP). **prepare** shifts the previous solution,
linearizes all stages in one compiled call and condenses the QP; **feedback**
solves the QP for the measured state and takes the step (with ``iterations >
1`` an ℓ1-merit Armijo line search and more SQP iterations follow). The module
docstring of ``controllers/nmpc.py`` states the OCP.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import MPCInfeasible

__all__ = ["NMPCRealTime"]


class NMPCRealTime:
    """Prepare/feedback phases and the SQP line search of ``NonlinearMPC`` (a mixin)."""

    n: int
    m: int
    N: int
    last: NMPCSolution | None

    def _linearize(self) -> None:
        """Defects and Jacobians of all stages at ``(X̄, Ū)`` (one compiled call)."""
        self._eval()

    def _condense(self) -> None:
        N, n = self.N, self.n
        np.subtract(self._X[1:].reshape(N, n), self._ref, out=self._e.reshape(N, n))
        np.subtract(self._U, self.u0, out=self._du.reshape(N, self.m))
        with np.errstate(over="ignore", invalid="ignore"):  # a diverged prediction is reported by feedback
            self.qp.build(self._e, self._du)
        self.qp.set_bounds(self._U, self._X[1:])

    def _shift(self) -> None:
        X, U = self._X, self._U
        X[:-1] = X[1:]
        U[:-1] = U[1:]

    def prepare(self) -> None:
        """Preparation phase: shift the previous solution and linearize/condense for the next state.

        Called by :meth:`~shinro_ctrl.controllers.nmpc.NonlinearMPC.__call__` after each feedback; call it yourself to
        overlap it with the time before the next measurement.
        """
        t0 = time.perf_counter()
        if self.solver == "ipopt" or not self._started:
            return
        if not self._prepared:
            self._shift()
        t1 = time.perf_counter()
        self._linearize()
        t2 = time.perf_counter()
        self._condense()
        t3 = time.perf_counter()
        self._prepared = True
        self._t_prep = (t2 - t1, t3 - t2, t1 - t0)

    def feedback(self, x: Any, ref: Any = None) -> np.ndarray:
        """Feedback phase: solve the prepared QP for the measured ``x (n,)`` and take the step.

        With ``iterations > 1`` SQP iterations follow until the KKT residual is
        below ``tol``. The first call after :meth:`~shinro_ctrl.controllers.nmpc.NonlinearMPC.reset` starts cold (see
        ``cold_start``).

        Returns:
            The input ``u (m,)`` clipped to ``[u_min, u_max]``.
        """
        t_start = time.perf_counter()
        x = self._check_x(x, ref)
        if self.solver == "ipopt":
            return self._solve_ipopt(x, t_start)
        t_lin = t_cond = 0.0
        fresh = not self._started
        budget, cold, t_qp = self._begin(x) if fresh else (self.iterations, False, 0.0)
        if not self._prepared:
            if not fresh:
                self._shift()
            t0 = time.perf_counter()
            self._linearize()
            t1 = time.perf_counter()
            self._condense()
            t_lin, t_cond = t1 - t0, time.perf_counter() - t1
        self._prepared = False
        dx0 = x - self._X[0]
        status = "rti"
        kkt = math.inf
        it = 0
        qp_status = ""
        qp_it = 0
        while True:
            t0 = time.perf_counter()
            z, ok, qp_status, qp_it = self.qp.solve(dx0)
            t_qp += time.perf_counter() - t0
            it += 1
            if not ok:
                self._fail(x, qp_status, t_start)
            kkt = max(self.qp.kkt(z), float(np.max(np.abs(self._D))), float(np.max(np.abs(dx0))))
            if it > 1 and kkt < self.tol:
                status = "solved"
                break
            self._step(x, z, dx0, line_search=it > 1 or cold)
            if it >= budget:
                break
            dx0 = np.zeros(self.n)
            t0 = time.perf_counter()
            self._linearize()
            t1 = time.perf_counter()
            self._condense()
            t_lin += t1 - t0
            t_cond += time.perf_counter() - t1
        u = np.clip(self._U[0], self.u_min, self.u_max)
        total = time.perf_counter() - t_start
        self.last = NMPCSolution(
            status=status,
            iterations=it,
            kkt_residual=kkt,
            qp_status=qp_status,
            qp_iterations=qp_it,
            time_linearization_s=t_lin,
            time_condensing_s=t_cond,
            time_qp_s=t_qp,
            time_other_s=total - t_lin - t_cond - t_qp,
            solve_time_s=total,
            states=self._X.copy(),
            inputs=self._U.copy(),
            u=u,
            objective=self.objective(self._X, self._U),
        )
        return u

    def _begin(self, x: np.ndarray) -> tuple[int, bool, float]:
        """The first trajectory after ``reset()``: ``(SQP budget, cold, IPOPT time)`` (see ``cold_start``)."""
        t_qp = 0.0
        self._prepared = False
        if self.cold_start == "ipopt":
            t0 = time.perf_counter()
            self._ipopt_guess = None
            X, U, _, _ = self._ipopt_solve(x)
            t_qp += time.perf_counter() - t0
            self._X[:] = X
            self._U[:] = U
            budget, cold = self.iterations, False
        else:
            self._X[:] = x
            self._U[:] = np.clip(self.u0, self.u_min, self.u_max)
            budget, cold = self.init_iterations, True
        self._started = True
        return budget, cold, t_qp

    def _step(self, x: np.ndarray, z: np.ndarray, dx0: np.ndarray, *, line_search: bool) -> None:
        N, m = self.N, self.m
        dU, dX = self.qp.step(z, dx0)
        if line_search:
            alpha = self._line_search(dX, dU.reshape(N, m), z)
        else:
            alpha = 1.0
        self._X[0] = x
        self._X[1:] += alpha * dX
        self._U += alpha * dU.reshape(N, m)

    # ============================================================= SQP merit
    def objective(self, X: np.ndarray, U: np.ndarray) -> float:
        """The OCP cost of a trajectory ``X (N + 1, n)``, ``U (N, m)`` (slack terms included)."""
        E = X - self._ref
        dU = U - self.u0
        J = 0.5 * float(np.einsum("ki,ij,kj->", E[:-1], self.Q, E[:-1]))
        J += 0.5 * float(E[-1] @ self.Qf @ E[-1])
        J += 0.5 * float(np.einsum("ki,ij,kj->", dU, self.R, dU))
        if self.soft:
            s = np.maximum(np.max(X[1:] - self.x_max, axis=0), np.max(self.x_min - X[1:], axis=0))
            s = np.maximum(s[np.isfinite(s)], 0.0)
            J += self.soft_weights[0] * float(s.sum()) + 0.5 * self.soft_weights[1] * float(s @ s)
        return J

    def _multiplier_bound(self, dX: np.ndarray) -> float:
        """``‖λ‖_∞`` of the dynamics multipliers of the QP solution (backward recursion)."""
        N, n = self.N, self.n
        qp = self.qp
        if hasattr(qp, "dynamics_multipliers"):  # the sparse QP has them
            return float(np.max(np.abs(qp.dynamics_multipliers())))
        nu_rows = qp.state_bound_multipliers()
        Xp = self._X[1:] + dX - self._ref
        lam_next = np.zeros(n)
        big = 0.0
        for k in range(N - 1, -1, -1):
            lam_k = self.W[k] @ Xp[k] + nu_rows[k]
            if k + 1 < N:
                lam_k += lam_next @ self._A[k + 1]
            big = max(big, float(np.max(np.abs(lam_k))))
            lam_next = lam_k
        return big

    def _line_search(self, dX: np.ndarray, dU: np.ndarray, z: np.ndarray) -> float:
        self._mu = max(self._mu, 1.5 * self._multiplier_bound(dX) + 1e-6)
        mu = self._mu
        X0, U0 = self._X.copy(), self._U.copy()
        defect0 = float(np.abs(self._D).sum())
        phi0 = self.objective(X0, U0) + mu * defect0
        E = X0 - self._ref
        grad = float(np.einsum("ki,ij,kj->", E[1:-1], self.Q, dX[:-1])) + float(E[-1] @ self.Qf @ dX[-1])
        grad += float(np.einsum("ki,ij,kj->", U0 - self.u0, self.R, dU))
        slope = grad - mu * defect0
        alpha = 1.0
        for _ in range(30):
            self._X[1:] = X0[1:] + alpha * dX
            self._U[:] = U0 + alpha * dU
            self._linearize()
            phi = self.objective(self._X, self._U) + mu * float(np.abs(self._D).sum())
            # the last term absorbs rounding of phi near convergence (else tiny steps stall the iteration)
            if phi <= phi0 + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * max(1.0, abs(phi0)):
                break
            alpha *= 0.5
        self._X[:] = X0
        self._U[:] = U0
        return alpha

    def _fail(self, x: np.ndarray, status: str, t_start: float) -> None:
        message = f"NonlinearMPC: the QP failed ({status}) at x = {np.array2string(x, precision=4)}"
        reason = self.qp.explain()
        if reason:
            message += f"; {reason}"
        self.last = NMPCSolution(
            status=status, iterations=0, kkt_residual=math.nan, qp_status=status, qp_iterations=0,
            time_linearization_s=0.0, time_condensing_s=0.0, time_qp_s=0.0, time_other_s=0.0,
            solve_time_s=time.perf_counter() - t_start, states=self._X.copy(), inputs=self._U.copy(),
            u=np.full(self.m, np.nan), objective=math.nan, message=message,
        )  # fmt: skip
        self._started = False  # the next call starts cold
        raise MPCInfeasible(message)
