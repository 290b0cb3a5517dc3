"""The outcome of one MPC call: ``LinearMPC``'s (whichever backend solved it) and ``NonlinearMPC``'s."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["MPCSolution", "NMPCSolution", "clip_input", "same_reference"]


@dataclasses.dataclass(frozen=True, kw_only=True)
class MPCSolution:
    """The outcome of one :class:`~shinro_ctrl.controllers.mpc.LinearMPC` call (built by keyword).

    Attributes:
        status: The backend's status (OSQP's string, ``"solved"``,
            ``"primal infeasible"``, …, or DAQP's exit flag name).
        iterations: ADMM iterations (OSQP, re-solves included) or active-set
            iterations (DAQP).
        solve_time_s: The QP solver's own solve time [s] (OSQP's or DAQP's).
        objective: Value of the MPC cost (constant reference terms included);
            NaN when the solve failed.
        states: Predicted states ``(N + 1, n)`` in absolute units.
        inputs: Planned inputs ``(N, m)`` in absolute units (before clipping).
        u: The input returned by the call ``(m,)`` (clipped to its hard bounds).
        call_time_s: Wall time of the backend's whole call [s], Python work included.
        fallback_used: True when the solve failed and the shifted previous plan
            was applied instead (``fallback="shift"``).
        message: Why the solve failed (empty when solved).
        max_slack: Largest slack of the soft state bounds over the horizon,
            i.e. the planned bound violation (0 for hard bounds).
        backend: ``"osqp"`` or ``"daqp"``.
        active_set_size: Inequality constraints active at the solution
            (nonzero multipliers; -1 when not solved).
        kkt_residual: KKT residual of the returned solution: OSQP's
            ``max(prim_res, dual_res)``, or the condensed QP's stationarity,
            feasibility and complementarity residual (NaN when not solved).
        dropped_rows: State-bound rows left out of the solve because no input
            can move them at their stage (see ``LinearMPC``), described; empty when none.
    """

    status: str
    iterations: int
    solve_time_s: float
    objective: float
    states: np.ndarray
    inputs: np.ndarray
    u: np.ndarray
    call_time_s: float = math.nan
    fallback_used: bool = False
    message: str = ""
    max_slack: float = 0.0
    backend: str = "osqp"
    active_set_size: int = -1
    kkt_residual: float = math.nan
    dropped_rows: str = ""


def clip_input(u: np.ndarray, u_prev: np.ndarray | None, du_max: np.ndarray | None, u_min: np.ndarray,
               u_max: np.ndarray) -> None:  # fmt: skip
    """Clip ``u`` in place to the rate bounds around ``u_prev`` (when both exist), then the input bounds (which win)."""
    if u_prev is not None and du_max is not None:
        np.minimum(u, u_prev + du_max, out=u)
        np.maximum(u, u_prev - du_max, out=u)
    np.minimum(u, u_max, out=u)
    np.maximum(u, u_min, out=u)


def same_reference(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or equal arrays of the same shape (a reference unchanged since the last call)."""
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and bool(np.array_equal(a, b))


@dataclasses.dataclass(frozen=True)
class NMPCSolution:
    """The outcome of one :class:`~shinro_ctrl.controllers.nmpc.NonlinearMPC` call.

    Attributes:
        status: ``"solved"`` (KKT residual below ``tol``), ``"rti"`` (the
            real-time iteration budget was used up first), or the failure.
        iterations: SQP iterations (QP solves) of the call; IPOPT's iterations
            with ``solver="ipopt"``.
        kkt_residual: KKT residual of the OCP at the last linearization point
            (stationarity and complementarity with the QP's multipliers, and
            the shooting defects), ∞-norm; IPOPT's final one for ``"ipopt"``.
        qp_status: The last QP's status (DAQP's exit flag in words, or OSQP's status).
        qp_iterations: Active-set iterations of the last QP.
        time_linearization_s: Defects and Jacobians (CasADi) [s].
        time_condensing_s: Building the condensed QP [s].
        time_qp_s: QP solves [s].
        time_other_s: Everything else (shift, step, line search) [s].
        solve_time_s: Wall time of the whole call [s].
        states: Predicted states ``(N + 1, n)``.
        inputs: Planned inputs ``(N, m)`` (before clipping).
        u: The input returned ``(m,)`` (clipped to the hard bounds).
        objective: OCP cost of the predicted trajectory.
        message: Why the call failed (empty when it did not).
    """

    status: str
    iterations: int
    kkt_residual: float
    qp_status: str
    qp_iterations: int
    time_linearization_s: float
    time_condensing_s: float
    time_qp_s: float
    time_other_s: float
    solve_time_s: float
    states: np.ndarray
    inputs: np.ndarray
    u: np.ndarray
    objective: float
    message: str = ""
