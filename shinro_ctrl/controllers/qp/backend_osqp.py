"""The sparse-QP backend of ``LinearMPC``: one warm-started OSQP object, polished and checked for exactness.

:class:`OsqpBackend` owns the sparse QP's vectors (``q``, ``l``, ``u``), the
warm-start buffers and one :class:`~shinro_ctrl.controllers._osqp.OsqpQP`. A
call writes the measured state into the initial-state rows, the previously
applied input into the first rate rows, rewrites ``q`` only when the
reference changes, warm-starts from the previous solution shifted by one
stage, and solves. A solve that ends "solved inaccurate", unpolished or at the
iteration limit is not exact: with a ``referee`` (the caller's condensed
solver, exact in a fraction of a millisecond) :attr:`OsqpBackend.settled`
becomes False at once and the caller settles the step; without one it is
re-solved from its own iterate with tightened tolerances, and
:attr:`~OsqpBackend.settled` is False if it still is not exact. The module docstring of
``controllers/mpc.py`` states the QP.
"""

from __future__ import annotations

import math
import time

import numpy as np

from shinro_ctrl.controllers._osqp import OsqpQP
from shinro_ctrl.controllers.qp.condensed import fixed_rows_note
from shinro_ctrl.controllers.qp.diagnose import describe_groups, diagnose
from shinro_ctrl.controllers.qp.options import MPCOptions, MPCProblem
from shinro_ctrl.controllers.qp.solution import MPCSolution, clip_input
from shinro_ctrl.controllers.qp.solution import same_reference as _same
from shinro_ctrl.controllers.qp.sparse import INF, QP, SparseQP, build_sparse, fill_linear_cost, fill_rate_rows

__all__ = ["OsqpBackend"]

_SOLVED = "solved"

#: Tightened settings of the OSQP re-solves after an inaccurate or unpolished solve, tried in turn
#: from the previous iterate: a moderately tighter one (usually enough for the polish to find the
#: active set), then a tight one.
_REFINES = (
    {"eps_abs": 1e-6, "eps_rel": 1e-6, "max_iter": 20_000, "polishing": True},
    {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 100_000, "polishing": True},
)

#: With polishing on, a polished OSQP solution is accepted as the optimum only when its residuals
#: ``max(prim_res, dual_res)`` are below this: a polish on a nearly right active set "succeeds"
#: with residuals ~1e-7 and a plan ~1e-4 off (measured on the cart-pole with an active cart bound).
_KKT_TOL = 1e-8


