"""The multiple-shooting LTV QP in its sparse form, solved by OSQP with in-place value updates.

The sparse sibling of :class:`~shinro_ctrl.controllers.qp.ltv.CondensedLTV`
(``NonlinearMPC(solver="osqp")``): states and inputs stay variables, the
shooting rows carry the stage Jacobians, and one warm-started OSQP object
(through the adapter in ``controllers/_osqp.py``) solves every iteration.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from shinro_ctrl.controllers._osqp import OsqpQP, merge_settings

__all__ = ["SPARSE_OSQP_SETTINGS", "SparseLTV"]


#: OSQP settings of the sparse RTI QP: accurate enough that the RTI iterates match DAQP's (polishing),
#: warm-started duals, overridable through ``osqp_settings``.
SPARSE_OSQP_SETTINGS: dict[str, Any] = {
    "eps_abs": 1e-7,
    "eps_rel": 1e-7,
    "polishing": True,
    "warm_starting": True,
    "check_termination": 10,
    "max_iter": 20000,
    "verbose": False,
}

_BIG = 1e30  # OSQP's infinity (the compiled path does not clamp)


class SparseLTV:
    r"""The multiple-shooting QP in its sparse form, solved by OSQP with in-place value updates.

    Variables ``z = [Δx_0 … Δx_N, Δu_0 … Δu_{N-1}, s]``; cost
    ``½ Σ Δx_kᵀ W_k Δx_k + Δu_kᵀ R Δu_k + q(z)`` (``W_0 = Q``); rows
    ``Δx_0 = dx0``, ``A_k Δx_k + B_k Δu_k − Δx_{k+1} = −d_k``, the input
    bounds, and the state bounds on ``x_1 … x_N`` (with the shared slacks when
    ``soft``). ``P`` is constant; the pattern of ``A`` is fixed (every entry of
    ``A_k``, ``B_k`` kept, zero or not), and each :meth:`build` copies the new
    ``[A_k, B_k]`` into the values ``Ax`` through a permutation computed once.
    The one OSQP adapter (:class:`~shinro_ctrl.controllers._osqp.OsqpQP`)
    does the updates and the warm-started solve.

    Args:
        G: The stage matrices ``(N, n, n + m + 1)`` (bound, as for :class:`CondensedLTV`).
        Q: Stage weight ``(n, n)`` (on ``x_0 … x_{N-1}``).
        W, R, u_min, u_max, x_min, x_max, soft, soft_weight_l1, soft_weight_quad: As for :class:`CondensedLTV`.
        osqp_settings: Overrides of :data:`SPARSE_OSQP_SETTINGS`.
    """

    def __init__(
        self,
        G: np.ndarray,
        Q: np.ndarray,
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
        osqp_settings: dict[str, Any] | None = None,
    ):
        N, n, w_ = G.shape
        m = w_ - n - 1
        self.n, self.m, self.N = n, m, N
        self.G = G
        self.u_min, self.u_max = u_min, u_max
        self.bounded = np.flatnonzero(np.isfinite(x_min) | np.isfinite(x_max))
        w = self.bounded.size
        self.soft = bool(soft) and w > 0
        ns = N * w if self.soft else 0  # one slack per state-bound row
        nx, nu = n * (N + 1), N * m
        self.nx, self.nu, self.ns = nx, nu, ns
        nz = nx + nu + ns
        self.nvar = nz
        P = self._cost(Q, W, R, (soft_weight_l1, soft_weight_quad))
        rows, cols, vals, nrow = self._constraint_triplets()
        rows_a, cols_a = np.concatenate(rows), np.concatenate(cols)
        self._vals = np.concatenate(vals)
        marker = sp.csc_matrix((np.arange(1, rows_a.size + 1, dtype=float), (rows_a, cols_a)), shape=(nrow, nz))
        self._perm = (marker.data - 1).astype(np.intp)  # CSC position -> triplet index
        self.A = sp.csc_matrix((np.ones(rows_a.size), marker.indices.copy(), marker.indptr.copy()), shape=(nrow, nz))
        self.Ax = self._vals[self._perm]
        self.A.data = self.Ax
        self._valsG = self._vals[: self._nG].reshape(N, n, n + m)
        self.l = np.zeros(nrow)
        self.u = np.zeros(nrow)
        self._xlo = np.tile(x_min[self.bounded], N)
        self._xhi = np.tile(x_max[self.bounded], N)
        if ns:
            self.l[nrow - ns :] = 0.0
            self.u[nrow - ns :] = _BIG
        settings = merge_settings(SPARSE_OSQP_SETTINGS, osqp_settings)
        self.osqp = OsqpQP("NMPC sparse QP or its osqp_settings", P, self.q, self.A, self.l, self.u, settings)
        self.y = np.zeros(nrow)
        self._zero = np.zeros(nz)
        self.lam = self.y
        self.status = ""
        self.dX = np.empty((N, n))

    def _cost(self, Q: np.ndarray, W: np.ndarray, R: np.ndarray, weights: tuple[float, float]) -> sp.csc_matrix:
        """The constant cost: ``P`` (upper triangle, returned), ``Pfull`` and the linear term ``q``."""
        N, ns, nx, nu = self.N, self.ns, self.nx, self.nu
        nz = self.nvar
        blocks = [Q] + [W[k] for k in range(N)] + [R] * N + ([weights[1] * np.eye(ns)] if ns else [])
        Pfull = sp.block_diag(blocks, format="csc")
        self.Pfull = Pfull
        P = sp.csc_matrix(sp.triu(Pfull, format="csc"))
        self._Wall = np.stack([Q] + [W[k] for k in range(N)])
        self.R = R
        self.q = np.zeros(nz)
        if ns:
            self.q[nx + nu :] = weights[0]
        return P

    def _constraint_triplets(self) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], int]:
        """``(rows, cols, vals, n_rows)`` of the constraints; the first ``N n (n + m)`` values are ``[A_k, B_k]``."""
        n, m, N = self.n, self.m, self.N
        nx, nu, ns = self.nx, self.nu, self.ns
        rows, cols, vals = [], [], []
        k_idx, i_idx, j_idx = np.meshgrid(np.arange(N), np.arange(n), np.arange(n + m), indexing="ij")
        r_dyn = n + k_idx * n + i_idx
        c_dyn = np.where(j_idx < n, k_idx * n + j_idx, nx + k_idx * m + (j_idx - n))
        rows.append(r_dyn.ravel())
        cols.append(c_dyn.ravel())
        vals.append(np.zeros(r_dyn.size))
        self._nG = r_dyn.size
        # Δx_0 = dx0
        rows.append(np.arange(n))
        cols.append(np.arange(n))
        vals.append(np.ones(n))
        # −Δx_{k+1}
        rows.append(n + np.arange(N * n))
        cols.append(n + np.arange(N * n))
        vals.append(-np.ones(N * n))
        r0 = n + N * n
        # input bounds
        rows.append(r0 + np.arange(nu))
        cols.append(nx + np.arange(nu))
        vals.append(np.ones(nu))
        r0 += nu
        self._r_u = slice(n + N * n, r0)
        # state bounds
        xr = (n + (np.arange(N)[:, None] * n + self.bounded[None, :])).ravel()  # columns of Δx_{k+1}[i]
        self._xcols = xr
        nb = xr.size
        rows.append(r0 + np.arange(nb))
        cols.append(xr)
        vals.append(np.ones(nb))
        if ns:
            scol = nx + nu + np.arange(nb)
            rows.append(r0 + np.arange(nb))
            cols.append(scol)
            vals.append(-np.ones(nb))  # Δx − s ≤ hi
            rows.append(r0 + nb + np.arange(nb))
            cols.append(xr)
            vals.append(np.ones(nb))
            rows.append(r0 + nb + np.arange(nb))
            cols.append(scol)
            vals.append(np.ones(nb))  # Δx + s ≥ lo
            rows.append(r0 + 2 * nb + np.arange(ns))
            cols.append(nx + nu + np.arange(ns))
            vals.append(np.ones(ns))  # s ≥ 0
            nrow = r0 + 2 * nb + ns
        else:
            nrow = r0 + nb
        self._r_x = r0
        self.nrow = nrow
        return rows, cols, vals, nrow

    def build(self, e: np.ndarray, du_ref: np.ndarray, e0: np.ndarray | None = None) -> None:
        """Copy the current ``[A_k, B_k]`` into ``Ax``, the defects into the dynamics rows, and the cost's ``q``.

        Args:
            e: ``x̄_{k+1} − r`` stacked ``(N n,)``.
            du_ref: ``ū_k − u_ref`` stacked ``(N m,)``.
            e0: ``x̄_0 − r`` ``(n,)`` (its term does not change the step; default zero).
        """
        n, m, N = self.n, self.m, self.N
        np.copyto(self._valsG, self.G[:, :, : n + m])
        np.take(self._vals, self._perm, out=self.Ax)
        d = self.G[:, :, n + m]
        np.negative(d.reshape(-1), out=self.l[n : n + N * n])
        self.u[n : n + N * n] = self.l[n : n + N * n]
        E = np.empty((N + 1, n))
        E[0] = 0.0 if e0 is None else e0
        E[1:] = e.reshape(N, n)
        np.matmul(self._Wall, E[:, :, None], out=self.q[: self.nx].reshape(N + 1, n, 1))
        np.matmul(du_ref.reshape(N, m), self.R, out=self.q[self.nx : self.nx + self.nu].reshape(N, m))

    def set_bounds(self, ubar: np.ndarray, xbar_next: np.ndarray) -> None:
        """Input and state bounds relative to the linearization point (see :meth:`CondensedLTV.set_bounds`)."""
        r_u = self._r_u
        np.subtract(np.broadcast_to(self.u_max, ubar.shape).ravel(), ubar.ravel(), out=self.u[r_u])
        np.subtract(np.broadcast_to(self.u_min, ubar.shape).ravel(), ubar.ravel(), out=self.l[r_u])
        nb = self._xcols.size
        if nb:
            xb = xbar_next[:, self.bounded].ravel()
            r = self._r_x
            if self.soft:
                self.u[r : r + nb] = self._xhi - xb
                self.l[r : r + nb] = -np.inf
                self.u[r + nb : r + 2 * nb] = np.inf
                self.l[r + nb : r + 2 * nb] = self._xlo - xb
            else:
                self.u[r : r + nb] = self._xhi - xb
                self.l[r : r + nb] = self._xlo - xb
        np.clip(self.l, -_BIG, _BIG, out=self.l)
        np.clip(self.u, -_BIG, _BIG, out=self.u)

    def solve(self, dx0: np.ndarray) -> tuple[np.ndarray, bool, str, int]:
        """Warm-started OSQP solve for the initial-state step ``dx0 (n,)``; see :meth:`CondensedLTV.solve`."""
        n = self.n
        self.l[:n] = dx0
        self.u[:n] = dx0
        self.osqp.update(self.q, self.l, self.u, Ax=self.Ax)
        self.osqp.warm_start(self._zero, self.y)
        sol, info = self.osqp.solve()
        self.status = str(info.status)
        usable = ("solved", "solved inaccurate")
        if self.soft:  # always feasible: an unfinished ADMM iterate is an inexact step, not a failure
            usable += ("maximum iterations reached",)
        ok = self.status in usable and np.all(np.isfinite(sol.x))
        if ok:
            self.y = np.array(sol.y, dtype=float)
            self.lam = self.y
        return np.array(sol.x, dtype=float), bool(ok), self.status, int(info.iter)

    def step(self, z: np.ndarray, dx0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(ΔU (N m,), ΔX (N, n))`` of a solution (``Δx_1 … Δx_N``)."""
        n, N = self.n, self.N
        self.dX[:] = z[n : n * (N + 1)].reshape(N, n)
        return z[self.nx : self.nx + self.nu], self.dX

    def kkt(self, z: np.ndarray) -> float:
        """``‖P z‖_∞`` (stationarity at the linearization point; see :meth:`CondensedLTV.kkt`)."""
        return float(np.max(np.abs(self.Pfull @ z)))

    def explain(self) -> str:
        """Why the last solve failed, for the error message."""
        if not (np.all(np.isfinite(self._vals)) and np.all(np.isfinite(self.q))):
            return "the predicted trajectory diverged (the QP data are not finite)"
        if "infeasible" in self.status and not self.soft:
            return "the linearized hard state bounds cannot be met (use soft=True or looser x_min/x_max)"
        return ""

    def dynamics_multipliers(self) -> np.ndarray:
        """Multipliers ``(N, n)`` of the shooting rows."""
        n, N = self.n, self.N
        return self.y[n : n + N * n].reshape(N, n)
