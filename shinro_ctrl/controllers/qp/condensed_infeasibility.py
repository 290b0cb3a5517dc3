"""The condensed QP at one state, and why it is infeasible: an elastic LP's Farkas certificate.

:class:`CondensedDiagnosis` is a mixin of
:class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP`: :meth:`~CondensedDiagnosis.problem`
writes out the QP of a state (unscaled rows, nothing solved) and
:meth:`~CondensedDiagnosis.explain_infeasibility` names the constraint group and
stage that cannot hold together.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.controllers.qp.condensed_build import DenseRowGroup
from shinro_ctrl.controllers.qp.diagnose import explain_certificate

__all__ = ["CondensedDiagnosis", "DenseQP"]


@dataclass(frozen=True)
class DenseQP:
    """The condensed QP of one state: ``min ½ zᵀHz + fᵀz  s.t.  lower ≤ A z ≤ upper``.

    ``A`` stacks the slack rows (an identity block, ``s ≥ 0``) over the
    constraint rows of :attr:`~shinro_ctrl.controllers.qp.condensed.CondensedQP.G` (unscaled, fixed rows included,
    as their own rows of zeros); the constant ``const`` completes the MPC cost
    ``J = ½ zᵀHz + fᵀz + const``.

    Attributes:
        H: Hessian ``(nz, nz)``.
        f: Linear cost ``(nz,)``.
        A: Constraint rows ``(ns + rows, nz)``.
        lower: Lower bounds (``-inf`` where none).
        upper: Upper bounds (``inf`` where none).
        const: Constant cost term.
    """

    H: np.ndarray
    f: np.ndarray
    A: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    const: float


class CondensedDiagnosis:
    """The state's QP and its infeasibility certificate (a mixin of ``CondensedQP``)."""

    n_slack: int
    n_var: int
    groups: dict[str, DenseRowGroup]
    _group_list: list[DenseRowGroup]

    def problem(self, x: Any, u_prev: Any = None) -> DenseQP:
        """The condensed QP for state ``x`` (fresh arrays, unscaled rows; nothing is solved)."""
        e0 = np.asarray(x, dtype=float) - self.x_op
        ns, nz = self.n_slack, self.n_var
        f = np.empty(nz)
        f[:ns] = self.w1
        f[ns:] = self.F[ns:] @ e0 + self._fr
        Ee = self.E @ e0
        lo, hi = self._lo - Ee, self._hi - Ee
        if self._rate0 is not None:
            sl = self._rate0
            if u_prev is None:
                lo[sl], hi[sl] = -np.inf, np.inf
            else:
                d = (np.asarray(u_prev, dtype=float) - self.u_op)[self._rb]
                lo[sl] += d
                hi[sl] += d
        Aall = np.vstack([np.eye(ns, nz), self.G])
        lower = np.concatenate([np.zeros(ns), lo])
        upper = np.concatenate([np.full(ns, np.inf), hi])
        const = 0.5 * float(e0 @ self._W @ e0) + float(self._w_lin @ e0) + self._c0
        return DenseQP(self.H.copy(), f, Aall, lower, upper, const)

    def explain_infeasibility(self, x: Any, u_prev: Any = None) -> str | None:
        """Name the constraint group and stage that make the QP at ``x`` infeasible.

        Solves the elastic LP ``min Σ t  s.t.  ℓ − t ≤ G z ≤ h + t, s ≥ 0, t ≥ 0``
        (HiGHS). A positive optimum certifies infeasibility, and its
        multipliers ``y`` (``Gᵀ y = 0`` on the free variables) are a Farkas
        certificate: the rows with ``y ≠ 0`` cannot hold together. The stage
        named is the first one where the culprit group (state, then rate,
        then input bounds) enters the certificate.

        Returns:
            The explanation, or None when the LP finds the problem feasible
            (no certificate: the failure was numerical).
        """
        qp = self.problem(x, u_prev)
        ns = self.n_slack
        G = qp.A[ns:]
        lo, hi = qp.lower[ns:], qp.upper[ns:]
        norms = np.linalg.norm(G, axis=1)
        scale = np.where(norms > 0, norms, 1.0)
        Gs, los, his = G / scale[:, None], lo / scale, hi / scale
        up = np.flatnonzero(np.isfinite(his))
        dn = np.flatnonzero(np.isfinite(los))
        nz, nu_, nd = self.n_var, up.size, dn.size
        # variables [z, t_up, t_dn]; rows  G z - t <= h,  -G z - t <= -l
        A_ub = np.zeros((nu_ + nd, nz + nu_ + nd))
        A_ub[:nu_, :nz] = Gs[up]
        A_ub[:nu_, nz : nz + nu_] = -np.eye(nu_)
        A_ub[nu_:, :nz] = -Gs[dn]
        A_ub[nu_:, nz + nu_ :] = -np.eye(nd)
        b_ub = np.concatenate([his[up], -los[dn]])
        cost = np.concatenate([np.zeros(nz), np.ones(nu_ + nd)])
        bounds = [(0, None)] * ns + [(None, None)] * (nz - ns) + [(0, None)] * (nu_ + nd)
        import scipy.optimize  # only when an infeasible QP is explained (it costs ~40 % of the package import)

        res = scipy.optimize.linprog(cost, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.status != 0 or res.fun <= 1e-9:
            return None
        y = np.zeros(G.shape[0])
        marg = -np.asarray(res.ineqlin.marginals)
        y[up] += marg[:nu_]
        y[dn] += marg[nu_:]
        return explain_certificate(y, self._group_list)
