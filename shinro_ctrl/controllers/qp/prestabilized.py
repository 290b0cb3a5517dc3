r"""The bound-active LTV QP of the real-time iteration in prestabilized, Riccati-factored form, solved with DAQP.

The Riccati step of :class:`~shinro_ctrl.controllers._nmpc_rti.RealTimeIteration` (the recursion of
:func:`~shinro_ctrl.controllers._nmpc_ocp.riccati_functions`) gives the unconstrained minimizer
``(ΔU*, ΔX*)`` of the LTV QP and its time-varying policy ``Δu_k = K_k Δx_k + κ_k``. When that step breaks a
bound, the QP is solved here in the variables ``v`` of the prestabilized parametrization

.. math::

    \Delta u_k = K_k\,\Delta x_k + \kappa_k + v_k,\qquad
    \Delta x_{k+1} = (A_k + B_k K_k)\,\Delta x_k + B_k (\kappa_k + v_k) + d_k,

so that ``ΔU = ΔU* + T v`` and ``ΔX = ΔX* + Z v`` (``T`` unit lower block-triangular, ``Z`` strictly
lower block-triangular: ``∂Δu_k/∂v = T_k = K_k Z_k + E_k``, ``Z_{k+1} = (A_k + B_k K_k) Z_k + B_k E_k``,
``Z_0 = 0``: closed-loop transitions, stable where the policy stabilizes). Completing the square stage by stage with the
Riccati value function gives the cost exactly as

.. math::

    J(v) = J(\Delta U^*) + \tfrac12 \textstyle\sum_k v_k^\top \bigl(R + B_k^\top (W_k + P_{k+1}) B_k\bigr) v_k ,

i.e. ``Tᵀ H T = blockdiag(R_{e,k})`` for the condensed Hessian ``H``, with no linear term (``v = 0`` is the
unconstrained minimizer). On the cart-pole swing-up ``H`` has condition number 10⁸–10⁹ (one rounding of it
moves ``u₀`` by ~1e-8) while ``blockdiag(R_{e,k})`` has about 10, and the dual Hessian of the active rows
``A_W H_v⁻¹ A_Wᵀ`` about 10⁴. The QP in ``z = (v, s)`` (``s``: one slack per state-bound row with ``soft``)

.. math::

    \min_{v, s}\; \tfrac12 \textstyle\sum_k v_k^\top R_{e,k} v_k + w_1 \mathbf 1^\top s + \tfrac{w_2}{2} s^\top s
    \quad\text{s.t.}\quad u_{min} - \bar U - \Delta U^* \le T v \le u_{max} - \bar U - \Delta U^*,\;
    x_{min} - s \le \bar X + \Delta X^* + Z v \le x_{max} + s,\; s \ge 0

is the same QP as :class:`~shinro_ctrl.controllers.qp.ltv.CondensedLTV`'s (the same constraints, so the same
multipliers), in well-conditioned variables: the input bounds are general rows here. DAQP solves it
(``daqp.solve`` with ``A``, ``bupper``, ``blower``, ``sense``); the exported C (``export/nmpc.py``) forms the
same rows and solves the same least-distance problem.
"""

from __future__ import annotations

from typing import Any

import daqp
import numpy as np
import scipy.linalg as sla

from shinro_ctrl.controllers.qp.active_set import InputActiveSet
from shinro_ctrl.controllers.qp.condensed import DAQP_STATUS

__all__ = ["PrestabilizedLTV"]


