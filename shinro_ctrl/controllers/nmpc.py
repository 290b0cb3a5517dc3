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
from dataclasses import replace
from typing import Any

import casadi as cs
import numpy as np

from shinro_ctrl.controllers._nmpc_ipopt import NMPCIpopt
from shinro_ctrl.controllers._nmpc_rti import NMPCRealTime
from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.lqr import riccati_solution
from shinro_ctrl.controllers.qp.ltv import CondensedLTV, SparseLTV
from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import InvalidArgument, NonFiniteError
from shinro_ctrl.validation import as_vector, bound_pair, check_positive, weight_matrix

__all__ = ["NMPCSolution", "NonlinearMPC"]

SOLVERS = ("auto", "daqp", "osqp", "ipopt")
INTEGRATORS = ("rk4", "semi_implicit")


def rk4_step(f: cs.Function, x: Any, u: Any, h: float) -> Any:
    """One classical RK4 step of ``xdot = f(x, u)`` with ``u`` held for ``h``."""
    k1 = f(x, u)
    k2 = f(x + 0.5 * h * k1, u)
    k3 = f(x + 0.5 * h * k2, u)
    k4 = f(x + h * k3, u)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


class NonlinearMPC(NMPCRealTime, NMPCIpopt, Controller):
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
        self._set_options(horizon, dt, iterations, init_iterations, cold_start, hold, tol, solver, integrator)
        self._set_weights(Q, R, x_ref, u_ref)
        self._set_bounds(u_min, u_max, x_min, x_max, soft, soft_weight_l1, soft_weight_quad, state_names, input_names)
        self._build_step(f, integrator, position_indices, velocity_indices)
        self._set_terminal(Qf)
        self._build_qp(osqp_settings)
        self.reset()

    # ================================================================ set-up
    def _set_options(
        self, horizon: int, dt: float, iterations: int, init_iterations: int, cold_start: str, hold: int,
        tol: float, solver: str, integrator: str,
    ) -> None:  # fmt: skip
        """Validate and keep the scalar options."""
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

    def _set_weights(self, Q: Any, R: Any, x_ref: Any, u_ref: Any) -> None:
        """Validate and keep the weights and the references."""
        n, m = self.n, self.m
        self.Q = weight_matrix("Q", Q, n)
        self.R = weight_matrix("R", R, m)
        if np.min(np.linalg.eigvalsh(self.R)) <= 0:
            raise InvalidArgument("R must be positive definite")
        if np.min(np.linalg.eigvalsh(self.Q)) < -1e-12:
            raise InvalidArgument("Q must be positive semidefinite")
        self.x0 = np.zeros(n) if x_ref is None else as_vector("x0", x_ref, n)
        self.u0 = np.zeros(m) if u_ref is None else as_vector("u0", u_ref, m)

    def _set_bounds(
        self, u_min: Any, u_max: Any, x_min: Any, x_max: Any, soft: bool, soft_weight_l1: float,
        soft_weight_quad: float, state_names: Any, input_names: Any,
    ) -> None:  # fmt: skip
        """Validate and keep the bounds, the slack weights and the names."""
        n, m = self.n, self.m
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

    def _build_step(self, f: cs.Function, integrator: str, position_indices: Any, velocity_indices: Any) -> None:
        """The discrete step ``F`` and the compiled linearization of all stages."""
        n, m = self.n, self.m
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

    def _set_terminal(self, Qf: str | Any) -> None:
        """The terminal weight ``Q_f`` and the stacked weights ``W``."""
        n, N = self.n, self.N
        if Qf is None:
            self.Qf = self.Q.copy()
        elif isinstance(Qf, str):
            if Qf != "lqr":
                raise InvalidArgument(f"Qf must be None, 'lqr' or an (n, n) matrix, got {Qf!r}")
            self.Qf = self._dare()
        else:
            self.Qf = weight_matrix("Qf", Qf, n)
        self.W = np.stack([self.Q] * (N - 1) + [self.Qf])

    def _build_qp(self, osqp_settings: Mapping[str, Any] | None) -> None:
        """The numeric buffers the compiled linearization writes into, and the QP (or IPOPT)."""
        n, m, N = self.n, self.m, self.N
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

    def _dare(self) -> np.ndarray:
        xs, us = cs.SX.sym("x", self.n), cs.SX.sym("u", self.m)
        xn = self.F(xs, us)
        jac = cs.Function("F_jac", [xs, us], [cs.jacobian(xn, xs), cs.jacobian(xn, us)])
        A, B = (np.array(M, dtype=float) for M in jac(self.x0, self.u0))
        return riccati_solution(A, B, self.Q, self.R, what="Qf='lqr' at the target")

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
