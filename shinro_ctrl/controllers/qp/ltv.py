r"""Condensing of a linear time-varying (LTV) multiple-shooting QP, solved with DAQP.

Around a trajectory ``(x̄_0 … x̄_N, ū_0 … ū_{N-1})`` the shooting constraints
``x_{k+1} = F(x_k, u_k)`` linearize to

.. math::

    \Delta x_{k+1} = A_k \Delta x_k + B_k \Delta u_k + d_k,\qquad
    d_k = F(\bar x_k, \bar u_k) - \bar x_{k+1},

so the stacked state steps ``ΔX = (Δx_1 … Δx_N)`` are an affine function of
the input steps ``ΔU`` and of the initial-state step ``Δx_0``:

.. math::

    \Delta X = \Gamma\,\Delta U + \Phi\,\Delta x_0 + c .

:class:`CondensedLTV` builds ``[c | Φ | Γ]`` with one batched recursion over
the stages (``M_k = A_k M_{k-1}`` plus ``B_k`` / ``d_k`` in place; the block
lower-triangular structure keeps it ``O(N² n² m)``), then the dense
Hessian ``H = Γᵀ Q̄ Γ + R̄`` and the linear term as ``g = g_0 + G_x Δx_0`` so
that the feedback half only needs a matrix-vector product before the solve
(``prepare`` / ``feedback`` of real-time iterations). The QP

.. math::

    \min_{\Delta U, s}\; \tfrac12 \Delta U^\top H \Delta U + g^\top \Delta U
        + w_1 \mathbf 1^\top s + \tfrac{w_2}{2} s^\top s
    \quad\text{s.t.}\quad u_{min} \le \bar u_k + \Delta u_k \le u_{max},\;
        x_{min} - s \le \bar x_k + \Delta x_k \le x_{max} + s,\; s \ge 0

(the slack ``s`` only with ``soft``: one slack per state-bound row, i.e. per
stage and bounded component, shared by its upper and lower bound, so that no
state bound can make the QP infeasible) is
handed to ``daqp.solve`` with the input bounds as simple bounds and the state
bounds as dense rows of ``Γ``. Every array is allocated once.
"""

from __future__ import annotations

from typing import Any

import daqp
import numpy as np

from shinro_ctrl.controllers.qp.active_set import InputActiveSet
from shinro_ctrl.controllers.qp.condensed import DAQP_STATUS
from shinro_ctrl.controllers.qp.ltv_sparse import SPARSE_OSQP_SETTINGS, SparseLTV

__all__ = ["DIRECT_MAX_WORK", "SPARSE_OSQP_SETTINGS", "CondensedLTV", "SparseLTV"]

_GEMV_SIZE = 9000  # entries of a matrix-vector product below OpenBLAS's threading threshold (2304 × 4)
#: Largest ``(N m)² N n`` (the multiply-adds of ``Γᵀ Q̄ Γ``) condensed by one product; above it, the recursion.
DIRECT_MAX_WORK = 1 << 18


