"""The reference solver of :class:`~shinro_ctrl.controllers.nmpc.NonlinearMPC`: the OCP by IPOPT.

:class:`NMPCIpopt` (a mixin of ``NonlinearMPC``) writes the multiple-shooting
OCP as one ``casadi.nlpsol`` problem (the measured state and the reference as
parameters) and solves it warm-started from the previous solution shifted by
one stage: ``solver="ipopt"`` at every call, and the ``cold_start="ipopt"``
first trajectory of the real-time iteration.
"""

from __future__ import annotations

import math
import time
from typing import Any

import casadi as cs
import numpy as np

from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import MPCInfeasible

__all__ = ["NMPCIpopt"]


class NMPCIpopt:
    """The OCP solved by IPOPT (a mixin of ``NonlinearMPC``)."""

    n: int
    m: int
    N: int
    last: NMPCSolution | None

    def _build_ipopt(self) -> None:
        n, m, N = self.n, self.m, self.N
        X = cs.MX.sym("X", n, N + 1)
        U = cs.MX.sym("U", m, N)
        bounded = np.flatnonzero(np.isfinite(self.x_min) | np.isfinite(self.x_max))
        ns = bounded.size if self.soft else 0
        S = cs.MX.sym("S", ns)
        P = cs.MX.sym("P", 2 * n)
        x_meas, r = P[:n], P[n:]
        E = X - cs.repmat(r, 1, N + 1)
        dU = U - cs.repmat(cs.DM(self.u0), 1, N)
        J = 0.5 * cs.sum2(cs.sum1(E[:, :N] * cs.mtimes(cs.DM(self.Q), E[:, :N])))
        J += 0.5 * cs.bilin(cs.DM(self.Qf), E[:, N], E[:, N])
        J += 0.5 * cs.sum2(cs.sum1(dU * cs.mtimes(cs.DM(self.R), dU)))
        if ns:
            J += self.soft_weights[0] * cs.sum1(S) + 0.5 * self.soft_weights[1] * cs.sumsqr(S)
        Fk = self.F.map(N)(X[:, :N], U)
        g = [X[:, 0] - x_meas, cs.vec(Fk - X[:, 1:])]
        lbg = [np.zeros(n), np.zeros(n * N)]
        ubg = [np.zeros(n), np.zeros(n * N)]
        lbx_X = np.full((N + 1, n), -np.inf)
        ubx_X = np.full((N + 1, n), np.inf)
        if ns:
            for j, i in enumerate(bounded):
                if np.isfinite(self.x_max[i]):
                    g.append(X[i, 1:].T - S[j])
                    lbg.append(np.full(N, -np.inf))
                    ubg.append(np.full(N, self.x_max[i]))
                if np.isfinite(self.x_min[i]):
                    g.append(X[i, 1:].T + S[j])
                    lbg.append(np.full(N, self.x_min[i]))
                    ubg.append(np.full(N, np.inf))
        else:
            lbx_X[1:] = self.x_min
            ubx_X[1:] = self.x_max
        w = cs.vertcat(cs.vec(X), cs.vec(U), S)
        nlp = {"x": w, "f": J, "g": cs.vertcat(*g), "p": P}
        opts = {
            "print_time": False,
            "ipopt": {"print_level": 0, "sb": "yes", "tol": self.tol, "max_iter": 3000},
        }
        self._ipopt = cs.nlpsol("nmpc", "ipopt", nlp, opts)
        self._lbw = np.concatenate([lbx_X.ravel(), np.tile(self.u_min, N), np.zeros(ns)])
        self._ubw = np.concatenate([ubx_X.ravel(), np.tile(self.u_max, N), np.full(ns, np.inf)])
        self._lbg = np.concatenate(lbg)
        self._ubg = np.concatenate(ubg)

    def _solve_ipopt(self, x: np.ndarray, t_start: float) -> np.ndarray:
        t0 = time.perf_counter()
        X, U, stats, obj = self._ipopt_solve(x)
        t_qp = time.perf_counter() - t0
        u = np.clip(U[0], self.u_min, self.u_max)
        total = time.perf_counter() - t_start
        iters = int(stats.get("iter_count", 0))
        self.last = NMPCSolution(
            status="solved", iterations=iters, kkt_residual=math.nan, qp_status=str(stats.get("return_status")),
            qp_iterations=iters, time_linearization_s=0.0, time_condensing_s=0.0, time_qp_s=t_qp,
            time_other_s=total - t_qp, solve_time_s=total, states=X.copy(), inputs=U.copy(), u=u,
            objective=obj,
        )  # fmt: skip
        self._started = True
        return u

    def _ipopt_solve(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, Any], float]:
        """The OCP from ``x`` solved by IPOPT, warm-started from the previous solution shifted.

        Returns:
            ``(X (N + 1, n), U (N, m), IPOPT's stats, objective)``.

        Raises:
            MPCInfeasible: IPOPT did not succeed.
        """
        if self._ipopt is None:
            self._build_ipopt()
        n, m, N = self.n, self.m, self.N
        nX = n * (N + 1)
        if self._ipopt_guess is None:
            guess = np.concatenate(
                [
                    np.tile(x, N + 1),
                    np.tile(np.clip(self.u0, self.u_min, self.u_max), N),
                    np.zeros(self._lbw.size - nX - N * m),
                ]
            )
        else:
            guess = self._ipopt_guess.copy()
            Xg = guess[:nX].reshape(N + 1, n)
            Ug = guess[nX : nX + N * m].reshape(N, m)
            Xg[:-1] = Xg[1:].copy()
            Ug[:-1] = Ug[1:].copy()
            Xg[0] = x
        sol = self._ipopt(
            x0=guess, lbx=self._lbw, ubx=self._ubw, lbg=self._lbg, ubg=self._ubg, p=np.concatenate([x, self._ref])
        )
        stats = self._ipopt.stats()
        w = np.asarray(sol["x"], dtype=float).ravel()
        if not stats.get("success", False) or not np.all(np.isfinite(w)):
            status = str(stats.get("return_status", "failed"))
            self._ipopt_guess = None
            self._started = False
            raise MPCInfeasible(f"NonlinearMPC (ipopt): {status} at x = {np.array2string(x, precision=4)}")
        self._ipopt_guess = w
        X = w[:nX].reshape(N + 1, n)
        U = w[nX : nX + N * m].reshape(N, m)
        return X, U, stats, float(sol["f"])