class OsqpBackend:
    """The sparse MPC QP solved by one warm-started OSQP object.

    Args:
        problem: Model, weights and horizon.
        options: The resolved options (bounds, operating point, OSQP settings, …).
        sparse: The sparse QP of ``problem`` (default: built here); its arrays are copied.
        referee: The caller settles solves that stay inexact (with the condensed
            solver): such a solve is then returned as is, not diagnosed.

    Attributes:
        name: ``"osqp"``.
        sparse: The sparse QP template (``P``, ``A_con``, groups, index maps).
        qp: The :class:`~shinro_ctrl.controllers._osqp.OsqpQP` (the only solver object).
        settled: False when the latest solve stayed inexact after the re-solves
            (neither a polished optimum with residuals below 1e-8 nor a certified infeasibility).
    """

    name = "osqp"

    def __init__(
        self, problem: MPCProblem, options: MPCOptions, sparse: SparseQP | None = None, *, referee: bool = False
    ):
        self.problem, self.options = problem, options
        p, n, m, N = problem, problem.n, problem.m, problem.N
        s = self.sparse = sparse if sparse is not None else build_sparse(p.A, p.B, p.Q, p.R, p.Qf, N, options)
        self.referee = bool(referee)
        self._q_default = s.q
        self._q, self._l, self._u = s.q.copy(), s.l.copy(), s.u.copy()
        self._has_slack = s.islack.stop > s.islack.start
        self._ineq0 = next(g for g in s.groups if g.name == "dynamics").stop  # rows from here on are inequalities
        self._warm = bool(options.osqp_settings["warm_starting"])
        nx = (N + 1) * n
        self._zws = np.zeros(s.n_var)
        self._yws = np.zeros(s.n_con)
        self._yinit = self._yws[:n]
        # LQR continuation of the shifted plan (views into the warm-start buffer)
        self._Acl = None if p.K is None else p.A - p.B @ p.K
        self._mK = None if p.K is None else -p.K
        self._zN_prev = self._zws[(N - 1) * n : N * n]  # after the shift: the old x_N
        self._zN = self._zws[N * n : (N + 1) * n]
        self._zuN = self._zws[nx + (N - 1) * m : nx + N * m]
        self._dx0 = self._l[:n]  # views into the bound vectors
        self._dx0u = self._u[:n]
        self._iu0 = slice(nx, nx + m)  # u_0 inside z
        self._q_dirty = False  # q differs from the default (reference terms present)
        self._q_const = 0.0  # constant cost term of the current reference
        self._ref_cache: np.ndarray | None = None  # the reference q was built for
        self._uref_cache: np.ndarray | None = None
        self._solved_since_setup = False
        self.settled = True
        self._fixed = _fixed_state_rows(problem, options, s)
        self._opened = False  # some of those rows are open in l/u (the previous step dropped them)
        if self._fixed is not None:
            self._fixed_value = np.empty(self._fixed[0].size)
            self._fixed_lo, self._fixed_hi = self._fixed[3] - 1e-9, self._fixed[4] + 1e-9
        self.qp = OsqpQP("MPC problem or its osqp_settings", s.P, self._q, s.A, self._l, self._u, options.osqp_settings)

    def reset(self) -> None:
        """Forget the warm start; a solver that has solved is set up afresh (OSQP keeps adaptive rho between solves)."""
        self._zws[:] = 0.0
        self._yws[:] = 0.0
        if self._solved_since_setup:
            self.qp.setup()
            self._solved_since_setup = False

    def current_qp(self) -> QP:
        """The QP as last sent to OSQP (copies)."""
        s = self.sparse
        return QP(s.P.copy(), self._q.copy(), s.A.copy(), self._l.copy(), self._u.copy())

    def describe(self) -> str:
        """Sizes and settings of the sparse QP and of OSQP."""
        s = self.sparse
        settings = ", ".join(f"{k}={v}" for k, v in sorted(self.qp.settings.items()))
        return (
            f"sparse QP (OSQP): {s.n_var} variables, {s.n_con} constraints, nnz(P) = {s.P.nnz}, "
            f"nnz(A) = {s.A.nnz}\nconstraint groups: {describe_groups(s.groups)}\nOSQP settings: {settings}"
        )

    def solve(
        self, x: np.ndarray, ref: np.ndarray | None, u_ref: np.ndarray | None, u_prev: np.ndarray | None
    ) -> MPCSolution:
        """One MPC step on the sparse QP.

        Args:
            x: Measured state ``(n,)`` [absolute], finite.
            ref: Checked state reference ``(n,)`` or ``(N + 1, n)``, or None (the operating point).
            u_ref: Checked input reference ``(m,)``, or None.
            u_prev: The previously applied input ``(m,)`` for the rate bounds, or None.

        Returns:
            The :class:`MPCSolution` (``u`` clipped to the hard input and rate bounds);
            on failure its ``message`` names the constraint group and stage.

        Raises:
            KeyboardInterrupt: OSQP was interrupted.
        """
        t0 = time.perf_counter()
        opts, s, n = self.options, self.sparse, self.problem.n
        np.subtract(x, opts.x0, out=self._dx0)
        self._dx0u[:] = self._dx0
        fill_rate_rows(s, opts, u_prev, self._l, self._u)
        dropped = self._drop_fixed_rows() if self._fixed is not None else ""
        q = self._update_q(ref, u_ref)
        if self._warm:
            self._zws[:n] = self._dx0
        self._solved_since_setup = True
        qp = self.qp
        qp.update(q, self._l, self._u)  # our l/u already hold ±1e30, never ±inf
        if self._warm:
            qp.warm_start(self._zws, self._yws)
        sol, info = qp.solve()
        iterations = info.iter
        self.settled = True
        if info.status != _SOLVED or (
            qp.settings["polishing"] and (info.status_polish != 1 or max(info.prim_res, info.dual_res) > _KKT_TOL)
        ):
            if self.referee and info.status not in ("primal infeasible", "interrupted"):
                # the caller's condensed solver gives the exact optimum in a fraction of a millisecond: cheaper
                # than re-solving to 1e-9 (up to 120,000 ADMM iterations, 0.8 s, on an ill-conditioned step)
                self.settled = False
            else:
                sol, info, iterations = self._refine(sol, info)
            if not self.settled and self.referee:
                self._shift_warm_start(np.array(sol.x, dtype=float), np.array(sol.y, dtype=float))
                return self._result(info.status, iterations, info.solve_time, t0, message="not settled")
        if info.status != _SOLVED:
            message = diagnose(x, info, sol, s.A, self._l, self._u, s.groups)
            # the next attempt starts from the shifted warm start, not the failed iterate
            self._shift_warm_start(self._zws.copy(), self._yws.copy())
            return self._result(info.status, iterations, info.solve_time, t0, message=message, dropped=dropped)
        z = sol.x
        u_out = z[self._iu0] + opts.u0
        clip_input(u_out, u_prev, opts.du_max, opts.u_min, opts.u_max)
        self._shift_warm_start(z, sol.y)  # for the next call
        states = z[s.ix].reshape(self.problem.N + 1, n)
        states += opts.x0
        inputs = z[s.iu].reshape(self.problem.N, self.problem.m)
        inputs += opts.u0
        return self._result(
            info.status,
            iterations,
            info.solve_time,
            t0,
            objective=info.obj_val + self._q_const,
            plan=(states, inputs, u_out),
            max_slack=float(z[s.islack].max()) if self._has_slack else 0.0,
            active=int(np.count_nonzero(sol.y[self._ineq0 :])),
            kkt=max(info.prim_res, info.dual_res),
            dropped=dropped,
        )

    def _result(
        self,
        status: str,
        iterations: int,
        solve_time: float,
        t0: float,
        *,
        objective: float = math.nan,
        plan: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        max_slack: float = 0.0,
        active: int = -1,
        kkt: float = math.nan,
        message: str = "",
        dropped: str = "",
    ) -> MPCSolution:
        if plan is None:
            p = self.problem
            plan = (np.full((p.N + 1, p.n), np.nan), np.full((p.N, p.m), np.nan), np.full(p.m, np.nan))
        return MPCSolution(
            status=status,
            iterations=iterations,
            solve_time_s=solve_time,
            objective=objective,
            states=plan[0],
            inputs=plan[1],
            u=plan[2],
            call_time_s=time.perf_counter() - t0,
            message=message,
            max_slack=max_slack,
            backend="osqp",
            active_set_size=active,
            kkt_residual=kkt,
            dropped_rows=dropped,
        )

    def _drop_fixed_rows(self) -> str:
        """Open the hard state-bound rows no input can move that the measured state violates (this step only)."""
        fx = self._fixed
        assert fx is not None
        rows, E, c, lo, hi = fx
        if self._opened:  # the previous step's opened rows are bounds again
            self._l[rows] = lo
            self._u[rows] = hi
            self._opened = False
        value = np.matmul(E, self._dx0, out=self._fixed_value)
        value += c
        if _within(value, self._fixed_lo, self._fixed_hi):
            return ""
        bad = np.flatnonzero((value > hi + 1e-9) | (value < lo - 1e-9))
        self._l[rows[bad]] = -INF
        self._u[rows[bad]] = INF
        self._opened = True
        opts, group = self.options, next(g for g in self.sparse.groups if g.name == "state bounds")
        bounded = np.flatnonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max))
        parts = []
        for b in bad:
            stage, label = group.locate(int(rows[b]))
            i = int(bounded[(rows[b] - group.start) % group.width])
            parts.append(f"{label} at stage {stage}: predicted {opts.x0[i] + value[b]:.4g} whatever the input")
        return fixed_rows_note(parts)

    def _update_q(self, ref: np.ndarray | None, u_ref: np.ndarray | None) -> np.ndarray | None:
        """Bring ``q`` to the references; returns it when it changed (for OSQP), else None."""
        if ref is None and u_ref is None:
            if not self._q_dirty:
                return None
            self._q[:] = self._q_default
            self._q_const = 0.0
            self._q_dirty = False
            return self._q
        if self._q_dirty and _same(ref, self._ref_cache) and _same(u_ref, self._uref_cache):
            return None  # same reference as last call: q is already in OSQP
        p = self.problem
        self._q_const = fill_linear_cost(self.sparse, p.Q, p.R, p.Qf, self.options, ref, u_ref, self._q)
        self._q_dirty = True
        self._ref_cache = None if ref is None else ref.copy()
        self._uref_cache = None if u_ref is None else u_ref.copy()
        return self._q

    def _refine(self, sol: object, info: object) -> tuple[object, object, int]:
        """Settle an OSQP solve that is not exact yet: interrupted, inaccurate, unpolished or out of iterations.

        An interrupted solve re-raises ``KeyboardInterrupt``; a certified
        infeasibility ("primal infeasible") is returned as is. Otherwise OSQP
        re-solves from its own iterate with tolerances 1e-6, then 1e-9, and
        polishing; if the result is still not a polished "solved" with
        residuals below ``_KKT_TOL`` (1e-8), :attr:`settled` becomes False.

        Returns:
            ``(sol, info, iterations)``: OSQP's final result and the total ADMM iterations.
        """
        if info.status == "interrupted":
            raise KeyboardInterrupt("OSQP solve interrupted")
        iterations = info.iter
        if info.status == "primal infeasible":
            return sol, info, iterations
        qp = self.qp
        saved = {k: qp.settings[k] for k in _REFINES[0]}
        for tighter in _REFINES:
            z, y = np.array(sol.x, dtype=float), np.array(sol.y, dtype=float)
            if np.all(np.isfinite(z)) and np.all(np.isfinite(y)):
                qp.warm_start(z, y)
            qp.update_settings(**tighter)
            try:
                sol, info = qp.solve()
            finally:
                qp.update_settings(**saved)
            iterations += info.iter
            if info.status == "interrupted":
                raise KeyboardInterrupt("OSQP solve interrupted")
            exact = info.status == _SOLVED and info.status_polish == 1 and max(info.prim_res, info.dual_res) <= _KKT_TOL
            if exact or info.status == "primal infeasible":
                return sol, info, iterations
        self.settled = False
        return sol, info, iterations

    def _shift_warm_start(self, z: np.ndarray, y: np.ndarray) -> None:
        """Warm start for the next call: stage k takes stage k + 1 of ``(z, y)``.

        The new last stage continues with the LQR policy when the terminal cost
        is the DARE's (``x_N ← (A − B K) x_N``, ``u_{N−1} ← −K x_N``), else it
        repeats. Writes into preallocated buffers only.
        """
        zws = self._zws
        np.take(z, self.sparse.zshift, out=zws)
        np.take(y, self.sparse.yshift, out=self._yws)
        np.negative(self._yinit, out=self._yinit)  # old -y(dynamics, stage 1) is the new y(initial state)
        if self._Acl is not None:
            np.matmul(self._Acl, self._zN_prev, out=self._zN)
            np.matmul(self._mK, self._zN_prev, out=self._zuN)


