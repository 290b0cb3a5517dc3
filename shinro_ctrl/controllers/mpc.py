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
      + \tfrac12 (\delta x_N - \rho_N)^\top P_f (\delta x_N - \rho_N)
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

``P`` and ``A_con`` are built once as CSC matrices (``controllers/qp/sparse.py``)
and handed to one OSQP object (``controllers/_osqp.py``). A call writes the
measured state into the initial-state rows of
``l``/``u`` (and the previous input into the first rate rows), rewrites ``q``
only when the reference changes, warm-starts primal and dual variables from
the previous solution shifted by one stage, and solves.

**Backends** (``solver=``). ``"osqp"`` solves the sparse form above; its
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
import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from shinro_ctrl.controllers._mpc_solve import MPCSolve
from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.lqr import riccati
from shinro_ctrl.controllers.offset_free import offset_free_call
from shinro_ctrl.controllers.qp.condensed import CondensedQP
from shinro_ctrl.controllers.qp.diagnose import fmt
from shinro_ctrl.controllers.qp.dispatch import AUTO_DAQP_MAX_VARIABLES, choose_solver
from shinro_ctrl.controllers.qp.options import DEFAULT_OSQP_SETTINGS, PLANT_GIVEN, MPCOptions
from shinro_ctrl.controllers.qp.solution import MPCSolution
from shinro_ctrl.controllers.qp.sparse import MAX_QP_SIZE, QP, RowGroup, qp_size
from shinro_ctrl.errors import InvalidArgument, NonFiniteError
from shinro_ctrl.validation import as_vector, state_space, weight_matrix

__all__ = [
    "AUTO_DAQP_MAX_VARIABLES",
    "DEFAULT_OSQP_SETTINGS",
    "MAX_QP_SIZE",
    "QP",
    "LinearMPC",
    "MPCOptions",
    "MPCSolution",
    "RowGroup",
    "choose_solver",
]

_fmt = fmt


