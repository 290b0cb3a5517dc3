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

``P`` and ``A_con`` are built once as CSC matrices and handed to one OSQP
object. A call writes the measured state into the initial-state rows of
``l``/``u`` (and the previous input into the first rate rows), rewrites ``q``
only when the reference changes, warm-starts primal and dual variables from
the previous solution shifted by one stage, and solves.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp

from shinro_ctrl.controllers._osqp import setup_solver
from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.errors import InvalidArgument, MPCInfeasible, NonFiniteError, NotStabilizable
from shinro_ctrl.linearization import discretize
from shinro_ctrl.validation import (
    as_vector,
    bound_pair,
    bound_vector,
    check_positive,
    closest,
    state_space,
    unknown_keys,
)

__all__ = ["QP", "LinearMPC", "MPCSolution", "RowGroup"]

_INF = 1e30  # OSQP_INFTY: what OSQP treats as an absent bound

#: Defaults tuned for closed-loop control of the cart-pole benchmark (see
#: API-NOTES and benchmarks/mpc.py). eps <= 1e-4 keeps the first move within
#: ~1 % of the exact optimum; check_termination 5 avoids paying for 25
#: iterations when 5-10 suffice warm; under-relaxation alpha = 1.3 (OSQP's
#: default 1.6) halved the warm-started iteration count (median 20 -> 10 at
#: N = 50); the duality-gap test (check_dualgap) made active-bound solves
#: crawl into the iteration limit; max_iter 10000 leaves room for cold solves
#: with active soft bounds (up to ~3000 iterations measured). Every key can be
#: overridden with ``osqp_settings``.
DEFAULT_OSQP_SETTINGS: dict[str, Any] = {
    "eps_abs": 1e-4,
    "eps_rel": 1e-4,
    "warm_starting": True,
    "polishing": False,
    "check_termination": 5,
    "check_dualgap": False,
    "alpha": 1.3,
    "adaptive_rho": True,
    "scaling": 10,
    "max_iter": 10000,
    "verbose": False,
}

_SOLVED = "solved"

#: Largest QP :class:`LinearMPC` builds: decision variables, and nonzeros of
#: ``P`` and ``A_con`` together. Two million nonzeros already take OSQP about
#: a gigabyte (factorization fill-in included) and seconds per solve; a
#: horizon beyond this is almost always a typo (``10**8`` used to exhaust
#: the memory and get the process killed).
MAX_QP_SIZE = 2_000_000


class QP(NamedTuple):
    """The QP ``min ½ zᵀ P z + qᵀ z  s.t.  l ≤ A z ≤ u`` in OSQP's form.

    Attributes:
        P: Upper-triangular cost Hessian, CSC ``(n_var, n_var)``.
        q: Linear cost ``(n_var,)``.
        A: Constraint matrix, CSC ``(n_con, n_var)``.
        l: Lower bounds ``(n_con,)`` (±1e30 stands for ±inf).
        u: Upper bounds ``(n_con,)``.
    """

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    l: np.ndarray
    u: np.ndarray


@dataclass(frozen=True)
class RowGroup:
    """A block of constraint rows with the same meaning at consecutive stages.

    Rows ``start + (k - first_stage) * width + j`` hold component ``labels[j]``
    of the group at stage ``k``.

    Attributes:
        name: ``"initial state"``, ``"dynamics"``, ``"input bounds"``,
            ``"rate bounds"``, ``"state bounds"`` or ``"slack bounds"``.
        start: First row.
        width: Rows per stage.
        first_stage: Stage of the first block.
        stages: Number of stages.
        labels: Description of each row within a stage (length ``width``).
    """

    name: str
    start: int
    width: int
    first_stage: int
    stages: int
    labels: tuple[str, ...]

    @property
    def stop(self) -> int:
        """One past the last row."""
        return self.start + self.width * self.stages

    def locate(self, row: int) -> tuple[int, str]:
        """The ``(stage, label)`` of a row inside this group."""
        k, j = divmod(row - self.start, self.width)
        return self.first_stage + k, self.labels[j]


