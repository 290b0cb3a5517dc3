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

from shinro_ctrl.controllers.qp.condensed import DAQP_STATUS
from shinro_ctrl.controllers.qp.ltv_sparse import SPARSE_OSQP_SETTINGS, SparseLTV

__all__ = ["SPARSE_OSQP_SETTINGS", "CondensedLTV", "SparseLTV"]


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
        self.Rbar = np.kron(np.eye(N), self.R)
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
        self._I = np.eye(n)
        self.QG = np.empty((N, n, 1 + n + nu))
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
        self._tmp = np.empty(N * n)
        self.dX = np.empty(N * n)
        self.lam = np.zeros(self.nvar + nrow)

    def build(self, e: np.ndarray, du_ref: np.ndarray) -> None:
        """Build ``[c | Φ | Γ]``, ``H``, ``g_0`` and ``G_x`` for the linearization now in ``G``.

        Args:
            e: State errors ``(N n,)``: ``x̄_{k+1} − r_{k+1}`` stacked.
            du_ref: Input errors ``(N m,)``: ``ū_k − u_ref`` stacked.
        """
        n, N, nu = self.n, self.N, self.nu
        mm = np.matmul
        for g, z, out in self._stages:
            mm(g, z, out=out)
        M3 = self.M3
        np.copyto(M3, self.Z[1:, :n])
        np.matmul(self.W, M3, out=self.QG)
        QG = self.QG.reshape(N * n, 1 + n + nu)
        G = self.M[:, 1 + n :]
        QGu = QG[:, 1 + n :]
        Hu = self.H[:nu, :nu]
        np.matmul(QGu.T, G, out=Hu)
        Hu += self.Rbar
        # g0 = Γᵀ Q̄ (e + c) + R̄ (ū − u_ref);  Gx = Γᵀ Q̄ Φ
        np.add(e, self.M[:, 0], out=self._tmp)
        np.matmul(QGu.T, self._tmp, out=self.g0[:nu])
        self.g0[:nu] += self.Rbar @ du_ref
        np.matmul(QGu.T, self.M[:, 1 : 1 + n], out=self.Gx[:nu])
        if self.rows.size:
            rows = self.rows
            self.A[: rows.size, :nu] = G[rows]
            if self.soft:
                self.A[rows.size :, :nu] = G[rows]
            self.Phi_rows[:] = self.M[rows, 1 : 1 + n]

    def set_bounds(self, ubar: np.ndarray, xbar_next: np.ndarray) -> None:
        """Input bounds relative to ``ū`` and the state-row offsets ``x̄ + c`` (before ``Δx_0``).

        Args:
            ubar: Inputs ``(N, m)`` of the linearization point.
            xbar_next: States ``(N, n)`` ``x̄_1 … x̄_N`` of the linearization point.
        """
        nu = self.nu
        np.subtract(np.broadcast_to(self.u_max, ubar.shape).ravel(), ubar.ravel(), out=self.bu[:nu])
        np.subtract(np.broadcast_to(self.u_min, ubar.shape).ravel(), ubar.ravel(), out=self.bl[:nu])
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
        z, _, flag, info = daqp.solve(self.H, self.g, self.A, self.bu, self.bl, self.sense, **self.settings)
        self.lam = info["lam"]
        self.flag = int(flag)
        return z, flag in (1, 2), DAQP_STATUS.get(self.flag, f"exit flag {self.flag}"), int(info["iterations"])

    def step(self, z: np.ndarray, dx0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(ΔU (N m,), ΔX (N, n))`` of a solution, ``ΔX = Γ ΔU + Φ Δx_0 + c`` (a view of an internal buffer)."""
        n = self.n
        dU = z[: self.nu]
        np.matmul(self.M[:, 1 + n :], dU, out=self.dX)
        self.dX += self.M[:, 1 : 1 + n] @ dx0
        self.dX += self.M[:, 0]
        return dU, self.dX.reshape(self.N, n)

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
        r = float(np.max(np.abs(self.H @ z)))
        c = float(np.max(np.abs(lam[:nv] * z)))
        if self.nrow:
            c = max(c, float(np.max(np.abs(lam[nv:] * (self.A @ z)))))
        return max(r, c)