class LinearMPC(MPCSolve, Controller):
    r"""Linear MPC solved exactly: a condensed QP by DAQP, or the sparse QP by one warm-started OSQP object.

    With ``δx = x − x0``, ``δu = u − u0`` and references ``r_k``, ``ū`` (in
    absolute units; default ``x0``, ``u0``) each call solves

    .. math::

        \min \tfrac12 \sum_{k=0}^{N-1} \big[\lVert x_k - r_k \rVert_Q^2 + \lVert u_k - \bar u \rVert_R^2\big]
            + \tfrac12 \lVert x_N - r_N \rVert_{P_f}^2
            + \sum_{k=1}^{N} \big(w_1 \mathbf 1^\top s_k + \tfrac{w_2}{2} \lVert s_k \rVert^2\big)

    subject to ``x_0 = x`` (measured), ``δx_{k+1} = A δx_k + B δu_k + d``,
    ``u_min <= u_k <= u_max`` (k = 0..N−1), ``|u_k − u_{k−1}| <= du_max``
    (``u_{−1}`` the previously applied input), ``x_min − s_k <= x_k <= x_max + s_k``
    (k = 1..N; ``s_k >= 0`` only when ``soft``, else ``s_k = 0``). The module
    docstring spells out the sparse form. ``P`` and ``A_con`` are built once;
    a call only updates the initial-state rows, the first rate-bound rows,
    and (when the reference changes) the linear cost ``q``.

    The options (everything after ``horizon``) are the fields of
    :class:`MPCOptions`, passed as keywords or as one ``options`` object
    (keywords override its fields).

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``, symmetric PSD (a length-``n`` vector
            means a diagonal).
        R: Stage input weight ``(m, m)``, symmetric positive definite.
        horizon: Prediction horizon ``N`` >= 1 (steps).
        options: An :class:`MPCOptions` holding the options below.
        **kwargs: The options below as keywords (they override ``options``).

    Keyword Args:
        x0: Operating-point state ``(n,)`` [absolute units]; default zeros.
        u0: Operating-point input ``(m,)``; default zeros.
        dt: Sampling time [s] (informational; used by :meth:`describe`).
        u_min: Lower input bounds ``(m,)`` (a scalar broadcasts; -inf = none).
        u_max: Upper input bounds ``(m,)``.
        x_min: Lower state bounds ``(n,)`` on ``x_1 … x_N`` (never on the
            measured ``x_0``).
        x_max: Upper state bounds ``(n,)``.
        du_max: Input-rate bounds ``(m,)``, ``|u_k − u_{k−1}| <= du_max`` per
            step, ``u_{−1}`` the previously applied input (the first call
            after construction or :meth:`reset` has no previous input unless
            ``reset(u_prev=...)`` provides one).
        soft: Make the state bounds soft with slack variables.
        soft_weight_l1: Linear slack weight ``w_1`` (an exact penalty when it
            exceeds the bound's multiplier; keep it moderate, OSQP converges
            slowly with huge weights).
        soft_weight_quad: Quadratic slack weight ``w_2`` (> 0 keeps the
            slack problem strongly convex).
        terminal_cost: ``"dare"`` (default; ``P_f`` from the discrete
            algebraic Riccati equation, so with no active constraint the
            first move equals the LQR input), ``"Q"``, or a matrix ``(n, n)``.
        u_ref: Default input reference ``(m,)`` in absolute units (default
            ``u0``).
        offset: Affine term ``d`` ``(n,)`` of the model; zero at an
            equilibrium.
        fallback: None (raise on failure) or ``"shift"`` (apply the previous
            plan shifted by one step and flag it).
        solver: QP backend: ``"auto"`` (default; :func:`choose_solver`:
            ``"daqp"`` up to 250 condensed variables ``N·m`` + slacks, else ``"osqp"``),
            ``"daqp"`` (condensed input-only QP, dense dual active set,
            exact) or ``"osqp"`` (sparse QP, ADMM + polishing, exact unless a
            polish fails on a problem too large for the condensed check).
        osqp_settings: Overrides of :data:`DEFAULT_OSQP_SETTINGS`; unknown
            keys raise ``ValueError`` listing the valid ones.
        state_names: Names of the states for messages (default ``x[i]``).
        input_names: Names of the inputs for messages (default ``u[i]``).

    Attributes:
        options: The resolved :class:`MPCOptions` (validated arrays, merged OSQP settings).
        K: LQR gain ``(m, n)`` of the DARE (None for another terminal cost).
        u_min, u_max, x_min, x_max: The bounds ``(m,)`` / ``(n,)`` in absolute
            units (±inf where unbounded).
        P_f: Terminal cost matrix ``(n, n)``.
        last: :class:`MPCSolution` of the latest call (None before the first).
        groups: The :class:`RowGroup` blocks of ``A_con``, by name.
        solver: The backend in use, ``"osqp"`` or ``"daqp"`` (``"auto"`` resolved).
        dense: The :class:`~.qp.condensed.CondensedQP` (None on the OSQP backend).

    Raises:
        ValueError: wrong shapes (``expected (n, m) but found (p, q)``),
            asymmetric or indefinite weights, ``horizon < 1``, a horizon whose
            QP exceeds :data:`MAX_QP_SIZE` variables or nonzeros, crossed
            bounds, unknown or invalid OSQP settings.
        NonFiniteError: NaN or inf where a finite number is needed.
        NotStabilizable: ``terminal_cost="dare"`` but the DARE has no
            stabilizing solution.

    Example:
        >>> from shinro_ctrl.plants import CartPole
        >>> mpc = LinearMPC.from_plant(CartPole(dt=0.02), [10, 1, 100, 1], [0.1], horizon=50,
        ...                            u_min=-3, u_max=3, x_min=[-0.6, -np.inf, -np.inf, -np.inf],
        ...                            x_max=[0.6, np.inf, np.inf, np.inf])
        >>> u = mpc([0.0, 0.0, 0.3, 0.0])
    """

    stateful = True  # warm start, previous input and plan

    def __init__(
        self, A: Any, B: Any, Q: Any, R: Any, horizon: int, *, options: MPCOptions | None = None, **kwargs: Any
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
            if opts.terminal_cost == "dare":
                self.K, self.P_f = riccati(
                    A_, B_, Q_, R_, what="the terminal cost (or pass terminal_cost='Q' or a matrix)"
                )
            else:
                self.P_f = Q_.copy()
        else:
            self.P_f = opts.terminal_cost
            self.terminal_cost = "matrix"
        self._warm = bool(self.osqp_settings["warm_starting"])
        self._build_structure()
        self.solver = choose_solver(n, m, N, opts)
        # The OSQP object is set up on first use (``_osqp``): the DAQP backend needs it only as a fallback.
        # It is set up here when OSQP is the backend, or when the caller gave OSQP settings (OSQP checks
        # their values at set-up: a bad one raises now, and ``verbose`` prints its banner now).
        self._osqp_qp = None
        if self.solver == "osqp" or self.osqp_settings != DEFAULT_OSQP_SETTINGS:
            self._osqp  # noqa: B018 - set up now
        self.dense: CondensedQP | None = self._condensed() if self.solver == "daqp" else None
        self._referee: CondensedQP | None = self.dense  # settles OSQP solves that stay inexact
        self._dense_ref = False  # the condensed QP holds a reference (not the operating point)
        self._solved_since_setup = False
        self.reset()

    @classmethod
    def option_keys(cls) -> tuple[str, ...]:
        """The keys a scenario's ``[controller]`` table may hold: ``from_plant``'s and the options'."""
        own = ("Q", "R", "horizon", "x0", "u0", "discretization", "method")
        fields = [f.name for f in dataclasses.fields(MPCOptions)]
        return own + tuple(k for k in fields if k not in (*own, *PLANT_GIVEN))

    @classmethod
    def option_annotations(cls) -> dict[str, Any]:
        """``from_plant``'s annotations and those of the :class:`MPCOptions` fields it forwards."""
        return {**{f.name: f.type for f in dataclasses.fields(MPCOptions)}, **super().option_annotations()}

    # ================================================================ set-up
    def _qp_size(self) -> tuple[int, int]:
        """``(decision variables, nonzeros of P and A_con)`` of the QP (see :func:`~.qp.sparse.qp_size`)."""
        return qp_size(self.A, self.B, self.Q, self.R, self.N, self.options)

    def _check_size(self) -> None:
        nvar, nnz = self._qp_size()
        if nvar > MAX_QP_SIZE or nnz > MAX_QP_SIZE:
            raise InvalidArgument(
                f"horizon {self.N:,} makes an MPC QP too large to build: {nvar:,} decision variables and up to "
                f"{nnz:,} nonzeros (n = {self.n} states, m = {self.m} inputs); the limit is {MAX_QP_SIZE:,} of "
                "each. Use a shorter horizon (or a larger dt for the same preview time)"
            )

    @classmethod
    def from_plant(
        cls,
        plant: Any,
        Q: Any,
        R: Any,
        *,
        horizon: int,
        x0: Any = None,
        u0: Any = None,
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
            **options: The other fields of :class:`MPCOptions` (u_min, u_max,
                x_min, x_max, du_max, soft, soft_weight_l1, soft_weight_quad,
                terminal_cost, u_ref, fallback, osqp_settings); ``dt``,
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
        opts = MPCOptions(**options)  # TypeError names a misspelt option
        opts = dataclasses.replace(
            opts,
            x0=lm.x0,
            u0=lm.u0,
            dt=lm.dt,
            offset=offset,
            state_names=plant.state_names,
            input_names=plant.input_names,
        )
        ctrl = cls(lm.A, lm.B, Q, R, horizon, options=opts)
        ctrl.model = lm
        return ctrl

    # =============================================================== public
    @property
    def qp(self) -> QP:
        """The QP as last sent to OSQP (copies; inspect without solving)."""
        return QP(self._P.copy(), self._q.copy(), self._A.copy(), self._l.copy(), self._u.copy())

    @property
    def P(self) -> sp.csc_matrix:
        """Upper-triangular cost Hessian ``(n_var, n_var)`` (CSC, built once)."""
        return self._P

    @property
    def A_con(self) -> sp.csc_matrix:
        """Constraint matrix ``(n_con, n_var)`` (CSC, built once)."""
        return self._A

    def build(self, x: Any, ref: Any = None, *, u_ref: Any = None, u_prev: Any = None) -> QP:
        """The QP one call would solve for state ``x``, without solving it.

        Args:
            x: Measured state ``(n,)`` [absolute].
            ref: Target state ``(n,)`` or trajectory ``(N + 1, n)``; default ``x0``.
            u_ref: Input reference ``(m,)``; default the constructor's, else ``u0``.
            u_prev: Previously applied input ``(m,)`` for the rate bounds;
                default the controller's current one.

        Returns:
            A :class:`QP` with fresh arrays (the solver is not touched).
        """
        x = as_vector("x", x, self.n)
        q = self._q_default.copy()
        self._fill_q(self._check_ref(ref), self._check_uref(u_ref), q)
        l, u = self._l.copy(), self._u.copy()
        l[: self.n] = u[: self.n] = x - self.x0
        up = self._u_prev if u_prev is None else as_vector("u_prev", u_prev, self.m)
        self._fill_rate0(up, l, u)
        return QP(self._P.copy(), q, self._A.copy(), l, u)

    def reset(self, *, u_prev: Any = None) -> None:
        """Forget the warm start, the previous plan and the previous input.

        Args:
            u_prev: Optional input ``(m,)`` to treat as previously applied (for
                the rate bounds of the first move).
        """
        self._u_prev: np.ndarray | None = None
        if u_prev is not None:
            self._u_prev_buf[:] = as_vector("u_prev", u_prev, self.m)
            self._u_prev = self._u_prev_buf
        self._fill_rate0(self._u_prev, self._l, self._u)
        self._zws[:] = 0.0
        self._yws[:] = 0.0
        self._plan_u: np.ndarray | None = None
        self._plan_x: np.ndarray | None = None
        self._plan_age = 0
        self.last: MPCSolution | None = None
        if self._referee is not None:
            self._referee.reset()  # cold working set (the dense backend's, or the referee's): runs repeat exactly
        if self._solved_since_setup:
            # OSQP keeps internal state between solves (adaptive rho and its factorization), so a
            # reset controller must start from a fresh solver to repeat a run exactly.
            self._osqp.setup()
            self._solved_since_setup = False

    def __call__(self, x: Any, ref: Any = None, *, u_ref: Any = None) -> np.ndarray:
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
            MPCInfeasible: OSQP reported infeasibility or hit its iteration or
                time limit (and no ``fallback="shift"`` plan is left).
        """
        if self.disturbance_model is not None and np.shape(x) == (self.n + self.m,):
            return offset_free_call(self, x, ref, u_ref)  # [x̂; d̂] from a disturbance-augmented estimator
        t0 = time.perf_counter()
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n,):
            x = as_vector("x", x, self.n)  # raises with the standard message
        elif not np.isfinite(x).all():
            raise NonFiniteError(f"x must be finite, got {_fmt(x)}")
        if float(np.abs(x).max()) > self._x_overflow:
            raise NonFiniteError(
                f"x = {_fmt(x)} is beyond the MPC's numeric range |x| <= {self._x_overflow:.2g}: there the QP's "
                f"terms lose every significant digit (and ½ xᵀ Q x over {self.N} stages nears float64 overflow); "
                "a state this far off means the loop already diverged"
            )
        if self.dense is not None:
            return self._call_dense(x, ref, u_ref, t0)
        return self._call_osqp(x, ref, u_ref, t0)

    # ============================================================= describe
    def describe(self) -> str:
        """A human-readable summary: sizes, bounds, terminal cost and OSQP settings."""
        nnzP, nnzA = self._P.nnz, self._A.nnz
        dt = "" if self.dt is None else f", dt = {self.dt:g} s"
        lines = [
            f"LinearMPC: n = {self.n} states, m = {self.m} inputs, horizon N = {self.N}{dt}",
            f"backend: {self.solver} (solver = '{self.options.solver}')"
            + (f"; {self.dense.describe()}" if self.dense is not None else ""),
            f"QP: {self.n_var} variables, {self.n_con} constraints, nnz(P) = {nnzP}, nnz(A) = {nnzA}",
            "constraint groups: "
            + ", ".join(f"{g.name} [{g.start}:{g.stop}] ({g.width} x {g.stages} stages)" for g in self._group_list),
            f"operating point: x0 = {_fmt(self.x0)}, u0 = {_fmt(self.u0)}",
            f"input bounds: u_min = {_fmt(self.u_min)}, u_max = {_fmt(self.u_max)}",
            f"state bounds ({'soft' if self.soft else 'hard'}): x_min = {_fmt(self.x_min)}, x_max = {_fmt(self.x_max)}",
        ]
        if self.soft:
            lines.append(f"soft weights: l1 = {self.soft_weight_l1:g}, quad = {self.soft_weight_quad:g}")
        if self.du_max is not None:
            lines.append(f"rate bounds: du_max = {_fmt(self.du_max)}")
        lines.append(f"terminal cost ({self.terminal_cost}):")
        lines.append(np.array2string(self.P_f, precision=4, max_line_width=110))
        if self.K is not None:
            lines.append(f"LQR gain K = {_fmt(self.K)}")
        lines.append(f"fallback: {self.fallback}")
        lines.append("OSQP settings: " + ", ".join(f"{k}={v}" for k, v in sorted(self.osqp_settings.items())))
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (
            f"LinearMPC(n={self.n}, m={self.m}, horizon={self.N}, soft={self.soft}, "
            f"n_var={self.n_var}, n_con={self.n_con})"
        )
