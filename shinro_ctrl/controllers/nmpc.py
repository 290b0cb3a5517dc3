r"""Nonlinear MPC: multiple shooting with exact Jacobians, real-time iterations (RTI) or full SQP.

The optimal control problem, over a horizon of ``N`` steps of ``dt``, is

.. math::

    \min_{x, u, s}\; \tfrac12 \sum_{k=0}^{N-1} \big[\lVert x_k - r \rVert_Q^2 + \lVert u_k - \bar u \rVert_R^2\big]
        + \tfrac12 \lVert x_N - r \rVert_{Q_f}^2 + w_1 \mathbf 1^\top s + \tfrac{w_2}{2} \lVert s \rVert^2

subject to ``x_0 = x`` (measured), ``x_{k+1} = F(x_k, u_k)`` (``F`` one RK4 step
of the plant's own dynamics ``plant.symbolic()``, or its semi-implicit Euler
step), ``u_min <= u_k <= u_max`` and ``x_min - s <= x_k <= x_max + s``
(k = 1..N; ``s = 0`` unless ``soft``, then one slack per bounded state
component shared by the stages).

Each real-time iteration (``iterations=1``) is one Gauss-Newton SQP step:

* **prepare** (before the state is known): shift the previous solution one
  stage, evaluate the shooting defects ``d_k = F(x̄_k, ū_k) − x̄_{k+1}`` and
  their exact Jacobians ``A_k = ∂F/∂x``, ``B_k = ∂F/∂u`` for all stages in one
  compiled CasADi call (``Function.map`` over the horizon, evaluated through
  ``Function.buffer`` into preallocated arrays), and condense the QP
  (:class:`~shinro_ctrl.controllers.qp.ltv.CondensedLTV`);
* **feedback** (when ``x`` arrives): one matrix-vector product for the
  initial-state step, one DAQP solve, the full step.

``iterations > 1`` continues with SQP iterations (an ℓ1-merit Armijo line
search, ``x_0 = x`` held) until the KKT residual is below ``tol``. The
Hessian is the Gauss-Newton one, which is the exact Hessian of the cost; the
SQP iterates converge to the same KKT point as ``solver="ipopt"``, which
solves the same OCP with IPOPT through ``casadi.nlpsol`` (the reference).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import casadi as cs
import numpy as np
import scipy.linalg

from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.qp.ltv import CondensedLTV, SparseLTV
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError, NotStabilizable
from shinro_ctrl.validation import as_vector, bound_pair, check_positive

__all__ = ["NMPCSolution", "NonlinearMPC"]

SOLVERS = ("auto", "daqp", "osqp", "ipopt")
INTEGRATORS = ("rk4", "semi_implicit")


@dataclass(frozen=True)
class NMPCSolution:
    """The outcome of one :class:`NonlinearMPC` call.

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


def _weight(name: str, value: Any, size: int) -> np.ndarray:
    M = np.asarray(value, dtype=float)
    if M.ndim == 0 and size == 1:
        M = M.reshape(1, 1)
    elif M.ndim == 1:
        if M.shape != (size,):
            raise InvalidArgument(f"{name}: expected ({size},) or ({size}, {size}) but found {M.shape}")
        M = np.diag(M)
    if M.shape != (size, size):
        raise InvalidArgument(f"{name}: expected ({size},) or ({size}, {size}) but found {M.shape}")
    if not np.all(np.isfinite(M)):
        raise NonFiniteError(f"{name} holds NaN or inf")
    if not np.allclose(M, M.T, rtol=1e-9, atol=1e-12):
        raise InvalidArgument(f"{name} must be symmetric")
    return 0.5 * (M + M.T)


def rk4_step(f: cs.Function, x: Any, u: Any, h: float) -> Any:
    """One classical RK4 step of ``xdot = f(x, u)`` with ``u`` held for ``h``."""
    k1 = f(x, u)
    k2 = f(x + 0.5 * h * k1, u)
    k3 = f(x + 0.5 * h * k2, u)
    k4 = f(x + h * k3, u)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