class CondensedLTV:
    """Condensed LTV QP with fixed dimensions, refilled in place each time.

    Args:
        G: The stage matrices ``(N, n, n + m + 1)``, ``G[k] = [A_k, B_k, d_k]``: a buffer the caller
            refills before each :meth:`condense` (it is bound here, views are made once).
        W: Stage state weights ``(N, n, n)`` for ``x_1 … x_N`` (the last one is
            the terminal weight).
        R: Input weight ``(m, m)``.
        u_min, u_max: Input bounds ``(m,)`` (±inf where none).
        x_min, x_max: State bounds ``(n,)`` on ``x_1 … x_N`` (±inf where none).
        soft: Soften the state bounds with one slack per state-bound row (stage and bounded component).
        soft_weight_l1, soft_weight_quad: ``w_1``, ``w_2`` of the slack penalty ``w_1 1ᵀ s + ½ w_2 ‖s‖²``.
        daqp_settings: Keyword settings for ``daqp.solve`` (``primal_tol``, …).

    Attributes:
        warm_start: DAQP starts from the input bounds active at the last solution (moved one stage on by
            :meth:`shift_active_set`): on for the recursive (large) problems, where each active-set iteration
            costs tens of microseconds; off for the small ones (their iterates unchanged, bit for bit).
    """

    def __init__(
        self,
        G: np.ndarray,
        W: np.ndarray,
        R: np.ndarray,
        u_min: np.ndarray,
        u_max: np.ndarray,
        x_min: np.ndarray,
        x_max: np.ndarray,
        *,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        daqp_settings: dict[str, Any] | None = None,
    ):
        N, n, w_ = G.shape
        m = w_ - n - 1
        self.n, self.m, self.N = n, m, N
        self.W = np.ascontiguousarray(W, dtype=float)
        self.R = np.asarray(R, dtype=float)
        nu = N * m
        self.nu = nu
        self.u_min, self.u_max = u_min, u_max
        # bounded state components and their rows in ΔX
        self.bounded = np.flatnonzero(np.isfinite(x_min) | np.isfinite(x_max))
        w = self.bounded.size
        self.rows = (np.arange(N)[:, None] * n + self.bounded[None, :]).ravel()  # (N w,)
        self.soft = bool(soft) and w > 0
        self.ns = N * w if self.soft else 0
        self.nvar = nu + self.ns
        xlo = np.tile(x_min[self.bounded], N)
        xhi = np.tile(x_max[self.bounded], N)
        self._xlo, self._xhi = xlo, xhi
        # [c | Φ | Γ] stage blocks (N, n, 1 + n + N m) by M_{k+1} = G_k Z_k with the augmented
        # Z_k = [M_k; E_k; e_0ᵀ] (E_k = I_m at the columns of Δu_k): one matmul per stage, every view made once
        C = 1 + n + nu
        self.Z = np.zeros((N + 1, n + m + 1, C))
        self.Z[0, :n, 1 : 1 + n] = np.eye(n)
        for k in range(N):
            self.Z[k, n : n + m, 1 + n + k * m : 1 + n + (k + 1) * m] = np.eye(m)
            self.Z[k, n + m, 0] = 1.0
        self._stages = [(G[k], self.Z[k], self.Z[k + 1, :n]) for k in range(N)]
        self.M3 = np.zeros((N, n, C))
        self.M = self.M3.reshape(N * n, 1 + n + nu)
        self.H = np.empty((self.nvar, self.nvar))
        self.Hu = self.H[:nu, :nu] if self.ns else None
        self.g0 = np.empty(self.nvar)
        self.Gx = np.zeros((self.nvar, n))
        self.g = np.empty(self.nvar)
        self.xbar_rows = np.empty(N * w)  # x̄ + c on the bounded rows
        self.Phi_rows = np.empty((N * w, n))
        if self.soft:
            w1, w2 = soft_weight_l1, soft_weight_quad
            self.H[:] = 0.0
            self.H[nu:, nu:] = w2 * np.eye(self.ns)
            self.g0[nu:] = w1
            # upper rows [Γ_s, -I] <= hi, lower rows [Γ_s, +I] >= lo: one slack per row
            E = np.eye(self.ns)
            self.A = np.zeros((2 * N * w, self.nvar))
            self.A[: N * w, nu:] = -E
            self.A[N * w :, nu:] = E
            nrow = 2 * N * w
        else:
            self.A = np.zeros((N * w, self.nvar))
            nrow = N * w
        self.nrow = nrow
        self.bu = np.empty(self.nvar + nrow)
        self.bl = np.empty(self.nvar + nrow)
        if self.soft:
            self.bu[nu : self.nvar] = np.inf
            self.bl[nu : self.nvar] = 0.0
        self.sense = np.zeros(self.nvar + nrow, dtype=np.int32)
        self.settings = dict(daqp_settings or {})
        self.dX = np.empty(N * n)
        self.lam = np.zeros(self.nvar + nrow)
        self.flag = 0
        self._Hz = np.empty(self.nvar)
        step = max(1, _GEMV_SIZE // self.nvar)
        self._H_rows = [(self.H[i : i + step], self._Hz[i : i + step]) for i in range(0, self.nvar, step)]
        self._umax = np.tile(np.broadcast_to(u_max, (m,)), N)
        self._umin = np.tile(np.broadcast_to(u_min, (m,)), N)
        self._init_recursions(G)
        self.warm_start = not self.direct
        self._active = InputActiveSet(nu, m)  # the warm start's input bounds

    def shift_active_set(self) -> None:
        """Move the warm-start active set one stage on (the RTI shift); the last stage starts inactive."""
        self._active.shift()

    def clear_active_set(self) -> None:
        """Start the next solve with no active input bound."""
        self._active.clear()

    def mark_unconstrained(self) -> None:
        """The last solution, found without DAQP, met every bound: no active set, zero multipliers."""
        self._active.clear()
        self.lam = np.zeros_like(self.lam)
        self.flag = 1

    def _init_recursions(self, G: np.ndarray) -> None:
        """Choose the condensing algorithm (:attr:`direct`) and make its buffers and views once."""
        n, m, N, nu = self.n, self.m, self.N, self.nu
        # one product Γᵀ Q̄ Γ while it is small (below OpenBLAS's threading threshold of 2¹⁸
        # multiply-adds): fewer Python calls than the recursion's 4 N; the recursion above it
        self.direct = nu * nu * N * n <= DIRECT_MAX_WORK
        self._ec = np.empty((N, n, 1))
        if self.direct:
            self._QG = np.empty((N, n, 1 + n + nu))
            self._Rbar = np.kron(np.eye(N), self.R)
            return
        self._A = G[:, :, :n]
        self._At = np.swapaxes(self._A, 1, 2)
        self._B = G[:, :, n : n + m]
        self._Bt = np.swapaxes(self._B, 1, 2)
        # forward free response [c_k | Φ_k] = G_k [c_{k-1} Φ_{k-1}; 0; 1 0] (Φ_{-1} = I): x_{k+1}'s
        self._Zs = np.zeros((N + 1, n + m + 1, 1 + n))
        self._Zs[0, :n, 1:] = np.eye(n)
        self._Zs[:, n + m, 0] = 1.0
        self._free = [(G[k], self._Zs[k], self._Zs[k + 1, :n]) for k in range(N)]
        self._cP = self._Zs[1:, :n] if self.rows.size == 0 else self.M3[:, :, : 1 + n]
        # backward: Buf_k = [X_k | S_k | y_k] (n, N m + n + 1); X_k's block j < k stays 0
        self._Buf = np.zeros((N, n, nu + n + 1))
        self._WW = np.empty((N, n, n + 1))  # [W_k | W_k (e_k + c_k)]
        self._WW[:, :, :n] = self.W
        self._back = [
            (
                self._At[k + 1],
                self._Buf[k + 1, :, (k + 1) * m :],
                self._Buf[k, :, (k + 1) * m :],
                self._Buf[k, :, nu : nu + n],
                self._A[k + 1],
                self._Buf[k, :, nu:],
                self._WW[k],
                self._B[k],
                self._Buf[k, :, k * m : (k + 1) * m],
            )
            for k in range(N - 2, -1, -1)
        ]
        self._BY = np.empty((N, m, nu + n + 1))
        # the diagonal blocks of Bᵀ X (the Hessian's block upper triangle, as rows of BY)
        s0, s1, s2 = self._BY.strides
        self._BYd = np.lib.stride_tricks.as_strided(self._BY, shape=(N, m, m), strides=(s0 + m * s2, s1, s2))
        self._Hu = self._BY[:, :, :nu].reshape(nu, nu)
        self._Gx3 = self.Gx[:nu].reshape(N, m, n)
        self._g0u = self.g0[:nu].reshape(N, m)
        self._zv = np.zeros((N + 1, n + m + 1))
        self._zv[:, n + m] = 1.0
        self._roll = [(G[k], self._zv[k], self._zv[k + 1, :n]) for k in range(N)]

    def build(self, e: np.ndarray, du_ref: np.ndarray) -> None:
        r"""Build ``H``, ``g_0`` and ``G_x`` (and ``[c | Φ | Γ]`` where it is used) for the linearization in ``G``.

        Two algorithms, chosen once by size (:attr:`direct`): small problems form ``[c | Φ | Γ]`` stage
        by stage and ``H = Γᵀ Q̄ Γ + R̄`` as one matrix product (:meth:`_build_direct`); larger ones, where
        that product costs ``O(N³ n m²)`` and would run on a threaded BLAS, use the backward recursion of
        :meth:`_build_recursive` (``O(N² n² m)`` in small products, no ``Γ`` unless state bounds need it).

        Args:
            e: State errors ``(N n,)``: ``x̄_{k+1} − r_{k+1}`` stacked.
            du_ref: Input errors ``(N m,)``: ``ū_k − u_ref`` stacked.
        """
        n, nu = self.n, self.nu
        if self.direct:
            self._build_direct(e, du_ref)
        else:
            self._build_recursive(e, du_ref)
        if self.rows.size:
            rows = self.rows
            G = self.M[:, 1 + n :]
            self.A[: rows.size, :nu] = G[rows]
            if self.soft:
                self.A[rows.size :, :nu] = G[rows]
            self.Phi_rows[:] = self.M[rows, 1 : 1 + n]

    def _build_direct(self, e: np.ndarray, du_ref: np.ndarray) -> None:
        """``[c | Φ | Γ]`` by ``M_{k+1} = G_k Z_k``, then ``Γᵀ Q̄ [c + e | Φ | Γ]`` as one product."""
        n, N, nu = self.n, self.N, self.nu
        mm = np.matmul
        for g, z, out in self._stages:
            mm(g, z, out=out)
        M3 = self.M3
        np.copyto(M3, self.Z[1:, :n])
        mm(self.W, M3, out=self._QG)
        QG = self._QG.reshape(N * n, 1 + n + nu)
        G = self.M[:, 1 + n :]
        QGu = QG[:, 1 + n :]
        mm(QGu.T, G, out=self.H[:nu, :nu])
        self.H[:nu, :nu] += self._Rbar
        # g0 = Γᵀ Q̄ (e + c) + R̄ (ū − u_ref);  Gx = Γᵀ Q̄ Φ
        np.add(e, self.M[:, 0], out=self._ec.reshape(-1))
        mm(QGu.T, self._ec.reshape(-1), out=self.g0[:nu])
        self.g0[:nu] += self._Rbar @ du_ref
        mm(QGu.T, self.M[:, 1 : 1 + n], out=self.Gx[:nu])

    def _build_recursive(self, e: np.ndarray, du_ref: np.ndarray) -> None:
        r"""``H``, ``g_0``, ``G_x`` by one backward recursion, without a product with ``Γ``.

        With ``S_{N-1} = W_{N-1}``, ``S_k = W_k + A_{k+1}ᵀ S_{k+1} A_{k+1}`` (stage ``k`` is ``x_{k+1}``;
        ``S_k`` the weight its free response carries to the end of the horizon), the Hessian's blocks are
        ``H_{ii} = B_iᵀ S_i B_i + R`` and ``H_{ij} = B_iᵀ A_{i+1}ᵀ ⋯ A_jᵀ S_j B_j`` (``i < j``), so the
        recursion ``X_k = [S_k B_k | A_{k+1}ᵀ X_{k+1}]`` gives the block rows ``H_{i, j ≥ i} = B_iᵀ X_i``
        (the lower triangle by symmetry). Along with it run ``y_k = W_k (e_k + c_k) + A_{k+1}ᵀ y_{k+1}``
        for ``g_{0,i} = B_iᵀ y_i + R (ū_i − u_ref)``, and ``G_{x,i} = B_iᵀ S_i Φ_i`` (``[c_k | Φ_k]`` the
        free response of ``x_{k+1}``, forward).
        """
        n, N, nu = self.n, self.N, self.nu
        mm = np.matmul
        if self.rows.size:  # the bounded rows need Γ
            for g, z, out in self._stages:
                mm(g, z, out=out)
            np.copyto(self.M3, self.Z[1:, :n])
        else:
            for g, z, out in self._free:
                mm(g, z, out=out)
        cP = self._cP
        np.add(e.reshape(N, n, 1), cP[:, :, :1], out=self._ec)
        mm(self.W, self._ec, out=self._WW[:, :, n:])
        Buf = self._Buf
        last = Buf[N - 1]
        last[:, nu:] = self._WW[N - 1]
        mm(self.W[N - 1], self._B[N - 1], out=last[:, nu - self.m : nu])
        add = np.add
        for At, src, dst, S, A, Sy, WW, B, V in self._back:
            mm(At, src, out=dst)  # A_{k+1}ᵀ [X_{k+1} (blocks > k) | S_{k+1} | y_{k+1}]
            mm(S, A, out=S)  # (A_{k+1}ᵀ S_{k+1}) A_{k+1} (numpy buffers the overlap)
            add(Sy, WW, out=Sy)
            mm(S, B, out=V)
        BY = self._BY
        mm(self._Bt, Buf, out=BY)
        Hd = self._BYd  # halve the diagonal blocks (plus R) so that U + Uᵀ counts them once
        add(Hd, self.R, out=Hd)
        Hd *= 0.5
        Hu = self._Hu
        add(Hu, Hu.T, out=self.H[:nu, :nu])
        mm(BY[:, :, nu : nu + n], cP[:, :, 1:], out=self._Gx3)
        mm(du_ref.reshape(N, self.m), self.R.T, out=self._g0u)  # R (ū_i − u_ref), block by block
        self._g0u += BY[:, :, nu + n]

    def set_bounds(self, ubar: np.ndarray, xbar_next: np.ndarray) -> None:
        """Input bounds relative to ``ū`` and the state-row offsets ``x̄ + c`` (before ``Δx_0``).

        Args:
            ubar: Inputs ``(N, m)`` of the linearization point.
            xbar_next: States ``(N, n)`` ``x̄_1 … x̄_N`` of the linearization point.
        """
        nu = self.nu
        np.subtract(self._umax, ubar.ravel(), out=self.bu[:nu])
        np.subtract(self._umin, ubar.ravel(), out=self.bl[:nu])
        if self.rows.size:
            np.add(xbar_next.ravel()[self.rows], self.M[self.rows, 0], out=self.xbar_rows)

    def solve(self, dx0: np.ndarray) -> tuple[np.ndarray, bool, str, int]:
        """Solve for the step with initial-state step ``dx0 (n,)``.

        Returns:
            ``(z (nvar,), ok, status, iterations)``; ``z[:N m]`` is ``ΔU``. The
            dual solution is kept in ``lam``, DAQP's exit flag in ``flag``.
        """
        with np.errstate(over="ignore", invalid="ignore"):
            np.matmul(self.Gx, dx0, out=self.g)
            self.g += self.g0
        nv, r = self.nvar, self.rows.size
        if r:
            off = self.xbar_rows + self.Phi_rows @ dx0
            if self.soft:
                self.bu[nv : nv + r] = self._xhi - off
                self.bl[nv : nv + r] = -np.inf
                self.bu[nv + r :] = np.inf
                self.bl[nv + r :] = self._xlo - off
            else:
                self.bu[nv:] = self._xhi - off
                self.bl[nv:] = self._xlo - off
        if self.soft:  # start with every slack at its bound s = 0 (DAQP's ACTIVE | LOWER): only violated rows leave
            self.sense[self.nu : nv] = 3
        if self.warm_start:
            self.sense[: self.nu] = self._active.sense
        z, _, flag, info = daqp.solve(self.H, self.g, self.A, self.bu, self.bl, self.sense, **self.settings)
        self.lam = info["lam"]
        self.flag = int(flag)
        if self.warm_start:
            self._active.record(self.lam[: self.nu], flag in (1, 2))
        return z, flag in (1, 2), DAQP_STATUS.get(self.flag, f"exit flag {self.flag}"), int(info["iterations"])

    def step(self, z: np.ndarray, dx0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(ΔU (N m,), ΔX (N, n))`` of a solution, ``ΔX = Γ ΔU + Φ Δx_0 + c`` (a view of an internal buffer)."""
        n, m = self.n, self.m
        dU = z[: self.nu]
        if self.direct or self.rows.size:
            np.matmul(self.M[:, 1 + n :], dU, out=self.dX)
            self.dX += self.M[:, 1 : 1 + n] @ dx0
            self.dX += self.M[:, 0]
            return dU, self.dX.reshape(self.N, n)
        # Γ is not formed: Δx_{k+1} = A_k Δx_k + B_k Δu_k + d_k, stage by stage
        zv = self._zv
        zv[0, :n] = dx0
        zv[:-1, n : n + m] = dU.reshape(self.N, m)
        mm = np.matmul
        for g, a, b in self._roll:
            mm(g, a, out=b)
        dX = self.dX.reshape(self.N, n)
        dX[:] = zv[1:, :n]
        return dU, dX

    def explain(self) -> str:
        """Why the last solve failed, for the error message (empty when there is nothing to add)."""
        if not (np.all(np.isfinite(self.H)) and np.all(np.isfinite(self.g))):
            return (
                "the predicted trajectory diverged (the QP data are not finite): the model no longer "
                "describes the plant well enough, or the horizon is too long for it"
            )
        if self.flag == -1 and not self.soft:
            return "the linearized hard state bounds cannot be met (use soft=True or looser x_min/x_max)"
        if self.flag == -5:
            return (
                "the condensed Hessian is numerically indefinite (ill-conditioned: a strongly unstable "
                "prediction over a long horizon; solver='osqp' uses the sparse QP)"
            )
        return ""

    def state_bound_multipliers(self) -> np.ndarray:
        """Multipliers of the state-bound rows by stage ``(N, n)`` (0 where unbounded)."""
        nu_rows = np.zeros((self.N, self.n))
        r = self.rows.size
        if r:
            lam = self.lam[self.nvar :]
            nu_rows.reshape(-1)[self.rows] = lam[:r] + (lam[r:] if self.soft else 0.0)
        return nu_rows

    def kkt(self, z: np.ndarray) -> float:
        """KKT residual of the QP's model at ``z = 0`` with the solution's multipliers.

        At the solution ``H z + g + Aᵀλ = 0``, so the stationarity residual at
        the linearization point is ``‖H z‖_∞``; complementarity there is
        ``max_i |λ_i (A z)_i|`` (the constraints active at ``z``). Both vanish
        as the SQP steps do.
        """
        nv = self.nvar
        lam = self.lam
        if nv * nv > _GEMV_SIZE:  # in row blocks: each product stays under OpenBLAS's threading threshold
            for rows, out in self._H_rows:
                np.matmul(rows, z, out=out)
            r = float(np.max(np.abs(self._Hz)))
        else:
            r = float(np.max(np.abs(self.H @ z)))
        c = float(np.max(np.abs(lam[:nv] * z)))
        if self.nrow:
            c = max(c, float(np.max(np.abs(lam[nv:] * (self.A @ z)))))
        return max(r, c)