class PrestabilizedLTV:
    """The LTV QP around the Riccati step, in the prestabilized variables ``v`` (module docstring).

    Args:
        G: The stage matrices ``(N, n, n + m + 1)`` ``[A_k, B_k, d_k]`` (bound: read at each :meth:`solve`).
        u_min, u_max: Input bounds ``(m,)`` (±inf where none).
        x_min, x_max: State bounds ``(n,)`` on ``x_1 … x_N`` (±inf where none).
        soft: One slack per state-bound row (stage and bounded component).
        soft_weight_l1, soft_weight_quad: ``w_1``, ``w_2`` of the slack penalty.
        warm_start: Start DAQP from the input rows active at the last solution, moved one stage on
            (:meth:`shift_active_set`).
        daqp_settings: Keyword settings for ``daqp.solve``.

    Attributes:
        dU: The input steps ``(N m,)`` of the last solution.
        dX: The state steps ``(N, n)`` of the last solution.
        lam: DAQP's multipliers ``(nvar + rows,)`` (simple bounds of ``z`` first, then the rows).
        flag: DAQP's exit flag of the last solve.
    """

    def __init__(
        self,
        G: np.ndarray,
        u_min: np.ndarray,
        u_max: np.ndarray,
        x_min: np.ndarray,
        x_max: np.ndarray,
        *,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        warm_start: bool = False,
        daqp_settings: dict[str, Any] | None = None,
    ):
        N, n, w_ = G.shape
        m = w_ - n - 1
        self.N, self.n, self.m = N, n, m
        nu = N * m
        self.nu = nu
        self._A = G[:, :, :n]
        self._B = G[:, :, n : n + m]
        self.bounded = np.flatnonzero(np.isfinite(x_min) | np.isfinite(x_max))
        w = self.bounded.size
        nr = N * w
        self.nr = nr
        self.soft = bool(soft) and w > 0
        ns = nr if self.soft else 0
        self.ns = ns
        self.nvar = nu + ns
        self.nrow = nu + (2 * nr if self.soft else nr)
        self._umin = np.tile(np.broadcast_to(np.asarray(u_min, dtype=float), (m,)), N)
        self._umax = np.tile(np.broadcast_to(np.asarray(u_max, dtype=float), (m,)), N)
        self._xlo = np.tile(np.asarray(x_min, dtype=float)[self.bounded], N)
        self._xhi = np.tile(np.asarray(x_max, dtype=float)[self.bounded], N)
        # the rows [T | 0], [Z_b | -I] (upper), [Z_b | +I] (lower); T is a view of the first block
        self.A = np.zeros((self.nrow, self.nvar))
        self.T = self.A[:nu, :nu]
        self._Z = np.zeros((N + 1, n, nu))  # Z_k = ∂Δx_k/∂v (Z_0 = 0)
        self._Acl = np.zeros((N, n, n))  # A_k + B_k K_k
        self._T3 = np.zeros((N, m, nu))  # T by stages
        self._E = np.zeros((N, m, nu))  # E_k: the identity at the columns of v_k
        for k in range(N):
            self._E[k, :, k * m : (k + 1) * m] = np.eye(m)
        if self.soft:
            E = np.eye(ns)
            self.A[nu : nu + nr, nu:] = -E
            self.A[nu + nr :, nu:] = E
        self.H = np.zeros((self.nvar, self.nvar))
        if ns:
            self.H[nu:, nu:] = soft_weight_quad * np.eye(ns)
        s0, s1 = self.H.strides
        # the diagonal blocks R_{e,k} of H (N, m, m)
        self._Hd = np.lib.stride_tricks.as_strided(self.H, shape=(N, m, m), strides=(m * (s0 + s1), s0, s1))
        self.f = np.zeros(self.nvar)
        self.f[nu:] = soft_weight_l1
        self.w2 = float(soft_weight_quad)
        mt = self.nvar + self.nrow
        self.bu = np.full(mt, np.inf)
        self.bl = np.full(mt, -np.inf)
        self.bl[nu : self.nvar] = 0.0  # s >= 0
        self.sense = np.zeros(mt, dtype=np.int32)
        self.settings = dict(daqp_settings or {})
        self.warm_start = bool(warm_start)
        self._active = InputActiveSet(nu, self.m)  # the warm start's input rows
        self.dU = np.zeros(nu)
        self.dX = np.zeros((N, n))
        self.z = np.zeros(self.nvar)
        self.lam = np.zeros(mt)
        self.flag = 0

    def shift_active_set(self) -> None:
        """Move the warm-start active set one stage on (the RTI shift); the last stage starts inactive."""
        self._active.shift()

    def mark_unconstrained(self) -> None:
        """The last step met every bound without this QP: no active set, zero multipliers."""
        self._active.clear()
        self.lam = np.zeros_like(self.lam)
        self.flag = 1

    def factor_rows(self, K: np.ndarray, Re: np.ndarray) -> None:
        """``T``, ``Z`` and ``H`` from the policy gains ``K (N, m, n)`` and the blocks ``R_e (N, m, m)``.

        ``Z_{k+1} = (A_k + B_k K_k) Z_k + B_k E_k`` (the closed-loop transition; ``Z_k`` has no column ``≥ k m``),
        then ``T_k = K_k Z_k + E_k`` for all stages at once.
        """
        m, nu = self.m, self.nu
        Z = self._Z
        mm = np.matmul
        mm(self._B, K, out=self._Acl)
        self._Acl += self._A
        for k, (acl, b) in enumerate(zip(self._Acl, self._B, strict=True)):
            zn = Z[k + 1]
            mm(acl, Z[k], out=zn)
            zn[:, k * m : (k + 1) * m] = b
        mm(K, Z[:-1], out=self._T3)
        self._T3 += self._E
        self.T[:] = self._T3.reshape(nu, nu)
        if self.nr:
            rows = Z[1:, self.bounded, :].reshape(self.nr, nu)
            self.A[nu : nu + self.nr, :nu] = rows
            if self.soft:
                self.A[nu + self.nr :, :nu] = rows
        self._Hd[:] = Re

    def solve(
        self,
        K: np.ndarray,
        Re: np.ndarray,
        dU_star: np.ndarray,
        dX_star: np.ndarray,
        ubar: np.ndarray,
        xbar_next: np.ndarray,
    ) -> tuple[bool, str, int]:
        """Solve the QP around the Riccati step; the solution in :attr:`dU`, :attr:`dX`.

        Args:
            K: Policy gains ``(N, m, n)``.
            Re: ``R + B_kᵀ (W_k + P_{k+1}) B_k`` ``(N, m, m)``.
            dU_star: The Riccati step's inputs ``(N, m)``.
            dX_star: Its states ``(N, n)``.
            ubar: Inputs ``(N, m)`` of the linearization point.
            xbar_next: States ``x̄_1 … x̄_N`` ``(N, n)`` of the linearization point.

        Returns:
            ``(ok, status, iterations)``.
        """
        nu, nv, nr = self.nu, self.nvar, self.nr
        with np.errstate(over="ignore", invalid="ignore"):
            self.factor_rows(K, Re)
            du = dU_star.reshape(-1)
            bu, bl = self.bu, self.bl
            np.subtract(self._umax, ubar.reshape(-1), out=bu[nv : nv + nu])
            bu[nv : nv + nu] -= du
            np.subtract(self._umin, ubar.reshape(-1), out=bl[nv : nv + nu])
            bl[nv : nv + nu] -= du
            if nr:
                off = (xbar_next[:, self.bounded] + dX_star[:, self.bounded]).reshape(-1)
                r0 = nv + nu
                if self.soft:
                    bu[r0 : r0 + nr] = self._xhi - off
                    bl[r0 + nr :] = self._xlo - off
                else:
                    bu[r0:] = self._xhi - off
                    bl[r0:] = self._xlo - off
        if not (np.all(np.isfinite(self.A)) and np.all(np.isfinite(self.H)) and np.all(np.isfinite(du))):
            self.flag = -6
            return False, "QP data not finite", 0
        if self.ns:  # every slack starts at its bound s = 0 (DAQP's ACTIVE | LOWER): only violated rows leave
            self.sense[nu:nv] = 3
        if self.warm_start:
            self.sense[nv : nv + nu] = self._active.sense
        z, _, flag, info = daqp.solve(self.H, self.f, self.A, bu, bl, self.sense, **self.settings)
        self.lam = info["lam"]
        self.flag = int(flag)
        ok = flag in (1, 2)
        if self.warm_start:
            self._active.record(self.lam[nv : nv + nu], ok)
        if ok:
            self.z = z
            v = z[:nu]
            np.matmul(self.T, v, out=self.dU)
            self.dU += du
            np.matmul(self._Z[1:], v, out=self.dX)
            self.dX += dX_star
        return ok, DAQP_STATUS.get(self.flag, f"exit flag {self.flag}"), int(info["iterations"])

    def state_bound_multipliers(self) -> np.ndarray:
        """Multipliers of the state-bound rows by stage ``(N, n)`` (0 where unbounded)."""
        out = np.zeros((self.N, self.n))
        nr = self.nr
        if nr:
            lam = self.lam[self.nvar + self.nu :]
            out[:, self.bounded] = (lam[:nr] + (lam[nr:] if self.soft else 0.0)).reshape(self.N, -1)
        return out

    def kkt(self, g: np.ndarray, dX_free: np.ndarray) -> float:
        """KKT residual of the QP's model at ``ΔU = 0`` with the solution's multipliers (as ``CondensedLTV.kkt``).

        Stationarity there is ``‖H ΔU‖_∞`` with the condensed ``H``: from ``Tᵀ H T = H_v`` and
        ``H ΔU* = −g``, ``H ΔU = T^{-T} H_v v − g`` (``g (N, m)`` the gradient at ``ΔU = 0``, from the Riccati
        forward function); the slacks' part is ``w₂ s``. Complementarity: ``λ`` times the constraint rows'
        change, ``ΔU`` on the input rows and ``Γ ΔU ∓ s = ΔX − ΔX_free ∓ s`` on the state rows
        (``dX_free (N, n)``: the free response from ``Δx_0``).
        """
        nu, nv, nr = self.nu, self.nvar, self.nr
        z = self.z
        Hv = np.einsum("kij,kj->ki", self._Hd, z[:nu].reshape(self.N, self.m)).reshape(-1)
        r_u = sla.solve_triangular(self.T, Hv, trans="T", lower=True, unit_diagonal=True) - g.reshape(-1)
        r = float(np.max(np.abs(r_u)))
        lam = self.lam
        c = float(np.max(np.abs(lam[nv : nv + nu] * self.dU)))
        if self.ns:
            s = z[nu:]
            r = max(r, float(np.max(np.abs(self.w2 * s))))
            c = max(c, float(np.max(np.abs(lam[nu:nv] * s))))
        if nr:
            gd = (self.dX - dX_free)[:, self.bounded].reshape(-1)
            lr = lam[nv + nu :]
            if self.soft:
                s = z[nu:]
                c = max(c, float(np.max(np.abs(lr[:nr] * (gd - s)))), float(np.max(np.abs(lr[nr:] * (gd + s)))))
            else:
                c = max(c, float(np.max(np.abs(lr * gd))))
        return max(r, c)

    def explain(self) -> str:
        """Why the last solve failed, for the error message (empty when there is nothing to add)."""
        if self.flag == -6:
            return (
                "the predicted trajectory diverged (the QP data are not finite): the model no longer "
                "describes the plant well enough, or the horizon is too long for it"
            )
        if self.flag == -1 and not self.soft:
            return "the linearized hard state bounds cannot be met (use soft=True or looser x_min/x_max)"
        return ""
