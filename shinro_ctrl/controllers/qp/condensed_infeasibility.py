"""The condensed QP at one state, and why it is infeasible: an elastic LP's Farkas certificate.

Free functions over the data of a
:class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP`: :class:`DenseQP` is
the QP of a state written out (unscaled rows, nothing solved), and
:func:`explain_infeasibility` names the constraint group and stage of such a
QP that cannot hold together.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from shinro_ctrl.controllers.qp.diagnose import explain_certificate
from shinro_ctrl.controllers.qp.sparse import RowGroup

__all__ = ["DenseQP", "explain_infeasibility"]


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


def explain_infeasibility(qp: DenseQP, n_slack: int, groups: Sequence[RowGroup]) -> str | None:
    """Name the constraint group and stage that make ``qp`` infeasible.

    Solves the elastic LP ``min Σ t  s.t.  ℓ − t ≤ G z ≤ h + t, s ≥ 0, t ≥ 0``
    (HiGHS). A positive optimum certifies infeasibility, and its
    multipliers ``y`` (``Gᵀ y = 0`` on the free variables) are a Farkas
    certificate: the rows with ``y ≠ 0`` cannot hold together. The stage
    named is the first one where the culprit group (state, then rate,
    then input bounds) enters the certificate.

    Args:
        qp: The QP of the state (:meth:`~shinro_ctrl.controllers.qp.condensed.CondensedQP.problem`).
        n_slack: Number of slacks (the first rows of ``qp.A``).
        groups: The row groups of the constraint rows after the slack rows.

    Returns:
        The explanation, or None when the LP finds the problem feasible
        (no certificate: the failure was numerical).
    """
    ns = n_slack
    G = qp.A[ns:]
    lo, hi = qp.lower[ns:], qp.upper[ns:]
    norms = np.linalg.norm(G, axis=1)
    scale = np.where(norms > 0, norms, 1.0)
    Gs, los, his = G / scale[:, None], lo / scale, hi / scale
    up = np.flatnonzero(np.isfinite(his))
    dn = np.flatnonzero(np.isfinite(los))
    nz, nu_, nd = qp.H.shape[0], up.size, dn.size
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
    return explain_certificate(y, list(groups))