@dataclass(frozen=True)
class MPCSolution:
    """The outcome of one :class:`LinearMPC` call.

    Attributes:
        status: OSQP's status string (``"solved"``, ``"primal infeasible"``, …).
        iterations: ADMM iterations.
        solve_time_s: Wall time of the whole call [s], Python work included.
        osqp_solve_time_s: OSQP's own solve time [s].
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


def _valid_osqp_settings() -> tuple[str, ...]:
    ext = osqp.OSQP().ext
    names = {k for k in ext.OSQPSettings.__dict__ if not k.startswith("_")}
    names -= {"linsys_solver", "cg_precond"}  # set through the two aliases below
    return tuple(sorted(names | {"solver_type", "cg_preconditioner"}))


def _square(name: str, value: Any, size: int) -> np.ndarray:
    """A ``(size, size)`` float matrix; a 1-D array of length ``size`` is a diagonal."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be a numeric ({size}, {size}) matrix, got {value!r}") from None
    if arr.ndim == 0 and size == 1:
        arr = arr.reshape(1, 1)
    elif arr.ndim == 1 and arr.shape == (size,):
        arr = np.diag(arr)
    if arr.shape != (size, size):
        raise InvalidArgument(f"{name}: expected ({size}, {size}) but found {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} must be finite")
    return arr


def _symmetric(name: str, M: np.ndarray, *, definite: bool, rtol: float = 1e-9) -> np.ndarray:
    """Check symmetry and semi-/definiteness with tolerances relative to ``M``'s scale."""
    scale = float(np.max(np.abs(M), initial=0.0))
    asym = float(np.max(np.abs(M - M.T), initial=0.0))
    if asym > rtol * max(scale, np.finfo(float).tiny):
        raise InvalidArgument(f"{name} must be symmetric; max |{name} - {name}ᵀ| = {asym:.3g} (scale {scale:.3g})")
    M = 0.5 * (M + M.T)
    eig = np.linalg.eigvalsh(M) if M.size else np.zeros(0)
    lo = float(eig.min()) if eig.size else 0.0
    if definite:
        if not eig.size or lo <= rtol * max(scale, np.finfo(float).tiny):
            raise InvalidArgument(f"{name} must be positive definite; smallest eigenvalue {lo:.3g}")
    elif lo < -rtol * max(scale, np.finfo(float).tiny):
        raise InvalidArgument(f"{name} must be positive semidefinite; smallest eigenvalue {lo:.3g}")
    return M


def _fmt(v: np.ndarray) -> str:
    return np.array2string(np.asarray(v), precision=4, suppress_small=True)


