r"""Linear model-predictive control with a sparse QP solved by OSQP.

The controller works in deviation variables around an operating point
``(x0, u0)`` of a discrete linear model

.. math::

    x_{k+1} - x_0 = A (x_k - x_0) + B (u_k - u_0) + d,

where ``d`` is zero at an equilibrium. Writing ``\delta x_k = x_k - x_0``,
``\delta u_k = u_k - u_0`` and ``\rho_k = r_k - x_0``, ``\nu = u_{ref} - u_0``,
each call solves

.. math::

    \min_{\delta x, \delta u, s}\;
      \tfrac12 \sum_{k=0}^{N-1} \big[(\delta x_k - \rho_k)^\top Q (\delta x_k - \rho_k)
        + (\delta u_k - \nu)^\top R (\delta u_k - \nu)\big]
      + \tfrac12 (\delta x_N - \rho_N)^\top Q_f (\delta x_N - \rho_N)
      + \sum_{k=1}^{N} \big(w_1 \mathbf 1^\top s_k + \tfrac{w_2}{2} \lVert s_k \rVert^2\big)

subject to

.. math::

    \delta x_0 &= x - x_0                                   &&\text{(initial state)}\\
    \delta x_{k+1} &= A \delta x_k + B \delta u_k + d,\; k = 0..N-1  &&\text{(dynamics)}\\
    u_{min} - u_0 &\le \delta u_k \le u_{max} - u_0,\; k = 0..N-1    &&\text{(input bounds)}\\
    -\Delta &\le \delta u_k - \delta u_{k-1} \le \Delta,\; \delta u_{-1} = u_{prev} - u_0
                                                            &&\text{(rate bounds)}\\
    x_{min} - x_0 - s_k &\le \delta x_k \le x_{max} - x_0 + s_k,\; k = 1..N  &&\text{(state bounds)}\\
    s_k &\ge 0                                              &&\text{(slack bounds)}

The slacks ``s_k`` exist only with ``soft=True`` (otherwise they are fixed at
zero and the state bounds are hard). The decision vector is
``z = [δx_0 … δx_N, δu_0 … δu_{N-1}, s_1 … s_N]``; the equality and
inequality rows form one matrix ``A_con`` with ``l ≤ A_con z ≤ u`` (OSQP's
form ``min ½ zᵀ P z + qᵀ z``).

``P`` and ``A_con`` are built once as CSC matrices (``controllers/qp/sparse.py``).

**Backends** (``solver=``), one object each behind one interface
(``controllers/qp/dispatch.py``: ``BACKENDS``), each owning its buffers and
solver object: :class:`~.qp.backend_osqp.OsqpBackend` and
:class:`~.qp.backend_daqp.DaqpBackend`; ``LinearMPC`` keeps the policy (the
backend choice, the referee of an inexact OSQP solve, the previous input, the
fallback and the result). ``"osqp"`` solves the sparse form above; its
default settings polish the ADMM solution (an exact solve of the KKT system
on the identified active set), and a solve that ends "solved inaccurate",
unpolished or at the iteration limit is re-solved from its own iterate with
tightened tolerances (and, when the problem is small enough, settled by the
condensed solver) before anything is reported. ``"daqp"`` solves the
condensed, input-only QP of ``controllers/qp/condensed.py`` (inputs around
the DARE's pre-stabilizing feedback, state bounds as dense rows, soft bounds
as slacks) with DAQP's dual active-set method: the exact optimum, warm-started
from the previous working set. ``"auto"`` (default) picks ``"daqp"`` while
the condensed problem is small (:func:`choose_solver`), else ``"osqp"``.
Either way ``MPCInfeasible`` is raised only with an infeasibility certificate
(OSQP's, or the elastic LP's behind DAQP's infeasible flag), naming the
constraint group and stage; an interrupted solve re-raises ``KeyboardInterrupt``.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from shinro_ctrl.analysis.design import finite_horizon_gain
from shinro_ctrl.controllers.base import Controller, default_input_bounds
from shinro_ctrl.controllers.lqr import riccati
from shinro_ctrl.controllers.offset_free import offset_free_call
from shinro_ctrl.controllers.qp.backend_daqp import DaqpBackend
from shinro_ctrl.controllers.qp.backend_osqp import OsqpBackend
from shinro_ctrl.controllers.qp.condensed import MAX_DENSE_SIZE, CondensedQP
from shinro_ctrl.controllers.qp.diagnose import fmt
from shinro_ctrl.controllers.qp.dispatch import (
    AUTO_DAQP_MAX_VARIABLES,
    BACKENDS,
    MPCBackend,
    choose_solver,
    dense_size,
)
from shinro_ctrl.controllers.qp.options import DEFAULT_OSQP_SETTINGS, PLANT_GIVEN, MPCOptions, MPCProblem
from shinro_ctrl.controllers.qp.solution import MPCSolution, clip_input
from shinro_ctrl.controllers.qp.sparse import (
    MAX_QP_SIZE,
    QP,
    RowGroup,
    build_sparse,
    fill_linear_cost,
    fill_rate_rows,
    qp_size,
)
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError, NotStabilizable
from shinro_ctrl.types import Vector, Weight
from shinro_ctrl.validation import as_vector, state_space, weight_matrix

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = [
    "AUTO_DAQP_MAX_VARIABLES",
    "BACKENDS",
    "DEFAULT_OSQP_SETTINGS",
    "MAX_QP_SIZE",
    "QP",
    "LinearMPC",
    "MPCOptions",
    "MPCSolution",
    "RowGroup",
    "choose_solver",
]

_SOLVED = ("solved", "solved (soft constraints violated)")


class LinearMPC(Controller):
    r"""Linear MPC solved exactly: a condensed QP by DAQP, or the sparse QP by one warm-started OSQP object.

    With ``δx = x − x0``, ``δu = u − u0`` and references ``r_k``, ``ū`` (in
    absolute units; default ``x0``, ``u0``) each call solves

    .. math::

        \min \tfrac12 \sum_{k=0}^{N-1} \big[\lVert x_k - r_k \rVert_Q^2 + \lVert u_k - \bar u \rVert_R^2\big]
            + \tfrac12 \lVert x_N - r_N \rVert_{Q_f}^2
            + \sum_{k=1}^{N} \big(w_1 \mathbf 1^\top s_k + \tfrac{w_2}{2} \lVert s_k \rVert^2\big)

    subject to ``x_0 = x`` (measured), ``δx_{k+1} = A δx_k + B δu_k + d``,
    ``u_min <= u_k <= u_max`` (k = 0..N−1), ``|u_k − u_{k−1}| <= du_max``
    (``u_{−1}`` the previously applied input), ``x_min − s_k <= x_k <= x_max + s_k``
    (k = 1..N; ``s_k >= 0`` only when ``soft``, else ``s_k = 0``). The module
    docstring spells out the sparse form.

    State bounds the input cannot affect at a stage (the rows of the
    prediction w.r.t. the inputs vanish: the cart position at stage 1 of an
    explicit-Euler model is ``x + dt·v`` whatever ``u_0``) are not
    constraints of the plan: no input changes them. When the measured state
    violates one, both backends leave that bound out of the step (it holds
    again from the next step on) and report it in ``last.dropped_rows``
    instead of declaring the problem infeasible.

    Threads: a call, :meth:`reset` and :meth:`build` hold the controller's
    lock, so concurrent calls from several threads are correct (each one a
    whole step on the shared warm start and previous input, in the order the
    threads get the lock; the lock costs well under 1 % of a call). For
    independent loops use one controller per thread.

    The options (everything after ``horizon``) are the fields of
    :class:`MPCOptions` (each documented there), passed as keywords or as one
    ``options`` object (keywords override its fields); the backend gets the
    resolved options whole.

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``, symmetric PSD (a length-``n`` vector
            means a diagonal).
        R: Stage input weight ``(m, m)``, symmetric positive definite.
        horizon: Prediction horizon ``N`` >= 1 (steps).
        options: An :class:`MPCOptions`.
        **kwargs: Fields of :class:`MPCOptions` as keywords (they override ``options``).

    Attributes:
        options: The resolved :class:`MPCOptions` (validated arrays, merged OSQP settings).
        K: LQR gain ``(m, n)`` of the DARE (None for another terminal cost).
        K_mpc: The unconstrained first-move gain ``(m, n)``: with no constraint active
            ``u − u0 = −K_mpc (x − x0)`` (+ reference and offset terms); ``K`` for ``terminal_cost="lqr"``.
        u_min, u_max, x_min, x_max: The bounds ``(m,)`` / ``(n,)`` in absolute
            units (±inf where unbounded).
        Qf: Terminal cost matrix ``(n, n)``.
        last: :class:`MPCSolution` of the latest call (None before the first).
        groups: The :class:`RowGroup` blocks of ``A_con``, by name.
        solver: The backend in use, ``"osqp"`` or ``"daqp"`` (``"auto"`` resolved).
        backend: The backend object (``BACKENDS[solver]``).
        dense: The :class:`~.qp.condensed.CondensedQP` (None on the OSQP backend).

    Raises:
        ValueError: wrong shapes (``expected (n, m) but found (p, q)``),
            asymmetric or indefinite weights, ``horizon < 1``, a horizon whose
            QP exceeds :data:`MAX_QP_SIZE` variables or nonzeros, crossed
            bounds, unknown or invalid OSQP settings.
        NonFiniteError: NaN or inf where a finite number is needed.
        NotStabilizable: ``terminal_cost="lqr"`` but the DARE has no
            stabilizing solution; or the unconstrained MPC law does not
            stabilize the model (a short horizon with ``terminal_cost="Q"``
            or a matrix): the message names the spectral radius and the fixes.

    Example:
        >>> from shinro_ctrl.plants import CartPole
        >>> mpc = LinearMPC.from_plant(CartPole(dt=0.02), [10, 1, 100, 1], [0.1], horizon=50,
        ...                            u_min=-3, u_max=3, x_min=[-0.6, -np.inf, -np.inf, -np.inf],
        ...                            x_max=[0.6, np.inf, np.inf, np.inf])
        >>> u = mpc([0.0, 0.0, 0.3, 0.0])
    """

    stateful = True  # warm start, previous input and plan

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        Q: ArrayLike,
        R: ArrayLike,
        horizon: int,
        *,
        options: MPCOptions | None = None,
        **kwargs: Any,
    ):
        A_, B_ = state_space(A, B)
        n, m = B_.shape
        Q_ = weight_matrix("Q", Q, n)
        R_ = weight_matrix("R", R, m, definite=True)
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)):
            raise InvalidArgument(f"horizon must be an int >= 1, got {horizon!r}")
        N = int(horizon)
        if N < 1:
            raise InvalidArgument(f"horizon must be >= 1, got {N}")
        opts = options if options is not None else MPCOptions()
        if kwargs:
            opts = dataclasses.replace(opts, **kwargs)  # TypeError names a misspelt option
        opts = self.options = opts.resolve(n, m)
        self.n, self.m, self.N = n, m, N
        self.state_dim, self.input_dim, self.horizon = n, m, N
        self.preview = N  # a simulation passes reference trajectories of N + 1 samples (see sim.RobotSim.run)
        self.model: Any = None  # the LinearModel when built by from_plant
        # a floating base (from_plant): the full state x (and ref) -> its deviation difference(x, x_op) (n,)
        self._to_tangent: Callable[[np.ndarray], np.ndarray] | None = None
        self.A, self.B, self.Q, self.R = A_, B_, Q_, R_
        # |x| beyond which ½ xᵀ Q x summed over the horizon overflows float64 (a "huge state" is not "infeasible")
        self._x_overflow = min(
            1e12,  # the QP solvers' relative precision: beyond it a feasible problem is reported infeasible
            math.sqrt(1e300 / ((N + 1) * max(1.0, float(np.abs(Q_).max(initial=0.0))))),
        )
        self.x0, self.u0, self.offset, self.dt = opts.x0, opts.u0, opts.offset, opts.dt
        self.u_min, self.u_max, self.x_min, self.x_max = opts.u_min, opts.u_max, opts.x_min, opts.x_max
        self.du_max, self.soft = opts.du_max, opts.soft
        self.soft_weight_l1, self.soft_weight_quad = opts.soft_weight_l1, opts.soft_weight_quad
        self.u_ref, self.fallback = opts.u_ref, opts.fallback
        self.disturbance_model = opts.disturbance_model  # "input": offset-free (controllers/offset_free.py)
        self.state_names, self.input_names = opts.state_names, opts.input_names
        self.osqp_settings = opts.osqp_settings
        self._check_size()
        # terminal cost: the DARE's P (with its gain K), Q, or the given matrix
        self.K: np.ndarray | None = None
        if isinstance(opts.terminal_cost, str):
            self.terminal_cost = opts.terminal_cost
            if opts.terminal_cost == "lqr":
                self.K, self.Qf = riccati(
                    A_, B_, Q_, R_, what="the terminal cost (or pass terminal_cost='Q' or a matrix)"
                )
            else:
                self.Qf = Q_.copy()
        else:
            self.Qf = opts.terminal_cost
            self.terminal_cost = "matrix"
        self.problem = MPCProblem(A_, B_, Q_, R_, self.Qf, self.K, N)
        self.K_mpc = self._check_nominal_loop()
        self.sparse = build_sparse(A_, B_, Q_, R_, self.Qf, N, opts)
        self.groups: dict[str, RowGroup] = {g.name: g for g in self.sparse.groups}
        self.solver = choose_solver(n, m, N, opts)
        # An inexact OSQP solve is settled by the condensed solver when the condensed QP fits
        fits = dense_size(n, m, N, opts) <= MAX_DENSE_SIZE
        if self.solver == "osqp":
            self.backend: MPCBackend = OsqpBackend(self.problem, opts, self.sparse, referee=fits)
        else:
            self.backend = BACKENDS[self.solver](self.problem, opts)
            if opts.osqp_settings != DEFAULT_OSQP_SETTINGS:
                # OSQP checks the values of the caller's settings at set-up: a bad one raises now, not when
                # the fallback first needs OSQP (and ``verbose`` prints its banner now)
                OsqpBackend(self.problem, opts, self.sparse)
        self._referee: DaqpBackend | None = self.backend if isinstance(self.backend, DaqpBackend) else None
        self._referee_fits = fits
        self._u_prev_buf = np.zeros(m)  # the previously applied input (when _u_prev is not None)
        self._lock = threading.RLock()  # one step at a time on the backend's buffers (re-entered by offset_free)
        self.reset()

    def _check_nominal_loop(self) -> np.ndarray:
        """The unconstrained first-move gain ``K_mpc``; raise unless ``A − B K_mpc`` is strictly stable.

        With no constraint active the MPC is the linear law ``u − u0 = −K_mpc (x − x0)``
        (plus a constant from the references and the offset), ``K_mpc`` the first
        block of ``H⁻¹ F`` of the condensed QP, i.e. the backward Riccati
        recursion over the horizon from the terminal cost
        (:func:`~shinro_ctrl.analysis.design.finite_horizon_gain`). A short
        horizon with a terminal cost other than the DARE's may leave that loop
        unstable on the very model it was designed on; such a controller would
        run and diverge, so it is refused, as LQR refuses an unstable loop.

        Raises:
            NotStabilizable: the spectral radius of ``A − B K_mpc`` is >= 1 (margin 1e-9),
                naming it, the shortest stabilizing horizon when there is one, and the fixes.
        """
        A, B, Q, R, N = self.A, self.B, self.Q, self.R, self.N
        if self.K is not None:  # terminal_cost="lqr": the law is the LQR's, whose loop riccati() checked
            return self.K
        K_mpc = finite_horizon_gain(A, B, Q, R, self.Qf, N)
        radius = float(np.max(np.abs(np.linalg.eigvals(A - B @ K_mpc))))
        if radius < 1.0 - 1e-9:
            return K_mpc
        hint = ""
        for longer in range(N + 1, max(4 * N, 200) + 1):  # the shortest horizon that stabilizes, if one is near
            K_long = finite_horizon_gain(A, B, Q, R, self.Qf, longer)
            if float(np.max(np.abs(np.linalg.eigvals(A - B @ K_long)))) < 1.0 - 1e-9:
                hint = f" (horizon = {longer} is the shortest that stabilizes it)"
                break
        tc = "the given matrix" if self.terminal_cost == "matrix" else f"'{self.terminal_cost}'"
        raise NotStabilizable(
            f"LinearMPC with horizon = {N} and terminal_cost = {tc} does not stabilize its own model: "
            f"with no constraint active its law u = -K_mpc (x - x0) leaves the closed loop A - B K_mpc with "
            f"spectral radius {radius:.4g} >= 1, so the loop diverges; use a longer horizon{hint} or "
            "terminal_cost = 'lqr' (the DARE's cost, stabilizing at any horizon)"
        )

    @classmethod
    def option_keys(cls) -> tuple[str, ...]:
        """The keys a scenario's ``[controller]`` table may hold: ``from_plant``'s and the options'."""
        own = ("Q", "R", "horizon", "x0", "u0", "discretization", "method")
        fields = [f.name for f in dataclasses.fields(MPCOptions) if f.init]
        return own + tuple(k for k in fields if k not in (*own, *PLANT_GIVEN))

    @classmethod
    def option_annotations(cls) -> dict[str, object]:
        """``from_plant``'s annotations and those of the :class:`MPCOptions` fields it forwards."""
        fields = {f.name: f.type for f in dataclasses.fields(MPCOptions) if f.init}
        return {**fields, **super().option_annotations()}

    # ================================================================ set-up
    def _check_size(self) -> None:
        nvar, nnz = qp_size(self.A, self.B, self.Q, self.R, self.N, self.options)
        if nvar > MAX_QP_SIZE or nnz > MAX_QP_SIZE:
            raise InvalidArgument(
                f"horizon {self.N:,} makes an MPC QP too large to build: {nvar:,} decision variables and up to "
                f"{nnz:,} nonzeros (n = {self.n} states, m = {self.m} inputs); the limit is {MAX_QP_SIZE:,} of "
                "each. Use a shorter horizon (or a larger dt for the same preview time)"
            )

    @classmethod
    def from_plant(
        cls,
        plant: Plant,
        Q: Weight,
        R: Weight,
        *,
        horizon: int,
        x0: Vector | None = None,
        u0: Vector | None = None,
        discretization: str = "step",
        method: str = "exact",
        **options: Any,
    ) -> LinearMPC:
        """Build the controller from a plant's linearization at ``(x0, u0)``.

        Args:
            plant: Any :class:`~shinro_ctrl.plants.base.Plant`.
            Q: Stage state weight ``(n, n)`` or its diagonal ``(n,)``.
            R: Stage input weight ``(m, m)`` or its diagonal ``(m,)``.
            horizon: Prediction horizon ``N`` (steps of ``plant.dt``).
            x0: Operating state ``(n,)``; default ``plant.equilibrium()``.
            u0: Operating input ``(m,)``; default ``plant.equilibrium()``.
            discretization: ``"step"`` (default: the exact linearization of the plant's own
                discrete step), ``"euler"``, ``"zoh"`` or ``"rk4"``.
            method: Linearization method, ``"exact"`` or ``"fd"``.
            **options: The other fields of :class:`MPCOptions`; ``dt``,
                ``offset`` and the names come from the plant.

        Raises:
            TypeError: an unknown option, or one the plant gives.

        The affine term ``d`` is the drift ``f(x0, u0)`` discretized the same
        way as ``B`` (zero at an equilibrium). The returned controller keeps
        the :class:`~shinro_ctrl.linearization.LinearModel` as ``model``.
        """
        given = [k for k in options if k in PLANT_GIVEN]
        if given:
            raise TypeError(f"from_plant() got an unexpected keyword argument '{given[0]}' (it comes from the plant)")
        lm = plant.linear_model(x0, u0, method=method, discretization=discretization)
        drift = np.asarray(plant.dynamics(lm.x0, lm.u0), dtype=float)
        offset = None
        if np.any(drift != 0.0):
            offset = plant.discrete_offset(lm)
        options["u_min"], options["u_max"] = default_input_bounds(plant, options.get("u_min"), options.get("u_max"))
        opts = MPCOptions(**options)  # TypeError names a misspelt option
        floating = plant.tangent_dim != plant.state_dim
        opts = dataclasses.replace(
            opts,
            x0=np.zeros(plant.tangent_dim) if floating else lm.x0,
            u0=lm.u0,
            dt=lm.dt,
            offset=offset,
            state_names=plant.tangent_names,
            input_names=plant.input_names,
        )
        ctrl = cls(lm.A, lm.B, Q, R, horizon, options=opts)
        ctrl.model = lm
        if floating:
            x_op = lm.x0.copy()
            ctrl.measure_deviations(lambda z: plant.difference(z, x_op), plant.state_dim)
        return ctrl

    def measure_deviations(self, deviation: Callable[[np.ndarray], np.ndarray], state_dim: int) -> None:
        """Take states ``(state_dim,)`` and references as ``deviation(x)`` (a floating base's tangent space).

        The QP then lives in the deviation coordinates of the operating state (:meth:`from_plant` passes
        ``plant.difference(·, x0)`` and an operating point 0): ``x`` and ``ref`` enter through
        ``deviation``; the plans ``last.states`` and the state bounds are deviations.
        """
        self._to_tangent = deviation
        self.state_dim = int(state_dim)

    def _tangent_args(self, x: ArrayLike, ref: ArrayLike | None) -> tuple[np.ndarray, np.ndarray | None]:
        """A floating base's full state and reference as deviations (see :meth:`from_plant`)."""
        assert self._to_tangent is not None
        x = as_vector("x", x, self.state_dim)
        if ref is None:
            return self._to_tangent(x), None
        r = np.asarray(ref, dtype=float)
        if r.shape not in ((self.state_dim,), (self.N + 1, self.state_dim)):
            raise InvalidArgument(
                f"ref: expected ({self.state_dim},) or ({self.N + 1}, {self.state_dim}) but found {r.shape}"
            )
        if not np.isfinite(r).all():
            raise NonFiniteError("ref must be finite")
        return self._to_tangent(x), self._to_tangent(r)

    # =============================================================== public
    @property
    def dense(self) -> CondensedQP | None:
        """The :class:`~.qp.condensed.CondensedQP` of the DAQP backend (None on the OSQP backend)."""
        return self.backend.dense if isinstance(self.backend, DaqpBackend) else None

    @property
    def qp(self) -> QP:
        """The sparse QP as last sent to OSQP (copies), or as the next call would start it on DAQP."""
        if isinstance(self.backend, OsqpBackend):
            return self.backend.current_qp()
        return self.build(self.x0)

    @property
    def P(self) -> sp.csc_matrix:
        """Upper-triangular cost Hessian ``(n_var, n_var)`` of the sparse QP (CSC, built once)."""
        return self.sparse.P

    @property
    def A_con(self) -> sp.csc_matrix:
        """Constraint matrix ``(n_con, n_var)`` of the sparse QP (CSC, built once)."""
        return self.sparse.A

    @property
    def n_var(self) -> int:
        """Decision variables of the sparse QP."""
        return self.sparse.n_var

    @property
    def n_con(self) -> int:
        """Constraint rows of the sparse QP."""
        return self.sparse.n_con

    def build(
        self,
        x: ArrayLike,
        ref: ArrayLike | None = None,
        *,
        u_ref: ArrayLike | None = None,
        u_prev: ArrayLike | None = None,
    ) -> QP:
        """The sparse QP one call would solve for state ``x``, without solving it.

        Args:
            x: Measured state ``(n,)`` [absolute].
            ref: Target state ``(n,)`` or trajectory ``(N + 1, n)``; default ``x0``.
            u_ref: Input reference ``(m,)``; default the constructor's, else ``u0``.
            u_prev: Previously applied input ``(m,)`` for the rate bounds;
                default the controller's current one.

        Returns:
            A :class:`QP` with fresh arrays (the solver is not touched).
        """
        if self._to_tangent is not None:
            x, ref = self._tangent_args(x, ref)
        with self._lock:
            return self._build(x, ref, u_ref, u_prev)

    def _build(self, x: ArrayLike, ref: ArrayLike | None, u_ref: ArrayLike | None, u_prev: ArrayLike | None) -> QP:
        s = self.sparse
        x = as_vector("x", x, self.n)
        q = s.q.copy()
        fill_linear_cost(s, self.Q, self.R, self.Qf, self.options, self._check_ref(ref), self._check_uref(u_ref), q)
        l, u = s.l.copy(), s.u.copy()
        l[: self.n] = u[: self.n] = x - self.x0
        up = self._u_prev if u_prev is None else as_vector("u_prev", u_prev, self.m)
        fill_rate_rows(s, self.options, up, l, u)
        return QP(s.P.copy(), q, s.A.copy(), l, u)

    def reset(self, *, u_prev: ArrayLike | None = None) -> None:
        """Forget the warm start, the previous plan and the previous input.

        Args:
            u_prev: Optional input ``(m,)`` to treat as previously applied (for
                the rate bounds of the first move).
        """
        with self._lock:
            self._u_prev: np.ndarray | None = None
            if u_prev is not None:
                self._u_prev_buf[:] = as_vector("u_prev", u_prev, self.m)
                self._u_prev = self._u_prev_buf
            self._plan_u: np.ndarray | None = None
            self._plan_x: np.ndarray | None = None
            self._plan_age = 0
            self.last: MPCSolution | None = None
            self.backend.reset()  # cold working set / warm start: runs repeat exactly
            if self._referee is not None and self._referee is not self.backend:
                self._referee.reset()

    def __call__(self, x: ArrayLike, ref: ArrayLike | None = None, *, u_ref: ArrayLike | None = None) -> np.ndarray:
        """Solve the MPC problem at state ``x`` and return the first input.

        Args:
            x: Measured state ``(n,)`` [absolute units]; with
                ``disturbance_model="input"`` also ``[x̂; d̂]`` ``(n + m,)``.
            ref: Target state ``(n,)`` or trajectory ``(N + 1, n)`` over the
                horizon [absolute]; default the operating point ``x0``.
            u_ref: Input reference ``(m,)`` [absolute]; default the
                constructor's ``u_ref``, else ``u0``.

        Returns:
            The input ``u_0`` ``(m,)``, clipped to the hard input and rate bounds.

        Raises:
            ValueError: wrong shape of ``x``, ``ref`` or ``u_ref``.
            NonFiniteError: NaN or inf in ``x``, ``ref`` or ``u_ref``.
            MPCInfeasible: the backend certified infeasibility or failed (and
                no ``fallback="shift"`` plan is left).
        """
        if self._to_tangent is not None:
            x, ref = self._tangent_args(x, ref)
        with self._lock:
            if self.disturbance_model is not None and np.shape(x) == (self.n + self.m,):
                return offset_free_call(self, x, ref, u_ref)  # [x̂; d̂] from a disturbance-augmented estimator
            return self._step(x, ref, u_ref)

    def _step(self, x: ArrayLike, ref: ArrayLike | None, u_ref: ArrayLike | None) -> np.ndarray:
        """One MPC step (under the lock): check the arguments, solve, settle, record or fall back."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n,):
            x = as_vector("x", x, self.n)  # raises with the standard message
        elif not np.isfinite(x).all():
            raise NonFiniteError(f"x must be finite, got {fmt(x)}")
        if float(np.abs(x).max()) > self._x_overflow:
            raise NonFiniteError(
                f"x = {fmt(x)} is beyond the MPC's numeric range |x| <= {self._x_overflow:.2g}: there the QP's "
                f"terms lose every significant digit (and ½ xᵀ Q x over {self.N} stages nears float64 overflow); "
                "a state this far off means the loop already diverged"
            )
        r = None if ref is None else self._check_ref(ref)
        ur = self._check_uref(u_ref)
        sol = self.backend.solve(x, r, ur, self._u_prev)
        if not self.backend.settled and self._referee_fits:
            # OSQP stayed inexact after its re-solves: the condensed solver settles the step exactly
            if self._referee is None:
                self._referee = DaqpBackend(self.problem, self.options)
            sol = self._referee.solve(x, r, ur, self._u_prev)
        if sol.status not in _SOLVED:
            return self._give_up(sol)
        return self._accept(sol)

    # ============================================================ internals
    def _accept(self, sol: MPCSolution) -> np.ndarray:
        """Record a solution: the applied input (for the rate bounds), the plan (for the fallback) and ``last``."""
        self._u_prev_buf[:] = sol.u  # a private copy: the caller may modify what we return
        self._u_prev = self._u_prev_buf
        self._plan_x, self._plan_u, self._plan_age = sol.states, sol.inputs, 0
        self.last = sol
        return sol.u

    def _give_up(self, sol: MPCSolution) -> np.ndarray:
        """Raise :class:`MPCInfeasible` with the backend's message, or apply the shifted previous plan."""
        message = sol.message
        age = self._plan_age + 1
        if self.fallback != "shift" or self._plan_u is None or age >= self.N:
            if self.fallback == "shift":
                message += (
                    "; fallback 'shift' has no previous plan"
                    if self._plan_u is None
                    else f"; fallback 'shift' exhausted the previous plan ({self.N} steps)"
                )
            self.last = dataclasses.replace(sol, message=message)
            raise MPCInfeasible(message)
        u_out = self._plan_u[age].copy()
        clip_input(u_out, self._u_prev, self.du_max, self.u_min, self.u_max)
        idx = np.minimum(np.arange(self.N + 1) + age, self.N)
        plan_x, plan_u = self._plan_x, self._plan_u
        assert plan_x is not None
        self._accept(
            dataclasses.replace(
                sol, states=plan_x[idx], inputs=plan_u[np.minimum(idx[:-1], self.N - 1)], u=u_out, fallback_used=True
            )
        )
        self._plan_x, self._plan_u, self._plan_age = plan_x, plan_u, age
        return u_out

    def _check_ref(self, ref: ArrayLike | None) -> np.ndarray | None:
        if ref is None:
            return None
        r = np.asarray(ref, dtype=float)
        if r.shape == (self.n,) or r.shape == (self.N + 1, self.n) or (self.n == 1 and r.shape == (self.N + 1,)):
            if not np.isfinite(r).all():
                raise NonFiniteError("ref must be finite")
            return r.reshape(-1, self.n) if r.ndim == 1 and r.shape != (self.n,) else r
        raise InvalidArgument(f"ref: expected ({self.n},) or ({self.N + 1}, {self.n}) but found {r.shape}")

    def _check_uref(self, u_ref: ArrayLike | None) -> np.ndarray | None:
        if u_ref is None:
            return self.u_ref
        return as_vector("u_ref", u_ref, self.m)

    # ============================================================= describe
    def describe(self) -> str:
        """A human-readable summary: sizes, bounds, terminal cost, and the sizes and settings of the backend in use."""
        dt = "" if self.dt is None else f", dt = {self.dt:g} s"
        lines = [
            f"LinearMPC: n = {self.n} states, m = {self.m} inputs, horizon N = {self.N}{dt}",
            f"backend: {self.solver} (solver = '{self.options.solver}')",
            self.backend.describe(),
            f"operating point: x0 = {fmt(self.x0)}, u0 = {fmt(self.u0)}",
            f"input bounds: u_min = {fmt(self.u_min)}, u_max = {fmt(self.u_max)}",
            f"state bounds ({'soft' if self.soft else 'hard'}): x_min = {fmt(self.x_min)}, x_max = {fmt(self.x_max)}",
        ]
        if self.soft:
            lines.append(f"soft weights: l1 = {self.soft_weight_l1:g}, quad = {self.soft_weight_quad:g}")
        if self.du_max is not None:
            lines.append(f"rate bounds: du_max = {fmt(self.du_max)}")
        lines.append(f"terminal cost ({self.terminal_cost}):")
        lines.append(np.array2string(self.Qf, precision=4, max_line_width=110))
        if self.K is not None:
            lines.append(f"LQR gain K = {fmt(self.K)}")
        lines.append(f"fallback: {self.fallback}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (
            f"LinearMPC(n={self.n}, m={self.m}, horizon={self.N}, soft={self.soft}, "
            f"n_var={self.n_var}, n_con={self.n_con})"
        )
