"""The pieces of :mod:`shinro_ctrl.controllers.ik_qp` besides the controller: its result records and the box QP."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from shinro_ctrl.controllers._osqp import OsqpQP
from shinro_ctrl.errors import InvalidArgument

__all__ = ["IKProblem", "IKStep"]


@dataclass(frozen=True)
class IKProblem:
    """One IK iteration's QP, for inspection (see :meth:`IKQP.build_qp`).

    ``min ½ dqᵀ P dq + cᵀ dq  s.t.  l ≤ A dq ≤ u``.

    Attributes:
        P: Hessian ``Jᵀ W J + λ I`` ``(n, n)`` (full, symmetric).
        c: Linear term ``−Jᵀ W e`` ``(n,)``.
        A: Constraint matrix, the identity ``(n, n)``.
        l: Lower bounds ``max(q_min − q, −s)`` ``(n,)`` [rad].
        u: Upper bounds ``min(q_max − q, s)`` ``(n,)`` [rad].
        J: Task Jacobian ``(k, n)`` (k = 6 pose, 3 position).
        error: Task error ``e`` ``(k,)`` [m, rad].
        weights: Task weights ``diag(W)`` ``(k,)``.
    """

    P: np.ndarray
    c: np.ndarray
    A: np.ndarray
    l: np.ndarray
    u: np.ndarray
    J: np.ndarray
    error: np.ndarray
    weights: np.ndarray


@dataclass(frozen=True)
class IKStep:
    """What the last control call (:meth:`IKQP.track` / ``__call__``) did.

    Attributes:
        q: Joint targets ``(n,)`` [rad] (inside the limits).
        dq: Change from the starting joints ``(n,)`` [rad].
        iterations: QP solves.
        pos_err: Remaining position error to the target [m].
        ori_err: Remaining orientation error to the target [rad].
        status: OSQP status of the last QP.
        solve_time_s: Wall time of the call [s].
    """

    q: np.ndarray
    dq: np.ndarray
    iterations: int
    pos_err: float
    ori_err: float
    status: str
    solve_time_s: float


class _BoxQP:
    """``min ½ xᵀPx + cᵀx  s.t.  l ≤ x ≤ u`` in one OSQP problem, updated in place.

    ``P``'s pattern is the full upper triangle (built from ``np.triu(np.ones)``, so no
    entry is dropped as an explicit zero) and ``A`` the identity; only values change.
    Updates go through :class:`~shinro_ctrl.controllers._osqp.OsqpQP` (OSQP's compiled
    solver when available). That path neither clamps infinite bounds nor checks
    lengths, so this class only ever passes finite bounds in arrays whose lengths are
    checked once here.
    """

    stateful = True  # warm start, previous input and plan

    def __init__(self, n: int, P_upper: np.ndarray, settings: dict[str, Any]):
        pattern = sp.csc_matrix(np.triu(np.ones((n, n))))
        self.n = n
        self.nnz = pattern.nnz
        if P_upper.shape != (self.nnz,):
            raise InvalidArgument(f"P upper triangle: expected {self.nnz} values but found {P_upper.shape}")
        P = sp.csc_matrix((P_upper.copy(), pattern.indices, pattern.indptr), shape=(n, n))
        self.qp = OsqpQP(
            "IK problem or its osqp_settings",
            P,
            np.zeros(n),
            sp.identity(n, format="csc"),
            -np.ones(n),
            np.ones(n),
            settings,
        )
        self.solver = self.qp.solver
        self._rho0 = float(settings.get("rho", self.solver.settings.rho))
        self._zeros = np.zeros(n)

    def solve(self, P_upper: np.ndarray, c: np.ndarray, l: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, int, int]:
        """Solve with new values; returns ``(x (n,), status_val, admm_iterations)``."""
        self.qp.update(c, l, u, P_upper)
        sol, info = self.qp.solve()
        return sol.x, int(info.status_val), int(info.iter)

    def reset(self) -> None:
        """Back to the set-up state: no warm start (iterates zero) and the initial ``rho``.

        OSQP carries both from one solve to the next (adaptive rho included), so results
        depend on the solve history unless this is called first.
        """
        self.qp.warm_start(self._zeros, self._zeros)
        self.qp.update_rho(self._rho0)