class LinearMPC(Controller):
    r"""Linear MPC on a sparse QP, solved by one warm-started OSQP object.

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

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``, symmetric PSD (a length-``n`` vector
            means a diagonal).
        R: Stage input weight ``(m, m)``, symmetric positive definite.
        horizon: Prediction horizon ``N`` >= 1 (steps).
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
        osqp_settings: Overrides of :data:`DEFAULT_OSQP_SETTINGS`; unknown
            keys raise ``ValueError`` listing the valid ones.
        state_names: Names of the states for messages (default ``x[i]``).
        input_names: Names of the inputs for messages (default ``u[i]``).

    Attributes:
        K: LQR gain ``(m, n)`` of the DARE (None for another terminal cost).
        u_min, u_max, x_min, x_max: The bounds ``(m,)`` / ``(n,)`` in absolute
            units (±inf where unbounded).
        P_f: Terminal cost matrix ``(n, n)``.
        last: :class:`MPCSolution` of the latest call (None before the first).
        groups: The :class:`RowGroup` blocks of ``A_con``, by name.

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

    def __init__(
        self,
        A: Any,
        B: Any,
        Q: Any,
        R: Any,
        horizon: int,
        *,
        x0: Any = None,
        u0: Any = None,
        dt: float | None = None,
        u_min: Any = None,
        u_max: Any = None,
        x_min: Any = None,
        x_max: Any = None,
        du_max: Any = None,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        terminal_cost: str | Any = "dare",
        u_ref: Any = None,
        offset: Any = None,
        fallback: str | None = None,
        osqp_settings: Mapping[str, Any] | None = None,
        state_names: Any = None,
        input_names: Any = None,
    ):
        # ------------------------------------------------------- validation
        A_, B_ = state_space(A, B)
        n, m = B_.shape
        Q_ = _symmetric("Q", _square("Q", Q, n), definite=False)
        R_ = _symmetric("R", _square("R", R, m), definite=True)
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)):
            raise InvalidArgument(f"horizon must be an int >= 1, got {horizon!r}")
        N = int(horizon)
        if N < 1:
            raise InvalidArgument(f"horizon must be >= 1, got {N}")
        self.n, self.m, self.N = n, m, N
        self.state_dim, self.input_dim, self.horizon = n, m, N
        self.preview = N  # a simulation passes reference trajectories of N + 1 samples (see sim.RobotSim.run)
        self.model: Any = None  # the LinearModel when built by from_plant
        self.A, self.B, self.Q, self.R = A_, B_, Q_, R_
        self.x0 = np.zeros(n) if x0 is None else as_vector("x0", x0, n)
        self.u0 = np.zeros(m) if u0 is None else as_vector("u0", u0, m)
        self.offset = np.zeros(n) if offset is None else as_vector("offset", offset, n)
        self.dt = None if dt is None else check_positive("dt", dt)
        self.u_min, self.u_max = bound_pair("u_min", "u_max", u_min, u_max, m)
        self.x_min, self.x_max = bound_pair("x_min", "x_max", x_min, x_max, n)
        if du_max is None:
            self.du_max = None
        else:
            self.du_max = bound_vector("du_max", du_max, m, np.inf)
            if np.any(self.du_max <= 0):
                raise InvalidArgument(f"du_max must be > 0, got {_fmt(self.du_max)}")
        self.soft = bool(soft)
        self.soft_weight_l1 = float(soft_weight_l1)
        self.soft_weight_quad = float(soft_weight_quad)
        if not math.isfinite(self.soft_weight_l1) or self.soft_weight_l1 < 0:
            raise InvalidArgument(f"soft_weight_l1 must be >= 0 and finite, got {soft_weight_l1!r}")
        if not math.isfinite(self.soft_weight_quad) or self.soft_weight_quad <= 0:
            raise InvalidArgument(f"soft_weight_quad must be > 0 and finite, got {soft_weight_quad!r}")
        self.u_ref = None if u_ref is None else as_vector("u_ref", u_ref, m)
        if fallback not in (None, "shift"):
            raise InvalidArgument(f"fallback must be None or 'shift', got {fallback!r}")
        self.fallback = fallback
        self.state_names = self._names("state_names", state_names, n, "x")
        self.input_names = self._names("input_names", input_names, m, "u")
        self._check_size()

        # ----------------------------------------------------- terminal cost
        self.K: np.ndarray | None = None
        if isinstance(terminal_cost, str):
            if terminal_cost == "dare":
                self.P_f = self._dare()
                BtP = B_.T @ self.P_f
                self.K = np.linalg.solve(R_ + BtP @ B_, BtP @ A_)
            elif terminal_cost == "Q":
                self.P_f = Q_.copy()
            else:
                raise InvalidArgument(f"terminal_cost must be 'dare', 'Q' or an (n, n) matrix, got {terminal_cost!r}")
            self.terminal_cost = terminal_cost
        else:
            self.P_f = _symmetric("terminal_cost", _square("terminal_cost", terminal_cost, n), definite=False)
            self.terminal_cost = "matrix"

        # ---------------------------------------------------------- settings
        settings = dict(DEFAULT_OSQP_SETTINGS)
        if osqp_settings:
            valid = _valid_osqp_settings()
            bad = unknown_keys(osqp_settings, valid)
            if bad:
                close = closest(bad[0], valid)
                near = f" (did you mean '{close}'?)" if close else ""
                raise InvalidArgument(f"unknown OSQP setting '{bad[0]}'{near}; valid settings: {', '.join(valid)}")
            settings.update(osqp_settings)
        self.osqp_settings = settings
        self._warm = bool(settings["warm_starting"])

        # ------------------------------------------------------------- build
        self._build_structure()
        self._setup_solver()
        self._solved_since_setup = False
        self.reset()

    def _setup_solver(self) -> None:
        """Create and set up the OSQP object (once; again only when :meth:`reset` needs a clean solver)."""
        settings = self.osqp_settings
        self._solver = osqp.OSQP()
        setup_solver(
            self._solver, "MPC problem or its osqp_settings", self._P, self._q, self._A, self._l, self._u, **settings
        )
        low = getattr(self._solver, "_solver", None)
        needed = ("update_data_vec", "warm_start", "solve", "info", "solution")
        self._low = low if low is not None and all(hasattr(low, a) for a in needed) else None

    # ================================================================ set-up
    def _qp_size(self) -> tuple[int, int]:
        """``(decision variables, nonzeros of P and A_con)`` of the QP :meth:`_build_structure` makes.

        Exact for the variables; for the nonzeros an upper bound (the terminal
        cost counted dense), computed with Python integers (no overflow).
        """
        n, m, N = self.n, self.m, self.N
        w = int(np.count_nonzero(np.isfinite(self.x_min) | np.isfinite(self.x_max)))
        mu = int(np.count_nonzero(np.isfinite(self.u_min) | np.isfinite(self.u_max)))
        r = 0 if self.du_max is None else int(np.count_nonzero(np.isfinite(self.du_max)))
        ns = N * w if self.soft else 0
        nvar = (N + 1) * n + N * m + ns
        nz_Q, nz_R = (int(np.count_nonzero(np.triu(M))) for M in (self.Q, self.R))
        nz_A, nz_B = int(np.count_nonzero(self.A)), int(np.count_nonzero(self.B))
        nnz_P = N * nz_Q + n * (n + 1) // 2 + N * nz_R + ns
        nnz_A = n + N * (nz_A + n + nz_B) + N * mu + (2 * N - 1) * r + (N * 4 * w + ns if self.soft else N * w)
        return nvar, nnz_P + nnz_A

    def _check_size(self) -> None:
        nvar, nnz = self._qp_size()
        if nvar > MAX_QP_SIZE or nnz > MAX_QP_SIZE:
            raise InvalidArgument(
                f"horizon {self.N:,} makes an MPC QP too large to build: {nvar:,} decision variables and up to "
                f"{nnz:,} nonzeros (n = {self.n} states, m = {self.m} inputs); the limit is {MAX_QP_SIZE:,} of "
                "each. Use a shorter horizon (or a larger dt for the same preview time)"
            )

    @staticmethod
    def _names(arg: str, names: Any, size: int, prefix: str) -> tuple[str, ...]:
        if names is None:
            return tuple(f"{prefix}[{i}]" for i in range(size))
        names = tuple(str(s) for s in names)
        if len(names) != size:
            raise InvalidArgument(f"{arg}: expected {size} names but found {len(names)}")
        return names

    def _dare(self) -> np.ndarray:
        try:
            P = scipy.linalg.solve_discrete_are(self.A, self.B, self.Q, self.R)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise NotStabilizable(
                f"no stabilizing DARE solution for the terminal cost ({exc}); (A, B) must be stabilizable "
                "and (A, Q) detectable, or pass terminal_cost='Q' or a matrix"
            ) from exc
        if not np.all(np.isfinite(P)):
            raise NotStabilizable("the DARE solution for the terminal cost is not finite")
        return 0.5 * (P + P.T)

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
        u_min: Any = None,
        u_max: Any = None,
        x_min: Any = None,
        x_max: Any = None,
        du_max: Any = None,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        terminal_cost: str | Any = "dare",
        u_ref: Any = None,
        fallback: str | None = None,
        osqp_settings: Mapping[str, Any] | None = None,
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
            u_min, u_max, x_min, x_max, du_max, soft, soft_weight_l1,
            soft_weight_quad, terminal_cost, u_ref, fallback, osqp_settings:
                As for :class:`LinearMPC`.

        The affine term ``d`` is the drift ``f(x0, u0)`` discretized the same
        way as ``B`` (zero at an equilibrium). The returned controller keeps
        the :class:`~shinro_ctrl.linearization.LinearModel` as ``model``.
        """
        lm = plant.linear_model(x0, u0, method=method, discretization=discretization)
        drift = np.asarray(plant.dynamics(lm.x0, lm.u0), dtype=float)
        offset = None
        if np.any(drift != 0.0):
            offset = discretize(lm.A_c, drift.reshape(-1, 1), lm.dt, discretization)[1][:, 0]
        ctrl = cls(
            lm.A,
            lm.B,
            Q,
            R,
            horizon,
            x0=lm.x0,
            u0=lm.u0,
            dt=lm.dt,
            u_min=u_min,
            u_max=u_max,
            x_min=x_min,
            x_max=x_max,
            du_max=du_max,
            soft=soft,
            soft_weight_l1=soft_weight_l1,
            soft_weight_quad=soft_weight_quad,
            terminal_cost=terminal_cost,
            u_ref=u_ref,
            offset=offset,
            fallback=fallback,
            osqp_settings=osqp_settings,
            state_names=plant.state_names,
            input_names=plant.input_names,
        )
        ctrl.model = lm
        return ctrl

    def _build_structure(self) -> None:
        """Assemble P, A_con, q, l, u and the index maps (once)."""
        n, m, N = self.n, self.m, self.N
        nx, nu = (N + 1) * n, N * m
        self._ix = slice(0, nx)
        self._iu = slice(nx, nx + nu)
        xb = np.isfinite(self.x_min) | np.isfinite(self.x_max)  # bounded state components
        ub = np.isfinite(self.u_min) | np.isfinite(self.u_max)
        self._xb_idx = np.flatnonzero(xb)
        self._ub_idx = np.flatnonzero(ub)
        nsb = self._xb_idx.size if self.soft else 0
        ns = N * nsb
        self._is = slice(nx + nu, nx + nu + ns)
        self._has_slack = ns > 0
        nvar = nx + nu + ns
        self.n_var = nvar

        # ---- cost: block diagonal, upper triangle
        Ts = _Triplets()
        Ts.blocks(self.Q, 0, 0, N, n, n)
        Ts.blocks(self.P_f, N * n, N * n, 1, 0, 0)
        Ts.blocks(self.R, nx, nx, N, m, m)
        if ns:
            Ts.blocks(np.array([[self.soft_weight_quad]]), nx + nu, nx + nu, ns, 1, 1)
        self._P = Ts.csc((nvar, nvar), upper=True)
        q = np.zeros(nvar)
        q[self._is] = self.soft_weight_l1
        self._q_default = q.copy()
        self._q = q

        # ---- constraints: one block of rows per group, stage-major inside each
        T = _Triplets()
        lo: list[np.ndarray] = []
        hi: list[np.ndarray] = []
        groups: list[RowGroup] = []
        r0 = 0

        def add(name: str, l: np.ndarray, u: np.ndarray, width: int, first: int, labels: Any) -> None:
            nonlocal r0
            lo.append(l)
            hi.append(u)
            groups.append(RowGroup(name, r0, width, first, l.size // width, tuple(labels)))
            r0 += l.size

        In = np.eye(n)
        # initial state: δx_0 = x - x0
        T.blocks(In, 0, 0, 1, 0, 0)
        add("initial state", np.zeros(n), np.zeros(n), n, 0, self.state_names)
        # dynamics, stage k + 1: A δx_k + B δu_k - δx_{k+1} = -d
        T.blocks(self.A, r0, 0, N, n, n)
        T.blocks(-In, r0, n, N, n, n)
        T.blocks(self.B, r0, nx, N, n, m)
        d = np.tile(-self.offset, N)
        add("dynamics", d, d.copy(), n, 1, self.state_names)
        # input bounds on u_0 … u_{N-1}
        ui = self._ub_idx
        if ui.size:
            S = np.eye(m)[ui]
            T.blocks(S, r0, nx, N, ui.size, m)
            labels = [f"{self.input_names[i]} in [{self.u_min[i]:g}, {self.u_max[i]:g}]" for i in ui]
            add(
                "input bounds",
                np.tile(self.u_min[ui] - self.u0[ui], N),
                np.tile(self.u_max[ui] - self.u0[ui], N),
                ui.size,
                0,
                labels,
            )
        # rate bounds: δu_k - δu_{k-1}; stage 0 uses the previously applied input (in l/u)
        self._rate_idx = np.zeros(0, dtype=int)
        if self.du_max is not None:
            ri = np.flatnonzero(np.isfinite(self.du_max))
            self._rate_idx = ri
            if ri.size:
                S = np.eye(m)[ri]
                T.blocks(S, r0, nx, N, ri.size, m)
                T.blocks(-S, r0 + ri.size, nx, N - 1, ri.size, m)
                dm = np.tile(self.du_max[ri], N)
                lb, ubv = -dm, dm.copy()
                lb[: ri.size], ubv[: ri.size] = -_INF, _INF  # no previous input yet
                labels = [f"|Δ{self.input_names[i]}| <= {self.du_max[i]:g}" for i in ri]
                add("rate bounds", lb, ubv, ri.size, 0, labels)
        # state bounds on x_1 … x_N (the measured x_0 is never bounded)
        xi = self._xb_idx
        if xi.size:
            w = xi.size
            S = np.eye(n)[xi]
            xlo = self.x_min[xi] - self.x0[xi]
            xhi = self.x_max[xi] - self.x0[xi]
            if not self.soft:
                T.blocks(S, r0, n, N, w, n)
                labels = [f"{self.state_names[i]} in [{self.x_min[i]:g}, {self.x_max[i]:g}]" for i in xi]
                add("state bounds", np.tile(xlo, N), np.tile(xhi, N), w, 1, labels)
            else:
                # per stage: w rows δx - s <= hi, then w rows δx + s >= lo
                s0 = nx + nu
                Iw = np.eye(w)
                T.blocks(S, r0, n, N, 2 * w, n)
                T.blocks(-Iw, r0, s0, N, 2 * w, w)
                T.blocks(S, r0 + w, n, N, 2 * w, n)
                T.blocks(Iw, r0 + w, s0, N, 2 * w, w)
                lb = np.concatenate([np.full((N, w), -_INF), np.tile(xlo, (N, 1))], axis=1).ravel()
                ubv = np.concatenate([np.tile(xhi, (N, 1)), np.full((N, w), _INF)], axis=1).ravel()
                lab_hi = [f"{self.state_names[i]} <= {self.x_max[i]:g}" for i in xi]
                lab_lo = [f"{self.state_names[i]} >= {self.x_min[i]:g}" for i in xi]
                add("state bounds", lb, ubv, 2 * w, 1, lab_hi + lab_lo)
                T.blocks(Iw, r0, s0, N, w, w)
                slack_labels = [f"slack {self.state_names[i]}" for i in xi]
                add("slack bounds", np.zeros(ns), np.full(ns, _INF), w, 1, slack_labels)
        self._A = T.csc((r0, nvar))
        self._l = np.clip(np.concatenate(lo), -_INF, _INF)
        self._u = np.clip(np.concatenate(hi), -_INF, _INF)
        self.n_con = self._A.shape[0]
        self.groups: dict[str, RowGroup] = {g.name: g for g in groups}
        self._group_list = groups
        self._rate0 = None
        if "rate bounds" in self.groups:
            g = self.groups["rate bounds"]
            self._rate0 = slice(g.start, g.start + g.width)

        # ---- warm-start shift maps: stage k takes stage k+1, the last stage repeats
        def shifted(start: int, width: int, stages: int) -> np.ndarray:
            k = np.minimum(np.arange(stages) + 1, stages - 1)
            return (start + width * k[:, None] + np.arange(width)[None, :]).ravel()

        self._zshift = np.concatenate(
            [
                shifted(0, n, N + 1),
                shifted(nx, m, N),
                shifted(nx + nu, nsb, N) if ns else np.zeros(0, dtype=int),
            ]
        ).astype(np.intp)
        yparts = []
        for g in groups:
            if g.name == "initial state":
                # the initial-state multiplier takes the first dynamics block's
                dyn = self.groups["dynamics"]
                yparts.append(np.arange(dyn.start, dyn.start + n))
            else:
                yparts.append(shifted(g.start, g.width, g.stages))
        self._yshift = np.concatenate(yparts).astype(np.intp)

        # ---- reusable buffers
        self._zws = np.zeros(nvar)
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
        if self._solved_since_setup:
            # OSQP keeps internal state between solves (adaptive rho and its factorization), so a
            # reset controller must start from a fresh solver to repeat a run exactly.
            self._setup_solver()
            self._solved_since_setup = False

    def __call__(self, x: Any, ref: Any = None, *, u_ref: Any = None) -> np.ndarray:
        """Solve the MPC problem at state ``x`` and return the first input.

        Args:
            x: Measured state ``(n,)`` [absolute units].
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
        t0 = time.perf_counter()
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n,):
            x = as_vector("x", x, self.n)  # raises with the standard message
        elif not np.isfinite(x).all():
            raise NonFiniteError(f"x must be finite, got {_fmt(x)}")
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
        low = self._low
        self._solved_since_setup = True
        if low is not None:
            # Direct calls into OSQP's compiled solver (the public wrapper costs ~40 µs per call in
            # argument clamping and result packing). Our l/u already hold ±1e30, never ±inf.
            if low.update_data_vec(q, self._l, self._u) != 0:  # pragma: no cover - sizes are fixed
                raise RuntimeError("OSQP rejected the vector update")
            if self._warm:
                low.warm_start(self._zws, self._yws)
            low.solve()
            info = low.info
            sol = low.solution
        else:
            solver = self._solver
            if q is None:
                solver.update(l=self._l, u=self._u)
            else:
                solver.update(q=q, l=self._l, u=self._u)
            if self._warm:
                solver.warm_start(x=self._zws, y=self._yws)
            sol = solver.solve(raise_error=False)
            info = sol.info
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
            info.iter,
            time.perf_counter() - t0,
            info.solve_time,
            info.obj_val + self._q_const,
            states,
            inputs,
            u_out,
            False,
            "",
            float(z[self._is].max()) if self._has_slack else 0.0,
        )
        return u_out

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

    def _failed(self, x: np.ndarray, info: Any, sol: Any, t0: float) -> np.ndarray:
        message = self._diagnose(x, info, sol)
        # the next attempt starts from the shifted warm start, not the failed iterate
        self._shift_warm_start(self._zws.copy(), self._yws.copy())
        age = self._plan_age + 1
        if self.fallback != "shift" or self._plan_u is None or age >= self.N:
            if self.fallback == "shift":
                message += (
                    "; fallback 'shift' has no previous plan"
                    if self._plan_u is None
                    else f"; fallback 'shift' exhausted the previous plan ({self.N} steps)"
                )
            self.last = MPCSolution(
                info.status,
                info.iter,
                time.perf_counter() - t0,
                info.solve_time,
                math.nan,
                np.full((self.N + 1, self.n), np.nan),
                np.full((self.N, self.m), np.nan),
                np.full(self.m, np.nan),
                False,
                message,
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
            info.status,
            info.iter,
            time.perf_counter() - t0,
            info.solve_time,
            math.nan,
            self._plan_x[idx],
            self._plan_u[np.minimum(idx[:-1], self.N - 1)],
            u_out,
            True,
            message,
        )
        return u_out

    def _diagnose(self, x: np.ndarray, info: Any, sol: Any) -> str:
        """Name the constraint group and stage behind a failed solve."""
        status = info.status
        head = f"MPC problem infeasible (OSQP status '{status}', {info.iter} iterations) at x = {_fmt(x)}"
        cert = np.asarray(sol.prim_inf_cert, dtype=float)
        if "primal infeasible" in status and cert.size and np.all(np.isfinite(cert)) and np.any(cert != 0):
            return head + ": " + self._explain_certificate(cert)
        if "dual infeasible" in status:
            return head + ": the cost is unbounded below (dual infeasible); check Q, R and the terminal cost"
        z = np.asarray(sol.x, dtype=float)
        if z.size and np.all(np.isfinite(z)):
            Az = self._A @ z
            viol = np.maximum(self._l - Az, 0.0) + np.maximum(Az - self._u, 0.0)
            row = int(np.argmax(viol))
            g = self._group_of(row)
            k, label = g.locate(row)
            return (
                head + f": largest violation of the last iterate is {viol[row]:.3g} in the {g.name} at stage {k} "
                f"({label}); the problem is likely infeasible or too hard within the iteration/time limit"
            )
        return head + ": OSQP returned no usable iterate"

    def _group_of(self, row: int) -> RowGroup:
        for g in self._group_list:
            if g.start <= row < g.stop:
                return g
        raise IndexError(row)  # pragma: no cover - rows always belong to a group

    def _explain_certificate(self, cert: np.ndarray) -> str:
        """Turn OSQP's primal infeasibility certificate into a sentence.

        The certificate ``δy`` (``Aᵀ δy = 0``, ``uᵀ δy₊ + lᵀ δy₋ < 0``) is
        nonzero on the rows that together cannot hold. Its entries spread
        over later stages, so the stage named is the *first* one where the
        culprit group (state, then rate, then input bounds) enters the
        certificate: the first stage that cannot be met.
        """
        peak = float(np.max(np.abs(cert)))
        involved: dict[str, list[int]] = {}
        first: dict[str, int] = {}
        for g in self._group_list:
            seg = np.abs(cert[g.start : g.stop])
            gmax = float(seg.max(initial=0.0))
            if gmax <= 1e-9 * peak:
                continue
            hits = np.flatnonzero(seg > 1e-3 * gmax)
            involved[g.name] = sorted({g.first_stage + int(h) // g.width for h in hits})
            first[g.name] = g.start + int(hits[0])
        culprit = next((name for name in ("state bounds", "rate bounds", "input bounds") if name in first), None)
        if culprit is None:  # pragma: no cover - equalities alone are always feasible
            return "the certificate involves only the dynamics (" + ", ".join(involved) + ")"
        k, label = self.groups[culprit].locate(first[culprit])
        others = [
            f"{name} at stages {_stages(s)}"
            for name, s in involved.items()
            if name not in (culprit, "initial state", "dynamics")
        ]
        return (
            f"{culprit} at stage {k} ({label}) cannot be met from this state under the dynamics"
            f" (conflict over stages {_stages(involved[culprit])})"
            + (" together with the " + "; ".join(others) if others else "")
        )

    # ============================================================= describe
    def describe(self) -> str:
        """A human-readable summary: sizes, bounds, terminal cost and OSQP settings."""
        nnzP, nnzA = self._P.nnz, self._A.nnz
        dt = "" if self.dt is None else f", dt = {self.dt:g} s"
        lines = [
            f"LinearMPC: n = {self.n} states, m = {self.m} inputs, horizon N = {self.N}{dt}",
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


class _Triplets:
    """COO triplets of a sparse matrix assembled from repeated dense blocks."""

    def __init__(self) -> None:
        self.r: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.v: list[np.ndarray] = []

    def blocks(self, M: np.ndarray, row0: int, col0: int, count: int, row_step: int, col_step: int) -> None:
        """Place the nonzeros of ``M`` at ``(row0 + i·row_step, col0 + i·col_step)``, i < count."""
        if count <= 0:
            return
        r, c = np.nonzero(M)
        k = np.arange(count)[:, None]
        self.r.append((row0 + k * row_step + r).ravel())
        self.c.append((col0 + k * col_step + c).ravel())
        self.v.append(np.broadcast_to(M[r, c], (count, r.size)).ravel())

    def csc(self, shape: tuple[int, int], *, upper: bool = False) -> sp.csc_matrix:
        """The CSC matrix (duplicates summed, indices sorted); ``upper`` keeps ``r <= c``."""
        r = np.concatenate(self.r) if self.r else np.zeros(0, dtype=int)
        c = np.concatenate(self.c) if self.c else np.zeros(0, dtype=int)
        v = np.concatenate(self.v) if self.v else np.zeros(0)
        if upper:
            keep = r <= c
            r, c, v = r[keep], c[keep], v[keep]
        M = sp.csc_matrix((v, (r, c)), shape=shape)
        M.sum_duplicates()
        M.sort_indices()
        return M


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or equal arrays of the same shape."""
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and bool(np.array_equal(a, b))


def _stages(stages: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    out: list[str] = []
    start = prev = stages[0]
    for s in [*stages[1:], None]:
        if s is not None and s == prev + 1:
            prev = s
            continue
        out.append(f"{start}" if start == prev else f"{start}-{prev}")
        if s is not None:
            start = prev = s
    return ", ".join(out)
