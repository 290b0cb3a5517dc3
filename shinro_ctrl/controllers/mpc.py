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

from shinro_ctrl.controllers._osqp import OsqpQP
from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.lqr import riccati
from shinro_ctrl.controllers.offset_free import offset_free_call
from shinro_ctrl.controllers.qp.condensed import MAX_DENSE_SIZE, CondensedQP, DenseSolveInfo, condensed_size
from shinro_ctrl.controllers.qp.diagnose import diagnose, fmt
from shinro_ctrl.controllers.qp.options import DEFAULT_OSQP_SETTINGS, PLANT_GIVEN, MPCOptions
from shinro_ctrl.controllers.qp.sparse import INF as _INF
from shinro_ctrl.controllers.qp.sparse import MAX_QP_SIZE, QP, RowGroup, build_sparse, qp_size
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError
from shinro_ctrl.linearization import discretize
from shinro_ctrl.validation import as_vector, state_space, weight_matrix

__all__ = [
    "DEFAULT_OSQP_SETTINGS",
    "MAX_QP_SIZE",
    "QP",
    "LinearMPC",
    "MPCOptions",
    "MPCSolution",
    "RowGroup",
    "choose_solver",
]

_SOLVED = "solved"
_fmt = fmt

#: ``solver="auto"`` uses DAQP while the condensed QP has at most this many
#: variables ``N·m`` plus slacks (and fits :data:`~.qp.condensed.MAX_DENSE_SIZE`).
#: Measured with ``benchmarks/mpc.py --crossover`` (median call, warm closed
#: loop, both backends exact): see :func:`choose_solver`.
AUTO_DAQP_MAX_VARIABLES = 250

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


def choose_solver(n: int, m: int, N: int, opts: MPCOptions) -> str:
    """The backend ``solver="auto"`` picks for a resolved :class:`MPCOptions`.

    A warm DAQP call on the condensed QP costs about ``O(nz·(nz + rows))``
    (``nz = N·m`` inputs plus one slack per soft-bounded state and stage) and
    its build ``O(N³)``; an OSQP call on the sparse QP ``O(N (n + m)²)`` per
    ADMM iteration plus the polish. Measured (``benchmarks/mpc.py
    --crossover``, median call, warm closed loop, both exact): DAQP is 2-5x
    faster up to ``nz`` ≈ 200 (cart-pole ``N = 200``: 0.24 vs 0.53 ms;
    quadrotor with soft bounds ``N = 30``, ``nz = 180``: 0.11 vs 0.28 ms),
    level with OSQP near ``nz`` = 400 on the cart-pole and already 1.6x slower
    at ``nz = 360`` on the soft-bounded quadrotor (``N = 60``). Rule:
    ``"daqp"`` when ``nz <= AUTO_DAQP_MAX_VARIABLES`` (250) and the dense
    matrices fit :data:`~.qp.condensed.MAX_DENSE_SIZE`, else ``"osqp"``.

    Args:
        n: States.
        m: Inputs.
        N: Horizon.
        opts: The resolved options (bounds decide slacks and dense rows).
    """
    if opts.solver != "auto":
        return opts.solver
    soft_rows = int(np.count_nonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max))) if opts.soft else 0
    nz = N * (m + soft_rows)
    return "daqp" if nz <= AUTO_DAQP_MAX_VARIABLES and _dense_size(n, m, N, opts) <= MAX_DENSE_SIZE else "osqp"


def _dense_size(n: int, m: int, N: int, opts: MPCOptions) -> int:
    bounded = np.isfinite
    return condensed_size(
        n,
        m,
        N,
        u_rows=int(np.count_nonzero(bounded(opts.u_min) | bounded(opts.u_max))),
        rate_rows=0 if opts.du_max is None else int(np.count_nonzero(bounded(opts.du_max))),
        x_rows=int(np.count_nonzero(bounded(opts.x_min) | bounded(opts.x_max))),
        soft=bool(opts.soft),
    )


@dataclasses.dataclass(frozen=True)
class MPCSolution:
    """The outcome of one :class:`LinearMPC` call.

    Attributes:
        status: The backend's status (OSQP's string, ``"solved"``,
            ``"primal infeasible"``, …, or DAQP's exit flag name).
        iterations: ADMM iterations (OSQP, re-solve included) or active-set
            iterations (DAQP).
        solve_time_s: Wall time of the whole call [s], Python work included.
        osqp_solve_time_s: The QP solver's own solve time [s] (OSQP's or
            DAQP's; the name predates the DAQP backend).
        objective: Value of the MPC cost (constant reference terms included);
            NaN when the solve failed.
        states: Predicted states ``(N + 1, n)`` in absolute units.
        inputs: Planned inputs ``(N, m)`` in absolute units (before clipping).
        u: The input returned by the call ``(m,)`` (clipped to its hard bounds).
        fallback_used: True when the solve failed and the shifted previous plan
            was applied instead (``fallback="shift"``).
        message: Why the solve failed (empty when solved).
        max_slack: Largest slack of the soft state bounds over the horizon,
            i.e. the planned bound violation (0 for hard bounds).
        backend: ``"osqp"`` or ``"daqp"``.
        active_set_size: Inequality constraints active at the solution
            (nonzero multipliers; -1 when not solved).
        kkt_residual: KKT residual of the returned solution: OSQP's
            ``max(prim_res, dual_res)``, or the condensed QP's stationarity,
            feasibility and complementarity residual (NaN when not solved).
    """

    status: str
    iterations: int
    solve_time_s: float
    osqp_solve_time_s: float
    objective: float
    states: np.ndarray
    inputs: np.ndarray
    u: np.ndarray
    fallback_used: bool = False
    message: str = ""
    max_slack: float = 0.0
    backend: str = "osqp"
    active_set_size: int = -1
    kkt_residual: float = math.nan


class LinearMPC(Controller):
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
        self._osqp = OsqpQP(
            "MPC problem or its osqp_settings", self._P, self._q, self._A, self._l, self._u, self.osqp_settings
        )
        self.solver = choose_solver(n, m, N, opts)
        self.dense: CondensedQP | None = self._condensed() if self.solver == "daqp" else None
        self._referee: CondensedQP | None = self.dense  # settles OSQP solves that stay inexact
        self._dense_ref = False  # the condensed QP holds a reference (not the operating point)
        self._solved_since_setup = False
        self.reset()

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
        discretization: str = "euler",
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
            discretization: ``"euler"``, ``"zoh"`` or ``"rk4"``.
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
            offset = discretize(lm.A_c, drift.reshape(-1, 1), lm.dt, discretization)[1][:, 0]
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
        if self._referee is None and _dense_size(self.n, self.m, self.N, self.options) <= MAX_DENSE_SIZE:
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


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or equal arrays of the same shape."""
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and bool(np.array_equal(a, b))
