r"""Time-varying LQR along a planned trajectory, handing over to an LQR at the goal.

Along the reference ``(x_k, u_k) = (x_ref(k dt), u_ref(k dt))``, ``k = 0 … K − 1``
(``K = ⌈T / dt⌉`` steps of the control rate cover the plan), the exact
Jacobians ``A_c,k = ∂f/∂x``, ``B_c,k = ∂f/∂u`` are evaluated in one CasADi
``map`` call over all samples and discretized like every design in the
project (:func:`~shinro_ctrl.linearization.discretize`, ``euler`` by default).
The finite-horizon problem

.. math::

    \min \; \tfrac12 \tilde x_K^T Q_f \tilde x_K + \tfrac12 \sum_{k<K} \tilde x_k^T Q \tilde x_k
    + \tilde u_k^T R \tilde u_k, \qquad \tilde x_{k+1} = A_k \tilde x_k + B_k \tilde u_k

is solved by the backward Riccati recursion ``S_K = Q_f``,

.. math::

    K_k = (R + B_k^T S_{k+1} B_k)^{-1} B_k^T S_{k+1} A_k, \qquad
    S_k = Q + A_k^T S_{k+1} (A_k − B_k K_k),

and the feedback is ``u = u_ref(t_k) − K_k (x − x_ref(t_k))``. From step ``K``
on the controller is the infinite-horizon :class:`~shinro_ctrl.controllers.lqr.LQR`
at the goal, whose cost-to-go ``S`` is the default ``Q_f``: the finite-horizon
cost then equals the infinite-horizon one from the hand-over on.

Time: the closed loop calls the controller once per step of ``dt``, so the
controller keeps a step counter: call ``k`` uses sample ``k``. :meth:`TVLQR.reset`
(which the simulation loop calls before every run) sets it back to 0;
:meth:`TVLQR.at_time` evaluates the law at an explicit time instead.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import casadi as cs
import numpy as np

from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.controllers.base import Controller, default_input_bounds
from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.linearization import MODEL_DISCRETIZATIONS, discretize
from shinro_ctrl.types import Bound, Weight
from shinro_ctrl.validation import as_vector, bound_pair, check_positive, weight_matrix

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.planning import Trajectory
    from shinro_ctrl.plants.base import Plant

__all__ = ["TVLQR", "riccati_backward", "trajectory_jacobians"]


# plant -> {"jac": SX Jacobian Function, K: the MX map over K samples}
_MAPPED: weakref.WeakKeyDictionary[Plant, dict[str | int, cs.Function]] = weakref.WeakKeyDictionary()
_MAPPED_LOCK = threading.Lock()  # the cache is shared by every TVLQR design


def trajectory_jacobians(plant: Plant, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact continuous Jacobians at every sample of a trajectory, in one CasADi ``map`` call.

    The Jacobian Function of ``plant.symbolic()`` (SX) is mapped
    over the ``K`` samples inside an MX Function (mapping on SX would unroll
    it), which is evaluated once. The mapped Function is kept per plant and
    number of samples, so designing again along another plan of the same
    length reuses it.

    Args:
        plant: Any plant.
        x: States ``(K, n)``.
        u: Inputs ``(K, m)``.

    Returns:
        ``(A_c (K, n, n), B_c (K, n, m))``.
    """
    n, m = plant.state_dim, plant.input_dim
    K = x.shape[0]
    with _MAPPED_LOCK:
        mapped = _mapped_jacobian(plant, n, m, K)
    A, B = mapped(np.ascontiguousarray(x.T), np.ascontiguousarray(u.T))
    A = np.asarray(A).reshape(n, K, n).transpose(1, 0, 2)
    B = np.asarray(B).reshape(n, K, m).transpose(1, 0, 2)
    return A, B


def _mapped_jacobian(plant: Plant, n: int, m: int, K: int) -> cs.Function:
    """The cached Jacobian Function of ``plant`` mapped over ``K`` samples (built on first use)."""
    cache = _MAPPED.setdefault(plant, {})
    if K not in cache:
        if "jac" not in cache:
            xs, us = cs.SX.sym("x", n), cs.SX.sym("u", m)
            xdot = plant.symbolic()(xs, us)  # the plant's parameters as constants
            dx, du = cs.densify(cs.jacobian(xdot, xs)), cs.densify(cs.jacobian(xdot, us))
            cache["jac"] = cs.Function("jac_xu", [xs, us], [dx, du])
        Xm, Um = cs.MX.sym("X", n, K), cs.MX.sym("U", m, K)
        A_all, B_all = cache["jac"].map(K)(Xm, Um)
        if len(cache) > 8:  # keep a few horizons per plant
            cache.pop(next(k for k in cache if k != "jac"))
        cache[K] = cs.Function("jac_traj", [Xm, Um], [A_all, B_all])
    return cache[K]


