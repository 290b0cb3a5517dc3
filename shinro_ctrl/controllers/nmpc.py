r"""Nonlinear MPC: multiple shooting with exact Jacobians, real-time iterations (RTI) or full SQP.

The optimal control problem, over a horizon of ``N`` steps of ``dt``, is

.. math::

    \min_{x, u, s}\; \tfrac12 \sum_{k=0}^{N-1} \big[\lVert x_k - r \rVert_Q^2 + \lVert u_k - \bar u \rVert_R^2\big]
        + \tfrac12 \lVert x_N - r \rVert_{Q_f}^2 + w_1 \mathbf 1^\top s + \tfrac{w_2}{2} \lVert s \rVert^2

subject to ``x_0 = x`` (measured), ``x_{k+1} = F(x_k, u_k)`` (``F`` one RK4 step
of the plant's own dynamics ``plant.symbolic()``, or its semi-implicit Euler
step), ``u_min <= u_k <= u_max`` and ``x_min - s <= x_k <= x_max + s``
(k = 1..N; ``s = 0`` unless ``soft``, then one slack ``s ≥ 0`` per
state-bound row, i.e. per stage and bounded component, so that no state bound
can make the problem infeasible).

The controller keeps only the policy (input checks, the reference, ``hold``,
the record of the last call); the OCP (:class:`~._nmpc_ocp.NMPCProblem`, with
the options :class:`NMPCOptions`) is solved by one strategy object it holds:
:class:`~._nmpc_rti.RealTimeIteration` (``solver="daqp"``/``"osqp"``) or
:class:`~._nmpc_ipopt.IpoptSolver` (``solver="ipopt"``).

Each real-time iteration (``iterations=1``) is one Gauss-Newton SQP step:

* **prepare** (before the state is known): shift the previous solution one
  stage, evaluate the shooting defects ``d_k = F(x̄_k, ū_k) − x̄_{k+1}`` and
  their exact Jacobians ``A_k = ∂F/∂x``, ``B_k = ∂F/∂u`` for all stages in one
  compiled CasADi call (``Function.map`` over the horizon, evaluated through
  ``Function.buffer`` into preallocated arrays), and condense the QP
  (:class:`~shinro_ctrl.controllers.qp.ltv.CondensedLTV`);
* **feedback** (when ``x`` arrives): one matrix-vector product for the
  initial-state step, one DAQP solve, the full step.

Large condensed QPs without state bounds (the arm, the quadrotor) take the
Riccati step first: prepare runs a compiled backward Riccati recursion
instead of the condensing, feedback rolls out its policy from ``Δx_0``, and
when that unconstrained minimizer meets every input bound it is the QP's
solution; only otherwise is the QP solved by DAQP, around that step in the policy's prestabilized
variables (block-diagonal Hessian; :class:`~shinro_ctrl.controllers.qp.prestabilized.PrestabilizedLTV`,
:func:`~._nmpc_ocp.riccati_functions`, ``RealTimeIteration._riccati_step``).

On a floating base (``plant.tangent_dim < plant.state_dim``: unit quaternions in the state) the
prediction is the plant's own manifold step and the QP works in tangent deviations
(:class:`~._nmpc_ocp.StateManifold`): ``A_k = D(F̄_k) F_x E(x̄_k)``, ``B_k = D(F̄_k) F_u``, the gaps
``d_k = difference(F̄_k, x̄_{k+1})``, the cost on ``difference(x_k, r)`` (``Q`` of ``tangent_dim``) and
the step ``x̄_k ← retract(x̄_k, Δx_k)``; the IPOPT cold start keeps the quaternions as variables (the
shooting constraints keep them unit) with the chordal attitude error ``D(r)(x − r)`` as its cost.

``iterations > 1`` continues with SQP iterations (an ℓ1-merit Armijo line
search, ``x_0 = x`` held) until the KKT residual is below ``tol``. The
Hessian is the Gauss-Newton one, which is the exact Hessian of the cost; the
SQP iterates converge to the same KKT point as ``solver="ipopt"``, which
solves the same OCP with IPOPT through ``casadi.nlpsol`` (the reference).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.controllers._nmpc_ipopt import IpoptSolver
from shinro_ctrl.controllers._nmpc_ocp import (
    PLANT_GIVEN,
    NMPCOptions,
    NMPCStrategy,
    StateManifold,
    build_ocp,
    rk4_step,
)
from shinro_ctrl.controllers._nmpc_rti import RealTimeIteration
from shinro_ctrl.controllers.base import Controller, default_input_bounds, default_state_bounds
from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError
from shinro_ctrl.multibody import configuration
from shinro_ctrl.types import Weight
from shinro_ctrl.validation import check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.plants.base import Plant

__all__ = ["NMPCOptions", "NMPCSolution", "NonlinearMPC", "rk4_step"]


class NonlinearMPC(Controller):
    r"""Nonlinear MPC by real-time iterations (or SQP, or IPOPT) on the plant's exact dynamics.

    See the module docstring for the OCP and the algorithm. Build it with
    :meth:`from_plant`.

    Threads: one object serves one caller at a time (it carries the previous
    trajectory from call to call). A call that enters while another thread is
    inside a call raises :class:`~shinro_ctrl.errors.ConcurrentUse`; use one
    controller per thread.

    Args:
        f: Continuous dynamics ``f(x, u) -> xdot`` as a CasADi ``Function``.
        Q: Stage state weight ``(n, n)`` or its diagonal ``(n,)``.
        R: Stage input weight ``(m, m)`` or its diagonal, positive definite.
        horizon: ``N`` >= 1 steps of ``dt``.
        dt: Shooting interval [s].
        options: The :class:`NMPCOptions` (default: all defaults).
        manifold: A floating base's :class:`~._nmpc_ocp.StateManifold` (``from_plant`` makes it): the
            prediction is then its manifold step and ``Q`` is ``(tangent_dim, tangent_dim)``.
        **kwargs: Fields of :class:`NMPCOptions` overriding ``options``
            (``NonlinearMPC(f, Q, R, 20, 0.05, u_max=3.0)``).

    Attributes:
        options: The resolved :class:`NMPCOptions`.
        strategy: The strategy object that solves the OCP.
        last: :class:`NMPCSolution` of the latest solve (None before).
        x0, u0: The target state and the input reference (the scenario's
            reference defaults to ``x0``).
    """

    stateful = True

    def __init__(
        self,
        f: cs.Function,
        Q: Weight,
        R: Weight,
        horizon: int,
        dt: float,
        *,
        options: NMPCOptions | None = None,
        manifold: StateManifold | None = None,
        **kwargs: object,
    ):
        opts = options if options is not None else NMPCOptions()
        if kwargs:
            opts = dataclasses.replace(opts, **kwargs)  # TypeError names a misspelt option
        self.ocp = ocp = build_ocp(f, Q, R, horizon, dt, opts, manifold)
        o = self.options = ocp.options
        self.n, self.m = self.state_dim, self.input_dim = ocp.n, ocp.m
        self.N = self.horizon = ocp.N
        self.dt, self.hold, self.solver = ocp.dt, o.hold, o.solver
        self.Q, self.R, self.Qf = ocp.Q, ocp.R, ocp.Qf
        self.x0, self.u0 = ocp.x0, ocp.u0
        self.u_min, self.u_max, self.x_min, self.x_max = o.u_min, o.u_max, o.x_min, o.x_max
        self.state_names, self.input_names = o.state_names, o.input_names
        self.strategy: NMPCStrategy = IpoptSolver(ocp) if o.solver == "ipopt" else RealTimeIteration(ocp)
        self._ref = ocp.x0.copy()
        self._busy = CallGuard("NonlinearMPC")
        self.reset()

    @classmethod
    def option_keys(cls) -> tuple[str, ...]:
        """The keys a scenario's ``[controller]`` table may hold: ``from_plant``'s and the options'."""
        own = ("Q", "R", "horizon", "dt")
        return own + tuple(f.name for f in dataclasses.fields(NMPCOptions) if f.name not in PLANT_GIVEN)

    @classmethod
    def option_annotations(cls) -> dict[str, object]:
        """``from_plant``'s annotations and those of the :class:`NMPCOptions` fields it forwards."""
        return {**{f.name: f.type for f in dataclasses.fields(NMPCOptions)}, **super().option_annotations()}

    @classmethod
    def from_plant(
        cls,
        plant: Plant,
        Q: Weight,
        R: Weight,
        *,
        horizon: int,
        dt: float | None = None,
        **options: object,
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
            **options: Fields of :class:`NMPCOptions`; ``x0`` and ``u0``
                default to ``plant.equilibrium()``; ``hold``, the position and
                velocity indices and the names come from the plant.

        Raises:
            TypeError: an unknown option, or one the plant gives.
        """
        given = [k for k in options if k in PLANT_GIVEN]
        if given:
            raise TypeError(f"from_plant() sets {', '.join(given)} from the plant; do not pass them")
        xe, ue = plant.equilibrium()
        options.setdefault("x0", None)
        options.setdefault("u0", None)
        if options["x0"] is None:
            options["x0"] = xe
        if options["u0"] is None:
            options["u0"] = ue
        options["u_min"], options["u_max"] = default_input_bounds(plant, options.get("u_min"), options.get("u_max"))
        options["x_min"], options["x_max"] = default_state_bounds(plant, options.get("x_min"), options.get("x_max"))
        step = float(plant.dt)
        if dt is None:
            h, hold = step, 1
        else:
            h = check_positive("dt", dt)
            ratio = h / step
            hold = round(ratio)
            if hold < 1 or abs(ratio - hold) > 1e-9 * max(1.0, ratio):
                raise InvalidArgument(f"dt must be a whole multiple of the plant's dt = {step:g} s, got {h:g}")
        manifold = None
        if plant.tangent_dim != plant.state_dim:  # a floating base: the plant's manifold step, held `hold` steps
            manifold = StateManifold(
                nt=plant.tangent_dim,
                step=_held_step(plant, hold),
                difference=plant.difference,
                retract=plant.retract,
                tangent_maps=plant.tangent_maps,
                rotations=tuple(d for _, d in configuration.quaternion_slices(plant.tree)),  # type: ignore[attr-defined]
            )
        return cls(
            plant.symbolic(),
            Q,
            R,
            horizon,
            h,
            hold=hold,
            position_indices=tuple(getattr(plant, "position_indices", ())),
            velocity_indices=tuple(getattr(plant, "velocity_indices", ())),
            state_names=plant.state_names,
            input_names=plant.input_names,
            manifold=manifold,
            **options,
        )

    def reset(self) -> None:
        """Forget the previous solution: the next call starts cold from the measured state."""
        self.last: NMPCSolution | None = None
        self._count = 0
        self._u_hold = np.zeros(self.m)
        self.strategy.reset()

    def _check(self, x: ArrayLike, ref: ArrayLike | None) -> np.ndarray:
        """``x`` as a checked ``(n,)`` array; a given ``ref`` (its first row for a preview) becomes the reference."""
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
            self._ref[:] = r
        return x

    def _enter(self) -> None:
        if not self._busy.acquire(False):
            raise self._busy.refused()

    def feedback(self, x: ArrayLike, ref: ArrayLike | None = None) -> np.ndarray:
        """Feedback phase: solve the OCP for the measured ``x (n,)`` (prepared by :meth:`prepare`).

        ``ref`` (a state ``(n,)``, or preview rows whose first is used) replaces
        the reference until the next one is given (initially ``x0``).

        Returns:
            The input ``u (m,)`` clipped to ``[u_min, u_max]``.

        Raises:
            MPCInfeasible: the QP (or IPOPT) failed; the message names the
                status and the state (:attr:`last` holds the failed record).
            NonFiniteError: NaN in the state or the reference.
        """
        self._enter()
        try:
            return self._feedback(x, ref)
        finally:
            self._busy.release()

    def _feedback(self, x: ArrayLike, ref: ArrayLike | None) -> np.ndarray:
        x = self._check(x, ref)
        sol = self.last = self.strategy.solve(x, self._ref)
        if sol.message:
            raise MPCInfeasible(sol.message)
        return sol.u

    def prepare(self) -> None:
        """Preparation phase: shift the previous solution and linearize/condense for the next state.

        Called by :meth:`__call__` after each feedback; call it yourself (then
        :meth:`feedback`) to overlap it with the time before the next measurement.
        """
        self._enter()
        try:
            self.strategy.prepare()
        finally:
            self._busy.release()

    def __call__(self, x: ArrayLike, ref: ArrayLike | None = None) -> np.ndarray:
        """Feedback then preparation for the next call; the input ``u (m,)`` clipped to its bounds.

        Raises:
            MPCInfeasible: the QP (or IPOPT) failed; the message names the
                status and the state.
            NonFiniteError: NaN in the state or the reference.
            ConcurrentUse: another thread is inside a call of this object.
        """
        self._enter()
        try:
            if self.hold > 1:
                k, self._count = self._count, self._count + 1
                if k % self.hold:
                    return self._u_hold.copy()
            u = self._feedback(x, ref)
            t0 = time.perf_counter()
            times = self.strategy.prepare()
            if times is not None and self.last is not None:
                self.last = _add_preparation(self.last, *times, time.perf_counter() - t0)
            self._u_hold[:] = u
            return u
        finally:
            self._busy.release()

    def objective(self, X: np.ndarray, U: np.ndarray) -> float:
        """The OCP cost of a trajectory ``X (N + 1, n)``, ``U (N, m)`` towards the current reference."""
        return self.ocp.objective(np.asarray(X, dtype=float), np.asarray(U, dtype=float), self._ref)

    def describe(self) -> str:
        """One paragraph: horizon, integrator, solver, bounds."""
        o = self.options
        return (
            f"NonlinearMPC: N = {self.N} steps of {self.dt:g} s ({o.integrator}), solver {self.solver}, "
            f"{'RTI' if o.iterations == 1 else f'SQP <= {o.iterations} iterations'}, "
            f"u in [{np.array2string(self.u_min)}, {np.array2string(self.u_max)}]"
        )

    def __repr__(self) -> str:
        return f"NonlinearMPC(n={self.n}, m={self.m}, N={self.N}, dt={self.dt:g}, solver={self.solver!r})"


def _held_step(plant: Plant, hold: int) -> cs.Function:
    """``F(x, u)``: ``hold`` of the plant's own steps ``plant.symbolic_step()`` with ``u`` held."""
    step = plant.symbolic_step()
    pv = cs.DM([plant.dynamics_params()[k] for k in plant.param_names])
    x, u = cs.SX.sym("x", plant.state_dim), cs.SX.sym("u", plant.input_dim)
    xn = x
    for _ in range(hold):
        xn = step(xn, u, pv)
    return cs.Function("F", [x, u], [xn], ["x", "u"], ["x_next"])


def _add_preparation(last: NMPCSolution, lin: float, cond: float, other: float, total: float) -> NMPCSolution:
    """Add the preparation phase run after the feedback to ``last``'s time split."""
    return replace(
        last,
        time_linearization_s=last.time_linearization_s + lin,
        time_condensing_s=last.time_condensing_s + cond,
        time_other_s=last.time_other_s + (total - lin - cond),
        solve_time_s=last.solve_time_s + total,
    )