class NonlinearMPC(Controller):
    r"""Nonlinear MPC by real-time iterations (or SQP, or IPOPT) on the plant's exact dynamics.

    See the module docstring for the OCP and the algorithm. Build it with
    :meth:`from_plant`.

    Args:
        f: Continuous dynamics ``f(x, u) -> xdot`` as a CasADi ``Function``.
        Q: Stage state weight ``(n, n)`` or its diagonal ``(n,)``.
        R: Stage input weight ``(m, m)`` or its diagonal, positive definite.
        horizon: ``N`` >= 1 steps of ``dt``.
        dt: Shooting interval [s].
        x_ref: Target state ``(n,)`` (the default reference ``r``).
        u_ref: Input reference ``ū`` ``(m,)`` (e.g. the hover thrust).
        u_min, u_max: Hard input bounds ``(m,)`` (±inf where none); the
            returned input is clipped to them.
        x_min, x_max: State bounds ``(n,)`` on ``x_1 … x_N``.
        soft: Soft state bounds (one slack per bounded component).
        soft_weight_l1, soft_weight_quad: Slack weights ``w_1``, ``w_2``.
        Qf: Terminal weight: None (``Q``), ``"lqr"`` (the DARE of the model
            linearized at ``(x_ref, u_ref)``), or a matrix ``(n, n)``.
        iterations: SQP iterations per call (1 = real-time iteration).
        tol: KKT residual at which SQP (and IPOPT) stop.
        solver: ``"auto"`` / ``"daqp"`` (condensed QP, DAQP), ``"osqp"``
            (the sparse multiple-shooting QP, OSQP with in-place value updates)
            or ``"ipopt"`` (the OCP to convergence at every call).
        osqp_settings: Overrides of the sparse QP's OSQP settings (``"osqp"`` only).
        integrator: ``"rk4"`` or ``"semi_implicit"`` (needs ``position_indices``).
        position_indices, velocity_indices: For ``"semi_implicit"``.
        init_iterations: SQP iterations allowed on a cold start with
            ``cold_start="sqp"``.
        cold_start: How the first call after construction or :meth:`reset`
            finds its first trajectory: ``"ipopt"`` (the OCP solved to
            convergence by IPOPT; the swing-ups need it: Gauss-Newton SQP
            from ``x`` held over the horizon converges slowly there and to a
            worse local minimum) or ``"sqp"`` (up to ``init_iterations`` SQP
            iterations from ``x`` held). Later calls never use IPOPT.
        hold: Calls per solve: the controller re-plans every ``hold`` calls and
            holds its input in between (``dt = hold · plant.dt``).
        state_names, input_names: For messages.

    Attributes:
        last: :class:`NMPCSolution` of the latest solve (None before).
        x0, u0: The target ``x_ref`` and ``u_ref`` (the scenario's reference
            defaults to ``x0``).
    """

    def __init__(
        self,
        f: cs.Function,
        Q: Any,
        R: Any,
        horizon: int,
        dt: float,
        *,
        x_ref: Any = None,
        u_ref: Any = None,
        u_min: Any = None,
        u_max: Any = None,
        x_min: Any = None,
        x_max: Any = None,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        Qf: str | Any = None,
        iterations: int = 1,
        tol: float = 1e-6,
        solver: str = "auto",
        osqp_settings: Mapping[str, Any] | None = None,
        integrator: str = "rk4",
        position_indices: tuple[int, ...] = (),
        velocity_indices: tuple[int, ...] = (),
        init_iterations: int = 30,
        cold_start: str = "ipopt",
        hold: int = 1,
        state_names: Any = None,
        input_names: Any = None,
    ):
        n, m = int(f.size1_in(0)), int(f.size1_in(1))
        self.n, self.m = n, m
        self.state_dim, self.input_dim = n, m
        for name, value, low in (("horizon", horizon, 1), ("iterations", iterations, 1), ("hold", hold, 1)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise InvalidArgument(f"{name} must be an int >= {low}, got {value!r}")
        if isinstance(init_iterations, bool) or not isinstance(init_iterations, (int, np.integer)):
            raise InvalidArgument(f"init_iterations must be an int >= 1, got {init_iterations!r}")
        if init_iterations < 1:
            raise InvalidArgument(f"init_iterations must be an int >= 1, got {init_iterations!r}")
        self.N = self.horizon = int(horizon)
        self.dt = check_positive("dt", dt)
        self.iterations = int(iterations)
        self.init_iterations = int(init_iterations)
        if cold_start not in ("ipopt", "sqp"):
            raise InvalidArgument(f"cold_start must be 'ipopt' or 'sqp', got {cold_start!r}")
        self.cold_start = cold_start
        self.hold = int(hold)
        self.tol = check_positive("tol", tol)
        if solver not in SOLVERS:
            raise InvalidArgument(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
        self.solver = "daqp" if solver == "auto" else solver
        if integrator not in INTEGRATORS:
            raise InvalidArgument(f"integrator must be one of {', '.join(INTEGRATORS)}, got {integrator!r}")
        self.integrator = integrator
        self.Q = _weight("Q", Q, n)
        self.R = _weight("R", R, m)
        if np.min(np.linalg.eigvalsh(self.R)) <= 0:
            raise InvalidArgument("R must be positive definite")
        if np.min(np.linalg.eigvalsh(self.Q)) < -1e-12:
            raise InvalidArgument("Q must be positive semidefinite")
        self.x0 = np.zeros(n) if x_ref is None else as_vector("x0", x_ref, n)
        self.u0 = np.zeros(m) if u_ref is None else as_vector("u0", u_ref, m)
        self.u_min, self.u_max = bound_pair("u_min", "u_max", u_min, u_max, m)
        self.x_min, self.x_max = bound_pair("x_min", "x_max", x_min, x_max, n)
        self.soft = bool(soft)
        self.soft_weights = (float(soft_weight_l1), float(soft_weight_quad))
        if not (math.isfinite(self.soft_weights[0]) and self.soft_weights[0] >= 0):
            raise InvalidArgument(f"soft_weight_l1 must be >= 0 and finite, got {soft_weight_l1!r}")
        if not (math.isfinite(self.soft_weights[1]) and self.soft_weights[1] > 0):
            raise InvalidArgument(f"soft_weight_quad must be > 0 and finite, got {soft_weight_quad!r}")
        self.state_names = tuple(state_names) if state_names is not None else tuple(f"x[{i}]" for i in range(n))
        self.input_names = tuple(input_names) if input_names is not None else tuple(f"u[{i}]" for i in range(m))

        # ------------------------------------------------- the discrete step F
        xs, us = cs.SX.sym("x", n), cs.SX.sym("u", m)
        if integrator == "rk4":
            x_next = rk4_step(f, xs, us, self.dt)
        else:
            if not position_indices or len(position_indices) != len(velocity_indices):
                raise InvalidArgument("integrator 'semi_implicit' needs the plant's position and velocity indices")
            xd = f(xs, us)
            new = [xs[i] for i in range(n)]
            for q, v in zip(position_indices, velocity_indices, strict=True):
                new[v] = xs[v] + self.dt * xd[v]
                new[q] = xs[q] + self.dt * new[v]
            x_next = cs.vertcat(*new)
        self.F = cs.Function("F", [xs, us], [x_next], ["x", "u"], ["x_next"])
        xn = cs.SX.sym("x_next", n)
        # G_k = [A_k, B_k, d_k] (n, n + m + 1), output transposed so that its column-major storage is G_k row-major
        G = cs.horzcat(cs.jacobian(x_next, xs), cs.jacobian(x_next, us), x_next - xn)
        stage = cs.Function("stage", [xs, us, xn], [cs.densify(G).T])
        N = self.N
        X = cs.MX.sym("X", n, N + 1)
        U = cs.MX.sym("U", m, N)
        #: All stages at once: ``G_kᵀ`` side by side, ``(n + m + 1, N n)`` (stored as ``(N, n, n + m + 1)``).
        self.linearization = cs.Function("lin", [X, U], [stage.map(N)(X[:, :N], U, X[:, 1:])], ["X", "U"], ["G"])

        # ----------------------------------------------------- terminal weight
        if Qf is None:
            self.Qf = self.Q.copy()
        elif isinstance(Qf, str):
            if Qf != "lqr":
                raise InvalidArgument(f"Qf must be None, 'lqr' or an (n, n) matrix, got {Qf!r}")
            self.Qf = self._dare()
        else:
            self.Qf = _weight("Qf", Qf, n)
        self.W = np.stack([self.Q] * (N - 1) + [self.Qf])

        # ------------------------------------------------------ numeric buffers
        self._X = np.zeros((N + 1, n))
        self._U = np.zeros((N, m))
        self._G = np.zeros((N, n, n + m + 1))  # [A_k, B_k, d_k] of every stage
        self._A = self._G[:, :, :n]  # views: A_k (N, n, n), B_k (N, n, m), defects d_k (N, n)
        self._B = self._G[:, :, n : n + m]
        self._D = self._G[:, :, n + m]
        self._buf, self._eval = self.linearization.buffer()
        self._buf.set_arg(0, memoryview(self._X))
        self._buf.set_arg(1, memoryview(self._U))
        self._buf.set_res(0, memoryview(self._G))
        self._e = np.zeros(N * n)
        self._du = np.zeros(N * m)
        self._ref = self.x0.copy()
        self._ipopt: Any = None
        self.qp: Any
        if self.solver == "daqp":
            self.qp = CondensedLTV(
                self._G, self.W, self.R, self.u_min, self.u_max, self.x_min, self.x_max,
                soft=self.soft, soft_weights=self.soft_weights,
            )  # fmt: skip
        elif self.solver == "osqp":
            self.qp = SparseLTV(
                self._G, self.Q, self.W, self.R, self.u_min, self.u_max, self.x_min, self.x_max,
                soft=self.soft, soft_weights=self.soft_weights, osqp_settings=osqp_settings,
            )  # fmt: skip
        else:
            self.qp = None
            self._build_ipopt()
        self.reset()

    # ================================================================ set-up
    def _dare(self) -> np.ndarray:
        xs, us = cs.SX.sym("x", self.n), cs.SX.sym("u", self.m)
        xn = self.F(xs, us)
        jac = cs.Function("F_jac", [xs, us], [cs.jacobian(xn, xs), cs.jacobian(xn, us)])
        A, B = (np.array(M, dtype=float) for M in jac(self.x0, self.u0))
        try:
            P = scipy.linalg.solve_discrete_are(A, B, self.Q, self.R)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise NotStabilizable(f"Qf='lqr': no stabilizing DARE solution at the target ({exc})") from exc
        if not np.all(np.isfinite(P)):
            raise NotStabilizable("Qf='lqr': the DARE solution at the target is not finite")
        return 0.5 * (P + P.T)

    @classmethod
    def from_plant(
        cls,
        plant: Any,
        Q: Any,
        R: Any,
        *,
        horizon: int,
        dt: float | None = None,
        integrator: str = "rk4",
        x0: Any = None,
        u0: Any = None,
        u_min: Any = None,
        u_max: Any = None,
        x_min: Any = None,
        x_max: Any = None,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        Qf: str | Any = None,
        iterations: int = 1,
        tol: float = 1e-6,
        solver: str = "auto",
        osqp_settings: Mapping[str, Any] | None = None,
        init_iterations: int = 30,
        cold_start: str = "ipopt",
    ) -> NonlinearMPC:
        """Build the controller on the plant's own dynamics ``plant.symbolic()``.

        Args:
            plant: Any :class:`~shinro_ctrl.plants.base.Plant`.
            Q, R: Stage weights (matrices or diagonals).
            horizon: ``N`` shooting intervals of ``dt``.
            dt: Shooting interval [s]; default ``plant.dt``. Otherwise it must
                be a whole multiple of ``plant.dt``: the controller is called
                every plant step, re-plans every ``dt / plant.dt`` calls and
                holds its input in between.
            integrator: ``"rk4"`` or ``"semi_implicit"`` (the plant's own
                standalone scheme, for mechanical plants).
            x0: Target state ``(n,)``; default ``plant.equilibrium()``.
            u0: Input reference ``(m,)``; default ``plant.equilibrium()``.
            u_min, u_max, x_min, x_max, soft, soft_weight_l1, soft_weight_quad,
            Qf, iterations, tol, solver, osqp_settings, init_iterations, cold_start: As for :class:`NonlinearMPC`.
        """
        xe, ue = plant.equilibrium()
        x_ref = xe if x0 is None else x0
        u_ref = ue if u0 is None else u0
        step = float(plant.dt)
        if dt is None:
            h, hold = step, 1
        else:
            h = check_positive("dt", dt)
            ratio = h / step
            hold = round(ratio)
            if hold < 1 or abs(ratio - hold) > 1e-9 * max(1.0, ratio):
                raise InvalidArgument(f"dt must be a whole multiple of the plant's dt = {step:g} s, got {h:g}")
        return cls(
            plant.symbolic(),
            Q,
            R,
            horizon,
            h,
            x_ref=x_ref,
            u_ref=u_ref,
            u_min=u_min,
            u_max=u_max,
            x_min=x_min,
            x_max=x_max,
            soft=soft,
            soft_weight_l1=soft_weight_l1,
            soft_weight_quad=soft_weight_quad,
            Qf=Qf,
            iterations=iterations,
            tol=tol,
            solver=solver,
            osqp_settings=osqp_settings,
            integrator=integrator,
            position_indices=tuple(getattr(plant, "position_indices", ())),
            velocity_indices=tuple(getattr(plant, "velocity_indices", ())),
            init_iterations=init_iterations,
            cold_start=cold_start,
            hold=hold,
            state_names=plant.state_names,
            input_names=plant.input_names,
        )

    def reset(self) -> None:
        """Forget the previous solution: the next call starts cold from the measured state."""
        self.last: NMPCSolution | None = None
        self._started = False
        self._prepared = False
        self._count = 0
        self._u_hold = np.zeros(self.m)
        self._mu = 0.0
        self._ipopt_guess: np.ndarray | None = None

    # ============================================================ the RTI step
    def _linearize(self) -> None:
        """Defects and Jacobians of all stages at ``(X̄, Ū)`` (one compiled call)."""
        self._eval()

    def _condense(self) -> None:
        N, n = self.N, self.n
        np.subtract(self._X[1:].reshape(N, n), self._ref, out=self._e.reshape(N, n))
        np.subtract(self._U, self.u0, out=self._du.reshape(N, self.m))
        with np.errstate(over="ignore", invalid="ignore"):  # a diverged prediction is reported by feedback
            self.qp.build(self._e, self._du)
        self.qp.set_bounds(self._U, self._X[1:])

    def _shift(self) -> None:
        X, U = self._X, self._U
        X[:-1] = X[1:]
        U[:-1] = U[1:]

    def prepare(self) -> None:
        """Preparation phase: shift the previous solution and linearize/condense for the next state.

        Called by :meth:`__call__` after each feedback; call it yourself to
        overlap it with the time before the next measurement.
        """
        t0 = time.perf_counter()
        if self.solver == "ipopt" or not self._started:
            return
        if not self._prepared:
            self._shift()
        t1 = time.perf_counter()
        self._linearize()
        t2 = time.perf_counter()
        self._condense()
        t3 = time.perf_counter()
        self._prepared = True
        self._t_prep = (t2 - t1, t3 - t2, t1 - t0)

    def _check_x(self, x: Any, ref: Any) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n,):
            raise InvalidArgument(f"NonlinearMPC: expected x ({self.n},) but found {x.shape}")
        if not np.all(np.isfinite(x)):
            raise NonFiniteError(f"NonlinearMPC: the state holds NaN or inf: {x}")
        if ref is not None:
            r = np.asarray(ref, dtype=float)
            if r.ndim == 2:
                r = r[0]
            if r.shape != (self.n,):
                raise InvalidArgument(f"NonlinearMPC: expected ref ({self.n},) but found {r.shape}")
            if not np.all(np.isfinite(r)):
                raise NonFiniteError("NonlinearMPC: the reference holds NaN or inf")
            if not np.array_equal(r, self._ref):
                self._ref[:] = r
                if self._prepared:  # re-condense for the new reference
                    self._condense()
        return x

    def __call__(self, x: Any, ref: Any = None) -> np.ndarray:
        """Feedback then preparation for the next call; the input ``u (m,)`` clipped to its bounds.

        Raises:
            MPCInfeasible: the QP (or IPOPT) failed; the message names the
                status and the state.
            NonFiniteError: NaN in the state or the reference.
        """
        if self.hold > 1:
            k, self._count = self._count, self._count + 1
            if k % self.hold:
                return self._u_hold.copy()
        u = self.feedback(x, ref)
        if self.solver != "ipopt":
            t0 = time.perf_counter()
            self.prepare()
            last = self.last
            lin, cond, other = self._t_prep
            self.last = _replace_times(last, lin, cond, other, time.perf_counter() - t0)
        self._u_hold[:] = u
        return u

    def feedback(self, x: Any, ref: Any = None) -> np.ndarray:
        """Feedback phase: solve the prepared QP for the measured ``x (n,)`` and take the step.

        With ``iterations > 1`` SQP iterations follow until the KKT residual is
        below ``tol``. The first call after :meth:`reset` starts cold (see
        ``cold_start``).

        Returns:
            The input ``u (m,)`` clipped to ``[u_min, u_max]``.
        """
        t_start = time.perf_counter()
        x = self._check_x(x, ref)
        if self.solver == "ipopt":
            return self._solve_ipopt(x, t_start)
        t_lin = t_cond = t_qp = 0.0
        fresh = not self._started
        if fresh:
            self._prepared = False
            if self.cold_start == "ipopt":
                t0 = time.perf_counter()
                self._ipopt_guess = None
                X, U, _, _ = self._ipopt_solve(x)
                t_qp += time.perf_counter() - t0
                self._X[:] = X
                self._U[:] = U
                budget, cold = self.iterations, False
            else:
                self._X[:] = x
                self._U[:] = np.clip(self.u0, self.u_min, self.u_max)
                budget, cold = self.init_iterations, True
            self._started = True
        else:
            budget, cold = self.iterations, False
        if not self._prepared:
            if not fresh:
                self._shift()
            t0 = time.perf_counter()
            self._linearize()
            t1 = time.perf_counter()
            self._condense()
            t_lin, t_cond = t1 - t0, time.perf_counter() - t1
        self._prepared = False
        dx0 = x - self._X[0]
        status = "rti"
        kkt = math.inf
        it = 0
        qp_status = ""
        qp_it = 0
        while True:
            t0 = time.perf_counter()
            z, ok, qp_status, qp_it = self.qp.solve(dx0)
            t_qp += time.perf_counter() - t0
            it += 1
            if not ok:
                self._fail(x, qp_status, t_start)
            kkt = max(self.qp.kkt(z), float(np.max(np.abs(self._D))), float(np.max(np.abs(dx0))))
            if it > 1 and kkt < self.tol:
                status = "solved"
                break
            self._step(x, z, dx0, line_search=it > 1 or cold)
            if it >= budget:
                break
            dx0 = np.zeros(self.n)
            t0 = time.perf_counter()
            self._linearize()
            t1 = time.perf_counter()
            self._condense()
            t_lin += t1 - t0
            t_cond += time.perf_counter() - t1
        u = np.clip(self._U[0], self.u_min, self.u_max)
        total = time.perf_counter() - t_start
        self.last = NMPCSolution(
            status=status,
            iterations=it,
            kkt_residual=kkt,
            qp_status=qp_status,
            qp_iterations=qp_it,
            time_linearization_s=t_lin,
            time_condensing_s=t_cond,
            time_qp_s=t_qp,
            time_other_s=total - t_lin - t_cond - t_qp,
            solve_time_s=total,
            states=self._X.copy(),
            inputs=self._U.copy(),
            u=u,
            objective=self.objective(self._X, self._U),
        )
        return u

    def _step(self, x: np.ndarray, z: np.ndarray, dx0: np.ndarray, *, line_search: bool) -> None:
        N, m = self.N, self.m
        dU, dX = self.qp.step(z, dx0)
        if line_search:
            alpha = self._line_search(dX, dU.reshape(N, m), z)
        else:
            alpha = 1.0
        self._X[0] = x
        self._X[1:] += alpha * dX
        self._U += alpha * dU.reshape(N, m)

    # ============================================================= SQP merit
    def objective(self, X: np.ndarray, U: np.ndarray) -> float:
        """The OCP cost of a trajectory ``X (N + 1, n)``, ``U (N, m)`` (slack terms included)."""
        E = X - self._ref
        dU = U - self.u0
        J = 0.5 * float(np.einsum("ki,ij,kj->", E[:-1], self.Q, E[:-1]))
        J += 0.5 * float(E[-1] @ self.Qf @ E[-1])
        J += 0.5 * float(np.einsum("ki,ij,kj->", dU, self.R, dU))
        if self.soft:
            s = np.maximum(np.max(X[1:] - self.x_max, axis=0), np.max(self.x_min - X[1:], axis=0))
            s = np.maximum(s[np.isfinite(s)], 0.0)
            J += self.soft_weights[0] * float(s.sum()) + 0.5 * self.soft_weights[1] * float(s @ s)
        return J

    def _multiplier_bound(self, dX: np.ndarray) -> float:
        """``‖λ‖_∞`` of the dynamics multipliers of the QP solution (backward recursion)."""
        N, n = self.N, self.n
        qp = self.qp
        if hasattr(qp, "dynamics_multipliers"):  # the sparse QP has them
            return float(np.max(np.abs(qp.dynamics_multipliers())))
        nu_rows = qp.state_bound_multipliers()
        Xp = self._X[1:] + dX - self._ref
        lam_next = np.zeros(n)
        big = 0.0
        for k in range(N - 1, -1, -1):
            lam_k = self.W[k] @ Xp[k] + nu_rows[k]
            if k + 1 < N:
                lam_k += lam_next @ self._A[k + 1]
            big = max(big, float(np.max(np.abs(lam_k))))
            lam_next = lam_k
        return big

    def _line_search(self, dX: np.ndarray, dU: np.ndarray, z: np.ndarray) -> float:
        self._mu = max(self._mu, 1.5 * self._multiplier_bound(dX) + 1e-6)
        mu = self._mu
        X0, U0 = self._X.copy(), self._U.copy()
        defect0 = float(np.abs(self._D).sum())
        phi0 = self.objective(X0, U0) + mu * defect0
        E = X0 - self._ref
        grad = float(np.einsum("ki,ij,kj->", E[1:-1], self.Q, dX[:-1])) + float(E[-1] @ self.Qf @ dX[-1])
        grad += float(np.einsum("ki,ij,kj->", U0 - self.u0, self.R, dU))
        slope = grad - mu * defect0
        alpha = 1.0
        for _ in range(30):
            self._X[1:] = X0[1:] + alpha * dX
            self._U[:] = U0 + alpha * dU
            self._linearize()
            phi = self.objective(self._X, self._U) + mu * float(np.abs(self._D).sum())
            # the last term absorbs rounding of phi near convergence (else tiny steps stall the iteration)
            if phi <= phi0 + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * max(1.0, abs(phi0)):
                break
            alpha *= 0.5
        self._X[:] = X0
        self._U[:] = U0
        return alpha

    def _fail(self, x: np.ndarray, status: str, t_start: float) -> None:
        message = f"NonlinearMPC: the QP failed ({status}) at x = {np.array2string(x, precision=4)}"
        reason = self.qp.explain()
        if reason:
            message += f"; {reason}"
        self.last = NMPCSolution(
            status=status, iterations=0, kkt_residual=math.nan, qp_status=status, qp_iterations=0,
            time_linearization_s=0.0, time_condensing_s=0.0, time_qp_s=0.0, time_other_s=0.0,
            solve_time_s=time.perf_counter() - t_start, states=self._X.copy(), inputs=self._U.copy(),
            u=np.full(self.m, np.nan), objective=math.nan, message=message,
        )  # fmt: skip
        self._started = False  # the next call starts cold
        raise MPCInfeasible(message)

    # ================================================================= IPOPT
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

    def describe(self) -> str:
        """One paragraph: horizon, integrator, solver, bounds."""
        return (
            f"NonlinearMPC: N = {self.N} steps of {self.dt:g} s ({self.integrator}), solver {self.solver}, "
            f"{'RTI' if self.iterations == 1 else f'SQP <= {self.iterations} iterations'}, "
            f"u in [{np.array2string(self.u_min)}, {np.array2string(self.u_max)}]"
        )

    def __repr__(self) -> str:
        return f"NonlinearMPC(n={self.n}, m={self.m}, N={self.N}, dt={self.dt:g}, solver={self.solver!r})"


def _replace_times(last: NMPCSolution | None, lin: float, cond: float, other: float, total: float) -> Any:
    """Add the preparation phase run after the feedback to ``last``'s time split."""
    if last is None:
        return None
    return replace(
        last,
        time_linearization_s=last.time_linearization_s + lin,
        time_condensing_s=last.time_condensing_s + cond,
        time_other_s=last.time_other_s + (total - lin - cond),
        solve_time_s=last.solve_time_s + total,
    )
