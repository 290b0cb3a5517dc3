"""The real-time iteration strategy of :class:`~shinro_ctrl.controllers.nmpc.NonlinearMPC`: prepare, feedback, SQP.

:class:`RealTimeIteration` owns the trajectory ``(X̄, Ū)``, the stage
matrices ``G_k = [A_k, B_k, d_k]`` the compiled linearization writes into, and
the LTV QP (condensed with DAQP, or sparse with OSQP). **prepare** shifts the
previous solution, linearizes all stages in one compiled call and condenses
the QP (or, with the Riccati step first, runs the backward Riccati recursion);
**solve** (the feedback) solves the QP for the measured state (with the Riccati
step first: the policy's rollout, and where it breaks a bound the QP in the
policy's prestabilized variables, :class:`PrestabilizedLTV`) and takes the step
(with ``iterations > 1`` an ℓ1-merit Armijo line search and more SQP
iterations follow). The module docstring of ``controllers/nmpc.py`` states the
OCP.
"""

from __future__ import annotations

import math
import time

import numpy as np

from shinro_ctrl.controllers._nmpc_ipopt import IpoptSolver
from shinro_ctrl.controllers._nmpc_ocp import NMPCProblem, failed_solution, riccati_functions
from shinro_ctrl.controllers.qp.condensed import DAQP_STATUS
from shinro_ctrl.controllers.qp.ltv import CondensedLTV, SparseLTV
from shinro_ctrl.controllers.qp.prestabilized import PrestabilizedLTV
from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import MPCInfeasible

__all__ = ["RealTimeIteration"]


