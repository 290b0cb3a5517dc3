"""The per-call solve of :class:`~shinro_ctrl.controllers.mpc.LinearMPC` on its two backends.

:class:`MPCSolve` is a mixin of ``LinearMPC`` (it holds no state of its own and
reads the controller's attributes): the sparse structure and the lazily set-up
OSQP object, the warm-started OSQP call with its exactness refinement, the
condensed (DAQP) call, and what happens when a solve fails (the
infeasibility message, ``MPCInfeasible`` or the ``fallback="shift"`` plan).
The module docstring of ``controllers/mpc.py`` states the QP.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from shinro_ctrl.controllers._osqp import OsqpQP
from shinro_ctrl.controllers.qp.condensed import MAX_DENSE_SIZE, CondensedQP, DenseSolveInfo
from shinro_ctrl.controllers.qp.diagnose import diagnose, fmt
from shinro_ctrl.controllers.qp.dispatch import dense_size
from shinro_ctrl.controllers.qp.solution import MPCSolution
from shinro_ctrl.controllers.qp.sparse import INF as _INF
from shinro_ctrl.controllers.qp.sparse import RowGroup, build_sparse
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError
from shinro_ctrl.validation import as_vector

__all__ = ["MPCSolve"]

_SOLVED = "solved"
_fmt = fmt

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


class MPCSolve:
    """The solve half of ``LinearMPC``: structure, both backends' calls, failure handling (a mixin)."""

    # these live on the controller (see LinearMPC.__init__); declared for readers and type checkers
    n: int
    m: int
    N: int
    dense: CondensedQP | None
    _referee: CondensedQP | None
    _osqp_qp: OsqpQP | None

    def _condensed(self) -> CondensedQP:
        """The condensed QP of this controller's model, bounds and weights (DARE gain as pre-stabilizer)."""
        o = self.options
        return CondensedQP(
            self.A,
            self.B,
            self.Q,
            self.R,
            self.P_f,
            self.N,
            K=self.K,
            x_op=self.x0,
            u_op=self.u0,
            offset=self.offset,
            u_min=self.u_min,
            u_max=self.u_max,
            x_min=self.x_min,
            x_max=self.x_max,
            du_max=self.du_max,
            soft=self.soft,
            soft_weight_l1=self.soft_weight_l1,
            soft_weight_quad=self.soft_weight_quad,
            state_names=o.state_names,
            input_names=o.input_names,
        )

    def _build_structure(self) -> None:
        """Assemble P, A_con, q, l, u and the index maps (once), then the reusable buffers."""
        n, m, N = self.n, self.m, self.N
        s = build_sparse(self.A, self.B, self.Q, self.R, self.P_f, N, self.options)
        self._sparse = s
        self._P, self._A, self._l, self._u = s.P, s.A, s.l, s.u
        self._q_default = s.q.copy()
        self._q = s.q
        self._ix, self._iu, self._is = s.ix, s.iu, s.islack
        self._has_slack = s.islack.stop > s.islack.start
        self.n_var, self.n_con = s.n_var, s.n_con
        self._group_list = s.groups
        self.groups: dict[str, RowGroup] = {g.name: g for g in s.groups}
        self._rate_idx = s.rate_idx
        rate = self.groups.get("rate bounds")
        self._rate0 = None if rate is None else slice(rate.start, rate.start + rate.width)
        self._zshift, self._yshift = s.zshift, s.yshift
        self._ineq0 = self.groups["dynamics"].stop  # rows from here on are inequalities
        nx = (N + 1) * n

        # ---- reusable buffers
        self._zws = np.zeros(self.n_var)
        self._yws = np.zeros(self.n_con)
        self._yinit = self._yws[:n]
        # LQR continuation of the shifted plan (views into the warm-start buffer)
        self._Acl = None if self.K is None else self.A - self.B @ self.K
        self._mK = None if self.K is None else -self.K
        self._zN_prev = self._zws[(N - 1) * n : N * n]  # after the shift: the old x_N
        self._zN = self._zws[N * n : (N + 1) * n]
        self._zuN = self._zws[nx + (N - 1) * m : nx + N * m]
        self._dx0 = self._l[:n]  # views into the bound vectors
        self._dx0u = self._u[:n]
        self._iu0 = slice(nx, nx + m)  # u_0 inside z
        self._u_prev_buf = np.zeros(m)  # the previously applied input (when _u_prev is not None)
        self._q_dirty = False  # q differs from the default (reference terms present)
        self._q_const = 0.0  # constant cost term of the current reference
        self._ref_cache: np.ndarray | None = None  # the reference q was built for
        self._uref_cache: np.ndarray | None = None

    @property
    def _osqp(self) -> OsqpQP:
        """The OSQP object of the sparse QP, set up on first use (the DAQP backend may never need it)."""
        qp = self._osqp_qp
        if qp is None:
            qp = self._osqp_qp = OsqpQP(
                "MPC problem or its osqp_settings", self._P, self._q, self._A, self._l, self._u, self.osqp_settings
            )
        return qp

    def _call_osqp(self, x: np.ndarray, ref: Any, u_ref: Any, t0: float) -> np.ndarray:
        """One call on the sparse QP: write ``x`` (and the reference) into the data, warm-start, solve."""
        n = self.n
        np.subtract(x, self.x0, out=self._dx0)
        self._dx0u[:] = self._dx0
        if ref is None and u_ref is None and self.u_ref is None:
            q = None
            if self._q_dirty:
                self._q[:] = self._q_default
                self._q_const = 0.0
                self._q_dirty = False
                q = self._q
        else:
            r, ur = self._check_ref(ref), self._check_uref(u_ref)
            if self._q_dirty and _same(r, self._ref_cache) and _same(ur, self._uref_cache):
                q = None  # same reference as last call: q is already in OSQP
            else:
                self._q_const = self._fill_q(r, ur, self._q)
                self._q_dirty = True
                self._ref_cache = None if r is None else r.copy()
                self._uref_cache = None if ur is None else ur.copy()
                q = self._q
        if self._warm:
            self._zws[:n] = self._dx0
        self._solved_since_setup = True
        qp = self._osqp
        qp.update(q, self._l, self._u)  # our l/u already hold ±1e30, never ±inf
        if self._warm:
            qp.warm_start(self._zws, self._yws)
        sol, info = qp.solve()
        iterations = info.iter
        if info.status != _SOLVED or (
            qp.settings["polishing"] and (info.status_polish != 1 or max(info.prim_res, info.dual_res) > _KKT_TOL)
        ):
            sol, info, iterations, settled = self._refine(x, sol, info, ref, u_ref)
            if settled is not None:
                return settled
        if info.status != _SOLVED:
            return self._failed(x, info, sol, t0)

        z = sol.x
        u_out = z[self._iu0] + self.u0
        self._clip(u_out)
        self._u_prev = self._u_prev_buf  # a private copy: the caller may modify what we return
        self._u_prev_buf[:] = u_out
        if self._rate0 is not None:
            self._fill_rate0(u_out, self._l, self._u)
        # shifted warm start for the next call
        self._shift_warm_start(z, sol.y)
        states = z[self._ix].reshape(self.N + 1, n)
        states += self.x0
        inputs = z[self._iu].reshape(self.N, self.m)
        inputs += self.u0
        self._plan_x, self._plan_u, self._plan_age = states, inputs, 0
        self.last = MPCSolution(
            info.status,
            iterations,
            time.perf_counter() - t0,
            info.solve_time,
            info.obj_val + self._q_const,
            states,
            inputs,
            u_out,
            False,
            "",
            float(z[self._is].max()) if self._has_slack else 0.0,
            "osqp",
            int(np.count_nonzero(sol.y[self._ineq0 :])),
            max(info.prim_res, info.dual_res),
        )
        return u_out

    def _refine(self, x: np.ndarray, sol: Any, info: Any, ref: Any, u_ref: Any) -> tuple[Any, Any, int, Any]:
        """Settle an OSQP solve that is not exact yet: interrupted, inaccurate, unpolished or out of iterations.

        An interrupted solve re-raises ``KeyboardInterrupt``; a certified
        infeasibility ("primal infeasible") is returned as is. Otherwise OSQP
        re-solves from its own iterate with tolerances 1e-6, then 1e-9, and polishing; if
        the result is still not a polished "solved" with residuals below
        ``_KKT_TOL`` (1e-8), the condensed solver
        settles the step when the problem fits it (its exact optimum, or its
        certified infeasibility).

        Returns:
            ``(sol, info, iterations, settled)``: OSQP's final result and the
            total ADMM iterations, and the input when the condensed solver
            answered (``last`` already set), else None.
        """
        if info.status == "interrupted":
            raise KeyboardInterrupt("OSQP solve interrupted")
        iterations = info.iter
        if info.status == "primal infeasible":
            return sol, info, iterations, None
        qp = self._osqp
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
                return sol, info, iterations, None
        if self._referee is None and dense_size(self.n, self.m, self.N, self.options) <= MAX_DENSE_SIZE:
            self._referee = self._condensed()
        if self._referee is None:
            return sol, info, iterations, None  # too large for the condensed check: the tightened solve stands
        t0 = time.perf_counter()
        u = self._call_dense(x, ref, u_ref, t0, self._referee)
        self._shift_warm_start(np.array(sol.x, dtype=float), np.array(sol.y, dtype=float))
        return sol, info, iterations, u

    # ============================================================ internals
    def _check_ref(self, ref: Any) -> np.ndarray | None:
        if ref is None:
            return None
        r = np.asarray(ref, dtype=float)
        if r.shape == (self.n,) or r.shape == (self.N + 1, self.n) or (self.n == 1 and r.shape == (self.N + 1,)):
            if not np.isfinite(r).all():
                raise NonFiniteError("ref must be finite")
            return r.reshape(-1, self.n) if r.ndim == 1 and r.shape != (self.n,) else r
        raise InvalidArgument(f"ref: expected ({self.n},) or ({self.N + 1}, {self.n}) but found {r.shape}")

    def _check_uref(self, u_ref: Any) -> np.ndarray | None:
        if u_ref is None:
            return self.u_ref
        return as_vector("u_ref", u_ref, self.m)

    def _fill_q(self, ref: np.ndarray | None, u_ref: np.ndarray | None, q: np.ndarray) -> float:
        """Write the linear cost for ``ref``/``u_ref`` into ``q``; return the constant term."""
        n, m, N = self.n, self.m, self.N
        qx = q[self._ix].reshape(N + 1, n)
        qu = q[self._iu].reshape(N, m)
        const = 0.0
        if ref is None:
            qx[:] = 0.0
        elif ref.ndim == 1:
            rho = ref - self.x0
            g = self.Q @ rho
            qx[:N] = -g
            gN = self.P_f @ rho
            qx[N] = -gN
            const += 0.5 * (N * float(rho @ g) + float(rho @ gN))
        else:
            rho = ref - self.x0
            G = rho[:N] @ self.Q
            qx[:N] = -G
            gN = self.P_f @ rho[N]
            qx[N] = -gN
            const += 0.5 * (float(np.sum(G * rho[:N])) + float(rho[N] @ gN))
        if u_ref is None:
            qu[:] = 0.0
        else:
            nu = u_ref - self.u0
            g = self.R @ nu
            qu[:] = -g
            const += 0.5 * N * float(nu @ g)
        return const

    def _fill_rate0(self, u_prev: np.ndarray | None, l: np.ndarray, u: np.ndarray) -> None:
        """Write the first-stage rate rows for the previously applied input."""
        if self._rate0 is None:
            return
        ri = self._rate_idx
        if u_prev is None:
            l[self._rate0] = -_INF
            u[self._rate0] = _INF
        else:
            c = u_prev[ri] - self.u0[ri]
            l[self._rate0] = c - self.du_max[ri]
            u[self._rate0] = c + self.du_max[ri]

    def _shift_warm_start(self, z: np.ndarray, y: np.ndarray) -> None:
        """Warm start for the next call: stage k takes stage k + 1 of ``(z, y)``.

        The new last stage continues with the LQR policy when the terminal cost
        is the DARE's (``x_N ← (A − B K) x_N``, ``u_{N−1} ← −K x_N``), else it
        repeats. Writes into preallocated buffers only.
        """
        zws = self._zws
        np.take(z, self._zshift, out=zws)
        np.take(y, self._yshift, out=self._yws)
        np.negative(self._yinit, out=self._yinit)  # old -y(dynamics, stage 1) is the new y(initial state)
        if self._Acl is not None:
            np.matmul(self._Acl, self._zN_prev, out=self._zN)
            np.matmul(self._mK, self._zN_prev, out=self._zuN)

    def _clip(self, u: np.ndarray) -> None:
        """Clip ``u`` in place to the rate bounds, then the input bounds (which win)."""
        if self._u_prev is not None and self._rate0 is not None:
            np.minimum(u, self._u_prev + self.du_max, out=u)
            np.maximum(u, self._u_prev - self.du_max, out=u)
        np.minimum(u, self.u_max, out=u)
        np.maximum(u, self.u_min, out=u)

    def _call_dense(self, x: np.ndarray, ref: Any, u_ref: Any, t0: float, dq: CondensedQP | None = None) -> np.ndarray:
        """One call on the condensed QP (``dq``: the referee of an inexact OSQP solve; default :attr:`dense`)."""
        own = dq is None
        dq = self.dense if dq is None else dq
        assert dq is not None
        if ref is None and u_ref is None and self.u_ref is None:
            if self._dense_ref or not own:
                dq.set_reference()
                self._dense_ref = False if own else self._dense_ref
        else:
            r, ur = self._check_ref(ref), self._check_uref(u_ref)
            if not own or not (self._dense_ref and _same(r, self._ref_cache) and _same(ur, self._uref_cache)):
                dq.set_reference(r, ur)
                if own:
                    self._dense_ref = True
                    self._ref_cache = None if r is None else r.copy()
                    self._uref_cache = None if ur is None else ur.copy()
        info = dq.solve(x, self._u_prev)
        if not own and self.dense is None:
            dq.set_reference()  # the referee's next use starts from the operating point again
        if not info.solved:
            return self._failed_dense(x, info, t0, dq)
        states, inputs, max_slack = dq.plan()
        u_out = inputs[0].copy()
        self._clip(u_out)
        self._u_prev = self._u_prev_buf  # a private copy: the caller may modify what we return
        self._u_prev_buf[:] = u_out
        if self._rate0 is not None:
            self._fill_rate0(u_out, self._l, self._u)
        self._plan_x, self._plan_u, self._plan_age = states, inputs, 0
        self.last = MPCSolution(
            info.status,
            info.iterations,
            time.perf_counter() - t0,
            info.solve_time_s,
            info.objective,
            states,
            inputs,
            u_out,
            False,
            "",
            max_slack,
            "daqp",
            info.active_set_size,
            info.kkt_residual,
        )
        return u_out

    def _failed_dense(self, x: np.ndarray, info: DenseSolveInfo, t0: float, dq: CondensedQP) -> np.ndarray:
        where = f"(DAQP status '{info.status}', {info.iterations} iterations) at x = {_fmt(x)}"
        why = dq.explain_infeasibility(x, self._u_prev)  # an elastic LP's certificate, or None
        if why is not None:
            message = f"MPC problem infeasible {where}: {why}"
        else:
            message = (
                f"MPC problem not solved {where}: no infeasibility certificate (an elastic LP finds the "
                "constraints feasible); the solver failed numerically"
            )
        return self._give_up(x, info.status, info.iterations, info.solve_time_s, message, t0, "daqp")

    def _failed(self, x: np.ndarray, info: Any, sol: Any, t0: float) -> np.ndarray:
        message = diagnose(x, info, sol, self._A, self._l, self._u, self._group_list)
        # the next attempt starts from the shifted warm start, not the failed iterate
        self._shift_warm_start(self._zws.copy(), self._yws.copy())
        return self._give_up(x, info.status, info.iter, info.solve_time, message, t0, "osqp")

    def _give_up(
        self, x: np.ndarray, status: str, iterations: int, solver_time: float, message: str, t0: float, backend: str
    ) -> np.ndarray:
        """Raise :class:`MPCInfeasible` with ``message``, or apply the shifted previous plan (``fallback="shift"``)."""
        age = self._plan_age + 1
        if self.fallback != "shift" or self._plan_u is None or age >= self.N:
            if self.fallback == "shift":
                message += (
                    "; fallback 'shift' has no previous plan"
                    if self._plan_u is None
                    else f"; fallback 'shift' exhausted the previous plan ({self.N} steps)"
                )
            self.last = MPCSolution(
                status,
                iterations,
                time.perf_counter() - t0,
                solver_time,
                math.nan,
                np.full((self.N + 1, self.n), np.nan),
                np.full((self.N, self.m), np.nan),
                np.full(self.m, np.nan),
                False,
                message,
                backend=backend,
            )
            raise MPCInfeasible(message)
        self._plan_age = age
        u_out = self._plan_u[age].copy()
        self._clip(u_out)
        self._u_prev = self._u_prev_buf
        self._u_prev_buf[:] = u_out
        if self._rate0 is not None:
            self._fill_rate0(u_out, self._l, self._u)
        idx = np.minimum(np.arange(self.N + 1) + age, self.N)
        self.last = MPCSolution(
            status,
            iterations,
            time.perf_counter() - t0,
            solver_time,
            math.nan,
            self._plan_x[idx],
            self._plan_u[np.minimum(idx[:-1], self.N - 1)],
            u_out,
            True,
            message,
            backend=backend,
        )
        return u_out


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or equal arrays of the same shape."""
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and bool(np.array_equal(a, b))