def riccati_backward(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, Qf: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Backward discrete Riccati recursion (see the module doc).

    Args:
        A: ``(K, n, n)``.
        B: ``(K, n, m)``.
        Q: ``(n, n)``.
        R: ``(m, m)``.
        Qf: ``(n, n)`` terminal weight ``S_K``.

    Returns:
        ``(K_gains (K, m, n), S (K + 1, n, n))``.
    """
    K, n, m = B.shape
    gains = np.empty((K, m, n))
    S = np.empty((K + 1, n, n))
    S[K] = Qf
    Sn = S[K]
    for k in range(K - 1, -1, -1):
        Ak, Bk = A[k], B[k]
        SB = Sn @ Bk
        H = R + Bk.T @ SB
        g = SB.T @ Ak
        G = g / H[0, 0] if m == 1 else np.linalg.solve(H, g)  # one input: skip LAPACK's per-call overhead
        gains[k] = G
        Sk = Q + Ak.T @ (Sn @ (Ak - Bk @ G))
        Sn = S[k] = 0.5 * (Sk + Sk.T)
    return gains, S


class TVLQR(Controller):
    """Time-varying LQR tracking a :class:`~shinro_ctrl.planning.Trajectory`, then an LQR at its goal.

    Build it with :meth:`from_trajectory` (a plan in hand) or :meth:`from_plant`
    (plans itself from a ``[plan]`` table).

    Threads: :meth:`at_time` reads only arrays fixed at construction and may be
    called from any number of threads at once. ``__call__`` advances the step
    counter of one run: a call that enters while another thread is inside one
    raises :class:`~shinro_ctrl.errors.ConcurrentUse` (use one controller per
    run and thread).

    Attributes:
        trajectory: The tracked plan.
        dt: Control step [s].
        x_ref: ``(K, n)`` and ``u_ref``: ``(K, m)`` the reference at ``k dt``.
        A, B: ``(K, n, n)``, ``(K, n, m)`` discrete linearizations along the plan.
        K: ``(K, m, n)`` gains; ``S``: ``(K + 1, n, n)`` cost-to-go matrices.
        final: The :class:`LQR` at the goal used from step ``K`` on.
        x0, u0: The goal state and input (the operating point after the hand-over).
        u_min, u_max: Saturation bounds ``(m,)`` (±inf where none).
        step: Index of the next call (reset to 0 by :meth:`reset`).
    """

    def __init__(
        self,
        trajectory: Trajectory,
        A: np.ndarray,
        B: np.ndarray,
        Q: np.ndarray,
        R: np.ndarray,
        final: LQR,
        *,
        dt: float,
        x_ref: np.ndarray,
        u_ref: np.ndarray,
        Qf: np.ndarray,
        u_min: Bound = None,
        u_max: Bound = None,
        difference: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    ):
        self.trajectory = trajectory
        self._difference = difference  # a floating base: deviations x ⊖ x_ref(t) in the tangent space
        self.dt = dt
        self.A, self.B, self.Q, self.R, self.Qf = A, B, Q, R, Qf
        self.x_ref, self.u_ref = x_ref, u_ref
        self.K, self.S = riccati_backward(A, B, Q, R, Qf)
        self.final = final
        self.x0, self.u0 = final.x0, final.u0
        self.state_dim, self.input_dim = x_ref.shape[1], u_ref.shape[1]
        self.u_min, self.u_max = bound_pair("u_min", "u_max", u_min, u_max, self.input_dim)
        self._saturate = bool(np.any(np.isfinite(self.u_min)) or np.any(np.isfinite(self.u_max)))
        self.horizon = x_ref.shape[0]
        self.step = 0
        self._busy = CallGuard("TVLQR")

    @classmethod
    def from_trajectory(
        cls,
        plant: Plant,
        traj: Trajectory,
        Q: Weight,
        R: Weight,
        *,
        terminal_cost: str | Weight = "lqr",
        dt: float | None = None,
        discretization: str = "step",
        u_min: Bound = None,
        u_max: Bound = None,
    ) -> TVLQR:
        """Design along ``traj`` at the control rate.

        Args:
            plant: The plant (its exact dynamics are linearized).
            traj: A :class:`~shinro_ctrl.planning.Trajectory` (``x_at``, ``u_at``, ``duration``).
            Q: ``(n, n)`` or diagonal ``(n,)`` state weight.
            R: ``(m, m)`` or diagonal ``(m,)`` input weight.
            terminal_cost: Terminal weight ``Q_f`` of the recursion: ``"lqr"`` (default:
                the goal LQR's cost-to-go ``S``), ``"Q"`` (the stage weight) or a matrix
                ``(n, n)`` (or its diagonal).
            dt: Control step [s]; default ``plant.dt``.
            discretization: ``step`` (default, as LQR: the exact Jacobians of the plant's own
                discrete step at each knot; needs ``dt == plant.dt``), ``euler``, ``zoh`` or ``rk4``.
            u_min, u_max: Optional saturation ``(m,)``; a side left None takes ``plant.input_bounds()``.

        Raises:
            InvalidArgument: wrong shapes or values.
            NotStabilizable: the goal's linearization cannot be stabilized.
        """
        n, m = plant.state_dim, plant.input_dim
        if traj.state_dim != n or traj.input_dim != m:
            raise InvalidArgument(
                f"traj: expected a trajectory with {n} states and {m} inputs but found "
                f"{traj.state_dim} and {traj.input_dim}"
            )
        dt = plant.dt if dt is None else check_positive("dt", dt)
        if discretization not in MODEL_DISCRETIZATIONS:
            raise InvalidArgument(
                f"unknown discretization {discretization!r}; valid: {', '.join(MODEL_DISCRETIZATIONS)}"
            )
        if discretization == "step" and dt != plant.dt:
            raise InvalidArgument(
                f"discretization 'step' is the plant's own step at dt = {plant.dt:g} s, not dt = {dt:g} s; "
                "use discretization 'zoh' or 'rk4' for another control rate"
            )
        u_min, u_max = default_input_bounds(plant, u_min, u_max)
        nt = plant.tangent_dim  # the deviations' dimension (n but on a floating base)
        Qm = weight_matrix("Q", Q, nt)
        Rm = weight_matrix("R", R, m, definite=True)
        steps = max(1, int(np.ceil(traj.duration / dt - 1e-9)))
        ts = traj.t[0] + dt * np.arange(steps)
        x_ref, u_ref = traj.x_at(ts), traj.u_at(ts)
        x_goal, u_goal = traj.x[-1].copy(), traj.u[-1].copy()
        final = LQR.from_plant(
            plant, Qm, Rm, x0=x_goal, u0=u_goal, discretization=discretization, u_min=u_min, u_max=u_max
        )
        if isinstance(terminal_cost, str):
            if terminal_cost not in ("lqr", "Q"):
                raise InvalidArgument(f"terminal_cost must be 'lqr', 'Q' or an (n, n) matrix, got {terminal_cost!r}")
            Qf_m = final.S if terminal_cost == "lqr" else Qm.copy()
        else:
            Qf_m = weight_matrix("terminal_cost", terminal_cost, nt)
        if nt != n:  # a floating base: the tangent-space Jacobians point by point
            jc = [plant.linearize(x, u) for x, u in zip(x_ref, u_ref, strict=True)]
            A_c, B_c = np.array([j[0] for j in jc]), np.array([j[1] for j in jc])
        else:
            A_c, B_c = trajectory_jacobians(plant, x_ref, u_ref)
        if discretization == "step":
            jac = [plant.step_jacobians(x, u) for x, u in zip(x_ref, u_ref, strict=True)]
            A, B = np.array([j[0] for j in jac]), np.array([j[1] for j in jac])
        else:
            A, B = _discretize_all(A_c, B_c, dt, discretization)
        ctrl = cls(
            traj,
            A,
            B,
            Qm,
            Rm,
            final,
            dt=dt,
            x_ref=x_ref,
            u_ref=u_ref,
            Qf=Qf_m,
            u_min=u_min,
            u_max=u_max,
            difference=plant.difference if nt != n else None,
        )
        ctrl.A_c, ctrl.B_c = A_c, B_c
        return ctrl

    @classmethod
    def from_plant(
        cls,
        plant: Plant,
        Q: Weight,
        R: Weight,
        *,
        terminal_cost: str | Weight = "lqr",
        plan: Mapping[str, Any] | Trajectory | None = None,
        discretization: str = "step",
    ) -> TVLQR:
        """Plan with ``plan`` (a ``[plan]`` table, or a Trajectory) on ``plant``, then design along it.

        The inputs saturate at the plan's ``bounds.u_min``/``u_max``.

        Args:
            plant: The (nominal) plant.
            Q, R, terminal_cost: As in :meth:`from_trajectory`.
            plan: A mapping with the keys of the scenario's ``[plan]`` table
                (see :mod:`shinro_ctrl.planning.spec`) or a ready Trajectory.
            discretization: As in :meth:`from_trajectory`.

        Raises:
            InvalidArgument: no plan, or an invalid one.
            PlanningFailed: the trajectory optimization failed.
        """
        from shinro_ctrl.planning import Trajectory
        from shinro_ctrl.planning.spec import check_plan, make_plan

        if isinstance(plan, Trajectory):
            traj, bounds = plan, {}
        elif isinstance(plan, Mapping):
            spec = check_plan(plan, plant.state_dim, plant.input_dim)
            traj, bounds = make_plan(plant, spec), spec.get("bounds", {})
        else:
            raise InvalidArgument(f"plan: TVLQR needs a plan table ([plan]) or a Trajectory, got {plan!r}")
        return cls.from_trajectory(
            plant,
            traj,
            Q,
            R,
            terminal_cost=terminal_cost,
            discretization=discretization,
            u_min=bounds.get("u_min"),
            u_max=bounds.get("u_max"),
        )

    # ---------------------------------------------------------------- control
    def reset(self) -> None:
        """Restart at the beginning of the plan (step 0)."""
        self.step = 0

    def __call__(self, x: ArrayLike, ref: ArrayLike | None = None) -> np.ndarray:
        """The input for state ``x (n,)`` at the current step, then advance the step counter.

        ``ref`` is ignored: the plan is the reference (and the goal after it).

        Raises:
            ConcurrentUse: another thread is inside a call of this object.
        """
        if not self._busy.acquire(False):
            raise self._busy.refused()
        try:
            x = as_vector("x", x, self.state_dim)
            k = self.step
            self.step = k + 1
        finally:
            self._busy.release()
        return self._law(k, x)

    def at_time(self, t: float, x: ArrayLike) -> np.ndarray:
        """The input at time ``t`` [s] (step ``round(t / dt)``) for state ``x (n,)``; no counter change."""
        return self._law(max(0, round(float(t) / self.dt)), as_vector("x", x, self.state_dim))

    def plan_states(self, t: ArrayLike) -> np.ndarray:
        """The plan's state at run times ``t`` ``(T,)`` [s] (0 = the first call), NaN rows past the plan.

        Run time ``t`` is the plan's time ``trajectory.t[0] + t`` (call ``k`` uses sample ``k dt``); the
        rows with ``t`` beyond the plan's duration, where the goal's LQR takes over, are NaN. A run
        plots these as its reference and reports ``plan_tracking_rms`` from them.
        """
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        traj = self.trajectory
        inside = ts <= traj.duration + 1e-9 * max(1.0, traj.duration)
        out = np.full((ts.size, self.state_dim), np.nan)
        if np.any(inside):
            out[inside] = traj.x_at(traj.t[0] + np.clip(ts[inside], 0.0, traj.duration))
        return out

    def _law(self, k: int, x: np.ndarray) -> np.ndarray:
        if k >= self.horizon:
            return self.final(x)
        dx = x - self.x_ref[k] if self._difference is None else self._difference(x, self.x_ref[k])
        u = self.u_ref[k] - self.K[k] @ dx
        if self._saturate:
            np.clip(u, self.u_min, self.u_max, out=u)
        return u


def _discretize_all(A_c: np.ndarray, B_c: np.ndarray, dt: float, method: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`discretize` over a stack ``(K, n, n)``, ``(K, n, m)`` (vectorized for ``euler``)."""
    if method == "euler":
        n = A_c.shape[1]
        return np.eye(n) + dt * A_c, dt * B_c
    out = [discretize(a, b, dt, method) for a, b in zip(A_c, B_c, strict=True)]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])
