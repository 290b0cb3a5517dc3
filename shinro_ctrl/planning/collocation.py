r"""Direct transcription of an optimal control problem, solved with IPOPT through CasADi.

The problem, on ``N`` knots ``t_k = k h``, ``h = T / (N − 1)``:

.. math::

    \min_{T, x_k, u_k} \; w_T T + \sum_j w_j \int_0^T u_j(t)^2 \, dt
    \quad \text{s.t.} \quad \text{defect}_k(x, u, h) = 0,\;
    x_0 = x_\text{start},\; x_{N-1} = x_\text{goal},\;
    x_\min \le x_k \le x_\max,\; u_\min \le u_k \le u_\max,\; T_\min \le T \le T_\max.

Transcriptions (``f`` the plant's continuous dynamics, ``f_k = f(x_k, u_k)``):

* ``hermite_simpson`` (compressed, first-order-hold inputs, as Drake's
  ``DirectCollocation``): ``x_c = (x_k + x_{k+1})/2 + h (f_k − f_{k+1})/8``,
  ``u_c = (u_k + u_{k+1})/2``, defect ``x_{k+1} − x_k − h (f_k + 4 f(x_c, u_c) + f_{k+1})/6``.
  Fourth order.
* ``trapezoid``: defect ``x_{k+1} − x_k − h (f_k + f_{k+1})/2``, linear inputs. Second order.
* ``multiple_shooting``: inputs held over each interval, defect
  ``x_{k+1} − Φ(x_k, u_k, h)`` with ``Φ`` ``substeps`` classical RK4 steps. Fourth order.

The effort integral is exact for the interpolated inputs: ``h (u_k² + u_k u_{k+1} + u_{k+1}²)/3``
per interval for linear inputs, ``h u_k²`` for held ones.

The NLP is built once per optimizer as a CasADi ``nlpsol`` Function on the
plant's SX dynamics (``plant.symbolic()``), with the start, goal, bounds and
duration entering as variable bounds and the cost weights as parameters, so
:meth:`TrajectoryOptimizer.solve` only calls the compiled solver.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import casadi as cs
import numpy as np

from shinro_ctrl._interrupts import solve_interruptibly
from shinro_ctrl.errors import InvalidArgument, PlanningFailed
from shinro_ctrl.planning._capture import _captured
from shinro_ctrl.planning.trajectory import METHODS, Trajectory, check_transcription_size
from shinro_ctrl.validation import as_vector, bound_pair, did_you_mean

__all__ = ["COSTS", "TrajectoryOptimizer"]

COSTS = ("effort", "time")
TIME_REGULARIZATION = 1e-3  # effort weight of the "time" preset: keeps a bang-bang optimum unique
DEFAULT_DURATION = (0.1, 10.0)
# IPOPT stops after which one retry with the adaptive barrier update often succeeds (crude initial guesses
# of swing-ups stall the default monotone update into a local infeasibility now and then).
RETRY_STATUSES = ("Infeasible_Problem_Detected", "Restoration_Failed", "Maximum_Iterations_Exceeded")


class TrajectoryOptimizer:
    """Plan state and input trajectories of a plant by direct transcription (see the module doc).

    Args:
        plant: Any plant (its ``symbolic()`` dynamics and ``dynamics()`` are used).
        knots: Number of knots ``N`` (3 to :data:`~shinro_ctrl.planning.trajectory.MAX_KNOTS`).
        method: ``"hermite_simpson"`` (default), ``"trapezoid"`` or ``"multiple_shooting"``.
        u_min, u_max: Input bounds ``(m,)`` (±inf allowed; default unbounded).
        x_min, x_max: State bounds ``(n,)`` applied at every knot (±inf allowed).
        substeps: RK4 steps per interval for ``multiple_shooting``.
        tol: IPOPT's convergence tolerance; the constraint tolerance is the same.
        max_iter: IPOPT's iteration limit.
        verbose: Let IPOPT print its log (default quiet, its output captured).
        ipopt: Extra IPOPT options (e.g. ``{"mu_strategy": "adaptive"}``), applied last.

    A solve that IPOPT stops as locally infeasible, in a failed restoration or
    at the iteration limit is retried once from the same guess with IPOPT's
    adaptive barrier update (the status then says so; the iterations of both
    attempts are counted).

    Attributes:
        solver: The ``casadi.Function`` returned by ``nlpsol``.
        build_time: Time spent building the NLP [s].
    """

    def __init__(
        self,
        plant: Any,
        *,
        knots: int = 61,
        method: str = "hermite_simpson",
        u_min: Any = None,
        u_max: Any = None,
        x_min: Any = None,
        x_max: Any = None,
        substeps: int = 1,
        tol: float = 1e-8,
        max_iter: int = 1000,
        verbose: bool = False,
        ipopt: Mapping[str, Any] | None = None,
    ):
        if method not in METHODS:
            raise InvalidArgument(f"method: unknown transcription {method!r}{did_you_mean(method, METHODS)}")
        knots, substeps = check_transcription_size(knots, substeps, method)
        self.plant = plant
        self.n, self.m = plant.state_dim, plant.input_dim
        self.knots, self.method, self.substeps = int(knots), method, int(substeps)
        self.state_names = tuple(plant.state_names)
        self.input_names = tuple(plant.input_names)
        self.u_min, self.u_max = bound_pair("u_min", "u_max", u_min, u_max, self.m)
        self.x_min, self.x_max = bound_pair("x_min", "x_max", x_min, x_max, self.n)
        self.verbose = bool(verbose)
        t0 = time.perf_counter()
        self._build(float(tol), int(max_iter), dict(ipopt or {}))
        self.build_time = time.perf_counter() - t0

    # ------------------------------------------------------------------ build
    @property
    def _nu(self) -> int:
        """Number of input columns: one per knot, or one per interval when held."""
        return self.knots - 1 if self.method == "multiple_shooting" else self.knots

    def _build(self, tol: float, max_iter: int, extra: dict[str, Any]) -> None:
        n, m, N, nu = self.n, self.m, self.knots, self._nu
        f = self.plant.symbolic()
        T = cs.SX.sym("T")
        X = cs.SX.sym("X", n, N)
        U = cs.SX.sym("U", m, nu)
        weights = cs.SX.sym("w", 1 + m)  # [w_time, w_effort (m)]
        h = T / (N - 1)
        if self.method == "multiple_shooting":
            xs, us, hs = cs.SX.sym("x", n), cs.SX.sym("u", m), cs.SX.sym("h")
            step = hs / self.substeps
            xk = xs
            for _ in range(self.substeps):
                k1 = f(xk, us)
                k2 = f(xk + step / 2 * k1, us)
                k3 = f(xk + step / 2 * k2, us)
                k4 = f(xk + step * k3, us)
                xk = xk + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            phi = cs.Function("phi", [xs, us, hs], [xk])
            D = X[:, 1:] - phi.map(N - 1)(X[:, :-1], U, cs.repmat(h, 1, N - 1))
            U2 = U * U
            effort = h * cs.sum2(U2)
        else:
            F = f.map(N)(X, U)
            if self.method == "hermite_simpson":
                Xc = 0.5 * (X[:, :-1] + X[:, 1:]) + (h / 8) * (F[:, :-1] - F[:, 1:])
                Uc = 0.5 * (U[:, :-1] + U[:, 1:])
                Fc = f.map(N - 1)(Xc, Uc)
                D = X[:, 1:] - X[:, :-1] - (h / 6) * (F[:, :-1] + 4 * Fc + F[:, 1:])
            else:
                D = X[:, 1:] - X[:, :-1] - (h / 2) * (F[:, :-1] + F[:, 1:])
            Ua, Ub = U[:, :-1], U[:, 1:]
            effort = (h / 3) * cs.sum2(Ua * Ua + Ua * Ub + Ub * Ub)
        J = weights[0] * T + cs.dot(weights[1:], effort)
        w = cs.vertcat(T, cs.vec(X), cs.vec(U))
        g = cs.vec(D)  # column k holds the n defects of interval k
        opts = {
            "print_time": False,
            "ipopt": {
                "print_level": 5 if self.verbose else 0,
                "sb": "yes",
                "tol": tol,
                "constr_viol_tol": tol,
                "max_iter": max_iter,
                "honor_original_bounds": "yes",
                **extra,
            },
        }
        self._nlp = {"x": w, "f": J, "g": g, "p": weights}
        self._opts = opts
        try:
            self.solver = cs.nlpsol("planner", "ipopt", self._nlp, opts)
        except RuntimeError as exc:  # an unknown or ill-typed IPOPT option
            raise InvalidArgument(f"ipopt: {' '.join(str(exc).split())[-300:]}") from None
        self._fallback: cs.Function | None = None
        self._defects = cs.Function("defects", [w], [D])

    # ------------------------------------------------------------------ solve
    def _duration(self, duration: Any) -> tuple[float, float]:
        if duration is None:
            return DEFAULT_DURATION
        if isinstance(duration, int | float | np.floating | np.integer) and not isinstance(duration, bool):
            lo = hi = float(duration)
        else:
            try:
                lo, hi = (float(v) for v in duration)
            except (TypeError, ValueError):
                raise InvalidArgument(
                    f"duration: expected None, a time T or a (T_min, T_max) pair but found {duration!r}"
                ) from None
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise InvalidArgument(f"duration: expected 0 < T_min <= T_max (finite) but found ({lo:g}, {hi:g})")
        return lo, hi

    def _weights(self, cost: Any) -> np.ndarray:
        m = self.m
        if isinstance(cost, str):
            if cost == "effort":
                return np.concatenate([[0.0], np.ones(m)])
            if cost == "time":
                return np.concatenate([[1.0], np.full(m, TIME_REGULARIZATION)])
            raise InvalidArgument(f"cost: unknown preset {cost!r}{did_you_mean(cost, COSTS)}; or a mapping")
        if not isinstance(cost, Mapping):
            raise InvalidArgument(f"cost: expected 'effort', 'time' or {{time = w, effort = w}} but found {cost!r}")
        allowed = ("time", "effort")
        for key in cost:
            if key not in allowed:
                raise InvalidArgument(f"cost: unknown key {key!r}{did_you_mean(str(key), allowed)}")
        wt = float(cost.get("time", 0.0))
        we = cost.get("effort", 0.0)
        we = np.full(m, float(we)) if np.ndim(we) == 0 else as_vector("cost effort", we, m)
        if not math.isfinite(wt) or wt < 0 or np.any(we < 0):
            raise InvalidArgument(f"cost: weights must be finite and >= 0, found time = {wt!r}, effort = {we}")
        if wt == 0 and not np.any(we > 0):
            raise InvalidArgument("cost: every weight is zero; give a positive time or effort weight")
        return np.concatenate([[wt], we])

    def _check_inside(self, name: str, x: np.ndarray) -> None:
        for i in range(self.n):
            if np.isnan(x[i]):
                continue
            if not self.x_min[i] <= x[i] <= self.x_max[i]:
                raise PlanningFailed(
                    f"infeasible plan: {name} {self.state_names[i]} = {x[i]:g} violates the bound "
                    f"x_min/x_max [{self.x_min[i]:g}, {self.x_max[i]:g}]"
                )

    def _unpack(self, wv: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        n, m, N, nu = self.n, self.m, self.knots, self._nu
        T = float(wv[0])
        X = wv[1 : 1 + n * N].reshape(N, n)
        U = wv[1 + n * N :].reshape(nu, m)
        return T, X, U

    def _guess(self, guess: Any, x_start: np.ndarray, x_goal: np.ndarray, lo: float, hi: float) -> np.ndarray:
        N, nu = self.knots, self._nu
        if guess is None:
            T0 = lo if lo == hi else (min(hi, 2.0 * lo) if not math.isfinite(hi) else 0.5 * (lo + hi))
            goal = np.where(np.isnan(x_goal), x_start, x_goal)
            s = np.linspace(0.0, 1.0, N)[:, None]
            X0 = (1 - s) * x_start + s * goal
            U0 = np.zeros((nu, self.m))
            U0[:] = np.clip(0.0, self.u_min, self.u_max)
        elif isinstance(guess, Trajectory):
            T0 = float(np.clip(guess.duration, lo, hi))
            ts = np.linspace(0.0, guess.duration, N)
            X0 = guess.x_at(ts)
            U0 = guess.u_at(ts[:nu])
        elif isinstance(guess, Mapping):
            T0 = float(np.clip(guess.get("T", 0.5 * (lo + hi)), lo, hi))
            X0 = np.asarray(guess["x"], dtype=float).reshape(N, self.n)
            U0 = np.asarray(guess["u"], dtype=float).reshape(nu, self.m)
        else:
            raise InvalidArgument(
                f"initial_guess: expected None, a Trajectory or {{'T', 'x', 'u'}} but found {type(guess).__name__}"
            )
        X0 = np.clip(X0, self.x_min, self.x_max)
        U0 = np.clip(U0, self.u_min, self.u_max)
        return np.concatenate([[T0], X0.ravel(), U0.ravel()])

    def solve(
        self,
        x_start: Any,
        x_goal: Any,
        *,
        duration: Any = None,
        cost: Any = "effort",
        initial_guess: Any = None,
        u_goal: Any = None,
    ) -> Trajectory:
        """Plan from ``x_start`` to ``x_goal``.

        Args:
            x_start: Initial state ``(n,)``.
            x_goal: Final state ``(n,)``; a NaN entry leaves that component
                free (within ``x_min``/``x_max``).
            duration: ``None`` (free in ``[0.1, 10]`` s), a fixed ``T`` [s] or
                a ``(T_min, T_max)`` pair.
            cost: ``"effort"`` (``∫ |u|² dt``), ``"time"`` (``T + 10⁻³ ∫ |u|² dt``)
                or weights ``{"time": w_T, "effort": w or (m,)}`` for
                ``w_T T + Σ_j w_j ∫ u_j² dt``.
            initial_guess: None (states linear from start to goal, inputs 0),
                a :class:`Trajectory` (resampled on the knots) or a mapping
                with ``T``, ``x (N, n)`` and ``u (N, m)`` (``(N − 1, m)`` for
                ``multiple_shooting``).
            u_goal: Optional input ``(m,)`` the last knot must take (the
                equilibrium input at the goal, for a smooth hand-over to a
                regulator); default free.

        Returns:
            The optimal :class:`Trajectory`.

        Raises:
            InvalidArgument: wrong shapes or values.
            PlanningFailed: start or goal outside the state bounds, or IPOPT
                did not converge (its status and the worst constraint named).
        """
        n = self.n
        x_start = as_vector("x_start", x_start, n)
        x_goal = np.asarray(x_goal, dtype=float)
        if x_goal.shape != (n,) or np.any(np.isinf(x_goal)):
            raise InvalidArgument(f"x_goal: expected a ({n},) array (NaN = free) but found {x_goal!r}")
        lo, hi = self._duration(duration)
        weights = self._weights(cost)
        self._check_inside("x_start", x_start)
        self._check_inside("x_goal", x_goal)

        lbx, ubx = self._box(x_start, x_goal, lo, hi, u_goal)
        w0 = self._guess(initial_guess, x_start, x_goal, lo, hi)

        sol, error, stats, status, iters, elapsed, solver, out = self._run_ipopt(w0, lbx, ubx, weights)
        if status == "Invalid_Option":
            raise InvalidArgument(
                f"ipopt: IPOPT rejected an option (status Invalid_Option); check the names and values in ipopt="
                f"{self._opts['ipopt']!r}"
            )
        if solver is not self.solver:
            status += " (after a retry with mu_strategy 'adaptive')"
        if sol is None:
            raise PlanningFailed(f"IPOPT stopped with an evaluation error after {iters} iterations: {error}")
        wv = np.asarray(sol["x"], dtype=float).ravel()
        T, X, U = self._unpack(wv)
        D = np.asarray(self._defects(wv), dtype=float)  # (n, N - 1)
        max_defect = float(np.abs(D).max())
        if not stats.get("success", False) or not np.all(np.isfinite(wv)):
            raise PlanningFailed(self._failure(status, iters, D, T, X, U, lbx, ubx, out.text()))

        return self._trajectory(T, X, U, elapsed, iters, float(sol["f"]), max_defect, status)

    def _trajectory(
        self,
        T: float,
        X: np.ndarray,
        U: np.ndarray,
        elapsed: float,
        iters: int,
        objective: float,
        max_defect: float,
        status: str,
    ) -> Trajectory:
        """The solved :class:`Trajectory`, with ``xdot`` (and the right-hand ``xdot`` of multiple shooting)."""
        N, nu = self.knots, self._nu
        Uk = U if nu == N else np.vstack([U, U[-1:]])
        t = np.linspace(0.0, T, N)
        xdot = self.plant.dynamics(X, Uk)
        xdot_right = self.plant.dynamics(X[1:], U) if self.method == "multiple_shooting" else None
        return Trajectory(
            t=t,
            x=X.copy(),
            u=Uk.copy(),
            xdot=xdot,
            method=self.method,
            solve_time=elapsed,
            iterations=iters,
            objective=objective,
            max_defect=max_defect,
            status=status,
            state_names=self.state_names,
            input_names=self.input_names,
            xdot_right=xdot_right,
        )

    def _box(
        self, x_start: np.ndarray, x_goal: np.ndarray, lo: float, hi: float, u_goal: Any
    ) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``(lbx, ubx)`` of the decision vector: ``T``, the state and input bounds, start, goal, ``u_goal``."""
        n, m, N, nu = self.n, self.m, self.knots, self._nu
        lbx = np.concatenate([[lo], np.tile(self.x_min, N), np.tile(self.u_min, nu)])
        ubx = np.concatenate([[hi], np.tile(self.x_max, N), np.tile(self.u_max, nu)])
        lbx[1 : 1 + n] = ubx[1 : 1 + n] = x_start
        last = slice(1 + n * (N - 1), 1 + n * N)
        fixed = ~np.isnan(x_goal)
        lbx[last] = np.where(fixed, x_goal, lbx[last])
        ubx[last] = np.where(fixed, x_goal, ubx[last])
        if u_goal is not None:
            u_goal = as_vector("u_goal", u_goal, m)
            bad = np.flatnonzero((u_goal < self.u_min) | (u_goal > self.u_max))
            if bad.size:
                j = int(bad[0])
                raise PlanningFailed(
                    f"infeasible plan: u_goal {self.input_names[j]} = {u_goal[j]:g} violates the bound "
                    f"u_min/u_max [{self.u_min[j]:g}, {self.u_max[j]:g}]"
                )
            lbx[len(lbx) - m :] = ubx[len(ubx) - m :] = u_goal
        return lbx, ubx

    def _run_ipopt(self, w0: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, weights: Any) -> tuple:
        """Solve, retrying once with ``mu_strategy`` adaptive on the statuses in ``RETRY_STATUSES``.

        Returns:
            ``(sol or None, evaluation error or None, stats, status, iterations, seconds, solver used,
            captured output)``.
        """
        t0 = time.perf_counter()
        solver = self.solver
        iters = 0
        with _captured(not self.verbose) as out:
            for attempt in range(2):
                try:  # a Ctrl-C inside IPOPT is raised, not returned as the status 'NonIpopt_Exception_Thrown'
                    sol = solve_interruptibly(solver, x0=w0, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0, p=weights)
                except RuntimeError as exc:  # CasADi raises on evaluation errors (NaN in a function)
                    sol, error = None, str(exc)
                else:
                    error = None
                stats = solver.stats()
                status = str(stats.get("return_status", "unknown"))
                iters += int(stats.get("iter_count", 0))
                if attempt == 1 or status not in RETRY_STATUSES or "mu_strategy" in self._opts["ipopt"]:
                    break
                solver = self._adaptive_solver()
        elapsed = time.perf_counter() - t0
        return sol, error, stats, status, iters, elapsed, solver, out

    def _adaptive_solver(self) -> cs.Function:
        """The same NLP with IPOPT's adaptive barrier update (built on first need)."""
        if self._fallback is None:
            opts = {**self._opts, "ipopt": {**self._opts["ipopt"], "mu_strategy": "adaptive"}}
            self._fallback = cs.nlpsol("planner_adaptive", "ipopt", self._nlp, opts)
        return self._fallback

    def _failure(self, status, iters, D, T, X, U, lbx, ubx, log) -> str:
        """The PlanningFailed message: IPOPT's status and the worst constraint at its last iterate."""
        N = self.knots
        # Worst dynamics defect.
        i, k = np.unravel_index(int(np.argmax(np.abs(D))), D.shape)
        h = T / (N - 1)
        worst = (
            f"worst constraint: dynamics defect of {self.state_names[i]} on interval {k} "
            f"(t = {k * h:.3g}..{(k + 1) * h:.3g} s), |defect| = {abs(D[i, k]):.3g}"
        )
        # Bounds the last iterate presses against, the likely cause.
        wv = np.concatenate([[T], X.ravel(), U.ravel()])
        at_bound = (np.isclose(wv, lbx, atol=1e-6) | np.isclose(wv, ubx, atol=1e-6)) & (lbx != ubx)
        pressed = []
        if at_bound[0]:
            pressed.append(f"duration T = {T:.4g} s (bounds [{lbx[0]:g}, {ubx[0]:g}])")
        xb = at_bound[1 : 1 + self.n * N].reshape(N, self.n).sum(axis=0)
        ub = at_bound[1 + self.n * N :].reshape(-1, self.m).sum(axis=0)
        pressed += [f"{self.state_names[j]} bound at {c} knots" for j, c in enumerate(xb) if c]
        pressed += [f"{self.input_names[j]} bound at {c} knots" for j, c in enumerate(ub) if c]
        msg = f"trajectory optimization failed: IPOPT status '{status}' after {iters} iterations; {worst}"
        if pressed:
            msg += "; active bounds: " + ", ".join(pressed)
        tail = [s for s in log.strip().splitlines() if s.strip()][-3:]
        if tail:
            msg += "; solver output: " + " | ".join(s.strip() for s in tail)
        return msg
