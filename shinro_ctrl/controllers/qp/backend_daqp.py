"""The condensed-QP backend of ``LinearMPC``: DAQP's dual active-set method on the input-only QP.

:class:`DaqpBackend` owns one :class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP`
(its matrices, buffers and warm working set) and the reference it was last set
to. A call sets the reference only when it changed, solves, and on failure asks
the elastic LP for the infeasibility certificate.
"""

from __future__ import annotations

import math
import time

import numpy as np

from shinro_ctrl.controllers.qp.condensed import CondensedQP
from shinro_ctrl.controllers.qp.diagnose import describe_groups, fmt
from shinro_ctrl.controllers.qp.options import MPCOptions, MPCProblem
from shinro_ctrl.controllers.qp.solution import MPCSolution, clip_input
from shinro_ctrl.controllers.qp.solution import same_reference as _same

__all__ = ["DaqpBackend"]


class DaqpBackend:
    """The condensed MPC QP (inputs around the DARE's pre-stabilizing feedback) solved exactly by DAQP.

    Args:
        problem: Model, weights and horizon.
        options: The resolved options.

    Attributes:
        name: ``"daqp"``.
        dense: The :class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP`.
        settled: Always True (DAQP's answer is exact, or a certified failure).
    """

    name = "daqp"
    settled = True

    def __init__(self, problem: MPCProblem, options: MPCOptions):
        self.problem, self.options = problem, options
        p = problem
        K = p.K  # the DARE's gain when the terminal cost is the DARE's; else CondensedQP computes one
        self.dense = CondensedQP(p.A, p.B, p.Q, p.R, p.Qf, p.N, K=K, options=options)
        self._has_ref = False  # the condensed QP holds a reference (not the operating point)
        self._ref_cache: np.ndarray | None = None
        self._uref_cache: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the working set (the next solve starts cold: runs repeat exactly)."""
        self.dense.reset()

    def describe(self) -> str:
        """Sizes and settings of the condensed QP and of DAQP."""
        settings = ", ".join(f"{k}={v}" for k, v in sorted(self.dense.settings.items()))
        groups = describe_groups(self.dense.matrices.groups)
        return f"{self.dense.describe()}\nconstraint groups: {groups or 'none'}\nDAQP settings: {settings}"

    def solve(
        self, x: np.ndarray, ref: np.ndarray | None, u_ref: np.ndarray | None, u_prev: np.ndarray | None
    ) -> MPCSolution:
        """One MPC step on the condensed QP (arguments as :meth:`.backend_osqp.OsqpBackend.solve`)."""
        t0 = time.perf_counter()
        dq, opts = self.dense, self.options
        if ref is None and u_ref is None:
            if self._has_ref:
                dq.set_reference()
                self._has_ref = False
        elif not (self._has_ref and _same(ref, self._ref_cache) and _same(u_ref, self._uref_cache)):
            dq.set_reference(ref, u_ref)
            self._has_ref = True
            self._ref_cache = None if ref is None else ref.copy()
            self._uref_cache = None if u_ref is None else u_ref.copy()
        info = dq.solve(x, u_prev)
        if not info.solved:
            where = f"(DAQP status '{info.status}', {info.iterations} iterations) at x = {fmt(x)}"
            why = dq.explain_infeasibility(x, u_prev)  # an elastic LP's certificate, or None
            if why is not None:
                message = f"MPC problem infeasible {where}: {why}"
            else:
                message = (
                    f"MPC problem not solved {where}: no infeasibility certificate (an elastic LP finds the "
                    "constraints feasible); the solver failed numerically"
                )
            p = self.problem
            states, inputs, u_out = np.full((p.N + 1, p.n), np.nan), np.full((p.N, p.m), np.nan), np.full(p.m, np.nan)
            objective, max_slack, active = math.nan, 0.0, -1
        else:
            states, inputs, max_slack = dq.plan()
            u_out = inputs[0].copy()
            clip_input(u_out, u_prev, opts.du_max, opts.u_min, opts.u_max)
            objective, active, message = info.objective, info.active_set_size, ""
        return MPCSolution(
            status=info.status,
            iterations=info.iterations,
            solve_time_s=info.solve_time_s,
            objective=objective,
            states=states,
            inputs=inputs,
            u=u_out,
            call_time_s=time.perf_counter() - t0,
            message=message,
            max_slack=max_slack,
            backend="daqp",
            active_set_size=active,
            kkt_residual=info.kkt_residual,
            dropped_rows=dq.dropped_rows,
        )