def _within(value: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """``lo <= value <= hi`` everywhere (a few small rows: a plain loop beats array temporaries)."""
    for v, a, b in zip(value.tolist(), lo.tolist(), hi.tolist(), strict=True):
        if v < a or v > b:
            return False
    return True


def _fixed_state_rows(
    problem: MPCProblem, opts: MPCOptions, s: SparseQP
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The hard state-bound rows whose state no input moves at their stage, with their prediction.

    State ``i`` at stage ``k`` depends on the inputs iff row ``i`` of
    ``[A^{k-1} B, …, A B, B]`` is nonzero (the same rows the condensed QP
    finds fixed). Returns ``(rows, E, c, lo, hi)``: the rows of ``A_con``,
    ``δx_{k,i} = E_r δx_0 + c_r`` and the rows' bounds; None when there are none.
    """
    group = next((g for g in s.groups if g.name == "state bounds"), None)
    if group is None or opts.soft:
        return None  # soft bounds take any violation into their slack
    A, B, N, n = problem.A, problem.B, problem.N, problem.n
    xb = np.flatnonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max))
    tol = 1e-13 * max(1.0, float(np.abs(B).max(initial=0.0)))
    reach = np.zeros(n)  # squared row norms of [A^{k-1} B, …, B]
    AkB = B.copy()
    Ak = np.eye(n)
    c = np.zeros(n)
    rows, Es, cs = [], [], []
    for k in range(1, N + 1):
        reach += np.sum(AkB * AkB, axis=1) if k == 1 else 0.0
        if k > 1:
            AkB = A @ AkB
            reach += np.sum(AkB * AkB, axis=1)
        Ak = A @ Ak
        c = A @ c + opts.offset
        free = [j for j, i in enumerate(xb) if np.sqrt(reach[i]) <= tol]
        if not free:
            break
        for j in free:
            rows.append(group.start + (k - 1) * group.width + j)
            Es.append(Ak[xb[j]])
            cs.append(c[xb[j]])
    if not rows:
        return None
    r = np.array(rows, dtype=np.intp)
    return r, np.array(Es), np.array(cs), s.l[r].copy(), s.u[r].copy()
