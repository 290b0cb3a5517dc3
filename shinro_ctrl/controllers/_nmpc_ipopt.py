"""The reference strategy of :class:`~shinro_ctrl.controllers.nmpc.NonlinearMPC`: the OCP solved by IPOPT.

:class:`IpoptSolver` writes the multiple-shooting OCP of an
:class:`~shinro_ctrl.controllers._nmpc_ocp.NMPCProblem` as one
``casadi.nlpsol`` problem (the measured state and the reference as
parameters) and solves it warm-started from its previous solution shifted by
one stage: ``solver="ipopt"`` at every call, and (held by the real-time
iteration) the ``cold_start="ipopt"`` first trajectory.
"""

from __future__ import annotations

import math
import time
from typing import Any

import casadi as cs
import numpy as np

from shinro_ctrl._interrupts import solve_interruptibly
from shinro_ctrl.controllers._nmpc_ocp import NMPCProblem, failed_solution
from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import MPCInfeasible

__all__ = ["IpoptSolver"]


class IpoptSolver:
    """The OCP solved to convergence by IPOPT at every call (an :class:`~._nmpc_ocp.NMPCStrategy`).

    Args:
        ocp: The problem (its options are read whole).
    """

    def __init__(self, ocp: NMPCProblem):
        self.ocp = ocp
        o = ocp.options
        n, m, N = ocp.n, ocp.m, ocp.N
        X = cs.MX.sym("X", n, N + 1)
        U = cs.MX.sym("U", m, N)
        bounded = np.flatnonzero(np.isfinite(o.x_min) | np.isfinite(o.x_max))
        self._bounded = bounded if o.soft else bounded[:0]
        ns = self._bounded.size * N  # one slack per state-bound row (stage and bounded component)
        S = cs.MX.sym("S", ns)
        man = ocp.manifold
        nt = ocp.nt
        P = cs.MX.sym("P", 2 * n + (0 if man is None else nt * n))
        x_meas, r = P[:n], P[n : 2 * n]
        E = X - cs.repmat(r, 1, N + 1)
        if man is not None:
            # a floating base (the cold start only): the deviation D(r) (x − r), on a quaternion the chordal
            # attitude error 2 vec(q_r⁻¹ ⊗ q) (|·| = 2 sin(θ/2), the same for q and −q: smooth, no sign
            # ambiguity); the quaternions stay unit through the manifold step from the measured x_0
            E = cs.mtimes(cs.reshape(P[2 * n :], nt, n), E)
        dU = U - cs.repmat(cs.DM(ocp.u0), 1, N)
        J = 0.5 * cs.sum2(cs.sum1(E[:, :N] * cs.mtimes(cs.DM(ocp.Q), E[:, :N])))
        J += 0.5 * cs.bilin(cs.DM(ocp.Qf), E[:, N], E[:, N])
        J += 0.5 * cs.sum2(cs.sum1(dU * cs.mtimes(cs.DM(ocp.R), dU)))
        if ns:
            J += o.soft_weight_l1 * cs.sum1(S) + 0.5 * o.soft_weight_quad * cs.sumsqr(S)
        Fk = ocp.F.map(N)(X[:, :N], U)
        g = [X[:, 0] - x_meas, cs.vec(Fk - X[:, 1:])]
        lbg = [np.zeros(n), np.zeros(n * N)]
        ubg = [np.zeros(n), np.zeros(n * N)]
        lbx_X = np.full((N + 1, n), -np.inf)
        ubx_X = np.full((N + 1, n), np.inf)
        if ns:
            Sm = cs.reshape(S, N, self._bounded.size)  # Sm[k, j]: the slack of x_{k+1}[bounded[j]]
            for j, i in enumerate(self._bounded):
                if np.isfinite(o.x_max[i]):
                    g.append(X[i, 1:].T - Sm[:, j])
                    lbg.append(np.full(N, -np.inf))
                    ubg.append(np.full(N, o.x_max[i]))
                if np.isfinite(o.x_min[i]):
                    g.append(X[i, 1:].T + Sm[:, j])
                    lbg.append(np.full(N, o.x_min[i]))
                    ubg.append(np.full(N, np.inf))
        else:
            lbx_X[1:] = o.x_min
            ubx_X[1:] = o.x_max
        w = cs.vertcat(cs.vec(X), cs.vec(U), S)
        nlp = {"x": w, "f": J, "g": cs.vertcat(*g), "p": P}
        opts = {
            "print_time": False,
            "ipopt": {"print_level": 0, "sb": "yes", "tol": o.tol, "max_iter": 3000},
        }
        self._nlp = cs.nlpsol("nmpc", "ipopt", nlp, opts)
        self._lbw = np.concatenate([lbx_X.ravel(), np.tile(o.u_min, N), np.zeros(ns)])
        self._ubw = np.concatenate([ubx_X.ravel(), np.tile(o.u_max, N), np.full(ns, np.inf)])
        self._lbg = np.concatenate(lbg)
        self._ubg = np.concatenate(ubg)
        self._guess: np.ndarray | None = None
        self.status = ""  # IPOPT's return status of the last solve

    def reset(self) -> None:
        """Forget the warm start: the next solve starts from the measured state held over the horizon."""
        self._guess = None

    def prepare(self) -> None:
        """Nothing to prepare: IPOPT solves the whole OCP when the state arrives."""
        return None

    def solve(self, x: np.ndarray, ref: np.ndarray) -> NMPCSolution:
        """The OCP from ``x (n,)`` towards ``ref (n,)`` to convergence (a failure is returned, not raised)."""
        t_start = time.perf_counter()
        o = self.ocp.options
        try:
            X, U, stats, obj = self.trajectory(x, ref)
        except MPCInfeasible as exc:
            total = time.perf_counter() - t_start
            return failed_solution(self.ocp, str(exc), self.status, total)
        t_qp = time.perf_counter() - t_start
        u = np.clip(U[0], o.u_min, o.u_max)
        iters = int(stats.get("iter_count", 0))
        total = time.perf_counter() - t_start
        return NMPCSolution(
            status="solved", iterations=iters, kkt_residual=math.nan, qp_status=str(stats.get("return_status")),
            qp_iterations=iters, time_linearization_s=0.0, time_condensing_s=0.0, time_qp_s=t_qp,
            time_other_s=total - t_qp, solve_time_s=total, states=X.copy(), inputs=U.copy(), u=u,
            objective=obj,
        )  # fmt: skip

    def _parameters(self, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """The NLP's parameters: ``[x; ref]`` (and ``D(ref)`` column-major on a floating base)."""
        man = self.ocp.manifold
        if man is None:
            return np.concatenate([x, ref])
        D, _ = man.tangent_maps(ref)
        return np.concatenate([x, ref, D.ravel(order="F")])

    def trajectory(self, x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, Any], float]:
        """The OCP from ``x`` solved by IPOPT, warm-started from the previous solution shifted.

        Returns:
            ``(X (N + 1, n), U (N, m), IPOPT's stats, objective)``.

        Raises:
            MPCInfeasible: IPOPT did not succeed (the warm start is then forgotten).
        """
        ocp = self.ocp
        o = ocp.options
        n, m, N = ocp.n, ocp.m, ocp.N
        nX = n * (N + 1)
        if self._guess is None:
            guess = np.concatenate(
                [
                    np.tile(x, N + 1),
                    np.tile(np.clip(ocp.u0, o.u_min, o.u_max), N),
                    np.zeros(self._lbw.size - nX - N * m),
                ]
            )
        else:
            guess = self._guess.copy()
            Xg = guess[:nX].reshape(N + 1, n)
            Ug = guess[nX : nX + N * m].reshape(N, m)
            Xg[:-1] = Xg[1:].copy()
            Ug[:-1] = Ug[1:].copy()
            Xg[0] = x
        if self._bounded.size:  # slacks that make the guess meet the soft bounds: a feasible start for them
            Xg = guess[:nX].reshape(N + 1, n)[1:, self._bounded]
            viol = np.maximum(Xg - o.x_max[self._bounded], o.x_min[self._bounded] - Xg)
            guess[nX + N * m :] = np.maximum(viol, 0.0).ravel(order="F")
        try:  # a Ctrl-C inside IPOPT is raised, not returned as 'NonIpopt_Exception_Thrown'
            sol = solve_interruptibly(
                self._nlp,
                x0=guess,
                lbx=self._lbw,
                ubx=self._ubw,
                lbg=self._lbg,
                ubg=self._ubg,
                p=self._parameters(x, ref),
            )
        except KeyboardInterrupt:
            self._guess = None
            raise
        stats = self._nlp.stats()
        self.status = str(stats.get("return_status", ""))
        w = np.asarray(sol["x"], dtype=float).ravel()
        if not stats.get("success", False) or not np.all(np.isfinite(w)):
            status = self.status = str(stats.get("return_status", "failed"))
            self._guess = None
            raise MPCInfeasible(f"NonlinearMPC (ipopt): {status} at x = {np.array2string(x, precision=4)}")
        self._guess = w
        X = w[:nX].reshape(N + 1, n)
        U = w[nX : nX + N * m].reshape(N, m)
        return X, U, stats, float(sol["f"])