class RealTimeIteration:
    """Real-time iterations (or SQP) on the LTV QP of the OCP (an :class:`~._nmpc_ocp.NMPCStrategy`).

    Args:
        ocp: The problem (its options are read whole: ``solver`` picks the QP,
            ``iterations``, ``tol``, ``cold_start`` … the iteration).

    Attributes:
        X: The trajectory's states ``(N + 1, n)`` (the linearization point).
        U: Its inputs ``(N, m)``.
        A: Stage Jacobians ``∂F/∂x`` ``(N, n, n)`` at ``(X, U)`` (views of one buffer).
        B: Stage Jacobians ``∂F/∂u`` ``(N, n, m)``.
        D: Shooting defects ``F(x̄_k, ū_k) − x̄_{k+1}`` ``(N, n)``.
        qp: The LTV QP (:class:`CondensedLTV` or :class:`SparseLTV`).
    """

    def __init__(self, ocp: NMPCProblem):
        self.ocp = ocp
        o = ocp.options
        n, m, N = ocp.n, ocp.m, ocp.N
        nt = ocp.nt  # the QP's state dimension: n, or the tangent dimension on a floating base
        self.X = np.zeros((N + 1, n))
        self.U = np.zeros((N, m))
        self._G = np.zeros((N, nt, nt + m + 1))  # [A_k, B_k, d_k] of every stage
        self.A = self._G[:, :, :nt]
        self.B = self._G[:, :, nt : nt + m]
        self.D = self._G[:, :, nt + m]
        x_min, x_max = o.x_min, o.x_max
        # on a floating base the compiled linearization writes the full-state [F_x, F_u, F̄ − x̄⁺] here, and
        # _tangent_stages maps it into _G (StateManifold); the state-bound offsets are then unused zeros
        self._Gfull = self._G if ocp.manifold is None else np.zeros((N, n, n + m + 1))
        self._buf, eval_full = ocp.linearization.buffer()
        self._buf.set_arg(0, memoryview(self.X))
        self._buf.set_arg(1, memoryview(self.U))
        self._buf.set_res(0, memoryview(self._Gfull))
        if ocp.manifold is None:
            self._eval = eval_full
            self._xb = self.X[1:]
        else:
            self._eval_full = eval_full
            self._eval = self._tangent_stages
            self._xb = np.zeros((N, nt))
            self._J = np.tile(np.eye(nt), (N + 1, 1, 1))  # the chart Jacobians J_k (StateManifold)
            self._Jinv = self._J.copy()
            x_min, x_max = np.full(nt, -np.inf), np.full(nt, np.inf)
        self._e = np.zeros(N * nt)
        self._du = np.zeros(N * m)
        self._ref = ocp.x0.copy()
        self.qp: CondensedLTV | SparseLTV
        soft = dict(soft=o.soft, soft_weight_l1=o.soft_weight_l1, soft_weight_quad=o.soft_weight_quad)
        if o.solver == "osqp":
            settings = dict(o.osqp_settings) if o.osqp_settings is not None else None
            self.qp = SparseLTV(
                self._G, ocp.Q, ocp.W, ocp.R, o.u_min, o.u_max, x_min, x_max, osqp_settings=settings, **soft
            )
        else:
            self.qp = CondensedLTV(self._G, ocp.W, ocp.R, o.u_min, o.u_max, x_min, x_max, **soft)
        self._ipopt: IpoptSolver | None = None  # the cold start's, built on first use
        # large condensed QPs with compiled stage functions: the Riccati step first (_riccati_step; in CasADi's
        # virtual machine the recursion costs more than the condensing it saves)
        auto = ocp.compiled and not self.qp.direct if isinstance(self.qp, CondensedLTV) else False
        self.riccati = isinstance(self.qp, CondensedLTV) and (auto if o.riccati is None else bool(o.riccati))
        if self.riccati:
            self._init_riccati()
        self.reset()

    def _init_riccati(self) -> None:
        """Bind the compiled Riccati recursion's buffers (:func:`~._nmpc_ocp.riccati_functions`) once."""
        ocp = self.ocp
        n, m, N = ocp.nt, ocp.m, ocp.N
        back, fwd = riccati_functions(n, m, N, codegen=True)
        # CasADi reads column-major: the C-ordered transposes are the matrices themselves
        self._Wt = np.ascontiguousarray(np.swapaxes(ocp.W, 1, 2))
        self._Rt = np.ascontiguousarray(ocp.R.T)
        self._KK = np.zeros((N * (n + 1), m))  # the blocks [K_k, κ_k], transposed
        self._K = np.swapaxes(self._KK.reshape(N, n + 1, m)[:, :n, :], 1, 2)  # K_k (N, m, n): a view
        self._Re = np.zeros((N, m, m))  # R + B_kᵀ S_k B_k (symmetric: the column-major blocks are themselves)
        self._fX = np.zeros((N, n))  # the free response from Δx_0
        self._dx0 = np.zeros(n)
        self._dU = np.zeros((N, m))
        self._dX = np.zeros((N, n))
        self._g = np.zeros((N, m))
        self._rbuf, self._back = back.buffer()
        for i, a in enumerate((self._G, self._Wt, self._Rt, self._e, self._du)):
            self._rbuf.set_arg(i, memoryview(a))
        self._rbuf.set_res(0, memoryview(self._KK))
        self._rbuf.set_res(1, memoryview(self._Re))
        self._fbuf, self._fwd = fwd.buffer()
        for i, a in enumerate((self._G, self._KK, self._Wt, self._Rt, self._e, self._du, self._dx0)):
            self._fbuf.set_arg(i, memoryview(a))
        for i, a in enumerate((self._dU, self._dX, self._g, self._fX)):
            self._fbuf.set_res(i, memoryview(a))
        nu = N * m
        qp = self.qp
        assert isinstance(qp, CondensedLTV)
        o = ocp.options
        xmin = np.broadcast_to(o.x_min if ocp.manifold is None else -np.inf, (n,))
        xmax = np.broadcast_to(o.x_max if ocp.manifold is None else np.inf, (n,))
        # the QP where the Riccati step breaks a bound, in the policy's prestabilized variables (well conditioned)
        self._pqp = PrestabilizedLTV(
            self._G,
            o.u_min,
            o.u_max,
            np.asarray(xmin, dtype=float),
            np.asarray(xmax, dtype=float),
            soft=o.soft,
            soft_weight_l1=o.soft_weight_l1,
            soft_weight_quad=o.soft_weight_quad,
            warm_start=qp.warm_start,
        )
        self._lo = qp.bl[:nu].reshape(N, m)  # ΔU bounds (views: set_bounds fills them)
        self._hi = qp.bu[:nu].reshape(N, m)
        # bounded state components: the predicted X̄₁…X̄_N + ΔX must lie within them too
        self._xcols = qp.bounded
        self._xlo = np.asarray(xmin, dtype=float)[self._xcols]
        self._xhi = np.asarray(xmax, dtype=float)[self._xcols]
        self._xpred = np.zeros((N, self._xcols.size))

    def reset(self) -> None:
        """Forget the trajectory: the next solve starts cold (see ``cold_start``)."""
        self._started = False
        self._prepared = False
        self._mu = 0.0
        if isinstance(self.qp, CondensedLTV):
            self.qp.clear_active_set()
        if self.riccati:
            self._pqp.mark_unconstrained()

    # ================================================================ phases
    def _tangent_stages(self) -> None:
        """A floating base's stages in the tangent space (see :class:`~._nmpc_ocp.StateManifold`).

        From the full-state ``[F_x, F_u, F̄_k − x̄_{k+1}]`` of the compiled linearization:
        ``A_k = D(F̄_k) F_x E(x̄_k)``, ``B_k = D(F̄_k) F_u``, ``d_k = difference(F̄_k, x̄_{k+1})``, then in the
        QP's variables ``J_k δ_k`` (the chart Jacobians at the reference: exact Gauss-Newton cost).
        """
        self._eval_full()
        man = self.ocp.manifold
        assert man is not None
        n, m = self.ocp.n, self.ocp.m
        Gf, X = self._Gfull, self.X
        Fbar = Gf[:, :, n + m] + X[1:]
        for k in range(self.ocp.N):
            D, _ = man.tangent_maps(Fbar[k])
            _, E = man.tangent_maps(X[k])
            self.A[k] = D @ Gf[k, :, :n] @ E
            self.B[k] = D @ Gf[k, :, n : n + m]
        self.D[:] = man.difference(Fbar, X[1:])
        E = man.difference(X, self._ref)
        for k in range(self.ocp.N + 1):
            self._J[k] = man.chart_jacobian(E[k])
            self._Jinv[k] = np.linalg.inv(self._J[k])
        for k in range(self.ocp.N):
            self.A[k] = self._J[k + 1] @ self.A[k] @ self._Jinv[k]
            self.B[k] = self._J[k + 1] @ self.B[k]
            self.D[k] = self._J[k + 1] @ self.D[k]

    def _advance(self, Xbase: np.ndarray, dX: np.ndarray, alpha: float) -> np.ndarray:
        """``x̄_{1..N}`` moved by ``α ΔX`` (the QP's variables: on a floating base ``retract(x̄_k, α J_k⁻¹ ΔX_k)``)."""
        man = self.ocp.manifold
        if man is None:
            return Xbase + alpha * dX
        return man.retract(Xbase, alpha * np.einsum("kij,kj->ki", self._Jinv[1:], dX))

    def _condense(self) -> None:
        N, n = self.ocp.N, self.ocp.nt
        if self.ocp.manifold is None:
            np.subtract(self.X[1:].reshape(N, n), self._ref, out=self._e.reshape(N, n))
        else:
            self._e.reshape(N, n)[:] = self.ocp.manifold.difference(self.X[1:], self._ref)
        np.subtract(self.U, self.ocp.u0, out=self._du.reshape(N, self.ocp.m))
        if self.riccati:  # no condensed QP: where a bound is reached, the prestabilized one (_riccati_step)
            self._back()
        else:
            self._build()
        self.qp.set_bounds(self.U, self._xb)

    def _build(self) -> None:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverged prediction is reported by solve
            self.qp.build(self._e, self._du)

    def _riccati_step(self, dx0: np.ndarray) -> bool:
        """The unconstrained minimizer of the prepared QP by the Riccati policy; True when it meets the bounds.

        The QP is convex, so a minimizer of its cost that meets every bound is its solution (all
        multipliers zero; soft state bounds: every slack at zero): then no QP is solved. Otherwise ``solve``
        solves the QP around this step in the policy's prestabilized variables (:class:`PrestabilizedLTV`:
        block-diagonal Hessian, the condensed one is never formed). The bounds are the inputs' and the predicted states'
        ``X̄₁…X̄_N + ΔX`` on the bounded components. ``ΔU``, ``ΔX`` and the gradient at ``ΔU = 0`` are left in
        ``_dU``, ``_dX``, ``_g``.
        """
        self._dx0[:] = dx0
        self._fwd()
        if not np.all((self._dU >= self._lo) & (self._dU <= self._hi)):  # False on NaN
            return False
        if self._xcols.size:
            xp = self._xpred
            np.add(self.X[1:, self._xcols], self._dX[:, self._xcols], out=xp)
            if not np.all((xp >= self._xlo) & (xp <= self._xhi)):
                return False
        self._pqp.mark_unconstrained()
        return True

    def _shift(self) -> None:
        X, U = self.X, self.U
        X[:-1] = X[1:]
        U[:-1] = U[1:]
        if isinstance(self.qp, CondensedLTV):
            self.qp.shift_active_set()
        if self.riccati:
            self._pqp.shift_active_set()

    def prepare(self) -> tuple[float, float, float] | None:
        """Shift the previous solution and linearize/condense for the next state.

        Returns:
            ``(linearization, condensing, other)`` seconds, or None when there
            is nothing to prepare (before the first solve).
        """
        t0 = time.perf_counter()
        if not self._started:
            return None
        if not self._prepared:
            self._shift()
        t1 = time.perf_counter()
        self._eval()
        t2 = time.perf_counter()
        self._condense()
        t3 = time.perf_counter()
        self._prepared = True
        return t2 - t1, t3 - t2, t1 - t0

    def solve(self, x: np.ndarray, ref: np.ndarray) -> NMPCSolution:
        """Feedback: solve the prepared QP for the measured ``x (n,)`` and take the step.

        With ``iterations > 1`` SQP iterations follow until the KKT residual is
        below ``tol``. The first call after :meth:`reset` starts cold (see
        ``cold_start``). A failed QP is returned (``message`` set), and the
        next call starts cold.

        A failed IPOPT cold start is returned likewise.
        """
        t_start = time.perf_counter()
        ocp = self.ocp
        o = ocp.options
        if not np.array_equal(ref, self._ref):
            self._ref[:] = ref
            if self._prepared:  # re-condense for the new reference
                if ocp.manifold is not None:  # the chart Jacobians are the reference's
                    self._eval()
                self._condense()
        t_lin = t_cond = 0.0
        fresh = not self._started
        try:
            budget, cold, t_qp = self._begin(x) if fresh else (o.iterations, False, 0.0)
        except MPCInfeasible as exc:  # the IPOPT cold start failed
            status = self._ipopt.status if self._ipopt is not None else "failed"
            return failed_solution(ocp, str(exc), status, time.perf_counter() - t_start)
        if not self._prepared:
            if not fresh:
                self._shift()
            t0 = time.perf_counter()
            self._eval()
            t1 = time.perf_counter()
            self._condense()
            t_lin, t_cond = t1 - t0, time.perf_counter() - t1
        self._prepared = False
        dx0 = x - self.X[0] if ocp.manifold is None else self._J[0] @ ocp.manifold.difference(x, self.X[0])
        status = "rti"
        kkt = math.inf
        it = 0
        qp_status = ""
        qp_it = 0
        while True:
            t0 = time.perf_counter()
            it += 1
            if self.riccati and self._riccati_step(dx0):
                dU, dX = self._dU.reshape(-1), self._dX
                qp_status, qp_it, qp_kkt = DAQP_STATUS[1], 0, float(np.max(np.abs(self._g)))  # H ΔU = -g
                t_qp += time.perf_counter() - t0
            elif self.riccati:  # a bound is reached: the QP around the Riccati step, prestabilized by its policy
                pqp = self._pqp
                ok, qp_status, qp_it = pqp.solve(self._K, self._Re, self._dU, self._dX, self.U, self._xb)
                t_qp += time.perf_counter() - t0
                if not ok:
                    return self._fail(x, qp_status, t_start)
                qp_kkt = pqp.kkt(self._g, self._fX)
                dU, dX = pqp.dU, pqp.dX
            else:
                z, ok, qp_status, qp_it = self.qp.solve(dx0)
                t_qp += time.perf_counter() - t0
                if not ok:
                    return self._fail(x, qp_status, t_start)
                qp_kkt = self.qp.kkt(z)
                dU, dX = self.qp.step(z, dx0)
            kkt = max(qp_kkt, float(np.max(np.abs(self.D))), float(np.max(np.abs(dx0))))
            if it > 1 and kkt < o.tol:
                status = "solved"
                break
            self._step(x, dU, dX, line_search=it > 1 or cold)
            if it >= budget:
                break
            dx0 = np.zeros(ocp.nt)
            t0 = time.perf_counter()
            self._eval()
            t1 = time.perf_counter()
            self._condense()
            t_lin += t1 - t0
            t_cond += time.perf_counter() - t1
        u = np.clip(self.U[0], o.u_min, o.u_max)
        total = time.perf_counter() - t_start
        return NMPCSolution(
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
            states=self.X.copy(),
            inputs=self.U.copy(),
            u=u,
            objective=ocp.objective(self.X, self.U, self._ref),
        )

    def _begin(self, x: np.ndarray) -> tuple[int, bool, float]:
        """The first trajectory after ``reset()``: ``(SQP budget, cold, IPOPT time)`` (see ``cold_start``)."""
        o = self.ocp.options
        t_qp = 0.0
        self._prepared = False
        if o.cold_start == "ipopt":
            t0 = time.perf_counter()
            if self._ipopt is None:
                self._ipopt = IpoptSolver(self.ocp)
            self._ipopt.reset()
            X, U, _, _ = self._ipopt.trajectory(x, self._ref)
            t_qp += time.perf_counter() - t0
            self.X[:] = X
            self.U[:] = U
            budget, cold = o.iterations, False
        else:
            self.X[:] = x
            self.U[:] = np.clip(self.ocp.u0, o.u_min, o.u_max)
            budget, cold = o.init_iterations, True
        self._started = True
        return budget, cold, t_qp

    def _step(self, x: np.ndarray, dU: np.ndarray, dX: np.ndarray, *, line_search: bool) -> None:
        N, m = self.ocp.N, self.ocp.m
        if line_search:
            alpha = self._line_search(dX, dU.reshape(N, m))
        else:
            alpha = 1.0
        self.X[0] = x
        if self.ocp.manifold is None:
            self.X[1:] += alpha * dX
        else:
            self.X[1:] = self._advance(self.X[1:], dX, alpha)
        self.U += alpha * dU.reshape(N, m)

    # ============================================================= SQP merit
    def _multiplier_bound(self, dX: np.ndarray) -> float:
        """``‖λ‖_∞`` of the dynamics multipliers of the QP solution (backward recursion)."""
        N, n = self.ocp.N, self.ocp.nt
        qp = self.qp
        if isinstance(qp, SparseLTV):  # the sparse QP has them
            return float(np.max(np.abs(qp.dynamics_multipliers())))
        nu_rows = self._pqp.state_bound_multipliers() if self.riccati else qp.state_bound_multipliers()
        Xp = self.ocp.deviation(self.X[1:], self._ref) + dX if self.ocp.manifold else self.X[1:] + dX - self._ref
        W = self.ocp.W
        lam_next = np.zeros(n)
        big = 0.0
        for k in range(N - 1, -1, -1):
            lam_k = W[k] @ Xp[k] + nu_rows[k]
            if k + 1 < N:
                lam_k += lam_next @ self.A[k + 1]
            big = max(big, float(np.max(np.abs(lam_k))))
            lam_next = lam_k
        return big

    def _line_search(self, dX: np.ndarray, dU: np.ndarray) -> float:
        ocp = self.ocp
        self._mu = max(self._mu, 1.5 * self._multiplier_bound(dX) + 1e-6)
        mu = self._mu
        X0, U0 = self.X.copy(), self.U.copy()
        defect0 = float(np.abs(self.D).sum())
        phi0 = ocp.objective(X0, U0, self._ref) + mu * defect0
        E = X0 - self._ref if ocp.manifold is None else ocp.manifold.difference(X0, self._ref)
        grad = float(np.einsum("ki,ij,kj->", E[1:-1], ocp.Q, dX[:-1])) + float(E[-1] @ ocp.Qf @ dX[-1])
        grad += float(np.einsum("ki,ij,kj->", U0 - ocp.u0, ocp.R, dU))
        slope = grad - mu * defect0
        alpha = 1.0
        for _ in range(30):
            self.X[1:] = X0[1:] + alpha * dX if ocp.manifold is None else self._advance(X0[1:], dX, alpha)
            self.U[:] = U0 + alpha * dU
            self._eval()
            phi = ocp.objective(self.X, self.U, self._ref) + mu * float(np.abs(self.D).sum())
            # the last term absorbs rounding of phi near convergence (else tiny steps stall the iteration)
            if phi <= phi0 + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * max(1.0, abs(phi0)):
                break
            alpha *= 0.5
        self.X[:] = X0
        self.U[:] = U0
        return alpha

    def _fail(self, x: np.ndarray, status: str, t_start: float) -> NMPCSolution:
        message = f"NonlinearMPC: the QP failed ({status}) at x = {np.array2string(x, precision=4)}"
        reason = self._pqp.explain() if self.riccati else self.qp.explain()
        if reason:
            message += f"; {reason}"
        self._started = False  # the next call starts cold
        return failed_solution(self.ocp, message, status, time.perf_counter() - t_start, self.X, self.U)
